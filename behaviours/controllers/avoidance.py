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

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import py_trees

from behaviours.base import Controller, Guard
from behaviours.goals import Goal
from behaviours.keys import COMMAND, OBSTACLES, POSE
from behaviours.laws.rate_limit import RateLimiter, RateLimits
from behaviours.laws.spiral import (
    SpiralAvoidance,
    SpiralObstacle,
    SpiralParams,
    path_blocked,
)
from behaviours.laws.velocity_obstacles import MovingDisc, VoParams, choose_velocity
from executive.core.frames import Pose2, wrap_angle
from executive.core.model import Platform
from executive.core.records import Obstacles, PoseEstimate, TrackedObstacle, VelocityCommand

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


@dataclass
class AvoidanceSession:
    """What the guard and the controller of one navigation share."""

    obstacle_id: int | None = None
    engaged_at: float = 0.0
    missing_since: float | None = None
    released: bool = False
    reason: str = ""


class AvoiderFactory(Protocol):
    """Builds the avoidance controller of one navigation (the compiler's plug-in point).

    :class:`AvoidObstacle` is the shipped one; ``benchmarks/dwa.py`` plugs a
    dynamic-window baseline in through :attr:`executive.compiler.CompileOptions.avoider`.
    """

    def __call__(
        self, goal: Goal, session: AvoidanceSession, platform: Platform, period: float
    ) -> Controller: ...


class AvoidanceTrigger(Guard):
    """r_c < r_OA-trigger for an obstacle on the way to the goal engages the avoidance;
    the spiral's release condition (or the obstacle lost for ``lost_after`` s) ends it.

    The path check is the thesis's "distance to the target" check (figure 4.15): an
    obstacle beside the path or beyond the goal does not engage, so a released robot is
    not caught again by the same obstacle.
    """

    reads = (OBSTACLES, POSE)

    def __init__(
        self,
        goal: Goal,
        session: AvoidanceSession,
        r_oa: float,
        margin: float,
        lost_after: float = 1.0,
        name: str = "obstacle on the way?",
    ) -> None:
        super().__init__(name)
        self.goal, self.session = goal, session
        self.r_oa, self.margin, self.lost_after = r_oa, margin, lost_after

    def update(self) -> Status:
        obstacles: Obstacles | None = self.read(OBSTACLES)
        pose: PoseEstimate | None = self.read(POSE)
        session = self.session
        if obstacles is None or pose is None:
            return Status.FAILURE
        now = obstacles.stamp
        robot = np.array([pose.pose_a.x, pose.pose_a.y])
        target = self.goal.in_airport(pose)
        target_xy = np.array([target.x, target.y])
        if session.obstacle_id is not None:
            track = next((t for t in obstacles.tracks if t.id == session.obstacle_id), None)
            if session.released:
                return self._release(session.reason)
            if track is None:
                session.missing_since = session.missing_since or now
                if now - session.missing_since > self.lost_after:
                    return self._release("obstacle no longer tracked")
            else:
                session.missing_since = None
            self.feedback_message = f"avoiding obstacle {session.obstacle_id}"
            return Status.SUCCESS
        if float(np.hypot(*(target_xy - robot))) < self.margin:
            self.feedback_message = "at the goal"
            return Status.FAILURE
        best: TrackedObstacle | None = None
        for track in obstacles.tracks:
            if track.kind == "zone" or track.clearance >= self.r_oa:
                continue
            obstacle = obstacle_in_airport(track, pose.pose_a)
            if not path_blocked(robot, target_xy, obstacle, self.margin):
                continue
            if best is None or track.clearance < best.clearance:
                best = track
        if best is None:
            self.feedback_message = f"way clear (r_c {obstacles.closest:.2f} m)"
            return Status.FAILURE
        session.obstacle_id, session.engaged_at = best.id, now
        session.released, session.reason, session.missing_since = False, "", None
        self.feedback_message = (
            f"obstacle {best.id} ({best.kind}) {best.clearance:.2f} m < r_OA "
            f"{self.r_oa:.2f} m on the way"
        )
        return Status.SUCCESS

    def _release(self, reason: str) -> Status:
        self.session.obstacle_id = None
        self.session.released = False
        self.feedback_message = f"released: {reason}"
        return Status.FAILURE


class AvoidObstacle(Controller):
    """Spiral obstacle avoidance around the session's obstacle (eqs. 4.1-4.16), velocity
    obstacles (Fiorini and Shiller) when it moves faster than ``vo_speed``; the command is
    rate limited (the thesis's future-work item: no oscillating velocities)."""

    reads = (OBSTACLES, POSE)
    writes = (COMMAND,)

    def __init__(
        self,
        goal: Goal,
        session: AvoidanceSession,
        platform: Platform,
        period: float,
        params: SpiralParams | None = None,
        vo_speed: float = 1.5,
        name: str = "spiral avoidance",
    ) -> None:
        super().__init__(name)
        self.goal, self.session, self.period = goal, session, period
        self.params = params or SpiralParams()
        self.law = SpiralAvoidance(self.params)
        self.vo_speed = vo_speed
        radius = 0.5 * math.hypot(platform.length, platform.width)
        self.vo = VoParams(
            v_max=self.params.nu_max,
            omega_max=min(self.params.omega_max, platform.max_angular_speed),
            robot_radius=radius,
        )
        self.limiter = RateLimiter(
            RateLimits(
                max_acceleration=platform.max_acceleration,
                max_angular_acceleration=platform.max_angular_acceleration,
                max_speed=platform.max_speed,
                max_angular_speed=platform.max_angular_speed,
            )
        )
        self.mode = "spiral"

    def initialise(self) -> None:
        self.law.reset()
        self.limiter.reset(0.0, 0.0)

    def update(self) -> Status:
        obstacles: Obstacles | None = self.read(OBSTACLES)
        pose: PoseEstimate | None = self.read(POSE)
        session = self.session
        track = None
        if obstacles is not None and session.obstacle_id is not None:
            track = next((t for t in obstacles.tracks if t.id == session.obstacle_id), None)
        if pose is None or track is None:
            v, omega = self.limiter.step(0.0, 0.0, self.period)
            self.write(COMMAND, VelocityCommand(v, omega))
            self.feedback_message = "obstacle not in view: braking"
            return Status.RUNNING
        obstacle = obstacle_in_airport(track, pose.pose_a)
        target = self.goal.in_airport(pose)
        target_xy = np.array([target.x, target.y])
        if obstacle.speed > self.vo_speed:
            v, omega = self._velocity_obstacles(pose.pose_a, target_xy, obstacle)
            self.mode = "velocity obstacles"
            self.feedback_message = f"VO: obstacle {track.id} at {obstacle.speed:.1f} m/s"
        else:
            out = self.law.command(pose.pose_a, target_xy, obstacle, self.period)
            if out.released:
                session.released, session.reason = True, out.reason
            v, omega = out.v, out.omega
            self.mode = "spiral"
            self.feedback_message = (
                f"spiral: alpha_d {math.degrees(out.alpha_d):.0f} deg, beta_c "
                f"{math.degrees(out.beta_c):.0f} deg, e_r {out.e_r:.2f} m"
            )
        v, omega = self.limiter.step(v, omega, self.period)
        self.write(COMMAND, VelocityCommand(v, omega))
        return Status.RUNNING

    def _velocity_obstacles(
        self, pose: Pose2, target_xy: np.ndarray, obstacle: SpiralObstacle
    ) -> tuple[float, float]:
        bearing = math.atan2(target_xy[1] - pose.y, target_xy[0] - pose.x)
        error = wrap_angle(bearing - pose.theta)
        preferred = (self.vo.v_max * max(0.0, math.cos(error)), max(-1.0, min(1.0, error)))
        disc = MovingDisc(obstacle.position, obstacle.velocity, obstacle.size)
        choice = choose_velocity(
            np.array([pose.x, pose.y]), pose.theta, preferred, (disc,), self.vo
        )
        return choice.v, choice.omega
