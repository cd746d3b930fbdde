"""Time-stamped records that cross the robot seam (ARCHITECTURE.md §3, §8).

A :class:`SensorFrame` is what :meth:`RobotInterface.read` returns: the *latest* reading
of every sensor, each with its own time stamp (sensors run at their own rates, so a
reader can tell how fresh each one is; a sensor that never reported is absent).
A :class:`VelocityCommand` is what :meth:`RobotInterface.send` takes.

Units: SI (m, s, rad). Frames: laser ranges in the scanner's frame, wheel speeds as
ground speeds of each side, yaw rate about +z_R, GPS in the airport frame A, pixel
coordinates (u right, v down) in the camera's output image.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np

from executive.core.frames import FloatArray, Pose2

_EMPTY: Mapping = MappingProxyType({})


def _empty() -> Mapping:
    return field(default_factory=lambda: _EMPTY)  # type: ignore[return-value]


@dataclass(frozen=True, slots=True, eq=False)
class LaserScan:
    """One sweep of a planar scanner: ``ranges[k]`` along ``angle_min + k * angle_increment``.

    Angles are in the scanner frame (x forward of the scanner). A beam with no return
    reads ``range_max``.
    """

    stamp: float
    angle_min: float
    angle_increment: float
    range_max: float
    ranges: FloatArray

    def angles(self) -> FloatArray:
        return self.angle_min + self.angle_increment * np.arange(len(self.ranges))

    def points(self) -> FloatArray:
        """Returns closer than ``range_max`` as (N, 2) points in the scanner frame."""
        ranges = self.ranges
        hit = ranges < self.range_max
        a = self.angles()[hit]
        return np.column_stack((ranges[hit] * np.cos(a), ranges[hit] * np.sin(a)))


@dataclass(frozen=True, slots=True)
class Detection:
    """One feature point seen by a camera: pixel coordinates in the output image."""

    feature: str
    point: int
    u: float
    v: float


@dataclass(frozen=True, slots=True)
class CameraFrame:
    """The detections of one camera image taken at ``stamp``."""

    stamp: float
    detections: tuple[Detection, ...] = ()


@dataclass(frozen=True, slots=True)
class PanTilt:
    """Angles of a pan-tilt unit (rad) at ``stamp``."""

    stamp: float
    pan: float
    tilt: float


@dataclass(frozen=True, slots=True)
class WheelSpeeds:
    """Measured ground speed of the left and right wheels (m/s)."""

    stamp: float
    left: float
    right: float


@dataclass(frozen=True, slots=True)
class ImuReading:
    """Yaw rate about +z_R (rad/s)."""

    stamp: float
    yaw_rate: float


@dataclass(frozen=True, slots=True)
class GpsFix:
    """A position fix in the airport frame A with its 1-sigma horizontal error (m)."""

    stamp: float
    x: float
    y: float
    sigma: float


@dataclass(frozen=True, slots=True)
class Bumpers:
    """Front and rear bumper switches."""

    stamp: float
    front: bool = False
    rear: bool = False

    @property
    def any(self) -> bool:
        return self.front or self.rear


@dataclass(frozen=True, slots=True)
class SensorFrame:
    """The latest reading of every sensor at time ``stamp``.

    ``gps`` is None while there is no fix. Mappings are keyed by sensor id: lasers
    (``front``, ``rear``), cameras (``front-left``, ``front-right``, ``rear-left``,
    ``rear-right``, ``ptz``) and pan-tilt units (the platform camera ids).
    """

    stamp: float
    scans: Mapping[str, LaserScan] = _empty()
    cameras: Mapping[str, CameraFrame] = _empty()
    pan_tilt: Mapping[str, PanTilt] = _empty()
    wheels: WheelSpeeds | None = None
    imu: ImuReading | None = None
    gps: GpsFix | None = None
    bumpers: Bumpers = field(default_factory=lambda: Bumpers(0.0))


@dataclass(frozen=True, slots=True)
class PanTiltRate:
    """Commanded pan and tilt rates (rad/s) of one pan-tilt unit."""

    pan: float = 0.0
    tilt: float = 0.0


@dataclass(frozen=True, slots=True)
class VelocityCommand:
    """The control vector q = (v, omega, pan/tilt rates per unit), thesis §3.2.

    ``v`` forward speed (m/s), ``omega`` yaw rate (rad/s) about +z_R.
    """

    v: float = 0.0
    omega: float = 0.0
    pan_tilt: Mapping[str, PanTiltRate] = _empty()

    @staticmethod
    def stop() -> VelocityCommand:
        return VelocityCommand()

    @property
    def is_stop(self) -> bool:
        return (
            self.v == 0.0
            and self.omega == 0.0
            and all(r.pan == 0.0 and r.tilt == 0.0 for r in self.pan_tilt.values())
        )


# -- executive state on the blackboard ------------------------------------------------------------
@dataclass(frozen=True, slots=True, eq=False)
class PoseEstimate:
    """The robot's estimated pose at ``stamp``.

    ``pose_a`` in the airport frame with its 3x3 ``covariance`` (x, y, theta); ``pose_f``
    the same pose in the aircraft frame, through the executive's current idea of where
    the aircraft stands; ``confidence`` in [0, 1] summarises the covariance (1: sure).
    """

    stamp: float
    pose_a: Pose2
    covariance: FloatArray
    pose_f: Pose2
    confidence: float
    sources: tuple[str, ...] = ()


@dataclass(frozen=True, slots=True, eq=False)
class Obstacles:
    """What the lasers see around the robot at ``stamp``.

    ``closest`` is r_c: the distance from the robot's footprint (not its centre) to the
    nearest laser return, ``inf`` when there is none; ``bearing`` its direction in the
    robot frame; ``points`` every return of both scanners in the robot frame (N, 2).
    """

    stamp: float
    closest: float
    bearing: float
    points: FloatArray


@dataclass(frozen=True, slots=True)
class FeatureObservations:
    """Feature points seen by each camera at ``stamp``: camera id -> detections."""

    stamp: float
    by_camera: Mapping[str, tuple[Detection, ...]] = _empty()

    def visible(self, feature: str, camera_prefix: str = "") -> bool:
        return any(
            d.feature == feature
            for cam, dets in self.by_camera.items()
            if cam.startswith(camera_prefix)
            for d in dets
        )


@dataclass(frozen=True, slots=True)
class OperatorRequests:
    """What the operator asks for: reset a latched e-stop, take over, or abort."""

    reset_estop: bool = False
    take_over: bool = False
    abort: bool = False
