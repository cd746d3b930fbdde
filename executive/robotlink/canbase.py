"""The CAN drive base: the executive's end of the bus and the rules the base firmware keeps.

The 4MOB base is commanded over CAN with our own DBC (``walkaround_base.dbc``, shipped
inside this package). Both ends live in this module so that they cannot drift apart:
:class:`CanBaseLink` is what the executive runs, :class:`SimulatedBaseFirmware` is what
the hardware-in-the-loop simulator runs in another process, and the firmware's
obligations written in the DBC's comments are exactly what that class implements (the
tests hold the two ends against each other over python-can's virtual bus).

Why every frame carries a checksum and a rolling counter although CAN has its own CRC:
the bus CRC protects bits on the wire, not the software at either end. A frozen
transmit buffer re-sends the same bytes forever, a mis-mapped mailbox sends one
message's bytes under another's identifier. The counter catches the first (a repeated
counter is dropped, so a frozen executive cannot keep the base's watchdog fed) and the
checksum, which covers the identifier, catches the second. The layout is AUTOSAR E2E
profile 1: CRC-8/SAE-J1850 in byte 0, a 4-bit counter in the low nibble of byte 1.

Nothing here clamps a command: the safety layer limits commands upstream, and a value
the DBC cannot carry (or a NaN) is a bug that must stop the robot, not be rounded into
something drivable. Such a command is refused and a stop goes out instead.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib.resources
import math
import threading
import time
from collections import Counter, deque
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from enum import IntEnum, StrEnum
from types import MappingProxyType
from typing import NamedTuple

import can
import cantools
from cantools.database.can import Database
from cantools.database.can import Message as DbcMessage

from executive.core.records import (
    Bumpers,
    ImuReading,
    PanTilt,
    SensorFrame,
    VelocityCommand,
    WheelSpeeds,
)
from executive.robotlink.wire import Wire

Clock = Callable[[], float]
Signals = Mapping[str, float]

DBC_RESOURCE = "walkaround_base.dbc"
DEFAULT_PTU_UNITS: tuple[str, ...] = ("front", "rear", "ptz")
DEFAULT_WATCHDOG = 0.1
"""The base brakes when no valid EXEC_HEARTBEAT arrived for this long (s); the DBC's
TimeoutMs of EXEC_HEARTBEAT."""
DEFAULT_BASE_TIMEOUT = 0.1
"""The executive stops when no valid BASE_HEARTBEAT arrived for this long (s); the DBC's
TimeoutMs of BASE_HEARTBEAT."""
RESET_MAGIC = 0xA55A
WATCHDOG_TRIPS = 3
WATCHDOG_TRIP_WINDOW = 10.0
"""The base braking on its watchdog in this many separate stalls within this many seconds
is a link fault: one stall of ours (a scheduling hiccup) only holds the robot for a moment,
the base's own rule, and the run goes on; a heartbeat that keeps arriving late cannot be
trusted."""
WATCHDOG_STALL_GAP = 1.0
"""Watchdog brakes less than this many seconds apart are one stall: a process (or the whole
machine) that runs slow for a few hundred milliseconds lets several heartbeat gaps in a row
pass the base's watchdog, which is one hiccup, not three."""
WATCHDOG_LONGEST_STALL = 1.0
"""One stall whose brakes go on for this many seconds is a link fault by itself: a
heartbeat that keeps arriving late is not a hiccup."""
COUNTER_MODULO = 16
CRC_SIGNAL = "CRC8"
COUNTER_SIGNAL = "COUNTER"
UNIT_SIGNAL = "UNIT"
EXECUTIVE_NODE = "EXECUTIVE"
BASE_NODE = "BASE"
MAX_PTU_UNITS = 16

_EMPTY_SIGNALS: Signals = MappingProxyType({})


# -- the DBC ---------------------------------------------------------------------------------
@functools.cache
def _dbc_text() -> str:
    return (
        importlib.resources.files("executive.robotlink")
        .joinpath(DBC_RESOURCE)
        .read_text(encoding="utf-8")
    )


def load_dbc() -> Database:
    """The shipped DBC, read as a package resource (works from a wheel or a zip), parsed
    afresh on each call so that callers never share a mutable database."""
    db = cantools.database.load_string(_dbc_text(), database_format="dbc")
    assert isinstance(db, Database)
    return db


def message_timeout(db: Database, name: str) -> float | None:
    """The DBC's TimeoutMs of message ``name`` in seconds, None when it has none."""
    dbc = db.get_message_by_name(name).dbc
    attribute = dbc.attributes.get("TimeoutMs") if dbc is not None else None
    if attribute is None or not attribute.value:
        return None
    return float(attribute.value) / 1000.0


class ExecState(IntEnum):
    """The executive's state in EXEC_HEARTBEAT (the DBC's VAL_ table)."""

    IDLE = 0
    RUNNING = 1
    PAUSED = 2
    STOPPING = 3


class BaseState(IntEnum):
    """Why the base brakes, in BASE_HEARTBEAT (the DBC's VAL_ table)."""

    OK = 0
    BRAKING_WATCHDOG = 1
    BRAKING_BUMPER = 2
    ESTOP = 3
    FAULT = 4


class BaseFault(IntEnum):
    """The base's active fault, in BASE_STATUS (the DBC's VAL_ table)."""

    NONE = 0
    DRIVE_OVERCURRENT = 1
    DRIVE_OVERTEMPERATURE = 2
    DRIVE_COMMUNICATION = 3
    ENCODER = 4
    BATTERY_CRITICAL = 5
    IMU = 6
    PTU = 7
    BRAKE = 8
    FIRMWARE = 9


# -- checksum and counter --------------------------------------------------------------------
def _crc8_table(poly: int) -> tuple[int, ...]:
    def entry(byte: int) -> int:
        crc = byte
        for _ in range(8):
            crc = ((crc << 1) ^ poly) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        return crc

    return tuple(entry(byte) for byte in range(256))


_CRC8_SAE_J1850 = _crc8_table(0x1D)


def crc8_sae_j1850(data: bytes | bytearray) -> int:
    """CRC-8/SAE-J1850: polynomial 0x1D, initial value 0xFF, no reflection, final XOR
    0xFF (check value 0x4B for ``b"123456789"``), one table look-up per byte."""
    crc = 0xFF
    for byte in data:
        crc = _CRC8_SAE_J1850[crc ^ byte]
    return crc ^ 0xFF


def frame_checksum(frame_id: int, data: bytes | bytearray) -> int:
    """The CRC8 byte of a frame: CRC-8/SAE-J1850 over the 11-bit identifier as two bytes
    (low byte first) then the payload with byte 0, the checksum itself, set to zero.

    Covering the identifier means a payload sent under the wrong identifier fails."""
    head = bytes((frame_id & 0xFF, (frame_id >> 8) & 0xFF, 0))
    return crc8_sae_j1850(head + bytes(data[1:]))


def next_counter(counter: int) -> int:
    """The rolling counter after ``counter`` (4 bits: 15 is followed by 0)."""
    return (counter + 1) % COUNTER_MODULO


class RollingCounter:
    """The counter a sender puts in successive frames of one stream: 0, 1, ... 15, 0."""

    def __init__(self, start: int = 0) -> None:
        self._next = start % COUNTER_MODULO

    def take(self) -> int:
        value = self._next
        self._next = next_counter(value)
        return value


class CounterVerdict(StrEnum):
    """How a received counter follows the previous one of its stream."""

    OK = "ok"
    REPEATED = "repeated"
    SKIPPED = "skipped"


class CounterCheck:
    """Classifies each received counter of one stream against the previous one.

    ``ok``: one more than the previous (or the first seen); ``repeated``: the same as the
    previous, i.e. the sender is frozen or the frame is replayed (the receiver drops it);
    ``skipped``: further ahead, i.e. frames were lost; the frame itself is new, so it is
    kept, and ``lost`` counts the frames missing in between. A repeated counter does not
    move the reference, so the next genuine frame is ``ok`` again.
    """

    def __init__(self) -> None:
        self.last: int | None = None
        self.lost = 0

    def check(self, counter: int) -> CounterVerdict:
        if not 0 <= counter < COUNTER_MODULO:
            raise ValueError(f"counter {counter} outside 0..{COUNTER_MODULO - 1}")
        last, self.last = self.last, counter
        if last is None:
            return CounterVerdict.OK
        delta = (counter - last) % COUNTER_MODULO
        if delta == 0:
            return CounterVerdict.REPEATED
        if delta == 1:
            return CounterVerdict.OK
        self.lost += delta - 1
        return CounterVerdict.SKIPPED


# -- protected frames ------------------------------------------------------------------------
class Verdict(StrEnum):
    """What a receiver did with a frame; the values name the counters of FrameCounts."""

    ACCEPTED = "accepted"
    IGNORED = "ignored_frames"
    UNKNOWN_ID = "unknown_frames"
    BAD_LENGTH = "bad_length"
    BAD_CHECKSUM = "bad_checksum"
    OUT_OF_RANGE = "out_of_range"
    REPEATED_COUNTER = "repeated_counter"


@dataclass(frozen=True, slots=True)
class Received:
    """One checked frame: its verdict, and when it decoded its message and signals (raw
    enum values, scaled numbers). ``skipped``: accepted although frames were lost."""

    verdict: Verdict
    name: str = ""
    signals: Signals = dataclasses.field(default_factory=lambda: _EMPTY_SIGNALS)
    skipped: bool = False


@dataclass(frozen=True, slots=True)
class FrameCounts:
    """How many received frames met each fate (a frame counts once, under its verdict)
    plus ``skipped_counter`` (accepted after lost frames) and ``unknown_units`` (a unit
    index nobody configured: accepted by the codec, used by nobody)."""

    accepted: int = 0
    ignored_frames: int = 0
    unknown_frames: int = 0
    bad_length: int = 0
    bad_checksum: int = 0
    out_of_range: int = 0
    repeated_counter: int = 0
    skipped_counter: int = 0
    unknown_units: int = 0

    @property
    def total(self) -> int:
        """Every frame checked (each has exactly one verdict)."""
        return sum(getattr(self, verdict.value) for verdict in Verdict)

    @staticmethod
    def of(counts: Mapping[str, int]) -> FrameCounts:
        return FrameCounts(
            **{f.name: counts.get(f.name, 0) for f in dataclasses.fields(FrameCounts)}
        )


def invalid_value(message: DbcMessage, signals: Signals) -> str | None:
    """Why ``signals`` cannot be message ``message``'s values (not finite, outside a
    signal's range or value table), or None. The one rule for what is sent and received."""
    for signal in message.signals:
        value = signals.get(signal.name)
        if value is None:
            continue
        unit = f" {signal.unit}" if signal.unit else ""
        if not math.isfinite(value):
            return f"{signal.name}={value}{unit} is not finite"
        if signal.choices is not None and int(value) not in signal.choices:
            return f"{signal.name}={value} is not in its value table"
        low = signal.minimum if signal.minimum is not None else -math.inf
        high = signal.maximum if signal.maximum is not None else math.inf
        if not low <= value <= high:
            return f"{signal.name}={value:g}{unit} is outside [{low:g}, {high:g}]"
    return None


class FrameCodec:
    """Encodes the frames one node sends and checks the frames it receives.

    ``node`` is the DBC node this side is (``EXECUTIVE`` or ``BASE``): its messages are
    sent, the others received; a received identifier of its own messages is ``ignored``
    (an echo, or a second transmitter). Each stream (a message, or a message and UNIT)
    has its own rolling counter when sent and its own :class:`CounterCheck` when received.
    The checks run cheapest first and the counter last, so a corrupted frame never moves
    a stream's counter. Not thread-safe: the owner serialises encode and check apart.
    """

    def __init__(self, db: Database, node: str) -> None:
        self._tx = {m.name: m for m in db.messages if node in m.senders}
        self._rx = {m.frame_id: m for m in db.messages if node not in m.senders}
        self._own_ids = {m.frame_id for m in self._tx.values()}
        self._tx_counters: dict[tuple[str | int, int | None], RollingCounter] = {}
        self._rx_checks: dict[tuple[str | int, int | None], CounterCheck] = {}

    def message(self, name: str) -> DbcMessage:
        """A message this side sends."""
        return self._tx[name]

    def encode(self, name: str, signals: Signals) -> can.Message:
        """A frame of message ``name`` with its stream's next counter and its checksum;
        raises cantools' EncodeError when a signal is missing or out of range."""
        message = self._tx[name]
        counter = self._tx_counters.setdefault(_stream(name, signals), RollingCounter()).take()
        data = bytearray(message.encode({**signals, COUNTER_SIGNAL: counter, CRC_SIGNAL: 0}))
        data[0] = frame_checksum(message.frame_id, data)
        return can.Message(arbitration_id=message.frame_id, data=data, is_extended_id=False)

    def check(self, msg: can.Message) -> Received:
        message = None if msg.is_extended_id else self._rx.get(msg.arbitration_id)
        if message is None or msg.is_remote_frame:
            own = not msg.is_extended_id and msg.arbitration_id in self._own_ids
            return Received(Verdict.IGNORED if own else Verdict.UNKNOWN_ID)
        data = bytes(msg.data)
        if len(data) != message.length:
            return Received(Verdict.BAD_LENGTH, message.name)
        if data[0] != frame_checksum(message.frame_id, data):
            return Received(Verdict.BAD_CHECKSUM, message.name)
        signals = message.decode(data, decode_choices=False)
        assert isinstance(signals, dict)
        if invalid_value(message, signals) is not None:
            return Received(Verdict.OUT_OF_RANGE, message.name)
        stream = _stream(message.frame_id, signals)
        verdict = self._rx_checks.setdefault(stream, CounterCheck()).check(
            int(signals[COUNTER_SIGNAL])
        )
        frozen = MappingProxyType(signals)
        if verdict is CounterVerdict.REPEATED:
            return Received(Verdict.REPEATED_COUNTER, message.name, frozen)
        return Received(Verdict.ACCEPTED, message.name, frozen, verdict is CounterVerdict.SKIPPED)


def _stream(key: str | int, signals: Signals) -> tuple[str | int, int | None]:
    unit = signals.get(UNIT_SIGNAL)
    return (key, None if unit is None else int(unit))


def _count(counts: Counter[str], received: Received) -> None:
    counts[received.verdict.value] += 1
    if received.skipped:
        counts["skipped_counter"] += 1


# -- the executive's end ---------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class BaseLinkConfig:
    """The executive's view of the base's wiring and timing.

    ``ptu_units``: the platform camera unit ids in PTU_CMD / PTU_STATE index order (an
    empty string marks an unused index); ``watchdog``: the base's watchdog on our
    heartbeat (s); ``base_timeout``: how long the base's heartbeat may be missing (s);
    ``error_hold``: how long a CAN error (error frame, failed send, refused command,
    repeated counter) keeps :meth:`CanBaseLink.health` failing (s), so that a runtime that
    asks once per tick cannot miss it; ``send_timeout``: the longest one frame may wait
    for the transmit queue (s).
    """

    ptu_units: tuple[str, ...] = DEFAULT_PTU_UNITS
    watchdog: float = DEFAULT_WATCHDOG
    base_timeout: float = DEFAULT_BASE_TIMEOUT
    error_hold: float = 1.0
    send_timeout: float = 0.01

    def __post_init__(self) -> None:
        named = [unit for unit in self.ptu_units if unit]
        if len(self.ptu_units) > MAX_PTU_UNITS:
            raise ValueError(f"at most {MAX_PTU_UNITS} pan-tilt units fit in UNIT")
        if len(set(named)) != len(named):
            raise ValueError(f"pan-tilt unit named twice in {self.ptu_units}")
        times = (self.watchdog, self.base_timeout, self.error_hold, self.send_timeout)
        if not all(math.isfinite(t) and t > 0.0 for t in times):
            raise ValueError("timeouts must be positive and finite")

    @staticmethod
    def from_indices(
        ptus: Mapping[str, int],
        *,
        watchdog: float = DEFAULT_WATCHDOG,
        base_timeout: float = DEFAULT_BASE_TIMEOUT,
    ) -> BaseLinkConfig:
        """From a unit -> index mapping (the robot file's ``<ptu>``), gaps kept."""
        units = [""] * (max(ptus.values(), default=-1) + 1)
        for unit, index in ptus.items():
            units[index] = unit
        return BaseLinkConfig(tuple(units), watchdog=watchdog, base_timeout=base_timeout)

    def unit_indices(self) -> dict[str, int]:
        return {unit: index for index, unit in enumerate(self.ptu_units) if unit}


@dataclass(frozen=True, slots=True)
class LatencyStats:
    """Bus time stamp to decoding (s) over the latest frames: ``count`` frames measured
    since the link opened, nearest-rank percentiles of the window; NaN before any."""

    count: int = 0
    p50: float = math.nan
    p99: float = math.nan
    max: float = math.nan


def latency_stats(samples: Iterable[float], count: int) -> LatencyStats:
    ordered = sorted(samples)
    if not ordered:
        return LatencyStats(count)

    def rank(q: float) -> float:
        return ordered[max(0, math.ceil(q * len(ordered)) - 1)]

    return LatencyStats(count, rank(0.50), rank(0.99), ordered[-1])


@dataclass(frozen=True, slots=True)
class LinkStats:
    """The link's counters: received frames by fate, CAN error frames, failed sends,
    refused commands, receive-thread errors, and the receive latency."""

    frames: FrameCounts
    error_frames: int
    send_errors: int
    refused_commands: int
    receive_errors: int
    latency: LatencyStats


@dataclass(frozen=True, slots=True)
class BaseSnapshot:
    """The latest of everything the base reported, each stamped with the executive's
    clock on arrival (None / empty: never received). Immutable: safe to hand to the tick
    while the receive thread goes on."""

    stamp: float
    wheels: WheelSpeeds | None = None
    imu: ImuReading | None = None
    acceleration: tuple[float, float] | None = None
    """(ax, ay) in m/s^2 from the same IMU frame as ``imu``."""
    pan_tilt: Mapping[str, PanTilt] = dataclasses.field(
        default_factory=lambda: MappingProxyType({})
    )
    bumpers: Bumpers | None = None
    estop: bool = False
    latched: bool = False
    reset_needed: bool = False
    base_state: BaseState | None = None
    heartbeat_at: float | None = None
    fault: BaseFault | None = None
    battery_voltage: float | None = None
    battery_percent: float | None = None
    travel: tuple[float, float] | None = None
    """The base's odometers (left, right, m; WHEEL_TRAVEL, wrapped)."""

    def fill(self, frame: SensorFrame) -> SensorFrame:
        """``frame`` with the base's sensors (wheels with the odometers, IMU, pan-tilt
        angles, bumpers) set from this snapshot; what the base never reported is left as it
        was."""
        return dataclasses.replace(
            frame,
            wheels=self.wheels or frame.wheels,
            imu=self.imu or frame.imu,
            pan_tilt=MappingProxyType({**frame.pan_tilt, **self.pan_tilt}),
            bumpers=self.bumpers or frame.bumpers,
        )


@dataclass(slots=True)
class _Events:
    """When the latest of each kind of trouble happened (executive clock) and what it was."""

    error_frame_at: float | None = None
    send_error: tuple[float, str] | None = None
    receive_error: tuple[float, str] | None = None
    refusal: tuple[float, str] | None = None
    repeat: tuple[float, str, int] | None = None
    heartbeat_sent_at: float | None = None
    watchdog_braking_at: float | None = None


_LATENCY_WINDOW = 4096
_STATE_REASONS = {
    BaseState.BRAKING_WATCHDOG: "base braking: its watchdog saw no valid executive heartbeat",
    BaseState.BRAKING_BUMPER: "base braking: bumper latch set, an operator reset is needed",
    BaseState.ESTOP: "hardware e-stop pressed",
}


class _Receiver(can.Listener):
    """Hands the notifier's frames and receive errors to the link."""

    def __init__(self, link: CanBaseLink) -> None:
        self._link = link

    def on_message_received(self, msg: can.Message) -> None:
        self._link._on_frame(msg)

    def on_error(self, exc: Exception) -> None:
        self._link._on_receive_error(exc)


class CanBaseLink(Wire):
    """The executive's end of the drive base's CAN bus.

    A python-can :class:`~can.Notifier` thread checks every received frame (length,
    checksum, ranges, rolling counter) and decodes it into the latest sensor values,
    stamped on arrival with ``clock`` (the executive's clock); ``bus_clock`` is the clock
    the bus stamps frames with (python-can's interfaces use wall time), for the receive
    latency. :meth:`send` puts one control cycle on the bus; :meth:`health` says why the
    executive must stop now. The caller owns ``bus`` (:meth:`close` stops only the thread).
    """

    def __init__(
        self,
        bus: can.BusABC,
        config: BaseLinkConfig | None = None,
        *,
        clock: Clock = time.monotonic,
        bus_clock: Clock = time.time,
        db: Database | None = None,
    ) -> None:
        self._bus = bus
        self.config = config or BaseLinkConfig()
        self._clock = clock
        self._bus_clock = bus_clock
        self._codec = FrameCodec(db or load_dbc(), EXECUTIVE_NODE)
        self._unit_index = self.config.unit_indices()
        self._unit_name = {index: unit for unit, index in self._unit_index.items()}
        self._lock = threading.Lock()
        self._tx_lock = threading.Lock()
        self._latest = BaseSnapshot(stamp=clock())
        self._opened_at = self._latest.stamp
        self._counts: Counter[str] = Counter()
        self._events = _Events()
        self._latencies: deque[float] = deque(maxlen=_LATENCY_WINDOW)
        self._latency_count = 0
        self._sent_listeners: list[Callable[[can.Message], None]] = []
        self._watchdog_trips: list[float] = []
        self._notifier = can.Notifier(bus, [_Receiver(self)], timeout=0.05)

    # -- lifecycle
    def close(self) -> None:
        """Stop the receive thread (idempotent); the bus stays open."""
        if not self._notifier.stopped:
            self._notifier.stop(timeout=1.0)

    # -- sending
    def send(self, command: VelocityCommand, state: ExecState = ExecState.RUNNING) -> bool:
        """One control cycle: MOTION_CMD, one PTU_CMD per unit of ``command``, then
        EXEC_HEARTBEAT. A command the DBC cannot carry (not finite, out of range, an
        unknown unit) is refused: a braking stop goes out instead and :meth:`health`
        names it. A send that fails ends the cycle without its heartbeat, so the base's
        watchdog brakes if sending keeps failing; :meth:`health` names the error."""
        now = self._clock()
        motion, ptus, refusal = self._cycle_signals(command, state)
        with self._tx_lock:
            frames = [self._codec.encode("MOTION_CMD", motion)]
            frames += [self._codec.encode("PTU_CMD", signals) for signals in ptus]
            frames.append(self._codec.encode("EXEC_HEARTBEAT", {"STATE": int(state)}))
            sent = self._transmit(frames, now)
        with self._lock:
            if refusal is not None:
                self._counts["refused_commands"] += 1
                self._events.refusal = (now, refusal)
            if sent:
                self._events.heartbeat_sent_at = now
        return sent

    def send_reset(self) -> bool:
        """Ask the base to clear its bumper latch (the operator's reset); True when the
        frame went out. The base ignores it while a bumper is still pressed."""
        now = self._clock()
        with self._tx_lock:
            frame = self._codec.encode("BASE_RESET", {"MAGIC": RESET_MAGIC})
            return self._transmit([frame], now)

    def _cycle_signals(
        self, command: VelocityCommand, state: ExecState
    ) -> tuple[dict[str, float], list[dict[str, float]], str | None]:
        enable = 0.0 if state is ExecState.IDLE else 1.0
        motion = {"ENABLE": enable, "V": command.v, "OMEGA": command.omega}
        rates = {self._unit_index.get(unit, -1): rate for unit, rate in command.pan_tilt.items()}
        ptus = [_ptu_signals(i, rates[i].pan, rates[i].tilt) for i in sorted(rates)]
        refusal = self._refusal(command, motion, ptus)
        if refusal is None:
            return motion, ptus, None
        stop = {"ENABLE": 0.0, "V": 0.0, "OMEGA": 0.0}
        return stop, [_ptu_signals(i, 0.0, 0.0) for i in sorted(self._unit_name)], refusal

    def _refusal(
        self, command: VelocityCommand, motion: Signals, ptus: Sequence[Signals]
    ) -> str | None:
        unknown = sorted(set(command.pan_tilt) - set(self._unit_index))
        if unknown:
            return f"command refused: unknown pan-tilt unit {', '.join(unknown)}; sent a stop"
        problem = invalid_value(self._codec.message("MOTION_CMD"), motion)
        for signals in ptus:
            problem = problem or invalid_value(self._codec.message("PTU_CMD"), signals)
        return None if problem is None else f"command refused: {problem}; sent a stop"

    def _transmit(self, frames: Sequence[can.Message], now: float) -> bool:
        for frame in frames:
            try:
                self._bus.send(frame, timeout=self.config.send_timeout)
            except can.CanError as exc:
                with self._lock:
                    self._counts["send_errors"] += 1
                    self._events.send_error = (now, str(exc) or type(exc).__name__)
                return False
            for listener in self._sent_listeners:
                listener(frame)
        return True

    def add_listener(self, listener: can.Listener) -> None:
        """Hand ``listener`` every frame of the bus, received (the notifier's thread) and
        sent (after it went out): a run's log of both directions on the link's own bus,
        which some interfaces let only one process or handle open."""
        self._notifier.add_listener(listener)
        self._sent_listeners.append(listener.on_message_received)

    # -- receiving (the notifier's thread)
    def _on_frame(self, msg: can.Message) -> None:
        now = self._clock()
        latency = self._bus_clock() - msg.timestamp if msg.timestamp > 0.0 else None
        if msg.is_error_frame:
            with self._lock:
                self._counts["error_frames"] += 1
                self._events.error_frame_at = now
            return
        with self._lock:
            if latency is not None:
                self._latencies.append(latency)
                self._latency_count += 1
            received = self._codec.check(msg)
            _count(self._counts, received)
            if received.verdict is Verdict.REPEATED_COUNTER:
                counter = int(received.signals[COUNTER_SIGNAL])
                self._events.repeat = (now, received.name, counter)
            elif received.verdict is Verdict.ACCEPTED:
                self._apply(received, now)

    def _on_receive_error(self, exc: Exception) -> None:
        with self._lock:
            self._counts["receive_errors"] += 1
            self._events.receive_error = (self._clock(), str(exc) or type(exc).__name__)
        time.sleep(0.01)  # a bus that keeps failing must not spin the thread

    def _apply(self, received: Received, now: float) -> None:
        s = received.signals
        latest = self._latest
        match received.name:
            case "WHEEL_SPEEDS":
                left, right = (s["FL"] + s["RL"]) / 2.0, (s["FR"] + s["RR"]) / 2.0
                wheels = WheelSpeeds(now, left, right, latest.travel)
                latest = dataclasses.replace(latest, wheels=wheels)
            case "WHEEL_TRAVEL":
                travel = (s["LEFT"], s["RIGHT"])
                wheels = latest.wheels
                if wheels is not None:
                    wheels = dataclasses.replace(wheels, travel=travel)
                latest = dataclasses.replace(latest, travel=travel, wheels=wheels)
            case "IMU":
                imu = ImuReading(now, s["YAW_RATE"])
                latest = dataclasses.replace(latest, imu=imu, acceleration=(s["AX"], s["AY"]))
            case "PTU_STATE":
                latest = self._apply_ptu(latest, s, now)
            case "BUMPERS_ESTOP":
                latest = dataclasses.replace(
                    latest,
                    bumpers=Bumpers(now, bool(s["FRONT"]), bool(s["REAR"])),
                    estop=bool(s["ESTOP"]),
                    latched=bool(s["LATCHED"]),
                    reset_needed=bool(s["RESET_NEEDED"]),
                )
            case "BASE_HEARTBEAT":
                state = BaseState(int(s["STATE"]))
                tripped = state is BaseState.BRAKING_WATCHDOG
                if tripped and latest.base_state is BaseState.OK:  # not the start-up state
                    self._events.watchdog_braking_at = now
                    self._watchdog_trips.append(now)
                latest = dataclasses.replace(latest, base_state=state, heartbeat_at=now)
            case "BASE_STATUS":
                latest = dataclasses.replace(
                    latest,
                    fault=BaseFault(int(s["FAULT"])),
                    battery_voltage=s["BATTERY_VOLTAGE"],
                    battery_percent=s["BATTERY_SOC"],
                )
        self._latest = latest

    def _apply_ptu(self, latest: BaseSnapshot, s: Signals, now: float) -> BaseSnapshot:
        unit = self._unit_name.get(int(s[UNIT_SIGNAL]))
        if unit is None:
            self._counts["unknown_units"] += 1
            return latest
        angles = {**latest.pan_tilt, unit: PanTilt(now, s["PAN"], s["TILT"])}
        return dataclasses.replace(latest, pan_tilt=MappingProxyType(angles))

    # -- reading
    def snapshot(self) -> BaseSnapshot:
        """The latest values, stamped now (executive clock)."""
        now = self._clock()
        with self._lock:
            return dataclasses.replace(self._latest, stamp=now)

    def stats(self) -> LinkStats:
        with self._lock:
            counts = Counter(self._counts)
            samples = list(self._latencies)
            measured = self._latency_count
        return LinkStats(
            frames=FrameCounts.of(counts),
            error_frames=counts["error_frames"],
            send_errors=counts["send_errors"],
            refused_commands=counts["refused_commands"],
            receive_errors=counts["receive_errors"],
            latency=latency_stats(samples, measured),
        )

    def health(self) -> list[str]:
        """Why the executive must stop now, one sentence each; empty while the link and
        the base are fine."""
        now = self._clock()
        reasons = _bus_state_reasons(self._bus)
        with self._lock:
            latest, events = self._latest, dataclasses.replace(self._events)
            recent = [t for t in self._watchdog_trips if now - t <= WATCHDOG_TRIP_WINDOW]
        reasons += self._heartbeat_reasons(latest, events, now)
        reasons += watchdog_stall_reasons(recent)
        reasons += self._error_reasons(events, now)
        reasons += _base_reasons(latest)
        return list(dict.fromkeys(reasons))

    def holds(self) -> list[str]:
        """Why the base brakes by its own rules (bumper latch, hardware e-stop, one late
        heartbeat of ours): not a link fault; the run waits for the operator or for the
        next heartbeat (:func:`base_holds`). Repeated watchdog braking is a fault."""
        now = self._clock()
        with self._lock:
            holds = base_holds(self._latest)
            at = self._events.watchdog_braking_at
        if at is not None and now - at <= self.config.error_hold:
            holds.append(f"the base braked on its watchdog {now - at:.1f} s ago (a late tick)")
        return holds

    @property
    def watchdog_trips(self) -> int:
        """How often the base braked on its watchdog while the link was open."""
        with self._lock:
            return len(self._watchdog_trips)

    def _heartbeat_reasons(self, latest: BaseSnapshot, events: _Events, now: float) -> list[str]:
        reasons = []
        timeout = self.config.base_timeout
        if latest.heartbeat_at is None:
            if now - self._opened_at > timeout:
                reasons.append(
                    f"base heartbeat never received (link open for {now - self._opened_at:.2f} s)"
                )
        elif now - latest.heartbeat_at > timeout:
            reasons.append(f"base heartbeat lost for {now - latest.heartbeat_at:.2f} s")
        # Our own late heartbeat is not judged here: the base brakes on it by itself (a
        # hold), and repeated braking is the fault (WATCHDOG_TRIPS).
        return reasons

    def _error_reasons(self, events: _Events, now: float) -> list[str]:
        def recent(at: float | None) -> bool:
            return at is not None and now - at <= self.config.error_hold

        reasons = []
        if recent(events.error_frame_at):
            reasons.append("CAN error frame received")
        if events.send_error is not None and recent(events.send_error[0]):
            reasons.append(f"CAN send failed: {events.send_error[1]}")
        if events.receive_error is not None and recent(events.receive_error[0]):
            reasons.append(f"CAN receive failed: {events.receive_error[1]}")
        if events.refusal is not None and recent(events.refusal[0]):
            reasons.append(events.refusal[1])
        if events.repeat is not None and recent(events.repeat[0]):
            _, name, counter = events.repeat
            reasons.append(f"stale frame from the base: {name} repeated rolling counter {counter}")
        return reasons


def _ptu_signals(index: int, pan_rate: float, tilt_rate: float) -> dict[str, float]:
    return {"UNIT": float(index), "PAN_RATE": pan_rate, "TILT_RATE": tilt_rate}


def watchdog_stalls(trips: Sequence[float], gap: float = WATCHDOG_STALL_GAP) -> list[list[float]]:
    """The base's watchdog brakes (times, ascending) grouped into stalls: a brake less than
    ``gap`` seconds after the previous one continues its stall."""
    stalls: list[list[float]] = []
    for t in trips:
        if stalls and t - stalls[-1][-1] < gap:
            stalls[-1].append(t)
        else:
            stalls.append([t])
    return stalls


def watchdog_stall_reasons(trips: Sequence[float]) -> list[str]:
    """Why the base's watchdog brakes within the last :data:`WATCHDOG_TRIP_WINDOW` seconds
    (``trips``) are a link fault, if they are: :data:`WATCHDOG_TRIPS` separate stalls, or one
    stall lasting :data:`WATCHDOG_LONGEST_STALL` or more."""
    stalls = watchdog_stalls(trips)
    reasons = []
    if len(stalls) >= WATCHDOG_TRIPS:
        reasons.append(
            f"the base braked on its watchdog in {len(stalls)} stalls within"
            f" {WATCHDOG_TRIP_WINDOW:g} s: the executive's heartbeat does not keep time"
        )
    longest = max(stalls, key=lambda s: s[-1] - s[0], default=None)
    if longest is not None and longest[-1] - longest[0] >= WATCHDOG_LONGEST_STALL:
        reasons.append(
            f"the base braked on its watchdog {len(longest)} times in"
            f" {longest[-1] - longest[0]:.1f} s: the executive's heartbeat keeps arriving late"
        )
    return reasons


def _bus_state_reasons(bus: can.BusABC) -> list[str]:
    try:
        state = bus.state
    except (NotImplementedError, can.CanError):
        return []
    if state is can.BusState.ERROR:
        return ["CAN bus-off: the controller is in its error state"]
    if state is can.BusState.PASSIVE:
        return ["CAN controller error-passive: the bus keeps corrupting frames"]
    return []


HOLDS = (BaseState.BRAKING_BUMPER, BaseState.ESTOP)
"""Base states that are not link faults: the base brakes by its own rules (a bumper's
latch until the operator's reset, the hardware e-stop) and the run goes on once it is
released; the bumper switches also reach the safety layer, which latches its own e-stop."""


def _base_reasons(latest: BaseSnapshot) -> list[str]:
    reasons = []
    fault = latest.fault if latest.fault not in (None, BaseFault.NONE) else None
    if fault is not None:
        reasons.append(f"base fault: {fault.name}")
    if latest.base_state is BaseState.FAULT:
        reasons.append(f"base fault: {fault.name if fault else 'unspecified'}")
    elif latest.base_state not in (None, BaseState.OK, BaseState.BRAKING_WATCHDOG, *HOLDS):
        reasons.append(_STATE_REASONS[latest.base_state])
    return reasons


def base_holds(latest: BaseSnapshot) -> list[str]:
    """Why the base brakes by its own rules now without the link being at fault."""
    reasons = []
    if latest.estop:
        reasons.append(_STATE_REASONS[BaseState.ESTOP])
    if latest.latched:
        reasons.append(_STATE_REASONS[BaseState.BRAKING_BUMPER])
    return reasons


# -- the base's end --------------------------------------------------------------------------
class BaseCommand(NamedTuple):
    """What the base drives now: (v, omega, {unit: (pan_rate, tilt_rate)})."""

    v: float
    omega: float
    pan_tilt: Mapping[str, tuple[float, float]]


@dataclass(slots=True)
class _FirmwareState:
    heartbeat_at: float | None = None
    exec_state: ExecState = ExecState.IDLE
    motion: tuple[float, float, bool, float] | None = None
    """(v, omega, enable, arrival)."""
    ptu: dict[str, tuple[float, float, float]] = dataclasses.field(default_factory=dict)
    """unit -> (pan_rate, tilt_rate, arrival)."""
    bumpers: tuple[bool, bool] = (False, False)
    latched: bool = False
    estop: bool = False
    fault: BaseFault = BaseFault.NONE
    expired: bool = True
    watchdog_fired_at: float | None = None
    watchdog_fired_after: float | None = None
    refused_resets: int = 0
    travel: tuple[float, float] = (0.0, 0.0)
    """The odometers (left, right, m) since the firmware started."""
    sides_at: tuple[float, float, float] | None = None
    """(left speed, right speed, time) of the last publish: the odometers integrate the
    wheel speeds between publishes (trapezoids)."""


class SimulatedBaseFirmware:
    """The base's end of the bus, keeping exactly the rules the real firmware must keep.

    Received frames are checked like the executive's (checksum, ranges, counter: a
    repeated or replayed frame is dropped, so it feeds no watchdog). :meth:`command` is
    what the motors get: zero whenever the watchdog has expired (no valid EXEC_HEARTBEAT
    for longer than ``watchdog``), the bumper latch is set, the hardware e-stop is
    pressed, a fault is active, ENABLE is 0, or the command itself is older than
    ``command_timeout`` (a heartbeat alone does not keep an old command alive). Any
    bumper contact sets the latch; only a valid BASE_RESET while no bumper is pressed
    clears it. Time is the base's own ``clock``; :attr:`watchdog_fired_at` is when the
    firmware noticed the watchdog expire, so a test can bound the braking delay.

    Frames are consumed by :meth:`poll` (a test's loop) or by handing
    :meth:`on_message_received` to a python-can Notifier; both are thread-safe.
    """

    def __init__(
        self,
        bus: can.BusABC,
        db: Database | None = None,
        *,
        clock: Clock = time.monotonic,
        watchdog: float = DEFAULT_WATCHDOG,
        command_timeout: float | None = None,
        ptu_units: Sequence[str] = DEFAULT_PTU_UNITS,
    ) -> None:
        self._bus = bus
        self._codec = FrameCodec(db or load_dbc(), BASE_NODE)
        self._clock = clock
        self.watchdog = watchdog
        self.command_timeout = watchdog if command_timeout is None else command_timeout
        self._units = {index: unit for index, unit in enumerate(ptu_units) if unit}
        self._index = {unit: index for index, unit in self._units.items()}
        self._lock = threading.Lock()
        self._state = _FirmwareState()
        self._counts: Counter[str] = Counter()

    # -- receiving
    def poll(self) -> int:
        """Consume every frame waiting on the bus, then run the watchdog; the number of
        frames consumed."""
        consumed = 0
        while (msg := self._bus.recv(timeout=0.0)) is not None:
            self.on_message_received(msg)
            consumed += 1
        with self._lock:
            self._update_watchdog(self._clock())
        return consumed

    def on_message_received(self, msg: can.Message) -> None:
        now = self._clock()
        with self._lock:
            self._update_watchdog(now)  # a late heartbeat arrives after the expiry
            if msg.is_error_frame:
                self._counts["error_frames"] += 1
                return
            received = self._codec.check(msg)
            _count(self._counts, received)
            if received.verdict is Verdict.ACCEPTED:
                self._apply(received.name, received.signals, now)

    def _apply(self, name: str, s: Signals, now: float) -> None:
        state = self._state
        match name:
            case "EXEC_HEARTBEAT":
                state.heartbeat_at = now
                state.exec_state = ExecState(int(s["STATE"]))
                self._update_watchdog(now)
            case "MOTION_CMD":
                state.motion = (s["V"], s["OMEGA"], bool(s["ENABLE"]), now)
            case "PTU_CMD":
                unit = self._units.get(int(s[UNIT_SIGNAL]))
                if unit is None:
                    self._counts["unknown_units"] += 1
                else:
                    state.ptu[unit] = (s["PAN_RATE"], s["TILT_RATE"], now)
            case "BASE_RESET":
                if any(state.bumpers) or int(s["MAGIC"]) != RESET_MAGIC:
                    state.refused_resets += 1
                else:
                    state.latched = False

    def _update_watchdog(self, now: float) -> None:
        state = self._state
        at = state.heartbeat_at
        expired = at is None or now - at > self.watchdog
        if expired and not state.expired and at is not None:
            state.watchdog_fired_at = now
            state.watchdog_fired_after = now - at
        state.expired = expired

    # -- what the base does
    def command(self) -> BaseCommand:
        """The velocities the motors get now (zero while braking)."""
        now = self._clock()
        with self._lock:
            self._update_watchdog(now)
            still = {unit: (0.0, 0.0) for unit in self._index}
            if self._braking() is not BaseState.OK:
                return BaseCommand(0.0, 0.0, still)
            return BaseCommand(*self._motion(now), {**still, **self._ptu_rates(now)})

    def _motion(self, now: float) -> tuple[float, float]:
        motion = self._state.motion
        if motion is None or not motion[2] or now - motion[3] > self.command_timeout:
            return (0.0, 0.0)
        return (motion[0], motion[1])

    def _ptu_rates(self, now: float) -> dict[str, tuple[float, float]]:
        return {
            unit: (pan, tilt)
            for unit, (pan, tilt, at) in self._state.ptu.items()
            if now - at <= self.command_timeout
        }

    def _braking(self) -> BaseState:
        """Why the base brakes, the first that holds in the DBC's order; OK if none."""
        state = self._state
        if state.estop:
            return BaseState.ESTOP
        if state.fault is not BaseFault.NONE:
            return BaseState.FAULT
        if state.latched:
            return BaseState.BRAKING_BUMPER
        if state.expired:
            return BaseState.BRAKING_WATCHDOG
        return BaseState.OK

    def base_state(self) -> BaseState:
        now = self._clock()
        with self._lock:
            self._update_watchdog(now)
            return self._braking()

    @property
    def watchdog_fired_at(self) -> float | None:
        """When (base clock) the firmware last noticed its watchdog expire."""
        with self._lock:
            return self._state.watchdog_fired_at

    @property
    def watchdog_fired_after(self) -> float | None:
        """How long after the last valid heartbeat the watchdog last fired (s)."""
        with self._lock:
            return self._state.watchdog_fired_after

    @property
    def heartbeat_at(self) -> float | None:
        """When (base clock) the last valid EXEC_HEARTBEAT arrived; None before any."""
        with self._lock:
            return self._state.heartbeat_at

    @property
    def latched(self) -> bool:
        with self._lock:
            return self._state.latched

    @property
    def exec_state(self) -> ExecState:
        with self._lock:
            return self._state.exec_state

    @property
    def refused_resets(self) -> int:
        with self._lock:
            return self._state.refused_resets

    def stats(self) -> FrameCounts:
        with self._lock:
            return FrameCounts.of(self._counts)

    # -- sending
    def publish(
        self,
        wheels: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0),
        yaw_rate: float = 0.0,
        ax: float = 0.0,
        ay: float = 0.0,
        ptu: Mapping[str, tuple[float, float]] | None = None,
        bumpers: tuple[bool, bool] = (False, False),
        estop: bool = False,
        battery: tuple[float, float] = (48.0, 100.0),
        fault: BaseFault = BaseFault.NONE,
    ) -> None:
        """Take the inputs (wheel speeds fl, fr, rl, rr in m/s; yaw rate; ax, ay; pan and
        tilt per unit; bumper switches front, rear; e-stop; battery volts and percent;
        fault), then send the status frames and BASE_HEARTBEAT. Values beyond a signal's
        range are saturated, as a sensor saturates; a value that is not finite raises."""
        now = self._clock()
        with self._lock:
            self._take_inputs(bumpers, estop, fault)
            self._update_watchdog(now)
            self._count_travel(wheels, now)
            frames = self._status_frames(wheels, (yaw_rate, ax, ay), ptu or {}, battery)
        for frame in frames:
            self._bus.send(frame)

    def _count_travel(self, wheels: tuple[float, float, float, float], now: float) -> None:
        state = self._state
        fl, fr, rl, rr = wheels
        left, right = 0.5 * (fl + rl), 0.5 * (fr + rr)
        if state.sides_at is not None:
            left0, right0, t0 = state.sides_at
            dt = max(0.0, now - t0)
            state.travel = (
                state.travel[0] + 0.5 * (left0 + left) * dt,
                state.travel[1] + 0.5 * (right0 + right) * dt,
            )
        state.sides_at = (left, right, now)

    @property
    def travel(self) -> tuple[float, float]:
        """The odometers (left, right, m) as counted, unwrapped."""
        with self._lock:
            return self._state.travel

    def _take_inputs(self, bumpers: tuple[bool, bool], estop: bool, fault: BaseFault) -> None:
        state = self._state
        state.bumpers = (bool(bumpers[0]), bool(bumpers[1]))
        state.latched = state.latched or any(state.bumpers)
        state.estop = bool(estop)
        state.fault = BaseFault(fault)

    def _status_frames(
        self,
        wheels: tuple[float, float, float, float],
        imu: tuple[float, float, float],
        ptu: Mapping[str, tuple[float, float]],
        battery: tuple[float, float],
    ) -> list[can.Message]:
        state = self._state
        fl, fr, rl, rr = wheels
        payloads: list[tuple[str, dict[str, float]]] = [
            (
                "BUMPERS_ESTOP",
                {
                    "FRONT": state.bumpers[0],
                    "REAR": state.bumpers[1],
                    "LATCHED": state.latched,
                    "ESTOP": state.estop,
                    "RESET_NEEDED": state.latched and not any(state.bumpers),
                },
            ),
            ("WHEEL_SPEEDS", {"FL": fl, "FR": fr, "RL": rl, "RR": rr}),
            (
                "WHEEL_TRAVEL",
                {"LEFT": wrap_travel(state.travel[0]), "RIGHT": wrap_travel(state.travel[1])},
            ),
            ("IMU", {"YAW_RATE": imu[0], "AX": imu[1], "AY": imu[2]}),
            *(
                ("PTU_STATE", {"UNIT": self._index[unit], "PAN": pan, "TILT": tilt})
                for unit, (pan, tilt) in ptu.items()
            ),
            (
                "BASE_STATUS",
                {"FAULT": state.fault, "BATTERY_VOLTAGE": battery[0], "BATTERY_SOC": battery[1]},
            ),
            ("BASE_HEARTBEAT", {"STATE": self._braking()}),
        ]
        return [
            self._codec.encode(name, _saturated(self._codec.message(name), signals))
            for name, signals in payloads
        ]


TRAVEL_WRAP_MM = 1 << 26
"""WHEEL_TRAVEL's odometers wrap modulo this many millimetres (26-bit signals)."""


def wrap_travel(metres: float) -> float:
    """An odometer reading as WHEEL_TRAVEL carries it: whole millimetres, wrapped into
    the signed 26-bit range."""
    mm = round(metres * 1000.0)
    half = TRAVEL_WRAP_MM // 2
    return ((mm + half) % TRAVEL_WRAP_MM - half) / 1000.0


def travel_difference(after: float, before: float) -> float:
    """``after - before`` of two wrapped odometer readings (m): the shortest way round,
    right while a side travels less than 33 km between them."""
    return wrap_travel(after - before)


def _saturated(message: DbcMessage, signals: Mapping[str, float]) -> dict[str, float]:
    out = {}
    for name, value in signals.items():
        if not math.isfinite(value):
            raise ValueError(f"{message.name}.{name}={value} is not finite")
        signal = message.get_signal_by_name(name)
        low = signal.minimum if signal.minimum is not None else -math.inf
        high = signal.maximum if signal.maximum is not None else math.inf
        out[name] = min(max(float(value), low), high)
    return out
