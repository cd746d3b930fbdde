"""Pose estimation of a skid-steer robot in the airport plane: an extended Kalman filter.

Fuses wheel odometry (thesis eq. 2.1, 2.2, seed lines 829-865), the IMU yaw rate and
GPS fixes, as the thesis fusion principle (seed lines 1147-1200) describes, and takes
later absolute measurements (laser registration) through :meth:`PoseFilter.update_pose`
and :meth:`PoseFilter.update_heading`. Pure numpy and ``math``; no py_trees import.

State (airport frame A: x east, y north, headings counter-clockwise from +x_A)::

    s = (x, y, theta, b, k, c, p_x, p_y, p_phi)

* ``x, y`` (m), ``theta`` (rad, kept in [-pi, pi)): the pose of the robot frame R in A;
* ``b`` (rad/s): the gyro bias, IMU reading = body yaw rate + b + white noise;
* ``k`` (-): the wheel-odometry yaw-rate scale, the fraction of the wheels' yaw rate
  that the body really turns (skid-steer slip: ~0.8-1.0, 1 = no slip);
* ``c`` (-): the wheel-odometry speed scale, the fraction of the wheels' speed that the
  body really moves (longitudinal slip, ~0.95-1.0). An addition to the minimal
  (x, y, theta, b, k) filter: sim2d's default 2 % longitudinal slip alone drifts 0.5 m
  over a 25 m GPS outage, and GPS observes c on every straight run.
* ``p_x, p_y, p_phi``: where the aircraft stands, as the proper SE(2) pose
  ``A <- G`` of the mirrored aircraft ground frame G = (x_F, -y_F) (origin at the nose
  tip, ``p_phi`` the heading of +x_F in A; see :mod:`executive.core.frames`). The
  aircraft does not move, so these states have no process noise; their prior is the
  mission's nominal parking pose with ``sigma_placement_xy`` / ``sigma_placement_theta``.
  Augmenting the filter with them (rather than a separate placement estimate) keeps the
  correlation between "where the robot is in A" and "where the aircraft is in A": a laser
  registration measures only their *relative* pose, and the filter splits a correction
  between the two by their covariances (GPS on the apron pins the robot, so the
  registration moves the aircraft; in a hangar both drift together and the registration
  still fixes the robot's pose in F, which is what the checkpoints need).

Models:

* wheels, eq. 2.1 and 2.2 with ``d`` the half track (``track = 2 d``)::

      v       = (v_r + v_l) / 2
      omega_w = (v_r - v_l) / (2 d)

* body speed ``u = c v``; body yaw rate ``omega = imu - b`` when an IMU reading is given,
  else ``omega = k omega_w``;
* motion over ``dt``: an exact arc of constant (u, omega), i.e. a chord of length
  ``u dt sinc(omega dt / 2)`` along ``theta + omega dt / 2``; F its Jacobian in s;
* ``b``, ``k`` and ``c`` follow random walks (``gyro_bias_walk``, ``yaw_scale_walk``,
  ``speed_scale_walk``, per sqrt(s)); k and c are clamped to their bounds;
* process noise: the wheel and gyro sample noises (per reading) plus slip, modelled as
  velocity errors with correlation time ``slip_time``: longitudinal ``slip_speed * |u|``,
  lateral ``slip_lateral * |u omega|`` and, on wheel yaw, ``slip_turn * |omega_w|`` --
  so the noise grows in turns, where a skid-steer base slips most;
* wheel/IMU yaw consistency (when both are read and ``fuse_wheel_yaw``): the wheels'
  yaw rate is a scalar measurement ``omega_w = (imu - b) / k + noise``. While the body
  does not turn (``|imu - b| <= 3 sqrt(gyro_noise^2 + P_bb)``: straight or at rest,
  where the wheels' "no turn" is reliable) it observes b only, with
  H = (0, 0, 0, -1/k, 0, 0); while turning it observes k only, with
  H = (0, 0, 0, 0, -(imu - b)/k^2, 0), so that a slip that varies from turn to turn
  (sim2d's depends on the share of rotation in the motion) is not mistaken for a bias.
  GPS refines both through the heading. The precise IMU rate is the regressor and the
  noisy wheel rate the measurement, so wheel noise does not bias k (regressing on a
  noisy rate would pull the slope towards 0: regression dilution); for the same reason,
  without an IMU, k is learnt only while ``|omega_w|`` exceeds 3 sigma of its wheel
  noise. (The same IMU reading also drives the prediction; the correlation
  is neglected, harmless as the wheel noise dominates this measurement's variance.)

Measurements: GPS position (H = [I2 0], gated by the Mahalanobis distance), heading
(H = e3), full pose in A (H = [I3 0]) and the robot's pose in the aircraft frame from a
laser registration (:meth:`PoseFilter.update_registration`): in G,

    z = (A <- G)^-1 (A <- R):  z_x =  c (x - p_x) + s (y - p_y)
                               z_y = -s (x - p_x) + c (y - p_y),  z_theta = theta - p_phi

with c = cos p_phi, s = sin p_phi, so dz/d(x, y, theta) = [[c, s, 0], [-s, c, 0],
[0, 0, 1]], dz/d(p_x, p_y) = -(the same 2x2 block) and dz/dp_phi = (z_y, -z_x, -1). The
update is iterated (Gauss-Newton on the linearisation point, an iterated EKF) because the
first registration can correct the placement by metres and degrees. Innovations in
theta are wrapped to [-pi, pi).
Updates use the Joseph form and the covariance is symmetrised after every step.

:attr:`PoseFilter.confidence` maps the covariance to [0, 1]::

    sigma_eff = sqrt(P_xx + P_yy + (lever * sigma_theta)^2)
    confidence = exp(-(sigma_eff / confidence_scale)^2)

with ``lever = 1 m`` (a heading error displaces a point 1 m ahead, e.g. a camera target)
and ``confidence_scale = 0.15 m``: 1 cm -> 0.996, 5 cm -> 0.89, 10 cm -> 0.64,
20 cm -> 0.17, 30 cm -> 0.018.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from executive.core.frames import (
    AircraftPlacement,
    FloatArray,
    Pose2,
    mirror_covariance,
    wrap_angle,
)
from executive.core.records import (
    FrameReference,
    GpsFix,
    ImuReading,
    PoseEstimate,
    RegistrationRecord,
    WheelSpeeds,
)

N_STATES = 9
"""(x, y, theta, b, k, c, p_x, p_y, p_phi)."""

_STATE_FIELDS = ("_x", "_y", "_theta", "_b", "_k", "_c", "_px", "_py", "_pphi")
"""The attributes holding the state, in :attr:`PoseFilter.state` order."""

_STATE_FIELDS = ("_x", "_y", "_theta", "_b", "_k", "_c", "_px", "_py", "_pphi")
"""The attributes holding the state, in :attr:`PoseFilter.state` order."""


CHI2_999 = {1: 10.828, 2: 13.816, 3: 16.266}
"""Chi-square 99.9% quantiles by degrees of freedom (Mahalanobis gates)."""


def wheel_odometry(wheels: WheelSpeeds, track: float) -> tuple[float, float]:
    """(v, omega) of the body from the wheel ground speeds, thesis eq. 2.1 and 2.2.

    ``track`` is the left-to-right wheel distance, twice the ``d`` of eq. 2.2.
    """
    return 0.5 * (wheels.right + wheels.left), (wheels.right - wheels.left) / track


def _is_psd3(m: FloatArray) -> bool:
    """Symmetric 3x3 positive semi-definite: every principal minor >= 0 (and finite)."""
    (a, b, c), (_, d, e), (_, _, g) = m.tolist()
    minors = (
        a,
        d,
        g,
        a * d - b * b,
        a * g - c * c,
        d * g - e * e,
        a * (d * g - e * e) - b * (b * g - c * e) + c * (b * e - c * d),
    )
    return all(x >= 0.0 for x in minors) and math.isfinite(sum(minors))


class PoseFilter:
    """EKF on (x, y, theta, b, k, c) for a skid-steer robot, augmented with the aircraft
    placement (p_x, p_y, p_phi); see the module docstring."""

    def __init__(
        self,
        initial: Pose2,
        *,
        track: float,
        sigma_xy: float = 0.05,
        sigma_theta: float = 0.05,
        wheel_noise: float = 0.02,
        gyro_noise: float = 0.005,
        gyro_bias_walk: float = 1e-4,
        gyro_bias: float = 0.0,
        sigma_gyro_bias: float = 0.01,
        yaw_scale: float = 0.9,
        sigma_yaw_scale: float = 0.1,
        yaw_scale_walk: float = 0.01,
        yaw_scale_bounds: tuple[float, float] = (0.5, 1.2),
        speed_scale: float = 1.0,
        sigma_speed_scale: float = 0.03,
        speed_scale_walk: float = 1e-3,
        speed_scale_bounds: tuple[float, float] = (0.7, 1.2),
        slip_speed: float = 0.02,
        slip_lateral: float = 0.05,
        slip_turn: float = 0.2,
        slip_time: float = 3.0,
        fuse_wheel_yaw: bool = True,
        gps_gate: float = CHI2_999[2],
        gps_reset_after: int = 10,
        confidence_scale: float = 0.15,
        confidence_lever: float = 1.0,
        placement: AircraftPlacement | None = None,
        sigma_placement_xy: float = 1.0,
        sigma_placement_theta: float = math.radians(6.0),
    ) -> None:
        """Start at ``initial`` with independent errors on every state.

        ``track`` is the left-to-right wheel distance (m), 2 d of eq. 2.2. ``sigma_*`` are
        the initial 1-sigma errors, ``gyro_bias``, ``yaw_scale`` and ``speed_scale`` the
        initial b, k and c. ``wheel_noise`` (m/s, each wheel) and ``gyro_noise`` (rad/s)
        are the 1-sigma noises of one reading; ``gyro_bias_walk`` (rad/s/sqrt(s)),
        ``yaw_scale_walk`` and ``speed_scale_walk`` (1/sqrt(s)) the random walks of b, k
        and c. ``slip_speed``, ``slip_lateral`` (per rad/s) and ``slip_turn`` are the
        1-sigma slips not explained by c and k, as fractions of the speed, the speed and
        the wheels' yaw rate, correlated over ``slip_time`` (s). ``gps_gate`` is the
        squared Mahalanobis gate of a GPS fix; after ``gps_reset_after`` consecutive
        rejected fixes the filter deems itself lost and re-centres its position on the
        next fix (0: never). ``confidence_scale`` (m) and ``confidence_lever`` (m): see
        :attr:`confidence`. ``placement`` is the prior on where the aircraft stands (the
        nominal parking pose; default: nose at the origin of A pointing north) with the
        1-sigma ``sigma_placement_xy`` (m, each axis) and ``sigma_placement_theta`` (rad).
        """
        if track <= 0.0:
            raise ValueError(f"track must be positive, got {track}")
        self.track = float(track)
        self.wheel_noise = float(wheel_noise)
        self.gyro_noise = float(gyro_noise)
        self.gyro_bias_walk = float(gyro_bias_walk)
        self.yaw_scale_walk = float(yaw_scale_walk)
        self.yaw_scale_bounds = (float(yaw_scale_bounds[0]), float(yaw_scale_bounds[1]))
        self.speed_scale_walk = float(speed_scale_walk)
        self.speed_scale_bounds = (float(speed_scale_bounds[0]), float(speed_scale_bounds[1]))
        self.slip_speed = float(slip_speed)
        self.slip_lateral = float(slip_lateral)
        self.slip_turn = float(slip_turn)
        self.slip_time = float(slip_time)
        self.fuse_wheel_yaw = bool(fuse_wheel_yaw)
        self.gps_gate = float(gps_gate)
        self.gps_reset_after = int(gps_reset_after)
        self.confidence_scale = float(confidence_scale)
        self.confidence_lever = float(confidence_lever)
        # variance of one reading of eq. 2.1 / eq. 2.2 from independent wheel noises
        self._var_v = 0.5 * self.wheel_noise**2
        self._var_wheel_yaw = 2.0 * self.wheel_noise**2 / self.track**2
        self._k_min_rate = 3.0 * math.sqrt(self._var_wheel_yaw)
        self._eye = np.eye(N_STATES)
        self._f = np.eye(N_STATES)
        self._h_yaw = np.zeros(N_STATES)
        self.gps_accepted = 0
        self.gps_rejected = 0
        self.consecutive_gps_rejections = 0
        self._x = self._y = self._theta = 0.0
        self._b, self._k, self._c = float(gyro_bias), float(yaw_scale), float(speed_scale)
        self._p = np.zeros((N_STATES, N_STATES))
        self.reset(initial, np.diag([sigma_xy**2, sigma_xy**2, sigma_theta**2]))
        self._p[3, 3] = sigma_gyro_bias**2
        self._p[4, 4] = sigma_yaw_scale**2
        self._p[5, 5] = sigma_speed_scale**2
        prior = placement or AircraftPlacement(0.0, 0.0, math.pi / 2)
        self.origin_height = prior.origin_height
        self._px, self._py, self._pphi = prior.x, prior.y, prior.x_axis_heading
        self._p[6, 6] = self._p[7, 7] = sigma_placement_xy**2
        self._p[8, 8] = sigma_placement_theta**2
        self.registrations_accepted = 0
        self.registrations_rejected = 0

    # -- state --------------------------------------------------------------------------
    def reset(self, pose: Pose2, cov: ArrayLike) -> None:
        """Re-initialise the pose (x, y, theta) and its 3x3 covariance; keep b, k and c
        (their correlations with the pose are cleared)."""
        c = np.asarray(cov, dtype=float)
        if c.shape != (3, 3):
            raise ValueError(f"pose covariance must be 3x3, got {c.shape}")
        self._x, self._y, self._theta = float(pose.x), float(pose.y), wrap_angle(float(pose.theta))
        self._p[:3, :] = 0.0
        self._p[:, :3] = 0.0
        self._p[:3, :3] = 0.5 * (c + c.T)
        self.consecutive_gps_rejections = 0

    @property
    def pose(self) -> Pose2:
        return Pose2(self._x, self._y, self._theta)

    @property
    def covariance(self) -> FloatArray:
        """3x3 covariance of (x, y, theta), a copy."""
        return self._p[:3, :3].copy()

    @property
    def state(self) -> FloatArray:
        """(x, y, theta, b, k, c, p_x, p_y, p_phi)."""
        return np.array([getattr(self, name) for name in _STATE_FIELDS])

    @property
    def state_covariance(self) -> FloatArray:
        """9x9 covariance of :attr:`state`, a copy."""
        return self._p.copy()

    @property
    def placement(self) -> AircraftPlacement:
        """The estimated aircraft placement A <- F."""
        return AircraftPlacement(
            self._px, self._py, wrap_angle(self._pphi - math.pi), self.origin_height
        )

    @property
    def placement_covariance(self) -> FloatArray:
        """3x3 covariance of the placement (nose x, nose y, heading) in A, a copy."""
        return self._p[6:, 6:].copy()

    def _relative(self) -> tuple[FloatArray, FloatArray]:
        """z (robot pose in G) and its 3x9 Jacobian H in the state (module docstring)."""
        c, s = math.cos(self._pphi), math.sin(self._pphi)
        dx, dy = self._x - self._px, self._y - self._py
        zx, zy = c * dx + s * dy, -s * dx + c * dy
        z = np.array([zx, zy, wrap_angle(self._theta - self._pphi)])
        h = np.zeros((3, N_STATES))
        h[0, 0], h[0, 1], h[1, 0], h[1, 1] = c, s, -s, c
        h[2, 2] = 1.0
        h[0, 6], h[0, 7], h[1, 6], h[1, 7] = -c, -s, s, -c
        h[0, 8], h[1, 8], h[2, 8] = zy, -zx, -1.0
        return z, h

    @property
    def pose_f(self) -> Pose2:
        """The robot's pose in the aircraft frame F (heading from +x_F towards +y_F)."""
        z, _ = self._relative()
        return Pose2(float(z[0]), float(-z[1]), wrap_angle(float(-z[2])))

    @property
    def covariance_f(self) -> FloatArray:
        """3x3 covariance of :attr:`pose_f` (x_F, y_F, heading_F): robot and placement."""
        _, h = self._relative()
        cov_g = h @ self._p @ h.T
        return mirror_covariance(cov_g)

    @property
    def confidence_f(self) -> float:
        """:attr:`confidence` of the pose in F (same mapping, on :attr:`covariance_f`)."""
        return self._confidence_of(self.covariance_f)

    @property
    def gyro_bias(self) -> float:
        return self._b

    @property
    def yaw_scale(self) -> float:
        return self._k

    @property
    def speed_scale(self) -> float:
        return self._c

    @property
    def position_sigma(self) -> float:
        """sqrt(P_xx + P_yy) (m)."""
        return math.sqrt(max(self._p[0, 0] + self._p[1, 1], 0.0))

    @property
    def confidence(self) -> float:
        """exp(-(sigma_eff / confidence_scale)^2), see the module docstring."""
        return self._confidence_of(self._p)

    def _confidence_of(self, p: FloatArray) -> float:
        var = max(p[0, 0] + p[1, 1] + self.confidence_lever**2 * p[2, 2], 0.0)
        return math.exp(-var / self.confidence_scale**2)

    def estimate(
        self,
        stamp: float,
        sources: tuple[str, ...] = (),
        reference: FrameReference = FrameReference.NOMINAL,
        anchor: str = "",
        registration: RegistrationRecord | None = None,
    ) -> PoseEstimate:
        """The blackboard record: the pose in A and, through the estimated placement, in F."""
        pose = self.pose
        placement = self.placement
        covariance_f = self.covariance_f
        return PoseEstimate(
            stamp=stamp,
            pose_a=pose,
            covariance=self.covariance,
            pose_f=placement.pose_to_aircraft(pose),
            confidence=self.confidence,
            sources=sources,
            placement=placement,
            covariance_f=covariance_f,
            confidence_f=self._confidence_of(covariance_f),
            reference=reference,
            anchor=anchor,
            registration=registration,
        )

    # -- prediction ---------------------------------------------------------------------
    def predict(self, wheels: WheelSpeeds, imu: ImuReading | None, dt: float) -> None:
        """Propagate over ``dt`` (s) with eq. 2.1 for v and the IMU (or eq. 2.2 x k) for
        the yaw rate; then, with both, the wheel/IMU yaw consistency update.

        A non-finite IMU reading is ignored (wheel yaw is used); non-finite wheel speeds or
        ``dt <= 0`` leave the filter unchanged.
        """
        if not dt > 0.0:
            return
        v = 0.5 * (wheels.right + wheels.left)
        omega_w = (wheels.right - wheels.left) / self.track
        if not (math.isfinite(v) and math.isfinite(omega_w)):
            return
        imu_rate = imu.yaw_rate if imu is not None else math.nan
        has_imu = math.isfinite(imu_rate)
        k = self._k
        if has_imu:
            omega = imu_rate - self._b
            dw_db, dw_dk = -1.0, 0.0
            var_w = self.gyro_noise**2
        else:
            omega = k * omega_w
            dw_db = 0.0
            # k is learnt only while the wheels clearly turn (see the module docstring)
            dw_dk = omega_w if abs(omega_w) > self._k_min_rate else 0.0
            var_w = (
                k * k * self._var_wheel_yaw + (self.slip_turn * omega_w) ** 2 * self.slip_time / dt
            )

        # exact arc: chord length u dt sinc(h) along theta + h, h = omega dt / 2, with the
        # body's forward speed u = c v
        u = self._c * v
        h = 0.5 * omega * dt
        if abs(h) < 1e-4:
            sinc, dsinc = 1.0 - h * h / 6.0, -h / 3.0
        else:
            sinc = math.sin(h) / h
            dsinc = (h * math.cos(h) - math.sin(h)) / (h * h)
        udt = u * dt
        dist = udt * sinc
        phi = self._theta + h
        c, s = math.cos(phi), math.sin(phi)
        self._x += dist * c
        self._y += dist * s
        self._theta = wrap_angle(self._theta + omega * dt)

        # sensitivities of (x, y, theta) to omega and u
        half_dt = 0.5 * dt
        dx_dw = half_dt * (udt * dsinc * c - dist * s)
        dy_dw = half_dt * (udt * dsinc * s + dist * c)
        dx_du, dy_du = dt * sinc * c, dt * sinc * s

        f = self._f
        f[0, 2] = -dist * s
        f[1, 2] = dist * c
        f[0, 3], f[1, 3], f[2, 3] = dx_dw * dw_db, dy_dw * dw_db, dt * dw_db
        f[0, 4], f[1, 4], f[2, 4] = dx_dw * dw_dk, dy_dw * dw_dk, dt * dw_dk
        f[0, 5], f[1, 5] = dx_du * v, dy_du * v
        p = np.dot(np.dot(f, self._p), f.T)

        # process noise: G diag(var) G^T over u (along phi), lateral and omega
        corr = self.slip_time / dt
        var_u = self._c**2 * self._var_v + (self.slip_speed * u) ** 2 * corr
        var_l = (self.slip_lateral * u * omega) ** 2 * corr
        lx, ly = -s * dt, c * dt
        qxx = var_u * dx_du * dx_du + var_l * lx * lx + var_w * dx_dw * dx_dw
        qyy = var_u * dy_du * dy_du + var_l * ly * ly + var_w * dy_dw * dy_dw
        qxy = var_u * dx_du * dy_du + var_l * lx * ly + var_w * dx_dw * dy_dw
        qxt = var_w * dx_dw * dt
        qyt = var_w * dy_dw * dt
        p[0, 0] += qxx
        p[1, 1] += qyy
        p[2, 2] += var_w * dt * dt
        p[0, 1] += qxy
        p[1, 0] += qxy
        p[0, 2] += qxt
        p[2, 0] += qxt
        p[1, 2] += qyt
        p[2, 1] += qyt
        p[3, 3] += self.gyro_bias_walk**2 * dt
        p[4, 4] += self.yaw_scale_walk**2 * dt
        p[5, 5] += self.speed_scale_walk**2 * dt
        self._p = p  # symmetric up to rounding: symmetrised once, after the yaw update
        if not (
            has_imu and self.fuse_wheel_yaw and self._update_yaw_consistency(imu_rate, omega_w)
        ):
            self._p = (p + p.T) * 0.5

    def _update_yaw_consistency(self, imu_rate: float, omega_w: float) -> bool:
        """Scalar update omega_w = (imu - b) / k: of b at rest or straight, of k in turns."""
        k = self._k
        rate = imu_rate - self._b
        r = self._var_wheel_yaw + (self.gyro_noise / k) ** 2 + (self.slip_turn * omega_w) ** 2
        h = self._h_yaw
        if rate * rate > 9.0 * (self.gyro_noise**2 + self._p[3, 3]):  # turning: learn k only
            h[3], h[4] = 0.0, -rate / (k * k)
        else:  # the wheels' "no turn" is reliable: learn b only
            h[3], h[4] = -1.0 / k, 0.0
        return self._correct_scalar(h, omega_w - rate / k, r)

    # -- measurements -------------------------------------------------------------------
    def update_gps(self, fix: GpsFix) -> bool:
        """Position update with the fix's sigma; False when the Mahalanobis gate rejects it.

        After ``gps_reset_after`` consecutive rejections the filter is taken to be lost:
        the next fix re-centres the position (covariance sigma^2 I, correlations cleared).
        """
        if not (math.isfinite(fix.x) and math.isfinite(fix.y) and fix.sigma > 0.0):
            return False
        r = fix.sigma**2
        if 0 < self.gps_reset_after <= self.consecutive_gps_rejections:
            p = self._p
            p[:2, :] = 0.0
            p[:, :2] = 0.0
            p[0, 0] = p[1, 1] = r
            self._x, self._y = float(fix.x), float(fix.y)
            self.consecutive_gps_rejections = 0
            self.gps_accepted += 1
            return True
        y = np.array([fix.x - self._x, fix.y - self._y])
        if self._correct_block(2, y, np.array([[r, 0.0], [0.0, r]]), self.gps_gate):
            self.gps_accepted += 1
            self.consecutive_gps_rejections = 0
            return True
        self.gps_rejected += 1
        self.consecutive_gps_rejections += 1
        return False

    def update_heading(self, theta: float, sigma: float, gate: float | None = None) -> bool:
        """Absolute heading measurement (rad) with 1-sigma ``sigma``; wrapped innovation.

        ``gate`` (squared Mahalanobis distance, e.g. ``CHI2_999[1]``) rejects outliers;
        None accepts everything. Returns whether the measurement was used.
        """
        if not (math.isfinite(theta) and sigma > 0.0):
            return False
        h = self._eye[2]
        return self._correct_scalar(h, wrap_angle(theta - self._theta), sigma**2, gate)

    def update_pose(self, pose: Pose2, cov: ArrayLike, gate: float | None = None) -> bool:
        """Absolute pose measurement (e.g. laser registration) with its 3x3 covariance.

        The estimate moves towards ``pose`` by the Kalman gain P (P + cov)^-1 (wrapped
        heading innovation). ``gate`` as in :meth:`update_heading` (``CHI2_999[3]``).
        A ``cov`` that is not symmetric positive semi-definite (or not finite) is refused.
        """
        r = np.asarray(cov, dtype=float)
        if r.shape != (3, 3):
            raise ValueError(f"pose covariance must be 3x3, got {r.shape}")
        if not (math.isfinite(pose.x) and math.isfinite(pose.y) and math.isfinite(pose.theta)):
            return False
        r = 0.5 * (r + r.T)
        if not _is_psd3(r):
            return False
        y = np.array([pose.x - self._x, pose.y - self._y, wrap_angle(pose.theta - self._theta)])
        return self._correct_block(3, y, r, gate)

    def update_registration(
        self, pose_f: Pose2, cov_f: ArrayLike, gate: float | None = None, iterations: int = 3
    ) -> bool:
        """The robot's pose in F measured by a laser registration, with its 3x3 covariance
        in (x_F, y_F, heading_F): an iterated EKF update of the robot pose *and* the
        placement (module docstring). ``gate`` as in :meth:`update_pose`, applied to the
        first linearisation. Returns whether the measurement was used.
        """
        r_f = np.asarray(cov_f, dtype=float)
        if r_f.shape != (3, 3):
            raise ValueError(f"registration covariance must be 3x3, got {r_f.shape}")
        if not (
            math.isfinite(pose_f.x) and math.isfinite(pose_f.y) and math.isfinite(pose_f.theta)
        ):
            return False
        r = mirror_covariance(0.5 * (r_f + r_f.T))
        if not _is_psd3(r):
            return False
        meas = np.array([pose_f.x, -pose_f.y, wrap_angle(-pose_f.theta)])
        x0 = self.state
        p0 = self._p
        xi = x0.copy()
        gain = h = s_mat = None
        for it in range(max(1, iterations)):
            self._set_state(xi)
            z, h = self._relative()
            s_mat = h @ p0 @ h.T + r
            try:
                s_inv = np.linalg.inv(s_mat)
            except np.linalg.LinAlgError:
                self._set_state(x0)
                return False
            # IEKF: x_{i+1} = x0 + K_i (m - h(x_i) - H_i (x0 - x_i))
            y = meas - z
            y[2] = wrap_angle(y[2])
            if it == 0 and gate is not None and not float(y @ s_inv @ y) <= gate:
                self._set_state(x0)
                self.registrations_rejected += 1
                return False
            gain = p0 @ h.T @ s_inv
            d = x0 - xi
            d[2] = wrap_angle(d[2])
            d[8] = wrap_angle(d[8])
            step = gain @ (y - h @ d)
            if not np.all(np.isfinite(step)):
                self._set_state(x0)
                return False
            xi = x0 + step
        assert gain is not None and h is not None
        self._set_state(x0)
        a_mat = self._eye - gain @ h
        p = a_mat @ p0 @ a_mat.T + gain @ r @ gain.T
        self._p = (p + p.T) * 0.5
        self._add((xi - x0).tolist())
        self.registrations_accepted += 1
        return True

    def reset_placement(self, pose_f: Pose2, cov_f: ArrayLike) -> None:
        """Re-initialise the placement so that the current robot pose in A sits at
        ``pose_f`` in F (a registration the filter's gate refused although the global
        matching is sure of it: the placement, not the registration, was wrong). Its
        covariance comes from the robot's and the registration's; correlations cleared.
        """
        r_f = np.asarray(cov_f, dtype=float)
        g = Pose2(pose_f.x, -pose_f.y, wrap_angle(-pose_f.theta))
        placement_g = self.pose @ g.inverse()
        self._px, self._py, self._pphi = placement_g.x, placement_g.y, placement_g.theta
        # p = pose_a (+) g^-1: first-order covariance from both
        _, h = self._relative()
        hr = h[:, :3]  # dz/d(robot pose)
        hp = h[:, 6:]  # dz/d(placement)
        hp_inv = np.linalg.inv(hp)
        cov_g = mirror_covariance(0.5 * (r_f + r_f.T))
        p_rr = self._p[:3, :3]
        j_r = -hp_inv @ hr
        cov_p = j_r @ p_rr @ j_r.T + hp_inv @ cov_g @ hp_inv.T
        self._p[6:, :] = 0.0
        self._p[:, 6:] = 0.0
        self._p[6:, 6:] = 0.5 * (cov_p + cov_p.T)
        # keep the robot-placement correlation the map implies
        cross = p_rr @ j_r.T
        self._p[:3, 6:] = cross
        self._p[6:, :3] = cross.T

    def _set_state(self, x: FloatArray) -> None:
        for name, value in zip(_STATE_FIELDS, x.tolist(), strict=True):
            setattr(self, name, value)

    # -- the Kalman correction ----------------------------------------------------------
    def _correct_block(
        self, m: int, y: FloatArray, r: FloatArray, gate: float | None = None
    ) -> bool:
        """Update with H = [I_m 0] (the first m states), innovation ``y``, noise ``r``."""
        p = self._p
        pht = p[:, :m]  # P H^T
        s_mat = p[:m, :m] + r
        if m == 2:
            a, b, c, d = s_mat[0, 0], s_mat[0, 1], s_mat[1, 0], s_mat[1, 1]
            det = a * d - b * c
            if not (det > 0.0 and a > 0.0):
                return False
            s_inv = np.array([[d, -b], [-c, a]]) / det
        else:  # symmetric 3x3: adjugate / determinant
            (a, b, c), (_, d, e), (_, _, g) = s_mat.tolist()
            c00, c01, c02 = d * g - e * e, c * e - b * g, b * e - c * d
            det = a * c00 + b * c01 + c * c02
            if not (det > 0.0 and a > 0.0):
                return False
            c11, c12, c22 = a * g - c * c, b * c - a * e, a * d - b * b
            s_inv = np.array([[c00, c01, c02], [c01, c11, c12], [c02, c12, c22]]) / det
        if gate is not None and not np.dot(y, np.dot(s_inv, y)) <= gate:
            return False
        gain = np.dot(pht, s_inv)  # (n, m)
        a_mat = self._eye.copy()
        a_mat[:, :m] -= gain  # I - K H
        return self._apply(np.dot(gain, y), a_mat, np.dot(np.dot(gain, r), gain.T))

    def _correct_scalar(self, h: FloatArray, y: float, r: float, gate: float | None = None) -> bool:
        """Update with one measurement row ``h`` (n,), innovation ``y``, variance ``r``.

        The Joseph product (I - K h^T) P (I - K h^T)^T is evaluated as two rank-one
        updates, AP = P - K (P h)^T and AP A^T = AP - (AP h) K^T, cheaper than matrix products.
        """
        p = self._p
        pht = np.dot(p, h)
        s = float(np.dot(h, pht)) + r
        if not s > 0.0:
            return False
        if gate is not None and not y * y / s <= gate:
            return False
        gain = pht * (1.0 / s)
        dx = (gain * y).tolist()
        if not all(map(math.isfinite, dx)):
            return False
        gain_col = gain[:, None]
        ap = p - gain_col * pht
        p = ap - np.dot(ap, h)[:, None] * gain
        p += (gain_col * r) * gain
        self._p = (p + p.T) * 0.5
        self._add(dx)
        return True

    def _apply(self, dx: FloatArray, a_mat: FloatArray, krk: FloatArray) -> bool:
        """Joseph form P <- (I - K H) P (I - K H)^T + K R K^T, symmetrised; state += dx."""
        step = dx.tolist()
        if not all(map(math.isfinite, step)):
            return False
        p = np.dot(np.dot(a_mat, self._p), a_mat.T)
        p += krk
        self._p = (p + p.T) * 0.5
        self._add(step)
        return True

    def _add(self, dx: list[float]) -> None:
        ddx, ddy, dth, db, dk, dc, dpx, dpy, dpphi = dx
        self._px += dpx
        self._py += dpy
        self._pphi = wrap_angle(self._pphi + dpphi)
        self._x += ddx
        self._y += ddy
        self._theta = wrap_angle(self._theta + dth)
        self._b += db
        lo, hi = self.yaw_scale_bounds
        self._k = min(hi, max(lo, self._k + dk))
        lo, hi = self.speed_scale_bounds
        self._c = min(hi, max(lo, self._c + dc))


__all__ = ["CHI2_999", "PoseFilter", "wheel_odometry"]
