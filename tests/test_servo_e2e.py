"""Visual servoing end to end in sim2d (issue 13 §5): the lab mission reproduces the
thesis's experiment sequence (metric -> PBVS -> IBVS at checkpoints 1 and 2, metric then
IBVS at checkpoint 3; seed 000 lines 3241-3560), every servo checkpoint finished by
servoing within 2 cm and 0.5 deg of its true pose; a person occluding the target (the
augmented image carries it, the report shows the reconstructed time) and a frozen camera
(another camera takes over)."""

from __future__ import annotations

import pytest

from executive.dryrun import dry_run
from executive.report import metrics
from sim2d.scenario import load_scenario
from tests.conftest import MISSIONS
from tests.sim2d_helpers import assert_finished_by_servoing

LAB = MISSIONS / "lab" / "scenarios"
POSITION, HEADING_DEG = 0.02, 0.5


def _controller_events(run):
    return [e for e in run.result.events if e.kind == "controller"]


@pytest.fixture(scope="module")
def clear_run():
    return dry_run(load_scenario(LAB / "clear-apron.xml"), servo=True)


@pytest.fixture(scope="module")
def disturbed_run():
    return dry_run(load_scenario(LAB / "occlusion-and-camera-fault.xml"), servo=True)


def _assert_accurate(run):
    assert run.succeeded, run.first_cause
    assert not [w for w in run.warnings if "servo-metric" in w]
    for cp in run.checkpoints:
        assert cp.reached and cp.position_error is not None
        assert cp.position_error <= POSITION, (cp.id, cp.position_error)
        assert cp.heading_error_deg <= HEADING_DEG, (cp.id, cp.heading_error_deg)
        assert cp.items == cp.detected


def test_lab_reproduces_pbvs_ibvs_metric_and_reaches_every_checkpoint_by_servoing(clear_run):
    run = clear_run
    _assert_accurate(run)
    assert assert_finished_by_servoing(run) == ["CP1", "CP2", "CP3"]
    events = _controller_events(run)
    names = [e.detail["to"] for e in events]
    # CP1 and CP2: metric to the servo start, then PBVS, then IBVS, which ends the
    # navigation (the stop criterion), then the inspection
    for cp in ("CP1", "CP2"):
        start = names.index(f"go to {cp} servo start")
        pbvs = names.index("visual servoing (pbvs)", start)
        ibvs = names.index("visual servoing (ibvs)", pbvs)
        assert ibvs < names.index(f"inspect {cp}", start)
        reason = events[pbvs].detail["reason"]
        assert "features visible (measured or reconstructed)? [pbvs]" in reason
        assert "pbvs on front-" in reason and "target-" in reason
        assert "[ibvs]" in events[ibvs].detail["reason"]
    # CP3 (ibvs): metric, then IBVS only
    start = names.index("go to CP3 servo start")
    inspect = names.index("inspect CP3", start)
    between = names[start:inspect]
    assert "visual servoing (ibvs)" in between and "visual servoing (pbvs)" not in between
    # the navigation of each checkpoint ended under servoing (no metric 'stop' at the end)
    for cp in ("CP1", "CP2", "CP3"):
        inspect = names.index(f"inspect {cp}")
        before = [n for n in names[:inspect] if n not in ("correct front angle",)]
        assert before[-1] == "visual servoing (ibvs)", (cp, before[-3:])
    servo = metrics(run)["servo"]
    assert set(servo) == {"CP1", "CP2", "CP3"}
    assert servo["CP1"]["pbvs_s"] > 0 and servo["CP1"]["ibvs_s"] > 0
    assert servo["CP3"]["pbvs_s"] == 0


def test_lab_with_a_person_occluding_and_a_frozen_camera(disturbed_run):
    run = disturbed_run
    assert run.succeeded, run.first_cause
    # The person walking along the fence also engages velocity obstacles on the way to
    # checkpoint 2's servo start: the dodge leaves the robot off the heading line and the
    # servo cannot take the sideways offset out (four controls, five variables), so
    # checkpoint 2 is held to the mission's tolerance only. Checkpoints 1 and 3 (the
    # camera fault, no person) meet the servo bar.
    for cp in run.checkpoints:
        assert cp.reached and cp.items == cp.detected
        if cp.id != "CP2":
            assert cp.position_error <= POSITION and cp.heading_error_deg <= HEADING_DEG
    servo = metrics(run)["servo"]
    # the person hid target 2's points: the augmented image carried the servo
    assert servo["CP2"]["reconstructed_s"] > 0.0
    reasons = [e.detail["reason"] for e in _controller_events(run)]
    assert any("reconstructed" in r and "target-2" in r for r in reasons)
    # the frozen front-right camera (16-20 s), which drove, handed the servo to front-left
    switches = servo["CP1"]["switches"]
    assert any(
        16.0 <= sw["t"] <= 20.5
        and "ibvs -> ibvs" in sw["reason"]
        and "on front-left" in sw["reason"]
        for sw in switches
    ), switches


def test_lab_with_a_cone_behind_a_servo_start_slides_it_and_servoes_from_there():
    """A cone 0.64 m behind the robot standing at CP2's servo start (4 cm beyond r_ES, as
    the fuel truck behind the A320's CP10 on a busy apron): before, every turn there swung
    a rear corner into r_ES and the navigation was trapped ("no progress towards CP2
    servo start for 120 s", 19 e-stop latches). The start slides towards CP2 until the
    robot can turn there; CP2 is still finished by servoing within 2 cm and 0.5 deg."""
    run = dry_run(load_scenario(LAB / "cone-behind-servo-start.xml"), servo=True)
    _assert_accurate(run)
    assert "CP2" in assert_finished_by_servoing(run)
    servo = metrics(run)["servo"]
    assert servo["CP1"]["start_m"] == 1.0 and "start_note" not in servo["CP1"]
    assert 0.4 <= servo["CP2"]["start_m"] < 1.0
    assert "servo start slid from 1.00 m" in servo["CP2"]["start_note"]
    latches = [
        e.t
        for e in run.result.events
        if e.kind == "safety" and e.detail.get("kind") == "estop-latched"
    ]
    assert len(latches) <= 2, latches
