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
    """First time the discs touch under constant velocities, inf if never.

    Discs that already overlap give 0 unless the relative motion separates them (then
    inf): a robot that finds itself inside an inflated disc may still leave it.
    """
    ttc = _ttc_matrix(
        np.asarray(robot_xy, dtype=float),
        np.asarray(velocity, dtype=float).reshape(1, 2),
        np.asarray(obstacle.position, dtype=float).reshape(1, 2),
        np.asarray(obstacle.velocity, dtype=float).reshape(1, 2),
        np.array([robot_radius + obstacle.radius]),
    )
    return float(ttc[0, 0])


def _ttc_matrix(
    robot_xy: FloatArray, u: FloatArray, pos: FloatArray, vel: FloatArray, radii: FloatArray
) -> FloatArray:
    """Time to collision of K robot velocities ``u`` (K, 2) against M discs: (K, M)."""
    p = pos - robot_xy  # (M, 2)
    rel = u[:, None, :] - vel[None, :, :]  # (K, M, 2)
    c = np.einsum("mi,mi->m", p, p) - radii * radii  # (M,)
    a = np.einsum("kmi,kmi->km", rel, rel)
    b = np.einsum("kmi,mi->km", rel, p)  # |p - u t|^2 = a t^2 - 2 b t + |p|^2
    disc = b * b - a * c[None, :]
    with np.errstate(invalid="ignore", divide="ignore"):
        t = (b - np.sqrt(np.maximum(disc, 0.0))) / a
    ttc = np.where((a > 0.0) & (b > 0.0) & (disc >= 0.0), t, np.inf)
    overlap = c <= 0.0
    return np.where(overlap[None, :], np.where(b >= 0.0, 0.0, np.inf), ttc)


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
    v_grid, w_grid = (g.ravel() for g in np.meshgrid(vs, ws, indexing="ij"))
    heading = theta + w_grid * p.heading_lead
    u = np.column_stack((v_grid * np.cos(heading), v_grid * np.sin(heading)))
    if obstacles:
        ttc_all = _ttc_matrix(
            np.asarray(robot_xy, dtype=float),
            u,
            np.array([o.position for o in obstacles], dtype=float),
            np.array([o.velocity for o in obstacles], dtype=float),
            np.array([p.robot_radius + o.radius for o in obstacles]),
        ).min(axis=1)
    else:
        ttc_all = np.full(len(u), np.inf)
    cost = ((v_grid - preferred[0]) / p.v_max) ** 2 + ((w_grid - preferred[1]) / p.omega_max) ** 2
    # lexicographic: collision-free first (then the cheapest), else the latest collision
    late = np.where(ttc_all >= p.horizon, 0.0, -ttc_all)
    k = int(np.lexsort((cost, late))[0])
    v, w, ttc = float(v_grid[k]), float(w_grid[k]), float(ttc_all[k])
    return VelocityChoice(v, w, ttc >= p.horizon, ttc)
