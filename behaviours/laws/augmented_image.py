"""The augmented (virtual) image and the reliability of one camera's view of a target.

Seed 000, section 3.6.1-3.6.2 (lines 3146-3225): instead of servoing on the raw image, in
which features "can disappear at any moment", the executive servoes on an *augmented
image*: the real 2D cues of the cameras plus the missing ones reconstructed by projecting
the aircraft model (here: the target's points in F) through the current localisation.
Servoing on it stays sound while the localisation is accurate, so it is meant for
temporary losses; the thesis's experiments keep servoing while at least two real points
remain (line 3418), which is :data:`MIN_REAL_POINTS`.

Section 3.7 (lines 3560-3580): each visual-servoing node computes a *reliability factor*
"evaluated on the accuracy of the feature detection and resulting pose estimation"; the
most reliable node drives the base, the others keep their pan-tilt units on the target.
The thesis gives no formula. Ours (:func:`reliability`) multiplies what it names:

* the share of the target's points that are really detected (detection),
* ``exp(-r / r0)`` with ``r`` the RMS distance (px) between the detected points and the
  same points projected through the pose estimate (agreement of detection and pose),
* a margin factor that falls to 0 as the detected points approach the image border
  (a point about to leave the image is the next one lost).

Conventions: normalised image coordinates ``x = X/Z`` (ViSP), as
:mod:`behaviours.laws.interaction`. Pure numpy.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from behaviours.laws.interaction import point_interaction_matrix_eq_3_17
from executive.core.frames import FloatArray

__all__ = [
    "MIN_REAL_POINTS",
    "AugmentedImage",
    "augment",
    "feature_motion_eq_3_16",
    "filter_features",
    "filter_gain",
    "reliability",
]

MIN_REAL_POINTS = 2
"""Servoing continues on the augmented image while this many real points remain."""


@dataclass(frozen=True, slots=True)
class AugmentedImage:
    """All N points of a target in one camera: ``xy`` (N, 2) normalised, depths ``z`` (N,)
    and ``real`` (N,) True where the point was detected, False where reconstructed."""

    xy: FloatArray
    z: FloatArray
    real: np.ndarray

    @property
    def n_real(self) -> int:
        return int(np.count_nonzero(self.real))

    @property
    def n_reconstructed(self) -> int:
        return int(self.real.size - self.n_real)


def augment(
    detected: Mapping[int, tuple[float, float]], xy_estimate: ArrayLike, z_estimate: ArrayLike
) -> AugmentedImage:
    """Eq. of section 3.6.1: the real points ``detected`` (point index -> normalised
    (x, y)) completed by the projections ``xy_estimate`` (N, 2) of the model through the
    pose estimate; depths always from the pose estimate (the thesis's "relative
    localisation")."""
    xy = np.array(xy_estimate, dtype=float).reshape(-1, 2)
    real = np.zeros(xy.shape[0], dtype=bool)
    for k, p in detected.items():
        if 0 <= k < xy.shape[0]:
            xy[k] = p
            real[k] = True
    return AugmentedImage(xy, np.asarray(z_estimate, dtype=float).reshape(-1), real)


def reliability(
    image: AugmentedImage,
    xy_estimate: ArrayLike,
    focal_px: float,
    half_size_px: tuple[float, float],
    residual_scale_px: float = 5.0,
    margin_px: float = 20.0,
) -> float:
    """The reliability factor of one camera's view (module docstring), in [0, 1]; 0 when
    fewer than :data:`MIN_REAL_POINTS` real points remain."""
    n = image.real.size
    if n == 0 or image.n_real < MIN_REAL_POINTS:
        return 0.0
    est = np.asarray(xy_estimate, dtype=float).reshape(-1, 2)[image.real]
    real = image.xy[image.real]
    residual = float(np.sqrt(np.mean(np.sum((real - est) ** 2, axis=1)))) * focal_px
    px = np.abs(real) * focal_px
    room = np.min(np.array(half_size_px, dtype=float)[None, :] - px)
    margin = min(1.0, max(0.0, room / margin_px))
    return (image.n_real / n) * math.exp(-residual / residual_scale_px) * margin


def feature_motion_eq_3_16(
    xy: ArrayLike, depth: ArrayLike, robot_jacobian: ArrayLike, dq: ArrayLike
) -> FloatArray:
    """How the image points move for a small robot motion ``dq = (ds, dtheta, dpan,
    dtilt)``: ``ds = L_s J dq`` (eq. 3.16 with the robot Jacobian of eq. 3.2, ``J`` 6x4
    from q to the camera twist, ``L_s`` the stacked point interaction matrix of eq.
    3.17-3.18 at ``xy`` (N, 2) normalised with depths ``depth`` (N,)). Returns (N, 2)."""
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    lmat = point_interaction_matrix_eq_3_17(xy, depth)
    motion = lmat @ np.asarray(robot_jacobian, dtype=float) @ np.asarray(dq, dtype=float)
    return motion.reshape(-1, 2)


def filter_features(
    previous: ArrayLike, motion: ArrayLike, measured: ArrayLike, gain: float
) -> FloatArray:
    """A predict-correct (alpha) filter of image points: the previous estimate moved by
    the robot's own measured motion (:func:`feature_motion_eq_3_16`, wheels, IMU and
    pan-tilt encoders since the previous image), then pulled by ``gain`` in (0, 1]
    towards the new detections. Because the prediction carries the motion, a small gain
    averages the detection noise over about ``2 / gain`` images without the lag a plain
    exponential smoothing has while the robot moves (the servo's final accuracy is set
    by this noise: 0.5 px on two points 0.5 m apart at 3 m is 2 cm of depth)."""
    if not 0.0 < gain <= 1.0:
        raise ValueError(f"gain must be in (0, 1], got {gain}")
    predicted = np.asarray(previous, dtype=float) + np.asarray(motion, dtype=float)
    return predicted + gain * (np.asarray(measured, dtype=float) - predicted)


def filter_gain(
    variance: float,
    motion: ArrayLike,
    detection_sigma: float,
    model_share: float,
    still_sigma: float,
) -> tuple[float, float]:
    """The gain of :func:`filter_features` as a scalar Kalman filter (one variance for
    every coordinate of a camera's points, normalised units): the prediction's variance
    grows by ``still_sigma^2`` per image plus ``(model_share * |motion|_max)^2``, the part
    of the predicted image motion the wheel/IMU model may miss (slip); the gain weighs it
    against the detector's ``detection_sigma^2``. Moving, the gain is near 1 (the
    detections lead); as the servo converges and the robot stills, it falls towards
    ``still_sigma / detection_sigma`` and the estimate averages the noise over more
    images. Returns ``(gain, variance after the correction)``."""
    shift = float(np.max(np.abs(motion))) if np.size(motion) else 0.0
    predicted = variance + still_sigma**2 + (model_share * shift) ** 2
    gain = predicted / (predicted + detection_sigma**2)
    return gain, (1.0 - gain) * predicted
