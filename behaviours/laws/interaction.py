"""Interaction matrices: image points (IBVS, eq. 3.17-3.18) and the pose (PBVS, eq. 3.35).

Seed 000 lines 2130-2290 (IBVS: error eq. 3.3, projection eq. 3.11, point interaction
matrix eq. 3.12-3.17, stacked eq. 3.18) and 2600-2760 (PBVS: error eq. 3.25, its
interaction matrix eq. 3.30-3.35); appendix A.4 (eq. A.67-A.69).

Conventions: ViSP's. A camera twist ``v_c = (v, omega)`` is expressed in the camera frame
C (z optical axis, x right, y down); image points are in *normalised* coordinates
``x = X / Z, y = Y / Z`` (the thesis writes eq. 3.17 in focal-plane units ``f X / Z``;
with ``f = 1`` the two are the same, and pixels are ``u = c_x + f_x x``, so a pixel
interaction matrix is ``diag(f_x, f_y)`` times this one). ``s_dot = L v_c`` for a point
fixed in the world.

Depth Z: from the stereo pair (:func:`depth_from_disparity`; the two cameras of a unit share
their orientation, so the pair is rectified by construction, baseline along x_C) or from a
pose estimate (:func:`project_points` through ``cMo``).

PBVS (eq. 3.25): ``e = (c_t_O - c*_t_O, theta u)``, ``c_t_O`` the target's centroid O in
C and ``theta u`` the rotation ``c*Rc`` that takes the desired camera frame to the current
one (the thesis: "the axis around which one must turn ... to go from the current camera
frame to the object frame", the desired camera frame having the object's orientation; in
general the rotation is measured against the desired camera frame, as in Chaumette &
Hutchinson 2006, the thesis's reference). Its interaction matrix (eq. 3.35)::

    L = [[-I3, [c_t_O]x], [0, L_theta_u]]
    L_theta_u = I3 + theta/2 [u]x + (1 - sinc(theta) / sinc^2(theta/2)) [u]x^2   (eq. 3.34)

with sinc(x) = sin(x)/x. The extracted eq. 3.34 prints ``I3 - alpha/2 r^ + ...``: that
sign belongs to the opposite rotation ``cRc*`` (Malis's convention, which the thesis
cites), whose derivative also carries an overall minus (``d(theta u)/dt = -(I - theta/2
[u]x + ...) omega``); the printed pair mixes the two. For ``theta u`` of ``c*Rc`` (ours,
ViSP's ``vpFeatureThetaU::cdRc``), ``c*Rc(t + dt) = c*Rc(t) exp([omega dt]x)`` and the
derivative is the inverse right Jacobian of SO(3), with ``+ theta/2``: the tests check it
against finite differences. ``L_theta_u u = u`` either way, so the rotation part of PBVS
turns about a fixed axis with ``theta(t) = theta_0 exp(-lambda t)``.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from behaviours.laws.theta_u import skew, theta_u_from_rotation
from executive.core.frames import FloatArray, Transform3

__all__ = [
    "centroid_interaction_matrix",
    "depth_from_disparity",
    "ibvs_error_eq_3_3",
    "l_theta_u_eq_3_34",
    "normalised_from_pixels",
    "pbvs_error_eq_3_25",
    "pbvs_interaction_matrix_eq_3_35",
    "pixels_from_normalised",
    "point_interaction_matrix_eq_3_17",
    "project_points",
]


def project_points(c_m_o: Transform3, points_o: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Eq. 3.11 with f = 1: points in the object frame -> normalised ``(x, y)`` (N, 2) and
    their depths Z (N,) in the camera frame C."""
    pts_c = c_m_o.apply(np.asarray(points_o, dtype=float).reshape(-1, 3))
    z = pts_c[:, 2]
    return pts_c[:, :2] / z[:, None], z


def point_interaction_matrix_eq_3_17(xy: ArrayLike, depth: ArrayLike) -> FloatArray:
    """Eq. 3.17 (one point) stacked as eq. 3.18 (N points): the (2N, 6) matrix ``L`` with
    ``d(x1, y1, x2, y2, ...)/dt = L v_c``, normalised coordinates, depths Z > 0::

        L_i = [[-1/Z, 0, x/Z, x y, -(1 + x^2), y],
               [0, -1/Z, y/Z, 1 + y^2, -x y, -x]]
    """
    p = np.asarray(xy, dtype=float).reshape(-1, 2)
    z = np.broadcast_to(np.asarray(depth, dtype=float), (p.shape[0],))
    x, y = p[:, 0], p[:, 1]
    inv_z = 1.0 / z
    out = np.empty((2 * p.shape[0], 6))
    rx, ry = out[0::2], out[1::2]
    rx[:, 0] = -inv_z
    rx[:, 1] = 0.0
    rx[:, 2] = x * inv_z
    rx[:, 3] = x * y
    rx[:, 4] = -(1.0 + x * x)
    rx[:, 5] = y
    ry[:, 0] = 0.0
    ry[:, 1] = -inv_z
    ry[:, 2] = y * inv_z
    ry[:, 3] = 1.0 + y * y
    ry[:, 4] = -x * y
    ry[:, 5] = -x
    return out


def centroid_interaction_matrix(xy: ArrayLike, depth: ArrayLike) -> FloatArray:
    """The (2, 6) interaction matrix of the points' centroid ``(mean x, mean y)``: the mean
    of the points' x rows and of their y rows of eq. 3.17 (the derivative of a mean is the
    mean of the derivatives). The feature of the track-feature behaviour (lines 745-764)."""
    lmat = point_interaction_matrix_eq_3_17(xy, depth)
    return np.vstack((lmat[0::2].mean(axis=0), lmat[1::2].mean(axis=0)))


def ibvs_error_eq_3_3(xy: ArrayLike, xy_desired: ArrayLike) -> FloatArray:
    """Eq. 3.3: ``e_I = s - s*`` as the (2N,) vector ``(x1 - x1*, y1 - y1*, ...)``."""
    return (np.asarray(xy, dtype=float) - np.asarray(xy_desired, dtype=float)).reshape(-1)


def depth_from_disparity(x_left: ArrayLike, x_right: ArrayLike, baseline: float) -> FloatArray:
    """Depth of points seen by both cameras of a unit: ``Z = b / (x_left - x_right)``.

    ``x_left``, ``x_right``: normalised abscissae of the same points in the left and right
    cameras (same orientation, the left camera ``baseline`` metres to the left, i.e. at
    ``-b`` along x_C of the right one). A non-positive disparity gives ``inf``.
    """
    disparity = np.asarray(x_left, dtype=float) - np.asarray(x_right, dtype=float)
    with np.errstate(divide="ignore"):
        return np.where(disparity > 0.0, baseline / disparity, np.inf)


def normalised_from_pixels(uv: ArrayLike, camera_matrix: ArrayLike) -> FloatArray:
    """Pixels (N, 2) -> normalised coordinates through the intrinsics ``K`` (no skew)."""
    k = np.asarray(camera_matrix, dtype=float)
    p = np.asarray(uv, dtype=float).reshape(-1, 2)
    return np.column_stack(((p[:, 0] - k[0, 2]) / k[0, 0], (p[:, 1] - k[1, 2]) / k[1, 1]))


def pixels_from_normalised(xy: ArrayLike, camera_matrix: ArrayLike) -> FloatArray:
    """Normalised coordinates (N, 2) -> pixels through the intrinsics ``K`` (no skew)."""
    k = np.asarray(camera_matrix, dtype=float)
    p = np.asarray(xy, dtype=float).reshape(-1, 2)
    return np.column_stack((k[0, 2] + k[0, 0] * p[:, 0], k[1, 2] + k[1, 1] * p[:, 1]))


def pbvs_error_eq_3_25(
    c_m_o: Transform3, cd_m_o: Transform3, centroid_o: ArrayLike = (0.0, 0.0, 0.0)
) -> FloatArray:
    """Eq. 3.25: ``e_P = (c_t_O - c*_t_O, theta u(c*Rc))`` (6,).

    ``c_m_o`` and ``cd_m_o`` are the object's pose in the current and the desired camera
    frames; ``centroid_o`` is the point O (the target's centroid) in the object frame.
    """
    o = np.asarray(centroid_o, dtype=float)
    cd_r_c = cd_m_o.rotation @ c_m_o.rotation.T
    out = np.empty(6)
    out[:3] = c_m_o.apply(o) - cd_m_o.apply(o)
    out[3:] = theta_u_from_rotation(cd_r_c)
    return out


def _sinc(x: float) -> float:
    return 1.0 if abs(x) < 1e-8 else math.sin(x) / x


def l_theta_u_eq_3_34(theta_u: ArrayLike) -> FloatArray:
    """Eq. 3.34: ``d(theta u)/dt = L_theta_u omega_c`` for ``theta u`` of ``c*Rc``."""
    tu = np.asarray(theta_u, dtype=float)
    theta = float(np.linalg.norm(tu))
    if theta < 1e-12:
        return np.eye(3)
    u_x = skew(tu / theta)
    coeff = 1.0 - _sinc(theta) / _sinc(0.5 * theta) ** 2
    return np.eye(3) + 0.5 * theta * u_x + coeff * (u_x @ u_x)


def pbvs_interaction_matrix_eq_3_35(c_t_o: ArrayLike, theta_u: ArrayLike) -> FloatArray:
    """Eq. 3.35: the 6x6 ``L_PBVS = [[-I3, [c_t_O]x], [0, L_theta_u]]``, ``e_dot = L v_c``.

    ``c_t_o`` is the current position of O in C (eq. 3.32), ``theta_u`` the rotation part
    of the error (eq. 3.34).
    """
    out = np.zeros((6, 6))
    out[:3, :3] = -np.eye(3)
    out[:3, 3:] = skew(c_t_o)
    out[3:, 3:] = l_theta_u_eq_3_34(theta_u)
    return out
