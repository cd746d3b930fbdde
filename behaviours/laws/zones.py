"""Forbidden zones as virtual obstacles (seed lines 3596-3620).

The thesis maps forbidden airport areas (refuelling, engine danger, parking of other
vehicles) into the robot's obstacle map so that "the obstacle avoidance treats them like
real obstacles". Here every zone edge is sampled once into points, in the zone's own
frame; each tick the points within ``radius`` of the robot are expressed in the robot
frame R — virtual laser returns — and each zone in range becomes one virtual obstacle at
its boundary point nearest to the robot. Zones in the aircraft frame F follow the
current placement estimate. The safety layer's hard geofence (executive.safety) stays the
last word; this only lets the controllers see the walls before they reach them.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from behaviours.laws.obstacles import footprint_distances
from executive.core.frames import AircraftPlacement, FloatArray, Pose2
from executive.core.model import Circle, ForbiddenZone, Frame


@dataclass(frozen=True, slots=True)
class ZoneWall:
    """The nearest stretch of one zone's boundary, in the robot frame."""

    zone: str
    index: int
    nearest: tuple[float, float]
    """Boundary point nearest to the robot's centre (R)."""
    clearance: float
    """Distance from the robot's footprint to the boundary (m)."""
    edge: tuple[float, float, float, float]
    """End points (x0, y0, x1, y1) in R of the boundary edge through ``nearest``."""
    extent: float
    """Radius of a circle around ``nearest`` enclosing the boundary points in range."""


def sample_boundary(zone: ForbiddenZone, spacing: float) -> tuple[FloatArray, FloatArray]:
    """Points every ``spacing`` m along the zone's boundary, in the zone's frame, and for
    each point the index of its edge's start vertex in :func:`boundary_vertices`."""
    verts = boundary_vertices(zone)
    nxt = np.roll(verts, -1, axis=0)
    points: list[FloatArray] = []
    owners: list[FloatArray] = []
    for k, (a, b) in enumerate(zip(verts, nxt, strict=True)):
        n = max(1, math.ceil(float(np.hypot(*(b - a))) / spacing))
        t = np.arange(n) / n
        points.append(a + t[:, None] * (b - a))
        owners.append(np.full(n, k))
    return np.vstack(points), np.concatenate(owners).astype(np.intp)


def boundary_vertices(zone: ForbiddenZone) -> FloatArray:
    """The zone's boundary as a closed ring of vertices (a circle as a 64-gon)."""
    shape = zone.shape
    if isinstance(shape, Circle):
        return shape.vertices(64)
    return shape.vertices()


class VirtualWalls:
    """Zone boundaries as virtual laser points and one virtual obstacle per zone in range.

    ``radius`` (m): how far from the robot's centre boundary points are injected;
    ``spacing`` (m): the boundary sampling step (about a laser's beam spacing at a few
    metres). ``length`` x ``width`` is the robot's footprint for the clearances.
    """

    def __init__(
        self,
        zones: Iterable[ForbiddenZone],
        length: float,
        width: float,
        radius: float = 6.0,
        spacing: float = 0.1,
    ) -> None:
        self.zones = tuple(zones)
        self.length, self.width = float(length), float(width)
        self.radius = float(radius)
        samples = [sample_boundary(z, spacing) for z in self.zones]
        self._points = [p for p, _ in samples]
        self._owners = [o for _, o in samples]
        self._vertices = [boundary_vertices(z) for z in self.zones]
        self._placement: AircraftPlacement | None = None
        self._airport: list[FloatArray] = []
        self._airport_vertices: list[FloatArray] = []
        self._boxes = np.zeros((0, 4))

    def _in_airport(self, placement: AircraftPlacement) -> None:
        """Zone points in A; recomputed when the placement moved by 1 cm or 0.05 deg (the
        pose filter nudges it on every GPS fix)."""
        old = self._placement
        if old is not None and self._airport and not placement.differs_from(old):
            return
        self._placement = placement
        self._airport, self._airport_vertices = [], []
        for zone, pts, verts in zip(self.zones, self._points, self._vertices, strict=True):
            if zone.frame is Frame.AIRCRAFT:
                self._airport.append(placement.to_airport_xy(pts))
                self._airport_vertices.append(placement.to_airport_xy(verts))
            else:
                self._airport.append(pts)
                self._airport_vertices.append(verts)
        self._boxes = np.array([(*p.min(axis=0), *p.max(axis=0)) for p in self._airport]).reshape(
            -1, 4
        )

    def sense(
        self, pose_a: Pose2, placement: AircraftPlacement
    ) -> tuple[FloatArray, list[ZoneWall]]:
        """Virtual points (M, 2) in R within ``radius`` of the robot, and the walls."""
        self._in_airport(placement)
        parts: list[FloatArray] = []
        walls: list[ZoneWall] = []
        boxes, r = self._boxes, self.radius
        near_box = (
            (boxes[:, 0] - r <= pose_a.x)
            & (pose_a.x <= boxes[:, 2] + r)
            & (boxes[:, 1] - r <= pose_a.y)
            & (pose_a.y <= boxes[:, 3] + r)
        )
        if not near_box.any():
            return np.zeros((0, 2)), walls
        inverse = pose_a.inverse()
        r2 = r * r
        for k in np.flatnonzero(near_box).tolist():
            zone, pts_a = self.zones[k], self._airport[k]
            d = pts_a - pose_a.position
            near = np.einsum("ij,ij->i", d, d) <= r2
            if not near.any():
                continue
            local = inverse.apply(pts_a[near])
            parts.append(local)
            clearance = footprint_distances(local, self.length, self.width)
            j = int(np.argmin(clearance))
            nearest = local[j]
            owner = int(self._owners[k][np.flatnonzero(near)[j]])
            verts = self._airport_vertices[k]
            a, b = verts[owner], verts[(owner + 1) % len(verts)]
            ea, eb = inverse.apply(a), inverse.apply(b)
            extent = float(np.max(np.hypot(*(local - nearest).T)))
            walls.append(
                ZoneWall(
                    zone.id,
                    k,
                    (float(nearest[0]), float(nearest[1])),
                    float(clearance[j]),
                    (float(ea[0]), float(ea[1]), float(eb[0]), float(eb[1])),
                    extent,
                )
            )
        points = np.vstack(parts) if parts else np.zeros((0, 2))
        return points, walls
