"""Candidate robot poses for a draft mission and what the inspection camera sees from each.

Issue 18: for each inspection item, the poses from which its feature is visible to a camera
that can inspect it. The candidates are a grid of positions in the aircraft frame F, kept
where the robot may stop (:mod:`executive.planning.space`), each facing the nearest feature
(a robot that faces the aircraft has its lasers and front camera on it). From a candidate
the inspection unit (the PTZ camera, which :mod:`executive.compiler` gives every item; the
first camera when there is none) *sees* a feature when

1. **in range**: the feature's centroid (as the validator measures it) and a point of it
   (as the simulator detects it) are within its detection range of the camera, less
   :data:`RANGE_MARGIN` (the robot stops within its position tolerance,
   not on the pose), and within the range at which the camera resolves it as well as the
   camera the ranges are stated for (:data:`REFERENCE_FOCAL_PX`: the thesis' 1384 px,
   4.65 um, 6 mm camera, seed 000 lines 617-800): ``d <= range * focal_px / 1290``;
2. **facing**: for a feature with a normal, its outward normal makes at most
   :data:`MAX_INCIDENCE` with the line to the camera (the simulator, like a detector,
   sees a point only from its front side);
3. **within the pan-tilt limits and in the image**: the pan and tilt that centre the
   feature are within the unit's limits with :data:`ANGLE_MARGIN` to spare (the validator
   allows half the field of view beyond the limits), and with the unit aimed so (as
   :class:`behaviours.controllers.inspection.InspectItems` aims it) a point of test 1-2
   falls inside the image, :data:`IMAGE_MARGIN` from its edges;
4. **not occluded**: the line of sight, on the ground, crosses no footprint shape but the
   one the feature belongs to (gear legs and nacelles reach from the ground to the wings
   and the belly, above the camera).

The validator's own check (:func:`executive.core.checks.why_not_visible`) is implied by
1-3 and is run again on every checkpoint the planner writes. For an item no candidate
sees, :func:`candidate_views` says which test ruled out the last poses (the tests run in
the order above, each on the poses the previous ones kept).
All computations are vectorised over the candidates (numpy, shapely 2).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import shapely

from executive.core.frames import FloatArray, wrap_angle
from executive.core.model import Aircraft, CameraKind, CameraSpec, Feature, Mission
from executive.planning.space import FreeSpace

GRID_SPACING = 0.5
"""Metres between candidate positions."""

RANGE_MARGIN = 0.5
"""Metres kept inside a feature's detection range (position tolerance, heading error)."""

REFERENCE_FOCAL_PX = 6e-3 / 4.65e-6
"""Focal length (px) of the camera the aircraft files' detection ranges are stated for."""

MAX_INCIDENCE = math.radians(80.0)
"""Largest angle between a feature's normal and the line of sight to the camera: the
simulator, like a detector, sees a point only from its front side (below 90 deg); 10 deg
are kept for the pose tolerance and so that the feature keeps a sixth of its face-on size."""

ANGLE_MARGIN = math.radians(2.0)
"""Pan and tilt kept inside the unit's limits."""

IMAGE_MARGIN = 0.15
"""Fraction of the half image kept free at its edges (the aim settles within 1 deg, the
robot stands within its tolerance)."""

OWN_SHAPE_RADIUS = 0.5
"""A footprint shape within this distance (m, on the ground) of a feature's centroid is the
feature's own (a gear's tyres, a nacelle's inlet): it does not hide the feature."""


def inspection_unit(mission: Mission) -> CameraSpec:
    """The camera that inspects items, as the compiler chooses it: the first PTZ camera,
    else (the draft then names it on every checkpoint) the first camera."""
    cameras = list(mission.platform.cameras.values())
    return next((c for c in cameras if c.kind is CameraKind.PTZ), cameras[0])


@dataclass(frozen=True)
class CandidateViews:
    """Candidate poses in F and what the inspection unit sees from them.

    ``poses`` (N, 3): x, y, heading; ``items`` the item ids in the aircraft file's order;
    ``sees`` (N, M) which items each pose sees; ``distance`` (N, M) camera-to-feature
    distance (m, inf where not seen); ``reasons`` why each item no pose sees is not
    coverable.
    """

    poses: FloatArray
    items: tuple[str, ...]
    sees: np.ndarray
    distance: FloatArray
    reasons: dict[str, str]
    unit: CameraSpec


def candidate_positions(space: FreeSpace, spacing: float = GRID_SPACING) -> FloatArray:
    """Grid positions (N, 2) in F where the robot may stop, round the features."""
    aircraft = space.mission.aircraft
    cents = np.array([f.centroid()[:2] for f in aircraft.features.values()])
    reach = max(f.detection_range for f in aircraft.features.values())
    lo = np.floor((cents.min(axis=0) - reach) / spacing) * spacing
    hi = np.ceil((cents.max(axis=0) + reach) / spacing) * spacing
    xs = np.arange(lo[0], hi[0] + spacing / 2, spacing)
    ys = np.arange(lo[1], hi[1] + spacing / 2, spacing)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    xy = np.column_stack((gx.ravel(), gy.ravel()))
    return xy[space.can_stop(xy)]


def facing_headings(aircraft: Aircraft, xy: FloatArray) -> FloatArray:
    """Heading (rad, in F) from each position towards the nearest feature centroid."""
    cents = np.array([f.centroid()[:2] for f in aircraft.features.values()])
    d = cents[None, :, :] - xy[:, None, :]
    nearest = np.argmin(np.hypot(d[..., 0], d[..., 1]), axis=1)
    v = d[np.arange(len(xy)), nearest]
    return np.arctan2(v[:, 1], v[:, 0])


def camera_positions(
    camera: CameraSpec, poses: FloatArray, origin_height: float
) -> tuple[FloatArray, float]:
    """The unit's position in F from robot poses (N, 3): ground (N, 2) and z_F.

    R has z up and F z down (:func:`executive.core.frames.aircraft_from_robot`): the
    robot's +x is (cos h, sin h) in F and its +y is (sin h, -cos h).
    """
    mx, my, mz = camera.mount
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    xy = np.column_stack((poses[:, 0] + c * mx + s * my, poses[:, 1] + s * mx - c * my))
    return xy, origin_height - mz


def _in_range(limits: tuple[float, float], angle: FloatArray) -> np.ndarray:
    lo, hi = limits[0] + ANGLE_MARGIN, limits[1] - ANGLE_MARGIN
    ok = np.zeros(angle.shape, dtype=bool)
    for k in (-1, 0, 1):
        a = angle + 2 * math.pi * k
        ok |= (lo <= a) & (a <= hi)
    return ok


def pan_tilt(
    camera: CameraSpec, poses: FloatArray, target_f: FloatArray, origin_height: float
) -> tuple[FloatArray, FloatArray]:
    """Pan and tilt (rad) that centre ``target_f`` (3,) from robot poses (N, 3), as
    :func:`executive.core.frames.pan_tilt_towards` computes them in R."""
    dx = target_f[0] - poses[:, 0]
    dy = target_f[1] - poses[:, 1]
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    x_r = c * dx + s * dy - camera.mount[0]
    y_r = s * dx - c * dy - camera.mount[1]
    z_r = (origin_height - target_f[2]) - camera.mount[2]
    pan = np.vectorize(wrap_angle, otypes=[float])(np.arctan2(y_r, x_r) - camera.mount_yaw)
    tilt = np.arctan2(z_r, np.hypot(x_r, y_r))
    return pan, tilt


def in_image(
    camera: CameraSpec,
    poses: FloatArray,
    points_f: FloatArray,
    pan: FloatArray,
    tilt: FloatArray,
    origin_height: float,
) -> np.ndarray:
    """Which points (P, 3) fall inside the image, :data:`IMAGE_MARGIN` from its edges,
    with the unit at (``pan``, ``tilt``) (N,) from each pose (N, 3): (N, P).

    The pinhole of :func:`sim2d.cameras.detect` in the unit's frame
    (:func:`executive.core.frames.robot_from_camera`): after the pan, the optical axis is
    (cos t, 0, sin t), the image's x axis (0, -1, 0) and its y axis (sin t, 0, -cos t).
    """
    c, s = np.cos(poses[:, 2])[:, None], np.sin(poses[:, 2])[:, None]
    dx = points_f[None, :, 0] - poses[:, 0:1]
    dy = points_f[None, :, 1] - poses[:, 1:2]
    x_r = c * dx + s * dy - camera.mount[0]
    y_r = s * dx - c * dy - camera.mount[1]
    z_r = (origin_height - points_f[None, :, 2]) - camera.mount[2]
    yaw = (camera.mount_yaw + pan)[:, None]
    x1 = np.cos(yaw) * x_r + np.sin(yaw) * y_r
    y1 = -np.sin(yaw) * x_r + np.cos(yaw) * y_r
    ct, st = np.cos(tilt)[:, None], np.sin(tilt)[:, None]
    z_c = ct * x1 + st * z_r
    x_c = -y1
    y_c = st * x1 - ct * z_r
    f = camera.focal_px
    half_w = camera.image_width_px / 2 * (1.0 - IMAGE_MARGIN)
    half_h = camera.image_height_px / 2 * (1.0 - IMAGE_MARGIN)
    with np.errstate(divide="ignore", invalid="ignore"):
        u, v = f * x_c / z_c, f * y_c / z_c
    return (z_c > 1e-6) & (np.abs(u) <= half_w) & (np.abs(v) <= half_h)


def view_range(camera: CameraSpec, feature: Feature) -> float:
    """How far (m) from ``camera`` the planner accepts ``feature`` (test 1)."""
    pixels = feature.detection_range * camera.focal_px / REFERENCE_FOCAL_PX
    return min(feature.detection_range, pixels) - RANGE_MARGIN


def feature_views(
    space: FreeSpace, camera: CameraSpec, feature: Feature, poses: FloatArray
) -> tuple[np.ndarray, FloatArray, str | None]:
    """Which poses (N, 3) see ``feature`` (tests 1-4), the distance from each, and — when
    none does — why, from the last test that ruled poses out."""
    h0 = space.mission.aircraft.origin_height
    cam_xy, cam_z = camera_positions(camera, poses, h0)
    points = np.array([p.array() for p in feature.points])
    centroid = feature.centroid()
    limit = view_range(camera, feature)
    d_pts = np.sqrt(
        (points[None, :, 0] - cam_xy[:, None, 0]) ** 2
        + (points[None, :, 1] - cam_xy[:, None, 1]) ** 2
        + (points[None, :, 2] - cam_z) ** 2
    )  # (N, P)
    d_centroid = np.sqrt(
        (centroid[0] - cam_xy[:, 0]) ** 2
        + (centroid[1] - cam_xy[:, 1]) ** 2
        + (centroid[2] - cam_z) ** 2
    )
    # the validator measures the range to the centroid, the simulator to each point
    point_ok = (d_pts <= limit) & (d_centroid <= limit)[:, None]
    near = point_ok.any(axis=1)
    if not near.any():
        nearest = float(d_pts.min()) if d_pts.size else math.inf
        return (
            near,
            np.full(len(poses), math.inf),
            f"no pose clear of the footprint and the zones is within {limit:.1f} m of it "
            f"(detection range {feature.detection_range:g} m, less {RANGE_MARGIN:g} m for "
            f"the stop's tolerance{_pixel_note(camera, feature)}); the nearest clear pose "
            f"is {nearest:.1f} m away",
        )
    if feature.normal is not None:
        n = feature.normal.array()
        n = n / np.linalg.norm(n)
        to_cam = np.stack(
            [
                cam_xy[:, None, 0] - points[None, :, 0],
                cam_xy[:, None, 1] - points[None, :, 1],
                np.broadcast_to(cam_z - points[None, :, 2], d_pts.shape),
            ],
            axis=-1,
        )
        cos_inc = (to_cam @ n) / np.maximum(d_pts, 1e-9)
        point_ok &= cos_inc >= math.cos(MAX_INCIDENCE)
    facing = point_ok.any(axis=1)
    if not facing.any():
        return (
            facing,
            np.full(len(poses), math.inf),
            f"faces away from every clear pose within {limit:.1f} m: its normal is more than "
            f"{math.degrees(MAX_INCIDENCE):.0f} deg from the line of sight",
        )
    pan, tilt = pan_tilt(camera, poses, centroid, h0)
    aimed = facing & _in_range(camera.pan_limits, pan) & _in_range(camera.tilt_limits, tilt)
    if not aimed.any():
        idx = np.flatnonzero(facing)
        need = "tilt" if not _in_range(camera.tilt_limits, tilt[idx]).any() else "pan"
        lim = camera.tilt_limits if need == "tilt" else camera.pan_limits
        return (
            aimed,
            np.full(len(poses), math.inf),
            f"needs a {need} outside camera '{camera.id}''s limits "
            f"{math.degrees(lim[0]):.0f}..{math.degrees(lim[1]):.0f} deg from every clear "
            f"pose within {limit:.1f} m that it faces",
        )
    point_ok &= in_image(camera, poses, points, pan, tilt, h0)
    seen = aimed & point_ok.any(axis=1)
    if not seen.any():
        return (
            seen,
            np.full(len(poses), math.inf),
            f"falls outside camera '{camera.id}''s image, aimed at its centroid, from every "
            f"clear pose within {limit:.1f} m that it faces (too close under it, or spread "
            "wider than the field of view)",
        )
    blockers = [
        (sid, g)
        for sid, g in space.footprint
        if g.distance(shapely.Point(centroid[0], centroid[1])) > OWN_SHAPE_RADIUS
    ]
    if blockers:
        idx = np.flatnonzero(seen)
        lines = shapely.linestrings(
            np.stack([cam_xy[idx], np.broadcast_to(centroid[:2], (len(idx), 2))], axis=1)
        )
        hidden = np.zeros(len(idx), dtype=bool)
        names = set()
        for sid, g in blockers:
            hit = shapely.intersects(lines, g)
            if hit.any():
                names.add(sid)
            hidden |= hit
        seen[idx[hidden]] = False
        if not seen.any():
            return (
                seen,
                np.full(len(poses), math.inf),
                "is hidden behind the footprint ("
                + ", ".join(f"'{n}'" for n in sorted(names))
                + ") from every clear pose within range that it faces",
            )
    distance = np.where(seen, d_centroid, math.inf)
    return seen, distance, None


def _pixel_note(camera: CameraSpec, feature: Feature) -> str:
    pixels = feature.detection_range * camera.focal_px / REFERENCE_FOCAL_PX
    if pixels >= feature.detection_range:
        return ""
    return f"; camera '{camera.id}' resolves it as the reference camera only within {pixels:.1f} m"


def candidate_views(space: FreeSpace, spacing: float = GRID_SPACING) -> CandidateViews:
    """Every candidate pose and what the inspection unit sees from it."""
    mission = space.mission
    aircraft = mission.aircraft
    unit = inspection_unit(mission)
    xy = candidate_positions(space, spacing)
    headings = facing_headings(aircraft, xy) if len(xy) else np.zeros(0)
    poses = np.column_stack((xy, headings)) if len(xy) else np.zeros((0, 3))
    items = tuple(aircraft.items)
    sees = np.zeros((len(poses), len(items)), dtype=bool)
    distance = np.full((len(poses), len(items)), math.inf)
    reasons: dict[str, str] = {}
    per_feature: dict[str, tuple[np.ndarray, FloatArray, str | None]] = {}
    for j, item_id in enumerate(items):
        feature = aircraft.feature_of(item_id)
        if feature.id not in per_feature:
            if len(poses) == 0:
                per_feature[feature.id] = (
                    np.zeros(0, dtype=bool),
                    np.zeros(0),
                    "no pose round the aircraft is clear of the footprint and the zones",
                )
            else:
                per_feature[feature.id] = feature_views(space, unit, feature, poses)
        seen, dist, reason = per_feature[feature.id]
        sees[:, j] = seen
        distance[:, j] = dist
        if reason is not None:
            reasons[item_id] = f"its feature '{feature.id}' {reason}"
    return CandidateViews(poses, items, sees, distance, reasons, unit)
