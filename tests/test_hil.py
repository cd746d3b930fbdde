"""``walkaround run`` against ``walkaround sim-robot``: real processes speaking the real
wires (CAN frames per the DBC over python-can's udp_multicast, SCIP 2.0 and NMEA over TCP,
detections over ZeroMQ, on this machine only), judged on the simulator's ground truth
(issue 14). Each test runs in real time: about a minute and a half for the lab mission.
"""

from __future__ import annotations

import http.client
import json
import math
import re
import signal
import threading
import time

import can
import pytest

from executive.robotlink.canbase import load_dbc
from tests.conftest import MISSIONS
from tests.hil import LAB_MISSION, STRICT_BASE_TIMEOUT_MS, Hil

# one rig at a time (two real-time processes each): on a 2-core machine the other pytest
# worker's test is load enough beside it
pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("hil")]

TOLERANCE = (0.15, 5.0)  # the lab and track missions' checkpoint tolerance (m, deg)
BRAKE_WITHIN = 0.15  # s: the bound on both sides of a lost link


@pytest.fixture
def hil(tmp_path):
    rigs: list[Hil] = []

    def make(**kwargs) -> Hil:
        rigs.append(Hil(tmp_path, **kwargs))
        return rigs[-1]

    yield make
    for rig in rigs:
        rig.close()


def _assert_within_tolerance(rig: Hil, expected: list[str]) -> None:
    judged = rig.judged()
    assert [j.id for j in judged] == expected
    for j in judged:
        assert j.position_error <= TOLERANCE[0], j
        assert j.heading_error_deg <= TOLERANCE[1], j
    assert rig.truth().of_kind("collision") == []


def _assert_moving(rig: Hil) -> None:
    """The robot drives now (ground truth over the last half second): a stop after this
    is the stop under test, not a pause of the mission."""
    truth = rig.truth()
    recent = [p for u, p in zip(truth.unix, truth.poses, strict=True) if u > time.time() - 0.6]
    assert (
        len(recent) >= 2
        and math.dist((recent[0].x, recent[0].y), (recent[-1].x, recent[-1].y)) > 0.02
    ), "the robot stands still: the test would prove nothing"


def test_the_lab_mission_over_the_wires(hil):
    rig = hil()
    run = rig.start_run()
    code, out = rig.finish(run, timeout=400)
    sim_out = rig.stop_sim()
    assert code == 0, out + sim_out
    assert "completed: mission completed; 3/3 checkpoints" in out
    _assert_within_tolerance(rig, ["CP1", "CP2", "CP3"])
    metrics = rig.metrics()
    link = metrics["link"]
    assert link["can"]["frames"]["bad_checksum"] == 0
    assert link["can"]["frames"]["repeated_counter"] == 0
    assert link["lasers"]["front"]["scans"] > 1000
    assert link["gps"]["fixes"] > 0 and link["detections"]["accepted"] > 0
    # the CAN log of the run decodes with the shipped DBC, both directions in it
    db = load_dbc()
    names = set()
    with can.LogReader(str(rig.run_out / "can.blf")) as log:
        for msg in log:
            names.add(db.get_message_by_frame_id(msg.arbitration_id).name)
            db.decode_message(msg.arbitration_id, msg.data)
    assert {"MOTION_CMD", "EXEC_HEARTBEAT", "BASE_HEARTBEAT", "WHEEL_SPEEDS"} <= names


def test_the_40_m_track_run_over_the_wires(hil):
    scenario = MISSIONS / "track" / "scenarios" / "straight-run-40m.xml"
    rig = hil(scenario=scenario)
    run = rig.start_run(MISSIONS / "track" / "straight-run.xml")
    code, out = rig.finish(run, timeout=500)
    sim_out = rig.stop_sim()
    assert code == 0, out + sim_out
    _assert_within_tolerance(rig, ["CP1"])


def test_killed_run_the_base_brakes_and_resume_finishes(hil):
    rig = hil()
    run = rig.start_run()
    rig.wait_for(lambda: "CP1" in rig.journal_completed(), 200, "CP1 completed")
    time.sleep(1.0)  # on the way to CP2
    _assert_moving(rig)
    killed = time.time()
    run.send_signal(signal.SIGKILL)
    run.communicate(timeout=10)

    def braked() -> list[dict]:
        return [e for e in rig.truth().of_kind("watchdog") if e["unix"] >= killed - 0.2]

    rig.wait_for(braked, 5, "the base's watchdog")
    fired = braked()[0]
    # measured on the base's side: from the last valid heartbeat to the brake
    assert fired["after_s"] <= BRAKE_WITHIN, fired
    time.sleep(1.0)
    truth = rig.truth()
    still = [p for u, p in zip(truth.unix, truth.poses, strict=True) if u > fired["unix"] + 0.5]
    assert len(still) >= 3
    assert max(math.dist((p.x, p.y), (still[0].x, still[0].y)) for p in still) < 0.01

    resumed = rig.start_run(LAB_MISSION, "--resume")
    code, out = rig.finish(resumed, timeout=400)
    sim_out = rig.stop_sim()
    assert code == 0, out + sim_out
    metrics = rig.metrics()
    assert metrics["resumed_after"] == ["CP1"]
    # the robot drove on after the kill until the base braked: the resumed run started
    # from the last journaled pose plus what the base's odometers counted since
    moved = metrics["moved_while_down_m"]
    assert moved is not None and max(abs(v) for v in moved) > 0.005, moved
    print(f"moved while down: {moved} m; judged: {rig.judged()}")
    assert [c["id"] for c in metrics["checkpoints"]] == ["CP2", "CP3"]  # none twice, none skipped
    _assert_within_tolerance(rig, ["CP2", "CP3"])


def test_killed_simulator_the_run_stops_and_says_why(hil):
    rig = hil(base_timeout_ms=STRICT_BASE_TIMEOUT_MS)  # the executive's bound is the subject
    run = rig.start_run()
    rig.wait_for(lambda: (rig.run_out / "journal.jsonl").exists(), 30, "the run to start")
    time.sleep(5.0)
    rig.sim.send_signal(signal.SIGKILL)
    code, out = rig.finish(run, timeout=30)
    assert code == 1, out
    reason = rig.metrics()["reason"]
    lost = re.search(r"base heartbeat lost for ([0-9.]+) s", reason)
    assert lost is not None, reason
    assert float(lost.group(1)) <= BRAKE_WITHIN, reason
    assert "robot link lost" in out and "base heartbeat lost" in out


def test_dropped_lasers_foreign_frames_and_an_operator_without_the_secret(hil):
    rig = hil(scenario=MISSIONS / "lab" / "scenarios" / "laser-link-drop.xml")
    run = rig.start_run()
    rig.wait_for(lambda: (rig.run_out / "operator.json").exists(), 30, "the operator endpoint")
    address = json.loads((rig.run_out / "operator.json").read_text())
    conn = http.client.HTTPConnection(address["host"], address["port"], timeout=5)
    conn.request("POST", "/command", body=json.dumps({"command": "abort"}))
    response = conn.getresponse()
    response.read()  # a keep-alive connection: the body is read before the next request
    assert response.status == 401  # no secret: refused, the mission goes on
    conn.request("POST", "/command", body=json.dumps({"command": "abort"}),
                 headers={"Authorization": "Bearer guessed"})  # fmt: skip
    assert conn.getresponse().status == 401
    conn.close()

    stop = threading.Event()
    robot = rig.robot.read_text()
    port = int(re.search(r'<can [^>]*port="(\d+)"', robot).group(1))

    def flood() -> None:  # frames of identifiers the DBC does not know, ~500 a second
        with can.Bus(interface="udp_multicast", channel="239.74.163.2", port=port,
                     hop_limit=0) as bus:  # fmt: skip
            k = 0
            while not stop.is_set():
                bus.send(can.Message(arbitration_id=0x555 + k % 7, data=[k % 256] * 8,
                                     is_extended_id=False))  # fmt: skip
                k += 1
                time.sleep(0.002)

    flooder = threading.Thread(target=flood, daemon=True)
    flooder.start()
    try:
        code, out = rig.finish(run, timeout=400)
    finally:
        stop.set()
        flooder.join(timeout=5)
    sim_out = rig.stop_sim()
    assert code == 0, out + sim_out
    metrics = rig.metrics()
    assert metrics["link"]["can"]["frames"]["unknown_frames"] > 1000
    assert metrics["link"]["lasers"]["front"]["connections_lost"] >= 1
    events = [json.loads(line) for line in (rig.run_out / "events.jsonl").read_text().splitlines()]
    stale = [e for e in events if e.get("kind") == "stale-sensor" and "laser" in e["reason"]]
    assert stale, "the dropped lasers held the robot"
    _assert_within_tolerance(rig, ["CP1", "CP2", "CP3"])


def test_sigterm_stops_the_robot_and_leaves_a_resumable_run(hil):
    rig = hil()
    run = rig.start_run()
    rig.wait_for(lambda: (rig.run_out / "journal.jsonl").exists(), 30, "the run to start")
    time.sleep(6.0)  # on the way to P
    _assert_moving(rig)
    signalled = time.time()
    run.send_signal(signal.SIGTERM)
    code, out = rig.finish(run, timeout=30)
    assert code == 143, out
    assert "--resume" in out
    metrics = rig.metrics()
    assert metrics["outcome"] == "interrupted" and metrics["stop_sent"] is True
    last = json.loads((rig.run_out / "journal.jsonl").read_text().splitlines()[-1])
    assert last["event"] == "interrupted"
    time.sleep(1.0)
    truth = rig.truth()
    after = [p for u, p in zip(truth.unix, truth.poses, strict=True) if u > signalled + 0.5]
    assert len(after) >= 3
    assert max(math.dist((p.x, p.y), (after[0].x, after[0].y)) for p in after) < 0.01
    assert not (rig.run_out / "operator.secret").exists()  # the endpoint closed with the run
    # the robot was told to stop before the run let go of the link: when the base's
    # watchdog fired (the heartbeat ended with the process) its command was already zero
    braked = [e for e in truth.of_kind("watchdog") if e["unix"] >= signalled]
    assert braked and all(e["v"] == 0.0 for e in braked), braked
