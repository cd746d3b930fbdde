"""SCIP 2.0: the Hokuyo laser scanners' wire, both ends (issue 14).

The robot's two UTM-30LX-EW scanners speak SCIP 2.0 over TCP. This module holds:

* the codec (pure functions): the 6-bit character encoding (each 6 bits + 0x30, 2-, 3- or
  4-character values), the sum checksum ``(sum of bytes & 0x3F) + 0x30``, the 64-byte data
  blocks, and :func:`parse_response`, which checks a reply (echo, status, every checksum,
  the empty line that ends it) and raises a :class:`ScipError` subclass naming what is
  wrong, so a bad frame is counted and reported instead of becoming wrong ranges;
* :class:`ScipClient`, the executive's end: a background thread that connects, learns the
  scan geometry from ``PP``, switches the laser on and streams every scan (``MD``), turns
  each into a :class:`LaserScan` stamped on arrival, and reconnects by itself when the
  link drops (the executive's stale-sensor rule stops the robot meanwhile; the mission
  goes on once scans flow again);
* :class:`ScipServer`, a device emulator for the hardware-in-the-loop simulator: the same
  bytes a real scanner sends, on 127.0.0.1 only, so the client is tested against the
  protocol and not against a shortcut.

Range values below 20 mm are the UTM-30LX's error codes (no return, low intensity, ...);
the client reports them, and values beyond DMAX, as ``range_max`` (LaserScan's "no
return").
"""

from __future__ import annotations

import contextlib
import math
import socket
import threading
import time
from collections import deque
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from executive.core.records import LaserScan
from executive.robotlink.wire import Wire

LF = b"\n"
BLOCK = 64
"""Data bytes per block line; each block is followed by its checksum and LF."""
ERROR_BELOW_MM = 20
"""UTM-30LX range values 0..19 are error codes, not distances."""
NO_RETURN_CODE = 1
"""The error code the emulator sends for a beam with no return."""
TIMESTAMP_MODULUS = 1 << 24
"""Device timestamps are 4-character (24-bit) millisecond counters that wrap."""

_PARAM_COMMANDS = frozenset({"VV", "PP", "II"})
_CHARS_OF = {"MD": 3, "GD": 3, "MS": 2, "GS": 2}
_STREAM_COMMANDS = frozenset({"MD", "MS"})


# -- errors ---------------------------------------------------------------------------------------
class ScipError(Exception):
    """A SCIP reply that cannot be trusted; the message says why."""


class ScipChecksumError(ScipError):
    """A line's checksum character does not match its bytes."""


class ScipTruncatedError(ScipError):
    """The reply ends early: no terminating empty line, no status, no timestamp."""


class ScipFormatError(ScipError):
    """A line has the wrong shape: bad length, characters outside the encoding."""


class ScipEchoError(ScipError):
    """The reply echoes a different command from the one sent."""


class ScipStatusError(ScipError):
    """The device answered with an error status; ``status`` holds its two characters."""

    def __init__(self, command: str, status: str) -> None:
        self.command = command
        self.status = status
        super().__init__(f"{command} failed: status {status} ({status_meaning(command, status)})")


_COMMON_STATUS = {
    "0A": "unable to create the reply internally",
    "0B": "buffer shortage or command repeated",
    "0C": "command with insufficient parameters",
    "0D": "undefined command",
    "0E": "undefined command",
    "0F": "command with insufficient parameters",
    "0G": "string characters longer than 16",
    "0H": "string characters with invalid letters",
    "0I": "sensor in firmware update mode",
}
_SCAN_STATUS = {
    "01": "starting step is not a number",
    "02": "end step is not a number",
    "03": "cluster count is not a number",
    "04": "end step out of range",
    "05": "end step smaller than starting step",
    "06": "scan interval is not a number",
    "07": "number of scans is not a number",
    "10": "laser is off",
    "98": "resuming after confirming normal laser operation",
}
_BM_STATUS = {"01": "unable to control the laser (malfunction)", "02": "laser is already on"}


def status_meaning(command: str, status: str) -> str:
    """What a status means for a command, after the SCIP 2.0 specification."""
    if status in ("00", "99"):
        return "ok"
    if status in _COMMON_STATUS:
        return _COMMON_STATUS[status]
    if command in _CHARS_OF and status in _SCAN_STATUS:
        return _SCAN_STATUS[status]
    if command == "BM" and status in _BM_STATUS:
        return _BM_STATUS[status]
    if status.isdigit() and 21 <= int(status) <= 49:
        return "processing stopped to verify an error"
    if status.isdigit() and 50 <= int(status) <= 97:
        return "hardware trouble"
    return "unknown status"


# -- codec ----------------------------------------------------------------------------------------
def encode_value(value: int, chars: int) -> bytes:
    """``value`` in ``chars`` characters, 6 bits each (most significant first) + 0x30."""
    if chars < 1:
        raise ValueError(f"chars must be positive, got {chars}")
    if not 0 <= value < 1 << (6 * chars):
        raise ValueError(f"{value} does not fit in {chars} SCIP characters")
    return bytes(((value >> (6 * (chars - 1 - i))) & 0x3F) + 0x30 for i in range(chars))


def decode_value(text: bytes | str) -> int:
    """The value of SCIP-encoded characters (any count)."""
    data = text.encode("ascii", "replace") if isinstance(text, str) else text
    value = 0
    for byte in data:
        if not 0x30 <= byte <= 0x6F:
            raise ScipFormatError(f"byte {byte:#04x} is not a SCIP-encoded character")
        value = (value << 6) | (byte - 0x30)
    return value


def encode_values(values: Sequence[int] | np.ndarray, chars: int) -> bytes:
    """Many values, each in ``chars`` characters, concatenated (no blocks)."""
    arr = np.asarray(values, dtype=np.int64).ravel()
    if arr.size and (arr.min() < 0 or arr.max() >= 1 << (6 * chars)):
        raise ValueError(f"values must lie in 0..{(1 << (6 * chars)) - 1}")
    shifts = 6 * np.arange(chars - 1, -1, -1, dtype=np.int64)
    digits = ((arr[:, None] >> shifts) & 0x3F) + 0x30
    return digits.astype(np.uint8).tobytes()


def decode_values(data: bytes, chars: int) -> np.ndarray:
    """The values of concatenated ``chars``-character fields (int64 array)."""
    if len(data) % chars:
        raise ScipTruncatedError(
            f"{len(data)} data bytes are not a whole number of {chars}-character values"
        )
    raw = np.frombuffer(data, dtype=np.uint8).astype(np.int64)
    if raw.size and (raw.min() < 0x30 or raw.max() > 0x6F):
        raise ScipFormatError("data holds bytes outside the SCIP character encoding")
    digits = (raw - 0x30).reshape(-1, chars)
    shifts = 6 * np.arange(chars - 1, -1, -1, dtype=np.int64)
    return (digits << shifts).sum(axis=1)


def checksum(data: bytes | str) -> bytes:
    """The SCIP sum character of ``data``: ((sum of bytes) & 0x3F) + 0x30, as one byte."""
    raw = data.encode("ascii") if isinstance(data, str) else data
    return bytes(((sum(raw) & 0x3F) + 0x30,))


def encode_ranges(ranges_mm: Sequence[int] | np.ndarray, chars: int = 3) -> bytes:
    """The data blocks of a scan: the encoded values cut into 64-byte lines, each followed
    by its checksum and LF (the reply's final empty line is not included)."""
    return encode_blocks(encode_values(ranges_mm, chars))


def encode_blocks(data: bytes) -> bytes:
    """``data`` cut into 64-byte lines, each with its checksum and LF."""
    return b"".join(
        data[i : i + BLOCK] + checksum(data[i : i + BLOCK]) + LF for i in range(0, len(data), BLOCK)
    )


def param_line(label: str, value: str) -> bytes:
    """One VV/PP/II line, ``LABEL:value;`` + sum + LF; the sum leaves out the semicolon."""
    body = f"{label}:{value}".encode("ascii")
    return body + b";" + checksum(body) + LF


def build_response(echo: str, status: str, payload: bytes = b"") -> bytes:
    """A whole reply: echo, status + sum, payload lines (already with sums), empty line."""
    return echo.encode("ascii") + LF + status.encode("ascii") + checksum(status) + LF + payload + LF


# -- replies --------------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class ScipResponse:
    """A checked reply: the echoed command line, the status and the payload lines with
    their checksums verified and removed (``LABEL:value`` for VV/PP/II)."""

    echo: str
    status: str
    lines: tuple[bytes, ...] = ()

    @property
    def command(self) -> str:
        return self.echo[:2]

    def params(self) -> dict[str, str]:
        """The ``LABEL:value`` lines of a VV, PP or II reply as a dict."""
        out = {}
        for line in self.lines:
            label, sep, value = line.decode("ascii", "replace").partition(":")
            if not sep:
                raise ScipFormatError(f"{self.command} line {line!r} has no 'LABEL:'")
            out[label] = value
        return out


@dataclass(frozen=True, slots=True, eq=False)
class ScanReply:
    """The decoded data of an MD/MS/GD/GS reply: device time (ms, 24-bit) and values."""

    timestamp_ms: int
    values: np.ndarray


def parse_response(
    raw: bytes, *, command: str | None = None, ok: Collection[str] = ("00", "99")
) -> ScipResponse:
    """Check and split one reply (up to and including its empty line).

    ``command``: the command line sent; the echo must match it (for MD/MS scans, except
    for the remaining-scans field). ``ok``: the statuses that are not errors.
    """
    if not raw.endswith(LF + LF):
        raise ScipTruncatedError("truncated reply: it does not end with an empty line")
    lines = raw[:-2].split(LF)
    if len(lines) < 2:
        raise ScipTruncatedError("truncated reply: no status line after the echo")
    if any(not line for line in lines):
        raise ScipFormatError("empty line inside a reply (two replies run together?)")
    echo = _ascii(lines[0], "echo")
    if command is not None and not _echo_matches(command, echo):
        raise ScipEchoError(f"reply echoes {echo!r} but the command sent was {command!r}")
    status = _status(lines[1], echo[:2])
    if status not in ok:
        raise ScipStatusError(echo[:2], status)
    param = echo[:2] in _PARAM_COMMANDS
    payload = tuple(
        _param_payload(line, n) if param else _data_payload(line, n)
        for n, line in enumerate(lines[2:], start=3)
    )
    return ScipResponse(echo, status, payload)


def parse_scan(response: ScipResponse, *, expected: int | None = None) -> ScanReply:
    """The timestamp and values of a scan reply; ``expected`` the number of values."""
    chars = _CHARS_OF.get(response.command)
    if chars is None:
        raise ScipFormatError(f"{response.command} replies carry no scan")
    if not response.lines:
        raise ScipTruncatedError("truncated scan: no timestamp line")
    stamp = response.lines[0]
    if len(stamp) != 4:
        raise ScipFormatError(f"timestamp line has {len(stamp)} characters, not 4")
    values = decode_values(b"".join(response.lines[1:]), chars)
    if expected is not None and len(values) != expected:
        raise ScipTruncatedError(f"scan has {len(values)} values, expected {expected}")
    return ScanReply(decode_value(stamp), values)


def _ascii(line: bytes, what: str) -> str:
    try:
        return line.decode("ascii")
    except UnicodeDecodeError:
        raise ScipFormatError(f"{what} line {line!r} is not ASCII") from None


def _echo_matches(command: str, echo: str) -> bool:
    """True if ``echo`` answers ``command``; an MD/MS scan echoes the scans remaining
    (characters 13-14) instead of the number asked for."""
    if echo == command:
        return True
    scan = command[:2] in _STREAM_COMMANDS and len(command) >= 15 and len(echo) == len(command)
    return scan and echo[:13] == command[:13] and echo[15:] == command[15:]


def _status(line: bytes, command: str) -> str:
    if len(line) != 3:
        raise ScipFormatError(f"{command} status line {line!r} is not 2 characters + checksum")
    if checksum(line[:2]) != line[2:]:
        raise ScipChecksumError(f"bad checksum in {command} status line {line!r}")
    return _ascii(line[:2], "status")


def _param_payload(line: bytes, number: int) -> bytes:
    if len(line) < 3 or line[-2:-1] != b";":
        raise ScipFormatError(f"line {number} {line!r} does not end with ';' + checksum")
    body = line[:-2]
    if checksum(body) != line[-1:]:
        raise ScipChecksumError(f"bad checksum in line {number} {line!r}")
    return body


def _data_payload(line: bytes, number: int) -> bytes:
    if len(line) > BLOCK + 1:
        raise ScipFormatError(
            f"line {number} has {len(line)} bytes, more than a {BLOCK}-byte block + checksum"
            " (missing LF?)"
        )
    if len(line) < 2:
        raise ScipFormatError(f"line {number} {line!r} holds no data before its checksum")
    body = line[:-1]
    if checksum(body) != line[-1:]:
        raise ScipChecksumError(f"bad checksum in line {number} {line!r}")
    return body


# -- geometry -------------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class ScipGeometry:
    """What a PP reply says: range limits (mm), steps per turn, first, last and front
    step, motor speed (rpm). Step k points at (k - afrt) * 2 pi / ares, counter-clockwise."""

    dmin_mm: int
    dmax_mm: int
    ares: int
    amin: int
    amax: int
    afrt: int
    scan_rpm: int

    @classmethod
    def from_params(cls, params: Mapping[str, str]) -> ScipGeometry:
        """Read a PP reply's parameters; ScipFormatError if one is missing or not a number."""
        labels = ("DMIN", "DMAX", "ARES", "AMIN", "AMAX", "AFRT", "SCAN")
        try:
            values = [int(params[label].strip()) for label in labels]
        except (KeyError, ValueError) as exc:
            raise ScipFormatError(f"PP reply lacks a numeric parameter: {exc}") from None
        geometry = cls(*values)
        if geometry.ares <= 0 or not 0 <= geometry.amin <= geometry.amax:
            raise ScipFormatError(f"PP reply gives an impossible geometry: {geometry}")
        return geometry

    @property
    def steps(self) -> int:
        return self.amax - self.amin + 1

    @property
    def angle_increment(self) -> float:
        return 2.0 * math.pi / self.ares

    @property
    def angle_min(self) -> float:
        return (self.amin - self.afrt) * self.angle_increment

    @property
    def range_max(self) -> float:
        return self.dmax_mm / 1000.0

    def to_metres(self, values_mm: np.ndarray) -> np.ndarray:
        """Ranges in m; error codes and values beyond DMAX read ``range_max``."""
        bad = (values_mm < ERROR_BELOW_MM) | (values_mm > self.dmax_mm)
        ranges = np.where(bad, self.dmax_mm, values_mm) / 1000.0
        ranges.setflags(write=False)
        return ranges

    def to_codes(self, ranges_m: np.ndarray) -> np.ndarray:
        """What the device sends for ``ranges_m``: mm, or the no-return code for a beam
        with no return (not finite, below DMIN or at/after DMAX)."""
        r = np.asarray(ranges_m, dtype=float)
        with np.errstate(invalid="ignore"):
            mm = np.rint(np.where(np.isfinite(r), r, -1.0) * 1000.0)
            ok = (mm >= self.dmin_mm) & (mm < self.dmax_mm)
        return np.where(ok, mm, NO_RETURN_CODE).astype(np.int64)

    def param_lines(self, model: str) -> bytes:
        """The payload of a PP reply."""
        pairs = (
            ("MODL", model),
            ("DMIN", self.dmin_mm),
            ("DMAX", self.dmax_mm),
            ("ARES", self.ares),
            ("AMIN", self.amin),
            ("AMAX", self.amax),
            ("AFRT", self.afrt),
            ("SCAN", self.scan_rpm),
        )
        return b"".join(param_line(label, str(value)) for label, value in pairs)


UTM_30LX_EW = ScipGeometry(
    dmin_mm=23, dmax_mm=30000, ares=1440, amin=0, amax=1080, afrt=540, scan_rpm=2400
)
"""The Hokuyo UTM-30LX-EW: 270 deg in 0.25 deg steps, 30 m, 25 ms a scan."""


# -- client ---------------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class ScanStats:
    """How the scans arrive.

    ``scans`` good scans and ``bad_frames`` rejected ones (checksum, shape, status) since
    start; ``connections_lost`` links that dropped while streaming. Over the last 400 scans:
    ``interval_*``: inter-arrival time (s), mean and standard deviation (jitter).
    ``latency_excess_*``: the device clock is not synchronised with ours, so the absolute
    latency is unknown; arrival minus device time is offset + latency, and its excess over
    the window's minimum is the latency added to the best case (queueing, load). None when
    the device timestamps do not advance (then only the inter-arrival jitter is known).
    """

    scans: int
    bad_frames: int
    connections_lost: int
    interval_mean: float | None = None
    interval_jitter: float | None = None
    latency_excess_mean: float | None = None
    latency_excess_max: float | None = None


@dataclass(slots=True)
class _Timing:
    """Arrival statistics over a sliding window; reset on reconnection."""

    window: int = 400
    intervals: deque[float] = field(default_factory=deque)
    offsets: deque[float] = field(default_factory=deque)
    last_arrival: float | None = None
    last_device_ms: int | None = None
    device_wraps: int = 0

    def restart(self) -> None:
        self.offsets.clear()
        self.last_arrival = None
        self.last_device_ms = None
        self.device_wraps = 0

    def add(self, arrival: float, device_ms: int) -> None:
        if self.last_arrival is not None:
            _push(self.intervals, arrival - self.last_arrival, self.window)
        self.last_arrival = arrival
        previous = self.last_device_ms
        self.last_device_ms = device_ms
        if previous is not None and device_ms < previous:
            if previous - device_ms > TIMESTAMP_MODULUS // 2:
                self.device_wraps += 1
            else:
                self.offsets.clear()  # the device clock was reset: start again
                return
        if previous is not None and device_ms == previous:
            self.offsets.clear()  # a clock that does not advance gives no latency
            return
        device_s = (device_ms + self.device_wraps * TIMESTAMP_MODULUS) / 1000.0
        _push(self.offsets, arrival - device_s, self.window)

    def summary(self) -> tuple[float | None, float | None, float | None, float | None]:
        mean = jitter = lat_mean = lat_max = None
        if self.intervals:
            iv = np.asarray(self.intervals)
            mean, jitter = float(iv.mean()), float(iv.std())
        if len(self.offsets) >= 2:
            off = np.asarray(self.offsets)
            excess = off - off.min()
            lat_mean, lat_max = float(excess.mean()), float(excess.max())
        return mean, jitter, lat_mean, lat_max


def _push(window: deque[float], value: float, size: int) -> None:
    window.append(value)
    if len(window) > size:
        window.popleft()


class _Reader:
    """Buffered reads of whole replies (up to the empty line) from a socket."""

    LIMIT = 1 << 16

    def __init__(self, sock: socket.socket) -> None:
        self._sock = sock
        self._buf = bytearray()

    def response(self) -> bytes:
        while True:
            end = self._buf.find(LF + LF)
            if end >= 0:
                raw = bytes(self._buf[: end + 2])
                del self._buf[: end + 2]
                return raw
            if len(self._buf) > self.LIMIT:
                raise ScipFormatError(f"no end of reply within {self.LIMIT} bytes")
            chunk = self._sock.recv(self.LIMIT)
            if not chunk:
                raise ConnectionResetError("the laser closed the connection")
            self._buf += chunk


class _LinkDownError(Exception):
    """A session ended; ``stage`` says how far it got (connect, handshake, streaming)."""

    def __init__(self, stage: str, cause: BaseException) -> None:
        super().__init__(stage)
        self.stage = stage
        self.cause = cause


class ScipClient(Wire):
    """One laser scanner over SCIP 2.0/TCP, read by a background thread.

    The thread connects, sends QT (stop whatever a previous session left running), VV,
    PP (the scan geometry), BM (laser on) and ``MD`` over every step, every scan; each
    scan becomes a :class:`LaserScan` stamped with ``clock()`` on arrival. When the link
    drops it reconnects with a backoff from 0.1 s to 1 s; meanwhile :meth:`latest` keeps
    returning the last scan (its stamp ages, so the executive's stale rule stops the
    robot) and :meth:`health` names the lost connection until scans flow again.

    ``clock`` is called from the background thread and must be thread-safe.
    """

    def __init__(
        self,
        host: str,
        port: int = 10940,
        *,
        clock: Callable[[], float] = time.monotonic,
        name: str = "laser",
        connect_timeout: float = 1.0,
        read_timeout: float = 1.0,
        backoff: tuple[float, float] = (0.1, 1.0),
        report_window: float = 1.0,
    ) -> None:
        self.host, self.port, self.name = host, port, name
        self._clock = clock
        self._connect_timeout = connect_timeout
        self._read_timeout = read_timeout
        self._backoff = backoff
        self._report_window = report_window
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._sock: socket.socket | None = None
        self._latest: LaserScan | None = None
        self._geometry: ScipGeometry | None = None
        self._down: str | None = "not connected yet"
        self._bad: tuple[float, str] | None = None
        self._scans = self._bad_frames = self._connections_lost = 0
        self._timing = _Timing()
        self._thread = threading.Thread(target=self._run, name=f"scip-{name}", daemon=True)
        self._thread.start()

    # -- public -----------------------------------------------------------------------------------
    def latest(self) -> LaserScan | None:
        """The newest scan, None before the first (never blocks)."""
        with self._lock:
            return self._latest

    @property
    def geometry(self) -> ScipGeometry | None:
        """The geometry from the device's PP reply, None before the first handshake."""
        with self._lock:
            return self._geometry

    def health(self) -> list[str]:
        """Why the laser cannot be trusted now (empty: healthy): a connection that is down,
        a bad frame within the last ``report_window`` seconds."""
        now = self._clock()
        with self._lock:
            reasons = [] if self._down is None else [self._down]
            if self._bad is not None and now - self._bad[0] <= self._report_window:
                reasons.append(self._bad[1])
        return [f"laser {self.name}: {reason}" for reason in reasons]

    def stats(self) -> ScanStats:
        """Counts and arrival statistics (see :class:`ScanStats`)."""
        with self._lock:
            counts = (self._scans, self._bad_frames, self._connections_lost)
            return ScanStats(*counts, *self._timing.summary())

    def close(self) -> None:
        """Stop the thread and close the connection."""
        self._stop.set()
        with self._lock:
            sock = self._sock
        if sock is not None:
            _shutdown(sock)
        self._thread.join(timeout=5.0)

    # -- the thread -------------------------------------------------------------------------------
    def _run(self) -> None:
        delay = self._backoff[0]
        while not self._stop.is_set():
            streamed = False
            try:
                streamed = self._session()
            except _LinkDownError as down:
                streamed = down.stage == "streaming"
                if not self._stop.is_set():
                    self._went_down(down)
            if streamed:
                delay = self._backoff[0]
            if self._stop.wait(delay):
                break
            delay = min(2.0 * delay, self._backoff[1])

    def _session(self) -> bool:
        """Connect, hand-shake and stream until the link fails (raises _LinkDownError) or the
        client is closed (returns whether scans flowed)."""
        try:
            sock = socket.create_connection((self.host, self.port), self._connect_timeout)
        except OSError as exc:
            raise _LinkDownError("connect", exc) from exc
        with self._lock:
            self._sock = sock
        stage = "handshake"
        try:
            if self._stop.is_set():  # closed while connecting: close() saw no socket
                return False
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            sock.settimeout(self._read_timeout)
            reader = _Reader(sock)
            geometry, md = self._handshake(sock, reader)
            stage = "streaming"
            self._stream(reader, geometry, md)
        except (OSError, ScipError) as exc:
            if not self._stop.is_set():
                raise _LinkDownError(stage, exc) from exc
        finally:
            with self._lock:
                self._sock = None
            sock.close()
        return stage == "streaming"

    def _handshake(self, sock: socket.socket, reader: _Reader) -> tuple[ScipGeometry, str]:
        _send(sock, "QT")
        _skip_to(reader, "QT")
        _command(sock, reader, "VV")
        geometry = ScipGeometry.from_params(_command(sock, reader, "PP").params())
        _command(sock, reader, "BM", ok=("00", "02"))
        md = f"MD{geometry.amin:04d}{geometry.amax:04d}00000"
        _command(sock, reader, md)
        with self._lock:
            self._geometry = geometry
            self._timing.restart()
            if self._down is None or not self._down.startswith("connection lost"):
                self._down = "connected, no scan yet"
        return geometry, md

    def _stream(self, reader: _Reader, geometry: ScipGeometry, md: str) -> None:
        while not self._stop.is_set():
            raw = reader.response()
            arrival = self._clock()
            try:
                response = parse_response(raw, command=md, ok=("99", "98"))
                if response.status == "98":
                    continue  # the device resumed after checking its laser: no scan
                scan = parse_scan(response, expected=geometry.steps)
            except ScipError as exc:
                self._bad_frame(arrival, exc)
                continue
            self._deliver(arrival, geometry, scan)

    def _deliver(self, arrival: float, geometry: ScipGeometry, scan: ScanReply) -> None:
        laser = LaserScan(
            stamp=arrival,
            angle_min=geometry.angle_min,
            angle_increment=geometry.angle_increment,
            range_max=geometry.range_max,
            ranges=geometry.to_metres(scan.values),
        )
        with self._lock:
            self._latest = laser
            self._scans += 1
            self._timing.add(arrival, scan.timestamp_ms)
            self._down = None

    def _bad_frame(self, arrival: float, exc: ScipError) -> None:
        with self._lock:
            self._bad_frames += 1
            self._bad = (arrival, _bad_frame_reason(exc))

    def _went_down(self, down: _LinkDownError) -> None:
        cause = _describe(down.cause)
        with self._lock:
            if down.stage == "streaming":
                self._down = f"connection lost ({cause})"
                self._connections_lost += 1
            elif self._down is None or not self._down.startswith("connection lost"):
                what = "cannot connect" if down.stage == "connect" else "handshake failed"
                self._down = f"{what} ({cause})"


def _send(sock: socket.socket, command: str) -> None:
    sock.sendall(command.encode("ascii") + LF)


def _command(
    sock: socket.socket, reader: _Reader, command: str, ok: Collection[str] = ("00",)
) -> ScipResponse:
    _send(sock, command)
    return parse_response(reader.response(), command=command, ok=ok)


def _skip_to(reader: _Reader, command: str, limit: int = 400) -> ScipResponse:
    """Read past what a previous session left streaming, up to ``command``'s reply."""
    for _ in range(limit):
        raw = reader.response()
        if raw.startswith(command.encode("ascii") + LF):
            return parse_response(raw, command=command, ok=("00",))
    raise ScipEchoError(f"no reply to {command} within {limit} replies")


def _describe(exc: BaseException) -> str:
    if isinstance(exc, ScipError):
        return f"{type(exc).__name__}: {exc}"
    return type(exc).__name__


def _bad_frame_reason(exc: ScipError) -> str:
    if isinstance(exc, ScipChecksumError):
        return "bad checksum in scan"
    if isinstance(exc, ScipStatusError):
        return f"scan status {exc.status} ({status_meaning(exc.command, exc.status)})"
    if isinstance(exc, ScipTruncatedError):
        return f"truncated scan ({exc})"
    return f"malformed scan ({exc})"


def _shutdown(sock: socket.socket) -> None:
    with contextlib.suppress(OSError):
        sock.shutdown(socket.SHUT_RDWR)
    with contextlib.suppress(OSError):
        sock.close()


# -- device emulator ------------------------------------------------------------------------------
LOOPBACK = "127.0.0.1"


@dataclass(slots=True)
class _Stream:
    """A client's MD/MS request: steps, cluster, scans skipped between two sent, scans
    left (0: until QT), and the echo's parts. The first scan goes out at once, then
    ``skip`` are left out before each next one."""

    command: str
    start: int
    end: int
    cluster: int
    skip: int
    remaining: int
    tag: str
    skipped: int = 0

    def echo(self) -> str:
        steps = f"{self.start:04d}{self.end:04d}{self.cluster:02d}"
        return f"{self.command}{steps}{self.skip:01d}{self.remaining:02d}{self.tag}"


@dataclass(eq=False, slots=True)
class _Peer:
    sock: socket.socket
    lock: threading.Lock = field(default_factory=threading.Lock)
    stream: _Stream | None = None
    open: bool = True


class ScipServer(Wire):
    """A UTM-30LX-EW on 127.0.0.1 for the hardware-in-the-loop simulator.

    It answers VV, PP, II, BM, QT, RS, GD/GS and MD/MS as the specification says, and
    :meth:`publish` (the simulator's 40 Hz scan) goes to every client streaming MD/MS,
    honouring its steps, cluster count, interval and scan count. One thread accepts,
    one per client reads commands; publish writes from the caller's thread, with a send
    timeout so a client that stops reading is dropped rather than stalling the simulator.
    """

    MODEL = "UTM-30LX-EW(walkaround emulator)"

    def __init__(
        self, port: int = 0, *, geometry: ScipGeometry = UTM_30LX_EW, send_timeout: float = 0.5
    ) -> None:
        self.geometry = geometry
        self._send_timeout = send_timeout
        self._lock = threading.Lock()
        self._peers: list[_Peer] = []
        self._closed = threading.Event()
        self._laser_on = False
        self._codes = np.full(geometry.steps, NO_RETURN_CODE, dtype=np.int64)
        self._stamp_ms = 0
        self._listener = socket.create_server((LOOPBACK, port))
        self._listener.settimeout(0.1)
        self.port: int = self._listener.getsockname()[1]
        self._threads: list[threading.Thread] = []
        self._spawn(self._accept, "scip-server-accept")

    # -- public -----------------------------------------------------------------------------------
    @property
    def client_count(self) -> int:
        with self._lock:
            return len(self._peers)

    def publish(self, ranges_m: np.ndarray, stamp_ms: int) -> None:
        """A new scan (metres over steps amin..amax; no return: inf, nan or >= DMAX) taken
        at device time ``stamp_ms``; sent to every client in continuous mode."""
        codes = self.geometry.to_codes(ranges_m)
        if codes.shape != (self.geometry.steps,):
            raise ValueError(f"expected {self.geometry.steps} ranges, got {codes.shape}")
        with self._lock:
            self._codes, self._stamp_ms = codes, int(stamp_ms) % TIMESTAMP_MODULUS
            peers = list(self._peers)
        for peer in peers:
            self._push_scan(peer, codes, int(stamp_ms) % TIMESTAMP_MODULUS)

    def drop_connections(self) -> None:
        """Close every client's socket (a fault: the cable pulled); keep listening."""
        with self._lock:
            peers, self._peers = self._peers, []
        for peer in peers:
            self._drop(peer)

    def close(self) -> None:
        """Stop listening, drop every client, join the threads."""
        self._closed.set()
        self.drop_connections()
        with contextlib.suppress(OSError):
            self._listener.close()
        for thread in self._threads:
            if thread is not threading.current_thread():
                thread.join(timeout=2.0)

    # -- threads ----------------------------------------------------------------------------------
    def _spawn(self, target: Callable[..., None], name: str, *args: object) -> None:
        thread = threading.Thread(target=target, name=name, args=args, daemon=True)
        self._threads = [t for t in self._threads if t.is_alive()] + [thread]
        thread.start()

    def _accept(self) -> None:
        while not self._closed.is_set():
            try:
                sock, _ = self._listener.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            sock.settimeout(self._send_timeout)
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            peer = _Peer(sock)
            with self._lock:
                if self._closed.is_set():
                    _shutdown(sock)
                    return
                self._peers.append(peer)
            self._spawn(self._serve, f"scip-server-{self.port}", peer)

    def _serve(self, peer: _Peer) -> None:
        buf = bytearray()
        while peer.open and not self._closed.is_set():
            try:
                chunk = peer.sock.recv(4096)
            except TimeoutError:
                continue
            except OSError:
                break
            if not chunk:
                break
            buf += chunk.replace(b"\r", LF)
            while (end := buf.find(LF)) >= 0:
                line = bytes(buf[:end]).decode("ascii", "replace")
                del buf[: end + 1]
                if line:
                    self._handle(peer, line)
        self._forget(peer)

    def _forget(self, peer: _Peer) -> None:
        with self._lock:
            if peer in self._peers:
                self._peers.remove(peer)
        self._drop(peer)

    def _drop(self, peer: _Peer) -> None:
        peer.open = False
        _shutdown(peer.sock)

    def _send(self, peer: _Peer, data: bytes) -> None:
        """Write under the peer's lock (held by the caller); drop the peer on failure."""
        try:
            peer.sock.sendall(data)
        except OSError:
            peer.stream = None
            self._drop(peer)

    # -- commands ---------------------------------------------------------------------------------
    def _handle(self, peer: _Peer, line: str) -> None:
        with peer.lock:
            self._send(peer, self._reply(peer, line))

    def _reply(self, peer: _Peer, line: str) -> bytes:
        code = line[:2]
        if code in ("VV", "PP", "II", "BM", "QT", "RS"):
            return self._simple(peer, code, line)
        if code in ("GD", "GS"):
            return self._single(code, line)
        if code in ("MD", "MS"):
            return self._start_stream(peer, code, line)
        return build_response(line, "0E")

    def _simple(self, peer: _Peer, code: str, line: str) -> bytes:
        if code == "VV":
            return build_response(line, "00", self._version_lines())
        if code == "PP":
            return build_response(line, "00", self.geometry.param_lines(self.MODEL))
        if code == "II":
            return build_response(line, "00", self._status_lines())
        if code == "BM":
            with self._lock:
                was_on, self._laser_on = self._laser_on, True
            return build_response(line, "02" if was_on else "00")
        peer.stream = None  # QT and RS stop this client's stream and the laser
        with self._lock:
            self._laser_on = False
        return build_response(line, "00")

    def _version_lines(self) -> bytes:
        return b"".join(
            param_line(label, value)
            for label, value in (
                ("VEND", "Hokuyo Automatic Co.,Ltd."),
                ("PROD", "SOKUIKI Sensor TOP-URG UTM-30LX-EW (walkaround emulator)"),
                ("FIRM", "walkaround"),
                ("PROT", "SCIP 2.0"),
                ("SERI", "H0000000"),
            )
        )

    def _status_lines(self) -> bytes:
        with self._lock:
            on, stamp = self._laser_on, self._stamp_ms
            measuring = any(p.stream is not None for p in self._peers)
        return b"".join(
            param_line(label, value)
            for label, value in (
                ("MODL", self.MODEL),
                ("LASR", "ON" if on else "OFF"),
                ("SCSP", f"Initial({self.geometry.scan_rpm}[rpm])"),
                ("MESM", "Measuring by Sensitive Mode" if measuring else "Idle"),
                ("SBPS", "Ethernet 100 [Mbps]"),
                ("TIME", encode_value(stamp, 4).decode("ascii")),
                ("STAT", "Stable 000 no error."),
            )
        )

    def _steps(self, line: str, with_stream: bool) -> tuple[str, tuple[int, ...]]:
        """(status, numbers) of a GD/MD request: start, end, cluster[, interval, scans]."""
        fields = ((2, 6, "01"), (6, 10, "02"), (10, 12, "03"))
        if with_stream:
            fields += ((12, 13, "06"), (13, 15, "07"))
        body = line.partition(";")[0]
        if len(body) < fields[-1][1]:
            return "0C", ()
        if len(body) > fields[-1][1]:
            return "0F", ()
        numbers = []
        for lo, hi, error in fields:
            if not body[lo:hi].isdigit():
                return error, ()
            numbers.append(int(body[lo:hi]))
        if numbers[1] > self.geometry.amax or numbers[0] < self.geometry.amin:
            return "04", ()
        if numbers[1] < numbers[0]:
            return "05", ()
        return "00", tuple(numbers)

    def _single(self, code: str, line: str) -> bytes:
        status, numbers = self._steps(line, with_stream=False)
        if status != "00":
            return build_response(line, status)
        with self._lock:
            on, codes, stamp = self._laser_on, self._codes, self._stamp_ms
        if not on:
            return build_response(line, "10")
        start, end, cluster = numbers
        payload = self._scan_payload(code, codes, stamp, start, end, cluster)
        return build_response(line, "00", payload)

    def _start_stream(self, peer: _Peer, code: str, line: str) -> bytes:
        status, numbers = self._steps(line, with_stream=True)
        if status != "00":
            return build_response(line, status)
        start, end, cluster, skip, count = numbers
        tag = line[15:]
        with self._lock:
            self._laser_on = True  # MD/MS switch the laser on by themselves
        peer.stream = _Stream(code, start, end, cluster, skip, count, tag, skipped=skip)
        return build_response(line, "00")

    # -- scans ------------------------------------------------------------------------------------
    def _scan_payload(
        self, code: str, codes: np.ndarray, stamp: int, start: int, end: int, cluster: int
    ) -> bytes:
        chars = _CHARS_OF[code]
        values = _cluster(codes[start - self.geometry.amin : end - self.geometry.amin + 1], cluster)
        # a range the encoding cannot hold (2 characters: 4095 mm) is sent as no return,
        # never clamped into a nearer obstacle
        values = np.where(values < 1 << (6 * chars), values, NO_RETURN_CODE)
        stamp_chars = encode_value(stamp, 4)
        return stamp_chars + checksum(stamp_chars) + LF + encode_ranges(values, chars)

    def _push_scan(self, peer: _Peer, codes: np.ndarray, stamp: int) -> None:
        with peer.lock:
            stream = peer.stream
            if stream is None or not peer.open:
                return
            if stream.skipped < stream.skip:
                stream.skipped += 1
                return
            stream.skipped = 0
            if stream.remaining > 0:
                stream.remaining -= 1
                if stream.remaining == 0:
                    peer.stream = None  # the last of the scans asked for
            payload = self._scan_payload(
                stream.command, codes, stamp, stream.start, stream.end, stream.cluster
            )
            self._send(peer, build_response(stream.echo(), "99", payload))


def _cluster(codes: np.ndarray, cluster: int) -> np.ndarray:
    """Group ``cluster`` neighbouring steps into one value: the nearest valid range of
    the group, or the no-return code when the group has none."""
    if cluster <= 1:
        return codes
    pad = (-len(codes)) % cluster
    padded = np.concatenate((codes, np.full(pad, NO_RETURN_CODE, dtype=np.int64)))
    groups = padded.reshape(-1, cluster)
    valid = np.where(groups >= ERROR_BELOW_MM, groups, np.iinfo(np.int64).max)
    nearest = valid.min(axis=1)
    return np.where(nearest == np.iinfo(np.int64).max, NO_RETURN_CODE, nearest)
