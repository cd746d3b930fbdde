"""Ceiling landmarks in real images: detection, mosaic building and localisation (issue 17).

The image side of Blanc et al. 2004 §2.1-2.2 (seed 002); the geometry (eq. 1-4) is in
:mod:`behaviours.laws.ceiling`, which this module feeds.

Landmarks
---------
A landmark (the paper's 2D model ``m_i``) is a disc of ceiling, ``radius_px`` pixels
across in the image where it was created, described by the ORB keypoints inside it: their
positions in the landmark's own frame (pixels, origin at their centroid, axes the image's
(u, v) axes in the creation image) and their binary descriptors. Its *image pose*
``I_L_i = (u, v, phi)`` in a new image is the rigid transform that maps its stored keypoint
positions onto their matches: a RANSAC fit (``cv2.estimateAffinePartial2D``, 2-point
minimal sets) for the inliers, then a least-squares rigid (Kabsch) refit on them. Fitting
tens of keypoints spread over ~100 px gives the landmark's position to a small fraction of a
pixel and its angle to a few hundredths of a degree, where one keypoint's own angle (ORB's
intensity centroid) is good to a few degrees only. The fit's residuals give the
observation's ``sigma_px`` and ``sigma_phi`` (eq. 3 weights).

Why ORB: the ceiling is seen from a constant distance (fixed scale) and only rotates in the
image, so ORB's rotation-invariant binary descriptors are enough; it detects and describes
1500 keypoints of a 640x480 image in a few milliseconds (AKAZE and SIFT take 5-10 times
longer, outside the 10 ms budget), and binary descriptors match by Hamming distance in
OpenCV's brute-force matcher. ORB's keypoint positions are pixel-quantised (and coarser
on upper pyramid levels), so only two pyramid levels are used and the positions of the
keypoints that are actually used (a landmark's at creation, the matched ones in a new
image: a few hundred, not all 1500) are refined by ``cv2.cornerSubPix`` (7x7 window):
this halved the localisation error in the tests. Unlike :mod:`behaviours.laws.ceiling`,
this module uses OpenCV (it is the image side); it still has no clock and no I/O.

Distinctiveness and robustness
------------------------------
* At creation, a keypoint is kept only if no other keypoint of the same image has a
  similar descriptor (Hamming distance below ``min_self_distance``): keypoints of the
  repeated vent tiles (when two copies are in view), of the regular panel seams and beam
  crossings are mostly dropped. Keypoints near saturated pixels (lit lamps) are dropped
  too: a lamp switched off changes them.
* Matching is gated by the pose prior (the robot's predicted pose, e.g. odometry): each
  stored keypoint of a landmark is predicted in the image through the mosaic pose of the
  landmark and the prior, and may only match image keypoints within a gate of
  ``prior_position_m + prior_heading_rad * lever`` (the lever is the keypoint's distance
  from the camera axis) plus a margin. The repeated tiles are identical: no descriptor
  test can tell their copies apart, only *where* they are; the gate (about 1 m for a
  0.5 m / 5 degree prior) is smaller than the distance between two copies (at least two
  tile sizes, 3.2 m), so a copy cannot be matched to another. Inside the gate, Lowe's
  ratio test (best / second best Hamming distance < ``ratio``) drops ambiguous matches
  (seam crossings, slats of one grille).
* The RANSAC fit per landmark drops the remaining wrong matches (occluders, lamps off);
  a landmark needs ``min_inliers`` inliers. Finally the robot poses given by each landmark
  (eq. 2) must agree: those farther than ``consensus_m`` / ``consensus_rad`` from their
  median are dropped before the fusion of eq. 3 (a landmark matched on the wrong copy of a
  tile would give a pose metres off).

Mosaic (eq. 4)
--------------
The mosaic frame M is anchored to the world frame: the first image is taken at a known
robot pose ``first_pose`` (in A), and its landmarks get ``M_T_i = first_pose R_T_C C_T_i``;
so M = A and mosaic poses can be compared with the ground truth directly (the paper's
choice, M = the first landmark's frame, differs by a constant transform). For every later
image, the landmarks of the mosaic seen in it give the camera pose by eq. 2-3, and each new
landmark ``i`` created in the image is added by eq. 4 *fused over all the known landmarks
j in view*: ``M_T_j j_T_i = M_T_j (C_T_j)^-1 C_T_i = M_T_C^(j) C_T_i``, so fusing the
``M_T_C^(j)`` by eq. 3 first and composing once with ``C_T_i`` is eq. 4 averaged over j
(less drift than chaining through a single j). A new landmark is *provisional* for its
first ``confirm_images`` images: it is matched, but not used to localise while confirmed
landmarks are in view, and its pose is the inverse-variance weighted mean (eq. 3) of its
eq. 4 estimates in those images; then it is frozen, like every landmark of the first
image. Averaging over ~10 images halves the mosaic's error against a single eq. 4 at
creation; waiting longer (20) made it worse, the fixes then resting on fewer landmarks.
New landmarks are created on a grid of image cells, in cells whose centre is far enough
from every landmark in view, with enough distinctive keypoints spread in both directions
(keypoints along one edge or cable slide along it and spoil the landmark's angle).

Speed: only the ``max_landmarks`` landmarks predicted nearest the image centre are
matched (12 give the accuracy of all of them at half the cost), and each landmark's gate
is evaluated only on the image keypoints in its bounding box.

Conventions: image poses are :class:`Pose2` in pixels (u, v, phi from +u towards +v), as
in :mod:`behaviours.laws.ceiling`. For :class:`sim2d.ceiling.UpwardCamera` (u along the
robot's left, v backwards), the law's ``robot_from_camera`` is
``Pose2(mount_x, mount_y, mount_yaw + pi/2)``: see :func:`law_camera_for`.
Units: m, rad, pixels.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Protocol

import cv2
import numpy as np
from numpy.typing import NDArray

from behaviours.laws.ceiling import (
    CeilingCamera,
    CeilingFix,
    LandmarkObservation,
    camera_from_landmark_eq1,
    fuse_poses_eq3,
    localise,
    robot_pose_from_landmark_eq2,
)
from executive.core.frames import FloatArray, Pose2, wrap_angle

__all__ = [
    "CeilingLocaliser",
    "CeilingMapper",
    "Features",
    "Landmark",
    "LandmarkConfig",
    "detect",
    "law_camera_for",
    "observe_landmarks",
    "predict_image_pose",
    "subpixel",
]

ImageU8 = NDArray[np.uint8]


class _UpwardCameraLike(Protocol):
    fx: float
    fy: float
    cx: float
    cy: float
    mount_x: float
    mount_y: float
    mount_z: float
    mount_yaw: float


def law_camera_for(camera: _UpwardCameraLike, ceiling_height: float) -> CeilingCamera:
    """The law's :class:`CeilingCamera` for a :class:`sim2d.ceiling.UpwardCamera`.

    The renderer's image axes are u = the robot's left turned by ``mount_yaw`` and v = its
    backward; the law's camera frame has x_C along u and y_C along v. The frame (left,
    backward) is the robot frame (forward, left) turned by +90 degrees, so
    ``robot_from_camera = Pose2(mount_x, mount_y, mount_yaw + pi/2)``. Z is the ceiling's
    height above the optical centre. Square pixels are assumed (fx == fy).
    """
    if not math.isclose(camera.fx, camera.fy, rel_tol=1e-9):
        raise ValueError("the law assumes square pixels (fx == fy)")
    return CeilingCamera(
        focal_px=camera.fx,
        cu=camera.cx,
        cv=camera.cy,
        height=ceiling_height - camera.mount_z,
        robot_from_camera=Pose2(
            camera.mount_x, camera.mount_y, wrap_angle(camera.mount_yaw + 0.5 * math.pi)
        ),
    )


@dataclass(frozen=True, slots=True)
class LandmarkConfig:
    """Tuning of detection, landmark creation and gated matching (pixels unless noted)."""

    n_features: int = 1500
    fast_threshold: int = 12
    n_levels: int = 2
    scale_factor: float = 1.3
    subpixel_win: int = 3  # cornerSubPix half window (0: keep ORB's positions)
    saturation_grey: int = 240  # pixels at or above: lamp emitters
    saturation_margin_px: int = 12  # keypoints this close to a saturated pixel are dropped
    radius_px: float = 80.0  # landmark disc radius at creation
    cell_px: int = 80  # grid of candidate landmark centres
    border_px: float = 85.0  # a new landmark's centre keeps this far from the image border
    min_keypoints: int = 25  # distinctive keypoints needed to create a landmark
    min_spread_px: float = 15.0  # smallest principal std of its keypoints
    min_self_distance: int = 40  # Hamming distance to every other keypoint of the image
    spacing_px: float = 100.0  # a new landmark keeps this far from landmarks in view
    ratio: float = 0.8  # Lowe's ratio inside the gate
    max_hamming: int = 70  # absolute bound on a match's Hamming distance
    gate_margin_px: float = 6.0
    ransac_px: float = 2.0
    refit_px: float = 1.0  # inlier residual bound of the final rigid refit
    min_inliers: int = 8
    consensus_m: float = 0.15
    consensus_rad: float = math.radians(2.0)
    min_sigma_px: float = 0.05
    min_sigma_phi: float = 2e-4
    max_landmarks: int = 12  # the landmarks nearest the image centre are matched
    confirm_images: int = 10  # eq. 4 estimates averaged into a new landmark's pose


@dataclass(frozen=True, slots=True, eq=False)
class Features:
    """Keypoints of one image: positions (N, 2) float (u, v) and ORB descriptors (N, 32)."""

    points: FloatArray
    descriptors: NDArray[np.uint8]
    image: ImageU8 | None = None  # for the sub-pixel refinement of the matched keypoints

    def __len__(self) -> int:
        return len(self.points)


@dataclass(frozen=True, slots=True, eq=False)
class Landmark:
    """A 2D model ``m_i``: its pose ``M_T_i`` in the mosaic and its keypoints.

    ``points`` (K, 2) are the keypoint positions in the landmark frame (pixels of the
    creation image, origin at their centroid, axes the image's), ``descriptors`` (K, 32).
    ``created_in`` is the index of the creation image in the mapping sequence and
    ``origin_px`` the landmark's origin (u, v) in it: its image pose there is
    ``(u, v, 0)`` (what a ground truth can be checked against).
    """

    landmark_id: str
    pose: Pose2
    points: FloatArray
    descriptors: NDArray[np.uint8]
    created_in: int = -1
    origin_px: tuple[float, float] = (math.nan, math.nan)

    @property
    def extent_px(self) -> float:
        """The largest distance of a keypoint from the landmark's origin (pixels)."""
        return float(np.hypot(*self.points.T).max()) if len(self.points) else 0.0


_ORB_CACHE: dict[tuple[int, int, int, float], cv2.ORB] = {}


def _orb(config: LandmarkConfig) -> cv2.ORB:
    key = (config.n_features, config.fast_threshold, config.n_levels, config.scale_factor)
    if key not in _ORB_CACHE:
        _ORB_CACHE[key] = cv2.ORB_create(
            nfeatures=config.n_features,
            scaleFactor=config.scale_factor,
            nlevels=config.n_levels,
            fastThreshold=config.fast_threshold,
            edgeThreshold=19,
            patchSize=19,
        )
    return _ORB_CACHE[key]


def detect(image: ImageU8, config: LandmarkConfig | None = None) -> Features:
    """ORB keypoints and descriptors of a grey image (uint8); positions as ORB gives
    them (see :func:`subpixel`)."""
    config = config or LandmarkConfig()
    keypoints, descriptors = _orb(config).detectAndCompute(image, None)
    if descriptors is None or not keypoints:
        return Features(np.zeros((0, 2)), np.zeros((0, 32), dtype=np.uint8), image)
    points = np.array([kp.pt for kp in keypoints], dtype=float)
    return Features(points, descriptors, image)


def subpixel(image: ImageU8, points: FloatArray, config: LandmarkConfig) -> FloatArray:
    """Keypoint positions refined by ``cv2.cornerSubPix`` (kept where it moves a point
    more than the window, i.e. where it does not converge)."""
    w = config.subpixel_win
    if w <= 0 or not len(points):
        return points
    start = points.astype(np.float32).reshape(-1, 1, 2)
    refined = cv2.cornerSubPix(image, start.copy(), (w, w), (-1, -1), _SUBPIX_CRITERIA)
    refined = refined.reshape(-1, 2).astype(float)
    moved = np.hypot(*(refined - points).T) <= w
    return np.where(moved[:, None], refined, points)


_SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 10, 0.01)


# -- prediction and gated matching -----------------------------------------------------------
def predict_image_pose(landmark_pose: Pose2, robot_pose: Pose2, camera: CeilingCamera) -> Pose2:
    """The image pose ``I_L_i`` of a landmark of pose ``M_T_i`` for the robot at
    ``robot_pose`` (the inverse of eq. 1-2)."""
    camera_from_landmark = (robot_pose @ camera.robot_from_camera).inverse() @ landmark_pose
    k = camera.scale
    return Pose2(
        camera.cu + camera_from_landmark.x / k,
        camera.cv + camera_from_landmark.y / k,
        camera_from_landmark.theta,
    )


def _rigid_fit(src: FloatArray, dst: FloatArray) -> tuple[float, float, float]:
    """Least-squares rigid transform (tu, tv, phi) with dst ~ R(phi) src + t (Kabsch, 2D)."""
    ms, md = src.mean(axis=0), dst.mean(axis=0)
    a, b = src - ms, dst - md
    sxx = float(np.sum(a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1]))
    sxy = float(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]))
    phi = math.atan2(sxy, sxx)
    c, s = math.cos(phi), math.sin(phi)
    t = md - np.array([c * ms[0] - s * ms[1], s * ms[0] + c * ms[1]])
    return float(t[0]), float(t[1]), phi


def _apply(pose: tuple[float, float, float], pts: FloatArray) -> FloatArray:
    c, s = math.cos(pose[2]), math.sin(pose[2])
    return pts @ np.array([[c, s], [-s, c]]) + np.array(pose[:2])


@dataclass(frozen=True, slots=True)
class _Fit:
    observation: LandmarkObservation
    inliers: int
    image_indices: NDArray[np.intp]


def observe_landmarks(
    features: Features,
    landmarks: Sequence[Landmark],
    prior: Pose2,
    camera: CeilingCamera,
    image_size: tuple[int, int],
    *,
    prior_position_m: float = 0.5,
    prior_heading_rad: float = math.radians(5.0),
    config: LandmarkConfig | None = None,
) -> list[LandmarkObservation]:
    """The image poses (eq. 1) of the mosaic landmarks found in an image.

    Landmarks predicted (through ``prior``) to lie in the image (``image_size`` = (width,
    height)) are matched with a gate from the prior's uncertainty, a ratio test and a
    RANSAC rigid fit, then checked for consensus (module docstring).
    """
    return [
        fit.observation
        for fit in _observe(
            features,
            landmarks,
            prior,
            camera,
            image_size,
            prior_position_m,
            prior_heading_rad,
            config or LandmarkConfig(),
        )
    ]


def _observe(
    features: Features,
    landmarks: Sequence[Landmark],
    prior: Pose2,
    camera: CeilingCamera,
    image_size: tuple[int, int],
    prior_position_m: float,
    prior_heading_rad: float,
    config: LandmarkConfig,
) -> list[_Fit]:
    if len(features) < config.min_inliers or not landmarks:
        return []
    width, height = image_size
    scale = camera.scale
    model_pts: list[FloatArray] = []
    model_desc: list[NDArray[np.uint8]] = []
    owners: list[NDArray[np.intp]] = []
    gates: list[FloatArray] = []
    in_view: list[tuple[Landmark, Pose2]] = []
    candidates: list[tuple[float, Landmark, Pose2]] = []
    for lm in landmarks:
        pred = predict_image_pose(lm.pose, prior, camera)
        r = lm.extent_px
        if -r < pred.x < width + r and -r < pred.y < height + r:
            off_centre = math.hypot(pred.x - camera.cu, pred.y - camera.cv)
            candidates.append((off_centre, lm, pred))
    candidates.sort(key=lambda c: c[0])
    for _, lm, pred in candidates[: config.max_landmarks]:
        idx = len(in_view)
        in_view.append((lm, pred))
        predicted = _apply((pred.x, pred.y, pred.theta), lm.points)
        lever_px = np.hypot(predicted[:, 0] - camera.cu, predicted[:, 1] - camera.cv)
        gate = (prior_position_m / scale) + prior_heading_rad * lever_px + config.gate_margin_px
        model_pts.append(predicted)
        model_desc.append(lm.descriptors)
        owners.append(np.full(len(predicted), idx, dtype=np.intp))
        gates.append(gate)
    if not in_view:
        return []
    pts = np.concatenate(model_pts)
    desc = np.concatenate(model_desc)
    owner = np.concatenate(owners)
    gate = np.concatenate(gates)
    img = features.points
    # gate mask (model x image), built landmark by landmark on the image keypoints inside
    # the landmark's gated bounding box (a fraction of the image each)
    mask = np.zeros((len(pts), len(img)), dtype=np.uint8)
    start = 0
    for block, g in zip(model_pts, gates, strict=True):
        stop = start + len(block)
        reach = float(g.max())
        lo, hi = block.min(axis=0) - reach, block.max(axis=0) + reach
        cand = np.flatnonzero(
            (img[:, 0] >= lo[0])
            & (img[:, 0] <= hi[0])
            & (img[:, 1] >= lo[1])
            & (img[:, 1] <= hi[1])
        )
        if len(cand):
            d2 = (block[:, 0:1] - img[cand, 0]) ** 2 + (block[:, 1:2] - img[cand, 1]) ** 2
            mask[start:stop, cand] = d2 <= (g * g)[:, None]
        start = stop
    rows = np.flatnonzero(mask.any(axis=1))
    if not len(rows):
        return []
    matcher = cv2.BFMatcher(cv2.NORM_HAMMING)
    knn = matcher.knnMatch(desc[rows], features.descriptors, k=2, mask=mask[rows])
    best = np.array(
        [
            (m[0].trainIdx, m[0].distance, m[1].distance if len(m) > 1 else np.inf)
            if m
            else (-1, np.inf, np.inf)
            for m in knn
        ]
    ).reshape(-1, 3)
    good = (best[:, 1] <= config.max_hamming) & (best[:, 1] < config.ratio * best[:, 2])
    if not good.any():
        return []
    mi = rows[good]
    ii = best[good, 0].astype(np.intp)
    # sub-pixel positions of the matched image keypoints only (a few hundred of them)
    found_all = img[ii] if features.image is None else subpixel(features.image, img[ii], config)
    offsets = np.cumsum([0] + [len(lm.points) for lm, _ in in_view])
    fits: list[_Fit] = []
    for k, (lm, _) in enumerate(in_view):
        sel = owner[mi] == k
        if int(sel.sum()) < config.min_inliers:
            continue
        local = lm.points[mi[sel] - offsets[k]]
        found = found_all[sel]
        fit = _fit_landmark(lm, local, found, ii[sel], camera, config)
        if fit is not None:
            fits.append(fit)
    return _consensus(fits, {lm.landmark_id: lm.pose for lm, _ in in_view}, camera, config)


def _fit_landmark(
    lm: Landmark,
    local: FloatArray,
    found: FloatArray,
    image_idx: NDArray[np.intp],
    camera: CeilingCamera,
    config: LandmarkConfig,
) -> _Fit | None:
    _, inl = cv2.estimateAffinePartial2D(
        local.astype(np.float32),
        found.astype(np.float32),
        method=cv2.RANSAC,
        ransacReprojThreshold=config.ransac_px,
        maxIters=200,
        confidence=0.995,
    )
    if inl is None:
        return None
    inliers = inl.ravel().astype(bool)
    if int(inliers.sum()) < config.min_inliers:
        return None
    pose = _rigid_fit(local[inliers], found[inliers])
    # re-select the inliers against the rigid (scale 1) model and refit
    res = np.hypot(*(_apply(pose, local) - found).T)
    inliers = res < config.refit_px
    if int(inliers.sum()) < config.min_inliers:
        return None
    pose = _rigid_fit(local[inliers], found[inliers])
    res = np.hypot(*(_apply(pose, local[inliers]) - found[inliers]).T)
    n = int(inliers.sum())
    rms = float(np.sqrt(np.mean(res * res) / 2.0))  # per-axis residual
    centred = local[inliers] - local[inliers].mean(axis=0)
    spread = float(np.sqrt(np.sum(centred * centred)))
    sigma_px = max(rms / math.sqrt(n), config.min_sigma_px)  # the fitted centroid's error
    sigma_phi = max(rms / max(spread, 1.0), config.min_sigma_phi)
    obs = LandmarkObservation(lm.landmark_id, Pose2(*pose), sigma_px, sigma_phi)
    return _Fit(obs, n, image_idx[inliers])


def _consensus(
    fits: list[_Fit], poses: Mapping[str, Pose2], camera: CeilingCamera, config: LandmarkConfig
) -> list[_Fit]:
    """Drop the landmarks whose robot pose (eq. 2) disagrees with the median of all."""
    if len(fits) < 3:
        return fits
    robot = [
        robot_pose_from_landmark_eq2(
            poses[f.observation.landmark_id], f.observation.image_pose, camera
        )
        for f in fits
    ]
    xy = np.array([(p.x, p.y) for p in robot])
    med = np.median(xy, axis=0)
    ref = math.atan2(
        float(np.median([math.sin(p.theta) for p in robot])),
        float(np.median([math.cos(p.theta) for p in robot])),
    )
    return [
        f
        for f, p, q in zip(fits, robot, xy, strict=True)
        if float(np.hypot(*(q - med))) <= config.consensus_m
        and abs(wrap_angle(p.theta - ref)) <= config.consensus_rad
    ]


# -- localisation and mapping ----------------------------------------------------------------
@dataclass(slots=True)
class CeilingLocaliser:
    """Localisation in a mosaic (§2.1): detect, gate-match, fit, then eq. 1-3.

    ``landmarks`` is the mosaic (by id); ``image_size`` (width, height).
    """

    camera: CeilingCamera
    landmarks: dict[str, Landmark]
    image_size: tuple[int, int] = (640, 480)
    config: LandmarkConfig = field(default_factory=LandmarkConfig)

    @property
    def mosaic(self) -> dict[str, Pose2]:
        """``M_T_i`` by landmark id (the law's mosaic)."""
        return {k: lm.pose for k, lm in self.landmarks.items()}

    def observe(
        self,
        features: Features,
        prior: Pose2,
        prior_position_m: float = 0.5,
        prior_heading_rad: float = math.radians(5.0),
    ) -> list[LandmarkObservation]:
        """The landmarks of the mosaic found among ``features`` (eq. 1 image poses)."""
        return observe_landmarks(
            features,
            list(self.landmarks.values()),
            prior,
            self.camera,
            self.image_size,
            prior_position_m=prior_position_m,
            prior_heading_rad=prior_heading_rad,
            config=self.config,
        )

    def locate(
        self,
        image: ImageU8,
        prior: Pose2,
        prior_position_m: float = 0.5,
        prior_heading_rad: float = math.radians(5.0),
    ) -> CeilingFix | None:
        """The robot pose in M from one image and a prior (None when no landmark is found)."""
        features = detect(image, self.config)
        obs = self.observe(features, prior, prior_position_m, prior_heading_rad)
        return localise(obs, self.mosaic, self.camera)


@dataclass(slots=True)
class CeilingMapper:
    """Builds the mosaic from a sequence of images (§2.2, eq. 4); M = A (module doc).

    Call :meth:`add_image` for each image in driving order with a prior pose (e.g. the
    last fix moved by odometry); the first image needs its true pose.
    """

    camera: CeilingCamera
    image_size: tuple[int, int] = (640, 480)
    config: LandmarkConfig = field(default_factory=LandmarkConfig)
    landmarks: dict[str, Landmark] = field(default_factory=dict)
    images: int = 0
    _next_id: int = 0
    _pending: dict[str, list[tuple[Pose2, float, float]]] = field(default_factory=dict)

    def localiser(self) -> CeilingLocaliser:
        """A localiser on the mosaic built so far (shares the landmarks)."""
        return CeilingLocaliser(self.camera, self.landmarks, self.image_size, self.config)

    def add_image(
        self,
        image: ImageU8,
        prior: Pose2,
        prior_position_m: float = 0.5,
        prior_heading_rad: float = math.radians(5.0),
    ) -> CeilingFix | None:
        """Localise in the mosaic (the first image: at ``prior`` exactly) and add new
        landmarks by eq. 4. Returns the fix used (None if the image could not be placed)."""
        config = self.config
        features = detect(image, config)
        first = not self.landmarks
        if first:
            fix = CeilingFix(prior, np.zeros((3, 3)), ())
            observed: list[LandmarkObservation] = []
        else:
            observed = self.localiser().observe(
                features, prior, prior_position_m, prior_heading_rad
            )
            confirmed = {k: p for k, p in self.mosaic.items() if k not in self._pending}
            located = localise(observed, confirmed, self.camera) or localise(
                observed, self.mosaic, self.camera
            )
            if located is None:
                return None
            fix = located
            self._refine(observed, fix)
        self._create(image, features, fix, confirmed=first)
        self.images += 1
        return fix

    def _refine(self, observed: Sequence[LandmarkObservation], fix: CeilingFix) -> None:
        """Eq. 4 again for the provisional landmarks seen: their pose is the mean of the
        estimates ``M_T_C C_T_i`` over the images that saw them, frozen after
        ``confirm_images`` estimates. Weights: inverse variances of the fix plus the
        observation."""
        mosaic_from_camera = fix.pose @ self.camera.robot_from_camera
        var_pos, var_h = _fix_variances(fix)
        for obs in observed:
            estimates = self._pending.get(obs.landmark_id)
            if estimates is None:
                continue
            estimates.append(
                (
                    mosaic_from_camera @ camera_from_landmark_eq1(obs.image_pose, self.camera),
                    1.0 / (var_pos + (self.camera.scale * obs.sigma_px) ** 2),
                    1.0 / (var_h + obs.sigma_phi**2),
                )
            )
            mean = fuse_poses_eq3(
                [e[0] for e in estimates], [e[1] for e in estimates], [e[2] for e in estimates]
            )
            lm = self.landmarks[obs.landmark_id]
            self.landmarks[obs.landmark_id] = replace(lm, pose=mean)
            if len(estimates) >= self.config.confirm_images:
                del self._pending[obs.landmark_id]

    @property
    def mosaic(self) -> dict[str, Pose2]:
        """``M_T_i`` by landmark id."""
        return {k: lm.pose for k, lm in self.landmarks.items()}

    def _create(
        self, image: ImageU8, features: Features, fix: CeilingFix, *, confirmed: bool
    ) -> None:
        config = self.config
        robot = fix.pose
        var_pos, var_h = _fix_variances(fix)
        if len(features) < config.min_keypoints:
            return
        width, height = self.image_size
        pts = features.points
        usable = _distinctive(features, config) & ~_near_saturated(image, pts, config)
        # centres of landmarks in view (predicted through the fix)
        taken = [predict_image_pose(lm.pose, robot, self.camera) for lm in self.landmarks.values()]
        taken_xy = np.array([(p.x, p.y) for p in taken]).reshape(-1, 2)
        cell = config.cell_px
        for v0 in np.arange(cell / 2.0, height, cell):
            for u0 in np.arange(cell / 2.0, width, cell):
                centre = np.array([u0, v0])
                if not (config.border_px <= u0 <= width - config.border_px):
                    continue
                if not (config.border_px <= v0 <= height - config.border_px):
                    continue
                if len(taken_xy) and np.hypot(*(taken_xy - centre).T).min() < config.spacing_px:
                    continue
                inside = usable & (np.hypot(*(pts - centre).T) <= config.radius_px)
                if int(inside.sum()) < config.min_keypoints:
                    continue
                sel = subpixel(image, pts[inside], config)
                mean = sel.mean(axis=0)
                local = sel - mean
                # both principal spreads: keypoints along one edge or cable slide along it
                smallest = float(np.linalg.eigvalsh(np.cov(local.T))[0])
                if math.sqrt(max(smallest, 0.0)) < config.min_spread_px:
                    continue
                image_pose = Pose2(float(mean[0]), float(mean[1]), 0.0)
                mosaic_pose = (
                    robot
                    @ self.camera.robot_from_camera
                    @ camera_from_landmark_eq1(image_pose, self.camera)
                )
                lid = f"m{self._next_id}"
                self._next_id += 1
                self.landmarks[lid] = Landmark(
                    lid,
                    mosaic_pose,
                    local,
                    features.descriptors[inside].copy(),
                    self.images,
                    (float(mean[0]), float(mean[1])),
                )
                if not confirmed:
                    self._pending[lid] = [(mosaic_pose, 1.0 / var_pos, 1.0 / var_h)]
                taken_xy = np.vstack([taken_xy, mean])
                usable &= ~inside


def _fix_variances(fix: CeilingFix) -> tuple[float, float]:
    """(position, heading) variances of a fix, floored (a known pose has none)."""
    cov = fix.covariance
    return max(float(cov[0, 0]), 1e-8), max(float(cov[2, 2]), 1e-10)


def _distinctive(features: Features, config: LandmarkConfig) -> NDArray[np.bool_]:
    """Keypoints whose descriptor is far (Hamming) from every other one of the image."""
    n = len(features)
    if n < 2:
        return np.ones(n, dtype=bool)
    matcher = cv2.BFMatcher(cv2.NORM_HAMMING)
    knn = matcher.knnMatch(features.descriptors, features.descriptors, k=2)
    out = np.ones(n, dtype=bool)
    for i, matches in enumerate(knn):
        others = [m.distance for m in matches if m.trainIdx != i]
        if others and others[0] < config.min_self_distance:
            out[i] = False
    return out


def _near_saturated(image: ImageU8, pts: FloatArray, config: LandmarkConfig) -> NDArray[np.bool_]:
    """Keypoints within ``saturation_margin_px`` of a saturated pixel (lit lamp)."""
    saturated = (image >= config.saturation_grey).astype(np.uint8)
    if not saturated.any():
        return np.zeros(len(pts), dtype=bool)
    k = 2 * config.saturation_margin_px + 1
    near = cv2.dilate(saturated, np.ones((k, k), np.uint8))
    h, w = image.shape[:2]
    u = np.clip(np.rint(pts[:, 0]).astype(int), 0, w - 1)
    v = np.clip(np.rint(pts[:, 1]).astype(int), 0, h - 1)
    return near[v, u].astype(bool)
