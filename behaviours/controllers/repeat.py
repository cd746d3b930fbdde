"""Repeating a taught route under a hangar ceiling (issue 17, seed 002 §2.3 and §3).

Thin behaviours over :mod:`behaviours.laws.routes`: the robot follows the straight line
through each key image's pose in turn with the VNHV law (eq. 12), at the route's
longitudinal speed V (forwards or backwards), passing to the next key image when it
crosses the key's normal, the two lines' commands blended so that omega does not jump.

One :class:`RouteSession` per taught route holds the law's state (which key image is the
target), shared by the controller (:class:`FollowTaughtRoute`), its trap guard
(:class:`RouteProgressing`) and the avoidance branches, whose goal is the current key
image (:class:`RouteGoal`): after an avoidance the route resumes at the key the robot is
heading for, the keys it passed meanwhile skipped by the law.

The pose read is the executive's estimate in A (odometry + GPS, or ceiling fixes where
the pose filter fuses them); the mosaic frame M is the airport frame A
(:mod:`executive.core.mosaicfile`), so the key poses are used as they are.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import py_trees

from behaviours.base import Controller, Guard
from behaviours.goals import Goal
from behaviours.keys import COMMAND, POSE
from behaviours.laws.routes import RepeatStep, RouteFollower, gains_for_settling_distance
from executive.core.frames import Pose2
from executive.core.model import Platform, TaughtRoute
from executive.core.records import PoseEstimate, VelocityCommand

Status = py_trees.common.Status

__all__ = [
    "FollowTaughtRoute",
    "RouteEvent",
    "RouteGoal",
    "RouteProgressing",
    "RouteSession",
]


@dataclass(frozen=True, slots=True)
class RouteEvent:
    """A key image passed (``kind`` ``key-passed``) or the route's end (``route-done``)
    at ``stamp``, with the lateral error (m, left positive) to the key's line there."""

    stamp: float
    kind: str
    route: str
    key: str
    index: int
    lateral_error: float

    def detail(self) -> dict[str, object]:
        return {
            "route": self.route,
            "key": self.key,
            "index": self.index,
            "lateral_error_m": round(self.lateral_error, 4),
        }


class RouteSession:
    """The state of one taught route's repetition (module docstring)."""

    def __init__(self, route: TaughtRoute, platform: Platform) -> None:
        self.route = route
        self.follower = RouteFollower(
            [k.pose_m for k in route.keys],
            route.speed,
            gains_for_settling_distance(route.settling_distance),
            omega_max=platform.max_angular_speed,
            deceleration=platform.max_acceleration,
        )
        self.events: list[RouteEvent] = []
        self.last: RepeatStep | None = None
        self.lateral: list[tuple[float, float]] = []
        """(stamp, y) against the line followed, every step: the repeat's own record."""

    def target_pose(self) -> Pose2:
        """The key pose the robot is heading for (the last once the route is done)."""
        return self.route.keys[min(self.follower.target, len(self.route.keys) - 1)].pose_m

    def remaining(self, pose_m: Pose2) -> float:
        """Metres still to go along the key poses (to the target key, then key to key)."""
        return self.follower.remaining(pose_m)

    def step(self, stamp: float, pose_m: Pose2, speed_cap: float | None) -> RepeatStep:
        """One command of the law; records the keys passed as events."""
        step = self.follower.step(pose_m, speed_cap)
        self.last = step
        if step.passed >= 0:
            key = self.route.keys[step.passed]
            kind = "route-done" if step.done else "key-passed"
            self.events.append(
                RouteEvent(stamp, kind, self.route.id, key.id, step.passed, step.passed_error)
            )
        if not step.done:
            self.lateral.append((stamp, step.state.y))
        return step

    def drain_events(self) -> list[RouteEvent]:
        out, self.events = self.events, []
        return out


@dataclass(frozen=True, slots=True)
class RouteGoal(Goal):
    """The current target key image as a navigation goal (for the avoidance branches,
    which steer round an obstacle towards it); ``pose`` is the route's end."""

    session: RouteSession | None = field(default=None, compare=False)

    def in_airport(self, estimate: PoseEstimate | None) -> Pose2:
        return self.pose if self.session is None else self.session.target_pose()


class FollowTaughtRoute(Controller):
    """Repeat a taught route (seed 002 §3): eq. 12 towards the current key image's line,
    V the route's (lowered to the mission's speed limit at the pose, to the platform's
    omega limit and to stop at the last key). RUNNING on the way, SUCCESS at the last key
    image. ``speed_limit`` gives the speed allowed at a pose in A."""

    reads = (POSE,)
    writes = (COMMAND,)

    def __init__(
        self,
        session: RouteSession,
        speed_limit: Callable[[Pose2], float] | None = None,
        name: str = "follow taught route",
    ) -> None:
        super().__init__(name)
        self.session = session
        self.speed_limit = speed_limit

    def bt_ports(self) -> dict[str, object]:
        """The parameters worth showing in a BehaviorTree.CPP export."""
        route = self.session.route
        return {
            "route": route.id,
            "keys": len(route.keys),
            "speed": route.speed,
            "settling_distance": route.settling_distance,
        }

    def update(self) -> Status:
        pose: PoseEstimate | None = self.read(POSE)
        if pose is None:
            self.write(COMMAND, VelocityCommand.stop())
            self.feedback_message = "no pose estimate"
            return Status.RUNNING
        cap = self.speed_limit(pose.pose_a) if self.speed_limit is not None else None
        step = self.session.step(pose.stamp, pose.pose_a, cap)
        keys = self.session.route.keys
        if step.done:
            self.write(COMMAND, VelocityCommand.stop())
            self.feedback_message = f"route '{self.session.route.id}' done"
            return Status.SUCCESS
        self.write(COMMAND, VelocityCommand(step.v, step.omega))
        state = step.state
        self.feedback_message = (
            f"to key {keys[step.target].id} ({step.target}/{len(keys) - 1}): "
            f"y {state.y * 100:+.1f} cm, theta {math.degrees(state.theta):+.1f} deg"
            + ("" if step.in_domain else " (turning back towards the line)")
        )
        return Status.RUNNING


class RouteProgressing(Guard):
    """FAILURE once the metres still to go along the route have not fallen by
    ``min_progress`` for ``period`` s (the route's trap guard, like
    :class:`behaviours.guards.conditions.NotTrapped` for a goal)."""

    reads = (POSE,)

    def __init__(
        self,
        session: RouteSession,
        period: float,
        min_progress: float = 0.25,
        name: str = "route progressing?",
    ) -> None:
        super().__init__(name)
        self.session = session
        self.period = period
        self.min_progress = min_progress
        self._best: float | None = None
        self._since = 0.0
        self._seen = -math.inf

    def update(self) -> Status:
        pose: PoseEstimate | None = self.read(POSE)
        if pose is None:
            return Status.SUCCESS
        left = self.session.remaining(pose.pose_a)
        now = pose.stamp
        if now - self._seen > 1.0:  # re-entered after a pause: start afresh
            self._best = None
        self._seen = now
        if self._best is None or left < self._best - self.min_progress:
            self._best, self._since = left, now
        stuck = now - self._since
        self.feedback_message = (
            f"{left:.1f} m to go; no progress for {stuck:.0f} s (limit {self.period:.0f} s)"
        )
        return Status.FAILURE if stuck > self.period else Status.SUCCESS
