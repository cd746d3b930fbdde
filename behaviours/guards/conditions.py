"""The guard conditions of the decision layer (thesis seed lines 1453-1542).

Each guard's ``feedback_message`` states the value against its threshold; the runtime
logs it as the reason of the controller switch it causes.
"""

from __future__ import annotations

import math

import py_trees
from shapely.geometry import Point
from shapely.geometry.base import BaseGeometry

from behaviours.base import Guard
from behaviours.goals import Goal
from behaviours.keys import OBSTACLES, OPERATOR, POSE, PROGRESS, SENSOR_FRAME, MissionProgress
from behaviours.laws.estop import EStopLatch
from executive.core.frames import AircraftPlacement, wrap_angle
from executive.core.records import (
    FrameReference,
    Obstacles,
    OperatorRequests,
    PoseEstimate,
    SensorFrame,
)

Status = py_trees.common.Status


class EmergencyStop(Guard):
    """r_c < r_ES or a bumper: latched (released after ``hold`` s clear; a bumper only by
    an operator reset)."""

    reads = (OBSTACLES, SENSOR_FRAME, OPERATOR)

    def __init__(self, r_es: float, hold: float, name: str = "e-stop?") -> None:
        super().__init__(name)
        self.latch = EStopLatch(r_es, hold)

    def update(self) -> Status:
        obstacles: Obstacles | None = self.read(OBSTACLES)
        frame: SensorFrame = self.read(SENSOR_FRAME)
        operator: OperatorRequests = self.read(OPERATOR, OperatorRequests())
        r_c = obstacles.closest if obstacles is not None else None
        latched = self.latch.update(frame.stamp, r_c, frame.bumpers.any, operator.reset_estop)
        shown = "unknown" if r_c is None else f"{r_c:.2f} m"
        self.feedback_message = self.latch.reason if latched else f"clear (r_c {shown})"
        return Status.SUCCESS if latched else Status.FAILURE


class ObstacleTrigger(Guard):
    """r_c < r_OA-trigger engages obstacle avoidance; it disengages once r_c exceeds the
    trigger by ``release_margin`` (hysteresis, so the avoidance does not flicker)."""

    reads = (OBSTACLES,)

    def __init__(self, r_oa: float, release_margin: float = 0.3, name: str = "obstacle?") -> None:
        super().__init__(name)
        self.r_oa = r_oa
        self.release_margin = release_margin
        self.engaged = False

    def update(self) -> Status:
        obstacles: Obstacles | None = self.read(OBSTACLES)
        r_c = obstacles.closest if obstacles is not None else math.inf
        if self.engaged:
            self.engaged = r_c < self.r_oa + self.release_margin
        else:
            self.engaged = r_c < self.r_oa
        self.feedback_message = f"r_c {r_c:.2f} m vs r_OA {self.r_oa:.2f} m"
        return Status.SUCCESS if self.engaged else Status.FAILURE


class PoseNotGoodEnough(Guard):
    """The pose in F is too uncertain to steer to an aircraft-frame goal: stop and let
    the laser registration measure it (the thesis stops for every point-cloud matching,
    seed lines 1053-1070; here only when the estimate is not good enough while moving).

    Engages when ``confidence_f`` falls below ``low`` and releases above ``high``
    (hysteresis). A hold lasts at most ``max_hold`` s: if the registration cannot help
    (the aircraft hidden by vehicles), the robot goes on with the estimate it has (the
    last-checkpoint frame) and the guard rests for ``cooldown`` s, so it never deadlocks.
    Before the first registration (reference ``nominal``) it never holds: the global
    registration runs while moving, and holding cannot help an aircraft the lasers cannot
    register (e.g. a lone target board).
    """

    reads = (POSE,)

    def __init__(
        self,
        low: float = 0.3,
        high: float = 0.6,
        max_hold: float = 5.0,
        cooldown: float = 20.0,
        name: str = "pose not good enough?",
    ) -> None:
        super().__init__(name)
        self.low, self.high = low, high
        self.max_hold, self.cooldown = max_hold, cooldown
        self.engaged = False
        self._since = 0.0
        self._rest_until = -math.inf

    def update(self) -> Status:
        pose: PoseEstimate | None = self.read(POSE)
        if pose is None:
            return Status.FAILURE
        now, confidence = pose.stamp, pose.confidence_f
        if self.engaged:
            if confidence >= self.high:
                self.engaged = False
            elif now - self._since > self.max_hold:
                self.engaged = False
                self._rest_until = now + self.cooldown
        elif (
            confidence < self.low
            and now >= self._rest_until
            and pose.reference is not FrameReference.NOMINAL
        ):
            self.engaged, self._since = True, now
        where = f"{pose.reference}{' ' + pose.anchor if pose.anchor else ''}"
        self.feedback_message = f"confidence_F {confidence:.2f} (low {self.low:.2f}), {where}"
        return Status.SUCCESS if self.engaged else Status.FAILURE


class NotTrapped(Guard):
    """FAILURE once the robot has made no progress towards its goal for ``period`` s.

    Progress is a decrease of the best distance to the goal so far by ``min_progress`` m,
    or by what is left of it down to ``at_goal`` (the navigation's position tolerance), or
    being within ``at_goal``: there what remains (the turn to the goal heading, a servo
    settling) is the navigation's own business. Merely being near the goal is no progress:
    a robot that shuttles 0.1-0.3 m short of its goal because every approach ends in an
    e-stop and a retreat (campaign a320-busy-apron, episode 17: an hour of it) is trapped.
    Placed in front of a navigation, its FAILURE fails the navigation with the reason in
    its feedback.
    """

    reads = (POSE,)

    def __init__(
        self,
        goal: Goal,
        period: float,
        min_progress: float = 0.25,
        at_goal: float = 0.0,
        towards: str = "the goal",
        name: str = "not trapped?",
    ) -> None:
        super().__init__(name)
        self.goal = goal
        self.period = period
        self.min_progress = min_progress
        self.at_goal = at_goal
        self.towards = towards
        self._best: float | None = None
        self._since = 0.0
        self._seen = -math.inf
        self._closest = math.inf

    def restart(self, now: float) -> None:
        """Start the period again from ``now`` (the operator said wait, or took over)."""
        self._best, self._since, self._seen = None, now, now

    def update(self) -> Status:
        # Not reset in initialise(): py_trees calls it before every tick of a behaviour
        # that returned SUCCESS. A navigation re-entered after a pause starts afresh.
        pose: PoseEstimate | None = self.read(POSE)
        if pose is None:
            return Status.SUCCESS
        goal = self.goal.in_airport(pose)
        d = math.hypot(goal.x - pose.pose_a.x, goal.y - pose.pose_a.y)
        now = pose.stamp
        if now - self._seen > 1.0:
            self._best = None
        self._seen = now
        best = self._best
        if best is None or d <= self.at_goal or d < max(best - self.min_progress, self.at_goal):
            self._best, self._since, self._closest = d, now, d
        else:
            self._closest = min(self._closest, d)  # since the last progress
        stuck = now - self._since
        self.feedback_message = (
            f"no progress towards {self.towards} for {stuck:.0f} s (limit {self.period:.0f} s; "
            f"{d:.2f} m from it, {self._closest:.2f} m at the closest)"
        )
        return Status.FAILURE if stuck > self.period else Status.SUCCESS


class Reached(Guard):
    """The estimated pose is within the goal's position and heading tolerances."""

    reads = (POSE,)

    def __init__(
        self,
        goal: Goal,
        position_tolerance: float,
        heading_tolerance: float | None,
        name: str = "reached?",
    ) -> None:
        super().__init__(name)
        self.goal = goal
        self.position_tolerance = position_tolerance
        self.heading_tolerance = heading_tolerance

    def update(self) -> Status:
        pose: PoseEstimate | None = self.read(POSE)
        if pose is None:
            return Status.FAILURE
        goal = self.goal.in_airport(pose)
        d = math.hypot(goal.x - pose.pose_a.x, goal.y - pose.pose_a.y)
        ok = d <= self.position_tolerance
        if self.heading_tolerance is not None:
            e = abs(wrap_angle(goal.theta - pose.pose_a.theta))
            ok = ok and e <= self.heading_tolerance
            self.feedback_message = f"{d:.3f} m, {math.degrees(e):.1f} deg to go"
        else:
            self.feedback_message = f"{d:.3f} m to go"
        return Status.SUCCESS if ok else Status.FAILURE


class OperatorTakeOver(Guard):
    """The operator has the robot (collaborative mode): a take-over or a pause.

    It lasts as long as the operator asks for it; its branch pre-empts the mission (and
    the return after an abort), which resumes where it was at the hand-back
    (:class:`ResumableSequence` in the compiler).
    """

    reads = (OPERATOR,)

    def __init__(self, name: str = "operator takes over?") -> None:
        super().__init__(name)
        self.hand_backs = 0
        """How many times a take-over (or pause) ended (:class:`RejoinAfterHandBack`)."""
        self._taken = False

    def update(self) -> Status:
        operator: OperatorRequests = self.read(OPERATOR, OperatorRequests())
        if self._taken and not operator.take_over:
            self.hand_backs += 1
        self._taken = operator.take_over
        self.feedback_message = "operator request" if operator.take_over else "no request"
        return Status.SUCCESS if operator.take_over else Status.FAILURE


class OperatorAborted(Guard):
    """The operator aborted the mission (latched: one request is enough, it never
    resumes in this run). Its branch takes the robot back to the handover point P
    (seed 000 fig. 2.21's way out of the inspection); the runtime then ends the run as
    ``aborted``. A take-over still pre-empts the return."""

    reads = (OPERATOR,)

    def __init__(self, name: str = "operator aborted?") -> None:
        super().__init__(name)
        self.aborted = False

    def update(self) -> Status:
        operator: OperatorRequests = self.read(OPERATOR, OperatorRequests())
        self.aborted = self.aborted or operator.abort
        self.feedback_message = "operator abort" if self.aborted else "no abort"
        return Status.SUCCESS if self.aborted else Status.FAILURE


class RejoinAfterHandBack(Guard):
    """The surrender transitions of seed 000 fig. 2.21, at the operator's hand-back.

    "Operator surrenders robot control - point P detected in close vicinity": the paused
    phase resumes (the mission's :class:`ResumableSequence` does that by itself).
    "Operator surrenders robot control - point P can not be found": approach mode, back to
    P first. P is the handover point where the approach ends and the inspection begins;
    "close vicinity" is the band round the airframe that P itself lies in: a robot handed
    back no farther from the airframe than P is (plus ``margin``) is where the inspection
    goes on, one led farther out goes back to P before the checkpoint it was on.

    SUCCESS (latched) from a hand-back of the take-over ``take_over`` (its
    :attr:`OperatorTakeOver.hand_backs`) while the mission is past its approach and the
    robot is out of the vicinity, until :meth:`rejoined`; FAILURE otherwise.
    """

    reads = (POSE,)
    reads_previous = (PROGRESS,)

    def __init__(
        self,
        take_over: OperatorTakeOver,
        airframe_f: BaseGeometry,
        reach: float,
        nominal: AircraftPlacement,
        name: str = "P not in close vicinity?",
    ) -> None:
        super().__init__(name)
        self.take_over = take_over
        self.airframe_f = airframe_f
        self.reach = reach
        self.nominal = nominal
        self.active = False
        self._seen = 0

    def rejoined(self) -> None:
        """P was reached: the paused phase resumes."""
        self.active = False

    def distance(self, pose: PoseEstimate) -> float:
        """The robot's distance (m) to the airframe, with the pose estimate's placement."""
        placement = pose.placement or self.nominal
        x, y = placement.to_aircraft_xy([[pose.pose_a.x, pose.pose_a.y]])[0]
        return float(self.airframe_f.distance(Point(x, y)))

    def update(self) -> Status:
        hand_backs = self.take_over.hand_backs
        if hand_backs != self._seen and not self.active:
            progress: MissionProgress | None = self.read(PROGRESS, None)
            pose: PoseEstimate | None = self.read(POSE, None)
            past_approach = progress is not None and progress.phase in ("inspection", "return")
            if past_approach and pose is not None:
                d = self.distance(pose)
                self.active = d > self.reach
                self.feedback_message = (
                    f"handed back {d:.1f} m from the airframe, P is within {self.reach:.1f} m: "
                    + ("P not found close by, back to P" if self.active else "resume")
                )
        self._seen = hand_backs
        return Status.SUCCESS if self.active else Status.FAILURE
