"""Simulated cameras: pan-tilt units, camera rigs and feature detection.

The simulator does not render images. A camera "sees" the aircraft's feature points
(:class:`executive.core.model.Feature`) and reports where they fall in its output image,
as a real feature detector would:

* :class:`PanTiltUnit` integrates the commanded pan and tilt rates of one platform camera
  unit within its rate and angle limits;
* :func:`camera_rigs` lists the physical cameras of a platform: two per stereo unit
  (``<id>-left``, ``<id>-right``), one per mono or PTZ unit (``<id>``);
* :class:`FeatureCloud` holds every feature point of a parked aircraft in the airport
  frame A, built once;
* :func:`detect` projects the cloud into one camera (pinhole model, ViSP camera frame:
  x right, y down, z along the optical axis) and returns a :class:`CameraFrame`.

Frames and transforms come from :mod:`executive.core.frames` (docs/mission-format.md).
Units: m, s, rad, pixels.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

from executive.core.frames import (
    AircraftPlacement,
    FloatArray,
    Pose2,
    Transform3,
    airport_from_robot,
    robot_from_camera,
)
from executive.core.model import Aircraft, CameraKind, CameraSpec
from executive.core.records import CameraFrame, Detection, PanTilt

BoolArray = NDArray[np.bool_]
IntArray = NDArray[np.intp]

#: ``occluded(camera_position_a, points_a) -> blocked``: given the camera's position (3,)
#: and candidate points (M, 3), both in A, says which lines of sight are blocked (M,).
OcclusionTest = Callable[[FloatArray, FloatArray], BoolArray]

__all__ = [
    "CameraRig",
    "FeatureCloud",
    "OcclusionTest",
    "PanTiltUnit",
    "airport_from_camera",
    "camera_rigs",
    "detect",
]


# -- pan-tilt units ---------------------------------------------------------------------
class PanTiltUnit:
    """The pan and tilt angles of one platform camera unit (rad).

    :meth:`command` stores the requested rates; :meth:`step` integrates them over ``dt``
    after clamping them to the unit's rate limits, and clamps the angles to the unit's
    angle limits (a rate that pushes against a limit just stops there). The angles start
    at 0, clamped into the limits.
    """

    __slots__ = ("_pan", "_pan_rate", "_tilt", "_tilt_rate", "spec")

    def __init__(self, spec: CameraSpec) -> None:
        self.spec = spec
        self._pan = _clamp(0.0, *spec.pan_limits)
        self._tilt = _clamp(0.0, *spec.tilt_limits)
        self._pan_rate = 0.0
        self._tilt_rate = 0.0

    @property
    def id(self) -> str:
        """The unit id: the platform camera id (``front``, ``rear``, ``ptz``)."""
        return self.spec.id

    @property
    def pan(self) -> float:
        return self._pan

    @property
    def tilt(self) -> float:
        return self._tilt

    @property
    def commanded(self) -> tuple[float, float]:
        """The requested (pan, tilt) rates as given to :meth:`command` (rad/s)."""
        return self._pan_rate, self._tilt_rate

    def command(self, pan_rate: float, tilt_rate: float) -> None:
        """Request pan and tilt rates (rad/s) until the next command."""
        if not (math.isfinite(pan_rate) and math.isfinite(tilt_rate)):
            raise ValueError(f"pan-tilt unit '{self.id}': rates must be finite")
        self._pan_rate = float(pan_rate)
        self._tilt_rate = float(tilt_rate)

    def step(self, dt: float) -> None:
        """Advance by ``dt`` seconds at the commanded rates, within the unit's limits."""
        if not dt >= 0.0:
            raise ValueError(f"pan-tilt unit '{self.id}': dt must be >= 0, got {dt}")
        if self._pan_rate == 0.0 and self._tilt_rate == 0.0:
            return  # holding still (the usual case): nothing to integrate
        spec = self.spec
        pan_rate = _clamp(self._pan_rate, -spec.pan_rate, spec.pan_rate)
        tilt_rate = _clamp(self._tilt_rate, -spec.tilt_rate, spec.tilt_rate)
        self._pan = _clamp(self._pan + pan_rate * dt, *spec.pan_limits)
        self._tilt = _clamp(self._tilt + tilt_rate * dt, *spec.tilt_limits)

    def reading(self, stamp: float) -> PanTilt:
        """The current angles, stamped."""
        return PanTilt(stamp, self._pan, self._tilt)


def _clamp(value: float, low: float, high: float) -> float:
    return min(max(value, low), high)


# -- camera rigs --------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class CameraRig:
    """One physical camera on a pan-tilt unit.

    ``unit`` is the id of its pan-tilt unit (the platform camera id). ``lateral`` is the
    camera's offset (m) from the unit's mount along the unit's lateral axis, which turns
    with pan (positive = the unit's left, +y of the unit): +baseline/2 for the left camera
    of a stereo pair, -baseline/2 for the right one, 0 otherwise.
    """

    id: str
    unit: str
    spec: CameraSpec
    lateral: float = 0.0
    # image-plane tests of detect(): rows of (-U, -V, U - W Z, V - H Z, -Z) as a linear
    # map of the point in C, with U = f X + cx Z and V = f Y + cy Z (u = U / Z, v = V / Z)
    _image_rows: FloatArray = field(init=False, repr=False, compare=False)
    # the constant part of detect()'s weights, and the image size as a (2, 1) column
    _weights: FloatArray = field(init=False, repr=False, compare=False)
    _image_size: FloatArray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        spec = self.spec
        f = spec.focal_px
        w, h = float(spec.image_width_px), float(spec.image_height_px)
        cx, cy = w / 2.0, h / 2.0
        rows = np.array(
            [
                [-f, 0.0, -cx],
                [0.0, -f, -cy],
                [f, 0.0, cx - w],
                [0.0, f, cy - h],
                [0.0, 0.0, -1.0],
            ]
        )
        weights = np.zeros((7, 9))
        weights[5, 7] = 1.0
        weights[6, 8] = 1.0
        object.__setattr__(self, "_image_rows", _frozen(rows))
        object.__setattr__(self, "_weights", _frozen(weights))
        object.__setattr__(self, "_image_size", _frozen(np.array([[w], [h]])))

    @property
    def principal_point(self) -> tuple[float, float]:
        """(cx, cy): the centre of the output image (px)."""
        return self.spec.image_width_px / 2.0, self.spec.image_height_px / 2.0


def camera_rigs(platform_cameras: Mapping[str, CameraSpec]) -> tuple[CameraRig, ...]:
    """The physical cameras of a platform, in the mapping's order.

    A stereo unit ``<id>`` gives ``<id>-left`` then ``<id>-right``; mono and PTZ units
    give one camera named ``<id>``.
    """
    rigs: list[CameraRig] = []
    for unit_id, spec in platform_cameras.items():
        if spec.kind is CameraKind.STEREO:
            if spec.baseline is None or not spec.baseline > 0.0:
                raise ValueError(f"stereo camera '{unit_id}' needs a positive baseline")
            half = spec.baseline / 2.0
            rigs.append(CameraRig(f"{unit_id}-left", unit_id, spec, half))
            rigs.append(CameraRig(f"{unit_id}-right", unit_id, spec, -half))
        else:
            rigs.append(CameraRig(unit_id, unit_id, spec, 0.0))
    return tuple(rigs)


def airport_from_camera(
    rig: CameraRig, unit_pan: float, unit_tilt: float, robot_pose_a: Pose2
) -> Transform3:
    """3D transform A <- C of ``rig`` for a robot standing on the ground at ``robot_pose_a``.

    The camera sits at its unit's mount plus ``rig.lateral`` along the unit's lateral axis
    (+y of the unit after pan; tilt turns about that axis, so it does not move the camera).
    """
    spec = rig.spec
    r_from_c = _robot_from_camera(
        spec.mount, spec.mount_yaw, rig.lateral, float(unit_pan), float(unit_tilt)
    )
    return _airport_from_robot(robot_pose_a) @ r_from_c


@lru_cache(maxsize=256)
def _robot_from_camera(
    mount: tuple[float, float, float], mount_yaw: float, lateral: float, pan: float, tilt: float
) -> Transform3:
    """R <- C of one camera of a unit (cached: units often hold still, stereo pairs share)."""
    transform = robot_from_camera(mount, mount_yaw, pan, tilt, lateral)
    _frozen(transform.rotation)
    _frozen(transform.translation)
    return transform


@lru_cache(maxsize=16)
def _airport_from_robot(pose_a: Pose2) -> Transform3:
    """A <- R for a robot on the ground (z = 0) at ``pose_a`` (cached: all cameras of a
    sensor cycle share the pose)."""
    transform = airport_from_robot(pose_a)
    _frozen(transform.rotation)
    _frozen(transform.translation)
    return transform


def _frozen(arr: NDArray) -> NDArray:
    arr.flags.writeable = False
    return arr


# -- feature cloud --------------------------------------------------------------------------
@dataclass(frozen=True, slots=True, eq=False)
class FeatureCloud:
    """Every feature point of a parked aircraft, in the airport frame A (z up).

    Rows are ordered by feature id, then by point index, so that detections come out in
    (feature, point) order: row k is point ``point_index[k]`` of feature
    ``feature_ids[feature_index[k]]``. Arrays are read-only.
    """

    feature_ids: tuple[str, ...]
    points: FloatArray  # (N, 3) in A
    normals: FloatArray  # (N, 3) unit outward normals in A; NaN rows: no normal
    feature_index: IntArray  # (N,)
    point_index: IntArray  # (N,)
    detection_range: FloatArray  # (N,) m
    # for detect(): the (9, N) design matrix, one column (p, 1, n, n.p, |p|^2 - range^2)
    # per point (n = 0 and n.p = -1 where the normal is unknown), and each point's feature
    _design: FloatArray = field(repr=False)
    _feature_of: NDArray[np.object_] = field(repr=False)

    @staticmethod
    def from_aircraft(aircraft: Aircraft, placement: AircraftPlacement) -> FeatureCloud:
        """Place the aircraft's feature points and normals in A with ``placement``."""
        a_from_f = placement.airport_from_aircraft()
        ids = tuple(sorted(aircraft.features))
        pts: list[tuple[float, float, float]] = []
        nrm: list[tuple[float, float, float]] = []
        fidx: list[int] = []
        pidx: list[int] = []
        ranges: list[float] = []
        for k, fid in enumerate(ids):
            feature = aircraft.features[fid]
            n = feature.normal
            normal = (math.nan,) * 3 if n is None else (n.x, n.y, n.z)
            for j, p in enumerate(feature.points):
                pts.append((p.x, p.y, p.z))
                nrm.append(normal)
                fidx.append(k)
                pidx.append(j)
                ranges.append(feature.detection_range)
        count = len(pts)
        points = a_from_f.apply(np.array(pts, dtype=float).reshape(count, 3)).reshape(count, 3)
        # normals are directions: rotation only
        normals = np.array(nrm, dtype=float).reshape(count, 3) @ a_from_f.rotation.T
        length = np.linalg.norm(normals, axis=1)
        known = length > 1e-12  # False for NaN (no normal) and zero
        normals[known] /= length[known, None]
        normals[~known] = math.nan
        detection_range = np.array(ranges, dtype=float)

        normals0 = np.where(known[:, None], normals, 0.0)
        design = np.empty((9, count))
        design[0:3] = points.T
        design[3] = 1.0
        design[4:7] = normals0.T
        design[7] = np.where(known, np.einsum("ij,ij->i", normals0, points), -1.0)
        design[8] = np.einsum("ij,ij->i", points, points) - detection_range**2
        return FeatureCloud(
            feature_ids=ids,
            points=_frozen(points),
            normals=_frozen(normals),
            feature_index=_frozen(np.array(fidx, dtype=np.intp)),
            point_index=_frozen(np.array(pidx, dtype=np.intp)),
            detection_range=_frozen(detection_range),
            _design=_frozen(design),
            _feature_of=_frozen(np.array([ids[k] for k in fidx], dtype=object)),
        )

    def __len__(self) -> int:
        return len(self.points)

    def out_of_range(self, x: float, y: float, reach: float) -> bool:
        """True when no camera within ``reach`` (m, horizontally) of ``(x, y)`` can detect
        any point: every point is more than 1 m beyond its detection range from there.

        The metre dwarfs any rounding in :func:`detect`'s range test, so :func:`detect`
        from such a camera surely returns no detection (and draws no random number).
        """
        dx = self.points[:, 0] - x
        dy = self.points[:, 1] - y
        limit = self.detection_range + (reach + 1.0)
        return bool(np.all(dx * dx + dy * dy > limit * limit))


# -- detection ------------------------------------------------------------------------------
def detect(
    rig: CameraRig,
    unit_pan: float,
    unit_tilt: float,
    robot_pose_a: Pose2,
    cloud: FeatureCloud,
    *,
    rng: np.random.Generator,
    pixel_noise: float,
    dropout: float,
    occluded: OcclusionTest | None,
    stamp: float,
) -> CameraFrame:
    """What camera ``rig`` detects of ``cloud`` with its unit at (``unit_pan``, ``unit_tilt``).

    The robot stands on the ground at ``robot_pose_a`` (A); the camera's pose is
    :func:`airport_from_camera`. Pinhole model on the output image: fx = fy =
    ``spec.focal_px``, principal point (cx, cy) at the image centre, u right, v down:
    ``u = cx + f X / Z``, ``v = cy + f Y / Z`` for the point (X, Y, Z) in C. A point is
    detected when it is

    * in front of the camera (Z > 0) and inside the image (0 <= u < W, 0 <= v < H),
    * within its feature's detection range (3D distance camera - point),
    * facing the camera (normal . (camera - point) > 0) when its normal is known,
    * not ``occluded``: the callback gets the camera position and the points that passed
      every other test (in A) and says which lines of sight are blocked; it is not called
      when it is None or no point passed.

    Then, using ``rng`` only and in this order, on the M remaining detections in
    (feature, point) order: Gaussian pixel noise on (u, v) (one ``rng.normal`` draw of
    shape (M, 2), skipped when ``pixel_noise`` is 0) and dropouts (one ``rng.random`` draw
    of shape (M,), each detection dropped with probability ``dropout``, skipped when
    ``dropout`` is 0). A detection whose noisy pixel falls outside the image is dropped
    as well (a detector only reports pixels of its image). The same inputs and generator
    state give the same frame. Detections are sorted by (feature id, point index).

    Points exactly on a boundary (image edge, detection range, edge-on normal) are decided
    up to floating-point rounding; a reported pixel is always inside the image.
    """
    if not pixel_noise >= 0.0:
        raise ValueError(f"pixel_noise must be >= 0, got {pixel_noise}")
    if not 0.0 <= dropout <= 1.0:
        raise ValueError(f"dropout must be in [0, 1], got {dropout}")
    a_from_c = airport_from_camera(rig, unit_pan, unit_tilt, robot_pose_a)
    cam = a_from_c.translation

    # One product tests every point: rows (-U, -V, U - W Z, V - H Z, -Z, n.(p - cam),
    # |p - cam|^2 - range^2) must all be negative. With (X, Y, Z) = R^T (p - cam):
    weights = rig._weights.copy()
    image = rig._image_rows @ a_from_c.rotation.T  # the image rows as a map of p in A
    weights[:5, :3] = image
    weights[:5, 3] = -(image @ cam)
    weights[5, 4:7] = -cam
    weights[6, :3] = -2.0 * cam
    weights[6, 3] = cam @ cam
    tests = weights @ cloud._design
    idx = (np.maximum.reduce(tests, axis=0) < 0.0).nonzero()[0]
    if idx.size == 0:
        return CameraFrame(stamp)
    uv = tests[:2].take(idx, axis=1) / tests[4].take(idx)  # (-U, -V) / (-Z): rows u, v

    if occluded is not None:
        blocked = np.asarray(occluded(cam, cloud.points.take(idx, axis=0)), dtype=bool)
        if blocked.shape != idx.shape:
            raise ValueError(f"occlusion test returned shape {blocked.shape}, not {idx.shape}")
        if blocked.any():
            seen = ~blocked
            idx, uv = idx[seen], uv[:, seen]
            if idx.size == 0:
                return CameraFrame(stamp)

    count = idx.size
    if pixel_noise > 0.0:
        uv += rng.normal(0.0, pixel_noise, size=(count, 2)).T
    keep = ((uv >= 0.0) & (uv < rig._image_size)).all(axis=0)
    if dropout > 0.0:
        keep &= rng.random(count) >= dropout
    if not keep.all():
        idx, uv = idx[keep], uv[:, keep]

    return CameraFrame(
        stamp,
        tuple(
            map(
                Detection,
                cloud._feature_of.take(idx).tolist(),
                cloud.point_index.take(idx).tolist(),
                *uv.tolist(),
            )
        ),
    )
