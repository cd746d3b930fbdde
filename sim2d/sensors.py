"""Simulated sensors of sim2d, each sampled at its own rate by :class:`sim2d.robot.SimRobot`.

* :class:`LaserSensor` — a planar scanner at its mounting pose, vectorised ray casting
  (:mod:`sim2d.raycast`) against the world scene, Gaussian range noise, max-range returns.
* :class:`WheelEncoders` — ground speed of each side as the motor controllers achieve it
  (the body moves less: slip), plus noise.
* :class:`Imu` — true yaw rate plus a constant bias and noise.
* :class:`Gps` — position fix with noise; degraded within ``shadow_margin`` of the edge of
  the aircraft's overhead outline, lost deeper under it, lost everywhere indoors.
"""

from __future__ import annotations

import numpy as np
import shapely
from shapely.geometry import Point
from shapely.geometry import Polygon as ShapelyPolygon
from shapely.ops import unary_union

from executive.core.frames import AircraftPlacement, Pose2
from executive.core.model import LaserSpec, Polygon
from executive.core.records import GpsFix, ImuReading, LaserScan, WheelSpeeds
from sim2d.raycast import Scene, cast_scan
from sim2d.scenario import GpsConditions


class LaserSensor:
    """A scanner at ``spec.mount`` facing ``spec.mount_yaw`` on the robot."""

    def __init__(self, spec: LaserSpec, sigma: float, rng: np.random.Generator) -> None:
        self.spec = spec
        self.sigma = sigma
        self.rng = rng
        self.n = spec.beam_count
        self.angle_min = -spec.fov / 2.0
        self._buffer = np.empty(self.n)

    def pose_in_world(self, robot: Pose2) -> Pose2:
        return robot @ Pose2(self.spec.mount[0], self.spec.mount[1], self.spec.mount_yaw)

    def scan(self, scene: Scene, robot: Pose2, stamp: float) -> LaserScan:
        pose = self.pose_in_world(robot)
        ranges = cast_scan(
            scene,
            (pose.x, pose.y),
            pose.theta,
            self.angle_min,
            self.spec.resolution,
            self.n,
            self.spec.range,
            out=self._buffer,
        ).copy()
        hit = ranges < self.spec.range
        if self.sigma > 0.0:
            noise = self.rng.normal(0.0, self.sigma, self.n)
            ranges[hit] = np.clip(ranges[hit] + noise[hit], 0.0, self.spec.range - 1e-6)
        return LaserScan(stamp, self.angle_min, self.spec.resolution, self.spec.range, ranges)


class WheelEncoders:
    def __init__(self, sigma: float, rng: np.random.Generator) -> None:
        self.sigma = sigma
        self.rng = rng

    def read(self, left: float, right: float, stamp: float) -> WheelSpeeds:
        noise = self.rng.normal(0.0, self.sigma, 2) if self.sigma > 0 else (0.0, 0.0)
        return WheelSpeeds(stamp, left + float(noise[0]), right + float(noise[1]))


class Imu:
    def __init__(self, sigma: float, bias_sigma: float, rng: np.random.Generator) -> None:
        self.sigma = sigma
        self.rng = rng
        self.bias = float(rng.normal(0.0, bias_sigma)) if bias_sigma > 0 else 0.0

    def read(self, yaw_rate: float, stamp: float) -> ImuReading:
        noise = float(self.rng.normal(0.0, self.sigma)) if self.sigma > 0 else 0.0
        return ImuReading(stamp, yaw_rate + self.bias + noise)


class Gps:
    """GPS with the aircraft's overhead outline as its sky mask."""

    DEGRADED_GAIN = 15.0
    """How much the noise grows from the outline's edge to ``shadow_margin`` inside it."""

    def __init__(
        self,
        conditions: GpsConditions,
        sigma: float,
        outline: tuple[Polygon, ...],
        placement: AircraftPlacement,
        rng: np.random.Generator,
    ) -> None:
        self.conditions = conditions
        self.sigma = sigma
        self.rng = rng
        shadows = [
            ShapelyPolygon(placement.to_airport_xy(np.array(p.points))).buffer(0) for p in outline
        ]
        self.shadow = unary_union(shadows) if shadows else ShapelyPolygon()
        shapely.prepare(self.shadow)
        self.boundary = self.shadow.boundary

    def depth_under_outline(self, x: float, y: float) -> float:
        """How far inside the overhead outline (m); 0 outside it."""
        point = Point(x, y)
        if not self.shadow.contains(point):
            return 0.0
        return float(self.boundary.distance(point))

    def sigma_at(self, x: float, y: float) -> float | None:
        """Noise of a fix at (x, y), or None where there is no fix."""
        if self.conditions.denied:
            return None
        depth = self.depth_under_outline(x, y)
        margin = self.conditions.shadow_margin
        if depth <= 0.0:
            return self.sigma
        if depth >= margin:
            return None
        return self.sigma * (1.0 + self.DEGRADED_GAIN * depth / max(margin, 1e-9))

    def read(self, robot: Pose2, stamp: float) -> GpsFix | None:
        sigma = self.sigma_at(robot.x, robot.y)
        if sigma is None:
            return None
        dx, dy = self.rng.normal(0.0, sigma, 2) if sigma > 0 else (0.0, 0.0)
        return GpsFix(stamp, robot.x + float(dx), robot.y + float(dy), max(sigma, 1e-3))


def sight_lines_blocked(
    scene: Scene, heights: np.ndarray, origin: np.ndarray, targets: np.ndarray
) -> np.ndarray:
    """Which lines of sight from ``origin`` (3,) to ``targets`` (M, 3) an occluder blocks.

    An occluder (a segment or circle of ``scene``, with the height of its owner) blocks a
    line of sight when the line crosses it in plan view at a point where the line is
    lower than the occluder. Every occluder is tested, not just the first one crossed: a
    low cone in front does not hide a tall truck behind it. Plain broadcasting over
    (lines x occluders): a camera frame has a few dozen candidate points and the apron a
    few dozen occluders, where a beam-sorting ray caster would cost more in fixed overhead.
    """
    blocked = np.zeros(len(targets), dtype=bool)
    if len(targets) == 0:
        return blocked
    o = origin[:2]
    d = targets[:, :2] - o  # (M, 2)
    zo, dz = origin[2], targets[:, 2] - origin[2]
    owners = np.concatenate((scene.segment_owner, scene.circle_owner))
    seg = scene.segments
    if len(seg):
        a = seg[:, :2] - o  # (S, 2)
        e = seg[:, 2:] - seg[:, :2]
        denom = d[:, None, 0] * e[None, :, 1] - d[:, None, 1] * e[None, :, 0]  # (M, S)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):  # parallel: t = inf
            t = (a[None, :, 0] * e[None, :, 1] - a[None, :, 1] * e[None, :, 0]) / denom
            u = (a[None, :, 0] * d[:, None, 1] - a[None, :, 1] * d[:, None, 0]) / denom
            crosses = (t > 0.0) & (t < 1.0) & (u >= 0.0) & (u <= 1.0)
            z = zo + dz[:, None] * t
        tall = heights[owners[: len(seg)]][None, :]
        blocked |= np.any(crosses & (z < tall), axis=1)
    centers = scene.centers
    if len(centers):
        c = centers - o  # (K, 2)
        dd = np.maximum(np.einsum("ij,ij->i", d, d), 1e-12)
        t = np.clip((d @ c.T) / dd[:, None], 0.0, 1.0)  # (M, K): closest approach
        px = d[:, None, 0] * t - c[None, :, 0]
        py = d[:, None, 1] * t - c[None, :, 1]
        inside = px * px + py * py < scene.radii[None, :] ** 2
        z = zo + dz[:, None] * t
        tall = heights[owners[len(seg) :]][None, :]
        blocked |= np.any(inside & (t < 1.0) & (z < tall), axis=1)
    return blocked
