"""Both laser scans -> :class:`Obstacles`: r_c, tracked obstacles, virtual zone walls.

The thesis's obstacle pipeline (Algorithm 2.1, seed lines 780-830) over the laws in
:mod:`behaviours.laws.laser_clusters` (clean, cluster, RANSAC line/circle) and
:mod:`behaviours.laws.tracking` (constant-velocity Kalman tracks with danger levels),
run on *every* new scan of each scanner (the thesis processed 20 Hz of its 50 Hz data):
a scan enters the pipeline once, the tick it first appears.

Returns near the footprint are remembered in that frame while they lie in the lasers'
blind pockets beside the body (:mod:`behaviours.laws.blind_spots`: ``Obstacles.hidden``).

Tracks live in an odometry frame integrated here from the wheels and the IMU: continuous
by construction (REP-105's ``odom``), so a GPS fix or a registration that corrects the
pose estimate never shows up as a jump in every obstacle's velocity.

r_c, the e-stop's distance, is measured on every raw return of the latest scans (no
cleaning: the e-stop must not wait for a cluster to be confirmed). Forbidden zones near
the robot are injected as virtual points and as ``zone`` obstacles
(:mod:`behaviours.laws.zones`, seed lines 3596-3620); they count for avoidance
(:attr:`Obstacles.closest_any`), not for the e-stop.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np
import py_trees

from behaviours.base import Node
from behaviours.keys import OBSTACLES, POSE, SENSOR_FRAME
from behaviours.laws.blind_spots import BlindSpotMemory
from behaviours.laws.laser_clusters import ScanClusterer
from behaviours.laws.localisation import wheel_odometry
from behaviours.laws.obstacles import closest_obstacle, scan_to_robot
from behaviours.laws.tracking import DangerParams, ObstacleTracker, danger_level
from behaviours.laws.zones import VirtualWalls, ZoneWall
from executive.core.frames import Pose2, wrap_angle
from executive.core.model import ForbiddenZone, Platform
from executive.core.records import (
    Danger,
    LaserScan,
    Obstacles,
    PoseEstimate,
    SensorFrame,
    TrackedObstacle,
)

_NO_COVARIANCE = np.zeros((4, 4))


class SenseObstacles(Node):
    """Merge the scans in the robot frame; measure r_c; detect, classify and track."""

    reads = (SENSOR_FRAME, POSE)
    writes = (OBSTACLES,)

    def __init__(
        self,
        platform: Platform,
        zones: Iterable[ForbiddenZone] = (),
        r_oa_trigger: float = 2.5,
        name: str = "sense obstacles",
    ) -> None:
        super().__init__(name)
        self.platform = platform
        self.mounts = {
            lid: Pose2(spec.mount[0], spec.mount[1], spec.mount_yaw)
            for lid, spec in platform.lasers.items()
        }
        self.clusterer = ScanClusterer(platform.length, platform.width)
        self.tracker = ObstacleTracker(
            DangerParams(platform.length, platform.width, r_oa_trigger=r_oa_trigger)
        )
        self.danger = self.tracker.danger
        self.walls = VirtualWalls(zones, platform.length, platform.width)
        self.blind_spots = BlindSpotMemory(
            platform.lasers.values(), platform.length, platform.width
        )
        self._hidden = np.zeros((0, 2))
        self._seen: dict[str, float] = {}
        self._points: dict[str, tuple[LaserScan, np.ndarray]] = {}
        self._raw = (np.zeros((0, 2)), math.inf, 0.0)
        self._tracks: tuple[TrackedObstacle, ...] = ()
        self._odom = Pose2(0.0, 0.0, 0.0)
        self._odom_stamp: float | None = None
        self._velocity = (0.0, 0.0)
        self.scans_processed = 0

    def _integrate_odometry(self, frame: SensorFrame) -> None:
        """Dead-reckon the continuous odometry frame (eq. 2.1, IMU yaw rate if any)."""
        wheels = frame.wheels
        if wheels is None or wheels.stamp == self._odom_stamp:
            return
        v, omega = wheel_odometry(wheels, self.platform.odometry_track)
        if frame.imu is not None and math.isfinite(frame.imu.yaw_rate):
            omega = frame.imu.yaw_rate
        if self._odom_stamp is not None and math.isfinite(v) and math.isfinite(omega):
            dt = wheels.stamp - self._odom_stamp
            if dt > 0.0:
                o = self._odom
                mid = o.theta + 0.5 * omega * dt
                self._odom = Pose2(
                    o.x + v * dt * math.cos(mid),
                    o.y + v * dt * math.sin(mid),
                    wrap_angle(o.theta + omega * dt),
                )
            self._velocity = (v, omega)
        self._odom_stamp = wheels.stamp

    def _odometry_at(self, stamp: float) -> Pose2:
        """The odometry pose at the scans' ``stamp``, moved from the last wheel reading's
        at the last ``(v, omega)``: the scans and the wheels are sampled at their own rates
        (40 and 50 Hz), and a pose 10 ms off, turning at 0.8 rad/s, shifts a static obstacle
        8 m away by 6 cm, which the tracker would read as motion."""
        if self._odom_stamp is None:
            return self._odom
        dt = stamp - self._odom_stamp
        v, omega = self._velocity
        o = self._odom
        mid = o.theta + 0.5 * omega * dt
        return Pose2(
            o.x + v * dt * math.cos(mid),
            o.y + v * dt * math.sin(mid),
            wrap_angle(o.theta + omega * dt),
        )

    def update(self) -> py_trees.common.Status:
        frame: SensorFrame = self.read(SENSOR_FRAME)
        self._integrate_odometry(frame)
        scans = [(lid, s) for lid, s in frame.scans.items() if lid in self.mounts]
        fresh = [(lid, s) for lid, s in scans if self._seen.get(lid) != s.stamp]
        if fresh:
            robot_points = {lid: self._robot_points(lid, s) for lid, s in scans}
            self._raw = self._closest(list(robot_points.values()))
            stamp = max(s.stamp for _, s in fresh)  # the clusters' stamp
            pose = self._odometry_at(stamp)
            clusters = self.clusterer.detect(
                [(s, self.mounts[lid]) for lid, s in fresh],
                [robot_points[lid] for lid, _ in fresh],
                self.tracker.hints(stamp, pose),
            )
            self._tracks = self.tracker.update(clusters, pose, self._velocity)
            self._hidden = self.blind_spots.update(self._raw[0], pose, self._raw[1])
            for lid, s in scans:
                self._seen[lid] = s.stamp
            self.scans_processed += len(fresh)
        points, r_c, bearing = self._raw
        virtual, walls, closest_virtual = np.zeros((0, 2)), (), math.inf
        pose: PoseEstimate | None = self.read(POSE)
        if pose is not None and pose.placement is not None and self.walls.zones:
            virtual, found = self.walls.sense(pose.pose_a, pose.placement)
            walls = self._wall_tracks(found)
            closest_virtual = min((w.clearance for w in found), default=math.inf)
        self.write(
            OBSTACLES,
            Obstacles(
                frame.stamp,
                r_c,
                bearing,
                points,
                tracks=self._tracks + walls,
                virtual=virtual,
                closest_virtual=closest_virtual,
                hidden=self._hidden,
            ),
        )
        self.feedback_message = (
            f"r_c {r_c:.2f} m, {len(self._tracks)} tracks, {len(walls)} zone walls"
        )
        return py_trees.common.Status.SUCCESS

    def _robot_points(self, lid: str, scan: LaserScan) -> np.ndarray:
        """The returns of laser ``lid``'s ``scan`` in R, computed once per scan (the same
        scan is read again on the ticks before the next one arrives)."""
        cached = self._points.get(lid)
        if cached is not None and cached[0] is scan:
            return cached[1]
        mount = self.mounts[lid]
        points = scan_to_robot(
            scan.ranges, scan.angle_min, scan.angle_increment, scan.range_max, mount
        )
        self._points[lid] = (scan, points)
        return points

    def _closest(self, parts: list[np.ndarray]) -> tuple[np.ndarray, float, float]:
        points = np.vstack(parts) if parts else np.zeros((0, 2))
        r_c, bearing = closest_obstacle(points, self.platform.length, self.platform.width)
        return points, r_c, bearing

    def _wall_tracks(self, walls: list[ZoneWall]) -> tuple[TrackedObstacle, ...]:
        """One static ``zone`` obstacle per wall in range, ids -1, -2, ... by zone."""
        if not walls:
            return ()
        position = np.array([w.nearest for w in walls])
        zeros = np.zeros_like(position)
        extent = np.array([w.extent for w in walls])
        clearance = np.array([w.clearance for w in walls])
        v, omega = self._velocity
        levels = danger_level(
            position, zeros, np.zeros(len(walls)), clearance, v, omega, self.danger
        )
        return tuple(
            TrackedObstacle(
                id=-1 - w.index,
                kind="zone",
                position=w.nearest,
                velocity=(0.0, 0.0),
                covariance=_NO_COVARIANCE,
                size=float(extent[k]),
                clearance=w.clearance,
                age=math.inf,
                danger=Danger(int(levels[k])),
                shape=w.edge,
            )
            for k, w in enumerate(walls)
        )
