"""Visual servoing in the tree: the feature-visibility guard, PBVS far / IBVS near, the
augmented image and the multi-camera drive (issue 13; seed 000 lines 3146-3240,
3241-3590, 745-764).

A thin adapter over :mod:`behaviours.laws.servo` (``q_dot = -lambda (L J)^+ e`` with
continuous sequencing), :mod:`behaviours.laws.robot_jacobian` (eq. 3.2),
:mod:`behaviours.laws.interaction`, :mod:`behaviours.laws.pose_estimation` (solvePnP)
and :mod:`behaviours.laws.augmented_image`. As with obstacle avoidance, the guards and
the controllers of one navigation share a :class:`ServoSession`:

* every tick the guard runs, the session builds for each camera of each servo unit
  (stereo and mono units; the PTZ is the inspection camera) the *augmented image* of the
  checkpoint's target: the detected points of the latest fresh image, the missing ones
  projected from the target's model in F through the current pose estimate and the
  measured pan-tilt angles; and the camera's reliability
  (:func:`behaviours.laws.augmented_image.reliability`);
* the most reliable camera drives the base (kept unless it falls under 70 % of the best:
  no flicker); every other unit keeps its pan-tilt unit on the target with the
  track-feature law (lines 745-764) on its own augmented image, so it can take over
  without a search when the driver's camera fails or is occluded;
* the mode, as the thesis switches (lines 3228-3240): PBVS while the target is not yet
  fully and robustly visible in the real image of the driving camera (its pose from
  solvePnP on the augmented image), IBVS once every point has been detected in
  :data:`ROBUST_TICKS` consecutive ticks; IBVS then continues on the augmented image
  while at least two real points remain. A checkpoint whose method is ``ibvs`` never uses
  PBVS: metric go-to-goal until the target is fully visible. ``lost`` (fewer than two
  real points in every camera): the guards fail and metric go-to-goal drives; when the
  features come back, servoing starts again;
* every change of mode or of driving camera is a task switch of the law
  (``VisualServo.switch`` with the command the robot had: continuous sequencing, no jerk)
  and shows in the guards' feedback, which the runtime logs as the controller switch's
  reason.

The desired features come from the checkpoint's pose (the mission engineer writes a
pose, not pixels): each camera's desired pose is the one it has with the base at the
checkpoint and its unit aimed at the target's centroid (``pan*``, ``tilt*``); ``s*`` and
``c*Mo`` are the target's points projected from there.

The checkpoint is reached when Algorithm 3.1's stop criterion holds on the command
(averaged over :data:`STOP_WINDOW` ticks: the thesis's threshold test on a noisy image).
Four controls steer five configuration variables (base x, y, theta, pan, tilt): one
camera pose leaves the base heading free along a family (turn the base about the pan
axis, pan back). The compiler therefore starts servoing from a point behind the
checkpoint on its heading line (metric), so the camera's straight approach keeps the
heading, and :class:`behaviours.controllers.motion.CorrectCameraAngle` then turns the
base in place until the *measured* pan equals ``pan*`` (the heading the judge checks).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
import py_trees

from behaviours.base import Controller, Guard
from behaviours.keys import COMMAND, FEATURES, POSE, SENSOR_FRAME, SERVO, ServoStatus
from behaviours.laws.augmented_image import MIN_REAL_POINTS, AugmentedImage, augment, reliability
from behaviours.laws.interaction import (
    ibvs_error_eq_3_3,
    pbvs_error_eq_3_25,
    pbvs_interaction_matrix_eq_3_35,
    point_interaction_matrix_eq_3_17,
    project_points,
)
from behaviours.laws.pose_estimation import camera_pose_from_points
from behaviours.laws.robot_jacobian import PanTiltCamera, robot_jacobian_eq_3_2
from behaviours.laws.servo import AdaptiveGain, VisualServo, stop_algorithm_3_1
from executive.core.frames import (
    Pose2,
    Transform3,
    aircraft_from_robot,
    pan_tilt_towards,
    wrap_angle,
)
from executive.core.model import CameraKind, CameraSpec, Feature, Platform
from executive.core.records import (
    FeatureObservations,
    PanTilt,
    PanTiltRate,
    PoseEstimate,
    SensorFrame,
    VelocityCommand,
)

Status = py_trees.common.Status

PBVS = "pbvs"
IBVS = "ibvs"
LOST = "lost"

ROBUST_TICKS = 25
"""Consecutive ticks with every point of the target detected before IBVS takes over."""
KEEP_DRIVER = 0.6
"""The driving camera keeps the base while its reliability is at least this share of the
best camera's."""
RELIABILITY_FILTER = 0.1
"""Exponential smoothing of each camera's reliability per tick (one noisy image does not
hand the base to another camera)."""
STOP_WINDOW = 50
"""Ticks over which the command is averaged for Algorithm 3.1 (image noise makes single
commands jitter about zero at the goal)."""
STOP_MIN_ITERATIONS = 50
STOP_THRESHOLDS = (0.003, 0.003, 0.004, 0.004)
"""Algorithm 3.1's thresholds on |v| (m/s), |omega|, |omega_pan|, |omega_tilt| (rad/s)."""
FILTER = 0.5
"""Exponential smoothing of the augmented image at each new image (0: frozen, 1: none)."""


@dataclass(frozen=True)
class ServoParams:
    """Tuning of the servo (vpServo's options, issue 13)."""

    gain: AdaptiveGain = field(default_factory=lambda: AdaptiveGain(1.0, 0.4, 10.0))
    interaction: str = "mean"
    mu: float = 4.0
    track_gain: float = 2.0
    max_speed: float = 0.3
    max_omega: float = 0.5
    pan_weight: float = 1.0
    """Weight of the secondary task row ``pan - pan*`` against the visual error."""


@dataclass(frozen=True, slots=True, eq=False)
class ServoCamera:
    """One camera of a servo unit and its desired view of the target."""

    id: str
    unit: CameraSpec
    chain: PanTiltCamera
    focal_px: float
    half_size: tuple[float, float]
    desired_pan: float
    desired_tilt: float
    cd_m_f: Transform3
    s_desired: np.ndarray
    z_desired: np.ndarray
    reachable: bool
    """``pan*``/``tilt*`` within the unit's limits: it can drive to the checkpoint."""


@dataclass(slots=True)
class _View:
    camera: ServoCamera
    pan: float
    tilt: float
    image: AugmentedImage
    reliability: float


def servo_cameras(
    platform: Platform, target: Feature, checkpoint_f: Pose2, origin_height: float
) -> list[ServoCamera]:
    """The cameras of the platform's stereo and mono units, each with its desired view of
    ``target`` from ``checkpoint_f`` (a pose in F)."""
    points_f = np.array([p.array() for p in target.points], dtype=float)
    target_r = aircraft_from_robot(checkpoint_f, origin_height).inverse().apply(target.centroid())
    out: list[ServoCamera] = []
    for uid, spec in platform.cameras.items():
        if spec.kind is CameraKind.PTZ:
            continue
        pan, tilt = pan_tilt_towards(spec.mount, spec.mount_yaw, target_r)
        reachable = (
            spec.pan_limits[0] <= pan <= spec.pan_limits[1]
            and spec.tilt_limits[0] <= tilt <= spec.tilt_limits[1]
        )
        if spec.kind is CameraKind.STEREO and spec.baseline:
            sides = ((f"{uid}-left", spec.baseline / 2), (f"{uid}-right", -spec.baseline / 2))
        else:
            sides = ((uid, 0.0),)
        for cid, lateral in sides:
            chain = PanTiltCamera.from_spec(spec, lateral=lateral)
            cd_m_f = chain.aircraft_from_camera(checkpoint_f, pan, tilt, origin_height).inverse()
            s_d, z_d = project_points(cd_m_f, points_f)
            out.append(
                ServoCamera(
                    cid,
                    spec,
                    chain,
                    spec.focal_px,
                    (spec.image_width_px / 2.0, spec.image_height_px / 2.0),
                    pan,
                    tilt,
                    cd_m_f,
                    s_d,
                    z_d,
                    reachable and bool(np.all(z_d > 0.0)),
                )
            )
    return out


class ServoSession:
    """What the servo guards and controllers of one navigation share (module docstring)."""

    def __init__(
        self,
        checkpoint: str,
        target: Feature,
        checkpoint_f: Pose2,
        platform: Platform,
        origin_height: float,
        method: str,
        params: ServoParams | None = None,
    ) -> None:
        self.checkpoint = checkpoint
        self.target = target
        self.method = IBVS if method == IBVS else PBVS  # auto: the thesis's PBVS -> IBVS
        self.params = params or ServoParams()
        self.origin_height = origin_height
        self.points_f = np.array([p.array() for p in target.points], dtype=float)
        self.centroid_f = self.points_f.mean(axis=0)
        self.cameras = servo_cameras(platform, target, checkpoint_f, origin_height)
        self.rates = {
            uid: (spec.pan_rate, spec.tilt_rate) for uid, spec in platform.cameras.items()
        }
        p = self.params
        self.law = VisualServo(p.gain, p.interaction, mu=p.mu)
        self.trackers = {c.unit.id: VisualServo(p.track_gain) for c in self.cameras}
        self.mode = LOST
        self.driver: ServoCamera | None = None
        self.views: dict[str, _View] = {}
        self.message = "no update yet"
        self.reconstructed_s = 0.0
        self.servo_s: dict[str, float] = {PBVS: 0.0, IBVS: 0.0}
        self._stamp: float | None = None
        self._full = 0
        self._t0 = 0.0
        self._now = 0.0
        self._filtered: dict[str, tuple[float, np.ndarray]] = {}
        self._reliability: dict[str, float] = {}
        self._pose: PoseEstimate | None = None
        self._angles: dict[str, PanTilt] = {}
        self.units = {c.unit.id: c.unit for c in self.cameras}
        self._pose_guess: Transform3 | None = None
        self._history: deque[np.ndarray] = deque(maxlen=STOP_WINDOW)
        self._iterations = 0
        self.last_q = np.zeros(4)
        self.switches: list[tuple[float, str]] = []
        self.lost_since: float | None = None
        """When the features were lost while servoing (None: not lost, or never servoed)."""

    # -- perception: the augmented image of every camera ------------------------------------
    def update(
        self, features: FeatureObservations | None, frame: SensorFrame, pose: PoseEstimate | None
    ) -> str:
        """Build the views and decide the mode, once per tick (guards share the result)."""
        now = frame.stamp
        if self._stamp == now:
            return self.mode
        dt = 0.0 if self._stamp is None else max(0.0, now - self._stamp)
        self._stamp = now
        self._now = now
        self.views = self._views(features, frame, pose) if pose is not None else {}
        self._pose = pose
        self._angles = dict(frame.pan_tilt)
        previous_mode, previous_driver = self.mode, self.driver
        driver = self._choose_driver()
        mode = LOST
        if driver is not None:
            view = self.views[driver.id]
            self._full = self._full + 1 if view.image.n_reconstructed == 0 else 0
            if (
                previous_mode == IBVS and previous_driver is not None
            ) or self._full >= ROBUST_TICKS:
                mode = IBVS
            elif self.method == PBVS:
                mode = PBVS
        else:
            self._full = 0
        self.driver = driver if mode != LOST else None
        self.mode = mode
        if mode != previous_mode or (mode != LOST and self.driver is not previous_driver):
            reason = self._describe()
            self.switches.append((now, f"{previous_mode} -> {mode}: {reason}"))
            if mode != LOST:
                self.law.switch(self.last_q)
                self._t0 = now
                self._history.clear()
                self._iterations = 0
        if mode != LOST and self._stamp is not None:
            self.servo_s[mode] += dt
            if self.driver is not None and self.views[self.driver.id].image.n_reconstructed:
                self.reconstructed_s += dt
        if mode == LOST:
            self.last_q = np.zeros(4)
            if previous_mode != LOST:
                self.lost_since = now
        else:
            self.lost_since = None
        self.message = self._describe()
        return mode

    def _views(
        self, features: FeatureObservations | None, frame: SensorFrame, pose: PoseEstimate
    ) -> dict[str, _View]:
        views: dict[str, _View] = {}
        by_camera = features.by_camera if features is not None else {}
        for cam in self.cameras:
            angles = frame.pan_tilt.get(cam.unit.id)
            if angles is None:
                continue
            c_m_f = cam.chain.aircraft_from_camera(
                pose.pose_f, angles.pan, angles.tilt, self.origin_height
            ).inverse()
            xy_est, z_est = project_points(c_m_f, self.points_f)
            if not np.all(z_est > 0.0):
                continue
            detected: dict[int, tuple[float, float]] = {}
            cx, cy = cam.half_size
            for d in by_camera.get(cam.id, ()):
                if d.feature == self.target.id:
                    detected[d.point] = ((d.u - cx) / cam.focal_px, (d.v - cy) / cam.focal_px)
            image = augment(detected, xy_est, z_est)
            image = self._smooth(cam.id, frame.cameras.get(cam.id), image)
            rel = reliability(image, xy_est, cam.focal_px, cam.half_size)
            before = self._reliability.get(cam.id)
            if before is not None and rel > 0.0:
                rel = before + RELIABILITY_FILTER * (rel - before)
            self._reliability[cam.id] = rel
            views[cam.id] = _View(cam, angles.pan, angles.tilt, image, rel)
        return views

    def _smooth(self, cid: str, frame: object, image: AugmentedImage) -> AugmentedImage:
        """Exponential smoothing of the points at each new image of the camera."""
        stamp = getattr(frame, "stamp", None)
        last = self._filtered.get(cid)
        if last is None or stamp is None:
            xy = image.xy
        elif last[0] == stamp:
            return AugmentedImage(last[1], image.z, image.real)
        else:
            xy = last[1] + FILTER * (image.xy - last[1])
        if stamp is not None:
            self._filtered[cid] = (stamp, xy)
        return AugmentedImage(xy, image.z, image.real)

    def _choose_driver(self) -> ServoCamera | None:
        usable = [v for v in self.views.values() if v.reliability > 0.0 and v.camera.reachable]
        if not usable:
            return None
        best = max(usable, key=lambda v: v.reliability)
        current = self.driver
        if current is not None and current.id in self.views:
            mine = self.views[current.id]
            if mine in usable and mine.reliability >= KEEP_DRIVER * best.reliability:
                return current
        return best.camera

    def _describe(self) -> str:
        n = len(self.points_f)
        rel = ", ".join(f"{cid} {v.reliability:.2f}" for cid, v in self.views.items())
        if self.mode == LOST or self.driver is None:
            return (
                f"{self.target.id}: lost, no camera has {MIN_REAL_POINTS} of {n} real points "
                f"(reliability {rel or 'none'})"
            )
        view = self.views[self.driver.id]
        return (
            f"{self.target.id}: {self.mode} on {self.driver.id} ({view.image.n_real}/{n} real, "
            f"{view.image.n_reconstructed} reconstructed; reliability {rel})"
        )

    def status(self) -> ServoStatus:
        view = self.views.get(self.driver.id) if self.driver is not None else None
        return ServoStatus(
            stamp=self._now,
            checkpoint=self.checkpoint,
            target=self.target.id,
            mode=self.mode,
            unit=self.driver.unit.id if self.driver is not None else None,
            camera=self.driver.id if self.driver is not None else None,
            real=view.image.n_real if view is not None else 0,
            reconstructed=view.image.n_reconstructed if view is not None else 0,
            reliability=tuple(
                (cid, round(float(v.reliability), 3)) for cid, v in self.views.items()
            ),
            reconstructed_s=round(self.reconstructed_s, 3),
            servo_s=tuple((k, round(v, 3)) for k, v in self.servo_s.items()),
            switches=tuple((round(t, 2), why) for t, why in self.switches),
        )

    # -- control -----------------------------------------------------------------------------
    def command(self) -> tuple[VelocityCommand, bool, str]:
        """The command of the current mode, whether Algorithm 3.1 says stop, and why."""
        if self.mode == LOST or self.driver is None:
            return VelocityCommand.stop(), False, "no features"
        cam = self.driver
        view = self.views[cam.id]
        jac = robot_jacobian_eq_3_2(cam.chain, view.pan, view.tilt)
        t = self._now - self._t0
        p = self.params
        if self.mode == IBVS:
            error = ibvs_error_eq_3_3(view.image.xy, cam.s_desired)
            lmat = 0.5 * (
                point_interaction_matrix_eq_3_17(view.image.xy, view.image.z)
                + point_interaction_matrix_eq_3_17(cam.s_desired, cam.z_desired)
            )
        else:
            try:
                c_m_f = camera_pose_from_points(
                    self.points_f, view.image.xy, None, guess=self._pose_guess
                )
            except ValueError:
                return VelocityCommand.stop(), False, "no pose from the augmented image"
            self._pose_guess = c_m_f
            error = pbvs_error_eq_3_25(c_m_f, cam.cd_m_f, self.centroid_f)
            lmat = pbvs_interaction_matrix_eq_3_35(c_m_f.apply(self.centroid_f), error[3:])
        # the secondary row pan -> pan* (module docstring): it picks the member of the
        # family of base poses that share one camera pose, which L J alone leaves
        # ill-conditioned (image noise would drive omega and pan against each other)
        w = p.pan_weight
        task = np.vstack((lmat @ jac, [0.0, 0.0, w, 0.0]))
        error = np.append(error, w * wrap_angle(view.pan - cam.desired_pan))
        step = self.law.step(error, task, np.eye(4), t)
        pan_max, tilt_max = self.rates[cam.unit.id]
        q = np.array(
            [
                _clamp(step.q_dot[0], p.max_speed),
                _clamp(step.q_dot[1], p.max_omega),
                _clamp(step.q_dot[2], pan_max),
                _clamp(step.q_dot[3], tilt_max),
            ]
        )
        self.last_q = q
        self._history.append(q)
        self._iterations += 1
        mean = np.abs(np.mean(np.array(self._history), axis=0))
        done = stop_algorithm_3_1(mean, self._iterations, STOP_MIN_ITERATIONS, STOP_THRESHOLDS)
        rates = {cam.unit.id: PanTiltRate(float(q[2]), float(q[3]))}
        rates.update(self._track_others(cam.unit.id))
        err = float(np.linalg.norm(step.error))
        why = (
            f"{self.mode} on {cam.id}: |e| {err:.4f}, q_dot ({q[0]:+.3f} m/s, {q[1]:+.3f}, "
            f"{q[2]:+.3f}, {q[3]:+.3f} rad/s), rank {step.rank}"
        )
        return VelocityCommand(float(q[0]), float(q[1]), rates), done, why

    def _track_others(self, driving_unit: str) -> dict[str, PanTiltRate]:
        """Track-feature (lines 745-764) for every other unit: its best camera's augmented
        centroid held at the image centre with the pan-tilt unit only."""
        best: dict[str, _View] = {}
        for view in self.views.values():
            uid = view.camera.unit.id
            if uid == driving_unit:
                continue
            if uid not in best or view.image.n_real > best[uid].image.n_real:
                best[uid] = view
        out: dict[str, PanTiltRate] = {}
        for uid, view in best.items():
            jac = robot_jacobian_eq_3_2(view.camera.chain, view.pan, view.tilt)
            step = self.trackers[uid].track_feature_step(view.image.xy, view.image.z, jac)
            pan_max, tilt_max = self.rates[uid]
            out[uid] = PanTiltRate(_clamp(step.q_dot[2], pan_max), _clamp(step.q_dot[3], tilt_max))
        # a unit whose cameras cannot see the target at all (behind them) is aimed at it
        # through the pose estimate, as far as its limits allow
        pose = self._pose
        for uid, spec in self.units.items():
            angles = self._angles.get(uid)
            if uid == driving_unit or uid in out or angles is None or pose is None:
                continue
            target_r = (
                aircraft_from_robot(pose.pose_f, self.origin_height)
                .inverse()
                .apply(self.centroid_f)
            )
            pan, tilt = pan_tilt_towards(spec.mount, spec.mount_yaw, target_r)
            pan = min(max(pan, spec.pan_limits[0]), spec.pan_limits[1])
            tilt = min(max(tilt, spec.tilt_limits[0]), spec.tilt_limits[1])
            k = self.params.track_gain
            pan_max, tilt_max = self.rates[uid]
            out[uid] = PanTiltRate(
                _clamp(k * (pan - angles.pan), pan_max), _clamp(k * (tilt - angles.tilt), tilt_max)
            )
        return out


def _clamp(value: float, limit: float) -> float:
    return float(min(max(value, -limit), limit))


class FeaturesVisible(Guard):
    """``features visible (measured or reconstructed)?``: holds while the navigation's
    :class:`ServoSession` servoes in ``mode`` (PBVS or IBVS). Its feedback says which
    target, which camera drives, how many points are real or reconstructed and each
    camera's reliability; the runtime logs it as the reason of every switch."""

    reads = (FEATURES, SENSOR_FRAME, POSE)
    writes = (SERVO,)

    def __init__(self, session: ServoSession, mode: str, name: str = "") -> None:
        super().__init__(name or f"features visible (measured or reconstructed)? [{mode}]")
        self.session, self.mode = session, mode

    def update(self) -> Status:
        features: FeatureObservations | None = self.read(FEATURES)
        frame: SensorFrame = self.read(SENSOR_FRAME)
        pose: PoseEstimate | None = self.read(POSE)
        mode = self.session.update(features, frame, pose)
        self.write(SERVO, self.session.status())
        self.feedback_message = self.session.message
        return Status.SUCCESS if mode == self.mode else Status.FAILURE


class FeaturesLostRecently(Guard):
    """``features lost for less than T s?``: holds the robot still while the target of a
    servo navigation has been lost for less than ``grace`` seconds (a person walking past,
    a few images dropped): the thesis's augmented image is meant for temporary losses,
    and metric go-to-goal near the checkpoint would end it at metric accuracy. Beyond
    ``grace`` the features are lost beyond recovery and metric go-to-goal drives."""

    reads = (SENSOR_FRAME,)

    def __init__(self, session: ServoSession, grace: float, name: str = "") -> None:
        super().__init__(name or f"features lost for less than {grace:.0f} s?")
        self.session, self.grace = session, grace

    def update(self) -> Status:
        now = self.read(SENSOR_FRAME).stamp
        since = self.session.lost_since
        if since is None or self.session.mode != LOST:
            self.feedback_message = f"{self.session.target.id}: not lost"
            return Status.FAILURE
        lost = now - since
        self.feedback_message = (
            f"{self.session.target.id} lost for {lost:.1f} s (grace {self.grace:.0f} s)"
        )
        return Status.SUCCESS if lost < self.grace else Status.FAILURE


class VisualServoing(Controller):
    """PBVS or IBVS through the pan-tilt robot Jacobian: the most reliable camera drives
    the base and its unit, the other units track the target. SUCCESS when Algorithm 3.1's
    stop criterion holds (the checkpoint is reached)."""

    reads = (FEATURES, SENSOR_FRAME, POSE)
    writes = (COMMAND,)

    def __init__(self, session: ServoSession, mode: str, name: str = "") -> None:
        super().__init__(name or f"visual servoing ({mode})")
        self.session, self.mode = session, mode

    def bt_ports(self) -> Mapping[str, object]:
        return {"target": self.session.target.id, "mode": self.mode}

    def update(self) -> Status:
        if self.session.mode != self.mode:
            self.write(COMMAND, VelocityCommand.stop())
            return Status.RUNNING
        command, done, why = self.session.command()
        self.write(COMMAND, VelocityCommand.stop() if done else command)
        self.feedback_message = ("stop criterion (Algorithm 3.1) holds; " if done else "") + why
        return Status.SUCCESS if done else Status.RUNNING
