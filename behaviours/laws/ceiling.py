"""Localisation from ceiling landmarks (seed 002, Blanc et al. 2004, §2.1-2.2, eq. 1-4).

A pure law module: no OpenCV, no clock, no I/O. A landmark ``m_i`` of the ceiling mosaic
has a planar pose ``M_T_i`` in the mosaic frame M (a 2D frame lying on the ceiling plane);
a tracker gives its planar pose ``I_L_i = (r_i, p_i)`` in the image (eq. 1). With the
calibrated camera (focal length f in pixels, principal point c, ceiling height Z above the
optical centre) the image pose becomes a metric pose of the landmark in the camera frame,
``C_T_i = (r_i, (Z / f) (p_i - c))`` (the paper writes ``Z/f p_i``; its image origin is the
principal point), and the robot pose follows by eq. 2, ``M_T_C = M_T_i (C_T_i)^-1``.
Several landmarks are fused by the weighted mean of eq. 3, and a new landmark is added to
the mosaic by chaining through one already in it (eq. 4, ``M_T_i = M_T_j j_T_i``).

Planar transforms are :class:`executive.core.frames.Pose2` (SE(2), ``@`` composes,
``inverse()``), reused rather than duplicated; an image pose ``(u, v, phi)`` is a Pose2 in
pixel units.

Image-axis conventions (camera looking UP)
------------------------------------------
The camera frame C is ViSP's (x right in the image, y down in the image, z the optical
axis) with the optical axis pointing **up**, vertical. Its horizontal axes (x_C, y_C) then
satisfy ``x_C x y_C = z_C = up``: seen from above they form a *proper*, counter-clockwise
2D frame, like the robot frame R (x forward, y left, z up) and the mosaic frame M (whose
normal is taken upwards). So, with pixel coordinates ``u`` (right) and ``v`` (down),

    X_C = (Z / f) (u - c_u),   Y_C = (Z / f) (v - c_v)

is a similarity with positive determinant, and an image angle ``phi`` measured **from +u
towards +v** is a counter-clockwise angle seen from above. No sign flip is needed; the
mistake to avoid is the floor-camera habit ``atan2(-dv, du)``. The "mirror" is only in the
display: drawn on a screen (u right, v down) the image shows the ceiling as seen from
below, the mirror image of a top-down map, so on the screen a counter-clockwise landmark
angle appears clockwise.

The paper takes the camera frame equal to the robot frame; :class:`CeilingCamera` allows a
constant planar mount ``robot_from_camera`` (§3: "a constant rigid transformation, due to
extrinsic calibration parameters"). With the default identity mount, x_C is the robot's
forward axis and y_C its left: a landmark ahead-left of the robot appears at ``u > c_u``,
``v > c_v``, and when the robot turns counter-clockwise by ``a``, every landmark's image
angle ``phi`` decreases by ``a``.

Eq. 3 weights
-------------
The paper weights each landmark by its tracker's quality factor ``w_i``. We use inverse
variances, which make the weighted mean the minimum-variance unbiased combination of
independent estimates and give the covariance the pose filter needs. A landmark seen with
pixel noise ``sigma_px`` (on its image position) and ``sigma_phi`` (on its image angle) at
the metric offset ``P = C_P_i`` from the optical axis gives a robot position with error
``(Z/f) dp`` plus the lever-arm term ``|P| dphi`` (the heading error swings the landmark
offset about the camera), so we take the per-axis (isotropic) position variance

    var_pos_i = (Z/f sigma_px)^2 + |P|^2 sigma_phi^2 / 2      (half of the covariance trace)

and the heading variance ``var_h_i = sigma_phi^2``. Positions are averaged with weights
``1/var_pos_i``; headings by the weighted *circular* mean ``atan2(sum w sin, sum w cos)``
with ``1/var_h_i`` (an arithmetic mean of angles fails across +-pi). The fused variances are
``1 / sum(1/var)``; correlations between landmarks and between a landmark's position and
heading errors are ignored.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from executive.core.frames import FloatArray, Pose2, wrap_angle

__all__ = [
    "CeilingCamera",
    "CeilingFix",
    "LandmarkObservation",
    "camera_from_landmark_eq1",
    "fuse_poses_eq3",
    "landmark_in_mosaic_eq4",
    "landmark_pose_variances",
    "localise",
    "relative_landmark_pose",
    "robot_pose_from_landmark_eq2",
    "weighted_circular_mean",
]


@dataclass(frozen=True, slots=True)
class CeilingCamera:
    """A calibrated upward-looking pinhole camera (optical axis vertical, up).

    ``focal_px`` is f in pixels (square pixels), ``(cu, cv)`` the principal point,
    ``height`` Z the distance from the optical centre up to the ceiling plane (m).
    ``robot_from_camera`` places the camera's projection on the floor in the robot frame
    (x, y offset of the optical axis and yaw of x_C from x_R); identity as in the paper.
    """

    focal_px: float
    cu: float
    cv: float
    height: float
    robot_from_camera: Pose2 = field(default_factory=lambda: Pose2(0.0, 0.0, 0.0))

    def __post_init__(self) -> None:
        if not (self.focal_px > 0.0 and self.height > 0.0):
            raise ValueError("focal_px and height must be positive")

    @property
    def scale(self) -> float:
        """The scale factor Z / f of eq. 1 and 4 (metres on the ceiling per pixel)."""
        return self.height / self.focal_px


@dataclass(frozen=True, slots=True)
class LandmarkObservation:
    """One tracked landmark: its image pose ``(u, v, phi)`` (eq. 1) and 1-sigma noise."""

    landmark_id: str
    image_pose: Pose2
    sigma_px: float = 1.0
    sigma_phi: float = math.radians(1.0)

    def __post_init__(self) -> None:
        if not (self.sigma_px > 0.0 and self.sigma_phi > 0.0):
            raise ValueError("sigma_px and sigma_phi must be positive (they set eq. 3 weights)")


@dataclass(frozen=True, slots=True)
class CeilingFix:
    """The fused robot pose in M (eq. 3) with a diagonal (x, y, heading) covariance."""

    pose: Pose2
    covariance: FloatArray
    used: tuple[str, ...]


def camera_from_landmark_eq1(image_pose: Pose2, camera: CeilingCamera) -> Pose2:
    """Eq. 1 lifted to the ceiling: ``C_T_i = (r_i, (Z/f) (p_i - c))``.

    The landmark's pose in the camera frame projected on the ceiling (metric, proper 2D
    frame (x_C, y_C), see the module docstring for why no axis flip is needed).
    """
    k = camera.scale
    return Pose2(k * (image_pose.x - camera.cu), k * (image_pose.y - camera.cv), image_pose.theta)


def robot_pose_from_landmark_eq2(
    mosaic_from_landmark: Pose2, image_pose: Pose2, camera: CeilingCamera
) -> Pose2:
    """Eq. 2: ``M_T_C = M_T_i (C_T_i)^-1``, then the robot ``M_T_R = M_T_C (R_T_C)^-1``."""
    mosaic_from_camera = (
        mosaic_from_landmark @ camera_from_landmark_eq1(image_pose, camera).inverse()
    )
    return mosaic_from_camera @ camera.robot_from_camera.inverse()


def relative_landmark_pose(image_j: Pose2, image_i: Pose2, camera: CeilingCamera) -> Pose2:
    """``j_T_i``: landmark i in landmark j's frame from one image showing both (§2.2).

    ``j_L_i = (I_L_j)^-1 I_L_i`` in pixels (the paper's printed ``0_L_i = 0_L_i^(k) I_L_i^(k)``
    is a typo for this), projected to the ceiling by scaling its translation by Z/f; the
    principal point cancels in the difference.
    """
    rel = image_j.inverse() @ image_i
    return Pose2(camera.scale * rel.x, camera.scale * rel.y, rel.theta)


def landmark_in_mosaic_eq4(
    mosaic_from_j: Pose2, image_j: Pose2, image_i: Pose2, camera: CeilingCamera
) -> Pose2:
    """Eq. 4 chained through a known landmark j: ``M_T_i = M_T_j j_T_i``."""
    return mosaic_from_j @ relative_landmark_pose(image_j, image_i, camera)


def landmark_pose_variances(
    observation: LandmarkObservation, camera: CeilingCamera
) -> tuple[float, float]:
    """(per-axis position variance, heading variance) of the robot pose from one landmark.

    ``var_pos = (Z/f sigma_px)^2 + |C_P_i|^2 sigma_phi^2 / 2`` and ``var_h = sigma_phi^2``
    (module docstring, "Eq. 3 weights").
    """
    offset = camera_from_landmark_eq1(observation.image_pose, camera)
    lever2 = offset.x * offset.x + offset.y * offset.y
    sphi2 = observation.sigma_phi**2
    var_pos = (camera.scale * observation.sigma_px) ** 2 + 0.5 * lever2 * sphi2
    return var_pos, sphi2


def weighted_circular_mean(angles: Sequence[float], weights: Sequence[float]) -> float:
    """``atan2(sum w sin a, sum w cos a)``: the weighted mean direction, in [-pi, pi)."""
    a = np.asarray(angles, dtype=float)
    w = np.asarray(weights, dtype=float)
    return wrap_angle(math.atan2(float(w @ np.sin(a)), float(w @ np.cos(a))))


def fuse_poses_eq3(
    poses: Sequence[Pose2],
    position_weights: Sequence[float],
    heading_weights: Sequence[float] | None = None,
) -> Pose2:
    """Eq. 3, ``X = sum w_i X_i / sum w_i``, with the circular mean for the heading.

    ``heading_weights`` defaults to ``position_weights`` (the paper's single ``w_i``).
    """
    if not poses:
        raise ValueError("no pose to fuse")
    wp = np.asarray(position_weights, dtype=float)
    wh = wp if heading_weights is None else np.asarray(heading_weights, dtype=float)
    if wp.shape != (len(poses),) or wh.shape != (len(poses),):
        raise ValueError("one weight per pose")
    if np.any(wp < 0.0) or np.any(wh < 0.0) or wp.sum() <= 0.0 or wh.sum() <= 0.0:
        raise ValueError("weights must be non-negative with a positive sum")
    xy = np.array([(p.x, p.y) for p in poses])
    mean_xy = wp @ xy / wp.sum()
    heading = weighted_circular_mean([p.theta for p in poses], wh)
    return Pose2(float(mean_xy[0]), float(mean_xy[1]), heading)


def localise(
    observations: Sequence[LandmarkObservation],
    mosaic: Mapping[str, Pose2],
    camera: CeilingCamera,
) -> CeilingFix | None:
    """Eq. 2 per landmark of the mosaic in view, fused by eq. 3 with inverse variances.

    Observations of landmarks not in ``mosaic`` are skipped; ``None`` when none is left.
    """
    poses: list[Pose2] = []
    wp: list[float] = []
    wh: list[float] = []
    used: list[str] = []
    for obs in observations:
        landmark = mosaic.get(obs.landmark_id)
        if landmark is None:
            continue
        var_pos, var_h = landmark_pose_variances(obs, camera)
        poses.append(robot_pose_from_landmark_eq2(landmark, obs.image_pose, camera))
        wp.append(1.0 / var_pos)
        wh.append(1.0 / var_h)
        used.append(obs.landmark_id)
    if not poses:
        return None
    pose = fuse_poses_eq3(poses, wp, wh)
    cov = np.diag([1.0 / sum(wp), 1.0 / sum(wp), 1.0 / sum(wh)])
    return CeilingFix(pose, cov, tuple(used))
