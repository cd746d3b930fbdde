"""Recording for Foxglove (issue 15): every dry-run and run as an MCAP file.

A :class:`Recorder` is a tick hook (:data:`executive.runtime.TickHook`): after every tick
it logs what the executive saw, believed and did on channels of its own
:class:`foxglove.Context`, which an MCAP writer (``foxglove.open_mcap``) and, for a live
view, a Foxglove WebSocket server (:func:`serve_live`) listen to. One context per
recording: two runs in one process (the tests run several) never see each other's
messages. Foxglove's well-known schemas (protobuf ``foxglove.*``) are used wherever one
fits, so Foxglove draws the recording without configuration; the rest is JSON with a JSON
schema. The topics, their schemas and rates are in ``docs/recording.md``; in short:
``/scene`` (once), ``/tf`` (every tick), ``/tf/sensors``, ``/pose``, ``/scan/<laser>``
(every scan), ``/obstacles``, ``/command`` (every tick: commanded and sent),
``/controller``, ``/events``, ``/log``, ``/camera/<camera>/detections`` and ``/state``.

Frames (:mod:`executive.core.frames`): ``airport`` (A, z up), ``aircraft`` (F, z down: the
transform is :meth:`AircraftPlacement.airport_from_aircraft` of the executive's current
estimate), ``base_link`` (R: :func:`airport_from_robot` of the estimated pose),
``laser_<id>`` and ``camera_<id>`` (ViSP axes, :func:`robot_from_camera`). Message times:
the run clock plus ``epoch`` (0 for a dry-run: the time line reads in simulated seconds,
as ``events.jsonl``; on the robot, the Unix time of the clock's zero).

Cost (aim: under 5 % of a dry-run's speed, BENCHMARKS.md): the recording runs in the tick
hook, after the tick's deadline was measured. Ticks are kept for :data:`BATCH_PERIOD` and
encoded together; what goes out every tick or every scan (transforms, poses, scans) is
written as protobuf bytes here, exactly as the SDK would (the tests compare the bytes),
because building the SDK's message objects field by field, or a 1081-element Python list
per scan, cost more than all the rest; slow-changing things are decimated (the periods
below). A failure to record (a full disk) never stops the robot: the recording ends and
:attr:`Recorder.error` says why.
"""

from __future__ import annotations

import functools
import json
import math
import struct
from collections.abc import Mapping
from pathlib import Path
from typing import Any, NamedTuple

import foxglove
import numpy as np
from foxglove.channels import (
    LogChannel,
    SceneUpdateChannel,
)
from foxglove.mcap import MCAPWriter
from foxglove.messages import (
    ArrowPrimitive,
    Color,
    CubePrimitive,
    CylinderPrimitive,
    FrameTransform,
    FrameTransforms,
    KeyValuePair,
    LaserScan,
    LinePrimitive,
    LinePrimitiveLineType,
    Log,
    LogLevel,
    Point3,
    Pose,
    PoseInFrame,
    Quaternion,
    SceneEntity,
    SceneEntityDeletion,
    SceneEntityDeletionType,
    SceneUpdate,
    SpherePrimitive,
    TextPrimitive,
    Timestamp,
    Vector3,
)
from foxglove.websocket import Capability, ChannelView, Client, ServerListener, WebSocketServer
from py_trees.blackboard import Blackboard

from behaviours.keys import OBSTACLES, POSE, PROGRESS, SERVO, Key, MissionProgress, ServoStatus
from executive import __version__
from executive.core.frames import (
    AircraftPlacement,
    FloatArray,
    Pose2,
    Transform3,
    robot_from_camera,
    rot_z,
)
from executive.core.geometry import to_shapely
from executive.core.model import CameraKind, Frame, Mission, Shape
from executive.core.records import (
    Danger,
    Obstacles,
    PoseEstimate,
    SensorFrame,
    TrackedObstacle,
    VelocityCommand,
    camera_ids,
)
from executive.core.records import LaserScan as ScanRecord
from executive.runtime import Event, RunResult, Runtime, TickHook
from executive.safety import SafetyStatus

AIRPORT_FRAME = "airport"
AIRCRAFT_FRAME = "aircraft"
ROBOT_FRAME = "base_link"

TOPIC_SCENE = "/scene"
TOPIC_TF = "/tf"
TOPIC_SENSOR_TF = "/tf/sensors"
TOPIC_POSE = "/pose"
TOPIC_OBSTACLES = "/obstacles"
TOPIC_COMMAND = "/command"
TOPIC_CONTROLLER = "/controller"
TOPIC_EVENTS = "/events"
TOPIC_LOG = "/log"
TOPIC_STATE = "/state"

SENSOR_TF_PERIOD = 0.2
"""Seconds between the sensor frames (lasers are fixed, the pan-tilt units move slowly)."""
PLACEMENT_STEP = (0.001, 1e-4)
"""Metres and radians the aircraft's estimated placement must move by for a new transform
(the pose filter nudges it every few ticks by far less than a millimetre)."""
POSE_PERIOD = 0.1
"""Seconds between pose records (the transform to base_link is in every tick's /tf)."""
OBSTACLE_PERIOD = 0.1
"""Seconds between obstacle updates: a person at 2 m/s moves 20 cm in between."""
STATE_PERIOD = 0.2
"""Seconds between executive state records."""
IDLE_CAMERA_PERIOD = 1.0
"""Seconds between the records of a camera that sees nothing (every image otherwise)."""
BATCH_PERIOD = 0.5
"""Seconds of ticks kept (by reference: records are immutable) and then encoded together:
encoding in a tight loop, with warm caches, costs half as much as between the ticks of
the simulator and the tree. A live view (:func:`serve_live`) encodes every tick."""

RECORDING_FILE = "run.mcap"
"""The recording's name in a run's report folder."""


def laser_frame(laser: str) -> str:
    return f"laser_{laser}"


def camera_frame(camera: str) -> str:
    return f"camera_{camera}"


def scan_topic(laser: str) -> str:
    return f"/scan/{laser}"


def camera_topic(camera: str) -> str:
    return f"/camera/{camera}/detections"


def recording_path(out: Path) -> Path:
    """The first free name of ``run.mcap``, ``run-2.mcap``, ... in ``out``: a resumed run
    keeps the recordings of the runs it continues (as ``can.blf``)."""
    path, k = out / RECORDING_FILE, 1
    while path.exists() or path.is_symlink():
        k += 1
        path = out / f"run-{k}.mcap"
    return path


def recordings_in(out: Path) -> list[Path]:
    """The recordings a new (not resumed) run replaces: ``run.mcap`` and ``run-N.mcap``."""
    found = [out / RECORDING_FILE] if (out / RECORDING_FILE).is_symlink() else []
    found += [p for p in out.glob("run*.mcap") if p.name == RECORDING_FILE or _numbered(p)]
    return sorted(set(found))


def _numbered(path: Path) -> bool:
    middle = path.name[len("run-") : -len(".mcap")]
    return path.name.startswith("run-") and middle.isdigit()


def chain(*hooks: TickHook | None) -> TickHook:
    """One tick hook calling each of ``hooks`` (None skipped) in order."""
    live = [h for h in hooks if h is not None]

    def on_tick(now: float, frame: SensorFrame, sent: VelocityCommand, runtime: Runtime) -> None:
        for hook in live:
            hook(now, frame, sent, runtime)

    return on_tick


# -- JSON schemas of the walkaround channels ------------------------------------------------------
_NUMBER = {"type": "number"}
_NULLABLE_NUMBER = {"type": ["number", "null"]}
_STRING = {"type": "string"}
_NULLABLE_STRING = {"type": ["string", "null"]}
_VELOCITY = {
    "type": "object",
    "properties": {
        "v": {"type": "number", "description": "forward speed (m/s)"},
        "omega": {"type": "number", "description": "yaw rate about +z of base_link (rad/s)"},
        "pan_tilt": {
            "type": "object",
            "description": "pan and tilt rates (rad/s) per pan-tilt unit",
            "additionalProperties": {
                "type": "object",
                "properties": {"pan": _NUMBER, "tilt": _NUMBER},
            },
        },
    },
}
_POSE2 = {
    "type": ["object", "null"],
    "properties": {"x": _NUMBER, "y": _NUMBER, "theta": _NUMBER},
}
COMMAND_SCHEMA: dict[str, Any] = {
    "title": "walkaround.Command",
    "description": "The tree's command and what the safety layer sent, each tick",
    "type": "object",
    "properties": {
        "t": {"type": "number", "description": "run clock (s)"},
        "controller": _STRING,
        "commanded": _VELOCITY,
        "sent": _VELOCITY,
    },
}
CONTROLLER_SCHEMA: dict[str, Any] = {
    "title": "walkaround.Controller",
    "description": "A switch of the active controller, with the guards' reason",
    "type": "object",
    "properties": {"t": _NUMBER, "from": _STRING, "to": _STRING, "reason": _STRING},
}
EVENT_SCHEMA: dict[str, Any] = {
    "title": "walkaround.Event",
    "description": "A mission event (as events.jsonl): t, event and its details",
    "type": "object",
    "properties": {"t": _NUMBER, "event": _STRING, "reason": _STRING},
    "additionalProperties": True,
}
DETECTIONS_SCHEMA: dict[str, Any] = {
    "title": "walkaround.Detections",
    "description": "The feature points of one camera image (pixels, u right, v down)",
    "type": "object",
    "properties": {
        "t": _NUMBER,
        "stamp": {"type": "number", "description": "the image's time (s)"},
        "camera": _STRING,
        "image": {"type": ["integer", "null"]},
        "detections": {
            "type": "array",
            "items": {
                "type": "object",
                "properties": {
                    "feature": _STRING,
                    "point": {"type": "integer"},
                    "u": _NUMBER,
                    "v": _NUMBER,
                },
            },
        },
    },
}
STATE_SCHEMA: dict[str, Any] = {
    "title": "walkaround.State",
    "description": "The executive's state: mission progress, pose estimate, safety layer",
    "type": "object",
    "properties": {
        "t": _NUMBER,
        "phase": _STRING,
        "checkpoint": _NULLABLE_STRING,
        "goal": _NULLABLE_STRING,
        "completed": {"type": "integer"},
        "controller": _STRING,
        "pose_a": _POSE2,
        "pose_f": _POSE2,
        "sigma_f": _NULLABLE_NUMBER,
        "confidence": _NULLABLE_NUMBER,
        "confidence_f": _NULLABLE_NUMBER,
        "reference": _NULLABLE_STRING,
        "closest": {"type": ["number", "null"], "description": "r_c (m)"},
        "tracks": {"type": "integer"},
        "safety": {
            "type": "object",
            "properties": {
                "estop_latched": {"type": "boolean"},
                "stopped_reason": _NULLABLE_STRING,
                "speed_scale": _NUMBER,
                "geofence_distance": _NULLABLE_NUMBER,
                "geofence_zone": _NULLABLE_STRING,
                "forced_stop": {"type": "boolean"},
            },
        },
        "servo": {"type": ["object", "null"]},
    },
}


# -- small conversions ----------------------------------------------------------------------------
def quaternion_of(rotation: FloatArray) -> tuple[float, float, float, float]:
    """The unit quaternion (x, y, z, w) of a 3x3 rotation matrix (Shepperd's method)."""
    m = rotation
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    if trace > 0.0:
        s = math.sqrt(trace + 1.0) * 2.0
        w, x = 0.25 * s, (m[2, 1] - m[1, 2]) / s
        y, z = (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2]) * 2.0
        w, x = (m[2, 1] - m[1, 2]) / s, 0.25 * s
        y, z = (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s
    elif m[1, 1] > m[2, 2]:
        s = math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2]) * 2.0
        w, x = (m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s
        y, z = 0.25 * s, (m[1, 2] + m[2, 1]) / s
    else:
        s = math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1]) * 2.0
        w, x = (m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s
        y, z = (m[1, 2] + m[2, 1]) / s, 0.25 * s
    return float(x), float(y), float(z), float(w)


def _yaw(theta: float) -> Quaternion:
    """The rotation ``rot_z(theta)`` as a quaternion (closed form: this runs every tick)."""
    return Quaternion(x=0.0, y=0.0, z=math.sin(theta / 2.0), w=math.cos(theta / 2.0))


def _quaternion(rotation: FloatArray) -> Quaternion:
    x, y, z, w = quaternion_of(rotation)
    return Quaternion(x=x, y=y, z=z, w=w)


def _vector(v: FloatArray | tuple[float, ...]) -> Vector3:
    return Vector3(x=float(v[0]), y=float(v[1]), z=float(v[2]))


def _planar_pose(x: float, y: float, z: float, theta: float) -> Pose:
    return Pose(position=Vector3(x=x, y=y, z=z), orientation=_yaw(theta))


def _stamp(ns: int) -> Timestamp:
    return Timestamp(ns // 1_000_000_000, ns % 1_000_000_000)


def _finite(value: float | None, digits: int = 4) -> float | None:
    """A JSON-safe number: None for None, inf and NaN."""
    if value is None or not math.isfinite(value):
        return None
    return round(value, digits)


def _number(x: float) -> str:
    """A float as JSON (``repr`` is exact and valid JSON when finite), null otherwise."""
    return repr(float(x)) if math.isfinite(x) else "null"


@functools.lru_cache(maxsize=256)
def _quoted(name: str) -> str:
    """A name as a JSON string (ids come from the mission: a few, used every tick)."""
    return json.dumps(name)


@functools.lru_cache(maxsize=4096)
def _point_json(feature: str, point: int) -> str:
    """The start of a detection's JSON, up to its pixel coordinates."""
    return f'{{"feature":{json.dumps(feature)},"point":{int(point)},'


def velocity_json(command: VelocityCommand) -> str:
    """A command as the JSON of the ``walkaround.Command`` schema's velocities."""
    rates = command.pan_tilt.items()
    text = ",".join(
        f'{_quoted(u)}:{{"pan":{float(r.pan)!r},"tilt":{float(r.tilt)!r}}}' for u, r in rates
    )
    out = f'{{"v":{float(command.v)!r},"omega":{float(command.omega)!r},"pan_tilt":{{{text}}}}}'
    if "nan" in out or "inf" in out:  # not JSON (or in a unit's name): null for those
        text = ",".join(
            f'{_quoted(u)}:{{"pan":{_number(r.pan)},"tilt":{_number(r.tilt)}}}' for u, r in rates
        )
        out = f'{{"v":{_number(command.v)},"omega":{_number(command.omega)},"pan_tilt":{{{text}}}}}'
    return out


def _read(key: Key) -> object:
    """A blackboard entry, None when not written yet. The recording is introspection, read
    after the tick: straight from py_trees' storage, as its ``Blackboard.get`` does
    without the client's access bookkeeping (~4 us a read through
    :meth:`Runtime._get`, a tenth of the recording's cost per tick)."""
    return Blackboard.storage.get(key.name)


def _protobuf_channel(topic: str, message: Any, context: foxglove.Context) -> Any:
    """A channel with the schema of a Foxglove message type, logged as bytes encoded here
    (the same schema and encoding as the SDK's typed channel for that type)."""
    channel = foxglove.Channel(
        topic, schema=message.get_schema(), message_encoding="protobuf", context=context
    )
    return channel.base


def _plain(value: object) -> object:
    """JSON for what ``json`` does not know: numpy scalars as numbers, the rest as text."""
    return value.item() if isinstance(value, np.generic) else str(value)


def _pose_json(pose: Pose2 | None) -> dict[str, float] | None:
    if pose is None:
        return None
    return {"x": round(pose.x, 4), "y": round(pose.y, 4), "theta": round(pose.theta, 5)}


# -- protobuf by hand, for what is logged every tick ----------------------------------------------
# Building the SDK's message objects costs microseconds per field; these few messages go out
# every tick or every scan, so their bytes are written directly, exactly as the SDK would
# write them (proto3: fields in order, zero values left out; tests compare the bytes).
_BYTES = [bytes((k,)) for k in range(0x80)]


def _varint(n: int) -> bytes:
    if n < 0x80:
        return _BYTES[n]
    out = bytearray()
    while n >= 0x80:
        out.append((n & 0x7F) | 0x80)
        n >>= 7
    out.append(n)
    return bytes(out)


def _field(key: int, body: bytes) -> bytes:
    """A length-delimited field (a message, a string, a packed array)."""
    return _BYTES[key] + _varint(len(body)) + body


@functools.lru_cache(maxsize=4)
def _seconds(sec: int) -> bytes:
    return b"\x08" + _varint(sec) if sec else b""


def timestamp_field(ns: int) -> bytes:
    """Field 1 ``google.protobuf.Timestamp timestamp`` of a message, for ``ns >= 0``."""
    sec, nsec = divmod(ns, 1_000_000_000)
    inner = _seconds(sec) + (b"\x10" + _varint(nsec) if nsec else b"")
    return b"\x0a" + _BYTES[len(inner)] + inner


_XY = struct.Struct("<BdBd")
_X, _Y, _Z, _W = 1 << 3 | 1, 2 << 3 | 1, 3 << 3 | 1, 4 << 3 | 1
"""Keys of the double fields x, y, z, w (Vector3, Quaternion)."""
_TRANSLATION_XY = _field(4 << 3 | 2, _XY.pack(_X, 0.0, _Y, 0.0))[:2]
_ROTATION_ZW = _field(5 << 3 | 2, _XY.pack(_Z, 0.0, _W, 0.0))[:2]
_POSITION_XY = _field(1 << 3 | 2, _XY.pack(_X, 0.0, _Y, 0.0))[:2]
_ORIENTATION_ZW = _field(2 << 3 | 2, _XY.pack(_Z, 0.0, _W, 0.0))[:2]
_PLANAR_POSE_SIZE = 2 * (2 + _XY.size)


def encode_planar_transform(ts: bytes, parent: str, child: str, pose: Pose2) -> bytes:
    """``foxglove.FrameTransform`` parent <- child at ``ts`` (:func:`timestamp_field`) for a
    pose on the ground plane (the transform of
    :func:`executive.core.frames.airport_from_robot`: ``rot_z(theta)``, (x, y, 0))."""
    s, c = math.sin(pose.theta / 2.0), math.cos(pose.theta / 2.0)
    if not (pose.x and pose.y and s and c):  # a zero field: proto3 leaves it out
        return (
            ts
            + FrameTransform(  # fields 2-5 after the time stamp (field 1)
                parent_frame_id=parent,
                child_frame_id=child,
                translation=Vector3(x=pose.x, y=pose.y, z=0.0),
                rotation=Quaternion(x=0.0, y=0.0, z=s, w=c),
            ).encode()
        )
    return b"".join(
        (
            ts,
            _field(2 << 3 | 2, parent.encode()),
            _field(3 << 3 | 2, child.encode()),
            _TRANSLATION_XY,
            _XY.pack(_X, pose.x, _Y, pose.y),
            _ROTATION_ZW,
            _XY.pack(_Z, s, _W, c),
        )
    )


def encode_planar_pose(ts: bytes, frame_id: str, pose: Pose2) -> bytes:
    """``foxglove.PoseInFrame`` at ``ts`` of a pose on the ground plane of ``frame_id``."""
    s, c = math.sin(pose.theta / 2.0), math.cos(pose.theta / 2.0)
    if not (pose.x and pose.y and s and c):
        return (
            ts
            + PoseInFrame(
                frame_id=frame_id, pose=_planar_pose(pose.x, pose.y, 0.0, pose.theta)
            ).encode()
        )
    return b"".join(
        (
            ts,
            _field(2 << 3 | 2, frame_id.encode()),
            bytes((3 << 3 | 2, _PLANAR_POSE_SIZE)),
            _POSITION_XY,
            _XY.pack(_X, pose.x, _Y, pose.y),
            _ORIENTATION_ZW,
            _XY.pack(_Z, s, _W, c),
        )
    )


def _transform_body(parent: str, child: str, transform: Transform3) -> bytes:
    """A ``foxglove.FrameTransform`` parent <- child but its time stamp: fields 2-5, to
    follow :func:`timestamp_field` (field 1)."""
    return FrameTransform(
        parent_frame_id=parent,
        child_frame_id=child,
        translation=_vector(transform.translation),
        rotation=_quaternion(transform.rotation),
    ).encode()


def encode_transforms(transforms: list[bytes]) -> bytes:
    """``foxglove.FrameTransforms`` of encoded ``FrameTransform`` messages."""
    return b"".join(_field(1 << 3 | 2, t) for t in transforms)


class ScanEncoder:
    """A laser's scans as ``foxglove.LaserScan`` in ``frame_id``, placed by ``pose`` (the
    laser's mount). The header but the time stamp is encoded once by the SDK; the ranges
    follow as one packed field of little-endian doubles straight from numpy, for a whole
    batch of scans at once. A beam with no return (``range_max``) is +inf, the usual
    "nothing within range", which Foxglove does not draw. The ranges are rounded to single
    precision (2 um at 30 m, a five-hundredth of the scanner's millimetre): the doubles'
    last 29 bits are then zero, and zstd packs a scan into half the bytes."""

    def __init__(self, frame_id: str, pose: Pose) -> None:
        self.frame_id = frame_id
        self.pose = pose
        self._heads: dict[tuple[float, float, int], bytes] = {}

    def _head(self, scan: ScanRecord, n: int) -> bytes:
        """Fields 2-5: frame, pose, start and end angles."""
        key = (scan.angle_min, scan.angle_increment, n)
        head = self._heads.get(key)
        if head is None:
            head = self._heads[key] = LaserScan(
                frame_id=self.frame_id,
                pose=self.pose,
                start_angle=scan.angle_min,
                end_angle=scan.angle_min + scan.angle_increment * max(n - 1, 0),
            ).encode()
        return head

    def encode(self, ns: int, scan: ScanRecord) -> bytes:
        return self.encode_many([(ns, scan)])[0]

    def encode_many(self, scans: list[tuple[int, ScanRecord]]) -> list[bytes]:
        """The messages of ``(ns, scan)`` pairs, in order."""
        n = len(scans[0][1].ranges)
        if any(len(scan.ranges) != n for _, scan in scans):  # not one array: one by one
            return [m for item in scans for m in self.encode_many([item])]
        ranges = np.array([scan.ranges for _, scan in scans], dtype=float).reshape(-1, n)
        limits = np.array([[scan.range_max] for _, scan in scans], dtype=float)
        kept = np.where(ranges < limits, ranges, np.inf).astype(np.float32)  # see the class
        data = memoryview(kept.astype("<f8").tobytes())
        size = 8 * n
        key = bytes((6 << 3 | 2,)) + _varint(size)
        return [
            b"".join(
                (timestamp_field(ns), self._head(scan, n))
                + ((key, data[k * size : (k + 1) * size]) if n else ())
            )
            for k, (ns, scan) in enumerate(scans)
        ]


# -- the static scene -----------------------------------------------------------------------------
_AIRCRAFT_COLOR = Color(r=0.35, g=0.65, b=1.0, a=1.0)
_OUTLINE_COLOR = Color(r=0.55, g=0.7, b=0.85, a=0.8)
_ZONE_COLOR = Color(r=0.95, g=0.2, b=0.2, a=1.0)
_GEOFENCE_COLOR = Color(r=1.0, g=0.6, b=0.1, a=0.9)
_CHECKPOINT_COLOR = Color(r=0.2, g=0.85, b=0.35, a=1.0)
_ROUTE_COLOR = Color(r=0.8, g=0.8, b=0.8, a=1.0)
_TEXT_COLOR = Color(r=1.0, g=1.0, b=1.0, a=1.0)
_DANGER_COLORS = {
    Danger.NONE: Color(r=0.3, g=0.8, b=1.0, a=0.7),
    Danger.NEAR: Color(r=1.0, g=0.85, b=0.2, a=0.8),
    Danger.ON_PATH: Color(r=1.0, g=0.5, b=0.1, a=0.85),
    Danger.IMMINENT: Color(r=1.0, g=0.1, b=0.1, a=0.9),
}
_ZONE_TRACK_COLOR = Color(r=0.6, g=0.3, b=0.3, a=0.35)
_OBSTACLE_HEIGHT = 1.0
_LIFT = 0.02
"""Lines are drawn this far (m) above the ground so the ground grid does not hide them."""


def _ring(points: FloatArray, z: float) -> list[Point3]:
    return [Point3(x=float(x), y=float(y), z=z) for x, y in points]


def _loop(points: FloatArray, z: float, color: Color, thickness: float) -> LinePrimitive:
    return LinePrimitive(
        type=LinePrimitiveLineType.LineLoop,
        points=_ring(points, z),
        color=color,
        thickness=thickness,
    )


def _label(x: float, y: float, z: float, text: str) -> TextPrimitive:
    return TextPrimitive(
        pose=_planar_pose(x, y, z, 0.0),
        billboard=True,
        font_size=13.0,
        scale_invariant=True,
        color=_TEXT_COLOR,
        text=text,
    )


def _shape_points(shape: Shape) -> FloatArray:
    return shape.vertices(48)


def static_scene(mission: Mission, stamp: Timestamp) -> SceneUpdate:
    """The mission's fixed things, each in the frame it is given in: the aircraft's
    footprint, outline and checkpoints in ``aircraft`` (so they sit where the executive
    believes the aircraft stands), forbidden zones with their geofence margin and the
    route in their own frame, the charging station in ``airport``."""
    aircraft = mission.aircraft
    ground_f = aircraft.origin_height - _LIFT  # z_F points down: the ground is +origin_height

    def z_of(frame: Frame) -> float:
        return ground_f if frame is Frame.AIRCRAFT else _LIFT

    def frame_of(frame: Frame) -> str:
        return AIRCRAFT_FRAME if frame is Frame.AIRCRAFT else AIRPORT_FRAME

    entities = [
        SceneEntity(
            timestamp=stamp,
            frame_id=AIRCRAFT_FRAME,
            id="aircraft",
            frame_locked=True,
            metadata=[
                KeyValuePair(key="type", value=aircraft.type),
                KeyValuePair(key="mission", value=mission.id),
            ],
            lines=[
                _loop(_shape_points(s), ground_f, _AIRCRAFT_COLOR, 0.08) for s in aircraft.footprint
            ]
            + [_loop(_shape_points(s), ground_f, _OUTLINE_COLOR, 0.03) for s in aircraft.outline],
        )
    ]
    margin = mission.safety.geofence_margin
    for zone in mission.airport.zones:
        z = z_of(zone.frame)
        points = _shape_points(zone.shape)
        fence = to_shapely(zone.shape).buffer(margin, quad_segs=8)
        lines = [_loop(points, z, _ZONE_COLOR, 0.1)]
        if not fence.is_empty and fence.geom_type == "Polygon":
            ring = np.asarray(fence.exterior.coords, dtype=float)[:-1]
            lines.append(_loop(ring, z, _GEOFENCE_COLOR, 0.04))
        cx, cy = points.mean(axis=0)
        entities.append(
            SceneEntity(
                timestamp=stamp,
                frame_id=frame_of(zone.frame),
                id=f"zone/{zone.id}",
                frame_locked=True,
                metadata=[
                    KeyValuePair(key="kind", value=str(zone.kind)),
                    KeyValuePair(key="geofence_margin_m", value=f"{margin:g}"),
                ],
                lines=lines,
                texts=[_label(float(cx), float(cy), z, f"{zone.id} ({zone.kind})")],
            )
        )
    for cp in mission.checkpoints:
        p = cp.pose
        entities.append(
            SceneEntity(
                timestamp=stamp,
                frame_id=AIRCRAFT_FRAME,
                id=f"checkpoint/{cp.id}",
                frame_locked=True,
                metadata=[
                    KeyValuePair(key="name", value=cp.name),
                    KeyValuePair(key="items", value=" ".join(cp.items)),
                    KeyValuePair(key="target", value=cp.target or ""),
                ],
                # heading in F turns from +x_F towards +y_F: about +z_F
                arrows=[
                    ArrowPrimitive(
                        pose=_planar_pose(p.x, p.y, ground_f, p.theta),
                        shaft_length=0.6,
                        shaft_diameter=0.08,
                        head_length=0.25,
                        head_diameter=0.2,
                        color=_CHECKPOINT_COLOR,
                    )
                ],
                texts=[_label(p.x, p.y, ground_f - 0.5, cp.id)],
            )
        )
    route = (*mission.approach, mission.handover, *mission.return_route)
    for k, wp in enumerate(route):
        z = z_of(wp.frame)
        entities.append(
            SceneEntity(
                timestamp=stamp,
                frame_id=frame_of(wp.frame),
                id=f"route/{k}/{wp.id}",
                frame_locked=True,
                spheres=[
                    SpherePrimitive(
                        pose=_planar_pose(wp.x, wp.y, z, 0.0),
                        size=Vector3(x=0.25, y=0.25, z=0.25),
                        color=_ROUTE_COLOR,
                    )
                ],
                texts=[
                    _label(wp.x, wp.y, z + (-0.4 if wp.frame is Frame.AIRCRAFT else 0.4), wp.id)
                ],
            )
        )
    station = mission.airport.station
    entities.append(
        SceneEntity(
            timestamp=stamp,
            frame_id=AIRPORT_FRAME,
            id="station",
            frame_locked=True,
            cubes=[
                CubePrimitive(
                    pose=_planar_pose(station.x, station.y, 0.25, station.theta),
                    size=Vector3(x=0.8, y=0.6, z=0.5),
                    color=_ROUTE_COLOR,
                )
            ],
            texts=[_label(station.x, station.y, 0.9, "station")],
        )
    )
    return SceneUpdate(entities=entities)


def obstacle_scene(obstacles: Obstacles, stamp: Timestamp) -> SceneUpdate:
    """The tracked obstacles in ``base_link`` at their stamp: a cylinder (or a segment for a
    line) coloured by danger, an arrow for the ground velocity (its length: one second of
    motion), the track's figures as metadata. Each update replaces the previous one."""
    entities = [_track_entity(track, stamp) for track in obstacles.tracks]
    return SceneUpdate(
        deletions=[SceneEntityDeletion(timestamp=stamp, type=SceneEntityDeletionType.All)],
        entities=entities,
    )


def _track_entity(track: TrackedObstacle, stamp: Timestamp) -> SceneEntity:
    x, y = track.position
    vx, vy = track.velocity
    zone = track.kind == "zone"
    color = _ZONE_TRACK_COLOR if zone else _DANGER_COLORS.get(track.danger, _ZONE_COLOR)
    half = _OBSTACLE_HEIGHT / 2.0
    cylinders: list[CylinderPrimitive] = []
    lines: list[LinePrimitive] = []
    if track.kind == "line" and len(track.shape) == 4:
        x0, y0, x1, y1 = track.shape
        lines.append(
            LinePrimitive(
                type=LinePrimitiveLineType.LineStrip,
                points=[Point3(x=x0, y=y0, z=half), Point3(x=x1, y=y1, z=half)],
                color=color,
                thickness=0.12,
            )
        )
    else:
        d = 2.0 * max(track.size, 0.05)
        cylinders.append(
            CylinderPrimitive(
                pose=_planar_pose(x, y, half, 0.0),
                size=Vector3(x=d, y=d, z=_OBSTACLE_HEIGHT),
                bottom_scale=1.0,
                top_scale=1.0,
                color=color,
            )
        )
    speed = track.speed
    arrows = []
    if speed > 0.05 and not zone:
        arrows.append(
            ArrowPrimitive(
                pose=_planar_pose(x, y, _OBSTACLE_HEIGHT + 0.05, math.atan2(vy, vx)),
                shaft_length=speed,
                shaft_diameter=0.05,
                head_length=0.15,
                head_diameter=0.12,
                color=color,
            )
        )
    texts = []
    if not zone:
        texts.append(_label(x, y, _OBSTACLE_HEIGHT + 0.4, f"#{track.id} {speed:.1f} m/s"))
    return SceneEntity(
        timestamp=stamp,
        frame_id=ROBOT_FRAME,
        id=f"track/{track.id}",
        metadata=[
            KeyValuePair(key="kind", value=track.kind),
            KeyValuePair(key="velocity", value=f"({vx:.2f}, {vy:.2f}) m/s"),
            KeyValuePair(key="danger", value=track.danger.name.lower()),
            KeyValuePair(
                key="figures",
                value=f"clearance {track.clearance:.2f} m, size {track.size:.2f} m, "
                f"age {track.age:.1f} s",
            ),
        ],
        cylinders=cylinders,
        lines=lines,
        arrows=arrows,
        texts=texts,
    )


# -- events ---------------------------------------------------------------------------------------
_ERROR_KINDS = {"fault", "link-lost", "mission-failed"}
_WARNING_KINDS = {"interrupted", "aborted", "checkpoint-uncertain"}
_SAFETY_ERRORS = {"fault-stop", "estop-latched", "geofence-stop"}
_SAFETY_INFO = {
    "estop-released",
    "estop-reset",
    "sensor-fresh",
    "sensor-recovered",
    "slowdown-end",
    "geofence-clear",
    "limit-end",
}


def _level(event: Event) -> LogLevel:
    kind = event.kind
    if kind in _ERROR_KINDS:
        return LogLevel.Error
    if kind in _WARNING_KINDS:
        return LogLevel.Warning
    if kind == "safety":
        sub = str(event.detail.get("kind", ""))
        if sub in _SAFETY_ERRORS:
            return LogLevel.Error
        return LogLevel.Info if sub in _SAFETY_INFO else LogLevel.Warning
    if kind == "registration" and not event.detail.get("accepted", True):
        return LogLevel.Warning
    return LogLevel.Info


def _summary(event: Event) -> str:
    d = event.detail
    if event.kind == "controller":
        reason = f": {d['reason']}" if d.get("reason") else ""
        return f"{d.get('from')} -> {d.get('to')}{reason}"
    if event.kind == "safety":
        return f"{d.get('kind')}: {d.get('reason')}"
    if "reason" in d and len(d) == 1:
        return str(d["reason"])
    return ", ".join(f"{k}={v}" for k, v in d.items())


class _Tick(NamedTuple):
    """What one tick leaves to record, as the runtime had it after the tick."""

    now: float
    frame: SensorFrame
    sent: VelocityCommand
    command: VelocityCommand
    controller: str
    pose: object
    obstacles: object
    progress: object
    servo: object
    safety: SafetyStatus
    events: int
    """How many events the runtime had."""


# -- the recorder ---------------------------------------------------------------------------------
class Recorder:
    """Logs a run to the channels of its own Foxglove context (see the module docstring).

    Use :meth:`open` to record to an MCAP file (or to nothing but a live server), pass
    :meth:`on_tick` to the runtime (:func:`chain` it after the other hooks), and call
    :meth:`close` once the run returned, with the runtime: the events the runtime added
    after its last tick (the mission's end, an interruption) are recorded then.
    """

    def __init__(
        self,
        mission: Mission,
        *,
        context: foxglove.Context | None = None,
        placement: AircraftPlacement | None = None,
        epoch: float = 0.0,
        batch: float = BATCH_PERIOD,
    ) -> None:
        self.mission = mission
        self.batch = batch
        """Seconds of ticks encoded together (0: every tick; see :data:`BATCH_PERIOD`)."""
        self.context = context if context is not None else foxglove.Context()
        self.placement = placement or mission.nominal_placement()
        self.epoch_ns = round(epoch * 1e9)
        self.path: Path | None = None
        self.writer: MCAPWriter | None = None
        self.servers: list[WebSocketServer] = []
        self.error: str | None = None
        """Why the recording stopped early (it never stops the run), or None."""
        self.closed = False
        ctx = self.context
        self._scene = SceneUpdateChannel(TOPIC_SCENE, context=ctx)
        self._tf = _protobuf_channel(TOPIC_TF, FrameTransforms, ctx)
        self._sensor_tf = _protobuf_channel(TOPIC_SENSOR_TF, FrameTransforms, ctx)
        self._pose = _protobuf_channel(TOPIC_POSE, PoseInFrame, ctx)
        self._obstacles = SceneUpdateChannel(TOPIC_OBSTACLES, context=ctx)
        self._log = LogChannel(TOPIC_LOG, context=ctx)
        self._command = foxglove.Channel(TOPIC_COMMAND, schema=COMMAND_SCHEMA, context=ctx)
        self._controller = foxglove.Channel(TOPIC_CONTROLLER, schema=CONTROLLER_SCHEMA, context=ctx)
        self._events = foxglove.Channel(TOPIC_EVENTS, schema=EVENT_SCHEMA, context=ctx)
        self._state = foxglove.Channel(TOPIC_STATE, schema=STATE_SCHEMA, context=ctx)
        platform = mission.platform
        self._lasers: dict[str, tuple[Any, ScanEncoder]] = {}
        """laser id -> (channel, encoder)."""
        self._laser_tf: list[bytes] = []
        """base_link <- laser_<id>, encoded but the time stamp."""
        for lid, spec in platform.lasers.items():
            mount = Transform3(rot_z(spec.mount_yaw), np.array(spec.mount, dtype=float))
            channel = _protobuf_channel(scan_topic(lid), LaserScan, ctx)
            pose = Pose(
                position=_vector(mount.translation), orientation=_quaternion(mount.rotation)
            )
            self._lasers[lid] = (channel, ScanEncoder(ROBOT_FRAME, pose))
            self._laser_tf.append(_transform_body(ROBOT_FRAME, laser_frame(lid), mount))
        self._cameras: dict[str, tuple[Any, str, float]] = {}
        """camera id -> (channel, pan-tilt unit, lateral offset along the unit's left)."""
        for unit, spec in platform.cameras.items():
            ids = camera_ids(platform, unit)
            half = (spec.baseline or 0.0) / 2.0 if spec.kind is CameraKind.STEREO else 0.0
            laterals = (half, -half) if len(ids) == 2 else (0.0,)
            for camera, lateral in zip(ids, laterals, strict=True):
                channel = foxglove.Channel(
                    camera_topic(camera), schema=DETECTIONS_SCHEMA, context=ctx
                )
                self._cameras[camera] = (channel, unit, lateral)
        self._channels: list[Any] = [
            self._scene,
            self._tf,
            self._sensor_tf,
            self._pose,
            self._obstacles,
            self._log,
            self._command,
            self._controller,
            self._events,
            self._state,
            *(laser[0] for laser in self._lasers.values()),
            *(c for c, _, _ in self._cameras.values()),
        ]
        self._pending: list[_Tick] = []
        self._started = False
        self._resend_scene = False
        self._runtime: Runtime | None = None
        self._events_seen = 0
        self._scan_stamps: dict[str, float] = {}
        self._image_stamps: dict[str, float] = {}
        self._aircraft_tf: tuple[AircraftPlacement, bytes] | None = None
        self._camera_tf: dict[str, tuple[float, float, bytes]] = {}
        self._image_logged: dict[str, tuple[float, bool]] = {}
        self._next_sensor_tf = -math.inf
        self._next_pose = -math.inf
        self._next_obstacles = -math.inf
        self._next_state = -math.inf
        self._progress: MissionProgress | None = None
        self._controller_name = ""
        self._controller_json = json.dumps("")

    # -- opening and closing ----------------------------------------------------------------------
    @classmethod
    def open(
        cls,
        path: Path | None,
        mission: Mission,
        *,
        placement: AircraftPlacement | None = None,
        epoch: float = 0.0,
        metadata: Mapping[str, str] | None = None,
        allow_overwrite: bool = True,
    ) -> Recorder:
        """A recorder writing to the MCAP file ``path``, created anew (zstd chunks; an
        existing file or link is replaced when ``allow_overwrite``, else it is an error;
        None: no file, for a live view only). Raises :class:`OSError` when the file cannot
        be created. ``placement`` is the executive's first estimate of where the
        aircraft stands (default: the mission's nominal parking pose), ``epoch`` the Unix
        time of the run clock's zero (0: log times are run-clock seconds); ``metadata`` is
        written in the file's ``walkaround`` metadata record."""
        recorder = cls(mission, placement=placement, epoch=epoch)
        if path is not None:
            recorder.path = path = Path(path)
            if allow_overwrite and (path.is_symlink() or path.is_file()):
                path.unlink()  # a link is replaced, never written through
            recorder.writer = foxglove.open_mcap(path, context=recorder.context)
            info = {
                "mission": mission.id,
                "mission_file": mission.source,
                "aircraft": mission.aircraft.type,
                "walkaround": __version__,
                "frames": "airport (A, z up), aircraft (F, z down), base_link (R, z up)",
                "time": "log time = run clock (s) + epoch",
                "epoch_ns": str(recorder.epoch_ns),
                **(metadata or {}),
            }
            recorder.writer.write_metadata("walkaround", {k: str(v) for k, v in info.items()})
        return recorder

    def close(self, runtime: Runtime | None = None, result: RunResult | None = None) -> None:
        """Record the events the runtime added after its last tick, the outcome
        (``result``, as the file's ``outcome`` metadata record), finish the file and stop
        the live servers. A second call does nothing."""
        if self.closed:
            return
        self.closed = True
        runtime = runtime or self._runtime
        try:
            if runtime is not None and self.error is None:
                self._runtime = runtime
                self._flush()
                now = runtime.clock.now()
                self._record_events(now, len(runtime.events), _read(PROGRESS))
            if result is not None and self.writer is not None:
                self._write_outcome(result)
        except Exception as exc:  # the end of the recording is lost, never the run
            self.error = self.error or f"recording failed at its end: {exc!r}"
        self._finish()

    def _write_outcome(self, result: RunResult) -> None:
        assert self.writer is not None
        self.writer.write_metadata(
            "outcome",
            {
                "outcome": result.outcome,
                "reason": result.reason,
                "duration_s": f"{result.duration:.3f}",
                "completed": " ".join(result.progress.completed),
            },
        )

    def _finish(self) -> None:
        for server in self.servers:
            server.stop()
        self.servers.clear()
        for channel in self._channels:
            channel.close()
        self._channels.clear()
        writer, self.writer = self.writer, None
        if writer is not None:
            try:
                writer.close()
            except Exception as exc:
                self.error = self.error or f"the recording could not be finished: {exc!r}"

    # -- per tick ---------------------------------------------------------------------------------
    def on_tick(
        self, now: float, frame: SensorFrame, sent: VelocityCommand, runtime: Runtime
    ) -> None:
        """The tick hook: keeps the tick (:class:`_Tick`), records the batch when it is
        :attr:`batch` seconds long. Never raises: a failure ends the recording, not the run."""
        if self.closed:
            return
        self._runtime = runtime
        pending = self._pending
        pending.append(
            _Tick(
                now,
                frame,
                sent,
                runtime.command,
                runtime.controller,
                _read(POSE),
                _read(OBSTACLES),
                _read(PROGRESS),
                _read(SERVO),
                runtime.safety.status,
                len(runtime.events),
            )
        )
        if now - pending[0].now >= self.batch:
            try:
                self._flush()
            except Exception as exc:
                self.error = f"recording stopped at {now:.1f} s: {exc!r}"
                self.closed = True
                self._pending.clear()
                self._finish()

    def _ns(self, t: float) -> int:
        return max(self.epoch_ns + round(t * 1e9), 0)

    def _flush(self) -> None:
        ticks, self._pending = self._pending, []
        for tick in ticks:
            self._record(tick)
        self._record_scans(ticks)

    def _record(self, tick: _Tick) -> None:
        now = tick.now
        ns = self._ns(now)
        stamp = _stamp(ns)
        if not self._started or self._resend_scene:
            self._started, self._resend_scene = True, False
            self._scene.log(static_scene(self.mission, stamp), log_time=ns)
            self._next_sensor_tf = -math.inf
        for server in self.servers:
            server.broadcast_time(ns)
        pose = tick.pose if isinstance(tick.pose, PoseEstimate) else None
        self._record_tf(now, ns, pose)
        if now >= self._next_sensor_tf:
            self._next_sensor_tf = now + SENSOR_TF_PERIOD - 1e-9
            self._record_sensor_tf(ns, tick.frame)
        self._record_cameras(now, tick.frame)
        self._record_events(now, tick.events, tick.progress)
        if tick.controller != self._controller_name:
            self._controller_name = tick.controller
            self._controller_json = json.dumps(tick.controller)
        self._command.base.log(
            (
                f'{{"t":{now:.3f},"controller":{self._controller_json},'
                f'"commanded":{velocity_json(tick.command)},'
                f'"sent":{velocity_json(tick.sent)}}}'
            ).encode(),
            ns,
        )
        obstacles = tick.obstacles if isinstance(tick.obstacles, Obstacles) else None
        if obstacles is not None and now >= self._next_obstacles:
            self._next_obstacles = now + OBSTACLE_PERIOD - 1e-9
            self._obstacles.log(obstacle_scene(obstacles, stamp), log_time=ns)
        if now >= self._next_state:
            self._next_state = now + STATE_PERIOD - 1e-9
            self._record_state(tick, ns, pose, obstacles)

    def _record_tf(self, now: float, ns: int, pose: PoseEstimate | None) -> None:
        placement = pose.placement if pose is not None and pose.placement else self.placement
        cached = self._aircraft_tf
        if cached is None or (
            cached[0] != placement and placement.differs_from(cached[0], *PLACEMENT_STEP)
        ):
            body = _transform_body(AIRPORT_FRAME, AIRCRAFT_FRAME, placement.airport_from_aircraft())
            cached = self._aircraft_tf = (placement, body)
        ts = timestamp_field(ns)
        transforms = [ts + cached[1]]
        if pose is not None:
            transforms.append(encode_planar_transform(ts, AIRPORT_FRAME, ROBOT_FRAME, pose.pose_a))
            if now >= self._next_pose:
                self._next_pose = now + POSE_PERIOD - 1e-9
                self._pose.log(encode_planar_pose(ts, AIRPORT_FRAME, pose.pose_a), ns)
        self._tf.log(encode_transforms(transforms), ns)

    def _record_sensor_tf(self, ns: int, frame: SensorFrame) -> None:
        ts = timestamp_field(ns)
        transforms = [ts + body for body in self._laser_tf]
        cameras = self.mission.platform.cameras
        for camera, (_, unit, lateral) in self._cameras.items():
            ptu = frame.pan_tilt.get(unit)
            pan, tilt = (ptu.pan, ptu.tilt) if ptu is not None else (0.0, 0.0)
            cached = self._camera_tf.get(camera)
            if cached is None or cached[:2] != (pan, tilt):
                spec = cameras[unit]
                r_from_c = robot_from_camera(spec.mount, spec.mount_yaw, pan, tilt, lateral)
                body = _transform_body(ROBOT_FRAME, camera_frame(camera), r_from_c)
                cached = self._camera_tf[camera] = (pan, tilt, body)
            transforms.append(ts + cached[2])
        self._sensor_tf.log(encode_transforms(transforms), ns)

    def _record_scans(self, ticks: list[_Tick]) -> None:
        """The new scans of ``ticks`` (the lasers are slower than the tree: a frame often
        holds the scan of the tick before), encoded together per laser."""
        new: dict[str, list[tuple[int, ScanRecord]]] = {}
        stamps = self._scan_stamps
        for tick in ticks:
            for lid, scan in tick.frame.scans.items():
                if stamps.get(lid) != scan.stamp and lid in self._lasers:
                    stamps[lid] = scan.stamp
                    new.setdefault(lid, []).append((self._ns(scan.stamp), scan))
        for lid, scans in new.items():
            channel, encoder = self._lasers[lid]
            for (ns, _), message in zip(scans, encoder.encode_many(scans), strict=True):
                channel.log(message, ns)

    def _record_cameras(self, now: float, frame: SensorFrame) -> None:
        """Every new image that shows something, the first one after that shows nothing,
        and one a second while nothing is seen (the camera still delivers)."""
        for camera, image in frame.cameras.items():
            if self._image_stamps.get(camera) == image.stamp:
                continue
            self._image_stamps[camera] = image.stamp
            entry = self._cameras.get(camera)
            if entry is None:
                continue
            seen = bool(image.detections)
            last_t, last_seen = self._image_logged.get(camera, (-math.inf, False))
            if not seen and not last_seen and now - last_t < IDLE_CAMERA_PERIOD:
                continue
            self._image_logged[camera] = (now, seen)
            detections = ",".join(
                f'{_point_json(d.feature, d.point)}"u":{d.u:.2f},"v":{d.v:.2f}}}'
                for d in image.detections
            )
            if "nan" in detections or "inf" in detections:  # (or in a feature's name)
                detections = ",".join(
                    f'{{"feature":{_quoted(d.feature)},"point":{int(d.point)},'
                    f'"u":{_number(d.u)},"v":{_number(d.v)}}}'
                    for d in image.detections
                )
            image_id = "null" if image.image is None else str(int(image.image))
            entry[0].base.log(
                (
                    f'{{"t":{now:.3f},"stamp":{_number(image.stamp)},'
                    f'"camera":{_quoted(camera)},"image":{image_id},'
                    f'"detections":[{detections}]}}'
                ).encode(),
                self._ns(image.stamp),
            )

    def _record_events(self, now: float, upto: int, progress: object) -> None:
        """The runtime's events up to the ``upto``-th, then what ``progress`` changed."""
        if self._runtime is not None and upto > self._events_seen:
            for event in self._runtime.events[self._events_seen : upto]:
                self._record_event(event)
            self._events_seen = upto
        if isinstance(progress, MissionProgress) and progress is not self._progress:
            self._record_progress(now, progress)

    def _record_event(self, event: Event) -> None:
        ns = self._ns(event.t)
        record = event.as_dict()
        self._events.log(json.dumps(record, default=_plain), log_time=ns)
        if event.kind == "controller":
            self._controller.log(
                json.dumps(
                    {
                        "t": record["t"],
                        "from": str(event.detail.get("from", "")),
                        "to": str(event.detail.get("to", "")),
                        "reason": str(event.detail.get("reason", "")),
                    }
                ),
                log_time=ns,
            )
        self._log.log(
            Log(
                timestamp=_stamp(ns),
                level=_level(event),
                message=_summary(event),
                name=event.kind,
            ),
            log_time=ns,
        )

    def _record_progress(self, now: float, progress: MissionProgress) -> None:
        """Checkpoint completions and phase changes (the runtime journals them but has no
        event for them): as ``checkpoint-completed`` and ``phase`` events."""
        before = self._progress
        self._progress = progress
        done = before.completed if before is not None else ()
        for cp in progress.completed[len(done) :]:
            self._record_event(Event(now, "checkpoint-completed", {"checkpoint": cp}))
        if before is None or progress.phase != before.phase:
            self._record_event(Event(now, "phase", {"phase": progress.phase}))

    def _record_state(
        self, tick: _Tick, ns: int, pose: PoseEstimate | None, obstacles: Obstacles | None
    ) -> None:
        progress = self._progress
        status = tick.safety
        servo = tick.servo
        state: dict[str, object] = {
            "t": round(tick.now, 3),
            "phase": progress.phase if progress is not None else "",
            "checkpoint": progress.checkpoint if progress is not None else None,
            "goal": progress.goal if progress is not None else None,
            "completed": len(progress.completed) if progress is not None else 0,
            "controller": tick.controller,
            "pose_a": _pose_json(pose.pose_a if pose is not None else None),
            "pose_f": _pose_json(pose.pose_f if pose is not None else None),
            "sigma_f": _finite(pose.sigma_f if pose is not None else None),
            "confidence": _finite(pose.confidence if pose is not None else None),
            "confidence_f": _finite(pose.confidence_f if pose is not None else None),
            "reference": str(pose.reference) if pose is not None else None,
            "closest": _finite(obstacles.closest if obstacles is not None else None),
            "tracks": len(obstacles.tracks) if obstacles is not None else 0,
            "safety": {
                "estop_latched": status.estop_latched,
                "stopped_reason": status.stopped_reason,
                "speed_scale": round(status.speed_scale, 4),
                "geofence_distance": _finite(status.geofence_distance),
                "geofence_zone": status.geofence_zone,
                "forced_stop": status.forced_stop,
            },
            "servo": (
                {
                    "checkpoint": servo.checkpoint,
                    "target": servo.target,
                    "mode": servo.mode,
                    "camera": servo.camera,
                    "real": servo.real,
                    "reconstructed": servo.reconstructed,
                }
                if isinstance(servo, ServoStatus)
                else None
            ),
        }
        self._state.log(json.dumps(state, default=_plain), log_time=ns)


# -- live view ------------------------------------------------------------------------------------
class _LateJoiners(ServerListener):
    """Sends the static scene again when a client subscribes to it: the scene is logged
    once, and a live client that joins later would otherwise never get it."""

    def __init__(self, recorder: Recorder) -> None:
        self.recorder = recorder

    def on_subscribe(self, client: Client, channel: ChannelView) -> None:
        del client
        if channel.topic in (TOPIC_SCENE, TOPIC_SENSOR_TF):
            self.recorder._resend_scene = True


def serve_live(recorder: Recorder, host: str = "127.0.0.1", port: int = 8765) -> WebSocketServer:
    """Serve the recorder's channels over the Foxglove WebSocket protocol on ``host``:``port``
    (0: any free port, see ``server.port``), in the recorder's own context: what is
    recorded is what a connected Foxglove shows. The server advertises the run clock
    (``Time`` capability) and stops when the recorder closes."""
    server = foxglove.start_server(
        name="walkaround",
        host=host,
        port=port,
        capabilities=[Capability.Time],
        server_listener=_LateJoiners(recorder),
        context=recorder.context,
    )
    recorder.servers.append(server)
    recorder.batch = 0.0  # a live view sees every tick as it happens
    return server
