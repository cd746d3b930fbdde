"""Camera detections -> :class:`FeatureObservations`, fresh images only."""

from __future__ import annotations

import py_trees

from behaviours.base import Node
from behaviours.keys import FEATURES, SENSOR_FRAME
from behaviours.laws.freshness import Freshness
from executive.core.model import Platform
from executive.core.records import FeatureObservations, SensorFrame, camera_ids

DEFAULT_STALE_AFTER = 0.12
"""Seconds without a new image after which a camera is stale when its rate is not known:
three periods of the shipped platforms' 25 Hz cameras."""


def camera_limits(platform: Platform) -> dict[str, float]:
    """Three frame periods of each camera of ``platform``, by the frame's camera id
    (``<unit>-left`` / ``<unit>-right`` for a stereo unit)."""
    limits: dict[str, float] = {}
    for uid, spec in platform.cameras.items():
        limit = 3.0 / spec.rate_hz if spec.rate_hz > 0 else DEFAULT_STALE_AFTER
        limits.update(dict.fromkeys(camera_ids(platform, uid), limit))
    return limits


class SenseFeatures(Node):
    """Collect the latest detections of every camera whose image is fresh.

    A camera whose last new image is older than its limit — no new stamp, or a frozen
    pipeline repeating the same detections with fresh stamps
    (:mod:`behaviours.laws.freshness`) — is listed in ``stale`` and its detections left
    out: a behaviour must not act on what a camera saw seconds ago as if it saw it now.
    """

    reads = (SENSOR_FRAME,)
    writes = (FEATURES,)

    def __init__(self, platform: Platform | None = None, name: str = "sense features") -> None:
        super().__init__(name)
        self.limits = camera_limits(platform) if platform is not None else {}
        self._fresh: dict[str, Freshness] = {}

    def update(self) -> py_trees.common.Status:
        frame: SensorFrame = self.read(SENSOR_FRAME)
        now = frame.stamp
        by_camera = {}
        stale = []
        for cid, cam in frame.cameras.items():
            fresh = self._fresh.get(cid)
            if fresh is None:
                limit = self.limits.get(cid, DEFAULT_STALE_AFTER)
                fresh = self._fresh[cid] = Freshness(limit, repeats_are_stale=True)
            fresh.observe(cam.stamp, cam.content)
            if fresh.stale(now):
                stale.append(cid)
            else:
                by_camera[cid] = cam.detections
        self.write(FEATURES, FeatureObservations(now, by_camera, tuple(stale)))
        return py_trees.common.Status.SUCCESS
