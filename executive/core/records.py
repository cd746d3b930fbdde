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

import math
from collections.abc import Hashable, Mapping
from dataclasses import dataclass, field
from enum import IntEnum, StrEnum
from types import MappingProxyType

import numpy as np
from numpy.typing import NDArray

from executive.core.frames import AircraftPlacement, FloatArray, Pose2
from executive.core.model import CameraKind, Platform

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
    """The detections of one camera image taken at ``stamp``.

    ``image`` identifies the captured image when the camera says (an exposure counter or
    a checksum of the pixels): a live camera never delivers the same image twice, a
    frozen pipeline repeats it, whatever stamp it puts on it. None: not known.
    """

    stamp: float
    detections: tuple[Detection, ...] = ()
    image: int | None = None

    @property
    def content(self) -> Hashable | None:
        """What tells this image from the previous one, for freshness: its identity and
        detections; without an identity its detections, None when there are none (a
        camera that sees nothing is no evidence of a frozen one)."""
        if self.image is not None:
            return (self.image, self.detections)
        return self.detections or None


@dataclass(frozen=True, slots=True)
class PanTilt:
    """Angles of a pan-tilt unit (rad) at ``stamp``."""

    stamp: float
    pan: float
    tilt: float


@dataclass(frozen=True, slots=True)
class WheelSpeeds:
    """Measured ground speed of the left and right wheels (m/s); ``travel`` the base's
    odometers (left, right, m) at ``stamp`` when it reports them (a real base's encoder
    counts: they go on counting while the executive is down, so a restarted run knows how
    far the robot moved meanwhile, :func:`behaviours.laws.localisation.arc_motion`)."""

    stamp: float
    left: float
    right: float
    travel: tuple[float, float] | None = None


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


@dataclass(frozen=True, slots=True, eq=False)
class CeilingImage:
    """One image of the upward (ceiling) camera taken at ``stamp``: H x W grey levels,
    u along the image's columns, v along its rows (docs/ceiling-navigation.md; seed 002
    §2)."""

    stamp: float
    image: NDArray[np.uint8]


@dataclass(frozen=True, slots=True)
class SensorFrame:
    """The latest reading of every sensor at time ``stamp``.

    ``gps`` is None while there is no fix; ``ceiling`` the latest upward image (None
    when the platform has no upward camera or it has sent no image yet). Mappings are
    keyed by sensor id: lasers (``front``, ``rear``), cameras (``front-left``,
    ``front-right``, ``rear-left``, ``rear-right``, ``ptz``) and pan-tilt units (the
    platform camera ids).
    """

    stamp: float
    scans: Mapping[str, LaserScan] = _empty()
    cameras: Mapping[str, CameraFrame] = _empty()
    pan_tilt: Mapping[str, PanTilt] = _empty()
    wheels: WheelSpeeds | None = None
    imu: ImuReading | None = None
    gps: GpsFix | None = None
    bumpers: Bumpers = field(default_factory=lambda: Bumpers(0.0))
    ceiling: CeilingImage | None = None


def camera_ids(platform: Platform, unit: str) -> tuple[str, ...]:
    """The cameras of platform camera unit ``unit`` as :attr:`SensorFrame.cameras` names
    them: ``<unit>-left`` and ``<unit>-right`` for a stereo unit, ``<unit>`` otherwise."""
    if platform.cameras[unit].kind is CameraKind.STEREO:
        return (f"{unit}-left", f"{unit}-right")
    return (unit,)


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
class FrameReference(StrEnum):
    """What the robot's pose in the aircraft frame F is anchored to (seed lines 1030-1040).

    ``nominal``: the mission's parking pose (no registration yet); ``aircraft``: a recent
    laser registration of the aircraft; ``checkpoint``: registration lost, the pose is
    carried by odometry from the last checkpoint reached (the thesis's back-up frame).
    """

    NOMINAL = "nominal"
    AIRCRAFT = "aircraft"
    CHECKPOINT = "checkpoint"


@dataclass(frozen=True, slots=True, eq=False)
class RegistrationRecord:
    """One attempt to register the aircraft from the laser returns.

    ``stamp`` is when the result was used (the pose estimate's time) and ``scan_stamp``
    the scans' time; ``method`` is ``global`` (RANSAC then ICP) or ``icp`` (tracking
    refinement); ``pose_f`` the measured robot pose in F carried forward by odometry from
    ``scan_stamp`` to ``stamp``, with its 3x3 ``covariance``; ``rms`` (m) and
    ``inlier_fraction`` the fit quality; ``accepted`` whether the pose filter took it and
    ``reason`` why not (or what it did: ``update``, ``reset``).
    """

    stamp: float
    scan_stamp: float
    method: str
    pose_f: Pose2 | None
    covariance: FloatArray | None
    rms: float
    inlier_fraction: float
    accepted: bool
    reason: str = ""


@dataclass(frozen=True, slots=True, eq=False)
class PoseEstimate:
    """The robot's estimated pose at ``stamp``.

    ``pose_a`` in the airport frame with its 3x3 ``covariance`` (x, y, theta); ``pose_f``
    the same pose in the aircraft frame, through the executive's current estimate of where
    the aircraft stands (``placement``), with its own 3x3 ``covariance_f``; ``confidence``
    in [0, 1] summarises the covariance in A, ``confidence_f`` the one in F (1: sure).
    ``reference`` says what ``pose_f`` is anchored to and ``anchor`` names it (the
    checkpoint id when the reference is the last checkpoint); ``registration`` is the
    latest laser registration attempt.
    """

    stamp: float
    pose_a: Pose2
    covariance: FloatArray
    pose_f: Pose2
    confidence: float
    sources: tuple[str, ...] = ()
    placement: AircraftPlacement | None = None
    covariance_f: FloatArray | None = None
    confidence_f: float = 1.0
    reference: FrameReference = FrameReference.NOMINAL
    anchor: str = ""
    registration: RegistrationRecord | None = None

    @property
    def sigma_f(self) -> float | None:
        """The estimate's own position uncertainty in F (m): the square root of the trace
        of the position block of ``covariance_f``; None when it has none."""
        cov = self.covariance_f
        if cov is None:
            return None
        value = float(cov[0, 0] + cov[1, 1])
        return math.sqrt(value) if math.isfinite(value) and value >= 0.0 else None


class Danger(IntEnum):
    """How much a tracked obstacle matters to the robot (ordered: higher is worse).

    ``NONE``: far and not on the path; ``NEAR``: within the avoidance trigger distance
    but not on the path; ``ON_PATH``: its predicted motion crosses the robot's swept
    corridor within the horizon; ``IMMINENT``: on the path with a time to contact shorter
    than the imminence threshold.
    """

    NONE = 0
    NEAR = 1
    ON_PATH = 2
    IMMINENT = 3


@dataclass(frozen=True, slots=True, eq=False)
class TrackedObstacle:
    """One obstacle tracked across scans, in the robot frame R at the record's stamp.

    ``kind``: ``line``, ``circle`` or ``blob`` (laser clusters, RANSAC-classified), or
    ``zone`` (a forbidden zone's edge injected as a virtual obstacle). ``position`` is the
    tracked point (circle centre, or centroid) and ``velocity`` the ground velocity, both
    expressed in R's axes; ``covariance`` the 4x4 covariance of (x, y, vx, vy).
    ``size`` is the radius of a circle enclosing the cluster, ``clearance`` the distance
    from the robot's footprint to its nearest point, ``age`` the time since it was first
    seen (s). ``shape`` holds the fitted parameters in R: (cx, cy, r) for a circle,
    (x0, y0, x1, y1) for a line's end points, () otherwise. ``motion_measured``: the
    velocity was measured on both axes lately (within the tracker's
    ``unseen_motion_time``): a view of the whole object, or for a line its two true ends
    in consecutive scans; a line followed only in part has its motion along itself
    unmeasured (:func:`behaviours.laws.obstacles.vouched_velocity`).
    """

    id: int
    kind: str
    position: tuple[float, float]
    velocity: tuple[float, float]
    covariance: FloatArray
    size: float
    clearance: float
    age: float
    danger: Danger = Danger.NONE
    shape: tuple[float, ...] = ()
    motion_measured: bool = False

    @property
    def speed(self) -> float:
        return math.hypot(*self.velocity)


@dataclass(frozen=True, slots=True, eq=False)
class Obstacles:
    """What the lasers see around the robot at ``stamp``.

    ``closest`` is r_c: the distance from the robot's footprint (not its centre) to the
    nearest laser return, ``inf`` when there is none; ``bearing`` its direction in the
    robot frame; ``points`` every return of both scanners in the robot frame (N, 2).
    ``tracks`` the tracked obstacles (real ones and forbidden-zone edges, kind ``zone``);
    ``virtual`` the zone-edge points injected near the robot (M, 2) in R, and
    ``closest_virtual`` their distance from the footprint. The e-stop uses ``closest``
    (real returns only: a virtual wall never moves away, so it must not latch the e-stop);
    avoidance uses :attr:`closest_any`. ``hidden``: returns remembered where the lasers
    cannot see now (the pockets beside the body, :mod:`behaviours.laws.blind_spots`), in
    R (K, 2); they count only for what a turn would sweep (the arc retreat).
    """

    stamp: float
    closest: float
    bearing: float
    points: FloatArray
    tracks: tuple[TrackedObstacle, ...] = ()
    virtual: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    closest_virtual: float = math.inf
    hidden: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))

    @property
    def closest_any(self) -> float:
        """min(r_c, closest virtual point): what obstacle avoidance reacts to."""
        return min(self.closest, self.closest_virtual)


@dataclass(frozen=True, slots=True)
class FeatureObservations:
    """Feature points seen by each camera at ``stamp``: camera id -> detections.

    Only fresh images are in ``by_camera``; ``stale`` names the cameras whose image is
    stale (no new image, or the same one repeated, for longer than their limit): what
    they show is not evidence of anything now.
    """

    stamp: float
    by_camera: Mapping[str, tuple[Detection, ...]] = _empty()
    stale: tuple[str, ...] = ()

    def visible(self, feature: str, camera_prefix: str = "") -> bool:
        return any(
            d.feature == feature
            for cam, dets in self.by_camera.items()
            if cam.startswith(camera_prefix)
            for d in dets
        )


@dataclass(frozen=True, slots=True)
class JoystickCommand:
    """The operator's virtual joystick (the HUD, issue 15): the speed (m/s) and turn rate
    (rad/s) asked for, ``stamp`` when it reached the executive (runtime clock). A
    dead-man: the stream must keep coming, a stale one stops the robot."""

    stamp: float
    v: float
    omega: float


@dataclass(frozen=True, slots=True)
class FollowRequest:
    """Collaborative mode (seed 000 Table 2.3, lines 1379-1452): follow the person the
    operator designated at ``(x, y)`` in the airport frame A (a tap on the HUD's top view)
    at ``distance`` (m); ``stamp`` when it was asked (runtime clock)."""

    stamp: float
    x: float
    y: float
    distance: float = 1.5


@dataclass(frozen=True, slots=True)
class OperatorRequests:
    """What the operator asks for: reset a latched e-stop, take over, or abort; with the
    HUD (issue 15) also an e-stop of their own (latched until ``reset_estop``), the
    joystick while they have the robot, a person to follow, and the answer to the
    question the run asked (``"wait"``, ``"take-over"`` or ``"skip"``; one-shot)."""

    reset_estop: bool = False
    take_over: bool = False
    abort: bool = False
    estop: bool = False
    joystick: JoystickCommand | None = None
    follow: FollowRequest | None = None
    answer: str | None = None
