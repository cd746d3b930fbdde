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
* the most reliable camera drives the base (kept unless it falls under
  :data:`KEEP_DRIVER` of the best, then the best camera of the same unit; another unit
  only when the driving unit has lost the target: no flicker); every other unit keeps its
  pan-tilt unit on the target with the track-feature law (lines 745-764) on its own
  augmented image, so it can take over without a search when the driver's camera fails
  or is occluded. A point missed in fewer than :data:`DROPOUT_IMAGES` images is a
  dropout, not a loss;
* the mode, as the thesis switches (lines 3228-3240): PBVS while the target is not yet
  fully and robustly visible in the real image of the driving camera (its pose from
  solvePnP on the augmented image), IBVS once every point has been detected in
  :data:`ROBUST_TICKS` consecutive ticks; IBVS then continues on the augmented image
  while at least two real points remain. A checkpoint whose method is ``ibvs`` never uses
  PBVS: metric go-to-goal until the target is fully visible. PBVS needs a pose: with the
  driving camera's points in view fewer than 4 or on one line
  (:func:`behaviours.laws.pose_estimation.is_well_posed`), or when solvePnP fails, the
  servo runs IBVS on the augmented image instead (the switch says why);
* a servo whose error has not fallen by :data:`PROGRESS_SHARE` for :data:`NO_PROGRESS_S`
  gives the checkpoint to metric go-to-goal for good (``gave_up``, in the guards'
  feedback), rather than holding the robot until the mission's trap guard ends it;
* ``lost`` (fewer than two real points in every camera): the guards fail and metric
  go-to-goal drives; when the features come back, servoing starts again;
* every change of mode or of driving camera is a task switch of the law
  (``VisualServo.switch`` with the command the robot had: continuous sequencing, no jerk)
  and shows in the guards' feedback, which the runtime logs as the controller switch's
  reason.

The desired features come from the checkpoint's pose (the mission engineer writes a
pose, not pixels): each camera's desired pose is the one it has with the base at the
checkpoint and its unit aimed at the target's centroid (``pan*``, ``tilt*``), or at the
target point that keeps the most points in its images (:func:`desired_aim`); ``s*`` and
``c*Mo`` are the target's points in view from there projected, and each camera servoes
on those only. Metric go-to-goal towards the servo start and as the fallback keeps the
units on the target (:class:`AimedGoToGoal`); a target of which no camera sees two points
from the checkpoint (one point: a bearing, not a pose) is reached by metric go-to-goal,
then :class:`TrackFeature` and correct camera angle on the tracking unit's pan.

The checkpoint is reached when Algorithm 3.1's stop criterion holds on the command
(averaged over :data:`STOP_WINDOW` ticks: the thesis's threshold test on a noisy image).
Four controls steer five configuration variables (base x, y, theta, pan, tilt): one
camera pose leaves the base heading free along a family (turn the base about the pan
axis, pan back). The compiler therefore starts servoing from a point behind the
checkpoint on its heading line (metric; :class:`SlideServoStart` moves it towards the
checkpoint where the robot could not turn in place there); on the way in, a task row
from the localisation steers the base back onto that line
(:func:`behaviours.laws.servo.approach_line_row`: the lateral offset is what no command
reaches at the goal and what the image hardly tells from a rotation), and
:class:`behaviours.controllers.motion.CorrectCameraAngle` then turns the base in place
until the *measured* pan of the driving unit equals ``pan*`` (the heading the judge
checks).
"""

from __future__ import annotations

import dataclasses
import math
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np
import py_trees

from behaviours.base import Controller, Guard, Node
from behaviours.controllers.motion import GoToGoalController
from behaviours.goals import Goal
from behaviours.keys import COMMAND, FEATURES, OBSTACLES, POSE, SENSOR_FRAME, SERVO, ServoStatus
from behaviours.laws.augmented_image import (
    MIN_REAL_POINTS,
    AugmentedImage,
    augment,
    feature_motion_eq_3_16,
    filter_features,
    filter_gain,
    reliability,
)
from behaviours.laws.go_to_goal import GoToGoalParams
from behaviours.laws.interaction import (
    ibvs_error_eq_3_3,
    pbvs_error_eq_3_25,
    pbvs_interaction_matrix_eq_3_35,
    point_interaction_matrix_eq_3_17,
    project_points,
)
from behaviours.laws.localisation import wheel_odometry
from behaviours.laws.obstacles import is_mover
from behaviours.laws.pose_estimation import camera_pose_from_points, is_well_posed
from behaviours.laws.robot_jacobian import PanTiltCamera, robot_jacobian_eq_3_2
from behaviours.laws.servo import (
    AdaptiveGain,
    VisualServo,
    approach_depth_row,
    approach_line_row,
    stop_algorithm_3_1,
)
from behaviours.laws.servo_start import (
    SERVO_START_MARGIN,
    candidate_distances,
    start_distance,
)
from executive.core.frames import (
    Pose2,
    Transform3,
    aircraft_from_robot,
    pan_tilt_towards,
)
from executive.core.model import CameraKind, CameraSpec, Feature, Platform
from executive.core.records import (
    FeatureObservations,
    Obstacles,
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
DETECTION_SIGMA_PX = 0.5
STILL_SIGMA_PX = 0.02
MODEL_SHARE = 0.2
"""The predict-correct filter of the augmented image at each new image
(:func:`behaviours.laws.augmented_image.filter_features`, gain from
:func:`behaviours.laws.augmented_image.filter_gain`): the points are moved by the robot's
measured motion since the previous image, then pulled towards the new detections by a
Kalman gain that weighs the detector's noise (``DETECTION_SIGMA_PX``, 1 sigma) against
what the motion model may miss (``MODEL_SHARE`` of the predicted shift, for the wheels'
slip, and ``STILL_SIGMA_PX`` per image). Driving, the detections lead; as the servo
converges the estimate averages the noise over more and more images (a two-point target
4 m away fixes its depth from a 0.5 px noisy spacing: the final accuracy is this noise
averaged)."""
PREDICT_SPAN_S = 0.5
PREDICT_MOTION = np.array([0.05, 0.05, 0.05, 0.05])
"""The filter restarts from the detections when the camera's previous image is older than
:data:`PREDICT_SPAN_S` (s) or the robot moved more than :data:`PREDICT_MOTION` (ds m,
dtheta, dpan, dtilt rad) since: beyond, the first-order image motion of eq. 3.16 is not
a prediction (a target far off the optical axis would be thrown out of the image)."""
DROPOUT_IMAGES = 3
"""Consecutive images of a camera with fewer than :data:`MIN_REAL_POINTS` real points of
the target before the camera counts as having lost it. A detector dropout in one image
(sim2d: 2 % per point) is not a loss: the camera keeps its (decaying) reliability, and a
point real in the previous image holds its filtered position, so one missed detection
neither hands the base to another camera nor ends the servo."""
NO_PROGRESS_S = 20.0
"""A servo whose error norm has not fallen by :data:`PROGRESS_SHARE` of its best value for
this long hands the checkpoint over to metric go-to-goal (with an event saying so) instead
of holding the robot until the mission's trap guard ends it."""
PROGRESS_SHARE = 0.05


@dataclass(frozen=True)
class ServoParams:
    """Tuning of the servo (vpServo's options, issue 13)."""

    gain: AdaptiveGain = field(default_factory=lambda: AdaptiveGain(2.0, 0.5, 10.0))
    interaction: str = "mean"
    mu: float = 4.0
    track_gain: float = 2.0
    max_speed: float = 0.3
    max_omega: float = 0.5
    pan_weight: float = 1.0
    """Weight of the secondary task row ``pan - pan*`` against the visual error, at the
    goal; :attr:`pan_weight_far` of it where the approach-line row steers at full weight."""
    pan_weight_far: float = 0.1
    line_weight: float = 3.0
    """Weight (1/m) of the approach-line row
    (:func:`behaviours.laws.servo.approach_line_row`) against the visual error. Against
    the pan row (the camera's yaw held by the image, turning the base costs pan error) the
    least-squares law turns the base by ``w^2 d^2 / (w^2 d^2 + 1)`` of the pure-pursuit
    angle ``-c / d``: 0.9 of it 1 m out (the servo start), half at 1 / w."""
    line_gain: float = 4.0
    """The approach-line row's error is regulated this many times faster than the visual
    rows (its error scaled, its Jacobian not): eq. 3.10 shrinks each independent task
    error as ``exp(-lambda t)`` in *time*, and at the servo's speed the approach takes
    three seconds, at a lambda near ``lambda_inf``: at the visual rows' rate the offset
    across the line had shrunk by a third when the row faded out."""
    line_lookahead: float = 0.4
    """Cap (m) of the approach-line row's pursuit distance
    (:func:`behaviours.laws.servo.approach_line_row`): the offset across the line decays
    over this distance instead of in proportion to the distance left."""
    depth_sigma: float = 0.01
    """Standard deviation (m) of the localisation's distance to the checkpoint along its
    heading line: the depth row (:func:`behaviours.laws.servo.approach_depth_row`) weighs
    ``sigma_image / depth_sigma`` against the IBVS rows (unit weight, ``sigma_image`` the
    detection noise in normalised image units)."""
    line_from: float = 1.0
    line_until: float = 0.25
    """The approach-line row's weight fades linearly from ``line_weight`` with the base
    ``line_from`` (m) or more behind the checkpoint along its heading line (the servo
    start) to 0 at ``line_until``; closer, the visual rows finish alone. A fixed weight
    holds a residual against them: with a target that fixes the distance weakly (two
    points) the robot stopped 37 cm short of the checkpoint, heading at it."""


IMAGE_MARGIN_PX = 20.0
"""A target point counts as in view at the checkpoint when its desired pixel is at least
this far inside the image (the reliability's margin, :mod:`behaviours.laws.augmented_image`)."""


@dataclass(frozen=True, slots=True, eq=False)
class ServoCamera:
    """One camera of a servo unit and its desired view of the target.

    ``points`` are the indices of the target's points that this camera sees from the
    checkpoint (in front of it and inside its image): the camera servoes on those only. A
    long target seen from close (a wing's leading edge from 2 m) does not fit in one
    image; a point outside the desired image can never be real there, so servoing on it
    would end on the pose estimate's reconstruction (or never see the target "fully")."""

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
    """``pan*``/``tilt*`` within the unit's limits and at least :data:`MIN_REAL_POINTS`
    points in view at the checkpoint: it can drive to the checkpoint."""
    points: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    pose_from_points: bool = False
    """The points in view determine the target's pose (PBVS possible with this camera)."""
    aim_f: np.ndarray = field(default_factory=lambda: np.zeros(3))
    """The point (F) the unit aims at with ``pan*``, ``tilt*`` (:func:`desired_aim`)."""
    within_limits: bool = False
    """``pan*`` and ``tilt*`` are within the unit's limits."""


@dataclass(slots=True)
class _View:
    camera: ServoCamera
    pan: float
    tilt: float
    image: AugmentedImage
    reliability: float


def _in_view(
    xy: np.ndarray, z: np.ndarray, focal_px: float, half: tuple[float, float]
) -> np.ndarray:
    px = np.abs(xy) * focal_px
    return (
        (z > 0.0) & (px[:, 0] < half[0] - IMAGE_MARGIN_PX) & (px[:, 1] < half[1] - IMAGE_MARGIN_PX)
    )


def desired_aim(
    spec: CameraSpec,
    chains: list[PanTiltCamera],
    points_f: np.ndarray,
    checkpoint_f: Pose2,
    origin_height: float,
) -> tuple[float, float, np.ndarray]:
    """``pan*``, ``tilt*`` of a unit at the checkpoint and the point of the target (in F)
    they aim at: the target's centroid, or,
    when that leaves some of its points out of an image, at the point (or midpoint of two
    points) that keeps the most points in view in every camera of the unit (ties: the
    candidate listed first, the centroid first, so a target that fits keeps its aim)."""
    robot_from_f = aircraft_from_robot(checkpoint_f, origin_height).inverse()
    n = len(points_f)
    candidates = [points_f.mean(axis=0), *points_f]
    candidates += [(points_f[i] + points_f[j]) / 2 for i in range(n) for j in range(i + 1, n)]
    best: tuple[tuple[int, int], tuple[float, float, np.ndarray]] | None = None
    for aim in candidates:
        pan, tilt = pan_tilt_towards(spec.mount, spec.mount_yaw, robot_from_f.apply(aim))
        reachable = (
            spec.pan_limits[0] <= pan <= spec.pan_limits[1]
            and spec.tilt_limits[0] <= tilt <= spec.tilt_limits[1]
        )
        seen = []
        for chain in chains:
            cd_m_f = chain.aircraft_from_camera(checkpoint_f, pan, tilt, origin_height).inverse()
            xy, z = project_points(cd_m_f, points_f)
            seen.append(int(np.count_nonzero(_in_view(xy, z, spec.focal_px, _half(spec)))))
        score = (int(reachable), min(seen))
        if best is None or score > best[0]:
            best = (score, (pan, tilt, aim))
        if score == (1, n):
            break
    assert best is not None
    return best[1]


def _half(spec: CameraSpec) -> tuple[float, float]:
    return (spec.image_width_px / 2.0, spec.image_height_px / 2.0)


def servo_cameras(
    platform: Platform, target: Feature, checkpoint_f: Pose2, origin_height: float
) -> list[ServoCamera]:
    """The cameras of the platform's stereo and mono units, each with its desired view of
    ``target`` from ``checkpoint_f`` (a pose in F)."""
    points_f = np.array([p.array() for p in target.points], dtype=float)
    out: list[ServoCamera] = []
    for uid, spec in platform.cameras.items():
        if spec.kind is CameraKind.PTZ:
            continue
        if spec.kind is CameraKind.STEREO and spec.baseline:
            sides = ((f"{uid}-left", spec.baseline / 2), (f"{uid}-right", -spec.baseline / 2))
        else:
            sides = ((uid, 0.0),)
        chains = [PanTiltCamera.from_spec(spec, lateral=lateral) for _, lateral in sides]
        pan, tilt, aim_f = desired_aim(spec, chains, points_f, checkpoint_f, origin_height)
        reachable = (
            spec.pan_limits[0] <= pan <= spec.pan_limits[1]
            and spec.tilt_limits[0] <= tilt <= spec.tilt_limits[1]
        )
        for (cid, _), chain in zip(sides, chains, strict=True):
            cd_m_f = chain.aircraft_from_camera(checkpoint_f, pan, tilt, origin_height).inverse()
            s_d, z_d = project_points(cd_m_f, points_f)
            seen = np.flatnonzero(_in_view(s_d, z_d, spec.focal_px, _half(spec)))
            out.append(
                ServoCamera(
                    cid,
                    spec,
                    chain,
                    spec.focal_px,
                    _half(spec),
                    pan,
                    tilt,
                    cd_m_f,
                    s_d[seen],
                    z_d[seen],
                    reachable and seen.size >= MIN_REAL_POINTS,
                    seen,
                    is_well_posed(points_f[seen]),
                    aim_f,
                    reachable,
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
        self.checkpoint_f = checkpoint_f
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
        self._filtered: dict[str, tuple[float, np.ndarray, np.ndarray]] = {}
        self._moved: dict[str, np.ndarray] = {}
        self._variance: dict[str, float] = {}
        """Base motion (ds m, dtheta rad) measured since each camera's last image."""
        self._image_angles: dict[str, PanTilt] = {}
        self.track = platform.track
        self._reliability: dict[str, float] = {}
        self._pose: PoseEstimate | None = None
        self._angles: dict[str, PanTilt] = {}
        self.units = {c.unit.id: c.unit for c in self.cameras}
        self.drivable = any(c.reachable for c in self.cameras)
        """Some camera sees enough of the target from the checkpoint to servo the base
        there (:data:`MIN_REAL_POINTS`; a one-point target never does)."""
        self.aims = {c.unit.id: c.aim_f for c in self.cameras}
        self._pose_guess: Transform3 | None = None
        self._history: deque[np.ndarray] = deque(maxlen=STOP_WINDOW)
        self._iterations = 0
        self.last_q = np.zeros(4)
        self.switches: list[tuple[float, str]] = []
        self.lost_since: float | None = None
        """When the features were lost while servoing (None: not lost, or never servoed)."""
        self.last_driver: ServoCamera | None = None
        """The camera that drove last (its unit's pan was servoed to ``pan*``)."""
        self.start_note = ""
        """Why the servo start was slid towards the checkpoint ("": it was not)."""
        self.compiled_start = self.params.line_from
        """Where the compiler put the servo start (m before the checkpoint)."""
        self.track_error_px: float | None = None
        """How far (px) the tracked camera's detections are from their desired pixels."""
        self.tracked: ServoCamera | None = None
        """The camera that last held the target at ``s*`` by track-feature under metric
        go-to-goal (:meth:`track_rates`)."""
        self.gave_up: str | None = None
        """Why servoing handed this checkpoint over to metric go-to-goal for good (no
        progress for :data:`NO_PROGRESS_S`), or None."""
        self._no_pose: str | None = None
        self._missed: dict[str, int] = {}
        self._image_stamp: dict[str, float | None] = {}
        self._best_error = math.inf
        self._best_t = 0.0
        self._outranked = 0

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
        if frame.wheels is not None and dt > 0.0:
            v, omega = wheel_odometry(frame.wheels, self.track)
            if frame.imu is not None:
                omega = frame.imu.yaw_rate
            step = np.array([v * dt, omega * dt])
            for moved in self._moved.values():
                moved += step
        self.views = self._views(features, frame, pose) if pose is not None else {}
        self._pose = pose
        self._angles = dict(frame.pan_tilt)
        previous_mode, previous_driver = self.mode, self.driver
        driver = self._choose_driver() if self.gave_up is None else None
        mode = LOST
        if driver is not None:
            view = self.views[driver.id]
            self._full = self._full + 1 if view.image.n_reconstructed == 0 else 0
            if (
                (previous_mode == IBVS and previous_driver is not None)
                or self._full >= ROBUST_TICKS
                or (self.method == PBVS and self._pbvs_blocked(driver) is not None)
            ):
                mode = IBVS
            elif self.method == PBVS:
                mode = PBVS
        else:
            self._full = 0
        self.driver = driver if mode != LOST else None
        self.mode = mode
        if self.driver is not None:
            self.last_driver = self.driver
        if mode != previous_mode or (mode != LOST and self.driver is not previous_driver):
            reason = self._describe()
            self.switches.append((now, f"{previous_mode} -> {mode}: {reason}"))
            if mode != LOST:
                self.law.switch(self.last_q)
                self._t0 = now
                self._history.clear()
                self._iterations = 0
                self._best_error, self._best_t = math.inf, now
        if mode != LOST and self._stamp is not None:
            self.servo_s[mode] += dt
            if self.driver is not None and self.views[self.driver.id].image.n_reconstructed:
                self.reconstructed_s += dt
        if mode == LOST:
            self.last_q = np.zeros(4)
            if previous_mode != LOST and self.gave_up is None:
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
            if cam.points.size == 0:
                continue
            xy_est, z_est = project_points(c_m_f, self.points_f[cam.points])
            if not np.all(z_est > 0.0):
                continue
            detected: dict[int, tuple[float, float]] = {}
            cx, cy = cam.half_size
            index = {int(k): i for i, k in enumerate(cam.points)}  # point -> servo row
            for d in by_camera.get(cam.id, ()):
                if d.feature == self.target.id and d.point in index:
                    detected[index[d.point]] = (
                        (d.u - cx) / cam.focal_px,
                        (d.v - cy) / cam.focal_px,
                    )
            image = augment(detected, xy_est, z_est)
            camera_frame = frame.cameras.get(cam.id)
            stamp = getattr(camera_frame, "stamp", None)
            if stamp is None or stamp != self._image_stamp.get(cam.id):
                self._image_stamp[cam.id] = stamp
                lost = image.n_real < MIN_REAL_POINTS
                self._missed[cam.id] = self._missed.get(cam.id, 0) + 1 if lost else 0
            image = self._smooth(cam, angles, camera_frame, image)
            raw = reliability(image, xy_est, cam.focal_px, cam.half_size)
            rel = _filter_reliability(
                self._reliability.get(cam.id, 0.0),
                raw,
                self._missed.get(cam.id, 0) < DROPOUT_IMAGES,
                RELIABILITY_FILTER,
            )
            self._reliability[cam.id] = rel
            views[cam.id] = _View(cam, angles.pan, angles.tilt, image, rel)
        return views

    def _smooth(
        self, cam: ServoCamera, angles: PanTilt, frame: object, image: AugmentedImage
    ) -> AugmentedImage:
        """The predict-correct filter of the points at each new image of the camera
        (:data:`DETECTION_SIGMA_PX`): the previous points moved by the base's wheel/IMU
        motion and the pan-tilt encoders' change since the previous image (eq. 3.16
        through the Jacobian of eq. 3.2), then corrected by the detections. A point missed in fewer
        than :data:`DROPOUT_IMAGES` consecutive images keeps its predicted position (a
        detector dropout) rather than being pulled towards its projection through the
        pose estimate."""
        cid = cam.id
        stamp = getattr(frame, "stamp", None)
        last = self._filtered.get(cid)
        if last is None or stamp is None:
            xy, missed = image.xy, np.where(image.real, 0, DROPOUT_IMAGES)
            self._variance[cid] = (DETECTION_SIGMA_PX / cam.focal_px) ** 2
        elif last[0] == stamp:
            return AugmentedImage(last[1], image.z, image.real)
        else:
            missed = np.where(image.real, 0, last[2] + 1)
            moved = self._moved.get(cid, np.zeros(2))
            before = self._image_angles.get(cid, angles)
            dq = np.array([moved[0], moved[1], angles.pan - before.pan, angles.tilt - before.tilt])
            if stamp - last[0] > PREDICT_SPAN_S or np.any(np.abs(dq) > PREDICT_MOTION):
                # the first-order motion model holds for small motions only: restart
                motion = image.xy - last[1]
                xy = image.xy.copy()
                self._variance[cid] = (DETECTION_SIGMA_PX / cam.focal_px) ** 2
            else:
                jac = robot_jacobian_eq_3_2(cam.chain, angles.pan, angles.tilt)
                motion = feature_motion_eq_3_16(last[1], image.z, jac, dq)
                gain, variance = filter_gain(
                    self._variance.get(cid, 0.0),
                    motion,
                    DETECTION_SIGMA_PX / cam.focal_px,
                    MODEL_SHARE,
                    STILL_SIGMA_PX / cam.focal_px,
                )
                self._variance[cid] = variance
                xy = filter_features(last[1], motion, image.xy, gain)
            held = missed < DROPOUT_IMAGES
            xy[held] = np.where(image.real[held, None], xy[held], (last[1] + motion)[held])
        if stamp is not None:
            self._filtered[cid] = (stamp, xy, missed)
            self._moved[cid] = np.zeros(2)
            self._image_angles[cid] = angles
        return AugmentedImage(xy, image.z, image.real)

    def _choose_driver(self) -> ServoCamera | None:
        """The most reliable usable camera, with hysteresis by unit: within the driving
        unit (one pan-tilt unit, twin views) the driver keeps the base while its
        reliability is at least :data:`KEEP_DRIVER` of the unit's best camera; another
        unit takes over when the driving unit has lost the target (the thesis's take-over
        without a search, lines 3560-3580), or when the unit's best camera has stayed
        under :data:`KEEP_DRIVER` of the best camera for :data:`ROBUST_TICKS` ticks. Each
        unit servoes towards its own ``pan*`` and desired image: handing the base between
        the front and the rear unit on one tick's reliability (which every fast motion
        lowers in all cameras) made the A320 CP10 servo thrash between them and end
        26 cm off."""
        usable = [v for v in self.views.values() if v.reliability > 0.0 and _can_drive(v)]
        if not usable:
            self._outranked = 0
            return None
        best = max(usable, key=lambda v: v.reliability)
        current = self.driver
        unit = [v for v in usable if current is not None and v.camera.unit.id == current.unit.id]
        if current is None or not unit:
            self._outranked = 0
            return best.camera
        unit_best = max(unit, key=lambda v: v.reliability)
        if unit_best.reliability < KEEP_DRIVER * best.reliability:
            self._outranked += 1
            if self._outranked >= ROBUST_TICKS:
                self._outranked = 0
                return best.camera
        else:
            self._outranked = 0
        mine = next((v for v in unit if v.camera is current), None)
        if mine is not None and mine.reliability >= KEEP_DRIVER * unit_best.reliability:
            return current
        return unit_best.camera

    def _pbvs_blocked(self, camera: ServoCamera) -> str | None:
        """Why PBVS cannot run with ``camera`` (IBVS on the augmented image instead)."""
        if not camera.pose_from_points:
            return (
                f"the {camera.points.size} point(s) of {self.target.id} in view from the "
                "checkpoint do not determine its pose (PBVS needs >= 4 not on one line): "
                "IBVS on the augmented image"
            )
        return self._no_pose

    def _describe(self) -> str:
        n = self.driver.points.size if self.driver is not None else len(self.points_f)
        rel = ", ".join(f"{cid} {v.reliability:.2f}" for cid, v in self.views.items())
        if self.gave_up is not None:
            return f"{self.target.id}: {self.gave_up}; metric go-to-goal finishes"
        if self.mode == LOST or self.driver is None:
            return (
                f"{self.target.id}: lost, no camera has {MIN_REAL_POINTS} of {n} real points "
                f"(reliability {rel or 'none'})"
            )
        view = self.views[self.driver.id]
        blocked = (
            self._pbvs_blocked(self.driver) if self.method == PBVS and self.mode == IBVS else None
        )
        return (
            f"{self.target.id}: {self.mode} on {self.driver.id} ({view.image.n_real}/{n} real, "
            f"{view.image.n_reconstructed} reconstructed; reliability {rel})"
            + (f"; {blocked}" if blocked else "")
        )

    def servoed_unit(self) -> tuple[str, tuple[str, ...], float, float] | None:
        """The unit whose camera drove the servo last (else the one that last tracked the
        target by vision, :meth:`track_rates`), its camera ids, its ``pan*`` and its
        image's half width (px)
        (None: servoing never drove): what correct camera angle acts on afterwards. The
        checkpoint's own camera may be another unit (the PTZ, or the front unit while the
        rear one drove) whose pan was only tracking the target, not servoed."""
        cam = self.last_driver or self.tracked
        if cam is None:
            return None
        ids = tuple(c.id for c in self.cameras if c.unit.id == cam.unit.id)
        return cam.unit.id, ids, cam.desired_pan, cam.half_size[0]

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
            start=self.start_distance,
            start_note=self.start_note,
        )

    @property
    def start_distance(self) -> float:
        """Where servoing starts: metres before the checkpoint on its heading line (the
        approach line's row fades in from there, :attr:`ServoParams.line_from`)."""
        return self.params.line_from

    def start_f(self) -> Pose2:
        """The servo start in F: :attr:`start_distance` behind the checkpoint, facing
        its heading (F is mirrored, but +x_R still maps to (cos h, sin h))."""
        cp, d = self.checkpoint_f, self.start_distance
        return Pose2(cp.x - d * math.cos(cp.theta), cp.y - d * math.sin(cp.theta), cp.theta)

    def slide_start(self, distance: float, why: str) -> None:
        """Start servoing ``distance`` m before the checkpoint instead (a shorter run),
        for the reason ``why`` (the report's)."""
        self.params = dataclasses.replace(self.params, line_from=distance)
        self.start_note = why

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
                    self.points_f[cam.points], view.image.xy, None, guess=self._pose_guess
                )
            except ValueError as exc:
                # the next update switches to IBVS on the augmented image (with the reason)
                self._no_pose = f"no pose from the augmented image ({exc}): IBVS on it"
                return VelocityCommand.stop(), False, self._no_pose
            self._pose_guess = c_m_f
            error = pbvs_error_eq_3_25(c_m_f, cam.cd_m_f, self.centroid_f)
            lmat = pbvs_interaction_matrix_eq_3_35(c_m_f.apply(self.centroid_f), error[3:])
        # the approach-line row: the base's offset across the checkpoint's heading line,
        # which the image hardly tells from a rotation and no command removes at the goal,
        # is steered out on the way there, from the localisation (module docstring)
        line = self._approach_line()
        fade = 0.0
        if line is not None and p.line_from > p.line_until:  # a start slid closer: no row
            span = p.line_from - p.line_until
            fade = min(1.0, max(0.0, (line[1] - p.line_until) / span))
        # the secondary row pan -> pan* (module docstring): it picks the member of the
        # family of base poses that share one camera pose, which L J alone leaves
        # ill-conditioned (image noise would drive omega and pan against each other). It
        # matters at the goal; on the way, where the line row turns the base towards the
        # goal and the pan absorbs the turn, it would hold the base against it (with the
        # pan row at full weight all along, a 1.5 cm offset at the servo start was still
        # 1.4 cm at the goal): it weighs in as the line row fades out
        w = p.pan_weight * max(p.pan_weight_far, 1.0 - fade)
        task = np.vstack((lmat @ jac, [0.0, 0.0, w, 0.0]))
        # not wrapped: the unit travels within its limits (+-170 deg), never through +-180,
        # so pan* = -160 deg from pan = +165 deg is 325 deg away, not 35 (a rear unit)
        error = np.append(error, w * (view.pan - cam.desired_pan))
        if line is not None:
            task = np.vstack((task, fade * p.line_weight * line[2]))
            error = np.append(error, fade * p.line_weight * p.line_gain * line[0])
        depth = self._approach_depth() if self.mode == IBVS else None
        if depth is not None:
            # the localisation's say on the distance still to go, weighed against the image
            # as the two measurements' noises (a weighted least-squares fusion): a target
            # that fixes the camera's depth well outweighs it, one that hardly does (two
            # points along the line of sight) stops where the localisation says
            wd = (DETECTION_SIGMA_PX / cam.focal_px) / p.depth_sigma
            task = np.vstack((task, wd * depth[1]))
            error = np.append(error, wd * depth[0])
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
        if done:
            pass
        elif err < (1.0 - PROGRESS_SHARE) * self._best_error:
            self._best_error, self._best_t = err, self._now
        elif self._now - self._best_t > NO_PROGRESS_S:
            self.gave_up = (
                f"{self.mode} on {cam.id} made no progress for {NO_PROGRESS_S:.0f} s "
                f"(|e| {err:.4f}, best {self._best_error:.4f})"
            )
            return VelocityCommand.stop(), False, self.gave_up
        why = (
            f"{self.mode} on {cam.id}: |e| {err:.4f}, q_dot ({q[0]:+.3f} m/s, {q[1]:+.3f}, "
            f"{q[2]:+.3f}, {q[3]:+.3f} rad/s), rank {step.rank}"
        )
        return VelocityCommand(float(q[0]), float(q[1]), rates), done, why

    def _goal_and_base(self) -> tuple[Pose2, Pose2] | None:
        pose = self._pose
        if pose is None or pose.placement is None:
            return None
        return pose.placement.pose_to_airport(self.checkpoint_f), pose.pose_a

    def _approach_line(self) -> tuple[float, float, np.ndarray] | None:
        poses = self._goal_and_base()
        if poses is None:
            return None
        goal, base = poses
        return approach_line_row(
            base.x, base.y, base.theta, goal.x, goal.y, goal.theta, self.params.line_lookahead
        )

    def _approach_depth(self) -> tuple[float, np.ndarray] | None:
        poses = self._goal_and_base()
        if poses is None:
            return None
        goal, base = poses
        return approach_depth_row(base.x, base.y, base.theta, goal.x, goal.y, goal.theta)

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
        if self._pose is not None:
            skip = {driving_unit, *out}
            out.update(self.aim_rates(self._pose, self._angles, skip))
        return out

    def track_rates(
        self, features: FeatureObservations | None, frame: SensorFrame, pose: PoseEstimate
    ) -> dict[str, PanTiltRate]:
        """Pan-tilt rates for every servo unit while metric go-to-goal drives: a unit whose
        camera detects the target holds the detected points at their *desired* image
        position with the pan-tilt unit only (track-feature, lines 745-764, towards ``s*``
        rather than the image centre); the others are aimed through the pose estimate
        (:meth:`aim_rates`).

        A unit tracking by vision measures the target's true bearing: at the checkpoint its
        pan differs from ``pan*`` by the base's heading error, which correct camera angle
        then removes (:meth:`servoed_unit`). That is what vision gives a target that cannot
        drive the base (one point fixes a bearing, not a pose)."""
        by_camera = features.by_camera if features is not None else {}
        out: dict[str, PanTiltRate] = {}
        for uid in self.units:
            angles = frame.pan_tilt.get(uid)
            if angles is None:
                continue
            best: tuple[ServoCamera, list[int], np.ndarray] | None = None
            for cam in self.cameras:
                if cam.unit.id != uid or cam.points.size == 0 or not cam.within_limits:
                    continue  # a unit that cannot reach pan* measures no usable bearing
                index = {int(k): i for i, k in enumerate(cam.points)}
                rows, xy = [], []
                cx, cy = cam.half_size
                for d in by_camera.get(cam.id, ()):
                    if d.feature == self.target.id and d.point in index:
                        rows.append(index[d.point])
                        xy.append(((d.u - cx) / cam.focal_px, (d.v - cy) / cam.focal_px))
                if rows and (best is None or len(rows) > len(best[1])):
                    best = (cam, rows, np.array(xy))
            if best is None:
                continue
            cam, rows, xy = best
            c_m_f = cam.chain.aircraft_from_camera(
                pose.pose_f, angles.pan, angles.tilt, self.origin_height
            ).inverse()
            _, z = project_points(c_m_f, self.points_f[cam.points[rows]])
            if not np.all(z > 0.0):
                continue
            jac = robot_jacobian_eq_3_2(cam.chain, angles.pan, angles.tilt)
            step = self.trackers[uid].track_feature_step(
                xy, z, jac, centroid_desired=cam.s_desired[rows].mean(axis=0)
            )
            pan_max, tilt_max = self.rates[uid]
            out[uid] = PanTiltRate(_clamp(step.q_dot[2], pan_max), _clamp(step.q_dot[3], tilt_max))
            self.tracked = cam
            offset = xy.mean(axis=0) - cam.s_desired[rows].mean(axis=0)
            self.track_error_px = float(np.linalg.norm(offset)) * cam.focal_px
        out.update(self.aim_rates(pose, frame.pan_tilt, set(out)))
        return out

    def aim_rates(
        self, pose: PoseEstimate, angles: Mapping[str, PanTilt], skip: set[str] | None = None
    ) -> dict[str, PanTiltRate]:
        """Pan-tilt rates that aim every servo unit (but ``skip``) at the point of the target
        its ``pan*``, ``tilt*`` aim at (:func:`desired_aim`) through the pose estimate,
        within the unit's limits (proportional, rate-limited).

        Metric go-to-goal towards the servo start and the checkpoint sends them
        (:class:`AimedGoToGoal`): a unit left where the previous inspection put it (tilted
        up at a radome) does not see a nose gear 4 m ahead, and the feature-visibility
        guard would never hold."""
        robot_from_f = aircraft_from_robot(pose.pose_f, self.origin_height).inverse()
        k = self.params.track_gain
        out: dict[str, PanTiltRate] = {}
        for uid, spec in self.units.items():
            measured = angles.get(uid)
            if measured is None or (skip is not None and uid in skip):
                continue
            target_r = robot_from_f.apply(self.aims[uid])
            pan, tilt = pan_tilt_towards(spec.mount, spec.mount_yaw, target_r)
            pan = min(max(pan, spec.pan_limits[0]), spec.pan_limits[1])
            tilt = min(max(tilt, spec.tilt_limits[0]), spec.tilt_limits[1])
            pan_max, tilt_max = self.rates[uid]
            out[uid] = PanTiltRate(
                _clamp(k * (pan - measured.pan), pan_max),
                _clamp(k * (tilt - measured.tilt), tilt_max),
            )
        return out


def _can_drive(view: _View) -> bool:
    """Whether ``view``'s camera may drive the base: ``pan*``/``tilt*`` within its unit's
    limits, two points in view from the checkpoint, and its unit's measured pan within half
    a field of view of ``pan*``. A rear unit still panning round to ``pan*`` = -164 deg from
    +170 deg sees the target past its stop, 334 deg from ``pan*`` the way it must turn: as
    a driver its pan row would throw the base about (B737 CP14 ended 8 cm off)."""
    cam = view.camera
    half_fov = math.atan2(cam.half_size[0], cam.focal_px)
    return cam.reachable and abs(view.pan - cam.desired_pan) <= half_fov


def _filter_reliability(before: float, raw: float, seeing: bool, gain: float) -> float:
    """One camera's reliability after a new tick: exponential smoothing of ``raw`` while
    the camera sees the target (``seeing``: it has not missed it in :data:`DROPOUT_IMAGES`
    images), 0 once it has lost it. A dropout (``raw`` 0 in one image) decays the value
    instead of resetting it, and a camera that sees the target again starts from its
    ``raw`` value, not from 0 (either would hand the base to another camera)."""
    if not seeing:
        return 0.0
    if before <= 0.0:
        return raw
    return before + gain * (raw - before)


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


@dataclass(frozen=True, slots=True)
class ServoStartGoal(Goal):
    """The servo start of ``session``'s checkpoint as a navigation goal, where the session
    has it now (:meth:`ServoSession.start_f`: :class:`SlideServoStart` may move it towards
    the checkpoint); ``pose`` is where the compiler put it."""

    session: ServoSession | None = field(default=None, compare=False)

    def in_airport(self, estimate: PoseEstimate | None) -> Pose2:
        return self.resolve(self.pose if self.session is None else self.session.start_f(), estimate)


class SlideServoStart(Node):
    """Slide a servo start the robot could not turn at towards its checkpoint
    (:mod:`behaviours.laws.servo_start`), every tick the navigation to it runs, from the
    lasers' returns: the first start along the heading line, from where it is now towards
    :data:`~behaviours.laws.servo_start.SHORTEST_RUN` before the checkpoint (onto it), whose turning
    disc clears every return but the movers' (tracked, :func:`is_mover`: a walker passing
    by moves nothing; the returns within a mover's disc are left out, so a cluster merged
    with what it passes hides that too) by r_ES and :data:`SERVO_START_MARGIN`. A start
    only ever slides forwards, so the goal settles (a person who stood there for a while
    shortens the run for good). Always SUCCESS: it only moves the goal."""

    reads = (OBSTACLES, POSE)

    def __init__(
        self, session: ServoSession, checkpoint: Goal, platform: Platform, r_es: float, name: str
    ) -> None:
        super().__init__(name)
        self.session = session
        self.checkpoint = checkpoint
        self.need = platform.turning_radius + r_es + SERVO_START_MARGIN

    def update(self) -> Status:
        obstacles: Obstacles | None = self.read(OBSTACLES)
        pose: PoseEstimate | None = self.read(POSE)
        if obstacles is None or pose is None or len(obstacles.points) == 0:
            return Status.SUCCESS
        points = obstacles.points
        for track in obstacles.tracks:
            if is_mover(track):
                off = np.hypot(points[:, 0] - track.position[0], points[:, 1] - track.position[1])
                points = points[off > track.size + 0.1]
        returns = pose.pose_a.apply(points)
        cp = self.checkpoint.in_airport(pose)
        now = self.session.start_distance
        distance, gap = start_distance(
            returns, (cp.x, cp.y, cp.theta), candidate_distances(now), self.need
        )
        if distance < now - 1e-9:
            was = start_distance(returns, (cp.x, cp.y, cp.theta), [now], self.need)[1]
            self.session.slide_start(
                distance,
                f"servo start slid from {self.session.compiled_start:.2f} m to "
                f"{distance:.2f} m before the checkpoint: a return {was:.2f} m from the "
                f"centre of the start {now:.2f} m before it ({self.need:.2f} m needed to "
                f"turn in place), {gap:.2f} m from the new one",
            )
            self.feedback_message = self.session.start_note
        return Status.SUCCESS


class AimedGoToGoal(GoToGoalController):
    """Metric go-to-goal that keeps the servo units on the checkpoint's target
    (:meth:`ServoSession.track_rates`: by vision where a camera sees it, else through the
    pose estimate): towards the servo start and as the fallback of a servo navigation, so
    the target is in view when the feature-visibility guard looks, and a unit measures the
    target's bearing for correct camera angle where the target cannot drive the base."""

    reads = (POSE, SENSOR_FRAME, FEATURES)

    def __init__(
        self,
        session: ServoSession,
        goal: Goal,
        params: GoToGoalParams,
        use_heading: bool,
        period: float,
        speed_limit: Callable[[Pose2], float] | None = None,
        name: str = "go to goal",
    ) -> None:
        super().__init__(goal, params, use_heading, period, speed_limit, name)
        self.session = session

    def pan_tilt_rates(self, pose: PoseEstimate) -> Mapping[str, PanTiltRate]:
        frame: SensorFrame | None = self.read(SENSOR_FRAME)
        if frame is None:
            return {}
        return self.session.track_rates(self.read(FEATURES), frame, pose)


class TrackFeature(Controller):
    """Track-feature (seed lines 745-764) with the base still: the units hold the target
    at its desired pixels (:meth:`ServoSession.track_rates`) until the tracking camera is
    within ``tolerance_px`` for ``settle`` seconds (or ``timeout`` passes). It precedes
    correct camera angle where the target cannot drive the base: the pan then measures
    the target's bearing, not where the unit was when the base stopped turning."""

    reads = (FEATURES, SENSOR_FRAME, POSE)
    writes = (COMMAND,)

    def __init__(
        self,
        session: ServoSession,
        tolerance_px: float = 1.0,
        settle: float = 0.5,
        timeout: float = 10.0,
        name: str = "",
    ) -> None:
        super().__init__(name or f"track {session.target.id}")
        self.session = session
        self.tolerance_px, self.settle, self.timeout = tolerance_px, settle, timeout
        self._start: float | None = None
        self._since: float | None = None

    def initialise(self) -> None:
        self._start = self._since = None
        self.session.track_error_px = None

    def update(self) -> Status:
        frame: SensorFrame = self.read(SENSOR_FRAME)
        pose: PoseEstimate | None = self.read(POSE)
        now = frame.stamp
        if self._start is None:
            self._start = now
        rates = self.session.track_rates(self.read(FEATURES), frame, pose) if pose else {}
        err = self.session.track_error_px
        if err is not None and err <= self.tolerance_px:
            self._since = now if self._since is None else self._since
        else:
            self._since = None
        if self._since is not None and now - self._since >= self.settle:
            self.write(COMMAND, VelocityCommand.stop())
            self.feedback_message = f"{self.session.target.id} at its desired pixel"
            return Status.SUCCESS
        if now - self._start >= self.timeout:
            self.write(COMMAND, VelocityCommand.stop())
            self.feedback_message = f"{self.session.target.id} not settled in {self.timeout:.0f} s"
            return Status.SUCCESS
        self.write(COMMAND, VelocityCommand(0.0, 0.0, rates))
        self.feedback_message = f"tracking {self.session.target.id}: " + (
            f"{err:.1f} px from s*" if err is not None else "not seen"
        )
        return Status.RUNNING
