"""Returns remembered in the lasers' blind spots beside the body: our addition, for the
arc retreat (:mod:`behaviours.laws.retreat`).

Two 270-degree scanners at the ends of the robot's axis (the Air-Cobot's Hokuyos, seed
000 lines 617-800) see all round it except two pockets beside the middle of its long
sides, where their last rays, 135 degrees off the axis, cross (0.15 m deep on the shipped
platforms: ``|x| + |y| < 0.65 m``). A straight motion never sweeps into them (the sides slide along
themselves); a turn does: the half of each side ahead of or behind the axle swings out.
What is in a pocket was in view before the robot drove alongside it, so the robot keeps
the returns near its footprint in its odometry frame (continuous, REP-105's ``odom``)
and, while they lie in a pocket, hands them on as *hidden* returns. A remembered return
that comes back into view is forgotten: the scan speaks for it again. Nothing is forgotten
for age: an unseen return may still be there.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np

from behaviours.laws.obstacles import footprint_distances, footprint_distances_xy
from executive.core.frames import FloatArray, Pose2
from executive.core.model import LaserSpec

MEMORY_REACH = 0.3
"""Returns within this distance (m) of the footprint are remembered: a blind pocket deeper
than this is not one the memory can fill (:func:`pockets_only`)."""

MEMORY_CELL = 0.02
"""Remembered returns are kept one per cell of this size (m) of the odometry frame."""


def seen_by(lasers: Iterable[LaserSpec], x: FloatArray, y: FloatArray) -> FloatArray:
    """Whether each point (robot frame, any shape) lies in some laser's field of view
    and range."""
    seen = np.zeros(np.shape(x), dtype=bool)
    for spec in lasers:
        dx, dy = x - spec.mount[0], y - spec.mount[1]
        bearing = np.arctan2(dy, dx) - spec.mount_yaw
        bearing = (bearing + np.pi) % (2 * np.pi) - np.pi
        seen |= (np.abs(bearing) <= 0.5 * spec.fov) & (np.hypot(dx, dy) <= spec.range)
    return seen


def blind_depth(
    lasers: Iterable[LaserSpec], length: float, width: float, reach: float, samples: int = 20
) -> float:
    """How far (m) from the footprint the lasers' blind spots reach within ``reach`` of it
    (sampled every 1 / ``samples`` m); 0 when they see all round it."""
    specs = list(lasers)
    half_x, half_y = 0.5 * length + reach, 0.5 * width + reach
    xs, ys = np.meshgrid(
        np.linspace(-half_x, half_x, math.ceil(2 * half_x * samples) + 1),
        np.linspace(-half_y, half_y, math.ceil(2 * half_y * samples) + 1),
    )
    d = footprint_distances_xy(xs, ys, length, width)
    ring = (d > 0.0) & (d <= reach)
    blind = ring & ~seen_by(specs, xs, ys)
    return float(d[blind].max()) + 1.0 / samples if blind.any() else 0.0


def pockets_only(lasers: Iterable[LaserSpec], length: float, width: float, reach: float) -> bool:
    """Whether everything the lasers miss within ``reach`` of the footprint lies within
    :data:`MEMORY_REACH` of it: blind pockets that :class:`BlindSpotMemory` fills."""
    return blind_depth(lasers, length, width, reach) <= MEMORY_REACH


class BlindSpotMemory:
    """The returns near the footprint of a robot with ``lasers``, remembered in the
    odometry frame while they lie in a blind spot (see the module docstring)."""

    def __init__(self, lasers: Iterable[LaserSpec], length: float, width: float) -> None:
        self.lasers = tuple(lasers)
        self.length, self.width = length, width
        self._memory = np.zeros((0, 2))  # odometry frame
        self._half_x, self._half_y = 0.5 * length + MEMORY_REACH, 0.5 * width + MEMORY_REACH

    def update(self, points: FloatArray, pose: Pose2, closest: float = 0.0) -> FloatArray:
        """Take this scan's returns (robot frame, (N, 2)) at odometry ``pose``; the
        remembered returns that lie in a blind spot now (robot frame, (M, 2)).
        ``closest``: the returns' smallest distance to the footprint when known (nothing
        to do when it is beyond :data:`MEMORY_REACH` and nothing is remembered)."""
        if closest > MEMORY_REACH and not len(self._memory):
            return np.zeros((0, 2))
        hidden = np.zeros((0, 2))
        if len(self._memory):
            robot = pose.inverse().apply(self._memory)
            rx, ry = robot[:, 0], robot[:, 1]
            keep = footprint_distances_xy(rx, ry, self.length, self.width) <= MEMORY_REACH
            keep &= ~seen_by(self.lasers, rx, ry)
            hidden = robot[keep]
        box = (np.abs(points[:, 0]) <= self._half_x) & (np.abs(points[:, 1]) <= self._half_y)
        near = points[box]
        near = near[footprint_distances(near, self.length, self.width) <= MEMORY_REACH]
        if len(near) or len(hidden):
            world = pose.apply(np.vstack((near, hidden)))
            cells = np.floor(world / MEMORY_CELL).astype(np.int64)
            _, first = np.unique(cells[:, 0] * (1 << 32) + cells[:, 1], return_index=True)
            self._memory = world[np.sort(first)]
        else:
            self._memory = np.zeros((0, 2))
        return hidden
