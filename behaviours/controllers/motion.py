"""Base motion controllers: emergency stop, go-to-goal, dwell, correct camera angle."""

from __future__ import annotations

import math
from collections.abc import Callable

import py_trees

from behaviours.base import Controller
from behaviours.goals import Goal
from behaviours.keys import COMMAND, POSE, SENSOR_FRAME
from behaviours.laws.go_to_goal import GoToGoal, GoToGoalParams
from executive.core.frames import Pose2, aircraft_from_robot, pan_tilt_towards
from executive.core.model import CameraSpec, Feature
from executive.core.records import PoseEstimate, VelocityCommand

Status = py_trees.common.Status


class EStopHold(Controller):
    """Zero command, for as long as its guard holds (seed lines 1536-1542)."""

    writes = (COMMAND,)

    def __init__(self, name: str = "emergency stop") -> None:
        super().__init__(name)

    def update(self) -> Status:
        self.write(COMMAND, VelocityCommand.stop())
        return Status.RUNNING


class HoldStill(Controller):
    """Zero command: while the operator has the robot (collaborative mode stand-in), or
    while the pose is re-measured (``name`` says which)."""

    writes = (COMMAND,)

    def __init__(self, name: str = "operator control") -> None:
        super().__init__(name)

    def update(self) -> Status:
        self.write(COMMAND, VelocityCommand.stop())
        return Status.RUNNING


class GoToGoalController(Controller):
    """Metric go-to-goal in the airport frame (seed lines 1260-1378).

    ``goal`` is resolved in A at every tick (a checkpoint given in F through the pose
    estimate's current aircraft placement); ``speed_limit`` the speed allowed at a pose
    (slower near the airframe). RUNNING while moving, SUCCESS when the law reports the
    goal reached.
    """

    reads = (POSE,)
    writes = (COMMAND,)

    def __init__(
        self,
        goal: Goal,
        params: GoToGoalParams,
        use_heading: bool,
        period: float,
        speed_limit: Callable[[Pose2], float] | None = None,
        name: str = "go to goal",
    ) -> None:
        super().__init__(name)
        self.goal = goal
        self.params = params
        self.law = GoToGoal(params)
        self.use_heading = use_heading
        self.period = period
        self.speed_limit = speed_limit
        self.last_v = 0.0
        self.phase = ""

    def bt_ports(self) -> dict[str, object]:
        """The parameters worth showing in a BehaviorTree.CPP export."""
        p = self.params
        return {
            "use_heading": self.use_heading,
            "max_speed": p.max_speed,
            "position_tolerance": p.position_tolerance,
            "heading_tolerance": p.heading_tolerance,
            "turn_mode": str(p.turn_mode),
        }

    def initialise(self) -> None:
        self.law.reset()

    def update(self) -> Status:
        pose: PoseEstimate | None = self.read(POSE)
        if pose is None:
            self.write(COMMAND, VelocityCommand.stop())
            return Status.RUNNING
        goal = self.goal.in_airport(pose)
        out = self.law.command(pose.pose_a, goal, self.use_heading, self.last_v, self.period)
        v = out.v
        if self.speed_limit is not None:
            cap = self.speed_limit(pose.pose_a)
            v = max(-cap, min(cap, v))
        self.last_v = v
        self.phase = out.phase
        self.write(COMMAND, VelocityCommand(v, out.omega))
        self.feedback_message = f"{out.phase}: {out.distance:.2f} m"
        return Status.SUCCESS if out.reached else Status.RUNNING


class Dwell(Controller):
    """Stand still for ``seconds`` (the checkpoint's dwell, or a wait)."""

    reads = (SENSOR_FRAME,)
    writes = (COMMAND,)

    def __init__(self, seconds: float, name: str = "dwell") -> None:
        super().__init__(name)
        self.seconds = seconds
        self._start: float | None = None

    def initialise(self) -> None:
        self._start = None

    def update(self) -> Status:
        now = self.read(SENSOR_FRAME).stamp
        if self._start is None:
            self._start = now
        self.write(COMMAND, VelocityCommand.stop())
        left = self.seconds - (now - self._start)
        self.feedback_message = f"{max(left, 0.0):.1f} s left"
        return Status.SUCCESS if left <= 0.0 else Status.RUNNING


class CorrectCameraAngle(Controller):
    """Turn in place until the active camera needs a pan under ``threshold`` to look at
    its target (seed lines 1379-1400); no linear velocity."""

    reads = (POSE,)
    writes = (COMMAND,)

    def __init__(
        self,
        camera: CameraSpec,
        target: Feature,
        origin_height: float,
        threshold: float,
        max_omega: float,
        gain: float = 1.0,
        name: str = "correct camera angle",
    ) -> None:
        super().__init__(name)
        self.camera = camera
        self.target = target
        self.origin_height = origin_height
        self.threshold = threshold
        self.max_omega = max_omega
        self.gain = gain

    def required_pan(self, pose_f: Pose2) -> float:
        target_r = (
            aircraft_from_robot(pose_f, self.origin_height).inverse().apply(self.target.centroid())
        )
        pan, _ = pan_tilt_towards(self.camera.mount, self.camera.mount_yaw, target_r)
        return pan

    def update(self) -> Status:
        pose: PoseEstimate | None = self.read(POSE)
        if pose is None:
            self.write(COMMAND, VelocityCommand.stop())
            return Status.RUNNING
        pan = self.required_pan(pose.pose_f)
        self.feedback_message = f"pan {math.degrees(pan):.0f} deg"
        if abs(pan) <= self.threshold:
            self.write(COMMAND, VelocityCommand.stop())
            return Status.SUCCESS
        # Pan is measured about +z_R (left positive): turning the base left by the same
        # angle brings the target towards the unit's zero.
        omega = max(-self.max_omega, min(self.max_omega, self.gain * pan))
        self.write(COMMAND, VelocityCommand(0.0, omega))
        return Status.RUNNING
