"""Wheel odometry + IMU + GPS -> :class:`PoseEstimate` (extended Kalman filter).

A thin adapter over :class:`behaviours.laws.localisation.PoseFilter`: predict on every new
wheel reading (thesis eq. 2.1, 2.2, with the IMU's yaw rate), correct on every new GPS
fix. The pose in the aircraft frame goes through the executive's current aircraft
placement (the nominal parking pose until the laser registration measures it).
"""

from __future__ import annotations

import py_trees

from behaviours.base import Node
from behaviours.keys import POSE, SENSOR_FRAME
from behaviours.laws.localisation import PoseFilter
from executive.core.frames import AircraftPlacement, Pose2
from executive.core.records import SensorFrame


class Localise(Node):
    """Fuse odometry, IMU and GPS; publish the pose in A and in F."""

    reads = (SENSOR_FRAME,)
    writes = (POSE,)

    def __init__(
        self, initial: Pose2, track: float, placement: AircraftPlacement, name: str = "localise"
    ) -> None:
        super().__init__(name)
        self.filter = PoseFilter(initial, track=track)
        self.placement = placement
        self._wheels_stamp: float | None = None
        self._gps_stamp: float | None = None

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
        gps = frame.gps
        if gps is not None and gps.stamp != self._gps_stamp:
            self.filter.update_gps(gps)
            self._gps_stamp = gps.stamp
            sources.append("gps")
        estimate = self.filter.estimate(frame.stamp, self.placement, tuple(sources))
        self.write(POSE, estimate)
        sigma = self.filter.position_sigma
        self.feedback_message = f"sigma {sigma:.3f} m, confidence {estimate.confidence:.2f}"
        return py_trees.common.Status.SUCCESS
