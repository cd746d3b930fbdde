"""Velocity obstacles for fast obstacles [Fiorini and Shiller, 1998] (seed 000 lines 1515-1520).

The thesis switches from the spiral to "an approach close to [Fiorini and Shiller, 1998]"
when an obstacle moves faster than a threshold (line 1516). A pure law: numpy and math.

Velocity obstacle (truncated at a time horizon tau). Robot at p_r with velocity u, a disc
obstacle at p_o with velocity w, combined radius R = robot radius + obstacle radius. With
``p = p_o - p_r`` and the relative velocity ``u_rel = u - w`` they collide within tau iff::

    min_{t in [0, tau]} |p - u_rel t| < R

i.e. ``u`` lies in the cone of apex w spanned by the disc of radius R around p (the
collision cone), cut at ``|u_rel| ~ |p| / tau``. :func:`in_velocity_obstacle` evaluates it
exactly (closest approach of the relative motion, clamped to [0, tau]).

Unicycle. The robot's velocity vector for a command (v, omega) is taken along the heading
it will have after ``heading_lead`` seconds, ``v (cos(theta + omega T), sin(theta + omega T))``.
:func:`choose_velocity` searches a grid of (v, omega) within the platform limits (and,
optionally, within one period of acceleration of the current command), keeps the candidates
whose velocity vector lies outside every velocity obstacle, and returns the one closest to
the preferred command in the weighted norm ``(dv / v_max)^2 + (domega / omega_max)^2``.
When every candidate is inside some cone it returns the one with the latest collision
(then the closest to the preferred command), flagged ``feasible = False``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from executive.core.frames import FloatArray

__all__ = [
    "MovingDisc",
    "VelocityChoice",
    "VoParams",
    "choose_velocity",
    "in_velocity_obstacle",
    "time_to_collision",
    "velocity_vector",
]


@dataclass(frozen=True, slots=True)
class MovingDisc:
    """An obstacle for the velocity-obstacle law: position, velocity, enclosing radius."""

    position: tuple[float, float]
    velocity: tuple[float, float]
    radius: float


@dataclass(frozen=True, slots=True)
class VoParams:
    """Limits and tuning of :func:`choose_velocity` (SI units)."""

    v_min: float = 0.0
    """Lowest linear speed (negative to allow reversing)."""
    v_max: float = 1.2
    omega_max: float = 1.0
    robot_radius: float = 0.6
    horizon: float = 5.0
    """tau: collisions later than this are ignored (s)."""
    heading_lead: float = 0.5
    """T: the velocity vector points along the heading after this time (s)."""
    n_v: int = 13
    n_omega: int = 21
    max_acceleration: float | None = None
    """With ``dt``: only commands within one period of acceleration of the current one."""
    max_angular_acceleration: float | None = None

    def __post_init__(self) -> None:
        if not self.v_min <= self.v_max or not self.v_max > 0.0:
            raise ValueError("need v_min <= v_max and v_max > 0")
        if not (self.omega_max > 0.0 and self.horizon > 0.0 and self.heading_lead >= 0.0):
            raise ValueError("omega_max, horizon must be > 0 and heading_lead >= 0")
        if self.n_v < 2 or self.n_omega < 2:
            raise ValueError("the grid needs at least 2 x 2 candidates")


@dataclass(frozen=True, slots=True)
class VelocityChoice:
    v: float
    omega: float
    feasible: bool
    """False: no candidate avoids every cone; (v, omega) delays the collision most."""
    time_to_collision: float


def velocity_vector(theta: float, v: float, omega: float, heading_lead: float) -> FloatArray:
    """The robot's velocity vector for the command (v, omega) (module docstring)."""
    heading = theta + omega * heading_lead
    return np.array([v * math.cos(heading), v * math.sin(heading)])


def time_to_collision(
    robot_xy: FloatArray, velocity: FloatArray, obstacle: MovingDisc, robot_radius: float
) -> float:
    """First time the discs touch under constant velocities; 0 if they overlap, inf never."""
    p = np.asarray(obstacle.position, dtype=float) - np.asarray(robot_xy, dtype=float)
    u = np.asarray(velocity, dtype=float) - np.asarray(obstacle.velocity, dtype=float)
    big_r = robot_radius + obstacle.radius
    c = float(p @ p) - big_r * big_r
    if c <= 0.0:
        return 0.0
    a = float(u @ u)
    b = float(p @ u)  # |p - u t|^2 = a t^2 - 2 b t + |p|^2
    disc = b * b - a * c
    if a == 0.0 or b <= 0.0 or disc < 0.0:
        return math.inf
    return (b - math.sqrt(disc)) / a


def in_velocity_obstacle(
    robot_xy: FloatArray,
    velocity: FloatArray,
    obstacle: MovingDisc,
    robot_radius: float,
    horizon: float,
) -> bool:
    """Whether ``velocity`` lies in the obstacle's velocity obstacle truncated at ``horizon``."""
    return time_to_collision(robot_xy, velocity, obstacle, robot_radius) < horizon


def choose_velocity(
    robot_xy: FloatArray,
    theta: float,
    preferred: tuple[float, float],
    obstacles: tuple[MovingDisc, ...],
    params: VoParams,
    current: tuple[float, float] | None = None,
    dt: float | None = None,
) -> VelocityChoice:
    """The admissible (v, omega) outside every velocity obstacle closest to ``preferred``.

    ``current`` and ``dt`` restrict the grid to one period of acceleration (when the
    parameters give the limits); the preferred command, clamped to the window, is always
    among the candidates.
    """
    p = params
    v_lo, v_hi, w_lo, w_hi = p.v_min, p.v_max, -p.omega_max, p.omega_max
    if current is not None and dt is not None:
        if p.max_acceleration is not None:
            v_lo = max(v_lo, min(v_hi, current[0] - p.max_acceleration * dt))
            v_hi = min(v_hi, max(v_lo, current[0] + p.max_acceleration * dt))
        if p.max_angular_acceleration is not None:
            w_lo = max(w_lo, min(w_hi, current[1] - p.max_angular_acceleration * dt))
            w_hi = min(w_hi, max(w_lo, current[1] + p.max_angular_acceleration * dt))
    vs = np.append(np.linspace(v_lo, v_hi, p.n_v), min(v_hi, max(v_lo, preferred[0])))
    ws = np.append(np.linspace(w_lo, w_hi, p.n_omega), min(w_hi, max(w_lo, preferred[1])))
    best: tuple[tuple[float, float], float, float, float] | None = None  # key, v, w, ttc
    for v in vs:
        for w in ws:
            u = velocity_vector(theta, float(v), float(w), p.heading_lead)
            ttc = min(
                (time_to_collision(robot_xy, u, o, p.robot_radius) for o in obstacles),
                default=math.inf,
            )
            cost = ((v - preferred[0]) / p.v_max) ** 2 + ((w - preferred[1]) / p.omega_max) ** 2
            key = (0.0 if ttc >= p.horizon else -ttc, float(cost))
            if best is None or key < best[0]:
                best = (key, float(v), float(w), ttc)
    assert best is not None
    _, v, w, ttc = best
    return VelocityChoice(v, w, ttc >= p.horizon, ttc)
