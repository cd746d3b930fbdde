"""The mission model: immutable dataclasses in SI units (m, s, rad).

An :class:`Aircraft` describes a type (footprint, outline, features, inspection items) in
the aircraft frame F; a :class:`Mission` adds the robot platform, safety radii, the
airport (station, parking pose, forbidden zones), routes and ordered checkpoints. Models
are built only by :mod:`executive.core.loader`, after every check passed.

Entities that a later stage may need to blame carry ``where``: the file and line they
were read from (compile errors name them). ``where`` does not take part in equality.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path

import numpy as np

from executive.core.frames import AircraftPlacement, FloatArray, Pose2
from executive.core.problems import SourceLocation


class ServoMethod(StrEnum):
    """Visual-servoing method: image-based, position-based, or chosen by distance."""

    IBVS = "ibvs"
    PBVS = "pbvs"
    AUTO = "auto"


class InspectionMethod(StrEnum):
    VISUAL = "visual"
    SCAN_3D = "3d-scan"


class CameraKind(StrEnum):
    STEREO = "stereo"
    MONO = "mono"
    PTZ = "ptz"


class ZoneKind(StrEnum):
    REFUELLING = "refuelling"
    ENGINE_DANGER = "engine-danger"
    APU_EXHAUST = "apu-exhaust"
    VEHICLE_PARKING = "vehicle-parking"
    EQUIPMENT = "equipment"
    NO_GO = "no-go"


class Frame(StrEnum):
    """The frame a mission position is expressed in."""

    AIRPORT = "airport"
    AIRCRAFT = "aircraft"


class TurnMode(StrEnum):
    """Go-to-goal: turn then move (align-first), or turn while moving."""

    ALIGN_FIRST = "align-first"
    SIMULTANEOUS = "simultaneous"


_NOWHERE = SourceLocation("<built>")


# -- geometry ----------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class Circle:
    """A disc in a 2D frame."""

    id: str
    cx: float
    cy: float
    radius: float

    def vertices(self, segments: int = 32) -> FloatArray:
        """A polygonal approximation (for drawing), counter-clockwise."""
        t = np.linspace(0.0, 2.0 * math.pi, segments, endpoint=False)
        return np.column_stack(
            (self.cx + self.radius * np.cos(t), self.cy + self.radius * np.sin(t))
        )


@dataclass(frozen=True, slots=True)
class Polygon:
    """A simple polygon in a 2D frame, as a tuple of (x, y) vertices (not closed)."""

    id: str
    points: tuple[tuple[float, float], ...]

    def vertices(self, segments: int = 0) -> FloatArray:
        del segments
        return np.array(self.points, dtype=float)


Shape = Circle | Polygon


@dataclass(frozen=True, slots=True)
class Point3:
    x: float
    y: float
    z: float

    def array(self) -> FloatArray:
        return np.array([self.x, self.y, self.z])


# -- aircraft -----------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class Dimensions:
    length: float
    span: float
    height: float
    fuselage_width: float


@dataclass(frozen=True, slots=True)
class Feature:
    """A visual feature: 3D points in F (z down), detection range, preferred servo method."""

    id: str
    kind: str
    points: tuple[Point3, ...]
    detection_range: float
    servo: ServoMethod
    normal: Point3 | None = None
    where: SourceLocation = field(default=_NOWHERE, compare=False, repr=False)

    def centroid(self) -> FloatArray:
        return np.mean([p.array() for p in self.points], axis=0)


@dataclass(frozen=True, slots=True)
class InspectionItem:
    id: str
    feature: str
    method: InspectionMethod
    description: str = ""
    where: SourceLocation = field(default=_NOWHERE, compare=False, repr=False)


@dataclass(frozen=True, slots=True)
class Aircraft:
    """An aircraft type in its own frame F."""

    type: str
    origin_height: float
    dimensions: Dimensions
    footprint: tuple[Shape, ...]
    outline: tuple[Polygon, ...]
    features: Mapping[str, Feature]
    items: Mapping[str, InspectionItem]
    description: str = ""
    source: str = ""

    def feature_of(self, item_id: str) -> Feature:
        return self.features[self.items[item_id].feature]


# -- mission --------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class CameraSpec:
    """A camera on a pan-tilt unit; mount pose in R, angles in rad, rates in rad/s."""

    id: str
    kind: CameraKind
    mount: tuple[float, float, float]
    mount_yaw: float
    width_px: int
    height_px: int
    pixel_size: float
    focal_length: float
    image_width_px: int
    image_height_px: int
    pan_limits: tuple[float, float]
    tilt_limits: tuple[float, float]
    pan_rate: float
    tilt_rate: float
    rate_hz: float
    baseline: float | None = None
    where: SourceLocation = field(default=_NOWHERE, compare=False, repr=False)

    @property
    def horizontal_fov(self) -> float:
        """Of the output image (the same as the sensor's: downscaling keeps the width's)."""
        return 2.0 * math.atan(self.image_width_px / (2.0 * self.focal_px))

    @property
    def vertical_fov(self) -> float:
        """Of the output image (a downscale to another aspect ratio crops vertically)."""
        return 2.0 * math.atan(self.image_height_px / (2.0 * self.focal_px))

    @property
    def focal_px(self) -> float:
        """Focal length in pixels of the (possibly downscaled) output image."""
        return self.focal_length / self.pixel_size * self.image_width_px / self.width_px


@dataclass(frozen=True, slots=True)
class LaserSpec:
    """A planar laser scanner: mount pose in R, field of view and resolution in rad."""

    id: str
    mount: tuple[float, float, float]
    mount_yaw: float
    fov: float
    resolution: float
    range: float
    rate_hz: float
    where: SourceLocation = field(default=_NOWHERE, compare=False, repr=False)

    @property
    def beam_count(self) -> int:
        """Returns per scan, both ends included (1081 for 270 deg in 0.25 deg steps)."""
        return round(self.fov / self.resolution) + 1


@dataclass(frozen=True, slots=True)
class CeilingCameraSpec:
    """The upward-looking camera of ceiling navigation (issue 17, seed 002 §2): a pinhole
    with its optical axis straight up at ``(mount_x, mount_y)`` in R, ``mount_z`` above
    the floor, turned by ``mount_yaw`` (rad) about the vertical; ``hfov`` (rad) across
    ``width_px`` square pixels; ``rate_hz`` images a second.

    Image axes as in :mod:`sim2d.ceiling`: the top of the image is the camera's forward,
    u grows towards its left (docs/ceiling-navigation.md). ``fx``, ``fy``, ``cx``, ``cy``
    are the intrinsics in OpenCV's convention (pixel (i, j) centred at (i, j)), so the
    spec reads directly where an upward camera is expected
    (:func:`behaviours.laws.ceiling_landmarks.law_camera_for`,
    :func:`sim2d.ceiling.upward_camera_for`).
    """

    mount_x: float
    mount_y: float
    mount_yaw: float
    width_px: int
    height_px: int
    hfov: float
    rate_hz: float
    mount_z: float = 0.6
    where: SourceLocation = field(default=_NOWHERE, compare=False, repr=False)

    @property
    def fx(self) -> float:
        """Focal length in pixels: ``width_px / (2 tan(hfov / 2))``."""
        return self.width_px / (2.0 * math.tan(0.5 * self.hfov))

    @property
    def fy(self) -> float:
        return self.fx

    @property
    def cx(self) -> float:
        return 0.5 * (self.width_px - 1)

    @property
    def cy(self) -> float:
        return 0.5 * (self.height_px - 1)


@dataclass(frozen=True, slots=True)
class Platform:
    """The robot: footprint (m) and limits (m/s, rad/s, m/s², rad/s², m/s³), sensors."""

    length: float
    width: float
    max_speed: float
    max_angular_speed: float
    max_acceleration: float
    max_angular_acceleration: float
    max_jerk: float
    cameras: Mapping[str, CameraSpec]
    lasers: Mapping[str, LaserSpec]
    track: float = 0.0
    """Left-to-right wheel centre distance (m), thesis eq. 2.2."""
    ceiling_camera: CeilingCameraSpec | None = None
    """The upward camera of ceiling navigation (issue 17); None: the robot has none."""

    @property
    def half_width(self) -> float:
        return self.width / 2.0

    @property
    def odometry_track(self) -> float:
        """The wheel distance that turns wheel speeds into a yaw rate (eq. 2.2):
        ``track``, or the width when the platform does not give its track."""
        return self.track or self.width

    @property
    def turning_radius(self) -> float:
        """Radius of the circle the footprint sweeps when the robot turns on the spot."""
        return math.hypot(self.length, self.width) / 2.0


DEFAULT_GEOFENCE_MARGIN = 0.3
"""Metres the footprint keeps from forbidden zones when a mission does not say."""


@dataclass(frozen=True, slots=True)
class SafetyRadii:
    """r_ES < r_OA-trigger (m), how long (s) the zone must be clear to release an e-stop,
    and the margin (m) the footprint keeps from forbidden zones."""

    r_es: float
    r_oa_trigger: float
    estop_hold: float
    geofence_margin: float = DEFAULT_GEOFENCE_MARGIN


@dataclass(frozen=True, slots=True)
class Navigation:
    cruise_speed: float
    inspection_speed: float
    position_tolerance: float
    heading_tolerance: float
    turn_mode: TurnMode


@dataclass(frozen=True, slots=True)
class ForbiddenZone:
    id: str
    kind: ZoneKind
    frame: Frame
    shape: Shape
    where: SourceLocation = field(default=_NOWHERE, compare=False, repr=False)


@dataclass(frozen=True, slots=True)
class Airport:
    station: Pose2
    parking: Pose2
    zones: tuple[ForbiddenZone, ...]


@dataclass(frozen=True, slots=True)
class Waypoint:
    """A route point; ``heading`` None means any heading."""

    id: str
    x: float
    y: float
    frame: Frame = Frame.AIRPORT
    heading: float | None = None
    speed: float | None = None
    where: SourceLocation = field(default=_NOWHERE, compare=False, repr=False)


@dataclass(frozen=True, slots=True)
class KeyImage:
    """A key image of a taught route (seed 002 §2.3): the robot pose in the mosaic frame
    M (= A) when it was taken, the mosaic landmarks it shows, its image file if kept."""

    id: str
    pose_m: Pose2
    landmarks: frozenset[str]
    image: Path | None = None
    where: SourceLocation = field(default=_NOWHERE, compare=False, repr=False)


@dataclass(frozen=True, slots=True)
class TaughtRoute:
    """A route taught under a hangar ceiling (issue 17, seed 002 §2.3, ``route.xsd``):
    its key images in order, repeated at the longitudinal speed ``speed`` (V, m/s;
    negative: backwards) by the VNHV law with eq. 10's ``settling_distance`` (m);
    ``mosaic`` the ceiling mosaic file of its landmarks."""

    id: str
    mosaic: Path
    ceiling_height: float
    speed: float
    settling_distance: float
    max_heading_change: float
    keys: tuple[KeyImage, ...]
    source: str = ""
    where: SourceLocation = field(default=_NOWHERE, compare=False, repr=False)

    @property
    def end(self) -> Pose2:
        """The last key pose (in M = A)."""
        return self.keys[-1].pose_m

    @property
    def length(self) -> float:
        """Metres along the key poses."""
        return sum(
            math.hypot(b.pose_m.x - a.pose_m.x, b.pose_m.y - a.pose_m.y)
            for a, b in zip(self.keys, self.keys[1:], strict=False)
        )


@dataclass(frozen=True, slots=True)
class Checkpoint:
    """An inspection stop: pose in F, items to inspect, optional visual-servo target."""

    id: str
    name: str
    pose: Pose2
    items: tuple[str, ...]
    camera: str | None = None
    target: str | None = None
    servo: ServoMethod | None = None
    dwell: float = 0.0
    via: tuple[tuple[float, float], ...] = ()
    """Pass-through points (in F) on the way to the checkpoint, in order."""
    where: SourceLocation = field(default=_NOWHERE, compare=False, repr=False)


@dataclass(frozen=True, slots=True)
class Mission:
    """A complete, validated mission for one aircraft type."""

    id: str
    aircraft: Aircraft
    platform: Platform
    safety: SafetyRadii
    navigation: Navigation
    airport: Airport
    approach: tuple[Waypoint, ...]
    handover: Waypoint
    checkpoints: tuple[Checkpoint, ...]
    return_route: tuple[Waypoint, ...]
    description: str = ""
    source: str = ""
    ceiling_mosaic: Path | None = None
    """The ceiling mosaic file (issue 17, :mod:`behaviours.laws.mosaic`) named by the
    airport's ``<ceiling-mosaic>``, resolved against the mission file; None: none."""
    taught_route: TaughtRoute | None = None
    """The approach as a route taught under the ceiling (issue 17, ``<approach>``'s
    ``<taught-route>``) instead of waypoints; None: waypoints (or none)."""

    def nominal_placement(self) -> AircraftPlacement:
        """The aircraft's nominal parking pose as a frame transform."""
        p = self.airport.parking
        return AircraftPlacement(p.x, p.y, p.theta, self.aircraft.origin_height)
