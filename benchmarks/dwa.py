"""A dynamic window approach (DWA) baseline for the avoidance campaign of issue 6.

Fox, Burgard and Thrun, "The dynamic window approach to collision avoidance", IEEE
Robotics & Automation Magazine 4(1), 1997. Written here from the paper's description, as a
*benchmark* baseline: it is not shipped as a controller (the package is ``executive``,
``behaviours`` and ``sim2d``); it plugs into the executive through the compiler's
:attr:`executive.compiler.CompileOptions.avoider` (see :class:`DwaAvoidance`).

The law (:func:`dwa_choose`, pure: numpy and math)
--------------------------------------------------
1. **Dynamic window.** The candidates (v, omega) are an ``n_v`` x ``n_omega`` grid over the
   velocities reachable from the current one within ``window`` = T seconds (one control
   period of the DWA) at the platform's accelerations, intersected with the limits::

       V_d = [v0 - a_v T, v0 + a_v T] & [v_min, v_max]
       W_d = [w0 - a_w T, w0 + a_w T] & [-omega_max, omega_max]

   The DWA's control period is Fox et al.'s 0.25 s, not the executive's 20 ms tick: with
   a one-tick window (+-0.02 m/s, +-0.04 rad/s) the search only sees a tiny neighbourhood
   of the current velocity and stays in local maxima of the objective (on a kinematic
   check it drove straight at a car across the track and stopped in front of it, the
   objective being flat in omega at omega = 0 there); with 0.25 s it turns away in time.

2. **Arcs.** Each candidate is held constant over ``horizon`` seconds (unicycle arc,
   integrated every ``step`` s) from the current pose.
3. **Obstacles** are discs (position, velocity, radius) predicted at constant velocity.
   The robot is its ``length`` x ``width`` rectangle centred on the axle (the footprint
   the dry-run judge and the e-stop use), not a disc: the clearance of an arc at time t is
   the distance from the rectangle at the arc's pose to the predicted disc.
4. **Collision-free and admissible.** An arc is *collision-free* when its clearance to
   each disc never drops below that disc's margin over the horizon: ``margin`` (0.65 m)
   for a static disc, ``moving_margin`` (1.0 m) for a moving one (nor below the current
   clearance when the robot is already closer than that: moving away is always
   allowed). A velocity is *admissible* (Fox et al., eq. 14) when the robot can brake to
   a stop on its arc before the first contact: ``v^2 / (2 a_v) <= v t_c`` with t_c the
   first time the clearance goes below the threshold.
5. **Objective** (Fox et al., eq. 15, with fixed rather than per-cycle normalisation)::

       G(v, w) = w_heading * heading + w_clearance * clearance + w_speed * velocity

   ``heading`` = 1 - |bearing of the target| / pi, the bearing taken (as in the paper) at
   the pose reached after one window followed by a full-deceleration stop, so that
   turning away costs little heading; ``clearance`` = min(arc clearance, cap) / cap with
   cap = ``clearance_cap`` and the arc clearance that of a disc of ``body_radius`` at
   the axle (see :func:`arc_clearances`; Fox et al. use the distance to the first
   obstacle on the arc, we use the arc's smallest clearance, which also scores moving
   obstacles passing beside it); ``velocity`` = v / v_max. Default weights
   1.0 / 0.6 / 0.3: the heading dominates as in the paper (alpha = 2, beta = gamma = 0.2
   after their per-cycle normalisation); our clearance weight is larger because the term
   is scaled over 1.5 m rather than over the candidate set, and must make the robot turn
   away before the arcs ahead become colliding. Chosen on a kinematic check (unicycle
   with the platform's accelerations; a static disc, a car along and across the track,
   a wall with a gap, crossing and oncoming movers): the footprint clearance stayed
   >= 1.1 m in every case and the robot reached the goal in all but one, where it ran
   alongside a mover that kept crossing for ever (a local method: it never turns back).
6. **Choice.** The best-scoring collision-free candidate; when there is none, the
   admissible candidate with the latest contact (then the best score); when none is
   admissible either, the strongest braking in the window with the turn rate that delays
   the contact most (``mode`` says which).

The adapter (:class:`DwaAvoidance`)
-----------------------------------
A :class:`behaviours.base.Controller` with the compiler's ``AvoiderFactory`` signature
``(goal, session, platform, period)``. Each tick it reads ``OBSTACLES`` and ``POSE`` (and
``SENSOR_FRAME`` once, to seed the current velocity from the wheel speeds when it is
engaged: the go-to-goal command that was running is not visible to it), expresses the
tracks in the airport frame A with :func:`obstacle_in_airport`, and plans against *every*
track within ``sensing_range`` (6 m) of the robot, not only the session's one:

* ``circle`` tracks: the fitted circle; ``blob`` tracks: the enclosing circle;
* ``line`` tracks: discs of radius ``LINE_DISC_RADIUS`` every ``LINE_DISC_SPACING`` along
  the fitted segment (a box seen as a line is not inflated to its enclosing circle);
* ``zone`` tracks (forbidden-zone edges injected as virtual walls) are *included*, as
  static lines of discs: the DWA keeps off the geofence itself rather than meeting the
  safety layer's stop (the track missions have no zones, so this never happens in the
  campaign);
* tracks slower than ``static_speed`` (tracker noise on parked things) are static.

It re-plans every DWA period (``window``, rounded to whole ticks) and holds its command in
between, like the paper's 4 Hz controller; the safety layer ramps each new command at the
platform's limits (the window is what they allow in one DWA period). The current velocity
is the last command it chose. It sets ``session.released`` with a reason when the
session's obstacle no longer blocks the straight path to the goal
(:func:`behaviours.laws.spiral.path_blocked`, with the guard's margin) or lies wholly
behind the robot (behind the line through the axle, across the direction to the goal);
the guard then hands back to go-to-goal.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import NamedTuple, Protocol

import numpy as np
import py_trees

from behaviours.base import Controller
from behaviours.controllers.avoidance import AvoidanceSession, obstacle_in_airport
from behaviours.goals import Goal
from behaviours.keys import COMMAND, OBSTACLES, POSE, SENSOR_FRAME
from behaviours.laws.spiral import SpiralObstacle, path_blocked
from behaviours.laws.velocity_obstacles import MovingDisc
from executive.core.frames import FloatArray, Pose2
from executive.core.model import Platform
from executive.core.records import Obstacles, PoseEstimate, SensorFrame, VelocityCommand

Status = py_trees.common.Status

__all__ = [
    "LINE_DISC_RADIUS",
    "LINE_DISC_SPACING",
    "Clearances",
    "DiscLike",
    "DwaAvoidance",
    "DwaChoice",
    "DwaParams",
    "arc_clearances",
    "candidates",
    "dwa_choose",
    "dwa_command",
    "obstacle_discs",
    "rollout",
]

LINE_DISC_RADIUS = 0.1
"""Radius of the discs that stand for a line track (m)."""
LINE_DISC_SPACING = 0.1
"""Their spacing along the segment (m): the union is at least 0.087 m thick everywhere."""
DEFAULT_RELEASE_MARGIN = 0.5 * 1.0 + 0.6 + 0.3
"""The guard's path margin on the track missions (half-width + r_ES + the compiler's
``AVOIDANCE_PATH_MARGIN``), for a session that does not carry its own ``margin``."""


class DiscLike(Protocol):
    """An obstacle disc: :class:`behaviours.laws.velocity_obstacles.MovingDisc` is one."""

    @property
    def position(self) -> tuple[float, float]: ...

    @property
    def velocity(self) -> tuple[float, float]: ...

    @property
    def radius(self) -> float: ...


@dataclass(frozen=True, slots=True)
class DwaParams:
    """Limits, window and weights of the DWA (SI units); see the module docstring."""

    v_min: float = 0.0
    """Lowest forward speed (0: the baseline never reverses, like go-to-goal)."""
    v_max: float = 0.6
    """Highest forward speed: the track missions' cruise speed."""
    omega_max: float = 1.0
    max_acceleration: float = 1.0
    max_angular_acceleration: float = 2.0
    window: float = 0.25
    """T: the DWA's control period (Fox et al.: 0.25 s); the window holds the velocities
    reachable within it (module docstring)."""
    horizon: float = 2.5
    """How long each arc is simulated (s)."""
    step: float = 0.1
    """Integration step of the arcs (s)."""
    n_v: int = 7
    n_omega: int = 15
    length: float = 1.4
    """Robot footprint, a rectangle centred on the axle (m)."""
    width: float = 1.0
    margin: float = 0.65
    """Smallest footprint clearance of a collision-free arc to a static disc (m): r_ES of
    the track missions (0.6 m) + 0.05 m, so that a chosen arc does not latch the e-stop
    (and a 2.5 m gap, 0.75 m each side, stays passable)."""
    moving_margin: float = 1.0
    """The same for a moving disc (m): the prediction at constant velocity is rough, and
    a robot stopped by the e-stop in a mover's way is run into."""
    clearance_cap: float = 1.5
    """Arc clearance above which the clearance term is 1 (m)."""
    body_radius: float = 0.5
    """Radius of the disc at the axle whose clearance the objective scores (m): the
    footprint's half-width (see :func:`arc_clearances`)."""
    w_heading: float = 1.0
    w_clearance: float = 0.6
    w_speed: float = 0.3

    def __post_init__(self) -> None:
        if not self.v_min <= self.v_max or not self.v_max > 0.0:
            raise ValueError("need v_min <= v_max and v_max > 0")
        for name in (
            "omega_max",
            "max_acceleration",
            "max_angular_acceleration",
            "window",
            "horizon",
            "step",
            "length",
            "width",
            "clearance_cap",
        ):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"DwaParams.{name} must be > 0")
        if self.n_v < 2 or self.n_omega < 2:
            raise ValueError("the window grid needs at least 2 x 2 candidates")
        if self.margin < 0.0 or self.moving_margin < 0.0:
            raise ValueError("margins must be >= 0")

    def within(self, platform: Platform) -> DwaParams:
        """These parameters clipped to the platform's limits, with its footprint."""
        return replace(
            self,
            v_max=min(self.v_max, platform.max_speed),
            v_min=max(self.v_min, -platform.max_speed),
            omega_max=min(self.omega_max, platform.max_angular_speed),
            max_acceleration=min(self.max_acceleration, platform.max_acceleration),
            max_angular_acceleration=min(
                self.max_angular_acceleration, platform.max_angular_acceleration
            ),
            length=platform.length,
            width=platform.width,
        )


@dataclass(frozen=True, slots=True)
class DwaChoice:
    """The chosen command and why.

    ``mode``: ``free`` (a collision-free arc), ``admissible`` (every arc meets an obstacle
    within the horizon; this one can still stop before it, and meets it last) or ``brake``
    (none can: strongest braking). ``clearance`` is the chosen arc's smallest footprint
    clearance over the horizon, ``contact`` the first time it goes below the threshold
    (inf: never), ``n_free`` how many candidates were collision-free.
    """

    v: float
    omega: float
    mode: str
    score: float
    clearance: float
    contact: float
    n_free: int


def candidates(velocity: tuple[float, float], params: DwaParams) -> tuple[FloatArray, FloatArray]:
    """The dynamic window's grid: flat arrays (v, omega) of ``n_v * n_omega`` candidates.

    A current velocity outside the limits (it cannot be, unless the limits changed) is
    first brought back as fast as the accelerations allow.
    """
    p = params
    v0, w0 = velocity
    dv, dw = p.max_acceleration * p.window, p.max_angular_acceleration * p.window
    v_lo = min(max(v0 - dv, p.v_min), p.v_max)
    v_hi = max(min(v0 + dv, p.v_max), p.v_min)
    w_lo = min(max(w0 - dw, -p.omega_max), p.omega_max)
    w_hi = max(min(w0 + dw, p.omega_max), -p.omega_max)
    vs = np.linspace(v_lo, v_hi, p.n_v)
    ws = np.linspace(w_lo, w_hi, p.n_omega)
    v_grid, w_grid = np.meshgrid(vs, ws, indexing="ij")
    return v_grid.ravel(), w_grid.ravel()


def rollout(pose: Pose2, v: FloatArray, omega: FloatArray, params: DwaParams) -> FloatArray:
    """Poses along each constant-(v, omega) arc: (N, K + 1, 3), index 0 the current pose,
    then every ``step`` until ``horizon`` (midpoint-heading integration)."""
    k = max(1, math.ceil(params.horizon / params.step - 1e-9))
    dt = params.horizon / k
    t = np.arange(k + 1) * dt
    theta = pose.theta + omega[:, None] * t[None, :]
    mid = pose.theta + omega[:, None] * (t[None, 1:] - 0.5 * dt)
    dx = np.cumsum(v[:, None] * dt * np.cos(mid), axis=1)
    dy = np.cumsum(v[:, None] * dt * np.sin(mid), axis=1)
    out = np.empty((len(v), k + 1, 3))
    out[:, 0, :] = (pose.x, pose.y, pose.theta)
    out[:, 1:, 0] = pose.x + dx
    out[:, 1:, 1] = pose.y + dy
    out[:, :, 2] = theta
    return out


class Clearances(NamedTuple):
    """What :func:`arc_clearances` returns, each (N, K + 1): per candidate and pose."""

    footprint: FloatArray
    """Footprint clearance to the nearest predicted disc (m)."""
    excess: FloatArray
    """Smallest footprint clearance minus that disc's margin (``margin`` for a static
    disc, ``moving_margin`` for a moving one): negative is "too close"."""
    body: FloatArray
    """Clearance of the disc of ``body_radius`` at the axle: what the objective scores."""


def arc_clearances(
    poses: FloatArray, obstacles: Sequence[DiscLike], params: DwaParams
) -> Clearances:
    """Clearances to the predicted discs at each pose of each arc.

    The disc m is at ``position + velocity * t`` at the time t of pose k (``k * dt``).
    The footprint clearance is the distance from the robot's rectangle to the disc
    (negative when they overlap; ``-radius`` when the centre is inside the rectangle).
    The body clearance, which the objective scores, is the distance from a disc of
    radius ``body_radius`` at the axle: unlike the rectangle's it does not depend on the
    heading (turning swings the rectangle's corners, which would put a local maximum of
    the objective at "no turn"). All inf without discs.
    """
    n, k1, _ = poses.shape
    if not obstacles:
        inf = np.full((n, k1), np.inf)
        return Clearances(inf, inf.copy(), inf.copy())
    pos = np.array([o.position for o in obstacles], dtype=float)  # (M, 2)
    vel = np.array([o.velocity for o in obstacles], dtype=float)
    rad = np.array([o.radius for o in obstacles], dtype=float)
    margin = np.where(np.hypot(vel[:, 0], vel[:, 1]) > 0.0, params.moving_margin, params.margin)
    t = np.arange(k1) * (params.horizon / (k1 - 1) if k1 > 1 else 0.0)
    centres = pos[None, :, :] + t[:, None, None] * vel[None, :, :]  # (K + 1, M, 2)
    d = centres[None, :, :, :] - poses[:, :, None, :2]  # (N, K + 1, M, 2)
    c, s = np.cos(poses[:, :, 2])[..., None], np.sin(poses[:, :, 2])[..., None]
    along = np.abs(c * d[..., 0] + s * d[..., 1]) - 0.5 * params.length
    across = np.abs(-s * d[..., 0] + c * d[..., 1]) - 0.5 * params.width
    outside = np.hypot(np.maximum(along, 0.0), np.maximum(across, 0.0))
    inside = np.minimum(np.maximum(along, across), 0.0)  # <= 0: centre inside the box
    foot = outside + inside - rad
    body = (np.hypot(d[..., 0], d[..., 1]) - rad).min(axis=2) - params.body_radius
    return Clearances(foot.min(axis=2), (foot - margin).min(axis=2), body)


def dwa_choose(
    pose: Pose2,
    velocity: tuple[float, float],
    target_xy: FloatArray | tuple[float, float],
    obstacles: Sequence[DiscLike],
    params: DwaParams,
) -> DwaChoice:
    """The DWA command for the robot at ``pose`` moving at ``velocity`` = (v, omega),
    heading for ``target_xy``, among ``obstacles`` (discs in the same frame as ``pose``)."""
    p = params
    v, w = candidates(velocity, p)
    poses = rollout(pose, v, w, p)
    clear = arc_clearances(poses, obstacles, p)
    now = clear.excess[0, 0]  # the same for every candidate: the current pose
    threshold = min(0.0, now - 1e-6) if math.isfinite(now) else 0.0
    below = clear.excess[:, 1:] < threshold
    hit = below.any(axis=1)
    dt = p.horizon / below.shape[1]
    contact = np.where(hit, (np.argmax(below, axis=1) + 1) * dt, np.inf)
    arc_clear = clear.footprint[:, 1:].min(axis=1)
    # objective
    tx, ty = float(target_xy[0]), float(target_xy[1])
    # heading at the pose reached after one window and a full-deceleration stop (Fox et
    # al.); the position is taken on the arc at the equivalent constant-speed time
    tau_v = p.window + np.abs(v) / (2.0 * p.max_acceleration)
    end_theta = pose.theta + w * (p.window + np.abs(w) / (2.0 * p.max_angular_acceleration))
    chord = pose.theta + 0.5 * w * tau_v
    end_x = pose.x + v * tau_v * np.cos(chord)
    end_y = pose.y + v * tau_v * np.sin(chord)
    bearing = np.arctan2(ty - end_y, tx - end_x) - end_theta
    bearing = np.abs((bearing + math.pi) % (2.0 * math.pi) - math.pi)
    heading = 1.0 - bearing / math.pi
    clearance = np.clip(clear.body[:, 1:].min(axis=1), 0.0, p.clearance_cap) / p.clearance_cap
    speed = v / p.v_max
    score = p.w_heading * heading + p.w_clearance * clearance + p.w_speed * speed
    free = ~hit
    if free.any():
        k = int(np.argmax(np.where(free, score, -np.inf)))
        mode = "free"
    else:
        travelled = np.abs(v) * contact
        admissible = v * v / (2.0 * p.max_acceleration) <= travelled + 1e-9
        if admissible.any():
            # latest contact first, then the best score (lexsort: last key is primary)
            order = np.lexsort((-score, -np.where(admissible, contact, -np.inf)))
            k = int(order[0])
            mode = "admissible"
        else:
            slowest = np.isclose(np.abs(v), np.abs(v).min())
            order = np.lexsort((-score, -np.where(slowest, contact, -np.inf)))
            k = int(order[0])
            mode = "brake"
    return DwaChoice(
        float(v[k]),
        float(w[k]),
        mode,
        float(score[k]),
        float(arc_clear[k]),
        float(contact[k]),
        int(free.sum()),
    )


def dwa_command(
    pose: Pose2,
    velocity: tuple[float, float],
    target_xy: FloatArray | tuple[float, float],
    obstacles: Sequence[DiscLike],
    params: DwaParams,
) -> tuple[float, float]:
    """(v, omega) of :func:`dwa_choose`."""
    choice = dwa_choose(pose, velocity, target_xy, obstacles, params)
    return choice.v, choice.omega


def obstacle_discs(obstacle: SpiralObstacle, static_speed: float = 0.1) -> list[MovingDisc]:
    """Discs standing for one obstacle (in the obstacle's frame): the fitted or enclosing
    circle, or a line of small discs along a segment (module docstring)."""
    velocity = obstacle.velocity if obstacle.speed >= static_speed else (0.0, 0.0)
    if obstacle.is_line:
        a, b = obstacle.segment()
        n = max(2, math.ceil(float(np.linalg.norm(b - a)) / LINE_DISC_SPACING) + 1)
        return [
            MovingDisc((float(x), float(y)), velocity, LINE_DISC_RADIUS)
            for x, y in np.linspace(a, b, n)
        ]
    cx, cy = obstacle.centre
    return [MovingDisc((float(cx), float(cy)), velocity, obstacle.radius)]


def _behind(robot: FloatArray, target: FloatArray, obstacle: SpiralObstacle) -> bool:
    """Whether the whole obstacle lies behind the robot's axle, across the goal direction."""
    direction = target - robot
    norm = float(np.linalg.norm(direction))
    if norm < 1e-9:
        return False
    u = direction / norm
    if obstacle.is_line:
        return all(float((end - robot) @ u) < 0.0 for end in obstacle.segment())
    return float((obstacle.centre - robot) @ u) + obstacle.radius < 0.0


class DwaAvoidance(Controller):
    """The DWA baseline as the avoidance controller of one navigation (module docstring).

    The constructor has the compiler's ``AvoiderFactory`` signature; ``params`` (clipped
    to the platform), ``release_margin`` and ``sensing_range`` can be bound with
    :func:`functools.partial`.
    """

    reads = (OBSTACLES, POSE, SENSOR_FRAME)
    writes = (COMMAND,)

    def __init__(
        self,
        goal: Goal,
        session: AvoidanceSession,
        platform: Platform,
        period: float,
        params: DwaParams | None = None,
        release_margin: float | None = None,
        sensing_range: float = 6.0,
        static_speed: float = 0.1,
        name: str = "dwa avoidance",
    ) -> None:
        super().__init__(name)
        self.goal, self.session, self.period = goal, session, period
        self.platform = platform
        self.params = (params or DwaParams()).within(platform)
        self.every = max(1, round(self.params.window / period))
        """Ticks per DWA period: the command is held in between."""
        self._tick = 0
        self.release_margin = (
            release_margin
            if release_margin is not None
            else float(getattr(session, "margin", DEFAULT_RELEASE_MARGIN))
        )
        """The path corridor of the release check: the session's (the policy's) margin."""
        self.sensing_range = sensing_range
        self.static_speed = static_speed
        self.velocity = (0.0, 0.0)
        self.last: DwaChoice | None = None

    def initialise(self) -> None:
        """Seed the current velocity from the wheel speeds (the last command otherwise)."""
        frame: SensorFrame | None = self.read(SENSOR_FRAME)
        wheels = frame.wheels if frame is not None else None
        if wheels is not None and self.platform.track > 0.0:
            v = 0.5 * (wheels.left + wheels.right)
            w = (wheels.right - wheels.left) / self.platform.track
            self.velocity = self._limit(v, w)
        else:
            self.velocity = (0.0, 0.0)
        self._tick = 0

    def _limit(self, v: float, w: float) -> tuple[float, float]:
        p = self.params
        return min(max(v, p.v_min), p.v_max), min(max(w, -p.omega_max), p.omega_max)

    def _brake(self) -> tuple[float, float]:
        p = self.params
        v0, w0 = self.velocity
        dv, dw = p.max_acceleration * p.window, p.max_angular_acceleration * p.window
        v = math.copysign(max(abs(v0) - dv, 0.0), v0)
        w = math.copysign(max(abs(w0) - dw, 0.0), w0)
        return v, w

    def discs(self, obstacles: Obstacles, pose_a: Pose2) -> list[MovingDisc]:
        """Every track within ``sensing_range`` of the robot as discs in A."""
        out: list[MovingDisc] = []
        for track in obstacles.tracks:
            if track.clearance > self.sensing_range:
                continue
            out += obstacle_discs(obstacle_in_airport(track, pose_a), self.static_speed)
        return out

    def update(self) -> Status:
        obstacles: Obstacles | None = self.read(OBSTACLES)
        pose: PoseEstimate | None = self.read(POSE)
        if obstacles is None or pose is None:
            self.velocity = self._brake()
            self.write(COMMAND, VelocityCommand(*self.velocity))
            self.feedback_message = "no pose or obstacles: braking"
            return Status.RUNNING
        pose_a = pose.pose_a
        target = self.goal.in_airport(pose)
        target_xy = np.array([target.x, target.y])
        if self._tick % self.every == 0 or self.last is None:
            choice = dwa_choose(
                pose_a, self.velocity, target_xy, self.discs(obstacles, pose_a), self.params
            )
            self.last = choice
            self.velocity = self._limit(choice.v, choice.omega)
            self.feedback_message = (
                f"DWA {choice.mode}: v {choice.v:.2f} m/s, omega {choice.omega:.2f} rad/s, "
                f"clearance {choice.clearance:.2f} m, {choice.n_free} free arcs"
            )
        self._tick += 1
        self.write(COMMAND, VelocityCommand(*self.velocity))
        self._check_release(obstacles, pose_a, target_xy)
        return Status.RUNNING

    def _check_release(self, obstacles: Obstacles, pose_a: Pose2, target_xy: FloatArray) -> None:
        session = self.session
        if session.obstacle_id is None or session.released:
            return
        track = next((t for t in obstacles.tracks if t.id == session.obstacle_id), None)
        if track is None:
            return  # the guard releases a lost track itself
        obstacle = obstacle_in_airport(track, pose_a)
        robot = np.array([pose_a.x, pose_a.y])
        if not path_blocked(robot, target_xy, obstacle, self.release_margin):
            session.released, session.reason = True, "DWA: path to the goal clear"
        elif _behind(robot, target_xy, obstacle):
            session.released, session.reason = True, "DWA: obstacle behind the robot"
