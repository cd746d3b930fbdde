"""Obstacle avoidance: the thesis's spiral (seed lines 3808-4240), velocity obstacles for
fast obstacles, and the guard that engages and releases them.

A thin adapter over :mod:`behaviours.laws.spiral` and
:mod:`behaviours.laws.velocity_obstacles`. The guard (:class:`AvoidanceTrigger`) and
the controller (:class:`AvoidObstacle`) of one navigation share an
:class:`AvoidanceSession`: the guard picks the obstacle (r_c < r_OA-trigger *and* on the
way to the goal) and keeps it until the spiral's release condition (beta_c past the
release angle and the path to the goal clear, figure 4.15) or until the track is lost;
the controller steers around it. Obstacles are expressed in the airport frame A with the
pose estimate, so the spiral's centre stays put while the robot turns.

Forbidden-zone walls (``zone`` obstacles) do not engage the spiral: the loader keeps
every leg clear of them and the safety layer's geofence is the hard limit.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import py_trees

from behaviours.base import Controller, Guard
from behaviours.goals import Goal
from behaviours.keys import COMMAND, OBSTACLES, POSE, SENSOR_FRAME
from behaviours.laws.localisation import wheel_odometry
from behaviours.laws.obstacles import vouched_velocity
from behaviours.laws.rate_limit import RateLimiter, RateLimits
from behaviours.laws.retreat import ESCAPE_FACTOR, heading_clearances, slowdown_scale
from behaviours.laws.spiral import (
    SpiralAvoidance,
    SpiralObstacle,
    SpiralOutput,
    SpiralParams,
    path_blocked,
)
from behaviours.laws.velocity_obstacles import (
    HeadingChoice,
    HeadingVoParams,
    MovingDisc,
    choose_heading,
    heading_command,
    time_to_collision,
)
from executive.core.frames import FloatArray, Pose2
from executive.core.model import Platform
from executive.core.records import (
    Danger,
    Obstacles,
    PoseEstimate,
    SensorFrame,
    TrackedObstacle,
    VelocityCommand,
)

Status = py_trees.common.Status


def obstacle_in_airport(track: TrackedObstacle, pose_a: Pose2) -> SpiralObstacle:
    """A tracked obstacle (robot frame) in A, for the spiral and VO laws."""
    c, s = math.cos(pose_a.theta), math.sin(pose_a.theta)
    x, y = pose_a.apply(np.array(track.position))
    vx, vy = track.velocity
    shape: tuple[float, ...] = ()
    if track.kind == "circle" and len(track.shape) == 3:
        cx, cy = pose_a.apply(np.array(track.shape[:2]))
        shape = (float(cx), float(cy), max(track.shape[2], track.size))
    elif track.kind == "line" and len(track.shape) == 4:
        ends = pose_a.apply(np.array(track.shape).reshape(2, 2))
        shape = tuple(float(v) for v in ends.ravel())
    return SpiralObstacle(
        (float(x), float(y)), (c * vx - s * vy, s * vx + c * vy), track.size, shape, track.id
    )


SPIRAL = "spiral"
DODGE = "velocity obstacles"
REPLAN = "fallback planner"


@dataclass
class AvoidanceSession:
    """One avoidance of one obstacle: what the policy and the controllers share."""

    obstacle_id: int | None = None
    mode: str = SPIRAL
    engaged_at: float = 0.0
    missing_since: float | None = None
    clear_since: float | None = None
    released: bool = False
    reason: str = ""
    count: int = 0
    """Engagements so far in this navigation (for the report)."""
    margin: float = 1.4
    """Half-width of the corridor robot -> goal (the policy's; the spiral's release uses
    the same, so engage and release stay exclusive)."""
    best_distance: float = math.inf
    best_at: float = 0.0
    """Closest the robot came to the goal during this avoidance, and when (trap check)."""
    stalled_since: float | None = None
    """Since when velocity obstacles have found no admissible motion (the robot stands;
    set by :class:`DodgeObstacle`, None while it moves)."""


class AvoiderFactory(Protocol):
    """Builds an avoidance controller of one navigation (the compiler's plug-in point).

    :class:`DodgeObstacle` and :class:`AvoidObstacle` are the shipped ones;
    ``benchmarks/dwa.py`` plugs a dynamic-window baseline in for both through
    :attr:`executive.compiler.CompileOptions.avoider`.
    """

    def __call__(
        self, goal: Goal, session: AvoidanceSession, platform: Platform, period: float
    ) -> Controller: ...


@dataclass(frozen=True, slots=True)
class AvoidanceParams:
    """Tuning of :class:`AvoidancePolicy` (SI units)."""

    r_oa: float = 2.5
    """r_OA-trigger: clearance under which an obstacle on the way engages the avoidance."""
    margin: float = 1.4
    """Half-width of the corridor robot -> goal in which an obstacle is "on the way"."""
    fast_speed: float = 0.15
    """An obstacle faster than this is avoided with velocity obstacles (the spiral goes
    round an obstacle; a walker at a third of the spiral's speed, nu_max = 0.4 m/s,
    already walks into it)..."""
    slow_speed: float = 0.08
    """...and with the spiral again once slower than this (hysteresis)."""
    lost_after: float = 1.0
    """An obstacle not tracked for this long releases the avoidance (s)."""
    clear_after: float = 1.0
    """Velocity obstacles end once the obstacle has been harmless for this long (s)."""
    hold_off: float = 3.0
    """A released obstacle does not engage again for this long (s), unless it comes
    closer than r_OA / 2: no re-trigger loop on a noisy boundary."""
    speed_time_constant: float = 0.5
    """Low-pass filter of each track's observable speed (s)."""
    large_size: float = 1.5
    """Obstacles larger than this (enclosing radius, m: vehicles, structures; a trolley
    seen as one blob measures about 1.1 m)..."""
    large_speed_allowance: float = 0.4
    """...have this much of their speed discounted (m/s): as the robot moves round a big
    static obstacle its visible part, hence its tracked centroid, slides by up to
    ~0.3 m/s; a vehicle that really moves is faster than that."""
    anticipation: float = 2.0
    """An obstacle moving onto the path engages this many seconds of its motion before
    r_OA-trigger (s): a trolley at 0.7 m/s is met 1.4 m earlier."""
    cruise: float = 0.6
    """The navigation's speed (m/s), for the collision-course check (the compiler sets the
    mission's cruise speed)."""
    horizon: float = 4.0
    """A mover whose motion meets the robot's within this time (s) is on a collision
    course: the robot driving to the goal at ``cruise``, or standing still..."""
    mover_margin: float = 0.4
    """...closer than the corridor half-width ``margin`` plus this plus the mover's size
    (m; :class:`DodgeObstacle` keeps the same distance)."""
    too_close: float = 0.9
    """A spiral that lets any obstacle come closer than this (m, footprint clearance; the
    compiler sets r_ES + 0.3) hands over to velocity obstacles, which keep the distance;
    the spiral takes over again only beyond this plus ``too_close_hysteresis``."""
    too_close_hysteresis: float = 0.5
    closer_by: float = 0.3
    """The spiral moves to another obstacle on the way once that one is this much closer
    than its own (m): the SCP is recomputed when the situation changes."""
    trapped_after: float = 20.0
    """An avoidance that brings the robot no ``progress`` closer to the goal for this long,
    with no obstacle around faster than ``fast_speed``, is trapped: the fallback planner
    takes over (s; inf: never). Avoidances that follow one another within ``hold_off``
    share this clock, so a loop of engagements and releases ends in the planner too; the
    one that follows the planner gets a clock of its own (a planner that found no path
    must not be asked again at once)."""
    progress: float = 0.5
    """Distance gain towards the goal that counts as progress (m)."""
    stalled_after: float = 3.0
    """Velocity obstacles that find no admissible motion for this long, with no obstacle
    around faster than ``fast_speed``, leave the robot trapped at once (s): obstacles
    that stand do not step aside, and waiting out ``trapped_after`` beside them only
    wastes the time (campaign episodes 652, 889 and 890 stood still for 20 s each)."""


class AvoidancePolicy:
    """Which obstacle to avoid and how; shared by the guards of one navigation.

    Engage (when no avoidance runs): the tracked obstacle (not a ``zone`` wall) with the
    smallest clearance among those under r_OA-trigger that are on the way to the goal —
    the straight corridor robot -> goal (the thesis's distance-to-target check, figure
    4.15) — or that move onto the robot's path (track danger ``ON_PATH`` or worse and
    faster than ``slow_speed``: a trolley coming from the side), or that are on a
    collision course with it (:meth:`_collision_course`). Mode: velocity obstacles when
    the obstacle moves faster than ``fast_speed`` or is on a collision course, else the
    spiral; a spiral also hands over to velocity obstacles when any obstacle comes
    within ``too_close``.

    While engaged: the spiral ends when its release condition holds (set by the
    controller in the session) or the track is lost; velocity obstacles end once the
    obstacle has stayed off the path (danger below ``ON_PATH`` and not in the corridor)
    for ``clear_after``. A spiral switches to velocity obstacles when its obstacle speeds
    up, or when another, faster obstacle moves onto the path; velocity obstacles switch
    back to the spiral when the obstacle slows down while still in the way.

    Trapped: an avoidance that brings the robot no closer to the goal for
    ``trapped_after``, or velocity obstacles that find no motion for ``stalled_after``,
    with nothing around faster than ``fast_speed``, hand over to the fallback planner,
    which plans round the obstacles and where the slower movers will be; only a mover
    faster than ``fast_speed`` on a collision course takes the robot from it (velocity
    obstacles, with a trap clock of their own).

    :meth:`decide` is evaluated once per obstacle estimate (the guards of one tick share
    it); every change leaves its reason in :attr:`message`.
    """

    def __init__(self, goal: Goal, params: AvoidanceParams) -> None:
        self.goal, self.params = goal, params
        self.session = AvoidanceSession(margin=params.margin)
        self._released: dict[int, float] = {}
        self._speeds: dict[int, float] = {}
        self._slowed: set[int] = set()
        """Tracks a dodge handed back to the spiral because they slowed down: they are
        dodged again only once faster than ``fast_speed`` (:meth:`_coming`)."""
        self.message = ""
        self._stamp: float | None = None
        self._mode: str | None = None
        self._ended_at: float | None = None

    def decide(self, obstacles: Obstacles, pose: PoseEstimate) -> str | None:
        """The avoidance mode for this tick (SPIRAL or DODGE), None when none is needed."""
        if self._stamp != obstacles.stamp:
            dt = obstacles.stamp - self._stamp if self._stamp is not None else 0.0
            self._stamp = obstacles.stamp
            self._mode = self._decide(obstacles, pose, dt)
        return self._mode

    def _smoothed_speeds(
        self, candidates: dict[int, tuple[TrackedObstacle, SpiralObstacle]], dt: float
    ) -> None:
        """Low-pass the speed of each track as far as the lasers vouch for it
        (:func:`~behaviours.laws.obstacles.vouched_velocity`; a noisy estimate must not
        flip the mode every tick)."""
        p = self.params
        gain = min(1.0, max(dt, 0.0) / p.speed_time_constant)
        speeds = {}
        for ident, (track, _) in candidates.items():
            measured = math.hypot(*vouched_velocity(track))
            if track.size > p.large_size:  # partial views slide a big centroid
                measured = max(0.0, measured - p.large_speed_allowance)
            previous = self._speeds.get(ident)
            speeds[ident] = (
                measured if previous is None else previous + gain * (measured - previous)
            )
        self._speeds = speeds
        self._slowed = {i for i in self._slowed if speeds.get(i, math.inf) <= p.fast_speed}

    def _decide(self, obstacles: Obstacles, pose: PoseEstimate, dt: float) -> str | None:
        p, session, now = self.params, self.session, obstacles.stamp
        robot = np.array([pose.pose_a.x, pose.pose_a.y])
        target = self.goal.in_airport(pose)
        target_xy = np.array([target.x, target.y])
        candidates = {
            t.id: (t, obstacle_in_airport(t, pose.pose_a))
            for t in obstacles.tracks
            if t.kind != "zone"
        }
        self._smoothed_speeds(candidates, dt)
        speed = self._speeds
        if session.obstacle_id is not None:
            if session.released:
                planned = session.mode == REPLAN
                self._end(now, session.reason)
                if planned:  # what follows the planner gets a trap clock of its own
                    self._ended_at = None
                return None
            if session.mode == REPLAN:  # the planner ends it (session.released)...
                # ...unless a mover faster than fast_speed comes: the planner plans round
                # where slower ones will be, not where fast ones will
                coming = self._mover_coming(candidates, robot, target_xy, p.fast_speed)
                if coming is not None:
                    session.best_at = now  # the dodge gets its own trapped_after
                    return self._switch(
                        DODGE,
                        coming,
                        f"obstacle {coming.id} moves at {speed[coming.id]:.2f} m/s on a "
                        "collision course while the planner drives",
                    )
                return REPLAN
            current = candidates.get(session.obstacle_id)
            if current is None:
                session.missing_since = session.missing_since or now
                if now - session.missing_since > p.lost_after:
                    return self._end(now, "obstacle no longer tracked")
                return session.mode
            session.missing_since = None
            track, obstacle = current
            blocked = path_blocked(robot, target_xy, obstacle, p.margin)
            distance = float(np.hypot(*(target_xy - robot)))
            if distance < session.best_distance - p.progress:
                session.best_distance, session.best_at = distance, now
            # trapped among obstacles that stand or move slower than fast_speed (fleeing a
            # faster mover is no lack of progress); the planner plans round where the
            # slow ones will be
            stalled = (
                session.mode == DODGE
                and session.stalled_since is not None
                and now - session.stalled_since >= p.stalled_after
            )
            no_progress = now - session.best_at > p.trapped_after
            if (no_progress or stalled) and all(speed[i] <= p.fast_speed for i in candidates):
                why = (
                    f"no progress towards the goal for {p.trapped_after:.0f} s"
                    if no_progress
                    else "velocity obstacles found no way among obstacles that stand for "
                    f"{p.stalled_after:.0f} s"
                )
                return self._switch(REPLAN, track, f"trapped: {why}")
            if session.mode == SPIRAL:
                if speed[track.id] > p.fast_speed:
                    return self._switch(DODGE, track, f"it moves at {speed[track.id]:.2f} m/s")
                if self._coming(track, obstacle, robot, target_xy):
                    return self._switch(
                        DODGE,
                        track,
                        f"it moves at {speed[track.id]:.2f} m/s on a collision course",
                    )
                threat = self._threat(candidates, robot, target_xy, now, p.fast_speed)
                if threat is not None and threat[0].id != track.id:
                    other = threat[0]
                    return self._switch(
                        DODGE, other, f"obstacle {other.id} closing in at {speed[other.id]:.2f} m/s"
                    )
                near = min(
                    (t for t, _ in candidates.values()), key=lambda t: t.clearance, default=None
                )
                if near is not None and near.clearance < p.too_close:
                    return self._switch(
                        DODGE,
                        near,
                        f"obstacle {near.id} at {near.clearance:.2f} m < {p.too_close:.2f} m",
                    )
                closer = self._threat(candidates, robot, target_xy, now, None)
                if (
                    closer is not None
                    and closer[0].id != track.id
                    and closer[0].clearance < track.clearance - p.closer_by
                ):
                    other = closer[0]
                    return self._switch(
                        SPIRAL,
                        other,
                        f"obstacle {other.id} on the way at {other.clearance:.2f} m, closer "
                        f"than obstacle {track.id} at {track.clearance:.2f} m",
                    )
                return SPIRAL
            roomy = track.clearance > p.too_close + p.too_close_hysteresis
            if speed[track.id] < p.slow_speed and blocked and roomy:
                self._slowed.add(track.id)
                return self._switch(SPIRAL, track, f"it slowed to {speed[track.id]:.2f} m/s")
            harmless = (
                track.danger < Danger.ON_PATH
                and not blocked
                and not self._collision_course(obstacle, speed[track.id], robot, target_xy)
            )
            if not harmless:
                session.clear_since = None
                return DODGE
            session.clear_since = session.clear_since or now
            if now - session.clear_since >= p.clear_after:
                return self._end(now, "obstacle off the path")
            return DODGE
        # at the goal nothing lies "on the way" any more; only an obstacle moving in counts
        at_goal = float(np.hypot(*(target_xy - robot))) < p.margin
        threat = self._threat(candidates, robot, target_xy, now, None, moving_only=at_goal)
        if threat is None:
            self.message = (
                "at the goal" if at_goal else f"way clear (r_c {obstacles.closest_any:.2f} m)"
            )
            return None
        track, obstacle = threat
        # a mover is dodged: fast, or on a collision course (the spiral would let it in)
        coming = self._coming(track, obstacle, robot, target_xy)
        mode = DODGE if speed[track.id] > p.fast_speed or coming else SPIRAL
        session.obstacle_id, session.mode, session.engaged_at = track.id, mode, now
        session.released, session.reason = False, ""
        session.missing_since = session.clear_since = session.stalled_since = None
        if self._ended_at is None or now - self._ended_at > p.hold_off:
            # a fresh avoidance; one that follows another at once keeps its trap clock
            session.best_distance, session.best_at = float(np.hypot(*(target_xy - robot))), now
        session.count += 1
        self.message = (
            f"obstacle {track.id} ({track.kind}, {speed[track.id]:.2f} m/s) "
            f"{track.clearance:.2f} m < r_OA {p.r_oa:.2f} m on the way"
        )
        return mode

    def _threat(
        self,
        candidates: dict[int, tuple[TrackedObstacle, SpiralObstacle]],
        robot: np.ndarray,
        target_xy: np.ndarray,
        now: float,
        faster_than: float | None,
        moving_only: bool = False,
    ) -> tuple[TrackedObstacle, SpiralObstacle] | None:
        """The closest obstacle under r_OA on the way or moving onto the path (one just
        released is ignored for ``hold_off`` s unless it comes closer than r_OA / 2)."""
        p = self.params
        best: tuple[TrackedObstacle, SpiralObstacle] | None = None
        for track, obstacle in candidates.values():
            speed = self._speeds[track.id]
            moving_in = speed > p.slow_speed and (
                track.danger >= Danger.ON_PATH
                or self._collision_course(obstacle, speed, robot, target_xy)
            )
            # an obstacle moving in is met earlier: r_OA plus anticipation x its speed
            reach = p.r_oa + (p.anticipation * speed if moving_in else 0.0)
            if track.clearance >= reach:
                continue
            if faster_than is not None and speed <= faster_than:
                continue
            released = self._released.get(track.id)
            held_off = released is not None and now - released < p.hold_off
            if held_off and track.clearance >= 0.5 * p.r_oa:
                continue
            if moving_only and not moving_in:
                continue
            if not (moving_in or path_blocked(robot, target_xy, obstacle, p.margin)):
                continue
            if best is None or track.clearance < best[0].clearance:
                best = (track, obstacle)
        return best

    def _mover_coming(
        self,
        candidates: dict[int, tuple[TrackedObstacle, SpiralObstacle]],
        robot: np.ndarray,
        target_xy: np.ndarray,
        faster_than: float = 0.0,
    ) -> TrackedObstacle | None:
        """The closest obstacle under r_OA (plus its anticipation), faster than
        ``faster_than``, whose motion meets the robot's (:meth:`_collision_course`), if
        any."""
        p, best = self.params, None
        for track, obstacle in candidates.values():
            speed = self._speeds[track.id]
            if track.clearance >= p.r_oa + p.anticipation * speed or speed <= faster_than:
                continue
            if not self._coming(track, obstacle, robot, target_xy):
                continue
            if best is None or track.clearance < best.clearance:
                best = track
        return best

    def _coming(
        self,
        track: TrackedObstacle,
        obstacle: SpiralObstacle,
        robot: np.ndarray,
        target_xy: np.ndarray,
    ) -> bool:
        """Whether ``track`` calls for a dodge for its collision course: as
        :meth:`_collision_course`, except that a track handed back to the spiral for
        slowing down must first be faster than ``fast_speed`` again (hysteresis: the
        noisy speed of a standing walker or trolley hovers about ``slow_speed``, and one
        threshold for both switches made them alternate every second)."""
        speed = self._speeds[track.id]
        if track.id in self._slowed and speed <= self.params.fast_speed:
            return False
        return self._collision_course(obstacle, speed, robot, target_xy)

    def _collision_course(
        self, obstacle: SpiralObstacle, speed: float, robot: np.ndarray, target_xy: np.ndarray
    ) -> bool:
        """Whether the obstacle (low-passed ``speed``), at its tracked velocity, comes
        within the robot's safety distance in ``horizon`` seconds, the robot standing
        still or, unless the obstacle walks away from it, driving to the goal at
        ``cruise`` (a velocity-obstacle test of both motions)."""
        p = self.params
        if speed <= p.slow_speed:
            return False
        disc = MovingDisc(obstacle.position, obstacle.velocity, obstacle.size + p.mover_margin)
        to_goal = target_xy - robot
        distance = float(np.hypot(*to_goal))
        drive = to_goal / distance * min(p.cruise, distance) if distance > 1e-6 else to_goal
        # one walking away from the robot is only caught up with: the spiral's case
        receding = float(np.dot(obstacle.velocity, robot - np.array(obstacle.position))) < 0.0
        motions = (np.zeros(2),) if receding else (drive, np.zeros(2))
        return any(
            time_to_collision(robot, velocity, disc, p.margin) < p.horizon for velocity in motions
        )

    def _switch(self, mode: str, track: TrackedObstacle, why: str) -> str:
        session = self.session
        session.obstacle_id, session.mode, session.clear_since = track.id, mode, None
        session.stalled_since = None
        self.message = f"obstacle {track.id}: {mode} ({why})"
        return mode

    def _end(self, now: float, reason: str) -> None:
        session = self.session
        if session.obstacle_id is not None:
            self._released[session.obstacle_id] = now
        self._ended_at = now
        session.obstacle_id, session.released = None, False
        session.missing_since = session.clear_since = None
        self.message = f"released: {reason}"
        return None


class AvoidanceTrigger(Guard):
    """Holds while the navigation's :class:`AvoidancePolicy` asks for ``mode``.

    r_c < r_OA-trigger for an obstacle on the way (or moving onto the path) engages; the
    spiral's release condition, a harmless obstacle (velocity obstacles) or a lost track
    ends it. The guard's feedback is the policy's reason, so every switch shows in the
    controller events.
    """

    reads = (OBSTACLES, POSE)

    def __init__(self, policy: AvoidancePolicy, mode: str, name: str = "") -> None:
        super().__init__(name or f"{mode}?")
        self.policy, self.mode = policy, mode

    def update(self) -> Status:
        obstacles: Obstacles | None = self.read(OBSTACLES)
        pose: PoseEstimate | None = self.read(POSE)
        if obstacles is None or pose is None:
            self.feedback_message = "no obstacle estimate or pose"
            return Status.FAILURE
        mode = self.policy.decide(obstacles, pose)
        self.feedback_message = self.policy.message
        return Status.SUCCESS if mode == self.mode else Status.FAILURE


class AvoidanceController(Controller):
    """What the avoidance controllers share: the navigation's goal and session, and a
    command rate limited to the platform (the thesis's future-work item: no oscillating
    velocities).

    The limiter starts from the motion the robot has when the controller takes over (the
    wheels' speeds, eq. 2.1-2.2, and the IMU's yaw rate), not from rest: a robot dodging
    a chaser at 1.2 m/s that was told 0.02 m/s on its first avoidance tick was braked by
    the drive base into the chaser's way (A320 busy-apron campaign episode 66). Without
    wheel speeds it starts from rest.
    """

    reads = (OBSTACLES, POSE, SENSOR_FRAME)
    writes = (COMMAND,)

    def __init__(
        self, goal: Goal, session: AvoidanceSession, platform: Platform, period: float, name: str
    ) -> None:
        super().__init__(name)
        self.goal, self.session, self.period = goal, session, period
        self.track = platform.odometry_track
        self.limiter = RateLimiter(
            RateLimits(
                max_acceleration=platform.max_acceleration,
                max_angular_acceleration=platform.max_angular_acceleration,
                max_speed=platform.max_speed,
                max_angular_speed=platform.max_angular_speed,
            )
        )

    def initialise(self) -> None:
        self.limiter.reset(*self.measured_motion())

    def measured_motion(self) -> tuple[float, float]:
        """(v, omega) the robot moves at: the wheels' (eq. 2.1-2.2), the IMU's yaw rate
        when it is read, within the platform's limits; (0, 0) without wheel speeds."""
        frame: SensorFrame | None = self.read(SENSOR_FRAME)
        if frame is None or frame.wheels is None:
            return 0.0, 0.0
        v, omega = wheel_odometry(frame.wheels, self.track)
        if frame.imu is not None:
            omega = frame.imu.yaw_rate
        if not (math.isfinite(v) and math.isfinite(omega)):
            return 0.0, 0.0
        limits = self.limiter.limits
        top, turn = limits.max_speed or math.inf, limits.max_angular_speed or math.inf
        return min(top, max(-top, v)), min(turn, max(-turn, omega))

    def drive(self, v: float, omega: float, why: str) -> Status:
        """Send (v, omega) through the rate limiter."""
        v, omega = self.limiter.step(v, omega, self.period)
        self.write(COMMAND, VelocityCommand(v, omega))
        self.feedback_message = why
        return Status.RUNNING

    def brake(self, why: str) -> Status:
        return self.drive(0.0, 0.0, why)


def _session_track(
    obstacles: Obstacles | None, session: AvoidanceSession
) -> TrackedObstacle | None:
    if obstacles is None or session.obstacle_id is None:
        return None
    return next((t for t in obstacles.tracks if t.id == session.obstacle_id), None)


class AvoidObstacle(AvoidanceController):
    """Spiral obstacle avoidance around the session's obstacle (eqs. 4.1-4.16), rate
    limited.

    :attr:`last` keeps the law's last :class:`SpiralOutput` (alpha_d, xi, beta_c, e_alpha,
    e_r, ...) for the report.
    """

    def __init__(
        self,
        goal: Goal,
        session: AvoidanceSession,
        platform: Platform,
        period: float,
        params: SpiralParams | None = None,
        name: str = "spiral avoidance",
    ) -> None:
        super().__init__(goal, session, platform, period, name)
        self.params = params or SpiralParams()
        self.law = SpiralAvoidance(self.params)
        self.last: SpiralOutput | None = None
        self._obstacle_id: int | None = None

    def initialise(self) -> None:
        super().initialise()
        # the release check uses the policy's corridor: engage and release stay exclusive;
        # the spiral never asks to come closer than that corridor's half-width (half the
        # robot's width + r_ES + a margin): an e-stop beside a static obstacle never ends
        margin = self.session.margin
        self.law = SpiralAvoidance(
            dataclasses.replace(
                self.params,
                path_margin=margin,
                min_clearance=max(self.params.min_clearance, margin),
            )
        )
        self.last = None
        self._obstacle_id = None

    def update(self) -> Status:
        obstacles: Obstacles | None = self.read(OBSTACLES)
        pose: PoseEstimate | None = self.read(POSE)
        track = _session_track(obstacles, self.session)
        if pose is None or track is None:
            return self.brake("obstacle not in view: braking")
        if track.id != self._obstacle_id:  # the policy moved the spiral: anchor it anew
            self.law.reset()
            self._obstacle_id = track.id
        obstacle = obstacle_in_airport(track, pose.pose_a)
        target = self.goal.in_airport(pose)
        out = self.law.command(pose.pose_a, np.array([target.x, target.y]), obstacle, self.period)
        if out.released:
            self.session.released, self.session.reason = True, out.reason
        self.last = out
        return self.drive(
            out.v,
            out.omega,
            f"spiral: alpha_d {math.degrees(out.alpha_d):.0f} deg, beta_c "
            f"{math.degrees(out.beta_c):.0f} deg, e_r {out.e_r:.2f} m",
        )


def obstacle_discs(obstacle: SpiralObstacle, spacing: float = 0.5) -> list[MovingDisc]:
    """An obstacle as discs for the velocity-obstacle law: a line (a wall, a fuselage
    side) as a row of discs along its segment, anything else as one enclosing disc."""
    if obstacle.is_line:
        x0, y0, x1, y1 = obstacle.shape
        n = max(2, math.ceil(math.hypot(x1 - x0, y1 - y0) / spacing) + 1)
        radius = 0.5 * spacing
        return [
            MovingDisc((float(x), float(y)), obstacle.velocity, radius)
            for x, y in zip(np.linspace(x0, x1, n), np.linspace(y0, y1, n), strict=True)
        ]
    return [MovingDisc(obstacle.position, obstacle.velocity, obstacle.size)]


class DodgeObstacle(AvoidanceController):
    """Velocity obstacles (Fiorini and Shiller) against every obstacle tracked within
    ``reach``, for obstacles that move (seed line 1516).

    The law is :func:`behaviours.laws.velocity_obstacles.choose_heading`: the robot, a
    differential drive, turns on the spot and then drives, so every candidate velocity is
    checked with the time it takes to turn to it; reversing is allowed (both lasers
    watch). The preferred velocity heads for the goal; the chosen one is the closest to it
    whose motion meets no obstacle within the horizon. Its top speed is ``escape_factor``
    x the fastest obstacle's speed (at least ``nu_min``, at most the platform's): a robot
    no faster than a trolley chasing it cannot get away. The compiler sets ``nu_min`` to
    the navigation's cruise speed: a robot that slows down to dodge a slow walker crossing
    its way stays in that walker's way for longer. Forbidden-zone walls count as
    static discs: the virtual wall points near the robot, one every ``zone_spacing``
    metres.

    Sizes: the robot is a disc (:attr:`radius`): the circle its footprint sweeps turning
    on the spot plus the session's corridor margin beyond half its width (r_ES and a
    margin) less ``static_inset``, so that no corner comes within r_ES of a static
    obstacle (the e-stop would hold the robot there for good); an obstacle that moves gets
    up to ``mover_margin`` more (in proportion to its speed, full at ``mover_speed``), so
    that a walker never comes within r_ES: the e-stop would hold the robot still in its
    way.

    Slowdown: with ``slowdown`` = (r_ES, r_OA-trigger), every candidate is judged at the
    speed the safety layer's slowdown zone will leave it along its heading
    (:func:`behaviours.laws.retreat.slowdown_scale` of the corridor it drives into): an
    escape towards a parked vehicle is slower than commanded (campaign episode 527).

    Reversing: as fast as driving forwards (both lasers watch), unless ``reverse_max``
    caps it; the safety layer's retreat backs away from a chaser at up to the same
    :data:`~behaviours.laws.retreat.ESCAPE_FACTOR` x its speed. Capped at 1 m/s, a robot
    reversing from a 1.2 m/s trolley was caught (A320 campaign episode 65). A way out
    that drives the other way than the robot rolls (its wheels' speed,
    :meth:`measured_motion`) starts once the robot has braked to rest at the platform's
    acceleration.

    Velocity memory: a track slower than it was within the last ``velocity_memory``
    seconds keeps that speed (in the direction it moves now, or the old velocity if it
    seems to stand). When a chaser passes a static obstacle the two merge into one
    cluster and the track's velocity collapses for a second or two; believing it, the
    robot stopped fleeing and turned for the goal (campaign episode 199).
    """

    def __init__(
        self,
        goal: Goal,
        session: AvoidanceSession,
        platform: Platform,
        period: float,
        nu_min: float = 0.4,
        escape_factor: float = ESCAPE_FACTOR,
        reach: float = 8.0,
        zone_spacing: float = 0.4,
        reverse_max: float | None = None,
        static_inset: float = 0.2,
        mover_margin: float = 0.4,
        mover_speed: float = 0.3,
        velocity_memory: float = 1.5,
        slowdown: tuple[float, float] | None = None,
        name: str = "velocity obstacles",
    ) -> None:
        super().__init__(goal, session, platform, period, name)
        self.velocity_memory = velocity_memory
        self.slowdown = slowdown
        self._fastest: dict[int | None, tuple[float, tuple[float, float]]] = {}
        self.platform, self.nu_min = platform, nu_min
        self.escape_factor, self.reach = escape_factor, reach
        self.zone_spacing, self.reverse_max = zone_spacing, reverse_max
        self.static_inset, self.mover_margin, self.mover_speed = (
            static_inset,
            mover_margin,
            mover_speed,
        )
        self.last: HeadingChoice | None = None

    @property
    def radius(self) -> float:
        """The robot's disc: the circle its footprint sweeps turning on the spot, widened
        as the corridor (r_ES and its margin) less ``static_inset``."""
        lateral = self.session.margin - 0.5 * self.platform.width
        return self.platform.turning_radius + lateral - self.static_inset

    def initialise(self) -> None:
        super().initialise()
        self.last = None
        self._fastest.clear()

    def _remembered(self, obstacle: SpiralObstacle, now: float) -> SpiralObstacle:
        """``obstacle`` with its velocity memory applied (class docstring)."""
        record = self._fastest.get(obstacle.ident)
        speed = obstacle.speed
        if record is None or now - record[0] > self.velocity_memory:
            self._fastest[obstacle.ident] = (now, obstacle.velocity)
            return obstacle
        remembered = math.hypot(*record[1])
        if speed >= remembered:
            self._fastest[obstacle.ident] = (now, obstacle.velocity)
            return obstacle
        if speed > 0.05:
            k = remembered / speed
            velocity = (obstacle.velocity[0] * k, obstacle.velocity[1] * k)
        else:
            velocity = record[1]
        return dataclasses.replace(obstacle, velocity=velocity)

    def update(self) -> Status:
        obstacles: Obstacles | None = self.read(OBSTACLES)
        pose: PoseEstimate | None = self.read(POSE)
        if pose is None or obstacles is None:
            return self.brake("no pose or obstacles: braking")
        robot = pose.pose_a
        near = [
            self._remembered(obstacle_in_airport(t, robot), obstacles.stamp)
            for t in obstacles.tracks
            if t.clearance < self.reach and t.kind != "zone"
        ]
        horizon = obstacles.stamp - self.velocity_memory  # forget what has expired
        self._fastest = {k: r for k, r in self._fastest.items() if r[0] >= horizon}
        fastest = max((o.speed for o in near), default=0.0)
        v_max = min(self.platform.max_speed, max(self.nu_min, self.escape_factor * fastest))
        params = HeadingVoParams(
            v_max=v_max,
            reverse_max=v_max if self.reverse_max is None else min(v_max, self.reverse_max),
            omega_max=self.platform.max_angular_speed,
            deceleration=self.platform.max_acceleration,
        )
        target = self.goal.in_airport(pose)
        to_goal = np.array([target.x - robot.x, target.y - robot.y])
        distance = float(np.hypot(*to_goal))
        speed = min(v_max, distance / 1.5)
        preferred = to_goal / distance * speed if distance > 1e-6 else np.zeros(2)
        discs = tuple(self._inflated(d) for o in near for d in obstacle_discs(o))
        discs += self._zone_discs(obstacles, robot)
        previous = self.last.velocity if self.last is not None else None
        choice = choose_heading(
            np.array([robot.x, robot.y]),
            robot.theta,
            preferred,
            discs,
            params,
            self.radius,
            previous,
            self._speed_scale(obstacles, robot.theta),
            self.measured_motion()[0],
        )
        self.last = choice
        if choice.speed > 1e-6:
            self.session.stalled_since = None
        elif self.session.stalled_since is None:
            self.session.stalled_since = obstacles.stamp
        v, omega = heading_command(robot.theta, choice, params.omega_max)
        return self.drive(
            v,
            omega,
            f"VO: {len(near)} obstacles, fastest {fastest:.2f} m/s, heading "
            f"{math.degrees(choice.heading):.0f} deg at {choice.speed:.2f} m/s"
            f"{' reversing' if choice.reverse else ''}, "
            f"{'clear' if choice.feasible else f'contact in {choice.time_to_collision:.1f} s'}",
        )

    def _speed_scale(
        self, obstacles: Obstacles, theta: float
    ) -> Callable[[FloatArray], FloatArray] | None:
        """The safety layer's slowdown factor along travel headings in A (class
        docstring), or None without ``slowdown`` or without a return near enough to slow
        anything."""
        if self.slowdown is None or not obstacles.closest < self.slowdown[1]:
            return None
        r_es, r_oa = self.slowdown
        points, length, width = obstacles.points, self.platform.length, self.platform.width

        def scale(headings: FloatArray) -> FloatArray:
            clear = heading_clearances(points, headings - theta, length, width, r_es)
            return slowdown_scale(clear, r_es, r_oa)

        return scale

    def _inflated(self, disc: MovingDisc) -> MovingDisc:
        """``disc`` grown by the mover margin for its speed."""
        speed = math.hypot(*disc.velocity)
        extra = self.mover_margin * min(1.0, speed / self.mover_speed)
        return MovingDisc(disc.position, disc.velocity, disc.radius + extra)

    def _zone_discs(self, obstacles: Obstacles, robot: Pose2) -> tuple[MovingDisc, ...]:
        virtual = obstacles.virtual
        if len(virtual) == 0:
            return ()
        near = virtual[np.hypot(virtual[:, 0], virtual[:, 1]) < self.reach]
        if len(near) == 0:
            return ()
        # thin to about one point per zone_spacing along the walls
        keep = [0]
        for k in range(1, len(near)):
            if float(np.hypot(*(near[k] - near[keep[-1]]))) >= self.zone_spacing:
                keep.append(k)
        points = robot.apply(near[keep])
        radius = 0.5 * self.zone_spacing
        return tuple(MovingDisc((float(x), float(y)), (0.0, 0.0), radius) for x, y in points)
