"""SCIP 2.0 (executive/robotlink/scip.py): the codec, recorded exchanges, the emulator and
the client on loopback.

The codec is checked against the specification's worked examples (``CB`` = 1234, ``1Dh`` =
5432, ``m2@0`` = 16000000, status ``00`` sums to ``P``) and against replies recorded from
the Hokuyo documentation (a URG-04LX's VV and PP), so the client and the emulator cannot
agree on a private dialect. Waits are bounded polls (up to 5 s), never timing assertions.
"""

from __future__ import annotations

import math
import socket
import threading
import time
from collections.abc import Callable, Iterator

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from executive.robotlink.scip import (
    UTM_30LX_EW,
    ScipChecksumError,
    ScipClient,
    ScipEchoError,
    ScipError,
    ScipFormatError,
    ScipGeometry,
    ScipServer,
    ScipStatusError,
    ScipTruncatedError,
    build_response,
    checksum,
    decode_value,
    decode_values,
    encode_ranges,
    encode_value,
    parse_response,
    parse_scan,
)

WAIT = 5.0

# -- recorded exchanges ---------------------------------------------------------------------------
# A URG-04LX's replies as printed in Hokuyo's SCIP 2.0 documentation (urgnetwork wiki).
VV_URG04 = (
    b"VV\n00P\n"
    b"VEND:Hokuyo Automatic Co.,Ltd.;[\n"
    b"PROD:SOKUIKI Sensor URG-04LX;[\n"
    b"FIRM:3.1.00(18/Jan./2007);`\n"
    b"PROT:SCIP 2.0;N\n"
    b"SERI:H0614967;V\n\n"
)
PP_URG04 = (
    b"PP\n00P\n"
    b"MODL:URG-04LX(Hokuyo Automatic Co.,Ltd.);N\n"
    b"DMIN:20;4\nDMAX:5600;_\nARES:1024;\\\nAMIN:44;7\nAMAX:725;o\nAFRT:384;6\nSCAN:600;e\n\n"
)
# A UTM-30LX-EW's PP reply (its parameters, sums per the specification).
PP_UTM30 = (
    b"PP\n00P\n"
    b"MODL:UTM-30LX-EW;I\n"
    b"DMIN:23;7\nDMAX:30000;G\nARES:1440;^\nAMIN:0;?\nAMAX:1080;Z\nAFRT:540;0\nSCAN:2400;U\n\n"
)
# MD over steps 0..29, cluster 1, every scan, 2 scans, string characters "scan": the
# acknowledgement, then the first scan (remaining scans 01) at device time 16000000 ms
# ("m2@0"), 30 values of 3 characters in a 64-byte block and a 26-byte block.
MD_COMMAND = "MD0000002901002;scan"
MD_ACK = b"MD0000002901002;scan\n00P\n\n"
MD_SCAN = (
    b"MD0000002901001;scan\n99b\nm2@0?\n"
    b"1Dh00100G7D_7D`0CB00000C00D?oo0?X0A<0B`0DD0Eh0GL0I00JT0L80M\\0O@04\n"
    b"Pd0RH0Sl0UP0W40XX0Z<0[`0]DO\n\n"
)
MD_VALUES = [5432, 1, 23, 29999, 30000, 1234, 0, 19, 20, 65535] + [
    1000 + 100 * i for i in range(20)
]


# -- helpers --------------------------------------------------------------------------------------
class FakeClock:
    """A clock the test sets; the client reads it from its thread."""

    def __init__(self, now: float = 0.0) -> None:
        self.now = now

    def __call__(self) -> float:
        return self.now


def wait_for(predicate: Callable[[], object], timeout: float = WAIT) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"not true within {timeout} s: {predicate}")
        time.sleep(0.01)


def read_reply(sock: socket.socket, buf: bytearray) -> bytes:
    while (end := buf.find(b"\n\n")) < 0:
        chunk = sock.recv(65536)
        assert chunk, "the emulator closed the connection"
        buf += chunk
    raw = bytes(buf[: end + 2])
    del buf[: end + 2]
    return raw


class RawLink:
    """A hand-driven TCP connection to the emulator."""

    def __init__(self, port: int) -> None:
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=WAIT)
        self.buf = bytearray()

    def ask(self, command: str) -> bytes:
        self.sock.sendall(command.encode() + b"\n")
        return self.reply()

    def reply(self) -> bytes:
        return read_reply(self.sock, self.buf)

    def close(self) -> None:
        self.sock.close()


@pytest.fixture
def server() -> Iterator[ScipServer]:
    srv = ScipServer(0)
    yield srv
    srv.close()


@pytest.fixture
def link(server: ScipServer) -> Iterator[RawLink]:
    raw = RawLink(server.port)
    yield raw
    raw.close()


def scene(seed: int = 0) -> np.ndarray:
    """1081 ranges: returns in 0.1..29 m, and beams with no return."""
    rng = np.random.default_rng(seed)
    ranges = rng.uniform(0.1, 29.0, UTM_30LX_EW.steps)
    ranges[::97] = np.inf
    ranges[5] = np.nan
    ranges[6] = 35.0
    return ranges


def no_return(ranges: np.ndarray) -> np.ndarray:
    return ~np.isfinite(ranges) | (ranges >= UTM_30LX_EW.range_max)


# -- value encoding -------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("text", "value"), [(b"CB", 1234), (b"1Dh", 5432), (b"m2@0", 16_000_000), (b"0", 0)]
)
def test_spec_encoding_examples(text, value):
    assert decode_value(text) == value
    assert encode_value(value, len(text)) == text


@given(st.integers(0, 2**18 - 1))
def test_three_char_round_trip(value):
    text = encode_value(value, 3)
    assert len(text) == 3 and all(0x30 <= b <= 0x6F for b in text)
    assert decode_value(text) == value


@given(
    st.sampled_from([2, 3, 4]).flatmap(
        lambda n: st.tuples(st.just(n), st.integers(0, 2 ** (6 * n) - 1))
    )
)
def test_round_trip_every_width(case):
    chars, value = case
    assert decode_value(encode_value(value, chars)) == value


@pytest.mark.parametrize(("value", "chars"), [(4096, 2), (-1, 3), (2**24, 4)])
def test_values_that_do_not_fit_are_refused(value, chars):
    with pytest.raises(ValueError, match="does not fit"):
        encode_value(value, chars)


def test_bytes_outside_the_encoding_are_refused():
    with pytest.raises(ScipFormatError, match="not a SCIP-encoded character"):
        decode_value(b"0p")


# -- checksum -------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("data", "expected"),
    [
        (b"00", b"P"),
        (b"99", b"b"),
        ("VEND:Hokuyo Automatic Co.,Ltd.", b"["),
        (b"PROT:SCIP 2.0", b"N"),
        (b"m2@0", b"?"),
    ],
)
def test_checksum_matches_the_spec(data, expected):
    assert checksum(data) == expected


# -- data blocks ----------------------------------------------------------------------------------
@given(st.lists(st.integers(0, 2**18 - 1), min_size=1, max_size=1081))
def test_ranges_blocks_round_trip(values):
    blocks = encode_ranges(values)
    lines = blocks.split(b"\n")
    assert lines[-1] == b""
    data_lines = lines[:-1]
    assert all(len(line) == 65 for line in data_lines[:-1])
    assert 2 <= len(data_lines[-1]) <= 65
    assert all(checksum(line[:-1]) == line[-1:] for line in data_lines)
    stamp = encode_value(1234, 4)
    raw = build_response("GD0000108000", "00", stamp + checksum(stamp) + b"\n" + blocks)
    scan = parse_scan(parse_response(raw, command="GD0000108000"), expected=len(values))
    assert scan.timestamp_ms == 1234
    assert scan.values.tolist() == values


def test_two_char_data_decodes():
    assert decode_values(b"CB1Dh0", 2).tolist() == [1234, 84, 3584]
    with pytest.raises(ScipTruncatedError, match="whole number"):
        decode_values(b"CB1", 2)


# -- recorded replies -----------------------------------------------------------------------------
def test_recorded_vv_reply():
    response = parse_response(VV_URG04, command="VV")
    assert (response.command, response.status) == ("VV", "00")
    params = response.params()
    assert params["VEND"] == "Hokuyo Automatic Co.,Ltd."
    assert params["PROT"] == "SCIP 2.0"
    assert params["SERI"] == "H0614967"


def test_recorded_pp_reply_gives_the_geometry():
    geometry = ScipGeometry.from_params(parse_response(PP_URG04, command="PP").params())
    assert geometry == ScipGeometry(20, 5600, 1024, 44, 725, 384, 600)
    assert geometry.steps == 682
    assert geometry.angle_min == pytest.approx((44 - 384) * 2 * math.pi / 1024)


def test_utm30_pp_reply_is_the_emulator_geometry():
    geometry = ScipGeometry.from_params(parse_response(PP_UTM30, command="PP").params())
    assert geometry == UTM_30LX_EW
    assert geometry.angle_min == pytest.approx(math.radians(-135.0))
    assert geometry.angle_increment == pytest.approx(math.radians(0.25))
    assert geometry.range_max == 30.0


def test_recorded_md_exchange():
    ack = parse_response(MD_ACK, command=MD_COMMAND, ok=("00",))
    assert (ack.status, ack.lines) == ("00", ())
    response = parse_response(MD_SCAN, command=MD_COMMAND, ok=("99",))
    assert response.status == "99"
    assert response.echo == "MD0000002901001;scan"  # scans remaining, not scans asked for
    scan = parse_scan(response, expected=30)
    assert scan.timestamp_ms == 16_000_000
    assert scan.values.tolist() == MD_VALUES


def test_error_codes_and_beyond_dmax_read_range_max():
    scan = parse_scan(parse_response(MD_SCAN, command=MD_COMMAND))
    ranges = UTM_30LX_EW.to_metres(scan.values)
    assert ranges[:10].tolist() == [5.432, 30.0, 0.023, 29.999, 30.0, 1.234, 30.0, 30.0, 0.02, 30.0]


# -- malformed replies ----------------------------------------------------------------------------
def test_bad_checksum_in_a_data_block():
    broken = MD_SCAN.replace(b"1Dh001", b"1Dh002")
    with pytest.raises(ScipChecksumError, match="bad checksum in line 4"):
        parse_response(broken, command=MD_COMMAND)


def test_bad_checksum_in_a_parameter_line():
    with pytest.raises(ScipChecksumError, match="bad checksum"):
        parse_response(PP_UTM30.replace(b"DMAX:30000;G", b"DMAX:60000;G"), command="PP")


def test_bad_checksum_in_the_status_line():
    with pytest.raises(ScipChecksumError, match="status"):
        parse_response(b"BM\n00Q\n\n", command="BM")


@pytest.mark.parametrize("cut", [1, 2, 20, len(MD_SCAN) - 22])
def test_truncated_reply(cut):
    with pytest.raises(ScipTruncatedError, match="truncated"):
        parse_response(MD_SCAN[:-cut], command=MD_COMMAND)


def test_no_status_line_is_truncated():
    with pytest.raises(ScipTruncatedError, match="no status"):
        parse_response(b"VV\n\n")


def test_missing_lf_between_blocks():
    first_block_end = MD_SCAN.index(b"04\nPd") + 2
    broken = MD_SCAN[:first_block_end] + MD_SCAN[first_block_end + 1 :]
    with pytest.raises(ScipFormatError, match="missing LF"):
        parse_response(broken, command=MD_COMMAND)


def test_wrong_echo():
    with pytest.raises(ScipEchoError, match=r"'VV'.*'PP'"):
        parse_response(VV_URG04, command="PP")
    with pytest.raises(ScipEchoError):
        parse_response(MD_SCAN, command="MD0000108001000")


def test_error_status_names_its_meaning():
    with pytest.raises(ScipStatusError, match=r"status 10 \(laser is off\)") as info:
        parse_response(b"GD0000108001\n10Q\n\n", command="GD0000108001")
    assert info.value.status == "10"
    with pytest.raises(ScipStatusError, match="undefined command"):
        parse_response(b"XX\n0Ee\n\n")


def test_short_scan_is_truncated():
    with pytest.raises(ScipTruncatedError, match="30 values, expected 1081"):
        parse_scan(parse_response(MD_SCAN), expected=1081)


def test_every_codec_error_is_a_scip_error():
    for cls in (ScipChecksumError, ScipTruncatedError, ScipFormatError, ScipEchoError):
        assert issubclass(cls, ScipError)
    assert issubclass(ScipStatusError, ScipError)


# -- the emulator, by hand ------------------------------------------------------------------------
def test_emulator_answers_vv_pp_ii(link):
    vv = parse_response(link.ask("VV"), command="VV").params()
    assert vv["PROT"] == "SCIP 2.0"
    pp = parse_response(link.ask("PP;tag"), command="PP;tag").params()
    assert ScipGeometry.from_params(pp) == UTM_30LX_EW
    ii = parse_response(link.ask("II"), command="II").params()
    assert ii["LASR"] == "OFF"


def test_emulator_laser_commands(server, link):
    with pytest.raises(ScipStatusError, match="laser is off"):
        parse_response(link.ask("GD0000108001"))
    assert parse_response(link.ask("BM")).status == "00"
    assert parse_response(link.ask("BM"), ok=("02",)).status == "02"
    ranges = scene(1)
    server.publish(ranges, stamp_ms=777)
    scan = parse_scan(parse_response(link.ask("GD0000108001")), expected=1081)
    assert scan.timestamp_ms == 777
    assert np.array_equal(scan.values, UTM_30LX_EW.to_codes(ranges))
    assert parse_response(link.ask("QT")).status == "00"
    with pytest.raises(ScipStatusError, match="laser is off"):
        parse_response(link.ask("GD0000108001"))
    assert parse_response(link.ask("RS")).status == "00"


def test_emulator_rejects_bad_requests(link):
    with pytest.raises(ScipStatusError, match="undefined command"):
        parse_response(link.ask("ZZ"))
    with pytest.raises(ScipStatusError, match="end step out of range"):
        parse_response(link.ask("MD0000200000000"))
    with pytest.raises(ScipStatusError, match="end step smaller"):
        parse_response(link.ask("MD0500010000000"))
    with pytest.raises(ScipStatusError, match="cluster count is not a number"):
        parse_response(link.ask("GD00001080x1"))


def test_emulator_md_sends_the_scans_asked_for(server, link):
    command = "MD0540054300002;abc"
    assert parse_response(link.ask(command), command=command).status == "00"
    echoes = []
    for k in range(3):  # the third scan is beyond the two asked for
        server.publish(np.full(1081, 2.0 + k), stamp_ms=100 + 25 * k)
        if k < 2:
            response = parse_response(link.reply(), command=command, ok=("99",))
            scan = parse_scan(response, expected=4)
            echoes.append(response.echo)
            assert scan.values.tolist() == [2000 + 1000 * k] * 4
            assert scan.timestamp_ms == 100 + 25 * k
    assert echoes == ["MD0540054300001;abc", "MD0540054300000;abc"]
    assert parse_response(link.ask("QT")).command == "QT"  # no third scan before it


def test_emulator_cluster_and_interval(server, link):
    command = "MS0000000502100"  # steps 0..5 in pairs, every second scan, 2 characters
    assert parse_response(link.ask(command)).status == "00"
    ranges = np.full(1081, np.inf)
    ranges[:6] = [1.0, 0.5, np.inf, np.inf, 5.0, 4.5]  # 5 m does not fit 2 characters
    for k in range(2):
        server.publish(ranges, stamp_ms=k)
    scan = parse_scan(parse_response(link.reply(), command=command, ok=("99",)), expected=3)
    assert scan.timestamp_ms == 0
    assert scan.values.tolist() == [500, 1, 1]
    assert parse_response(link.ask("QT")).command == "QT"  # the skipped scan never came


# -- client and emulator on loopback --------------------------------------------------------------
@pytest.fixture
def clock() -> FakeClock:
    return FakeClock(100.0)


@pytest.fixture
def client(server: ScipServer, clock: FakeClock) -> Iterator[ScipClient]:
    laser = ScipClient("127.0.0.1", server.port, clock=clock, name="front")
    wait_for(lambda: laser.geometry is not None)  # streaming: MD acknowledged
    yield laser
    laser.close()


def test_a_published_scan_arrives(server, client, clock):
    assert client.latest() is None
    ranges = scene(2)
    server.publish(ranges, stamp_ms=5000)
    wait_for(client.latest)
    scan = client.latest()
    assert scan.stamp == 100.0
    assert len(scan.ranges) == 1081
    assert scan.range_max == 30.0
    assert scan.angle_min == pytest.approx(math.radians(-135.0))
    assert scan.angle_increment == pytest.approx(math.radians(0.25))
    assert scan.angles()[540] == pytest.approx(0.0)
    hit = ~no_return(ranges)
    assert np.max(np.abs(scan.ranges[hit] - ranges[hit])) <= 0.001
    assert np.all(scan.ranges[~hit] == 30.0)
    assert client.health() == []


def test_arrival_statistics(server, client, clock):
    for k, now in enumerate((100.0, 100.03, 100.05)):
        clock.now = now
        server.publish(scene(k), stamp_ms=5000 + 25 * k)
        wait_for(lambda now=now: (s := client.latest()) is not None and s.stamp == now)
    stats = client.stats()
    assert (stats.scans, stats.bad_frames, stats.connections_lost) == (3, 0, 0)
    assert stats.interval_mean == pytest.approx(0.025)
    assert stats.latency_excess_max == pytest.approx(0.005)  # the second scan came 5 ms late


def test_two_clients_get_every_scan(server, client, clock):
    other = ScipClient("127.0.0.1", server.port, clock=clock, name="rear")
    try:
        wait_for(lambda: other.geometry is not None)
        assert server.client_count == 2
        server.publish(np.full(1081, 3.0), stamp_ms=1)
        wait_for(lambda: client.latest() is not None and other.latest() is not None)
        assert np.allclose(other.latest().ranges, 3.0)
        assert np.allclose(client.latest().ranges, 3.0)
    finally:
        other.close()
    wait_for(lambda: server.client_count == 1)


def test_dropped_connection_is_reported_then_scans_resume(server, client, clock):
    server.publish(np.full(1081, 4.0), stamp_ms=10)
    wait_for(client.latest)
    server.drop_connections()
    wait_for(lambda: client.health())
    assert client.health() == ["laser front: connection lost (ConnectionResetError)"]
    assert client.latest().stamp == 100.0  # the last scan stays, and ages
    clock.now = 200.0

    def resumed() -> bool:
        server.publish(np.full(1081, 6.0), stamp_ms=20)
        return client.latest().stamp == 200.0

    wait_for(resumed)
    assert np.allclose(client.latest().ranges, 6.0)
    assert client.health() == []
    assert client.stats().connections_lost == 1


def test_unreachable_laser_is_reported():
    with socket.create_server(("127.0.0.1", 0)) as probe:
        port = probe.getsockname()[1]
    laser = ScipClient("127.0.0.1", port, name="rear")
    try:
        wait_for(lambda: "cannot connect" in " ".join(laser.health()))
        assert laser.health() == ["laser rear: cannot connect (ConnectionRefusedError)"]
        assert laser.latest() is None
    finally:
        laser.close()


# -- bad frames from a scripted device ------------------------------------------------------------
class ScriptedDevice:
    """A device that answers the handshake with recorded replies, then sends ``frames``."""

    def __init__(self, frames: list[bytes]) -> None:
        self.frames = frames
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.port = self.listener.getsockname()[1]
        self.done = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        conn, _ = self.listener.accept()
        with conn, conn.makefile("rb") as commands:
            for line in commands:
                command = line.strip().decode()
                conn.sendall(self._answer(command))
                if command.startswith("MD"):
                    for frame in self.frames:
                        conn.sendall(frame)
                    self.done.wait(WAIT)
                    return

    @staticmethod
    def _answer(command: str) -> bytes:
        if command == "VV":
            return VV_URG04
        if command == "PP":
            return PP_UTM30
        return build_response(command, "00")

    def close(self) -> None:
        self.done.set()
        self.listener.close()
        self.thread.join(WAIT)


def utm_scan(values_mm: np.ndarray, stamp_ms: int) -> bytes:
    stamp = encode_value(stamp_ms, 4)
    payload = stamp + checksum(stamp) + b"\n" + encode_ranges(values_mm)
    return build_response("MD0000108000000", "99", payload)


def corrupt_first_block(raw: bytes) -> bytes:
    """``raw`` with the checksum character of its first data block changed."""
    lines = raw.split(b"\n")
    block = lines[3]
    lines[3] = block[:-1] + (b"0" if block[-1:] != b"0" else b"1")
    return b"\n".join(lines)


def test_bad_frames_are_counted_and_reported(clock):
    good = utm_scan(np.full(1081, 7000), 1)
    corrupt = corrupt_first_block(utm_scan(np.full(1081, 8000), 2))
    short = utm_scan(np.full(1000, 9000), 3)
    device = ScriptedDevice([corrupt, short, good])
    laser = ScipClient("127.0.0.1", device.port, clock=clock, name="front", report_window=1.0)
    try:
        wait_for(lambda: laser.stats().bad_frames == 2 and laser.latest() is not None)
        assert np.allclose(laser.latest().ranges, 7.0)
        reasons = laser.health()
        assert reasons[0].startswith("laser front: truncated scan")
        clock.now = 100.5
        assert laser.health()[0].startswith("laser front: truncated scan")
        clock.now = 101.5  # older than the report window
        assert laser.health() == []
    finally:
        laser.close()
        device.close()


def test_bad_checksum_is_named(clock):
    corrupt = corrupt_first_block(utm_scan(np.full(1081, 8000), 2))
    device = ScriptedDevice([corrupt])
    laser = ScipClient("127.0.0.1", device.port, clock=clock, name="front")
    try:
        wait_for(lambda: laser.stats().bad_frames == 1)
        assert laser.health() == [
            "laser front: connected, no scan yet",
            "laser front: bad checksum in scan",
        ]
        assert laser.latest() is None
    finally:
        laser.close()
        device.close()
