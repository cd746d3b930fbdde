"""The target's pose ``cMo`` from its detected points: OpenCV's ``solvePnP``.

PBVS (thesis §3.4, seed 000 lines 2600-2760) servoes on the pose of the target in the
camera frame; the thesis computes it from the image points and the known target geometry
("a pose calculation is made", lines 2782-2790). We use OpenCV:

* planar targets (all points on one plane, the usual case: a panel, a port, a square of
  four marks): ``SOLVEPNP_IPPE`` (Collins & Bartoli 2014), exact and fast for >= 4
  points. A plane seen from far has two nearly equally good poses (the flip ambiguity);
  given a ``guess`` (the previous tick's pose) we keep the solution closer to it, else the
  one with the smaller reprojection error;
* non-planar targets: ``SOLVEPNP_ITERATIVE`` (Levenberg-Marquardt from a DLT start, which
  needs >= 6 points, or from ``guess``); with fewer than 6 points and no guess,
  ``SOLVEPNP_SQPNP`` (>= 3 points), a global solver.

Image points are pixels with intrinsics ``K``, or normalised coordinates (``K = None``).
No distortion: sim2d's cameras are pinholes and the real ones are rectified upstream.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import ArrayLike

from behaviours.laws.theta_u import theta_u_from_rotation
from executive.core.frames import Transform3

__all__ = ["COLLINEAR", "SUSPECT_RESIDUAL", "camera_pose_from_points", "is_planar", "is_well_posed"]

SUSPECT_RESIDUAL = 0.05
"""An IPPE pose whose RMS reprojection residual exceeds this fraction of the image
points' spread is checked against SQPnP (see :func:`camera_pose_from_points`)."""


def is_planar(points_o: ArrayLike, tolerance: float = 1e-6) -> bool:
    """Whether the points lie on one plane (up to ``tolerance`` times their spread)."""
    pts = np.asarray(points_o, dtype=float).reshape(-1, 3)
    if pts.shape[0] <= 3:
        return True
    centred = pts - pts.mean(axis=0)
    s = np.linalg.svd(centred, compute_uv=False)
    return bool(s[2] <= tolerance * max(s[0], 1e-300))


COLLINEAR = 0.05
"""Points whose second principal spread is below this fraction of the first are treated as
collinear by :func:`is_well_posed`."""


def is_well_posed(points_o: ArrayLike, collinear: float = COLLINEAR) -> bool:
    """Whether the target's points determine a camera pose (thesis §3.4's "pose
    calculation", lines 2782-2790): at least 4 points, not (nearly) on one line.

    Three points have up to four P3P solutions, two or fewer a continuum; points on a line
    leave the rotation about that line unobservable (a wing's leading edge seen as three
    marks along it), so the solver returns one pose of a family and PBVS (eq. 3.25) servoes
    on noise. ``collinear``: the ratio of the second to the first singular value of the
    centred points below which they count as one line.
    """
    pts = np.asarray(points_o, dtype=float).reshape(-1, 3)
    if pts.shape[0] < 4:
        return False
    s = np.linalg.svd(pts - pts.mean(axis=0), compute_uv=False)
    return bool(s[1] > collinear * max(s[0], 1e-300))


def camera_pose_from_points(
    points_o: ArrayLike,
    image_points: ArrayLike,
    camera_matrix: ArrayLike | None = None,
    guess: Transform3 | None = None,
) -> Transform3:
    """``cMo`` from N >= 4 object points (N, 3, object frame, m) and their images (N, 2).

    ``camera_matrix``: the 3x3 intrinsics ``K`` when ``image_points`` are pixels; None
    when they are normalised coordinates. ``guess``: a previous ``cMo`` (disambiguates a
    plane; starts the iterative solver). Raises ValueError when OpenCV finds no pose.
    """
    obj = np.ascontiguousarray(np.asarray(points_o, dtype=np.float64).reshape(-1, 3))
    img = np.ascontiguousarray(np.asarray(image_points, dtype=np.float64).reshape(-1, 2))
    n = obj.shape[0]
    if n < 4 or img.shape[0] != n:
        raise ValueError(f"solvePnP needs >= 4 matching points, got {n} and {img.shape[0]}")
    k = np.eye(3) if camera_matrix is None else np.asarray(camera_matrix, dtype=np.float64)
    dist = np.zeros(4)
    if is_planar(obj):
        ok, rvecs, tvecs, _ = cv2.solvePnPGeneric(obj, img, k, dist, flags=cv2.SOLVEPNP_IPPE)
        candidates = [_transform(r, t) for r, t in zip(rvecs, tvecs, strict=True)] if ok else []
        errors = [_reprojection_rms(c, obj, img, k) for c in candidates]
        candidates = [c for c, err in zip(candidates, errors, strict=True) if np.isfinite(err)]
        errors = [err for err in errors if np.isfinite(err)]
        spread = float(np.sqrt(np.mean(np.sum((img - img.mean(axis=0)) ** 2, axis=1))))
        if not errors or min(errors) > SUSPECT_RESIDUAL * spread:
            # OpenCV 4.x/5.0's IPPE returns a wrong pose for an exactly fronto-parallel
            # plane turned by pi about the optical axis (residual ~ the target's size);
            # a residual above 5 % of the target's extent is checked with the global SQPnP
            ok, rvec, tvec = cv2.solvePnP(obj, img, k, dist, flags=cv2.SOLVEPNP_SQPNP)
            if ok:
                pose = _transform(rvec, tvec)
                if np.isfinite(err := _reprojection_rms(pose, obj, img, k)):
                    candidates.append(pose)
                    errors.append(err)
        if not candidates:
            raise ValueError("solvePnP (IPPE, SQPnP) found no pose")
        best = min(errors)
        if guess is not None:
            plausible = [
                c for c, err in zip(candidates, errors, strict=True) if err <= 2 * best + 1e-12
            ]
            return min(plausible, key=lambda c: _distance(c, guess))
        return candidates[int(np.argmin(errors))]
    if guess is not None or n >= 6:
        flags = cv2.SOLVEPNP_ITERATIVE
        use_guess = guess is not None
        rvec0 = (
            cv2.Rodrigues(guess.rotation)[0] if guess is not None else np.zeros((3, 1))
        ).astype(np.float64)
        tvec0 = (guess.translation.reshape(3, 1) if guess is not None else np.zeros((3, 1))).astype(
            np.float64
        )
        ok, rvec, tvec = cv2.solvePnP(obj, img, k, dist, rvec0, tvec0, use_guess, flags)
    else:
        ok, rvec, tvec = cv2.solvePnP(obj, img, k, dist, flags=cv2.SOLVEPNP_SQPNP)
    if not ok:
        raise ValueError("solvePnP found no pose")
    return _transform(rvec, tvec)


def _transform(rvec: ArrayLike, tvec: ArrayLike) -> Transform3:
    rotation, _ = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64))
    return Transform3(np.asarray(rotation, dtype=float), np.asarray(tvec, dtype=float).ravel())


def _reprojection_rms(c_m_o: Transform3, obj: np.ndarray, img: np.ndarray, k: np.ndarray) -> float:
    pts = c_m_o.apply(obj)
    proj = pts[:, :2] / pts[:, 2:3]
    pix = np.column_stack((k[0, 2] + k[0, 0] * proj[:, 0], k[1, 2] + k[1, 1] * proj[:, 1]))
    return float(np.sqrt(np.mean(np.sum((pix - img) ** 2, axis=1))))


def _distance(a: Transform3, b: Transform3) -> float:
    """Rotation angle between two poses plus their translation difference (m ~ rad)."""
    angle = float(np.linalg.norm(theta_u_from_rotation(a.rotation @ b.rotation.T)))
    return angle + float(np.linalg.norm(a.translation - b.translation))
