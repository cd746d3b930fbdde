"""Visual servoing in the tree (issue 13 §2-§5): the augmented image, the feature
visibility guard (PBVS -> IBVS, lost -> metric, recovered -> servo again), the camera
take-over, Algorithm 3.1 at the goal, correct camera angle on the measured pan, and the
compiled tree."""

from __future__ import annotations

import math

import numpy as np
import py_trees
import pytest

from behaviours.controllers.motion import CorrectCameraAngle
from behaviours.controllers.servo import (
    IBVS,
    LOST,
    PBVS,
    ROBUST_TICKS,
    STOP_MIN_ITERATIONS,
    FeaturesVisible,
    ServoSession,
    VisualServoing,
)
from behaviours.keys import COMMAND, FEATURES, POSE, SENSOR_FRAME, SERVO
from behaviours.laws.augmented_image import augment, reliability
from behaviours.laws.interaction import project_points
from executive.compiler import CompileOptions, GuardedBranch, check_tree, compile_mission
from executive.core.frames import Pose2
from executive.core.loader import load_mission
from executive.core.records import (
    CameraFrame,
    Detection,
    FeatureObservations,
    PanTilt,
    PoseEstimate,
    SensorFrame,
)
from tests.conftest import MISSIONS, blackboard_writer

S = py_trees.common.Status


pytestmark = pytest.mark.usefixtures("fresh_blackboard")


@pytest.fixture(scope="module")
def lab():
    return load_mission(MISSIONS / "lab" / "visual-servoing.xml")


def _reader(*keys):
    client = py_trees.blackboard.Client(name="reader")
    for key in keys:
        client.register_key(key=key.name, access=py_trees.common.Access.READ)
    return client


def _session(mission, cp_id="CP1", method=None) -> ServoSession:
    cp = next(c for c in mission.checkpoints if c.id == cp_id)
    target = mission.aircraft.features[cp.target]
    return ServoSession(
        cp.id,
        target,
        cp.pose,
        mission.platform,
        mission.aircraft.origin_height,
        method or (cp.servo or target.servo).value,
    )


class _World:
    """Detections of the session's target as each camera sees it from ``pose_f`` with
    every unit at its desired angles (noise-free), and the blackboard records."""

    def __init__(self, session: ServoSession, pose_f: Pose2) -> None:
        self.session, self.pose_f = session, pose_f
        self.t = 0.0
        self.hidden: dict[str, set[int]] = {}

    def frame(self) -> tuple[SensorFrame, FeatureObservations, PoseEstimate]:
        self.t += 0.04
        s = self.session
        cams, by_camera, angles = {}, {}, {}
        for cam in s.cameras:
            angles[cam.unit.id] = PanTilt(self.t, cam.desired_pan, cam.desired_tilt)
            c_m_f = cam.chain.aircraft_from_camera(
                self.pose_f, cam.desired_pan, cam.desired_tilt, s.origin_height
            ).inverse()
            xy, z = project_points(c_m_f, s.points_f)
            if not np.all(z > 0):
                continue
            cx, cy = cam.half_size
            dets = tuple(
                Detection(s.target.id, k, cx + cam.focal_px * x, cy + cam.focal_px * y)
                for k, (x, y) in enumerate(xy)
                if k not in self.hidden.get(cam.id, set())
            )
            cams[cam.id] = CameraFrame(self.t, dets)
            by_camera[cam.id] = dets
        frame = SensorFrame(self.t, cameras=cams, pan_tilt=angles)
        pose = PoseEstimate(self.t, self.pose_f, np.eye(3) * 1e-6, self.pose_f, 1.0)
        return frame, FeatureObservations(self.t, by_camera), pose

    def tick(self) -> str:
        frame, features, pose = self.frame()
        return self.session.update(features, frame, pose)


def test_augmented_image_fills_the_missing_points_from_the_pose_estimate():
    est = np.array([[0.0, 0.0], [0.1, 0.0], [0.1, 0.1], [0.0, 0.1]])
    image = augment({0: (0.001, 0.0), 2: (0.1, 0.101)}, est, np.full(4, 3.0))
    assert image.n_real == 2 and image.n_reconstructed == 2
    assert np.allclose(image.xy[1], est[1]) and np.allclose(image.xy[0], (0.001, 0.0))
    rel = reliability(image, est, 800.0, (400.0, 300.0))
    assert 0.0 < rel < 0.5  # half the points are real
    full = augment(dict(enumerate(map(tuple, est))), est, np.full(4, 3.0))
    assert reliability(full, est, 800.0, (400.0, 300.0)) == pytest.approx(1.0)
    one = augment({0: (0.0, 0.0)}, est, np.full(4, 3.0))
    assert reliability(one, est, 800.0, (400.0, 300.0)) == 0.0  # fewer than two real


def test_pbvs_then_ibvs_then_lost_then_servo_again(lab):
    session = _session(lab)
    assert session.method == PBVS
    world = _World(session, next(c for c in lab.checkpoints if c.id == "CP1").pose)
    modes = [world.tick() for _ in range(ROBUST_TICKS + 2)]
    assert modes[0] == PBVS and modes[-1] == IBVS  # fully visible long enough: IBVS
    assert "target-1: ibvs on front-" in session.message and "4/4 real" in session.message
    # two real points left: IBVS carries on, on the augmented image
    for cid in ("front-left", "front-right"):
        world.hidden[cid] = {0, 1}
    assert world.tick() == IBVS
    status = session.status()
    assert (status.real, status.reconstructed) == (2, 2)
    before = status.reconstructed_s
    world.tick()
    assert session.status().reconstructed_s > before
    # one real point: lost, metric go-to-goal drives
    for cid in ("front-left", "front-right"):
        world.hidden[cid] = {0, 1, 2}
    assert world.tick() == LOST
    assert "lost" in session.message
    # recovered: servoing again (PBVS until robustly visible, then IBVS)
    world.hidden.clear()
    assert world.tick() == PBVS
    assert [world.tick() for _ in range(ROBUST_TICKS)][-1] == IBVS
    switches = [why for _, why in session.switches]
    assert switches[0].startswith("lost -> pbvs")
    assert any(w.startswith("ibvs -> lost") for w in switches)
    assert any(w.startswith("lost -> pbvs") for w in switches[1:])


def test_an_ibvs_checkpoint_waits_for_the_full_target_on_metric(lab):
    session = _session(lab, "CP3")
    assert session.method == IBVS
    world = _World(session, next(c for c in lab.checkpoints if c.id == "CP3").pose)
    assert world.tick() == LOST  # not yet robustly visible: no PBVS for an ibvs checkpoint
    assert [world.tick() for _ in range(ROBUST_TICKS)][-1] == IBVS


def test_a_frozen_camera_hands_the_base_to_another_camera(lab):
    session = _session(lab)
    world = _World(session, next(c for c in lab.checkpoints if c.id == "CP1").pose)
    for _ in range(ROBUST_TICKS + 2):
        world.tick()
    driver = session.driver.id
    other = "front-right" if driver == "front-left" else "front-left"
    world.hidden[driver] = {0, 1, 2, 3}  # the camera's image is stale: nothing fresh
    assert world.tick() == IBVS
    assert session.driver.id == other
    assert any(f"on {other}" in why for _, why in session.switches)
    # the other units keep their pan-tilt units on the target (track-feature / aiming)
    command, _, _ = session.command()
    assert "rear" in command.pan_tilt and "front" in command.pan_tilt


def test_at_the_goal_the_command_vanishes_and_algorithm_3_1_stops(lab):
    session = _session(lab)
    world = _World(session, next(c for c in lab.checkpoints if c.id == "CP1").pose)
    done = False
    for _ in range(ROBUST_TICKS + STOP_MIN_ITERATIONS + 5):
        world.tick()
        command, done, _ = session.command()
        assert abs(command.v) < 1e-6 and abs(command.omega) < 1e-6
    assert done


def test_guard_and_controller_on_the_blackboard(lab):
    session = _session(lab)
    world = _World(session, next(c for c in lab.checkpoints if c.id == "CP1").pose)
    bb = blackboard_writer(SENSOR_FRAME, FEATURES, POSE)
    reader = _reader(SERVO, COMMAND)
    guards = {m: FeaturesVisible(session, m) for m in (IBVS, PBVS)}
    controller = VisualServoing(session, PBVS)
    frame, features, pose = world.frame()
    for key, value in ((SENSOR_FRAME, frame), (FEATURES, features), (POSE, pose)):
        bb.set(key.name, value, overwrite=True)
    guards[IBVS].tick_once()
    guards[PBVS].tick_once()
    assert guards[IBVS].status == S.FAILURE and guards[PBVS].status == S.SUCCESS
    assert "features visible (measured or reconstructed)?" in guards[PBVS].name
    assert "target-1: pbvs on front-" in guards[PBVS].feedback_message
    assert reader.get(SERVO.name).mode == PBVS
    controller.tick_once()
    assert controller.status == S.RUNNING and "pbvs on front-" in controller.feedback_message
    assert isinstance(reader.get(COMMAND.name).pan_tilt["front"].pan, float)


def _cca(lab, servoed=True):
    cp = next(c for c in lab.checkpoints if c.id == "CP1")
    camera = lab.platform.cameras["front"]
    node = CorrectCameraAngle(
        camera,
        ("front-left", "front-right"),
        lab.aircraft.features[cp.target],
        cp.pose,
        lab.aircraft.origin_height,
        threshold=math.radians(0.25),
        max_omega=0.5,
        servoed=servoed,
    )
    return node, camera


def _cca_inputs(pan: float, u: float = 400.0) -> tuple[SensorFrame, FeatureObservations]:
    dets = tuple(Detection("target-1", k, u + d, 300.0) for k, d in enumerate((-5, 5, 5, -5)))
    frame = SensorFrame(
        1.0,
        cameras={"front-left": CameraFrame(1.0, dets)},
        pan_tilt={"front": PanTilt(1.0, pan, 0.0)},
    )
    return frame, FeatureObservations(1.0, {"front-left": dets})


def test_correct_camera_angle_acts_on_the_measured_pan_and_keeps_the_target(lab):
    node, _ = _cca(lab)
    bb = blackboard_writer(SENSOR_FRAME, FEATURES)
    reader = _reader(COMMAND)
    pan_star = node.desired_pan
    for pan, expect in (
        (pan_star + math.radians(0.1), S.SUCCESS),
        (pan_star + math.radians(2.0), S.RUNNING),
    ):
        node.initialise()
        frame, features = _cca_inputs(pan)
        bb.set(SENSOR_FRAME.name, frame, overwrite=True)
        bb.set(FEATURES.name, features, overwrite=True)
        node.tick_once()
        assert node.status == expect
        command = reader.get(COMMAND.name)
        assert command.v == 0.0
        if expect == S.RUNNING:
            # the target is to the left of where pan* puts it: turn left, pan back right
            assert command.omega > 0.0 and command.pan_tilt["front"].pan == -command.omega
    # settles once the measured pan is back within a fifth of the threshold of pan*
    frame, features = _cca_inputs(pan_star + math.radians(0.04))
    bb.set(SENSOR_FRAME.name, frame, overwrite=True)
    node.tick_once()
    assert node.status == S.SUCCESS


def test_correct_camera_angle_leaves_a_metric_checkpoint_alone(lab):
    node, _ = _cca(lab, servoed=False)
    bb = blackboard_writer(SENSOR_FRAME, FEATURES)
    frame, features = _cca_inputs(node.desired_pan + math.radians(10.0))
    bb.set(SENSOR_FRAME.name, frame, overwrite=True)
    bb.set(FEATURES.name, features, overwrite=True)
    node.tick_once()
    assert node.status == S.SUCCESS and "nothing to correct" in node.feedback_message


def test_compiled_lab_tree_servoes_every_servo_checkpoint_without_warning(lab):
    compiled = compile_mission(lab, CompileOptions(servo=True))
    assert not [w for w in compiled.warnings if w.code == "servo-metric"]
    assert check_tree(compiled.root) == []
    assert [s.checkpoint for s in compiled.servo_sessions] == ["CP1", "CP2", "CP3"]
    branches = [n for n in compiled.root.iterate() if isinstance(n, GuardedBranch)]
    names = [b.name for b in branches]
    assert "pbvs CP1" in names and "ibvs CP1" in names
    assert "ibvs CP3" in names and "pbvs CP3" not in names  # an ibvs checkpoint
    # below e-stop and avoidance, above reached and metric go-to-goal
    guards = next(n for n in compiled.root.iterate() if n.name == "guards CP1")
    order = [c.name for c in guards.children]
    assert order.index("e-stop CP1") < order.index("avoid CP1") < order.index("ibvs CP1")
    assert order.index("pbvs CP1") < order.index("reached CP1") < order.index("go to CP1")


def test_servoing_is_selectable_and_kept_metric_where_not_verified():
    a320 = load_mission(MISSIONS / "a320" / "preflight.xml")
    default = compile_mission(a320, CompileOptions())
    warned = [w for w in default.warnings if w.code == "servo-metric"]
    assert warned and "not enabled by default" in warned[0].message
    assert not default.servo_sessions
    forced = compile_mission(a320, CompileOptions(servo=True))
    assert not [w for w in forced.warnings if w.code == "servo-metric"]
    assert check_tree(forced.root) == [] and forced.servo_sessions
