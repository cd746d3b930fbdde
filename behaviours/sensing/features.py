"""Camera detections -> :class:`FeatureObservations`."""

from __future__ import annotations

import py_trees

from behaviours.base import Node
from behaviours.keys import FEATURES, SENSOR_FRAME
from executive.core.records import FeatureObservations, SensorFrame


class SenseFeatures(Node):
    """Collect the latest detections of every camera."""

    reads = (SENSOR_FRAME,)
    writes = (FEATURES,)

    def __init__(self, name: str = "sense features") -> None:
        super().__init__(name)

    def update(self) -> py_trees.common.Status:
        frame: SensorFrame = self.read(SENSOR_FRAME)
        by_camera = {cid: cam.detections for cid, cam in frame.cameras.items()}
        self.write(FEATURES, FeatureObservations(frame.stamp, by_camera))
        return py_trees.common.Status.SUCCESS
