"""The camera wire: feature detections from the on-board vision process over ZeroMQ.

Why a separate process and a wire: image processing is heavy, written by other people,
possibly in another language, and may crash; the executive only needs its result (which
feature point is at which pixel) and must survive whatever comes over the wire. So the
interface is small, versioned and checked field by field; nothing that fails the check
is trusted or half-used.

Message interface, version 1
    ZeroMQ PUB/SUB. The vision process binds a PUB socket (``tcp://127.0.0.1:5560``, or
    ``ipc:///run/walkaround/detections``), the executive connects a SUB socket and
    subscribes to the camera ids it expects. One message per processed image, two frames:

    1. topic: the camera id, UTF-8 (``b"front-left"``): see ``records.camera_ids``;
    2. body: UTF-8 JSON, at most 1 MiB::

        {"v": 1, "camera": "front-left", "stamp": 1234.567, "image": 42,
         "detections": [{"feature": "pitot-l", "point": 0, "u": 512.3, "v": 300.1}]}

    ``v`` the integer 1; ``camera`` the topic again; ``stamp`` the sender's monotonic
    clock at exposure (s, finite); ``image`` an integer >= 0 that changes with every
    exposure (a counter), or null when unknown; ``detections`` at most 10 000 objects
    with ``feature`` (a non-empty string of at most 200 characters), ``point`` (integer
    >= 0: which point of the feature) and ``u``, ``v`` (finite pixel coordinates, u right,
    v down, in the output image). Other keys are ignored (room to grow within v1).

    Anything else (not two frames, body over 1 MiB, bad UTF-8 or JSON, another version, a
    missing or mistyped field, a non-finite number, too many detections, a camera not
    subscribed or differing from the topic) is dropped and counted by :class:`Rejection`
    kind. A peer sending more than 16 MiB is disconnected by ZeroMQ itself (not counted).

Time
    A frame is stamped with the executive's ``clock()`` on arrival, like every sensor
    reading. The sender's stamp runs on another clock, so arrival minus sender stamp
    is no latency: it is kept for the record (:class:`ReceivedFrame`) and the link is
    measured by inter-arrival times per camera.

Publishing from another program (plain pyzmq, no walkaround needed)::

    import json, time, zmq

    pub = zmq.Context().socket(zmq.PUB)
    pub.bind("tcp://127.0.0.1:5560")
    for image in range(1_000_000):
        dets = [{"feature": "pitot-l", "point": 0, "u": 512.3, "v": 300.1}]
        body = {"v": 1, "camera": "front-left", "stamp": time.monotonic(),
                "image": image, "detections": dets}
        pub.send_multipart([b"front-left", json.dumps(body).encode()])
        time.sleep(0.1)
"""

from __future__ import annotations

import json
import math
import threading
from collections import Counter
from collections.abc import Callable, Collection, Iterable, Mapping, Sequence
from dataclasses import dataclass
from enum import StrEnum
from types import MappingProxyType

import zmq

from executive.core.records import CameraFrame, Detection
from executive.robotlink.nmea import ArrivalStats, IntervalMeter
from executive.robotlink.wire import Wire

Clock = Callable[[], float]

VERSION = 1
MAX_BODY_BYTES = 1 << 20
MAX_DETECTIONS = 10_000
MAX_FEATURE_CHARS = 200
_ZMQ_MAX_MESSAGE = 16 << 20
_HWM = 100
_POLL_MS = 50
_JOIN_TIMEOUT = 5.0


class Rejection(StrEnum):
    """Why a message was dropped."""

    FRAMING = "framing"
    TOO_LARGE = "too-large"
    BAD_JSON = "bad-json"
    VERSION = "version"
    FIELDS = "fields"
    NON_FINITE = "non-finite"
    TOO_MANY = "too-many-detections"
    CAMERA = "camera"


class MessageRejectedError(ValueError):
    """A message that is not a valid v1 detection message."""

    def __init__(self, reason: Rejection, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason


@dataclass(frozen=True, slots=True)
class DetectionMessage:
    """A decoded, validated message (the sender's view: its stamp, its camera)."""

    camera: str
    sender_stamp: float
    image: int | None
    detections: tuple[Detection, ...]


@dataclass(frozen=True, slots=True)
class ReceivedFrame:
    """A frame as the executive uses it (stamped on arrival), with the sender's stamp kept
    for the record."""

    frame: CameraFrame
    sender_stamp: float


@dataclass(frozen=True, slots=True)
class DetectionCounts:
    """Totals since start: messages received, accepted, and rejected by kind."""

    received: int
    accepted: int
    rejected: Mapping[str, int]


# -- encoding and decoding ---------------------------------------------------------------------
def encode_message(camera: str, frame: CameraFrame) -> list[bytes]:
    """The two frames of a v1 message; ValueError for what a subscriber would reject."""
    if not camera:
        raise ValueError("camera id must not be empty")
    if len(frame.detections) > MAX_DETECTIONS:
        raise ValueError(f"{len(frame.detections)} detections: at most {MAX_DETECTIONS}")
    body = {
        "v": VERSION,
        "camera": camera,
        "stamp": float(frame.stamp),
        "image": None if frame.image is None else int(frame.image),
        "detections": [
            {"feature": d.feature, "point": int(d.point), "u": float(d.u), "v": float(d.v)}
            for d in frame.detections
        ],
    }
    data = json.dumps(body, allow_nan=False, separators=(",", ":")).encode("utf-8")
    if len(data) > MAX_BODY_BYTES:
        raise ValueError(f"message of {len(data)} bytes: at most {MAX_BODY_BYTES}")
    return [camera.encode("utf-8"), data]


def decode_message(
    frames: Sequence[bytes], cameras: Collection[str] | None = None
) -> DetectionMessage:
    """Validate a received message; MessageRejectedError says why it is not one. ``cameras``:
    the camera ids accepted (None: any)."""
    if len(frames) != 2:
        raise MessageRejectedError(Rejection.FRAMING, f"{len(frames)} frames, expected 2")
    topic, body = frames
    if len(body) > MAX_BODY_BYTES:
        raise MessageRejectedError(Rejection.TOO_LARGE, f"{len(body)} bytes")
    camera = _camera(topic, cameras)
    obj = _json_object(body)
    if type(obj.get("v")) is not int or obj["v"] != VERSION:
        raise MessageRejectedError(Rejection.VERSION, f"v = {obj.get('v')!r}, expected {VERSION}")
    if obj.get("camera") != camera:
        raise MessageRejectedError(Rejection.CAMERA, f"body camera {obj.get('camera')!r} != topic")
    return DetectionMessage(
        camera, _finite(obj, "stamp"), _image(obj), _detections(_field(obj, "detections"))
    )


def _camera(topic: bytes, cameras: Collection[str] | None) -> str:
    try:
        camera = topic.decode("utf-8")
    except UnicodeDecodeError:
        raise MessageRejectedError(Rejection.CAMERA, "topic is not UTF-8") from None
    if not camera or (cameras is not None and camera not in cameras):
        raise MessageRejectedError(Rejection.CAMERA, f"camera {camera!r} not subscribed")
    return camera


def _json_object(body: bytes) -> dict[str, object]:
    try:
        obj = json.loads(body.decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise MessageRejectedError(Rejection.BAD_JSON, str(exc)[:80]) from None
    if not isinstance(obj, dict):
        raise MessageRejectedError(Rejection.BAD_JSON, "not a JSON object")
    return obj


def _field(obj: Mapping[str, object], key: str) -> object:
    if key not in obj:
        raise MessageRejectedError(Rejection.FIELDS, f"missing {key!r}")
    return obj[key]


def _finite(obj: Mapping[str, object], key: str) -> float:
    value = _field(obj, key)
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise MessageRejectedError(Rejection.FIELDS, f"{key!r} is not a number")
    try:
        number = float(value)
    except OverflowError:  # an integer beyond float range
        number = math.inf
    if not math.isfinite(number):
        raise MessageRejectedError(Rejection.NON_FINITE, f"{key!r} is not finite")
    return number


def _count(obj: Mapping[str, object], key: str) -> int:
    value = _field(obj, key)
    if type(value) is not int or value < 0:
        raise MessageRejectedError(Rejection.FIELDS, f"{key!r} is not an integer >= 0")
    return value


def _image(obj: Mapping[str, object]) -> int | None:
    return None if _field(obj, "image") is None else _count(obj, "image")


def _detections(value: object) -> tuple[Detection, ...]:
    if not isinstance(value, list):
        raise MessageRejectedError(Rejection.FIELDS, "'detections' is not a list")
    if len(value) > MAX_DETECTIONS:
        raise MessageRejectedError(Rejection.TOO_MANY, f"{len(value)} detections")
    return tuple(_detection(item) for item in value)


def _detection(item: object) -> Detection:
    if not isinstance(item, dict):
        raise MessageRejectedError(Rejection.FIELDS, "a detection is not an object")
    feature = _field(item, "feature")
    if not isinstance(feature, str) or not 0 < len(feature) <= MAX_FEATURE_CHARS:
        raise MessageRejectedError(Rejection.FIELDS, "'feature' is not a short non-empty string")
    return Detection(feature, _count(item, "point"), _finite(item, "u"), _finite(item, "v"))


# -- subscriber --------------------------------------------------------------------------------
class DetectionSubscriber(Wire):
    """Receives detection messages in a background thread; keeps the latest per camera.

    The thread polls with a 50 ms timeout so :meth:`close` returns promptly, drains what
    has arrived, stamps each message with ``clock()`` and validates it with
    :func:`decode_message`. Thread-safe readers.
    """

    def __init__(
        self,
        endpoint: str,
        cameras: Iterable[str],
        clock: Clock,
        name: str = "detections",
        *,
        recent: float = 10.0,
    ) -> None:
        self.endpoint = endpoint
        self.cameras = frozenset(cameras)
        if not self.cameras:
            raise ValueError("subscribe to at least one camera")
        self.name = name
        self.recent = recent
        self._clock = clock
        self._lock = threading.Lock()
        self._frames: dict[str, ReceivedFrame] = {}
        self._meters = {camera: IntervalMeter() for camera in self.cameras}
        self._rejected: Counter[str] = Counter()
        self._last_rejected: dict[str, float] = {}
        self._accepted = 0
        self._context = zmq.Context()
        self._socket = self._subscribe(endpoint)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"zmq:{name}", daemon=True)
        self._thread.start()

    def _subscribe(self, endpoint: str) -> zmq.Socket:
        sock = self._context.socket(zmq.SUB)
        sock.setsockopt(zmq.LINGER, 0)
        sock.setsockopt(zmq.RCVHWM, _HWM)
        sock.setsockopt(zmq.MAXMSGSIZE, _ZMQ_MAX_MESSAGE)
        for camera in sorted(self.cameras):
            sock.setsockopt(zmq.SUBSCRIBE, camera.encode("utf-8"))
        try:
            sock.connect(endpoint)
        except zmq.ZMQError:
            sock.close()
            self._context.term()
            raise
        return sock

    # reading -------------------------------------------------------------------------------
    def latest(self) -> dict[str, CameraFrame]:
        """Camera id -> its latest frame (stamped on arrival); cameras not heard absent."""
        with self._lock:
            return {camera: received.frame for camera, received in self._frames.items()}

    def received(self) -> dict[str, ReceivedFrame]:
        """Like :meth:`latest`, with the sender's stamps."""
        with self._lock:
            return dict(self._frames)

    def stats(self) -> dict[str, ArrivalStats]:
        """Inter-arrival statistics per subscribed camera."""
        with self._lock:
            return {camera: meter.snapshot() for camera, meter in self._meters.items()}

    def counts(self) -> DetectionCounts:
        with self._lock:
            rejected = MappingProxyType(dict(self._rejected))
            total = self._accepted + sum(rejected.values())
            return DetectionCounts(total, self._accepted, rejected)

    def status(self) -> list[str]:
        """Soft problems: kinds of messages dropped within the last ``recent`` s. (A silent
        or frozen camera is judged by the executive's freshness checks on the stamps.)"""
        now = self._clock()
        with self._lock:
            return [
                f"{self.name}: dropped {self._rejected[kind]} invalid message"
                + ("" if self._rejected[kind] == 1 else "s")
                + f" ({kind})"
                for kind, last in sorted(self._last_rejected.items())
                if now - last <= self.recent
            ]

    def close(self) -> None:
        self._stop.set()
        self._thread.join(_JOIN_TIMEOUT)
        if not self._thread.is_alive():
            self._context.term()

    # the thread -------------------------------------------------------------------------------
    def _run(self) -> None:
        poller = zmq.Poller()
        poller.register(self._socket, zmq.POLLIN)
        try:
            while not self._stop.is_set():
                if poller.poll(_POLL_MS):
                    self._drain()
        finally:
            self._socket.close(linger=0)

    def _drain(self) -> None:
        while True:
            try:
                frames = self._socket.recv_multipart(zmq.NOBLOCK)
            except zmq.Again:
                return
            self._take(frames, self._clock())

    def _take(self, frames: list[bytes], now: float) -> None:
        try:
            message = decode_message(frames, self.cameras)
        except MessageRejectedError as exc:
            with self._lock:
                self._rejected[exc.reason.value] += 1
                self._last_rejected[exc.reason.value] = now
            return
        frame = CameraFrame(now, message.detections, message.image)
        with self._lock:
            self._frames[message.camera] = ReceivedFrame(frame, message.sender_stamp)
            self._meters[message.camera].mark(now)
            self._accepted += 1


# -- publisher ---------------------------------------------------------------------------------
class DetectionPublisher(Wire):
    """Publishes detection messages: the simulator's camera end, and a reference for a
    vision process written in Python. Binds ``endpoint`` (``tcp://127.0.0.1:*`` picks a
    free port; :attr:`endpoint` is then the one bound). Thread-safe."""

    def __init__(self, endpoint: str) -> None:
        self._context = zmq.Context()
        self._socket = self._context.socket(zmq.PUB)
        self._socket.setsockopt(zmq.LINGER, 0)
        self._socket.setsockopt(zmq.SNDHWM, _HWM)
        try:
            self._socket.bind(endpoint)
        except zmq.ZMQError:
            self._socket.close()
            self._context.term()
            raise
        self.endpoint: str = self._socket.getsockopt_string(zmq.LAST_ENDPOINT)
        self._lock = threading.Lock()

    def publish(self, camera: str, frame: CameraFrame) -> None:
        """Send ``frame`` (its stamp is the sender's) as ``camera``'s latest image. Never
        blocks: with no subscriber, or a slow one, messages are dropped (PUB semantics)."""
        frames = encode_message(camera, frame)
        with self._lock:
            self._socket.send_multipart(frames)

    def close(self) -> None:
        with self._lock:
            self._socket.close(linger=0)
        self._context.term()
