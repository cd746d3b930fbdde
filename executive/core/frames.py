"""The one place for frames and rigid transforms (ARCHITECTURE.md §4).

Frames:

* airport frame **A** — fixed; x east, y north, z up. Headings counter-clockwise from x.
* aircraft frame **F** — origin at the nose tip, x towards the tail, z towards the ground,
  y completing a right-handed frame, so **+y_F is the aircraft's left (port) side**.
  Seen from above, (x_F, y_F) is a *mirrored* 2D frame relative to A: a robot heading in F
  (angle from +x_F towards +y_F) maps to A as ``heading_A = theta_F - heading_F``.
* robot frame **R** — x forward, y left, z up, origin at the axle centre on the ground.
* pan-tilt frame and camera frame **C** — ViSP: z optical axis, x right, y down.

Notation: ``a_from_b`` is the transform that maps coordinates in frame b to frame a, so
``a_from_c = a_from_b @ b_from_c``. Angles in radians.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]


def wrap_angle(angle: float) -> float:
    """Wrap an angle to [-pi, pi)."""
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


# -- SE(2) ------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class Pose2:
    """A planar pose (x, y, theta): a proper rigid transform of SE(2).

    As a transform ``frame_from_body`` it maps body coordinates into the frame.
    """

    x: float
    y: float
    theta: float

    @property
    def position(self) -> FloatArray:
        return np.array([self.x, self.y])

    def rotation(self) -> FloatArray:
        c, s = math.cos(self.theta), math.sin(self.theta)
        return np.array([[c, -s], [s, c]])

    def matrix(self) -> FloatArray:
        """Homogeneous 3x3 matrix."""
        m = np.eye(3)
        m[:2, :2] = self.rotation()
        m[:2, 2] = (self.x, self.y)
        return m

    def __matmul__(self, other: Pose2) -> Pose2:
        c, s = math.cos(self.theta), math.sin(self.theta)
        return Pose2(
            self.x + c * other.x - s * other.y,
            self.y + s * other.x + c * other.y,
            wrap_angle(self.theta + other.theta),
        )

    def inverse(self) -> Pose2:
        c, s = math.cos(self.theta), math.sin(self.theta)
        return Pose2(-c * self.x - s * self.y, s * self.x - c * self.y, wrap_angle(-self.theta))

    def apply(self, points: ArrayLike) -> FloatArray:
        """Map points (shape (2,) or (N, 2)) from body to frame coordinates."""
        pts = np.asarray(points, dtype=float)
        return pts @ self.rotation().T + self.position

    def distance_to(self, other: Pose2) -> float:
        return math.hypot(self.x - other.x, self.y - other.y)


# -- SE(3) ------------------------------------------------------------------------------
def rot_x(angle: float) -> FloatArray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(angle: float) -> FloatArray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(angle: float) -> FloatArray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@dataclass(frozen=True, slots=True, eq=False)
class Transform3:
    """A rigid transform of SE(3): rotation matrix and translation."""

    rotation: FloatArray
    translation: FloatArray

    @staticmethod
    def identity() -> Transform3:
        return Transform3(np.eye(3), np.zeros(3))

    @staticmethod
    def from_matrix(m: ArrayLike) -> Transform3:
        mat = np.asarray(m, dtype=float)
        return Transform3(mat[:3, :3].copy(), mat[:3, 3].copy())

    def matrix(self) -> FloatArray:
        m = np.eye(4)
        m[:3, :3] = self.rotation
        m[:3, 3] = self.translation
        return m

    def __matmul__(self, other: Transform3) -> Transform3:
        return Transform3(
            self.rotation @ other.rotation, self.rotation @ other.translation + self.translation
        )

    def inverse(self) -> Transform3:
        rt = self.rotation.T
        return Transform3(rt, -rt @ self.translation)

    def apply(self, points: ArrayLike) -> FloatArray:
        """Map points (shape (3,) or (N, 3))."""
        pts = np.asarray(points, dtype=float)
        return pts @ self.rotation.T + self.translation

    def allclose(self, other: Transform3, atol: float = 1e-9) -> bool:
        return bool(
            np.allclose(self.rotation, other.rotation, atol=atol)
            and np.allclose(self.translation, other.translation, atol=atol)
        )


# -- airport <-> aircraft ---------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class AircraftPlacement:
    """Where the aircraft stands in the airport frame.

    ``nose`` is the nose tip (origin of F) on the ground in A, ``heading`` the direction
    the nose points in A (rad), ``origin_height`` the nose tip's height above the ground.
    The tail direction +x_F is therefore ``heading + pi`` in A.
    """

    x: float
    y: float
    heading: float
    origin_height: float = 0.0

    @property
    def x_axis_heading(self) -> float:
        """Heading in A of +x_F (towards the tail)."""
        return wrap_angle(self.heading + math.pi)

    def airport_from_aircraft(self) -> Transform3:
        """3D transform A <- F: ``R = Rz(theta) Rx(pi)``, origin at the nose tip's height."""
        rotation = rot_z(self.x_axis_heading) @ rot_x(math.pi)
        return Transform3(rotation, np.array([self.x, self.y, self.origin_height]))

    # 2D ground-plane maps ---------------------------------------------------------------
    def to_airport_xy(self, points_f: ArrayLike) -> FloatArray:
        """Ground positions (x_F, y_F) -> (x_A, y_A). Accepts (2,) or (N, 2)."""
        pts = np.asarray(points_f, dtype=float)
        mirrored = pts * np.array([1.0, -1.0])
        return Pose2(self.x, self.y, self.x_axis_heading).apply(mirrored)

    def to_aircraft_xy(self, points_a: ArrayLike) -> FloatArray:
        """Ground positions (x_A, y_A) -> (x_F, y_F). Accepts (2,) or (N, 2)."""
        pts = np.asarray(points_a, dtype=float)
        local = Pose2(self.x, self.y, self.x_axis_heading).inverse().apply(pts)
        return local * np.array([1.0, -1.0])

    def pose_to_airport(self, pose_f: Pose2) -> Pose2:
        """A robot pose in F (heading from +x_F towards +y_F) -> the same pose in A."""
        x, y = self.to_airport_xy((pose_f.x, pose_f.y))
        return Pose2(float(x), float(y), wrap_angle(self.x_axis_heading - pose_f.theta))

    def pose_to_aircraft(self, pose_a: Pose2) -> Pose2:
        """A robot pose in A -> the same pose in F."""
        x, y = self.to_aircraft_xy((pose_a.x, pose_a.y))
        return Pose2(float(x), float(y), wrap_angle(self.x_axis_heading - pose_a.theta))

    def differs_from(
        self, other: AircraftPlacement, distance: float = 0.01, angle: float = math.radians(0.05)
    ) -> bool:
        """Whether the nose moved by ``distance`` (m) or more, or the heading turned by
        ``angle`` (rad) or more: for caches of shapes placed with the aircraft, which the
        pose filter nudges on every GPS fix."""
        return (
            math.hypot(self.x - other.x, self.y - other.y) >= distance
            or abs(wrap_angle(self.heading - other.heading)) >= angle
        )

    def height_to_z(self, height: float) -> float:
        """Height above the ground -> z_F (z_F points down from the nose tip)."""
        return self.origin_height - height


def mirror_pose(pose: Pose2) -> Pose2:
    """A pose in F <-> the same pose in G = (x_F, -y_F), the proper (unmirrored) 2D frame
    of the aircraft ground plane: ``(x, y, h) -> (x, -y, -h)``, its own inverse.

    In G ordinary SE(2) algebra applies: ``mirror_pose(pose_f) @ delta`` is the robot
    after a motion ``delta`` expressed in R.
    """
    return Pose2(pose.x, -pose.y, wrap_angle(-pose.theta))


_MIRROR_SIGNS = np.outer((1.0, -1.0, -1.0), (1.0, -1.0, -1.0))
"""D C D for D = diag(1, -1, -1), elementwise."""


def mirror_covariance(cov: ArrayLike) -> FloatArray:
    """A 3x3 (x, y, heading) covariance in F <-> the same in G (see :func:`mirror_pose`)."""
    return np.asarray(cov, dtype=float) * _MIRROR_SIGNS


def moved_in_aircraft(pose_f: Pose2, delta_r: Pose2) -> Pose2:
    """The robot's pose in F after it moved by ``delta_r`` (a pose in its own frame R)."""
    return mirror_pose(mirror_pose(pose_f) @ delta_r)


def aircraft_points_from_robot(pose_f: Pose2, points_r: ArrayLike) -> FloatArray:
    """Ground points in R (x forward, y left) -> (x_F, y_F) for a robot at ``pose_f``.

    F is mirrored seen from above, so this is a reflection, not a rotation: the robot's
    +x maps to (cos h, sin h) and its +y (left) to (sin h, -cos h), h = ``pose_f.theta``.
    Equivalently ``mirror(Pose2(x_F, -y_F, -h).apply(p))`` with mirror (x, y) -> (x, -y).
    Accepts (2,) or (N, 2).
    """
    pts = np.asarray(points_r, dtype=float)
    c, s = math.cos(pose_f.theta), math.sin(pose_f.theta)
    m = np.array([[c, s], [s, -c]])
    return pts @ m.T + np.array([pose_f.x, pose_f.y])


def robot_points_from_aircraft(pose_f: Pose2, points_f: ArrayLike) -> FloatArray:
    """Inverse of :func:`aircraft_points_from_robot` (the reflection is its own inverse)."""
    pts = np.asarray(points_f, dtype=float) - np.array([pose_f.x, pose_f.y])
    c, s = math.cos(pose_f.theta), math.sin(pose_f.theta)
    m = np.array([[c, s], [s, -c]])
    return pts @ m  # m is symmetric and orthogonal: m^-1 = m^T = m


def aircraft_from_robot(pose_f: Pose2, origin_height: float) -> Transform3:
    """3D transform F <- R for a robot standing on the ground at ``pose_f`` (pose in F).

    R has z up and F has z down, so ``R_FR = Rx(pi) Rz(-heading_F)``: the robot's +x maps
    to (cos h, sin h, 0) in F and its +z to -z_F. The ground lies at ``z_F = origin_height``.
    """
    rotation = rot_x(math.pi) @ rot_z(-pose_f.theta)
    return Transform3(rotation, np.array([pose_f.x, pose_f.y, origin_height]))


# -- robot <-> camera ---------------------------------------------------------------------
_CAMERA_IN_PTU = np.array(
    [
        [0.0, 0.0, 1.0],  # columns are x_C, y_C, z_C expressed in the pan-tilt frame:
        [-1.0, 0.0, 0.0],  # x_C = -y (right), y_C = -z (down), z_C = +x (optical axis)
        [0.0, -1.0, 0.0],
    ]
)


def robot_from_camera(
    mount: ArrayLike, mount_yaw: float, pan: float, tilt: float, lateral: float = 0.0
) -> Transform3:
    """3D transform R <- C for a camera on a pan-tilt unit.

    The unit sits at ``mount`` (x, y, z in R) facing ``mount_yaw``; pan turns about +z_R
    (positive left), tilt raises the optical axis (positive up). At pan = tilt = 0 the
    optical axis z_C points along the mount direction, x_C to the right, y_C down.
    ``lateral`` offsets the camera along the unit's left axis, which turns with pan (the
    two cameras of a stereo pair sit at +/- baseline / 2); tilt does not move it.
    """
    yaw = mount_yaw + pan
    rotation = rot_z(yaw) @ rot_y(-tilt) @ _CAMERA_IN_PTU
    position = np.asarray(mount, dtype=float) + lateral * np.array(
        [-math.sin(yaw), math.cos(yaw), 0.0]
    )
    return Transform3(rotation, position)


def airport_from_robot(pose_a: Pose2) -> Transform3:
    """3D transform A <- R for a robot standing on the ground at ``pose_a`` (pose in A)."""
    return Transform3(rot_z(pose_a.theta), np.array([pose_a.x, pose_a.y, 0.0]))


def pan_tilt_towards(
    mount: ArrayLike, mount_yaw: float, target_r: ArrayLike
) -> tuple[float, float]:
    """Pan and tilt (rad) that put ``target_r`` (a point in R) on the optical axis."""
    d = np.asarray(target_r, dtype=float) - np.asarray(mount, dtype=float)
    pan = wrap_angle(math.atan2(d[1], d[0]) - mount_yaw)
    tilt = math.atan2(d[2], math.hypot(d[0], d[1]))
    return pan, tilt
