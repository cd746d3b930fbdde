"""Recording for Foxglove (issue 15 §5): every dry-run writes an MCAP file that the
``mcap`` reader opens, with Foxglove's well-known schemas where one fits, every topic
covering the run, and nothing of another recording made in the same process; the live
view serves the same channels over the Foxglove WebSocket protocol."""

from __future__ import annotations

import json
import math
import struct
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from foxglove.messages import (
    FrameTransform,
    LaserScan,
    Pose,
    PoseInFrame,
    Quaternion,
    Timestamp,
    Vector3,
)
from mcap.reader import make_reader
from scipy.spatial.transform import Rotation
from websockets.sync.client import connect

from executive.core.frames import (
    AircraftPlacement,
    Pose2,
    airport_from_robot,
    robot_from_camera,
)
from executive.core.records import LaserScan as ScanRecord
from executive.core.records import SensorFrame, VelocityCommand
from executive.dryrun import dry_run
from executive.recording import (
    Recorder,
    ScanEncoder,
    encode_planar_pose,
    encode_planar_transform,
    quaternion_of,
    recording_path,
    recordings_in,
    serve_live,
    timestamp_field,
    velocity_json,
)
from executive.safety import SafetyStatus
from sim2d.scenario import load_scenario
from tests.conftest import MISSIONS

LAB = MISSIONS / "lab" / "scenarios" / "clear-apron.xml"
LAB_SECONDS = 30.0

WELL_KNOWN = {
    "/scene": "foxglove.SceneUpdate",
    "/tf": "foxglove.FrameTransforms",
    "/tf/sensors": "foxglove.FrameTransforms",
    "/pose": "foxglove.PoseInFrame",
    "/scan/front": "foxglove.LaserScan",
    "/scan/rear": "foxglove.LaserScan",
    "/obstacles": "foxglove.SceneUpdate",
    "/log": "foxglove.Log",
}
OURS = {
    "/command": "walkaround.Command",
    "/controller": "walkaround.Controller",
    "/events": "walkaround.Event",
    "/state": "walkaround.State",
    **{
        f"/camera/{c}/detections": "walkaround.Detections"
        for c in ("front-left", "front-right", "rear-left", "rear-right", "ptz")
    },
}
PERIODIC = {  # topic -> the longest gap between two of its messages (s)
    "/tf": 0.021,
    "/command": 0.021,
    "/pose": 0.11,
    "/scan/front": 0.031,  # 40 Hz, stamped on the 50 Hz ticks
    "/scan/rear": 0.031,
    "/obstacles": 0.11,
    "/tf/sensors": 0.21,
    "/state": 0.21,
    **{f"/camera/{c}/detections": 1.05 for c in ("front-left", "front-right", "ptz")},
}


class Recording:
    """An MCAP file read back with the ``mcap`` reader: per topic, its schema and its
    messages (log time in s, bytes)."""

    def __init__(self, path: Path) -> None:
        self.topics: dict[str, list[tuple[float, bytes]]] = {}
        self.schemas: dict[str, tuple[str, str, str]] = {}
        with path.open("rb") as f:
            reader = make_reader(f)
            summary = reader.get_summary()
            assert summary is not None
            self.statistics = summary.statistics
            for channel in summary.channels.values():
                schema = summary.schemas[channel.schema_id]
                self.schemas[channel.topic] = (
                    schema.name,
                    schema.encoding,
                    channel.message_encoding,
                )
                self.topics.setdefault(channel.topic, [])
            for _, channel, message in reader.iter_messages(log_time_order=True):
                self.topics[channel.topic].append((message.log_time / 1e9, message.data))
            self.metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}

    def json(self, topic: str) -> list[dict]:
        return [json.loads(data) for _, data in self.topics[topic]]

    def times(self, topic: str) -> list[float]:
        return [t for t, _ in self.topics[topic]]


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    path = tmp_path_factory.mktemp("lab") / "run.mcap"
    run = dry_run(load_scenario(LAB), max_time=LAB_SECONDS, record=path)
    return run, Recording(path)


def _assert_covers(rec: Recording, end: float, gaps: dict[str, float]) -> None:
    for topic, gap in gaps.items():
        times = rec.times(topic)
        assert times, topic
        assert times[0] <= gap, (topic, times[0])
        assert times[-1] >= end - gap, (topic, times[-1], end)
        assert max(np.diff(times)) <= gap + 1e-6, (topic, max(np.diff(times)))


# -- a lab dry-run ------------------------------------------------------------------------------
def test_the_recording_holds_every_topic_with_foxglove_schemas(lab):
    run, rec = lab
    assert run.recording is not None and run.recording_error is None
    for topic, name in WELL_KNOWN.items():
        assert rec.schemas[topic] == (name, "protobuf", "protobuf"), topic
    for topic, name in OURS.items():
        assert rec.schemas[topic] == (name, "jsonschema", "json"), topic
    assert set(rec.topics) == set(WELL_KNOWN) | set(OURS)
    assert rec.metadata["walkaround"]["mission"] == run.scenario.mission.id
    assert rec.metadata["outcome"]["outcome"] == run.result.outcome == "timeout"


def test_every_periodic_topic_spans_the_run(lab):
    run, rec = lab
    end = run.result.duration
    assert end == pytest.approx(LAB_SECONDS, abs=0.05)
    _assert_covers(rec, end, PERIODIC)
    assert len(rec.topics["/tf"]) == len(run.result.stats.durations)  # every tick
    assert len(rec.topics["/scene"]) == 1 and rec.times("/scene")[0] == 0.0


def test_commands_are_those_of_the_runtime_commanded_and_sent(lab):
    run, rec = lab
    commands = rec.json("/command")
    assert len(commands) == len(run.result.stats.durations)
    # the recording's last sent commands are the ones the robot was sent
    sent = [c["sent"] for c in commands[-3:]]
    wire = [cmd for _, cmd in run.last_commands[-4:-1]]  # the last one is the final stop
    assert [(s["v"], s["omega"]) for s in sent] == [(c.v, c.omega) for c in wire]
    units = set(run.scenario.mission.platform.cameras)
    assert all(set(c["sent"]["pan_tilt"]) <= units for c in commands)
    assert any(c["commanded"]["v"] != c["sent"]["v"] for c in commands)  # the safety layer


def test_events_controllers_and_logs_are_the_runs(lab):
    run, rec = lab
    ours = ("phase", "checkpoint-completed")
    events = [e for e in rec.json("/events") if e["event"] not in ours]
    expected = [json.loads(json.dumps(e.as_dict(), default=_plain)) for e in run.result.events]
    assert sorted(map(json.dumps, events)) == sorted(map(json.dumps, expected))
    switches = [e for e in run.result.events if e.kind == "controller"]
    controllers = rec.json("/controller")
    assert [(c["from"], c["to"], c["reason"]) for c in controllers] == [
        (e.detail["from"], e.detail["to"], e.detail["reason"]) for e in switches
    ]
    assert "no guard holds" in controllers[0]["reason"]  # the guards' reason
    completed = [
        e["checkpoint"] for e in rec.json("/events") if e["event"] == "checkpoint-completed"
    ]
    assert completed == list(run.result.progress.completed) and completed
    assert len(rec.topics["/log"]) == len(rec.topics["/events"])
    assert any(b"go to CP1" in data for _, data in rec.topics["/log"])


def test_scans_are_recorded_at_the_lasers_rate_with_no_return_as_infinity(lab):
    run, rec = lab
    spec = run.scenario.mission.platform.lasers["front"]
    scans = rec.topics["/scan/front"]
    assert len(scans) == pytest.approx(spec.rate_hz * LAB_SECONDS, abs=2)  # no duplicate
    fields = _protobuf(scans[-1][1])
    ranges = np.frombuffer(fields[6][0], dtype="<f8")
    assert len(ranges) == spec.beam_count
    assert np.isinf(ranges).any() and np.isfinite(ranges).any()
    assert np.nanmax(ranges[np.isfinite(ranges)]) < spec.range
    assert fields[2][0] == b"base_link"  # in the robot frame, placed by the mount pose
    assert struct.unpack("<d", fields[4][0])[0] == pytest.approx(-spec.fov / 2)


def test_cameras_and_state_say_what_the_executive_saw(lab):
    run, rec = lab
    seen = [
        d
        for topic in OURS
        if topic.startswith("/camera/")
        for m in rec.json(topic)
        for d in m["detections"]
    ]
    assert seen and {"feature", "point", "u", "v"} <= set(seen[0])
    states = rec.json("/state")
    assert states[-1]["completed"] == len(run.result.progress.completed)
    assert {s["phase"] for s in states} >= {"approach", "inspection"}
    assert all(s["pose_a"] is not None for s in states[1:])
    assert rec.topics["/obstacles"]  # SceneUpdates in base_link
    assert b"base_link" in rec.topics["/obstacles"][-1][1]
    scene = rec.topics["/scene"][0][1]
    for entity in (b"aircraft", b"checkpoint/CP1", b"station", b"zone/"):
        assert entity in scene


def test_a_second_recording_in_the_process_gets_none_of_the_firsts_messages(lab, tmp_path):
    run, first = lab
    idle = Recorder.open(tmp_path / "idle.mcap", run.scenario.mission)
    second_path = tmp_path / "second.mcap"
    second_run = dry_run(load_scenario(LAB), max_time=3.0, record=second_path)
    idle.close()
    assert Recording(tmp_path / "idle.mcap").statistics.message_count == 0
    second = Recording(second_path)
    assert max(second.times("/tf")) <= 3.0
    assert len(second.topics["/tf"]) == len(second_run.result.stats.durations)
    assert second.statistics.message_count < first.statistics.message_count / 5


def test_a_recording_never_writes_through_a_link_and_resumed_runs_get_their_own(tmp_path):
    victim = tmp_path / "victim"
    victim.write_bytes(b"precious")
    (tmp_path / "run.mcap").symlink_to(victim)
    mission = load_scenario(LAB).mission
    Recorder.open(tmp_path / "run.mcap", mission).close()
    assert victim.read_bytes() == b"precious"
    assert not (tmp_path / "run.mcap").is_symlink()
    assert recording_path(tmp_path) == tmp_path / "run-2.mcap"
    (tmp_path / "run-2.mcap").write_bytes(b"")
    (tmp_path / "run-x.mcap").write_bytes(b"")
    assert recording_path(tmp_path) == tmp_path / "run-3.mcap"
    assert [p.name for p in recordings_in(tmp_path)] == ["run-2.mcap", "run.mcap"]


# -- the A320 (acceptance: its MCAP holds every topic for the whole run) -----------------------
def assert_whole_run_recorded(path: Path, duration: float) -> None:
    """A run's MCAP opens with the mcap reader and holds every topic, with Foxglove's
    schemas, from the start to the end (``duration``, s) of the run (tests/test_readme.py
    checks the README's main job, the whole A320 pre-flight, with this)."""
    rec = Recording(path)
    assert set(rec.topics) == set(WELL_KNOWN) | set(OURS)
    for topic, name in {**WELL_KNOWN, **OURS}.items():
        assert rec.schemas[topic][0] == name
    _assert_covers(rec, duration, PERIODIC)
    assert rec.statistics.message_end_time / 1e9 == pytest.approx(duration, abs=0.05)
    assert rec.json("/controller") and rec.json("/events")
    assert any(m["detections"] for m in rec.json("/camera/front-left/detections"))


# -- the live view --------------------------------------------------------------------------------
def test_a_live_client_gets_the_advertised_channels_and_the_ticks(tmp_path):
    mission = load_scenario(LAB).mission
    recorder = Recorder.open(None, mission)
    server = serve_live(recorder, "127.0.0.1", 0)
    runtime = SimpleNamespace(
        command=VelocityCommand(0.3, 0.1),
        controller="go to CP1",
        safety=SimpleNamespace(status=SafetyStatus()),
        events=[],
        clock=SimpleNamespace(now=lambda: 0.0),
    )
    try:
        with connect(f"ws://127.0.0.1:{server.port}", subprotocols=["foxglove.sdk.v1"]) as ws:
            advertised: dict[str, dict] = {}
            deadline = time.monotonic() + 10.0
            while "/command" not in advertised and time.monotonic() < deadline:
                message = json.loads(ws.recv(timeout=5.0))
                if message["op"] == "advertise":
                    advertised.update({c["topic"]: c for c in message["channels"]})
            assert set(WELL_KNOWN) | set(OURS) <= set(advertised)
            assert advertised["/tf"]["schemaName"] == "foxglove.FrameTransforms"
            command = advertised["/command"]
            ws.send(
                json.dumps(
                    {"op": "subscribe", "subscriptions": [{"id": 7, "channelId": command["id"]}]}
                )
            )
            got = None
            for k in range(200):
                frame = SensorFrame(stamp=0.02 * k)
                recorder.on_tick(0.02 * k, frame, VelocityCommand(0.25, 0.1), runtime)
                try:
                    data = ws.recv(timeout=0.05)
                except TimeoutError:
                    continue
                if isinstance(data, bytes) and data[0] == 1:  # message data
                    got = data
                    break
            assert got is not None, "no message data for the subscription"
            assert struct.unpack_from("<I", got, 1)[0] == 7
            assert json.loads(got[13:])["sent"]["v"] == 0.25
    finally:
        recorder.close()
    assert recorder.error is None and not recorder.servers


# -- the hand-encoded messages are the SDK's, byte for byte ---------------------------------------
@pytest.mark.parametrize(
    "pose", [Pose2(12.5, -3.25, 0.7), Pose2(0.0, 2.0, 0.0), Pose2(-1.0, 0.0, math.pi)]
)
@pytest.mark.parametrize("ns", [0, 999, 1_000_000_000, 1_700_000_123_456_789_012])
def test_hand_encoded_transforms_and_poses_are_the_sdks(pose, ns):
    stamp = Timestamp(ns // 10**9, ns % 10**9)
    ts = timestamp_field(ns)
    q = Quaternion(x=0.0, y=0.0, z=math.sin(pose.theta / 2), w=math.cos(pose.theta / 2))
    v = Vector3(x=pose.x, y=pose.y, z=0.0)
    expected = FrameTransform(
        timestamp=stamp,
        parent_frame_id="airport",
        child_frame_id="base_link",
        translation=v,
        rotation=q,
    ).encode()
    assert encode_planar_transform(ts, "airport", "base_link", pose) == expected
    expected = PoseInFrame(
        timestamp=stamp, frame_id="airport", pose=Pose(position=v, orientation=q)
    ).encode()
    assert encode_planar_pose(ts, "airport", pose) == expected


def test_hand_encoded_scans_are_the_sdks():
    rng = np.random.default_rng(3)
    ranges = rng.uniform(0.1, 30.0, 1081)
    ranges[::7] = 30.0  # no return
    scan = ScanRecord(1.5, -2.35, 0.0043, 30.0, ranges)
    pose = Pose(position=Vector3(x=0.65, y=0.0, z=0.35), orientation=Quaternion(w=1.0))
    encoder = ScanEncoder("base_link", pose)
    expected = LaserScan(
        timestamp=Timestamp(1, 500_000_000),
        frame_id="base_link",
        pose=pose,
        start_angle=-2.35,
        end_angle=-2.35 + 0.0043 * 1080,
        ranges=np.where(ranges < 30.0, ranges, np.inf).astype(np.float32).tolist(),
    ).encode()
    assert encoder.encode(1_500_000_000, scan) == expected
    batch = encoder.encode_many([(1_500_000_000, scan), (1_525_000_000, scan)])
    assert batch[0] == expected and len(batch[1]) == len(expected)


def test_quaternions_and_command_json():
    for rotation in Rotation.random(20, random_state=1):
        q = np.array(quaternion_of(rotation.as_matrix()))
        ref = rotation.as_quat()
        assert np.allclose(q, ref, atol=1e-9) or np.allclose(q, -ref, atol=1e-9)
    pose = Pose2(3.0, -1.0, 2.5)
    x, y, _, w = quaternion_of(airport_from_robot(pose).rotation)
    assert (x, y) == pytest.approx((0.0, 0.0)) and abs(w) == pytest.approx(math.cos(1.25))
    camera = robot_from_camera((0.5, 0.0, 1.2), 0.0, 0.3, -0.2, 0.15)
    q = quaternion_of(camera.rotation)
    assert np.allclose(Rotation.from_quat(q).as_matrix(), camera.rotation)
    placement = AircraftPlacement(10.0, 5.0, 1.2, 3.5)
    q = quaternion_of(placement.airport_from_aircraft().rotation)
    assert np.allclose(
        Rotation.from_quat(q).as_matrix(), placement.airport_from_aircraft().rotation
    )
    command = VelocityCommand(0.1 + 0.2, -1e-300)
    assert json.loads(velocity_json(command)) == {"v": 0.1 + 0.2, "omega": -1e-300, "pan_tilt": {}}
    assert json.loads(velocity_json(VelocityCommand(math.nan, math.inf)))["v"] is None


def _plain(value):
    return value.item() if isinstance(value, np.generic) else str(value)


def _protobuf(data: bytes) -> dict[int, list[bytes]]:
    """The fields of a protobuf message by number: length-delimited ones as their bytes,
    64-bit ones as their 8 bytes, varints as their value's 8 bytes (enough for tests)."""
    fields: dict[int, list[bytes]] = {}
    i = 0
    while i < len(data):
        key, i = _varint(data, i)
        number, wire = key >> 3, key & 7
        if wire == 2:
            size, i = _varint(data, i)
            value, i = data[i : i + size], i + size
        elif wire == 1:
            value, i = data[i : i + 8], i + 8
        elif wire == 0:
            n, i = _varint(data, i)
            value = n.to_bytes(8, "little")
        else:
            raise AssertionError(f"wire type {wire}")
        fields.setdefault(number, []).append(value)
    return fields


def _varint(data: bytes, i: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        b = data[i]
        i += 1
        value |= (b & 0x7F) << shift
        shift += 7
        if b < 0x80:
            return value, i


def test_the_shipped_layout_shows_recorded_topics(lab):
    _, rec = lab
    layout = json.loads((Path(__file__).parents[1] / "docs" / "foxglove-layout.json").read_text())
    panels = layout["configById"]
    used = set(panels["3D!walkaround"]["topics"])
    used |= {p["value"].split(".")[0] for p in panels["Plot!speed"]["paths"]}
    used |= {p["value"].split(".")[0] for p in panels["StateTransitions!modes"]["paths"]}
    used |= {panels["RosOut!log"]["topicToRender"], panels["RawMessages!command"]["topicPath"]}
    assert used <= set(rec.topics)
    assert panels["3D!walkaround"]["followTf"] == "airport"
    commands = rec.json("/command")
    assert all(isinstance(c["commanded"]["v"], float) for c in commands)  # what the plot reads


def test_a_robot_run_records_in_unix_time(tmp_path):
    from executive.dryrun import SimClock
    from executive.robotrun import robot_metrics, robot_run
    from sim2d.robot import SimRobot

    scenario = load_scenario(LAB)
    sim = SimRobot(scenario)
    path = tmp_path / "run.mcap"
    before = time.time()
    run = robot_run(scenario.mission, sim, clock=SimClock(sim), max_time=2.0, record=path)
    assert run.recording == path and run.recording_error is None
    assert robot_metrics(run)["recording"] == "run.mcap"
    rec = Recording(path)
    times = rec.times("/tf")
    assert len(times) == len(run.result.stats.durations)
    assert before - 1.0 <= times[0] <= time.time()  # Unix time, not the run clock
    assert times[-1] - times[0] == pytest.approx(2.0, abs=0.05)
