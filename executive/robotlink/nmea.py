"""The GPS wire: NMEA 0183 sentences in, :class:`GpsFix` in the airport frame A out.

Why this module exists: the executive reasons in A (x east, y north by default, metres;
docs/mission-format.md), while a GNSS receiver speaks latitude and longitude as NMEA text
over a serial port or a TCP socket. This module is the only place where the two meet.

Frame A on the globe (:class:`GeoReference`)
    A's origin is a point given by latitude, longitude and ellipsoidal height on WGS-84,
    and its +x axis points along a bearing (degrees clockwise from true north; 90: east,
    the convention of every shipped mission). A is right-handed with z up, so +y lies
    90 degrees counter-clockwise from +x seen from above (bearing - 90). Positions go
    through the local tangent plane (ENU) at the origin: exact on the tangent plane, and
    the plane differs from the ground by less than a millimetre horizontally within a few
    kilometres, far below any GNSS error. A fix is taken to lie at the origin's height
    (the robot drives on the apron), so :meth:`GeoReference.to_airport` is 2D.

Accuracy (``GpsFix.sigma``)
    The executive's filter uses ``sigma`` as the 1-sigma error *per axis* of an isotropic
    position error (covariance ``sigma**2 * I``). From a GST sentence
    ``sigma = sqrt((sd_lat**2 + sd_lon**2) / 2)``: the isotropic covariance with the same
    trace as the receiver's ``diag(sd_lat**2, sd_lon**2)`` (its DRMS divided by sqrt 2).
    Without a GST of the same epoch (UTC within :data:`GST_PAIRING_S`) it falls back to
    ``sigma = HDOP * UERE / sqrt(2)``, since DRMS = HDOP * UERE, with the user equivalent
    range error of :data:`UERE_M` for the fix quality: 5 m for a standalone fix (a
    conservative single-frequency figure), 1 m DGPS, 0.5 m RTK float, 0.02 m RTK fixed.
    Sigma is never below :data:`MIN_SIGMA` (the filter rejects a zero).

What counts as a fix
    Positions come from GGA only (RMC is accepted as a live sentence but carries no
    accuracy). GGA quality 1, 2, 3, 4, 5 and 8 (simulation) give a fix; 0 (invalid),
    6 (dead reckoning: the receiver's own odometry, which the filter would double count)
    and 7 (manual input), or an empty latitude/longitude, mean *no fix*: ``latest()``
    becomes None until the next fix.

Hard faults and soft status
    A GPS without a fix is no reason to stop: the executive treats GPS as degradable and
    carries the pose on odometry and laser registration. So :meth:`NmeaDecoder.health`
    lists only *hard* faults, of which GPS has one: the NMEA stream is lost (no valid
    sentence for ``stale_after`` s: unplugged, wrong baud rate, server gone).
    :meth:`NmeaDecoder.status` lists *soft* ones: no fix, bad checksums, truncated or
    unreadable lines, malformed fields (the counted kinds are listed while the last one
    is younger than ``recent`` s; the counts themselves never reset, see ``counts()``).
    ``problems`` is both, hard first.

Time
    A fix is stamped with the caller's ``clock()`` when its line arrives, like every other
    sensor reading. The receiver's UTC time of day is only used to pair GGA with GST and
    for the ``utc_lag`` statistic (wall clock minus sentence UTC), which means something
    only when the host clock is synchronised to UTC (NTP or PPS).

Wires
    :class:`NmeaClient` reads any pyserial URL (``/dev/ttyUSB0``, ``socket://host:port``,
    ``rfc2217://...``) in a background thread and reconnects with a 0.1 -> 1 s backoff.
    :class:`NmeaServer` is the hardware-in-the-loop end: a loopback TCP server that
    writes GST + GGA for every published fix. Parsing and sentence building go through
    pynmea2 objects; only line framing (bytes up to a newline) is done here.
"""

from __future__ import annotations

import datetime as dt
import math
import socket
import threading
import time
from collections import Counter, deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

import pynmea2
import serial

from executive.core.records import GpsFix
from executive.robotlink.wire import Wire

Clock = Callable[[], float]

_WGS84_A = 6_378_137.0
_WGS84_F = 1.0 / 298.257_223_563
_WGS84_E2 = _WGS84_F * (2.0 - _WGS84_F)

UERE_M: Mapping[int, float] = MappingProxyType({1: 5.0, 2: 1.0, 3: 5.0, 4: 0.02, 5: 0.5, 8: 5.0})
"""GGA fix quality -> user equivalent range error (m, 1 sigma); qualities absent: no fix."""

MIN_SIGMA = 0.001
"""The smallest sigma a fix gets (m)."""

GST_PAIRING_S = 2.0
"""A GST pairs with a GGA whose UTC time of day is within this many seconds of its own."""

_MAX_LINE = 4096
"""Bytes without a newline after which the buffered line is dropped as garbage."""
_READ_TIMEOUT = 0.1
_BACKOFF_MIN = 0.1
_BACKOFF_MAX = 1.0
_JOIN_TIMEOUT = 6.0
_LOOPBACK = "127.0.0.1"
_SEND_TIMEOUT = 1.0
_SECONDS_PER_DAY = 86_400.0


# -- geodesy ----------------------------------------------------------------------------------
def _ecef(lat: float, lon: float, h: float) -> tuple[float, float, float]:
    """Geodetic (rad, rad, m above the ellipsoid) -> Earth-centred Earth-fixed (m)."""
    s, c = math.sin(lat), math.cos(lat)
    n = _WGS84_A / math.sqrt(1.0 - _WGS84_E2 * s * s)
    return ((n + h) * c * math.cos(lon), (n + h) * c * math.sin(lon), (n * (1 - _WGS84_E2) + h) * s)


def _geodetic(x: float, y: float, z: float) -> tuple[float, float, float]:
    """ECEF (m) -> geodetic (rad, rad, m): fixed-point iteration on the latitude, converged
    to 1e-15 rad (nm) within a few steps anywhere off the Earth's centre."""
    p = math.hypot(x, y)
    lat = math.atan2(z, p * (1.0 - _WGS84_E2))
    for _ in range(12):
        s = math.sin(lat)
        n = _WGS84_A / math.sqrt(1.0 - _WGS84_E2 * s * s)
        new = math.atan2(z + _WGS84_E2 * n * s, p)
        done = abs(new - lat) < 1e-15
        lat = new
        if done:
            break
    s, c = math.sin(lat), math.cos(lat)
    h = p * c + z * s - _WGS84_A * math.sqrt(1.0 - _WGS84_E2 * s * s)
    return lat, math.atan2(y, x), h


@dataclass(frozen=True, slots=True)
class GeoReference:
    """Where the airport frame A lies on the WGS-84 ellipsoid.

    ``latitude_deg``/``longitude_deg``/``altitude_m`` (ellipsoidal height) place A's origin;
    ``x_axis_bearing_deg`` is the bearing of +x_A, clockwise from true north (90: x east,
    y north). The maps go through the tangent plane (ENU) at the origin, see the module
    docstring.
    """

    latitude_deg: float
    longitude_deg: float
    x_axis_bearing_deg: float
    altitude_m: float = 0.0
    _origin: tuple[float, float, float] = field(init=False, repr=False, compare=False)
    _trig: tuple[float, ...] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        values = (self.latitude_deg, self.longitude_deg, self.x_axis_bearing_deg, self.altitude_m)
        if not all(math.isfinite(v) for v in values):
            raise ValueError(f"geo reference must be finite: {values}")
        if not -89.0 <= self.latitude_deg <= 89.0:
            raise ValueError(f"latitude {self.latitude_deg} deg: an airport lies within 89 deg")
        lat, lon = math.radians(self.latitude_deg), math.radians(self.longitude_deg)
        bearing = math.radians(self.x_axis_bearing_deg)
        object.__setattr__(self, "_origin", _ecef(lat, lon, self.altitude_m))
        trig = (math.sin(lat), math.cos(lat), math.sin(lon), math.cos(lon))
        object.__setattr__(self, "_trig", (*trig, math.sin(bearing), math.cos(bearing)))

    def to_airport(self, latitude_deg: float, longitude_deg: float) -> tuple[float, float]:
        """A point on the ground (at the origin's height) -> (x, y) in A (m)."""
        lat, lon = math.radians(latitude_deg), math.radians(longitude_deg)
        east, north, _ = self._enu(_ecef(lat, lon, self.altitude_m))
        sin_b, cos_b = self._trig[4], self._trig[5]
        return east * sin_b + north * cos_b, -east * cos_b + north * sin_b

    def to_geodetic(self, x: float, y: float) -> tuple[float, float]:
        """(x, y) in A -> (latitude, longitude) in degrees of the ground point (at the
        origin's height) that :meth:`to_airport` maps to (x, y)."""
        sin_b, cos_b = self._trig[4], self._trig[5]
        east, north = x * sin_b - y * cos_b, x * cos_b + y * sin_b
        up = 0.0
        lat = lon = 0.0
        for _ in range(8):  # find the height above the plane that lands on the ground
            lat, lon, h = _geodetic(*self._ecef_of(east, north, up))
            error = h - self.altitude_m
            if abs(error) < 1e-9:
                break
            up -= error
        return math.degrees(lat), math.degrees(lon)

    def _enu(self, point: tuple[float, float, float]) -> tuple[float, float, float]:
        sin_lat, cos_lat, sin_lon, cos_lon = self._trig[:4]
        dx, dy, dz = (p - o for p, o in zip(point, self._origin, strict=True))
        east = -sin_lon * dx + cos_lon * dy
        north = -sin_lat * cos_lon * dx - sin_lat * sin_lon * dy + cos_lat * dz
        up = cos_lat * cos_lon * dx + cos_lat * sin_lon * dy + sin_lat * dz
        return east, north, up

    def _ecef_of(self, east: float, north: float, up: float) -> tuple[float, float, float]:
        sin_lat, cos_lat, sin_lon, cos_lon = self._trig[:4]
        ox, oy, oz = self._origin
        return (
            ox - sin_lon * east - sin_lat * cos_lon * north + cos_lat * cos_lon * up,
            oy + cos_lon * east - sin_lat * sin_lon * north + cos_lat * sin_lon * up,
            oz + cos_lat * north + sin_lat * up,
        )


# -- accuracy ---------------------------------------------------------------------------------
def sigma_from_gst(sd_latitude: float, sd_longitude: float) -> float:
    """Per-axis sigma (m) with the trace of the GST covariance (module docstring)."""
    return max(MIN_SIGMA, math.sqrt((sd_latitude**2 + sd_longitude**2) / 2.0))


def sigma_from_hdop(hdop: float, quality: int) -> float:
    """Per-axis sigma (m) from HDOP: DRMS = HDOP * UERE, sigma = DRMS / sqrt 2."""
    return max(MIN_SIGMA, hdop * UERE_M[quality] / math.sqrt(2.0))


# -- statistics -------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class ArrivalStats:
    """Inter-arrival times (s) of the last ``window`` arrivals; NaN before two arrivals."""

    count: int
    mean_interval: float = math.nan
    max_interval: float = math.nan
    last_interval: float = math.nan


class IntervalMeter:
    """Counts arrivals and keeps the intervals between the recent ones.

    Not locked: its owner serialises ``mark`` and ``snapshot``.
    """

    def __init__(self, window: int = 100) -> None:
        self._intervals: deque[float] = deque(maxlen=window)
        self._last: float | None = None
        self._count = 0

    def mark(self, now: float) -> None:
        if self._last is not None:
            self._intervals.append(now - self._last)
        self._last = now
        self._count += 1

    def snapshot(self) -> ArrivalStats:
        if not self._intervals:
            return ArrivalStats(self._count)
        intervals = self._intervals
        return ArrivalStats(
            self._count, sum(intervals) / len(intervals), max(intervals), intervals[-1]
        )


@dataclass(frozen=True, slots=True)
class NmeaStats:
    """Arrival statistics of valid sentences and of fixes, and the latest and worst recent
    ``utc_lag`` (wall clock minus the GGA's UTC time of day, s; see the module docstring)."""

    sentences: ArrivalStats
    fixes: ArrivalStats
    utc_lag: float = math.nan
    utc_lag_max: float = math.nan


@dataclass(frozen=True, slots=True)
class NmeaCounts:
    """Totals since start. ``sentences``: lines that parsed with a valid checksum;
    ``unsupported``: valid sentences of a type pynmea2 does not know (ignored, no problem);
    ``connections``/``link_errors``: successful opens of the wire and failures."""

    lines: int = 0
    sentences: int = 0
    fixes: int = 0
    no_fix: int = 0
    bad_checksum: int = 0
    truncated: int = 0
    garbage: int = 0
    malformed: int = 0
    unsupported: int = 0
    connections: int = 0
    link_errors: int = 0


_COUNTED_PROBLEMS = (
    ("bad_checksum", "bad NMEA checksum", "sentence"),
    ("truncated", "truncated NMEA, no checksum", "sentence"),
    ("garbage", "unreadable NMEA", "line"),
    ("malformed", "malformed NMEA fields", "sentence"),
)
"""Counter name, what the status says, what it counts: the soft, counted problems."""


def _plural(n: int, unit: str) -> str:
    return f"{n} {unit}" + ("" if n == 1 else "s")


def _positive_float(value: object) -> float | None:
    """A field pynmea2 left as text (or converted) as a finite positive float, else None."""
    try:
        number = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return None
    return number if math.isfinite(number) and number > 0.0 else None


def _seconds_of_day(value: object) -> float | None:
    if not isinstance(value, dt.time):
        return None
    return value.hour * 3600.0 + value.minute * 60.0 + value.second + value.microsecond * 1e-6


def _wrapped_day(seconds: float) -> float:
    """A time-of-day difference wrapped to [-12 h, 12 h)."""
    half = _SECONDS_PER_DAY / 2.0
    return (seconds + half) % _SECONDS_PER_DAY - half


def _same_epoch(utc_a: float, utc_b: float) -> bool:
    return abs(_wrapped_day(utc_a - utc_b)) <= GST_PAIRING_S


@dataclass(frozen=True, slots=True)
class _Gst:
    utc: float
    sigma: float


# -- decoding ---------------------------------------------------------------------------------
class NmeaDecoder:
    """Turns NMEA bytes into fixes in A, with counts, statistics and problem reports.

    Separate from the wire so that parsing is testable without sockets and the same
    decoder survives reconnects. Thread-safe: one thread feeds, any thread reads.
    """

    def __init__(
        self,
        geo: GeoReference,
        clock: Clock,
        name: str = "gps",
        *,
        stale_after: float = 2.0,
        recent: float = 10.0,
        wall_clock: Clock = time.time,
    ) -> None:
        self.geo = geo
        self.name = name
        self.stale_after = stale_after
        self.recent = recent
        self._clock = clock
        self._wall_clock = wall_clock
        self._lock = threading.Lock()
        self._buffer = bytearray()
        self._counts: Counter[str] = Counter()
        self._last_seen: dict[str, float] = {}
        self._started = clock()
        self._fix: GpsFix | None = None
        self._last_fix: float | None = None
        self._last_valid: float | None = None
        self._no_fix_why: str | None = None
        self._gst: _Gst | None = None
        self._link_error: str | None = None
        self._sentence_meter = IntervalMeter()
        self._fix_meter = IntervalMeter()
        self._utc_lags: deque[float] = deque(maxlen=100)

    # feeding ---------------------------------------------------------------------------------
    def feed(self, data: bytes) -> None:
        """Bytes as they came off the wire; complete lines are decoded, stamped now."""
        now = self._clock()
        with self._lock:
            self._buffer += data
            while (end := self._buffer.find(b"\n")) >= 0:
                line = bytes(self._buffer[:end])
                del self._buffer[: end + 1]
                self._line(line, now)
            if len(self._buffer) > _MAX_LINE:
                self._buffer.clear()
                self._count("garbage", now)

    def reset_line(self) -> None:
        """Forget a partial line (the wire was reopened: its rest will never come)."""
        with self._lock:
            self._buffer.clear()

    def note_connected(self) -> None:
        with self._lock:
            self._counts["connections"] += 1
            self._link_error = None

    def note_link_error(self, text: str) -> None:
        with self._lock:
            self._counts["link_errors"] += 1
            self._link_error = text

    def _count(self, what: str, now: float) -> None:
        self._counts[what] += 1
        self._last_seen[what] = now

    def _line(self, raw: bytes, now: float) -> None:
        try:
            text = raw.decode("ascii").strip()
        except UnicodeDecodeError:
            self._counts["lines"] += 1
            self._count("garbage", now)
            return
        if not text:
            return
        self._counts["lines"] += 1
        message = self._parse(text, now)
        if message is None:
            return
        self._count("sentences", now)
        self._last_valid = now
        self._sentence_meter.mark(now)
        if isinstance(message, pynmea2.GGA):
            self._on_gga(message, now)
        elif isinstance(message, pynmea2.GST):
            self._on_gst(message, now)

    def _parse(self, text: str, now: float) -> pynmea2.NMEASentence | None:
        try:
            return pynmea2.parse(text, check=True)
        except pynmea2.ChecksumError:
            self._count("bad_checksum" if "*" in text else "truncated", now)
        except pynmea2.SentenceTypeError:
            self._count("unsupported", now)  # a valid sentence we have no use for
            self._last_valid = now
        except pynmea2.ParseError:
            self._count("garbage", now)
        return None

    # sentences ----------------------------------------------------------------------------
    def _on_gga(self, msg: pynmea2.GGA, now: float) -> None:
        quality = msg.gps_qual
        if quality is not None and not isinstance(quality, int):
            self._count("malformed", now)
            return
        if quality not in UERE_M or not msg.lat or not msg.lon:
            self._count("no_fix", now)
            why = "without position" if quality in UERE_M else f"quality {quality}"
            self._fix, self._no_fix_why = None, f"GGA {why}"
            return
        position = self._position(msg)
        sigma = self._sigma(msg, quality)
        if position is None or sigma is None:
            self._count("malformed", now)
            return
        x, y = self.geo.to_airport(*position)
        self._fix, self._last_fix, self._no_fix_why = GpsFix(now, x, y, sigma), now, None
        self._counts["fixes"] += 1
        self._fix_meter.mark(now)
        self._note_utc_lag(_seconds_of_day(msg.timestamp))

    @staticmethod
    def _position(msg: pynmea2.GGA) -> tuple[float, float] | None:
        if msg.lat_dir not in ("N", "S") or msg.lon_dir not in ("E", "W"):
            return None
        try:
            lat, lon = msg.latitude, msg.longitude
        except ValueError:
            return None
        return (lat, lon) if abs(lat) <= 90.0 and abs(lon) <= 180.0 else None

    def _sigma(self, msg: pynmea2.GGA, quality: int) -> float | None:
        utc, gst = _seconds_of_day(msg.timestamp), self._gst
        if gst is not None and utc is not None and _same_epoch(utc, gst.utc):
            return gst.sigma
        hdop = _positive_float(msg.horizontal_dil)
        return None if hdop is None else sigma_from_hdop(hdop, quality)

    def _on_gst(self, msg: pynmea2.GST, now: float) -> None:
        sd_lat, sd_lon = msg.std_dev_latitude, msg.std_dev_longitude
        utc = _seconds_of_day(msg.timestamp)
        if sd_lat is None and sd_lon is None:
            return  # a receiver without an error estimate: HDOP it is
        sd_lat, sd_lon = _positive_float(sd_lat), _positive_float(sd_lon)
        if sd_lat is None or sd_lon is None or utc is None:
            self._count("malformed", now)
            return
        self._gst = _Gst(utc, sigma_from_gst(sd_lat, sd_lon))

    def _note_utc_lag(self, utc: float | None) -> None:
        if utc is None:
            return
        wall = self._wall_clock() % _SECONDS_PER_DAY
        self._utc_lags.append(_wrapped_day(wall - utc))

    # reading ------------------------------------------------------------------------------
    def latest(self) -> GpsFix | None:
        """The latest fix, or None when there was none yet or the receiver since reported
        no fix. A fix is not withdrawn when the stream goes silent: its stamp ages."""
        with self._lock:
            return self._fix

    def counts(self) -> NmeaCounts:
        with self._lock:
            return NmeaCounts(**{k: self._counts[k] for k in NmeaCounts.__dataclass_fields__})

    def stats(self) -> NmeaStats:
        with self._lock:
            lags = self._utc_lags
            return NmeaStats(
                self._sentence_meter.snapshot(),
                self._fix_meter.snapshot(),
                lags[-1] if lags else math.nan,
                max(lags, key=abs) if lags else math.nan,
            )

    def health(self) -> list[str]:
        """Hard faults: only a lost NMEA stream (module docstring). Empty: healthy."""
        now = self._clock()
        with self._lock:
            silent = now - (self._started if self._last_valid is None else self._last_valid)
            if silent <= self.stale_after:
                return []
            detail = f"; {self._link_error}" if self._link_error else ""
            label = self.name.upper()
            return [f"{label}: NMEA stream lost (no valid sentence for {silent:.1f} s{detail})"]

    def status(self) -> list[str]:
        """Soft problems, which degrade but do not stop: no fix, and recent bad lines."""
        now = self._clock()
        label = self.name.upper()
        with self._lock:
            out = self._no_fix_status(now, label)
            for key, text, unit in _COUNTED_PROBLEMS:
                last = self._last_seen.get(key)
                if last is not None and now - last <= self.recent:
                    out.append(f"{label}: {text} ({_plural(self._counts[key], unit)})")
            return out

    def _no_fix_status(self, now: float, label: str) -> list[str]:
        fix = self._fix
        if fix is not None and now - fix.stamp <= self.stale_after:
            return []
        since = now - (self._started if self._last_fix is None else self._last_fix)
        why = "" if self._no_fix_why is None else f" ({self._no_fix_why})"
        return [f"{label}: no fix since {since:.1f} s{why}"]

    @property
    def problems(self) -> list[str]:
        """Hard faults, then soft problems."""
        return self.health() + self.status()


# -- the wire: client -------------------------------------------------------------------------
class NmeaClient(Wire):
    """Reads an NMEA stream from any pyserial URL in a background thread.

    One code path for a receiver on a serial port (``/dev/ttyUSB0``) and for the simulator
    or a networked receiver (``socket://127.0.0.1:PORT``): pyserial's URL handlers. The
    wire is reopened after any error with a backoff from 0.1 s doubling to 1 s (reset once
    a valid sentence arrives), so a replugged receiver or a restarted simulator comes back
    by itself. Reading, counts and problem reports are those of :class:`NmeaDecoder`.
    """

    def __init__(
        self,
        url: str,
        geo: GeoReference,
        clock: Clock,
        name: str = "gps",
        *,
        baudrate: int = 38400,
        stale_after: float = 2.0,
        recent: float = 10.0,
        wall_clock: Clock = time.time,
    ) -> None:
        self.url = url
        self.baudrate = baudrate
        self.decoder = NmeaDecoder(
            geo, clock, name, stale_after=stale_after, recent=recent, wall_clock=wall_clock
        )
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"nmea:{name}", daemon=True)
        self._thread.start()

    def latest(self) -> GpsFix | None:
        return self.decoder.latest()

    def health(self) -> list[str]:
        return self.decoder.health()

    def status(self) -> list[str]:
        return self.decoder.status()

    @property
    def problems(self) -> list[str]:
        return self.decoder.problems

    def counts(self) -> NmeaCounts:
        return self.decoder.counts()

    def stats(self) -> NmeaStats:
        return self.decoder.stats()

    def close(self) -> None:
        """Stop reading and close the wire (returns within about 0.1 s once connected)."""
        self._stop.set()
        self._thread.join(_JOIN_TIMEOUT)

    def _run(self) -> None:
        backoff = _BACKOFF_MIN
        while not self._stop.is_set():
            if self._session():
                backoff = _BACKOFF_MIN
            if self._stop.wait(backoff):
                break
            backoff = min(_BACKOFF_MAX, backoff * 2.0)

    def _session(self) -> bool:
        """Open the wire and read until an error or close(); whether data flowed."""
        before = self.decoder.counts().sentences
        try:
            port = serial.serial_for_url(self.url, baudrate=self.baudrate, timeout=_READ_TIMEOUT)
        except (OSError, ValueError) as exc:  # SerialException is an OSError
            self.decoder.note_link_error(f"{self.url}: {exc}")
            return False
        self.decoder.note_connected()
        self.decoder.reset_line()
        try:
            with port:
                self._pump(port)
        except (OSError, ValueError) as exc:
            self.decoder.note_link_error(f"{self.url}: {exc}")
        return self.decoder.counts().sentences > before

    def _pump(self, port: serial.SerialBase) -> None:
        # read(1) returns as soon as a byte is there (or after the timeout, so close() is
        # prompt), then whatever else is waiting: lines are stamped when they arrive.
        while not self._stop.is_set():
            data = port.read(max(1, port.in_waiting))
            if data:
                self.decoder.feed(data)


# -- the wire: server (hardware in the loop) ---------------------------------------------------
def _nmea_time(utc: dt.datetime) -> str:
    utc = utc.replace(tzinfo=dt.UTC) if utc.tzinfo is None else utc.astimezone(dt.UTC)
    return f"{utc:%H%M%S}.{utc.microsecond // 10_000:02d}"


def _degrees_minutes(value: float, degree_digits: int) -> str:
    """|value| degrees as NMEA ``d..dmm.mmmmmmm`` (7 decimals of minutes: 0.2 mm)."""
    degrees = int(abs(value))
    minutes = round((abs(value) - degrees) * 60.0, 7)
    if minutes >= 60.0:
        degrees, minutes = degrees + 1, minutes - 60.0
    return f"{degrees:0{degree_digits}d}{minutes:010.7f}"


def _quality_for(sigma: float) -> int:
    """A plausible GGA quality for a simulated fix of this sigma (m)."""
    if sigma <= 0.05:
        return 4
    if sigma <= 0.5:
        return 5
    return 2 if sigma <= 2.0 else 1


def nmea_sentences(
    geo: GeoReference, fix: GpsFix | None, utc: dt.datetime, talker: str = "GN"
) -> list[str]:
    """GST then GGA for ``fix`` (x, y in A) at ``utc``, or a no-fix GGA (quality 0) for
    None; each with its checksum, without line ends. GST comes first so that a reader
    pairs them at once; HDOP is set so that HDOP * UERE / sqrt 2 gives the same sigma."""
    stamp = _nmea_time(utc)
    if fix is None:
        fields = (stamp, "", "", "", "", "0", "00", "99.99", "", "", "", "", "", "")
        return [str(pynmea2.GGA(talker, "GGA", fields))]
    lat, lon = geo.to_geodetic(fix.x, fix.y)
    quality = _quality_for(fix.sigma)
    hdop = max(0.01, fix.sigma * math.sqrt(2.0) / UERE_M[quality])
    sd = f"{fix.sigma:.4f}"
    gst = (stamp, sd, sd, sd, "0.0", sd, sd, f"{2.0 * fix.sigma:.4f}")
    gga = (
        stamp,
        _degrees_minutes(lat, 2),
        "N" if lat >= 0.0 else "S",
        _degrees_minutes(lon, 3),
        "E" if lon >= 0.0 else "W",
        str(quality),
        "12",
        f"{hdop:.2f}",
        f"{geo.altitude_m:.3f}",
        "M",
        "0.0",
        "M",
        "",
        "",
    )
    return [str(pynmea2.GST(talker, "GST", gst)), str(pynmea2.GGA(talker, "GGA", gga))]


class NmeaServer(Wire):
    """A loopback TCP server that plays a GNSS receiver for the hardware-in-the-loop
    simulator: every :meth:`publish` goes to every connected client.

    Loopback only (127.0.0.1): the simulated receiver must never be reachable from the
    network. A client that disconnects, or does not take data within 1 s, is dropped.
    """

    def __init__(self, geo: GeoReference, port: int = 0, *, talker: str = "GN") -> None:
        self.geo = geo
        self.talker = talker
        self._listener = socket.create_server((_LOOPBACK, port))  # SO_REUSEADDR on POSIX
        self._listener.settimeout(_READ_TIMEOUT)
        self.port: int = self._listener.getsockname()[1]
        self._clients: list[socket.socket] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(
            target=self._accept_loop, name=f"nmea-server:{self.port}", daemon=True
        )
        self._thread.start()

    @property
    def url(self) -> str:
        """The pyserial URL of this server, for :class:`NmeaClient`."""
        return f"socket://{_LOOPBACK}:{self.port}"

    @property
    def clients(self) -> int:
        with self._lock:
            return len(self._clients)

    def publish(self, fix: GpsFix | None, utc: dt.datetime) -> int:
        """Write the sentences of ``fix`` (None: no fix) to every client; how many took them."""
        lines = nmea_sentences(self.geo, fix, utc, self.talker)
        payload = "".join(line + "\r\n" for line in lines).encode("ascii")
        with self._lock:
            clients = list(self._clients)
        delivered = 0
        for client in clients:
            try:
                client.sendall(payload)
                delivered += 1
            except OSError:
                self._drop(client)
        return delivered

    def disconnect_clients(self) -> None:
        """Close every client connection (a simulated cable fault); new ones are accepted."""
        with self._lock:
            clients, self._clients = self._clients, []
        for client in clients:
            client.close()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(_JOIN_TIMEOUT)
        self._listener.close()
        self.disconnect_clients()

    def _drop(self, client: socket.socket) -> None:
        with self._lock:
            if client in self._clients:
                self._clients.remove(client)
        client.close()

    def _accept_loop(self) -> None:
        while not self._stop.is_set():
            try:
                client, _ = self._listener.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            client.settimeout(_SEND_TIMEOUT)
            client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            with self._lock:
                self._clients.append(client)
