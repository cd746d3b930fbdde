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

from executive.core.frames import FloatArray

__all__ = ["MIN_REAL_POINTS", "AugmentedImage", "augment", "reliability"]

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
