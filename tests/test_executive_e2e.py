"""End-to-end: the executive runs missions in sim2d (ISSUE 4 acceptance).

Each test runs the whole stack — compiled tree, runtime, safety layer — against the
simulator and judges the outcome on ground truth.
"""

import json
import math
import signal
import subprocess
import sys
import time

import pytest

from executive.core.records import OperatorRequests
from executive.dryrun import dry_run
from executive.report import metrics
from sim2d.scenario import load_scenario
from tests.conftest import MISSIONS
from tests.sim2d_helpers import assert_finished_by_servoing, make_scenario, stop_once_done

pytestmark = pytest.mark.slow


def _assert_mission_succeeded(run, first: int | None = None):
    """The mission completed (``first``: the run was stopped once that many checkpoints
    were done, by :func:`stop_once_done`), on ground truth: no collision or breach, every
    checkpoint (the first ones) reached within 0.15 m and 5 deg, every item of it
    inspected and detected."""
    if first is None:
        assert run.result.outcome == "completed", run.result.reason
    assert not run.robot.truth.collisions
    assert not run.breaches
    checkpoints = run.scenario.mission.checkpoints[:first]
    for cp, outcome in zip(checkpoints, run.checkpoints[:first], strict=True):
        assert outcome.reached, cp.id
        assert outcome.position_error <= 0.15, (cp.id, outcome)
        assert outcome.heading_error_deg <= 5.0, (cp.id, outcome)
        assert outcome.items == len(cp.items), cp.id  # every item inspected
    results = run.result.progress.results
    assert len(results) == sum(len(cp.items) for cp in checkpoints)
    assert all(r.detected for r in results)


@pytest.mark.parametrize(("kind", "first"), [("a320", 12), ("b737-800", None)])
def test_preflight_with_the_aircraft_parked_off_its_mark(kind, first):
    """ISSUE 4 and 5 acceptance with the aircraft parked off its nominal pose (the offset
    apron is the clear apron with the aircraft about a metre and 5-6 deg off its mark):
    the laser registration finds the aircraft, so every checkpoint (given in F) is reached
    within 0.15 m and 5 deg of where it really is; issue 13, visual servoing is on by
    default on the airliners and finishes every checkpoint whose target it can servo on
    within 2 cm and 0.5 deg. The B737 is run whole; the A320 until its first 12
    checkpoints are done (the README's main job, tests/test_readme.py, is the whole A320
    pre-flight on the clear apron, with its report and recording)."""
    stop, enough = stop_once_done(first) if first is not None else (None, None)
    run = dry_run(
        load_scenario(MISSIONS / kind / "scenarios" / "offset-apron.xml"),
        stop=stop,
        observers=[enough] if enough is not None else [],
    )
    assert first is None or stop, (run.result.outcome, run.result.reason)
    _assert_mission_succeeded(run, first)
    servoed = assert_finished_by_servoing(run, first)  # issue 13: the image, not the registration
    assert len(servoed) >= len(run.checkpoints[:first]) - 2, servoed
    report = metrics(run)
    loc = report["localisation"]
    assert loc["registrations"]["global"]["accepted"] >= 1
    assert loc["registrations"]["icp"]["accepted"] > 10
    assert loc["registration_position_error_m"]["p95"] < 0.05
    assert loc["registration_heading_error_deg"]["p95"] < 0.5
    assert loc["placement_error_final"]["position_m"] < 0.1
    assert loc["placement_error_final"]["heading_deg"] < 0.3
    kinds = [e.kind for e in run.result.events]
    assert "registration" in kinds and "localisation" in kinds


LAB = {"mission_type": "lab", "mission": "visual-servoing.xml"}


# Lab mission: the robot goes from P (2, -6) to CP1 (1.5, -3.5 in the lab frame). A person
# starts walking slowly across its way (y = -4.6) when the robot nears P, steps in front of
# it, and walks on to the far side of the room.
WALKER = (
    '<obstacles><path id="walker" kind="person" radius="0.3" height="1.8" speed="0.3"'
    ' trigger-radius="3"><waypoint x="-0.5" y="-4.6"/><waypoint x="9" y="-4.6"/>'
    "</path></obstacles>"
)


def test_pedestrian_in_front_triggers_the_estop_and_the_mission_goes_on(tmp_path):
    """Without obstacle avoidance the slowdown (the walker will enter the corridor) and the
    e-stop handle the walker: the robot stops, waits, and goes on once it has passed."""
    run = dry_run(make_scenario(tmp_path, WALKER, **LAB), avoidance=False)
    kinds = [e.detail.get("kind") for e in run.result.events if e.kind == "safety"]
    assert "estop-latched" in kinds and "estop-released" in kinds
    to_estop = [
        e
        for e in run.result.events
        if e.kind == "controller" and e.detail["to"] == "emergency stop"
    ]
    assert to_estop and "r_ES" in to_estop[0].detail["reason"]
    _assert_mission_succeeded(run)


def test_pedestrian_in_front_is_dodged_with_obstacle_avoidance(tmp_path):
    """With obstacle avoidance (the default) the same walker is dodged with velocity
    obstacles: no e-stop at all, and the mission completes."""
    run = dry_run(make_scenario(tmp_path, WALKER, **LAB))
    dodges = [
        e
        for e in run.result.events
        if e.kind == "controller" and e.detail["to"] == "velocity obstacles"
    ]
    assert dodges and "m/s" in dodges[0].detail["reason"]
    assert metrics(run)["estops"] == 0
    _assert_mission_succeeded(run)


def test_bumper_latches_until_the_operator_resets(tmp_path):
    fault = '<faults><bumper-hit bumper="front" at="8" duration="0.5"/></faults>'
    scenario = make_scenario(tmp_path, fault, **LAB)

    def reset_at_30(t):
        return OperatorRequests(reset_estop=30.0 <= t < 30.5)

    run = dry_run(scenario, operator=reset_at_30)
    latched = [s for s in run.samples if 8.2 <= s.t < 30.0]
    assert latched and all(s.v == 0.0 and s.omega == 0.0 for s in latched)
    assert any(s.v != 0.0 for s in run.samples if s.t > 30.5)
    _assert_mission_succeeded(run)

    held = dry_run(make_scenario(tmp_path, fault, name="nobody.xml", **LAB), max_time=45.0)
    assert held.result.outcome == "timeout"
    assert all(s.v == 0.0 and s.omega == 0.0 for s in held.samples if s.t >= 8.2)


def test_laser_dropout_stops_the_robot_and_the_report_says_why(tmp_path):
    fault = '<faults><laser-dropout laser="front" at="6" duration="4"/></faults>'
    run = dry_run(make_scenario(tmp_path, fault, **LAB))
    stopped = [s for s in run.samples if 6.3 <= s.t < 10.0]
    assert stopped and all(s.v == 0.0 and s.omega == 0.0 for s in stopped)
    report = metrics(run)
    stops = [s for s in report["safety_stops"] if s["kind"] == "stale-sensor"]
    assert stops and "front" in stops[0]["reason"] and math.isclose(stops[0]["t"], 6.1, abs_tol=0.3)
    _assert_mission_succeeded(run)


def test_a_killed_run_resumes_without_repeating_or_skipping_a_checkpoint(tmp_path):
    """SIGKILL the dry-run process once a checkpoint is journaled, then --resume."""
    out = tmp_path / "run"
    journal = out / "journal.jsonl"
    command = [
        sys.executable,
        "-m",
        "executive.cli",
        "dry-run",
        str(MISSIONS / "lab" / "visual-servoing.xml"),
        "--out",
        str(out),
        "--quiet",
    ]
    first = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 180
    try:
        while time.monotonic() < deadline and first.poll() is None:
            if journal.exists() and '"checkpoint-done"' in journal.read_text():
                break
            time.sleep(0.02)
        assert first.poll() is None, "the run ended before it could be killed"
        first.send_signal(signal.SIGKILL)
    finally:
        first.wait()
    done_before = _done(journal)
    assert 1 <= len(done_before) < 3
    second = subprocess.run(
        [*command, "--resume"], capture_output=True, text=True, timeout=300, check=False
    )
    assert second.returncode == 0, second.stdout + second.stderr
    assert _done(journal) == ["CP1", "CP2", "CP3"]  # each once, in order
    report = json.loads((out / "metrics.json").read_text())
    assert report["resumed_after"] == done_before and report["succeeded"]


def _done(journal):
    done = []
    for line in journal.read_text().splitlines():
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            continue  # the line SIGKILL tore
        if record.get("event") == "checkpoint-done":
            done.append(record["checkpoint"])
    return done
