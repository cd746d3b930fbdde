"""Robot Jacobian of a camera on a pan-tilt unit of a unicycle base (thesis eq. 3.2).

Seed 000: control vector eq. 3.1 and robot frames (lines 1991-2060), Jacobian eq. 3.2
(lines 2090-2129); appendix A.1 (the chain of transforms, eq. A.1-A.7, lines 4700-4800),
A.2-A.3 (kinematic screw and velocity twist matrix, eq. A.18-A.66, lines 5180-6230) and
A.5 (the Air-Cobot dimensions, eq. A.70-A.73, lines 6340-6400).

The control vector is ``q_dot = (v, omega, omega_pan, omega_tilt)`` (eq. 3.1) and the
Jacobian ``cJq`` maps it to the camera's velocity twist ``(v_c, omega_c)`` expressed in
the camera frame C (ViSP's ``v_c``, what an interaction matrix multiplies)::

    v_c = cJq @ q_dot            (eq. 3.2, = cVe eJe, eq. A.65)

Frames and conventions (ours, ARCHITECTURE.md §4)
-------------------------------------------------
The chain is the thesis's M -> P -> E -> C (eq. A.1-A.7): the robot frame R (the thesis's
R_M: origin at the axle centre M, x forward, z up), the pan-tilt centre P at ``mount``
(in R) facing ``mount_yaw``, the end effector E on the tilt axis, ``lateral`` metres to
the unit's left of P (the thesis's ``y_E``, +-150 mm for the two cameras of the stereo
pair), and the camera C, whose optical centre sits ``optical_offset`` from E, expressed
in C (the thesis's ``(x_C, y_C, z_C)`` in E is ``(-z_C, y_C, x_C)`` in C, since
``E -> C`` is ``Ry(pi/2)``; Air-Cobot: 25 mm above the tilt axis). The rotations are those
of :func:`executive.core.frames.robot_from_camera` (reused, not rewritten): pan turns
about +z_R (positive to the LEFT), tilt about the unit's lateral axis (positive raises the
optical axis). The thesis turns pan about the PTU's z axis, which points down after the
``Rx(pi)`` of eq. A.2, and writes ``Ry(-tilt)`` about an axis pointing right (eq. A.4):
its pan and tilt are ours negated, ``pan_thesis = -pan``, ``tilt_thesis = -tilt``.

What the extraction lost, and what we derived instead
-----------------------------------------------------
The printed eq. 3.2 (= A.66) comes from eq. A.28, which writes the PTU's angular
velocity as ``(0, tilt_rate, -pan_rate)`` in the pan-tilt frame before the tilt: its pan
column has the angular part ``(0, 1, 0)`` and the linear part ``(x_E + x_C, 0, z_C - y_E)``
whatever the tilt, while the pan axis is vertical, ``(0, -cos t, -sin t)`` in C (as the
robot's own omega column of eq. 3.2 says). Checked numerically: the printed v, omega and
tilt columns agree with the chain at every configuration (with our pan and tilt signs), the
printed pan column only at zero tilt. The thesis's simulations start at tilt pi/6 and
pi/10, where the printed pan column is off by 52 % and 31 % (relative norm of the
difference, Air-Cobot geometry).
We derive every column from the chain itself instead -- each joint is a screw (an axis
through a point) and its column is that screw moved to C::

    v       : linear (1, 0, 0) in R, no rotation;
    omega   : rotation about +z_R through M;
    pan     : rotation about +z_R through P;
    tilt    : rotation about the panned lateral axis ``Rz(yaw + pan) (0, -1, 0)`` through P;
    column  = (R_CR (w x (C - A) + v_lin), R_CR w)  for a screw of axis w through A.

The tests check this against finite differences of the camera pose over random
configurations (hypothesis) and against the printed eq. 3.2 where the latter holds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from executive.core.frames import (
    FloatArray,
    Pose2,
    Transform3,
    aircraft_from_robot,
    robot_from_camera,
)
from executive.core.model import CameraSpec

__all__ = [
    "AIR_COBOT_CAMERA_HEIGHT",
    "AIR_COBOT_LATERAL",
    "AIR_COBOT_MOUNT",
    "AIR_COBOT_OPTICAL_OFFSET",
    "PanTiltCamera",
    "camera_velocity_twist_matrix",
    "robot_jacobian_eq_3_2",
]

AIR_COBOT_MOUNT = (0.505, 0.0, 0.690)
"""Pan-tilt centre P in R (m): ``MP = (505, 0, 50)`` mm (eq. A.71) with M 640 mm above the
ground (``z_M``, eq. A.70); R's origin is on the ground under M."""
AIR_COBOT_LATERAL = 0.150
"""|y_E| (m, eq. A.72): each camera of the stereo pair sits 150 mm from P along the tilt
axis (the thesis's right camera, ``y_E = +150``, is our ``lateral = -0.150``)."""
AIR_COBOT_OPTICAL_OFFSET = (0.0, -0.025, 0.0)
"""C from E, in C (m): ``(x_C, y_C, z_C) = (0, -25, 0)`` mm in E (eq. A.73), 25 mm above
the tilt axis at zero tilt."""
AIR_COBOT_CAMERA_HEIGHT = AIR_COBOT_MOUNT[2] + 0.025
"""0.715 m: "the height of the camera in standard position" (line 2339)."""


@dataclass(frozen=True, slots=True)
class PanTiltCamera:
    """Where a camera sits on its pan-tilt unit (the offsets of the chain M -> P -> E -> C).

    ``mount`` (x, y, z in R, m) and ``mount_yaw`` (rad) place the unit's centre P;
    ``lateral`` (m, positive to the unit's left) places the camera's end effector E on the
    tilt axis; ``optical_offset`` (m, in C) places the optical centre from E. Angles of
    the unit: pan positive left, tilt positive up (module docstring).
    """

    mount: tuple[float, float, float]
    mount_yaw: float = 0.0
    lateral: float = 0.0
    optical_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @classmethod
    def air_cobot(cls, side: str = "right") -> PanTiltCamera:
        """The thesis's front stereo camera (appendix A.5); ``side`` "right" or "left".

        The thesis's simulations (Tables 3.1-3.3) use the right camera: the robot stands
        at ``y = 150`` mm so that C is on the world's x axis (line 2433).
        """
        if side not in ("right", "left"):
            raise ValueError(f"side is 'right' or 'left', got {side!r}")
        lateral = -AIR_COBOT_LATERAL if side == "right" else AIR_COBOT_LATERAL
        return cls(AIR_COBOT_MOUNT, 0.0, lateral, AIR_COBOT_OPTICAL_OFFSET)

    @classmethod
    def from_spec(
        cls,
        spec: CameraSpec,
        lateral: float = 0.0,
        optical_offset: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ) -> PanTiltCamera:
        """From a mission's ``<camera>`` element: its mount and yaw; ``lateral`` is
        ``+- baseline / 2`` for the left/right camera of a stereo pair (as sim2d's rigs)."""
        x, y, z = (float(c) for c in spec.mount)
        return cls((x, y, z), float(spec.mount_yaw), lateral, optical_offset)

    def robot_from_camera(self, pan: float, tilt: float) -> Transform3:
        """``rMc``: the camera frame C in R at these PTU angles (eq. A.5-A.7, our signs)."""
        r_m_e = robot_from_camera(self.mount, self.mount_yaw, pan, tilt, self.lateral)
        offset = np.asarray(self.optical_offset, dtype=float)
        return Transform3(r_m_e.rotation, r_m_e.translation + r_m_e.rotation @ offset)

    def aircraft_from_camera(
        self, pose_f: Pose2, pan: float, tilt: float, origin_height: float
    ) -> Transform3:
        """``fMc``: the camera in the aircraft frame F for the base at ``pose_f`` (a pose in
        F, the ground at ``z_F = origin_height``). Its inverse ``cMf`` projects feature
        points given in F: from a checkpoint's pose and PTU angles it gives the desired
        image ``s*`` and depths (``project_points(cMf, points_f)``), and ``c*Mo`` for PBVS.
        """
        return aircraft_from_robot(pose_f, origin_height) @ self.robot_from_camera(pan, tilt)


def robot_jacobian_eq_3_2(camera: PanTiltCamera, pan: float, tilt: float) -> FloatArray:
    """Eq. 3.2: the 6x4 ``cJq`` with ``v_c = cJq @ (v, omega, omega_pan, omega_tilt)``.

    Derived from the chain (module docstring), valid at any pan and tilt; it does not
    depend on the base's pose. Columns: the screw of each control input moved to C.
    """
    r_m_c = camera.robot_from_camera(pan, tilt)
    cx, cy, cz = (float(v) for v in r_m_c.translation)
    px, py, pz = camera.mount
    dx, dy, dz = cx - px, cy - py, cz - pz
    yaw = camera.mount_yaw + pan
    ax, ay = math.sin(yaw), -math.cos(yaw)  # tilt axis Rz(yaw) (0, -1, 0), no z part
    # columns in R, rows (linear; angular): z x c = (-cy, cx, 0); a x d = (ay dz, -ax dz,
    # ax dy - ay dx) for a = (ax, ay, 0) -- plain floats: np.cross costs ~20 us a call
    screws = np.array(
        [
            [1.0, -cy, -dy, ay * dz],
            [0.0, cx, dx, -ax * dz],
            [0.0, 0.0, 0.0, ax * dy - ay * dx],
            [0.0, 0.0, 0.0, ax],
            [0.0, 0.0, 0.0, ay],
            [0.0, 1.0, 1.0, 0.0],
        ]
    )
    c_r_r = r_m_c.rotation.T
    jac = np.empty((6, 4))
    jac[:3] = c_r_r @ screws[:3]
    jac[3:] = c_r_r @ screws[3:]
    return jac


def camera_velocity_twist_matrix(a_m_b: Transform3) -> FloatArray:
    """``aVb`` (6x6): maps a twist expressed in frame b to the same motion in frame a
    (eq. A.55: ``[[R, [t]x R], [0, R]]`` with ``R, t`` of ``aMb``; ViSP's
    ``vpVelocityTwistMatrix``)."""
    r = a_m_b.rotation
    t = a_m_b.translation
    tx = np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])
    out = np.zeros((6, 6))
    out[:3, :3] = r
    out[:3, 3:] = tx @ r
    out[3:, 3:] = r
    return out
