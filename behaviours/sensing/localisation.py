"""Wheel odometry + IMU + GPS + laser registration + ceiling -> :class:`PoseEstimate`.

A thin adapter over :class:`behaviours.laws.localisation.PoseFilter` (an EKF on the
robot's pose in A augmented with the aircraft placement): predict on every new wheel
reading (thesis eq. 2.1, 2.2, with the IMU's yaw rate), correct on every new GPS fix, and
on every laser registration of the aircraft the :class:`AircraftRegistrar` makes. The
pose in the aircraft frame is the filter's, through its *estimated* placement: the
nominal parking pose only until the first registration. Under a hangar ceiling, with an
upward camera and a mosaic (issue 17), each new ceiling image is localised against the
mosaic and fused as a pose fix (:class:`behaviours.sensing.ceiling.CeilingFixer`).
"""

from __future__ import annotations

import math

import py_trees

from behaviours.base import Node
from behaviours.keys import POSE, PROGRESS, SENSOR_FRAME, MissionProgress
from behaviours.laws.localisation import PoseFilter
from behaviours.sensing.ceiling import CeilingFixer
from behaviours.sensing.registration import AircraftRegistrar
from executive.core.frames import AircraftPlacement, Pose2
from executive.core.records import FrameReference, RegistrationRecord, SensorFrame, WheelSpeeds


class Localise(Node):
    """Fuse odometry, IMU, GPS and the aircraft registration; publish the pose in A and F.

    ``registrar`` None: no laser registration (the pose in F stays on the nominal
    placement, e.g. a mission whose aircraft has no footprint in laser range).
    ``ceiling`` None: no ceiling fixes (no upward camera or no mosaic).
    """

    reads = (SENSOR_FRAME,)
    reads_previous = (PROGRESS,)
    writes = (POSE,)

    def __init__(
        self,
        initial: Pose2,
        track: float,
        placement: AircraftPlacement,
        registrar: AircraftRegistrar | None = None,
        name: str = "localise",
        ceiling: CeilingFixer | None = None,
    ) -> None:
        super().__init__(name)
        self.filter = PoseFilter(initial, track=track, placement=placement)
        self.registrar = registrar
        self.ceiling = ceiling
        self._wheels_stamp: float | None = None
        self._gps_stamp: float | None = None
        self._last: RegistrationRecord | None = None

    def moved_before_start(self, left: float, right: float) -> None:
        """The base's odometers say its sides travelled ``left`` and ``right`` metres since
        the pose this node starts from (a resumed robot run: after the executive died the
        robot drove on until its base's watchdog braked it). Applied before the first tick
        as one constant-curvature odometry step of the filter (eq. 2.1 and 2.2 with its own
        speed and yaw scales; its covariance grows accordingly)."""
        if self._wheels_stamp is not None:
            raise RuntimeError("the pose filter has started: the motion is in it already")
        self.filter.predict(WheelSpeeds(0.0, left, right), None, 1.0)

    def update(self) -> py_trees.common.Status:
        frame: SensorFrame = self.read(SENSOR_FRAME)
        sources = []
        wheels = frame.wheels
        if wheels is not None and wheels.stamp != self._wheels_stamp:
            if self._wheels_stamp is not None:
                dt = wheels.stamp - self._wheels_stamp
                if dt > 0:
                    self.filter.predict(wheels, frame.imu, dt)
            self._wheels_stamp = wheels.stamp
            sources.append("odometry")
            if frame.imu is not None:
                sources.append("imu")
            if self.registrar is not None:
                self.registrar.record_pose(wheels.stamp, self.filter.pose)
            if self.ceiling is not None:
                self.ceiling.record_pose(wheels.stamp, self.filter.pose)
        gps = frame.gps
        if gps is not None and gps.stamp != self._gps_stamp:
            self.filter.update_gps(gps)
            self._gps_stamp = gps.stamp
            sources.append("gps")
        if self.ceiling is not None and self.ceiling.step(frame.stamp, frame.ceiling, self.filter):
            sources.append("ceiling")
        reference, anchor = FrameReference.NOMINAL, ""
        if self.registrar is not None:
            record = self.registrar.step(frame, self.filter)
            if record is not None:
                self._last = record
                if record.accepted:
                    sources.append(f"registration-{record.method}")
            reference = self.registrar.reference()
            if reference is FrameReference.CHECKPOINT:
                progress: MissionProgress | None = self.read(PROGRESS, None)
                anchor = progress.completed[-1] if progress and progress.completed else ""
            elif reference is FrameReference.AIRCRAFT:
                anchor = "registration"
        estimate = self.filter.estimate(
            frame.stamp, tuple(sources), reference, anchor, registration=self._last
        )
        self.write(POSE, estimate)
        cov_f = estimate.covariance_f
        sigma = math.sqrt(max(float(cov_f[0, 0] + cov_f[1, 1]), 0.0))
        self.feedback_message = (
            f"sigma_F {sigma:.3f} m, confidence_F {estimate.confidence_f:.2f}, {reference}"
        )
        if self.ceiling is not None:
            counts = self.ceiling.counts
            self.feedback_message += (
                f", ceiling fixes {counts['accepted']}/{counts['images']} "
                f"({counts['rejected']} refused)"
            )
        return py_trees.common.Status.SUCCESS
