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

from collections.abc import Sequence

import numpy as np
import shapely
from shapely.geometry import Point
from shapely.geometry import Polygon as ShapelyPolygon
from shapely.ops import unary_union

from executive.core.frames import AircraftPlacement, Pose2
from executive.core.model import LaserSpec, Polygon
from executive.core.records import GpsFix, ImuReading, LaserScan, WheelSpeeds
from sim2d.raycast import Scene, cast_scan, cast_scans
from sim2d.scenario import GpsConditions


class LaserSensor:
    """A scanner at ``spec.mount`` facing ``spec.mount_yaw`` on the robot."""

    def __init__(self, spec: LaserSpec, sigma: float, rng: np.random.Generator) -> None:
        self.spec = spec
        self.sigma = sigma
        self.rng = rng
        self.n = spec.beam_count
        self.angle_min = -spec.fov / 2.0
        self._mount = Pose2(spec.mount[0], spec.mount[1], spec.mount_yaw)
        #: the scans it makes: angle_min, resolution, beam count, range
        self.model = (self.angle_min, spec.resolution, self.n, spec.range)

    def pose_in_world(self, robot: Pose2) -> Pose2:
        return robot @ self._mount

    def scan(self, scene: Scene, robot: Pose2, stamp: float) -> LaserScan:
        return scan_lasers((self,), scene, robot, stamp)[0]


def scan_lasers(
    lasers: Sequence[LaserSensor], scene: Scene, robot: Pose2, stamp: float
) -> list[LaserScan]:
    """The scans of several lasers of one robot, as ``[laser.scan(...) for laser in
    lasers]`` (each laser draws its own noise), with the ranges of lasers of one
    :attr:`~LaserSensor.model` (the usual front and rear pair) cast in one batch."""
    if not lasers:
        return []
    model = lasers[0].model
    if any(laser.model != model for laser in lasers):
        return [scan for laser in lasers for scan in scan_lasers((laser,), scene, robot, stamp)]
    poses = [robot @ laser._mount for laser in lasers]
    if len(lasers) == 1:
        ranges = cast_scan(scene, (poses[0].x, poses[0].y), poses[0].theta, *model)[None]
    else:
        ranges = cast_scans(scene, [(p.x, p.y) for p in poses], [p.theta for p in poses], *model)
    noisy = [k for k, laser in enumerate(lasers) if laser.sigma > 0.0]
    if noisy:
        # Noise on the returns only, kept within [0, range_max): drawn for every beam
        # (each laser's n values) and copied where there is a return.
        range_max = model[3]
        noise = np.empty((len(noisy), model[2]))
        for row, k in zip(noise, noisy, strict=True):
            row[:] = lasers[k].rng.normal(0.0, lasers[k].sigma, model[2])
        target = ranges if len(noisy) == len(lasers) else ranges[noisy]
        noise += target
        np.maximum(noise, 0.0, out=noise)
        np.minimum(noise, range_max - 1e-6, out=noise)
        np.copyto(target, noise, where=target < range_max)
        if target is not ranges:
            ranges[noisy] = target
    return [
        LaserScan(stamp, laser.angle_min, laser.spec.resolution, laser.spec.range, row)
        for laser, row in zip(lasers, ranges, strict=True)
    ]


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
    n_seg = scene.n_segments
    if n_seg:
        seg = scene.segments
        a = seg[:, :2] - o  # (S, 2)
        e = seg[:, 2:] - seg[:, :2]
        dx, dy = d[:, 0, None], d[:, 1, None]  # (M, 1)
        ex, ey = e[:, 0], e[:, 1]  # (S,)
        ax, ay = a[:, 0], a[:, 1]
        denom = dx * ey - dy * ex  # (M, S)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):  # parallel: t = inf
            t = (ax * ey - ay * ex) / denom
            u = (ax * dy - ay * dx) / denom
            crosses = (t > 0.0) & (t < 1.0) & (u >= 0.0) & (u <= 1.0)
            z = zo + dz[:, None] * t
        crosses &= z < heights[scene.segment_owner]
        np.logical_or.reduce(crosses, axis=1, out=blocked)
    if scene.n_circles:
        c = scene.centers - o  # (K, 2)
        dd = np.maximum(np.einsum("ij,ij->i", d, d), 1e-12)
        t = (d @ c.T) / dd[:, None]  # (M, K): closest approach, clipped to [0, 1]
        np.maximum(t, 0.0, out=t)
        np.minimum(t, 1.0, out=t)
        px = d[:, 0, None] * t - c[:, 0]
        py = d[:, 1, None] * t - c[:, 1]
        radii = scene.radii
        inside = px * px + py * py < radii * radii
        inside &= t < 1.0
        inside &= zo + dz[:, None] * t < heights[scene.circle_owner]
        blocked |= np.logical_or.reduce(inside, axis=1)
    return blocked
