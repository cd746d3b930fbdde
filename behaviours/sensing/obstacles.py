"""Both laser scans -> :class:`Obstacles` (r_c from the footprint, and the points)."""

from __future__ import annotations

import numpy as np
import py_trees

from behaviours.base import Node
from behaviours.keys import OBSTACLES, SENSOR_FRAME
from behaviours.laws.obstacles import closest_obstacle, scan_to_robot
from executive.core.frames import Pose2
from executive.core.model import Platform
from executive.core.records import Obstacles, SensorFrame


class SenseObstacles(Node):
    """Merge the latest scan of every laser in the robot frame; measure r_c."""

    reads = (SENSOR_FRAME,)
    writes = (OBSTACLES,)

    def __init__(self, platform: Platform, name: str = "sense obstacles") -> None:
        super().__init__(name)
        self.platform = platform
        self.mounts = {
            lid: Pose2(spec.mount[0], spec.mount[1], spec.mount_yaw)
            for lid, spec in platform.lasers.items()
        }
        self._stamps: tuple[float, ...] = ()
        self._last: tuple[np.ndarray, float, float] = (np.zeros((0, 2)), np.inf, 0.0)

    def update(self) -> py_trees.common.Status:
        frame: SensorFrame = self.read(SENSOR_FRAME)
        scans = [(lid, s) for lid, s in frame.scans.items() if lid in self.mounts]
        stamps = tuple(s.stamp for _, s in scans)
        if stamps != self._stamps:  # lasers run slower than the tree: reuse when unchanged
            parts = [
                scan_to_robot(
                    s.ranges, s.angle_min, s.angle_increment, s.range_max, self.mounts[lid]
                )
                for lid, s in scans
            ]
            points = np.vstack(parts) if parts else np.zeros((0, 2))
            r_c, bearing = closest_obstacle(points, self.platform.length, self.platform.width)
            self._stamps, self._last = stamps, (points, r_c, bearing)
        points, r_c, bearing = self._last
        self.write(OBSTACLES, Obstacles(frame.stamp, r_c, bearing, points))
        self.feedback_message = f"r_c {r_c:.2f} m"
        return py_trees.common.Status.SUCCESS
