"""The robot runtime's pieces without the wires (issue 14): the robot file, the operator
endpoint and its secret, link faults stopping the runtime, the command line's refusals."""

from __future__ import annotations

import http.client
import json
import stat
from pathlib import Path

import pytest

from executive.cli import main
from executive.core.loader import load_mission
from executive.core.records import SensorFrame, VelocityCommand
from executive.hud.server import HudServer
from executive.operator import (
    COMMANDS,
    ENDPOINT_FILE,
    SECRET_FILE,
    OperatorError,
    OperatorState,
    send_command,
)
from executive.robotlink.config import load_robot
from tests.conftest import MISSIONS

ROBOTS = MISSIONS / "robots"
HIL = ROBOTS / "hil-localhost.xml"


# -- the robot file ------------------------------------------------------------------------------
@pytest.mark.parametrize("path", sorted(ROBOTS.glob("*.xml")), ids=lambda p: p.name)
def test_shipped_robot_files_validate_and_wire_every_platform_sensor(path, capsys):
    assert main(["validate", str(path)]) == 0
    robot = load_robot(path)
    for mission in ("a320/preflight.xml", "lab/visual-servoing.xml", "track/straight-run.xml"):
        assert robot.problems_with(load_mission(MISSIONS / mission).platform) == []


BAD_ROBOTS = {
    "watchdog-too-long": (
        '<can interface="udp_multicast" channel="239.1.1.1" watchdog-ms="5000"/>'
        '<laser id="front" host="127.0.0.1" port="1"/>',
        "between 20 and 1000 ms",
    ),
    "unknown-interface": (
        '<can interface="carrier-pigeon" channel="x"/><laser id="front" host="h" port="1"/>',
        "carrier-pigeon",
    ),
    "duplicate-ptu-index": (
        '<can interface="virtual" channel="x"/><ptu unit="front" index="0"/>'
        '<ptu unit="rear" index="0"/><laser id="front" host="h" port="1"/>',
        "duplicate pan-tilt index",
    ),
    "duplicate-laser": (
        '<can interface="virtual" channel="x"/><laser id="front" host="h" port="1"/>'
        '<laser id="front" host="h" port="2"/>',
        "duplicate laser",
    ),
    "laser-port-zero": (
        '<can interface="virtual" channel="x"/><laser id="front" host="h" port="0"/>',
        "port 0 names no device",
    ),
    "latitude-beyond-the-pole": (
        '<can interface="virtual" channel="x"/><laser id="front" host="h" port="1"/>'
        '<gps url="/dev/ttyUSB0" latitude-deg="91" longitude-deg="0"/>',
        "between -90 and 90",
    ),
    "no-laser": ('<can interface="virtual" channel="x"/>', "laser"),
}


@pytest.mark.parametrize("name", sorted(BAD_ROBOTS))
def test_bad_robot_files_exit_2_at_their_line(tmp_path, capsys, name):
    body, expected = BAD_ROBOTS[name]
    path = tmp_path / f"{name}.xml"
    path.write_text(f'<robot xmlns="urn:walkaround:robot:1" id="r">\n{body}\n</robot>\n')
    assert main(["validate", str(path)]) == 2
    err = capsys.readouterr().out
    assert f"{name}.xml:2:" in err or f"{name}.xml:1:" in err, err
    assert expected in err
    assert "Traceback" not in err


def test_run_refuses_a_robot_file_missing_a_platform_sensor(tmp_path, capsys):
    robot = tmp_path / "robot.xml"
    robot.write_text(
        HIL.read_text().replace('<laser id="rear" host="127.0.0.1" port="10941"/>', "")
    )
    code = main(["run", str(MISSIONS / "lab" / "visual-servoing.xml"), "--robot", str(robot),
                 "--out", str(tmp_path / "out")])  # fmt: skip
    assert code == 2
    assert "laser 'rear' of the platform has no <laser>" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("rate", ["5", "nan", "60"])
def test_run_refuses_a_rate_outside_10_to_50_hz(tmp_path, capsys, rate):
    code = main(["run", str(MISSIONS / "lab" / "visual-servoing.xml"), "--robot", str(HIL),
                 "--out", str(tmp_path / "out"), "--rate", rate])  # fmt: skip
    assert code == 2
    assert "--rate" in capsys.readouterr().err


# -- the operator endpoint -----------------------------------------------------------------------
def test_operator_state_semantics():
    state = OperatorState()
    assert state(0.0).take_over is False
    state.apply("pause")
    assert state(0.0).take_over is True
    state.apply("resume")
    state.apply("take-over")
    assert state(0.0).take_over is True
    state.apply("hand-back")
    assert state(0.0).take_over is False
    state.apply("reset-estop")
    assert state(0.0).reset_estop is True
    assert state(0.1).reset_estop is False  # a one-shot request
    state.apply("take-over")
    state.apply("abort")  # the robot goes back to P on its own: the take-over ends
    assert state(0.2).abort is True and state(0.2).take_over is False
    assert state.apply("resume") == "resume: accepted"  # nothing undoes an abort
    assert state(0.3).abort is True
    state.apply("take-over")  # but the operator can still take the robot on the way
    assert state(0.4).take_over is True and state(0.4).abort is True
    with pytest.raises(ValueError, match="unknown command"):
        state.apply("self-destruct")


@pytest.fixture
def endpoint(tmp_path):
    state = OperatorState()
    ep = HudServer(state, tmp_path, status=lambda: {"controller": "go to CP1"})
    yield ep
    ep.close()


def _post(ep, body: bytes, headers: dict[str, str]) -> tuple[int, dict]:
    conn = http.client.HTTPConnection(ep.host, ep.port, timeout=5)
    conn.request("POST", "/command", body=body, headers=headers)
    response = conn.getresponse()
    data = json.loads(response.read() or b"{}")
    conn.close()
    return response.status, data


def test_the_secret_is_private_and_required(endpoint, tmp_path):
    secret = tmp_path / SECRET_FILE
    assert stat.S_IMODE(secret.stat().st_mode) == 0o600
    assert json.loads((tmp_path / ENDPOINT_FILE).read_text())["port"] == endpoint.port
    body = json.dumps({"command": "abort"}).encode()
    assert _post(endpoint, body, {})[0] == 401
    assert _post(endpoint, body, {"Authorization": "Bearer not-the-secret"})[0] == 401
    assert endpoint.state.aborted is False and endpoint.refused == 2
    token = secret.read_text().strip()
    status, answer = _post(endpoint, body, {"Authorization": f"Bearer {token}"})
    assert status == 200 and answer["ok"] is True
    assert endpoint.state.aborted is True


@pytest.mark.parametrize(
    "body", [b"", b"not json", b'{"cmd": "pause"}', b'{"command": "dance"}', b"x" * 5000]
)
def test_bad_requests_are_refused_and_change_nothing(endpoint, tmp_path, body):
    token = (tmp_path / SECRET_FILE).read_text().strip()
    status, _ = _post(endpoint, body, {"Authorization": f"Bearer {token}"})
    assert status == 400
    assert endpoint.state.log == []


def test_the_operator_command_line(endpoint, tmp_path, capsys):
    assert main(["operator", "take-over", "--run", str(tmp_path)]) == 0
    assert endpoint.state.taken_over
    assert main(["operator", "status", "--run", str(tmp_path)]) == 0
    assert "go to CP1" in capsys.readouterr().out
    assert set(COMMANDS) >= {"pause", "resume", "take-over", "hand-back", "reset-estop", "abort"}


def test_no_running_executive_is_said(tmp_path, capsys):
    assert main(["operator", "pause", "--run", str(tmp_path)]) == 1
    assert "no running executive" in capsys.readouterr().err
    with pytest.raises(OperatorError):
        send_command(Path(tmp_path), "pause")


def test_closing_the_endpoint_removes_its_secret(tmp_path):
    ep = HudServer(OperatorState(), tmp_path, status=dict)
    ep.close()
    assert not (tmp_path / SECRET_FILE).exists() and not (tmp_path / ENDPOINT_FILE).exists()


# -- link faults stop the runtime ----------------------------------------------------------------
class _FaultyRobot:
    """A robot whose link fails after ``fail_at`` seconds; records what it was sent."""

    def __init__(self, clock, fail_at: float) -> None:
        self.clock = clock
        self.fail_at = fail_at
        self.sent: list[VelocityCommand] = []

    def read(self) -> SensorFrame:
        return SensorFrame(stamp=self.clock.now())

    def send(self, command: VelocityCommand) -> None:
        self.sent.append((self.clock.now(), command))

    def link_faults(self) -> tuple[str, ...]:
        if self.clock.now() >= self.fail_at:
            return ("base heartbeat lost for 0.12 s",)
        return ()


class _Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def now(self) -> float:
        return self.t

    def wait(self, until: float) -> None:
        self.t = max(self.t, until)

    @staticmethod
    def tick_timer() -> float:
        return 0.0


def test_a_link_fault_stops_the_robot_and_ends_the_run_with_its_reason():
    from executive.compiler import CompileOptions, compile_mission
    from executive.runtime import Runtime
    from executive.safety import SafetyLayer

    mission = load_mission(MISSIONS / "lab" / "visual-servoing.xml")
    compiled = compile_mission(mission, CompileOptions(rate_hz=50.0))
    clock = _Clock()
    robot = _FaultyRobot(clock, fail_at=0.5)
    safety = SafetyLayer(mission, compiled.placement, 0.02)
    result = Runtime(compiled, robot, clock, safety, rate_hz=50.0).run(10.0)
    assert result.outcome == "failed"
    assert "robot link lost at 0.5 s: base heartbeat lost for 0.12 s" in result.reason
    assert result.duration == pytest.approx(0.5, abs=0.021)  # ended at the fault's tick
    at_fault = [c for t, c in robot.sent if t >= 0.5]
    assert at_fault and all(c.is_stop for c in at_fault)
    assert [e.kind for e in result.events if e.kind == "link-lost"] == ["link-lost"]


# -- the link's own judgement ------------------------------------------------------------------
class _Gps:
    def __init__(self) -> None:
        from executive.robotlink.nmea import NmeaCounts

        self.counts_ = NmeaCounts()

    def counts(self):
        return self.counts_

    def latest(self):
        return None

    def close(self) -> None:
        pass


def _link(clock, gps=None):
    import can

    from executive.robotlink.canbase import CanBaseLink
    from executive.robotlink.link import RobotLink

    bus = can.Bus(interface="virtual", channel=f"link-{id(clock)}")
    return RobotLink(bus, CanBaseLink(bus, clock=clock.now), {}, gps, None, clock.now)


def test_a_gps_stream_failing_its_checksums_is_a_link_fault_one_bad_sentence_is_not():
    import dataclasses

    clock = _Clock()
    gps = _Gps()
    link = _link(clock, gps)
    try:
        nmea = [f for f in link._nmea_faults()]
        assert nmea == []
        clock.t = 0.5
        gps.counts_ = dataclasses.replace(gps.counts_, bad_checksum=1)
        assert link._nmea_faults() == ()
        clock.t = 3.0  # the old error has left the window
        gps.counts_ = dataclasses.replace(gps.counts_, bad_checksum=2)
        assert link._nmea_faults() == ()
        for k in range(3):
            clock.t = 3.1 + 0.1 * k
            gps.counts_ = dataclasses.replace(gps.counts_, bad_checksum=3 + k)
            faults = link._nmea_faults()
        assert faults and "bad NMEA checksums" in faults[0]
        assert "GPS:" in " ".join(link.link_faults())
    finally:
        link.close()


def test_the_operators_reset_releases_the_base_latch_with_the_next_command():
    clock = _Clock()
    link = _link(clock)
    sent = []
    link.base.send_reset = lambda: sent.append("reset") or True  # type: ignore[method-assign]
    try:
        state = OperatorState()
        state.listeners.append(lambda c: link.request_reset() if c == "reset-estop" else None)
        state.apply("reset-estop")
        link.send(VelocityCommand.stop())
        link.send(VelocityCommand.stop())
        assert sent == ["reset"]  # once, with the next command
    finally:
        link.close()


def test_run_refuses_a_rate_whose_ticks_the_watchdog_cannot_span(tmp_path, capsys):
    code = main(["run", str(MISSIONS / "lab" / "visual-servoing.xml"), "--robot", str(HIL),
                 "--out", str(tmp_path / "out"), "--rate", "20"])  # fmt: skip
    assert code == 2
    err = capsys.readouterr().err
    assert "watchdog (100 ms) must span 3 ticks at 20 Hz (150 ms)" in err


def test_a_platform_faster_than_the_can_frame_is_refused():
    import dataclasses

    from executive.cli_robot import _robot_problems

    platform = load_mission(MISSIONS / "lab" / "visual-servoing.xml").platform
    fast = dataclasses.replace(platform, max_speed=3.0)
    problems = _robot_problems(load_robot(HIL), fast, 50.0)
    assert problems == [
        "the platform's max-speed 3 is more than the CAN frame carries (MOTION_CMD.V at most 2)"
    ]
    assert _robot_problems(load_robot(HIL), platform, 50.0) == []


def test_bringing_the_base_up_ends_on_a_signal_and_sends_a_pending_reset():
    clock = _Clock()
    link = _link(clock)
    sent = []
    link.base.send_reset = lambda: sent.append("reset") or True  # type: ignore[method-assign]
    try:
        link.request_reset()
        asked: list[int] = []

        def second_time() -> bool:  # a signal while the base does not answer yet
            asked.append(1)
            return len(asked) > 1

        assert link.wait_ready(timeout=5.0, should_stop=second_time) is False
        assert sent == ["reset"]
    finally:
        link.close()


def test_a_cycle_that_did_not_go_out_raises_and_close_sends_enable_0():
    from executive.robotlink.canbase import ExecState
    from executive.robotlink.link import LinkError

    clock = _Clock()
    link = _link(clock)
    states = []
    link.base.send = lambda command, state: states.append(state) or False  # type: ignore
    with pytest.raises(LinkError, match="did not all go out"):
        link.send(VelocityCommand(v=0.3))
    link.close()
    assert states[-1] is ExecState.IDLE  # the final stop with ENABLE 0
