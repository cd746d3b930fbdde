"""Guards, controllers, runtime failure handling, journal and CLI exit codes."""

import gc
import json
import math

import numpy as np
import py_trees
import pytest

from behaviours.controllers.motion import CorrectCameraAngle
from behaviours.goals import Goal
from behaviours.guards.conditions import (
    NotTrapped,
    ObstacleTrigger,
    PoseNotGoodEnough,
    Reached,
)
from behaviours.keys import (
    COMMAND,
    FEATURES,
    OBSTACLES,
    POSE,
    SENSOR_FRAME,
    ItemResult,
    MissionProgress,
)
from executive.cli import main
from executive.core.frames import Pose2
from executive.core.loader import load_mission
from executive.core.records import FrameReference, Obstacles, PoseEstimate
from executive.dryrun import SimClock, dry_run
from executive.journal import Journal, MissionBinding, read_journal
from executive.runtime import Runtime
from sim2d.robot import SimRobot
from tests.conftest import MISSIONS, blackboard_writer
from tests.sim2d_helpers import make_scenario, scenario_file

S = py_trees.common.Status


pytestmark = pytest.mark.usefixtures("fresh_blackboard")


def _pose(x, y, theta=0.0, t=0.0):
    p = Pose2(x, y, theta)
    return PoseEstimate(t, p, np.eye(3) * 1e-4, p, 1.0)


def test_obstacle_trigger_engages_below_r_oa_and_releases_with_hysteresis():
    bb = blackboard_writer(OBSTACLES)
    guard = ObstacleTrigger(r_oa=2.5, release_margin=0.3)
    statuses = []
    for r_c in (3.0, 2.4, 2.6, 2.79, 2.81, 2.6):
        bb.set(OBSTACLES.name, Obstacles(0.0, r_c, 0.0, np.zeros((0, 2))), overwrite=True)
        guard.tick_once()
        statuses.append(guard.status)
    assert statuses == [S.FAILURE, S.SUCCESS, S.SUCCESS, S.SUCCESS, S.FAILURE, S.FAILURE]


def test_not_trapped_fails_after_the_period_without_progress():
    bb = blackboard_writer(POSE)
    guard = NotTrapped(Goal(Pose2(10.0, 0.0, 0.0)), period=5.0)
    for t in np.arange(0.0, 4.9, 0.1):  # progressing
        bb.set(POSE.name, _pose(t, 0.0, t=t), overwrite=True)
        guard.tick_once()
        assert guard.status == S.SUCCESS
    for t in np.arange(5.0, 10.5, 0.1):  # stuck at x = 4.9
        bb.set(POSE.name, _pose(4.9, 0.0, t=t), overwrite=True)
        guard.tick_once()
    assert guard.status == S.FAILURE and "no progress" in guard.feedback_message


def test_not_trapped_fails_a_robot_that_shuttles_just_short_of_its_goal():
    # campaign a320-busy-apron episode 17: every reverse into the servo start ended in an
    # e-stop and a retreat, 0.11-0.34 m short, for an hour; being near is not progress
    bb = blackboard_writer(POSE)
    guard = NotTrapped(
        Goal(Pose2(10.0, 0.0, 0.0)), period=20.0, at_goal=0.02, towards="CP10 servo start"
    )
    statuses = []
    for t in np.arange(0.0, 40.0, 0.1):
        d = 0.225 + 0.115 * math.cos(2 * math.pi * t / 8.0)  # 0.34 -> 0.11 -> 0.34 every 8 s
        bb.set(POSE.name, _pose(10.0 - d, 0.0, t=t), overwrite=True)
        guard.tick_once()
        statuses.append(guard.status)
    assert statuses[-1] == S.FAILURE
    message = (
        "towards CP10 servo start for 40 s (limit 20 s; 0.34 m from it, 0.11 m at the closest)"
    )
    assert message in guard.feedback_message
    assert statuses.index(S.FAILURE) == 201  # the first tick after the 20 s period


def test_not_trapped_reports_the_closest_approach_since_its_last_progress():
    bb = blackboard_writer(POSE)
    guard = NotTrapped(Goal(Pose2(10.0, 0.0, 0.0)), period=5.0, at_goal=0.02)
    for t in np.arange(0.0, 12.0, 0.1):  # at the goal, then pushed off: 0.2-0.3 m for 11 s
        d = 0.01 if t < 1.0 else 0.25 + 0.05 * math.cos(t)
        bb.set(POSE.name, _pose(10.0 - d, 0.0, t=t), overwrite=True)
        guard.tick_once()
    assert guard.status == S.FAILURE
    assert "for 11 s (limit 5 s; 0.29 m from it, 0.01 m at the closest)" in guard.feedback_message


def test_not_trapped_leaves_the_final_turn_at_the_goal_alone():
    bb = blackboard_writer(POSE)
    guard = NotTrapped(Goal(Pose2(10.0, 0.0, 0.0)), period=5.0, at_goal=0.02)
    for t in np.arange(0.0, 3.0, 0.1):  # the last 0.3 m at 0.1 m/s: progress by arriving
        bb.set(POSE.name, _pose(9.7 + 0.1 * t, 0.0, t=t), overwrite=True)
        guard.tick_once()
        assert guard.status == S.SUCCESS
    for t in np.arange(3.0, 12.0, 0.1):  # 1.5 cm off, turning (or a servo settling)
        bb.set(POSE.name, _pose(9.985, 0.0, theta=0.1 * (t - 3.0), t=t), overwrite=True)
        guard.tick_once()
        assert guard.status == S.SUCCESS


def test_every_navigation_trap_is_at_its_goal_where_the_navigation_is():
    from executive.compiler import CompileOptions, compile_mission

    mission = load_mission(MISSIONS / "a320" / "preflight.xml")
    for ask in (False, True):
        root = compile_mission(mission, CompileOptions(ask_operator=ask)).root
        checked = 0
        for nav in root.iterate():
            if not nav.name.startswith("navigate "):
                continue
            label = nav.name.removeprefix("navigate ")
            (trap,) = (n for n in nav.iterate() if isinstance(n, NotTrapped))
            (reached,) = (n for n in nav.iterate() if n.name == "reached?")
            assert trap.at_goal == reached.position_tolerance > 0.0
            assert trap.goal is reached.goal and trap.towards == label
            checked += 1
        assert checked > 2 * len(mission.checkpoints)  # servo starts, vias, P, station


def test_reached_needs_position_and_heading():
    bb = blackboard_writer(POSE)
    guard = Reached(Goal(Pose2(1.0, 1.0, 0.5)), 0.05, math.radians(2))
    for pose, expected in (
        (_pose(1.0, 1.0, 0.5), S.SUCCESS),
        (_pose(1.0, 1.1, 0.5), S.FAILURE),
        (_pose(1.0, 1.0, 0.6), S.FAILURE),
    ):
        bb.set(POSE.name, pose, overwrite=True)
        guard.tick_once()
        assert guard.status == expected


def test_correct_camera_angle_turns_towards_the_target_then_succeeds():
    # issue 13: it acts on the *measured* pan against pan* (the pan CP01's own pose needs),
    # once visual servoing has aimed the unit at the target (tests/test_servo_tree.py)
    from executive.core.records import (
        CameraFrame,
        Detection,
        FeatureObservations,
        PanTilt,
        SensorFrame,
    )

    mission = load_mission(MISSIONS / "a320" / "preflight.xml")
    camera = mission.platform.cameras["front"]
    feature = mission.aircraft.features["static-ports-left"]
    cp = next(c for c in mission.checkpoints if c.id == "CP01")
    node = CorrectCameraAngle(
        camera,
        ("front-left", "front-right"),
        feature,
        cp.pose,
        mission.aircraft.origin_height,
        math.radians(0.25),
        max_omega=0.5,
    )
    bb = blackboard_writer(SENSOR_FRAME, FEATURES)
    reader = py_trees.blackboard.Client(name="reader")
    reader.register_key(key=COMMAND.name, access=py_trees.common.Access.READ)
    centre = camera.image_width_px / 2
    dets = tuple(Detection(feature.id, k, centre, 300.0) for k in range(len(feature.points)))
    for offset, expect in ((0.0, S.SUCCESS), (math.radians(20), S.RUNNING)):
        node.initialise()
        pan = node.desired_pan + offset
        frame = SensorFrame(
            1.0,
            cameras={"front-left": CameraFrame(1.0, dets)},
            pan_tilt={"front": PanTilt(1.0, pan, 0.0)},
        )
        bb.set(SENSOR_FRAME.name, frame, overwrite=True)
        bb.set(FEATURES.name, FeatureObservations(1.0, {"front-left": dets}), overwrite=True)
        node.tick_once()
        assert node.status == expect
        command = reader.get(COMMAND.name)
        assert command.v == 0.0
        if expect == S.RUNNING:
            assert np.sign(command.omega) == np.sign(offset)


def test_an_exception_in_a_tick_stops_the_robot_and_fails_with_the_traceback(tmp_path, monkeypatch):
    from behaviours.sensing.features import SenseFeatures

    original = SenseFeatures.update

    def flaky(self):
        frame = self.bb.get("/sensors/frame")
        if frame.stamp > 3.0:
            raise RuntimeError("camera driver crashed")
        return original(self)

    monkeypatch.setattr(SenseFeatures, "update", flaky)
    run = dry_run(make_scenario(tmp_path, mission_type="lab", mission="visual-servoing.xml"))
    assert run.result.outcome == "failed"
    assert "camera driver crashed" in run.result.reason
    assert "RuntimeError" in run.result.traceback
    assert run.robot.world.base.v_cmd == 0.0 and run.robot.world.base.omega_cmd == 0.0
    assert any(e.kind == "fault" for e in run.result.events)
    assert gc.get_freeze_count() == 0  # a failed run lets go of what it froze too


def test_a_run_freezes_its_long_lived_objects_and_lets_them_go_at_the_end(tmp_path, monkeypatch):
    """The runtime moves what the first tick built out of the collector's full passes
    (a full collection stalled a tick for ~60 ms) and gives it back when the run ends."""
    frozen: list[int] = []
    step = Runtime.step

    def watched(self):
        frozen.append(gc.get_freeze_count())
        return step(self)

    monkeypatch.setattr(Runtime, "step", watched)
    scenario = make_scenario(tmp_path, mission_type="lab", mission="visual-servoing.xml")
    dry_run(scenario, max_time=2.0)
    assert len(frozen) > 50 and frozen[0] == 0 and all(n > 1000 for n in frozen[1:])
    assert gc.get_freeze_count() == 0


def test_an_error_outside_the_tick_still_stops_the_robot_and_unfreezes(tmp_path, monkeypatch):
    """The simulator steps in the clock's wait, outside the tick's own error handling: an
    exception there leaves the run, but the robot gets its stop and nothing stays frozen."""
    wait = SimClock.wait

    def broken(self, until):
        if until > 1.0:
            raise RuntimeError("simulator crashed")
        wait(self, until)

    monkeypatch.setattr(SimClock, "wait", broken)
    scenario = make_scenario(tmp_path, mission_type="lab", mission="visual-servoing.xml")
    sent = []
    send = SimRobot.send
    monkeypatch.setattr(SimRobot, "send", lambda self, cmd: (sent.append(cmd), send(self, cmd)))
    with pytest.raises(RuntimeError, match="simulator crashed"):
        dry_run(scenario)
    assert gc.get_freeze_count() == 0
    assert sent[-1].v == 0.0 and sent[-1].omega == 0.0


def test_journal_tolerates_a_torn_last_line(tmp_path):
    path = tmp_path / "journal.jsonl"
    journal = Journal(path, MissionBinding("m", "", "", (("CP1", 0.0, 0.0, 0.0),)))
    result = ItemResult("CP1", "item", 1.0, True, "ptz", 0.1, 0.2, (1.0, 2.0, 0.0))
    journal.record(1.0, MissionProgress("inspection", "CP1", "CP1", ("CP1",), (result,)), (1, 2, 3))
    journal.close()
    with path.open("a") as handle:
        handle.write('{"t": 2.0, "event": "checkpoint-do')  # killed mid-write
    state = read_journal(path)
    assert state.progress.completed == ("CP1",) and state.progress.results == (result,)
    assert state.pose_a == (1.0, 2.0, 3.0)


def test_dry_run_exit_codes(tmp_path, capsys):
    lab = MISSIONS / "lab" / "visual-servoing.xml"
    assert main(["dry-run", str(lab), "--rate", "100", "--out", str(tmp_path / "a")]) == 2
    broken = tmp_path / "broken.xml"
    broken.write_text("<mission/>")
    assert main(["dry-run", str(broken), "--out", str(tmp_path / "b")]) == 2
    short = scenario_file(
        tmp_path,
        '<faults><bumper-hit bumper="front" at="3" duration="0.5"/></faults>',
        mission_type="lab",
        mission="visual-servoing.xml",
    )
    short.write_text(short.read_text().replace('seed="1">', 'seed="1" duration="20">'))
    mission = short.parent.parent / "visual-servoing.xml"
    code = main(
        ["dry-run", str(mission), "--scenario", str(short), "--out", str(tmp_path / "c"), "--quiet"]
    )
    assert code == 1  # latched by the bumper, never reset: the mission did not complete
    report = json.loads((tmp_path / "c" / "metrics.json").read_text())
    assert report["outcome"] == "timeout" and report["safety_stops"][0]["kind"] == "estop-latched"
    capsys.readouterr()


FAIL, HOLD = py_trees.common.Status.FAILURE, py_trees.common.Status.SUCCESS


def _pose_with(confidence_f: float, reference, stamp: float):
    pose = Pose2(0.0, 0.0, 0.0)
    return PoseEstimate(
        stamp, pose, np.eye(3), pose, 1.0, confidence_f=confidence_f, reference=reference
    )


def test_pose_not_good_enough_holds_at_most_max_hold_and_never_before_registration():
    guard = PoseNotGoodEnough(low=0.3, high=0.6, max_hold=5.0, cooldown=20.0)
    bb = py_trees.blackboard.Client(name="t-relocalise")
    bb.register_key(key=POSE.name, access=py_trees.common.Access.WRITE)

    def tick(confidence, reference, t):
        bb.set(POSE.name, _pose_with(confidence, reference, t), overwrite=True)
        guard.tick_once()
        return guard.status

    assert tick(0.0, FrameReference.NOMINAL, 0.0) == FAIL  # not registered yet
    assert tick(0.1, FrameReference.AIRCRAFT, 1.0) == HOLD  # hold
    assert tick(0.5, FrameReference.AIRCRAFT, 2.0) == HOLD  # hysteresis
    assert tick(0.1, FrameReference.CHECKPOINT, 6.5) == FAIL  # held 5.5 s: go on
    assert tick(0.1, FrameReference.CHECKPOINT, 20.0) == FAIL  # resting
    assert tick(0.1, FrameReference.CHECKPOINT, 27.0) == HOLD  # rest over
    assert tick(0.7, FrameReference.AIRCRAFT, 28.0) == FAIL  # re-registered
    assert "confidence_F" in guard.feedback_message
