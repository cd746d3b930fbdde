"""Camera detections over ZeroMQ (executive/robotlink/detections.py).

The v1 message round-trips exactly (hypothesis, no sockets); every kind of malformed
message is rejected with its reason; over loopback TCP (and ipc) a publisher's frames
reach the subscriber intact and stamped on arrival, while malformed messages sent by a
raw PUB socket are counted and dropped and the good ones around them still pass.
Waits are bounded polls (PUB/SUB drops messages until the subscription has propagated,
so the sender repeats until the receiver has one); nothing asserts how long anything took.
"""

from __future__ import annotations

import json
import math
import time

import pytest
import zmq
from hypothesis import given, settings
from hypothesis import strategies as st

from executive.core.records import CameraFrame, Detection
from executive.robotlink.detections import (
    MAX_BODY_BYTES,
    MAX_DETECTIONS,
    DetectionPublisher,
    DetectionSubscriber,
    MessageRejectedError,
    Rejection,
    decode_message,
    encode_message,
)

CAMERAS = ("front-left", "front-right")
LOOPBACK = "tcp://127.0.0.1:*"
WAIT = 5.0
ARRIVAL = 777.0


def arrival_clock() -> float:
    return ARRIVAL


def frame(image: int, stamp: float = 12.5) -> CameraFrame:
    dets = (
        Detection("pitot-l", 0, 512.25, 300.125),
        Detection("static-port-\u00e9", 3, 0.1 + 0.2, 1e-9),
        Detection("aoa-vane", 12, 1919.999999999, 1079.5),
    )
    return CameraFrame(stamp, dets, image)


def body(**changes) -> dict:
    """A valid v1 body for front-left, with ``changes`` applied (None value: delete)."""
    obj = {
        "v": 1,
        "camera": "front-left",
        "stamp": 12.5,
        "image": 7,
        "detections": [{"feature": "pitot-l", "point": 0, "u": 512.3, "v": 300.1}],
    }
    for key, value in changes.items():
        if value is None:
            del obj[key]
        else:
            obj[key] = value
    return obj


def message(obj: object, topic: bytes = b"front-left") -> list[bytes]:
    return [topic, json.dumps(obj).encode("utf-8")]


def detection(**changes) -> dict:
    det = {"feature": "pitot-l", "point": 0, "u": 512.3, "v": 300.1}
    det.update(changes)
    return det


def wait_until(predicate, action=None, timeout: float = WAIT) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if action is not None:
            action()
        if predicate():
            return True
        time.sleep(0.02)
    return predicate()


# -- the message, without sockets -------------------------------------------------------------
finite = st.floats(allow_nan=False, allow_infinity=False)
detections = st.builds(
    Detection,
    feature=st.text(min_size=1, max_size=200),
    point=st.integers(0, 2**40),
    u=finite,
    v=finite,
)


@settings(max_examples=200, deadline=None)
@given(
    stamp=finite,
    image=st.none() | st.integers(0, 2**63),
    dets=st.lists(detections, max_size=20),
)
def test_encode_decode_round_trip(stamp, image, dets):
    sent = CameraFrame(stamp, tuple(dets), image)
    got = decode_message(encode_message("ptz", sent), {"ptz"})
    assert got.camera == "ptz"
    assert got.sender_stamp == stamp
    assert got.image == image
    assert got.detections == sent.detections


TOO_MANY = [detection(point=k) for k in range(MAX_DETECTIONS + 1)]

MALFORMED = {
    "one frame": ([b"front-left"], Rejection.FRAMING),
    "three frames": ([*message(body()), b"extra"], Rejection.FRAMING),
    "over 1 MiB": ([b"front-left", b" " * (MAX_BODY_BYTES + 1)], Rejection.TOO_LARGE),
    "not JSON": ([b"front-left", b"{not json"], Rejection.BAD_JSON),
    "not UTF-8": ([b"front-left", b'{"v": 1, "camera": "\xff"}'], Rejection.BAD_JSON),
    "not an object": (message([1, 2, 3]), Rejection.BAD_JSON),
    "deeply nested": ([b"front-left", b"[" * 100_000], Rejection.BAD_JSON),
    "version 2": (message(body(v=2)), Rejection.VERSION),
    "version as text": (message(body(v="1")), Rejection.VERSION),
    "version as bool": (message(body(v=True)), Rejection.VERSION),
    "no version": (message(body(v=None)), Rejection.VERSION),
    "no stamp": (message(body(stamp=None)), Rejection.FIELDS),
    "no detections": (message(body(detections=None)), Rejection.FIELDS),
    "no image": (message(body(image=None)), Rejection.FIELDS),
    "detections not a list": (message(body(detections={})), Rejection.FIELDS),
    "detection not an object": (message(body(detections=[[1, 2]])), Rejection.FIELDS),
    "pixel as text": (message(body(detections=[detection(u="512")])), Rejection.FIELDS),
    "negative point": (message(body(detections=[detection(point=-1)])), Rejection.FIELDS),
    "fractional point": (message(body(detections=[detection(point=1.5)])), Rejection.FIELDS),
    "empty feature": (message(body(detections=[detection(feature="")])), Rejection.FIELDS),
    "missing v pixel": (
        message(body(detections=[{"feature": "a", "point": 0, "u": 1.0}])),
        Rejection.FIELDS,
    ),
    "image negative": (message(body(image=-3)), Rejection.FIELDS),
    "NaN pixel": (message(body(detections=[detection(u=math.nan)])), Rejection.NON_FINITE),
    "infinite pixel": ([b"front-left", b'{"v":1,"camera":"front-left","stamp":1.0,"image":1,'
                        b'"detections":[{"feature":"a","point":0,"u":1e999,"v":0}]}'],
                       Rejection.NON_FINITE),
    "huge integer pixel": (message(body(detections=[detection(v=10**400)])), Rejection.NON_FINITE),
    "infinite stamp": (message(body(stamp=math.inf)), Rejection.NON_FINITE),
    "too many detections": (message(body(detections=TOO_MANY)), Rejection.TOO_MANY),
    "camera differs from topic": (message(body(camera="front-right")), Rejection.CAMERA),
    "camera not subscribed": (message(body(camera="front-leftover"), b"front-leftover"),
                              Rejection.CAMERA),
    "topic not UTF-8": (message(body(), b"front-left\xff"), Rejection.CAMERA),
}  # fmt: skip


@pytest.mark.parametrize("case", sorted(MALFORMED))
def test_malformed_message_is_rejected_with_its_reason(case):
    frames, reason = MALFORMED[case]
    with pytest.raises(MessageRejectedError) as caught:
        decode_message(frames, CAMERAS)
    assert caught.value.reason is reason


def test_valid_body_with_null_image_and_extra_keys_is_accepted():
    got = decode_message(message(body() | {"image": None, "exposure_us": 800}), CAMERAS)
    assert got.image is None
    assert got.detections == (Detection("pitot-l", 0, 512.3, 300.1),)


def test_encoder_refuses_what_a_subscriber_would_reject():
    with pytest.raises(ValueError):
        encode_message("ptz", CameraFrame(1.0, (Detection("a", 0, math.nan, 0.0),), 1))
    with pytest.raises(ValueError):
        encode_message("ptz", CameraFrame(math.inf, (), 1))
    with pytest.raises(ValueError, match="detections"):
        encode_message("ptz", CameraFrame(1.0, (Detection("a", 0, 1.0, 1.0),) * 10_001, 1))
    with pytest.raises(ValueError, match="camera"):
        encode_message("", CameraFrame(1.0))


# -- over the wire ----------------------------------------------------------------------------
def test_publisher_to_subscriber_over_loopback_values_intact():
    with (
        DetectionPublisher(LOOPBACK) as pub,
        DetectionSubscriber(pub.endpoint, CAMERAS, arrival_clock) as sub,
    ):
        assert pub.endpoint.startswith("tcp://127.0.0.1:")
        sent_left, sent_right = frame(41, stamp=12.5), CameraFrame(13.0, (), 9)

        def send() -> None:
            pub.publish("front-left", sent_left)
            pub.publish("front-right", sent_right)

        assert wait_until(lambda: len(sub.latest()) == 2, send)
        latest = sub.latest()
        assert latest["front-left"] == CameraFrame(ARRIVAL, sent_left.detections, 41)
        assert latest["front-right"] == CameraFrame(ARRIVAL, (), 9)
        received = sub.received()
        assert received["front-left"].sender_stamp == 12.5  # kept for the record
        assert received["front-right"].sender_stamp == 13.0
        counts = sub.counts()
        assert counts.accepted >= 2 and counts.rejected == {}
        assert sub.status() == []


def test_unsubscribed_cameras_are_not_delivered():
    with (
        DetectionPublisher(LOOPBACK) as pub,
        DetectionSubscriber(pub.endpoint, ["front-left"], arrival_clock) as sub,
    ):

        def send() -> None:
            pub.publish("rear-left", frame(1))
            pub.publish("front-left", frame(2))

        assert wait_until(lambda: "front-left" in sub.latest(), send)
        send()
        assert wait_until(lambda: sub.stats()["front-left"].count >= 2, send)
        assert set(sub.latest()) == {"front-left"}


def test_inter_arrival_statistics_per_camera():
    ticks = iter(range(1_000_000))
    with (
        DetectionPublisher(LOOPBACK) as pub,
        DetectionSubscriber(pub.endpoint, CAMERAS, lambda: float(next(ticks))) as sub,
    ):
        assert wait_until(
            lambda: sub.stats()["front-left"].count >= 3,
            lambda: pub.publish("front-left", frame(1)),
        )
        stats = sub.stats()
        assert stats["front-left"].mean_interval >= 1.0  # one clock tick per message
        assert stats["front-right"].count == 0
        assert math.isnan(stats["front-right"].mean_interval)


def test_ipc_endpoint(tmp_path):
    endpoint = f"ipc://{tmp_path / 'detections'}"
    with (
        DetectionPublisher(endpoint) as pub,
        DetectionSubscriber(endpoint, CAMERAS, arrival_clock) as sub,
    ):
        assert wait_until(
            lambda: "front-right" in sub.latest(), lambda: pub.publish("front-right", frame(5))
        )
        assert sub.latest()["front-right"].image == 5


def test_malformed_messages_are_counted_and_dropped_while_good_ones_pass():
    context = zmq.Context()
    raw = context.socket(zmq.PUB)
    raw.setsockopt(zmq.LINGER, 0)
    port = raw.bind_to_random_port("tcp://127.0.0.1")
    try:
        with DetectionSubscriber(f"tcp://127.0.0.1:{port}", CAMERAS, arrival_clock) as sub:
            good = encode_message("front-left", frame(1))
            assert wait_until(
                lambda: "front-left" in sub.latest(), lambda: raw.send_multipart(good)
            )
            # subscribed now; one TCP connection keeps order, so once the barrier is in,
            # every repeated sync message before it is too
            raw.send_multipart(encode_message("front-left", frame(100)))
            assert wait_until(lambda: sub.latest()["front-left"].image == 100)
            before = sub.counts()
            expected: dict[str, int] = {}
            for case in sorted(MALFORMED):
                frames, reason = MALFORMED[case]
                raw.send_multipart(frames)
                expected[reason.value] = expected.get(reason.value, 0) + 1
            sentinel = encode_message("front-left", frame(2))
            raw.send_multipart(sentinel)  # one TCP connection: delivered after the bad ones
            assert wait_until(lambda: sub.latest()["front-left"].image == 2)

            counts = sub.counts()
            assert dict(counts.rejected) == expected
            assert counts.accepted == before.accepted + 1  # only the sentinel got through
            assert counts.received == before.received + len(MALFORMED) + 1
            latest = sub.latest()["front-left"]
            assert latest.detections == frame(2).detections  # no bad message replaced it
            status = sub.status()
            assert f"detections: dropped {expected['fields']} invalid messages (fields)" in status
            assert len(status) == len(expected)
    finally:
        raw.close(linger=0)
        context.term()


def test_subscriber_refuses_an_invalid_endpoint_and_no_cameras():
    with pytest.raises(zmq.ZMQError):
        DetectionSubscriber("nonsense://x", CAMERAS, arrival_clock)
    with pytest.raises(ValueError):
        DetectionSubscriber(LOOPBACK, [], arrival_clock)
