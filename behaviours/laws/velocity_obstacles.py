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

Turn, then go (:func:`choose_heading`, what the executive uses). A differential drive
cannot take a velocity vector at once: it turns on the spot to the vector's heading
(``|heading error| / omega_max`` seconds), then drives. Each candidate ground velocity
(a heading round the full circle, a speed; backwards for headings behind) is checked with
that delay: while the robot turns it stands still and the discs move, then the relative
motion is linear again, so both phases have closed-form contact times
(:func:`turn_then_go_contact`): the velocity obstacle of each disc, as seen after the turn.
This is the "generalized velocity obstacle" of Wilkie, van den Berg and Manocha (2009)
for one family of controls. It lets the robot sidestep a walker coming head-on, which
the heading-lead model above, looking only about the current heading, does not.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from executive.core.frames import FloatArray

__all__ = [
    "HeadingChoice",
    "HeadingVoParams",
    "MovingDisc",
    "VelocityChoice",
    "VoParams",
    "choose_heading",
    "choose_velocity",
    "crosses_ahead",
    "heading_command",
    "in_velocity_obstacle",
    "time_to_collision",
    "turn_then_go_contact",
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


# -- turn-then-go velocity obstacles (a differential-drive robot) -------------------------------
@dataclass(frozen=True, slots=True)
class HeadingVoParams:
    """Limits and tuning of :func:`choose_heading` (SI units)."""

    v_max: float = 1.2
    reverse_max: float = 1.0
    """Top reversing speed (0: never reverse)."""
    omega_max: float = 1.0
    deceleration: float = math.inf
    """The platform's braking (m/s^2): a candidate that drives the other way than the
    robot rolls (:func:`choose_heading`'s ``speed_now``) starts once the robot has
    stopped. inf: at once."""
    horizon: float = 4.0
    """tau: contacts later than this are ignored (s)."""
    n_heading: int = 36
    """Headings sampled round the full circle (10 degrees apart by default)."""
    n_speed: int = 7
    turn_weight: float = 0.01
    """Cost per second squared spent turning before the robot can drive off (quadratic:
    a small turn towards the preferred velocity always pays)."""
    reverse_weight: float = 0.05
    """Extra cost of a reversing candidate."""
    hold_weight: float = 0.3
    """Cost of leaving the previously chosen velocity, per unit of ``(1 - cos)`` of the
    angle between them: no dithering between passing left and passing right."""
    behind_weight: float = 0.5
    """Cost of a candidate that crosses a mover's path ahead of it (see
    :func:`crosses_ahead`): between two equally short ways round a crossing walker, pass
    behind it, as people do; the way ahead of it closes while the robot takes it."""
    behind_lookahead: float = 10.0
    """Crossings of a mover's path later than this (s) carry no cost."""
    behind_window: float = 6.0
    """A crossing counts as ahead of the mover when the mover would reach the crossing
    point within this time (s) after the robot; farther ahead it is harmless."""

    def __post_init__(self) -> None:
        if not (self.v_max > 0.0 and self.reverse_max >= 0.0):
            raise ValueError("need v_max > 0 and reverse_max >= 0")
        if not (self.omega_max > 0.0 and self.horizon > 0.0 and self.deceleration > 0.0):
            raise ValueError("omega_max, deceleration and horizon must be > 0")
        if self.n_heading < 4 or self.n_speed < 2:
            raise ValueError("need at least 4 headings and 2 speeds")


@dataclass(frozen=True, slots=True)
class HeadingChoice:
    """A velocity chosen by :func:`choose_heading`: drive along ``heading`` (in the
    frame of the positions) at ``speed``, backwards when ``reverse``."""

    heading: float
    speed: float
    reverse: bool
    feasible: bool
    """False: every candidate meets a disc within the horizon; this one meets it last."""
    time_to_collision: float
    turn_time: float
    """Seconds before the robot drives off at this velocity (the model's): its turn on the
    spot, or its braking to rest when longer and it drives the other way than it rolls."""

    @property
    def velocity(self) -> FloatArray:
        """The chosen ground velocity (m/s)."""
        return np.array([self.speed * math.cos(self.heading), self.speed * math.sin(self.heading)])


def _first_contact(
    d0: FloatArray, rel: FloatArray, radii: FloatArray, t_end: FloatArray
) -> FloatArray:
    """First t in [0, t_end] with ``|d0 + rel t| <= radius``, inf if none (broadcast).

    ``d0`` (..., 2) is the obstacle's offset from the robot, ``rel`` (..., 2) its velocity
    relative to the robot. An offset already inside the radius gives 0 while the motion
    closes the gap and inf otherwise: a robot inside an inflated disc may leave it, or
    stand (turn on the spot) beside a static one.
    """
    a = np.einsum("...i,...i->...", rel, rel)
    b = np.einsum("...i,...i->...", d0, rel)  # |d0 + rel t|^2 = a t^2 + 2 b t + c
    c = np.einsum("...i,...i->...", d0, d0) - radii * radii
    disc = b * b - a * c
    with np.errstate(invalid="ignore", divide="ignore"):
        t = (-b - np.sqrt(np.maximum(disc, 0.0))) / a
    hit = (a > 0.0) & (b < 0.0) & (disc >= 0.0) & (t <= t_end)
    out = np.where(hit, t, np.inf)
    return np.where(c <= 0.0, np.where(b < 0.0, 0.0, np.inf), out)


def turn_then_go_contact(
    robot_xy: FloatArray,
    turn_time: FloatArray,
    velocity: FloatArray,
    obstacles: tuple[MovingDisc, ...],
    robot_radius: float,
    horizon: float,
) -> FloatArray:
    """First contact time of K candidate motions with any disc within ``horizon`` (K,).

    Candidate k turns on the spot for ``turn_time[k]`` seconds, then drives at the constant
    ground velocity ``velocity[k]``; every disc moves at its constant velocity. Both phases
    are linear relative motions, so each contact time is the smaller root of a quadratic
    (the velocity obstacle of Fiorini and Shiller, 1998, with the turning delay of a
    differential drive in front: the "generalized velocity obstacle" idea of Wilkie, van
    den Berg and Manocha, 2009, in closed form for this two-phase control).
    """
    if not obstacles:
        return np.full(len(turn_time), np.inf)
    pos = np.array([o.position for o in obstacles], dtype=float) - np.asarray(robot_xy, float)
    vel = np.array([o.velocity for o in obstacles], dtype=float)
    radii = robot_radius + np.array([o.radius for o in obstacles], dtype=float)
    t1 = np.minimum(np.asarray(turn_time, dtype=float), horizon)[:, None]  # (K, 1)
    # phase 1: the robot turns in place, the discs move (nothing to check without a turn)
    first = _first_contact(pos[None, :, :], vel[None, :, :], radii, t1)
    first = np.where(t1 > 0.0, first, np.inf)
    # phase 2: from t1 on, the robot drives at its velocity
    d0 = pos[None, :, :] + vel[None, :, :] * t1[:, :, None]
    rel = vel[None, :, :] - np.asarray(velocity, float)[:, None, :]
    second = t1 + _first_contact(d0, rel, radii, horizon - t1)
    return np.minimum(first, second).min(axis=1)


def _worst_clearance(
    robot_xy: FloatArray,
    turn_time: FloatArray,
    velocity: FloatArray,
    obstacles: tuple[MovingDisc, ...],
    robot_radius: float,
    horizon: float,
    samples: int = 16,
) -> FloatArray:
    """Smallest signed clearance (centre distance minus the radii) of each turn-then-go
    candidate to any disc at ``samples`` instants in (0, horizon] (K,)."""
    t = np.linspace(horizon / samples, horizon, samples)  # (S,)
    moved = np.maximum(0.0, t[None, :] - np.asarray(turn_time, float)[:, None])  # (K, S)
    robot = (
        np.asarray(robot_xy, float) + moved[:, :, None] * np.asarray(velocity, float)[:, None, :]
    )
    pos = np.array([o.position for o in obstacles], dtype=float)
    vel = np.array([o.velocity for o in obstacles], dtype=float)
    radii = robot_radius + np.array([o.radius for o in obstacles], dtype=float)
    where = pos[None, :, :] + t[:, None, None] * vel[None, :, :]  # (S, M, 2)
    gap = np.linalg.norm(where[None, :, :, :] - robot[:, :, None, :], axis=-1) - radii
    return gap.min(axis=(1, 2))


def crosses_ahead(
    robot_xy: FloatArray,
    turn_time: FloatArray,
    velocity: FloatArray,
    obstacles: tuple[MovingDisc, ...],
    robot_radius: float,
    lookahead: float,
    window: float,
    min_speed: float = 0.05,
) -> FloatArray:
    """Whether each turn-then-go candidate crosses some mover's path ahead of it (K,) bool.

    A mover (speed >= ``min_speed``) at p with velocity w sweeps the line through p along
    ŵ. The candidate (turn for ``turn_time``, then drive at ``velocity`` u from the robot's
    position r0) has the signed lateral offset ``s(t) = ŵ x (r0 - p) + (ŵ x u)(t - t1)``
    from that line, zero at ``t_c = t1 - ŵ x (r0 - p) / (ŵ x u)``; there the robot is
    ``g = ŵ . (r(t_c) - p) - |w| t_c`` ahead of the mover along its way. The candidate
    crosses ahead when ``t1 <= t_c <= lookahead`` and ``0 < g < |w| window`` (the mover
    would reach the crossing point less than ``window`` seconds after the robot). A robot
    already on the mover's way (``|s(t1)|`` under the two radii: a chaser, a walker coming
    head-on) has nothing to cross.
    """
    k = len(turn_time)
    out = np.zeros(k, dtype=bool)
    r0 = np.asarray(robot_xy, dtype=float)
    u = np.asarray(velocity, dtype=float)
    t1 = np.asarray(turn_time, dtype=float)
    for o in obstacles:
        w = np.asarray(o.velocity, dtype=float)
        speed = float(np.hypot(*w))
        if speed < min_speed:
            continue
        wh = w / speed
        rel = r0 - np.asarray(o.position, dtype=float)
        s0 = wh[0] * rel[1] - wh[1] * rel[0]
        if abs(s0) < robot_radius + o.radius:
            continue
        ds = wh[0] * u[:, 1] - wh[1] * u[:, 0]  # (K,)
        # a tiny ds overflows to inf (never within the lookahead): not a problem
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            t_c = t1 - s0 / ds
        valid = (np.abs(ds) > 1e-9) & (t_c >= t1) & (t_c <= lookahead)
        drive = np.where(valid, t_c - t1, 0.0)
        along = float(wh @ rel) + (u @ wh) * drive - speed * np.where(valid, t_c, 0.0)
        out |= valid & (along > 0.0) & (along < speed * window)
    return out


def choose_heading(
    robot_xy: FloatArray,
    theta: float,
    preferred: FloatArray,
    obstacles: tuple[MovingDisc, ...],
    params: HeadingVoParams,
    robot_radius: float,
    previous: FloatArray | None = None,
    speed_scale: Callable[[FloatArray], FloatArray] | None = None,
    speed_now: float = 0.0,
) -> HeadingChoice:
    """The velocity outside every velocity obstacle closest to ``preferred``, for a robot
    that must turn before it drives.

    ``speed_scale`` maps travel headings (K,) to the factor by which what executes a
    command will scale a speed along them (the safety layer's slowdown zone before a
    parked vehicle): each candidate is judged at the ground velocity it will really have,
    and its chosen ``speed`` stays the commanded one. Without it an escape at 0.2 m/s
    from a 0.12 m/s trolley, slowed to 0.05 m/s towards a vehicle behind, was taken for
    clear (campaign episode 527).

    ``speed_now`` is the robot's measured forward speed (m/s, negative reversing): a
    candidate that drives the other way starts no sooner than the robot can stop,
    ``|speed_now| / deceleration``, counted with its turn. Without it a robot fleeing
    forwards at 2 m/s took backing away at 2 m/s for an instant escape (A320 campaign
    episode 69).

    Candidates: ``n_heading`` headings round the circle (and the preferred one) times
    ``n_speed`` speeds in [0, v_max] (and the preferred one), driven forwards after
    turning on the spot, or
    backwards (up to ``reverse_max``) for headings more than 90 degrees off the robot's.
    Each is checked by :func:`turn_then_go_contact`. Cost: ``|u - preferred|^2 / v_max^2
    + turn_weight * turn time^2 + reverse_weight (reversing) + hold_weight (1 - cos angle
    to previous) + behind_weight (crosses a mover's way ahead of it,`` :func:`crosses_ahead`
    ``)``. The cheapest contact-free candidate wins; when there is none, the one
    whose contact comes last (then the cheapest), flagged ``feasible = False``.
    """
    p = params
    preferred = np.asarray(preferred, dtype=float)
    headings = theta + np.arange(p.n_heading) * (2.0 * math.pi / p.n_heading)
    if float(np.hypot(*preferred)) > 1e-9:
        headings = np.append(headings, math.atan2(preferred[1], preferred[0]))
    offset = np.remainder(headings - theta + math.pi, 2.0 * math.pi) - math.pi  # (-pi, pi]
    speeds = np.linspace(0.0, p.v_max, p.n_speed)
    speeds = np.append(speeds, min(p.v_max, float(np.hypot(*preferred))))
    h, s = (g.ravel() for g in np.meshgrid(headings, speeds, indexing="ij"))
    o = np.repeat(offset, len(speeds))
    turn = np.abs(o) / p.omega_max
    reverse = np.zeros(len(h), dtype=bool)
    if p.reverse_max > 0.0:
        back = np.abs(o) > 0.5 * math.pi
        rs = np.minimum(s[back], p.reverse_max)
        h = np.concatenate((h, h[back]))
        s = np.concatenate((s, rs))
        turn = np.concatenate((turn, (math.pi - np.abs(o[back])) / p.omega_max))
        reverse = np.concatenate((reverse, np.ones(len(rs), dtype=bool)))
    turn = np.where(s > 0.0, turn, 0.0)  # standing still needs no turn
    if speed_now != 0.0 and math.isfinite(p.deceleration):  # the other way: stop first
        against = (s > 0.0) & (reverse if speed_now > 0.0 else ~reverse)
        turn = np.where(against, np.maximum(turn, abs(speed_now) / p.deceleration), turn)
    if speed_scale is None:
        ground = s
    else:  # the speed it will get; one factor per heading, not per candidate
        unique, index = np.unique(h, return_inverse=True)
        ground = s * speed_scale(unique)[index]
    u = np.column_stack((ground * np.cos(h), ground * np.sin(h)))
    contact = turn_then_go_contact(robot_xy, turn, u, obstacles, robot_radius, p.horizon)
    cost = np.einsum("ki,ki->k", u - preferred, u - preferred) / (p.v_max * p.v_max)
    cost += p.turn_weight * turn * turn + p.reverse_weight * reverse
    if previous is not None and float(np.hypot(*previous)) > 1e-9:
        moving = s > 1e-9
        ref = math.atan2(previous[1], previous[0])
        cost += np.where(moving, p.hold_weight * 0.5 * (1.0 - np.cos(h - ref)), 0.0)
    if p.behind_weight > 0.0 and obstacles:
        ahead = crosses_ahead(
            robot_xy, turn, u, obstacles, robot_radius, p.behind_lookahead, p.behind_window
        )
        cost += p.behind_weight * ahead
    free = contact >= p.horizon
    if free.any():
        k = int(np.flatnonzero(free)[np.argmin(cost[free])])
    else:  # the best escape: the largest clearance left over the horizon, then the cheapest
        score = _worst_clearance(robot_xy, turn, u, obstacles, robot_radius, p.horizon)
        k = int(np.lexsort((cost, -np.round(score, 3)))[0])
    return HeadingChoice(
        float(h[k]),
        float(s[k]),
        bool(reverse[k]),
        bool(contact[k] >= p.horizon),
        float(contact[k]),
        float(turn[k]),
    )


def heading_command(
    theta: float, choice: HeadingChoice, omega_max: float, gain: float = 2.0, align: float = 0.6
) -> tuple[float, float]:
    """The unicycle command (v, omega) that carries out ``choice``: turn towards its
    heading (proportional, saturated at ``omega_max``), and drive at its speed scaled
    down linearly with the heading error, to zero at ``align`` rad (backwards when the
    choice reverses)."""
    facing = choice.heading + (math.pi if choice.reverse else 0.0)
    error = math.remainder(facing - theta, 2.0 * math.pi)
    omega = max(-omega_max, min(omega_max, gain * error))
    v = choice.speed * max(0.0, 1.0 - abs(error) / align)
    return (-v if choice.reverse else v), omega
