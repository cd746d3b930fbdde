"""Rotations as theta-u vectors and the SE(3) exponential map (for the servoing laws).

:mod:`executive.core.frames` holds the rigid transforms (:class:`Transform3`); it has no
axis-angle representation, which PBVS (thesis eq. 3.25, 3.34, seed 000 lines 2600-2750)
and a free-flying camera's motion need. These small helpers add exactly that, on top of
``Transform3``, with ViSP's conventions (``vpThetaUVector``, ``vpExponentialMap``):

* ``theta_u`` is the rotation vector ``theta * u``, ``u`` a unit axis, ``theta`` in
  [0, pi];
* a velocity twist is ``(v, omega)``: the linear velocity of the frame's origin and its
  angular velocity, both expressed in that frame (ViSP's camera velocity ``v_c``);
* :func:`se3_exponential` is the displacement ``cMc'`` of a frame moving at a constant
  twist for ``dt`` seconds (``vpExponentialMap::direct``): a camera at ``wMc`` moves to
  ``wMc @ se3_exponential(v, dt)``.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from executive.core.frames import FloatArray, Transform3

__all__ = [
    "rotation_from_theta_u",
    "se3_exponential",
    "skew",
    "theta_u_from_rotation",
    "transform_from_pose_vector",
]


def skew(w: ArrayLike) -> FloatArray:
    """The matrix ``[w]x`` with ``[w]x a = w x a``."""
    x, y, z = np.asarray(w, dtype=float)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def rotation_from_theta_u(theta_u: ArrayLike) -> FloatArray:
    """Rodrigues' formula: ``R = I + sin(t) [u]x + (1 - cos(t)) [u]x^2``."""
    tu = np.asarray(theta_u, dtype=float)
    theta = float(np.linalg.norm(tu))
    k = skew(tu)
    if theta < 1e-8:
        return np.eye(3) + k + 0.5 * (k @ k)
    return (
        np.eye(3) + (math.sin(theta) / theta) * k + ((1.0 - math.cos(theta)) / theta**2) * (k @ k)
    )


def theta_u_from_rotation(rotation: ArrayLike) -> FloatArray:
    """The rotation vector ``theta u`` of a rotation matrix, theta in [0, pi].

    Near theta = pi the antisymmetric part vanishes, so the axis is taken from the
    symmetric part ``(R + I) / 2 = u u^T`` (its largest column), with the sign that the
    antisymmetric part still carries; at exactly pi either sign is the same rotation.
    """
    r = np.asarray(rotation, dtype=float)
    cos_t = 0.5 * (float(np.trace(r)) - 1.0)
    w = 0.5 * np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    sin_t = float(np.linalg.norm(w))
    theta = math.atan2(sin_t, cos_t)  # acos would lose half the digits near 0 and pi
    if theta < 1e-8:
        return w  # sin(theta) / theta -> 1
    if theta < math.pi - 1e-4:
        return (theta / sin_t) * w
    b = 0.5 * (r + np.eye(3))
    col = int(np.argmax(np.diag(b)))
    u = b[:, col] / math.sqrt(max(b[col, col], 1e-300))
    if float(u @ w) < 0.0:
        u = -u
    return theta * u


def se3_exponential(twist: ArrayLike, dt: float) -> Transform3:
    """Displacement after moving at ``twist = (v, omega)`` (own frame) for ``dt`` seconds.

    ``R = exp([omega dt]x)`` and ``t = V (v dt)`` with
    ``V = I + (1 - cos t) / t^2 [w]x + (t - sin t) / t^3 [w]x^2``, ``w = omega dt``,
    ``t = |w|`` (the closed form of ``vpExponentialMap::direct``).
    """
    tw = np.asarray(twist, dtype=float) * dt
    v, w = tw[:3], tw[3:]
    theta = float(np.linalg.norm(w))
    k = skew(w)
    k2 = k @ k
    if theta < 1e-8:
        big_v = np.eye(3) + 0.5 * k + k2 / 6.0
    else:
        big_v = (
            np.eye(3)
            + ((1.0 - math.cos(theta)) / theta**2) * k
            + ((theta - math.sin(theta)) / theta**3) * k2
        )
    return Transform3(rotation_from_theta_u(w), big_v @ v)


def transform_from_pose_vector(pose: ArrayLike) -> Transform3:
    """``(tx, ty, tz, tux, tuy, tuz)`` -> transform (``vpHomogeneousMatrix(t, theta u)``)."""
    p = np.asarray(pose, dtype=float)
    if p.shape != (6,):
        raise ValueError(f"a pose vector has 6 numbers (t, theta u), got shape {p.shape}")
    return Transform3(rotation_from_theta_u(p[3:]), p[:3].copy())
