"""Ceiling fixes for the pose filter (issue 17, seed 002 §2.1): the upward camera's
images localised against the mission's mosaic.

:class:`CeilingFixer` is the policy around
:class:`~behaviours.laws.ceiling_landmarks.CeilingLocaliser` (detect, gate-match, fit,
eq. 1-3), used by :class:`~behaviours.sensing.localisation.Localise` on each new
:attr:`SensorFrame.ceiling` image:

* **prior**: the filter's pose taken back to the image's time (the image is older than
  the filter, which runs on the 50-100 Hz wheels), and a matching gate from the filter's
  own uncertainty: three sigmas of position and heading, clipped to
  ``gate_position_m`` and ``gate_heading_rad`` (the localiser's gate must stay smaller
  than the distance between two copies of a repeated tile, docs/ceiling-navigation.md);
* **fix**: eq. 3's fused pose with the covariance of its weights (the inverse of their
  sums). That covariance says how well the image places the robot *against the mosaic*;
  the mosaic's own error (about 0.5-1.3 cm and 0.1 degree after a loop,
  tests/test_ceiling_mapping.py) is not in it, so ``min_covariance`` is added, as the
  laser registration does;
* **fusion**: carried forward to now along the filter's motion since the image, then
  :meth:`PoseFilter.update_pose` with a chi-square gate (``gate``); a fix the gate refuses,
  an image without a fix (too few landmarks found) and an image too old are counted
  (:attr:`CeilingFixer.counts`).

No clock and no I/O here; the cost is one localisation (about 10 ms for 640x480) per
image at the camera's rate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from behaviours.laws.ceiling_landmarks import CeilingLocaliser, law_camera_for
from behaviours.laws.localisation import CHI2_999, PoseFilter
from behaviours.sensing.pose_history import PoseHistory
from executive.core.frames import Pose2, wrap_angle
from executive.core.model import CeilingCameraSpec
from executive.core.records import CeilingImage

__all__ = ["CeilingFixPolicy", "CeilingFixer", "camera_mismatch"]


@dataclass(frozen=True, slots=True)
class CeilingFixPolicy:
    """The knobs of :class:`CeilingFixer` (m, rad, s)."""

    min_covariance: tuple[float, float] = (0.01, math.radians(0.2))
    """1-sigma (position, heading) added to a fix's covariance: the mosaic's own error."""
    gate: float = CHI2_999[3]
    gate_position_m: tuple[float, float] = (0.15, 0.8)
    gate_heading_rad: tuple[float, float] = (math.radians(1.0), math.radians(8.0))
    history: float = 2.0
    """Seconds of filter poses kept to take the prior back to an image's time."""
    max_age: float = 1.0
    """An image older than this (against the frame's stamp) is not used."""


def camera_mismatch(
    spec: CeilingCameraSpec, localiser: CeilingLocaliser, ceiling_height: float
) -> str | None:
    """Why the platform's upward camera cannot use a mosaic learnt with
    ``localiser.camera`` under a ceiling ``ceiling_height`` m high (None: it can). ORB is
    used on two pyramid levels only, so the scale (f / Z) must agree within 3 %; the
    image size and the mount must be the same (1 cm, 0.5 degree)."""
    ours = law_camera_for(spec, ceiling_height)
    theirs = localiser.camera
    if (spec.width_px, spec.height_px) != tuple(localiser.image_size):
        w, h = localiser.image_size
        return (
            f"the mosaic was learnt with {w}x{h} images, the camera gives "
            f"{spec.width_px}x{spec.height_px}"
        )
    ratio = ours.scale / theirs.scale
    if not 0.97 <= ratio <= 1.03:
        return (
            f"the mosaic was learnt at {theirs.scale * 100:.2f} cm of ceiling per pixel, the "
            f"camera sees {ours.scale * 100:.2f} (focal length or height above the camera)"
        )
    a, b = ours.robot_from_camera, theirs.robot_from_camera
    if a.distance_to(b) > 0.01 or abs(wrap_angle(a.theta - b.theta)) > math.radians(0.5):
        return "the mosaic was learnt with the camera mounted elsewhere on the robot"
    return None


class CeilingFixer:
    """Localises each new ceiling image in the mosaic and feeds the pose filter."""

    def __init__(self, localiser: CeilingLocaliser, policy: CeilingFixPolicy | None = None) -> None:
        self.localiser = localiser
        self.policy = policy or CeilingFixPolicy()
        self._history = PoseHistory(self.policy.history)
        self._stamp: float | None = None
        self.counts = {"images": 0, "accepted": 0, "rejected": 0, "no-fix": 0, "stale": 0}
        self.last_fix: Pose2 | None = None

    def record_pose(self, stamp: float, pose_a: Pose2) -> None:
        """Remember the filter's pose at ``stamp`` (call after every prediction)."""
        self._history.record(stamp, pose_a)

    def _pose_at(self, stamp: float, default: Pose2) -> Pose2:
        """The filter's pose at ``stamp`` (nearest kept sample; ``default`` if none)."""
        return self._history.at(stamp, default)

    def step(self, now: float, image: CeilingImage | None, pose_filter: PoseFilter) -> bool:
        """Use ``image`` if it is new; returns whether a fix was fused into the filter."""
        if image is None or image.stamp == self._stamp:
            return False
        self._stamp = image.stamp
        self.counts["images"] += 1
        policy = self.policy
        if now - image.stamp > policy.max_age:
            self.counts["stale"] += 1
            return False
        pose_now = pose_filter.pose
        prior = self._pose_at(image.stamp, pose_now)
        cov = pose_filter.covariance
        sigma_xy = math.sqrt(max(float(np.linalg.eigvalsh(cov[:2, :2])[-1]), 0.0))
        sigma_th = math.sqrt(max(float(cov[2, 2]), 0.0))
        fix = self.localiser.locate(
            image.image,
            prior,
            prior_position_m=float(np.clip(3.0 * sigma_xy, *policy.gate_position_m)),
            prior_heading_rad=float(np.clip(3.0 * sigma_th, *policy.gate_heading_rad)),
        )
        if fix is None:
            self.counts["no-fix"] += 1
            return False
        measured = fix.pose @ (prior.inverse() @ pose_now)  # carried forward to now
        sx, sth = policy.min_covariance
        covariance = np.asarray(fix.covariance, dtype=float) + np.diag([sx * sx, sx * sx, sth**2])
        if pose_filter.update_pose(measured, covariance, gate=policy.gate):
            self.counts["accepted"] += 1
            self.last_fix = measured
            return True
        self.counts["rejected"] += 1
        return False
