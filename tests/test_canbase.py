"""The CAN drive base (executive/robotlink/canbase.py) and its DBC.

The DBC: every message round-trips through cantools at each signal's minimum, maximum
and a middle value; checksum against published CRC-8/SAE-J1850 vectors; the rolling
counter's verdicts (hypothesis). Then both ends on python-can virtual buses, with fake
clocks so that time is the test's: commands arrive, corrupted and repeated frames are
dropped and counted, the base's watchdog brakes within 150 ms of the last heartbeat, the
bumper latch holds until a reset, and health() names every reason to stop. Last, a
recorded .asc / .blf log of an exchange decodes with the shipped DBC.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import time
import uuid
from collections.abc import Callable, Iterator

import can
import pytest
from can.interfaces.virtual import VirtualBus
from hypothesis import given
from hypothesis import strategies as st

from executive.core.records import Bumpers, PanTiltRate, SensorFrame, VelocityCommand
from executive.robotlink.canbase import (
    BASE_NODE,
    DEFAULT_BASE_TIMEOUT,
    DEFAULT_WATCHDOG,
    EXECUTIVE_NODE,
    BaseFault,
    BaseLinkConfig,
    BaseState,
    CanBaseLink,
    CounterCheck,
    CounterVerdict,
    ExecState,
    FrameCodec,
    RollingCounter,
    SimulatedBaseFirmware,
    Verdict,
    crc8_sae_j1850,
    frame_checksum,
    latency_stats,
    load_dbc,
    message_timeout,
    travel_difference,
    wrap_travel,
)

DB = load_dbc()
MESSAGES = sorted(m.name for m in DB.messages)
FORWARD = VelocityCommand(0.8, 0.3, {"front": PanTiltRate(0.1, -0.2)})


class FakeClock:
    """A clock the test moves by hand (read from the link's receive thread too)."""

    def __init__(self, t: float) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


def wait_until(predicate: Callable[[], bool], timeout: float = 2.0) -> None:
    """Poll ``predicate`` (the link decodes on its own thread); fail after ``timeout``."""
    deadline = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < deadline, "condition not met in time"
        time.sleep(0.001)


@dataclasses.dataclass
class Rig:
    """Executive and base on one virtual channel, each with its own clock, and a spy bus
    that sees every frame of both."""

    channel: str
    exec_bus: can.BusABC
    base_bus: can.BusABC
    spy: can.BusABC
    exec_clock: FakeClock
    base_clock: FakeClock
    link: CanBaseLink
    fw: SimulatedBaseFirmware

    def tick(self, dt: float) -> None:
        self.exec_clock.t += dt
        self.base_clock.t += dt

    def seen(self) -> int:
        stats = self.link.stats()
        return stats.frames.total + stats.error_frames

    def from_base(self, send: Callable[[], object], frames: int) -> None:
        """Run ``send`` on the base side and wait until the link has checked ``frames``."""
        before = self.seen()
        send()
        wait_until(lambda: self.seen() >= before + frames)

    def publish(self, **inputs: object) -> None:
        ptu = inputs.get("ptu") or {}
        assert isinstance(ptu, dict)
        self.from_base(lambda: self.fw.publish(**inputs), 6 + len(ptu))

    def cycle(self, command: VelocityCommand = FORWARD) -> None:
        """One control cycle: the executive sends, the base consumes."""
        self.link.send(command)
        self.fw.poll()

    def spied(self, name: str | None = None) -> list[can.Message]:
        """Every frame the spy saw since last asked (of message ``name`` only if given)."""
        frames = list(iter(lambda: self.spy.recv(timeout=0.0), None))
        if name is None:
            return frames
        frame_id = DB.get_message_by_name(name).frame_id
        return [m for m in frames if m.arbitration_id == frame_id]


def make_rig(
    config: BaseLinkConfig | None = None, bus_class: type[VirtualBus] = VirtualBus, **fw_kwargs
) -> Rig:
    # letters only: a BLF log stores the channel as a small number parsed from its digits
    channel = "canbase-" + uuid.uuid4().hex.translate(str.maketrans("0123456789", "ghijklmnop"))
    exec_bus = bus_class(channel=channel)
    base_bus = VirtualBus(channel=channel)
    spy = VirtualBus(channel=channel)
    exec_clock, base_clock = FakeClock(100.0), FakeClock(5000.0)
    link = CanBaseLink(exec_bus, config, clock=exec_clock, db=DB)
    fw = SimulatedBaseFirmware(base_bus, DB, clock=base_clock, **fw_kwargs)
    return Rig(channel, exec_bus, base_bus, spy, exec_clock, base_clock, link, fw)


def close_rig(rig: Rig) -> None:
    rig.link.close()
    for bus in (rig.exec_bus, rig.base_bus, rig.spy):
        bus.shutdown()


@pytest.fixture
def rig() -> Iterator[Rig]:
    r = make_rig()
    yield r
    close_rig(r)


def zero(rig: Rig) -> bool:
    v, omega, rates = rig.fw.command()
    return v == 0.0 and omega == 0.0 and all(r == (0.0, 0.0) for r in rates.values())


# -- the DBC -----------------------------------------------------------------------------
def test_dbc_declares_the_bus_and_the_protection_layout():
    assert DB.buses[0].baudrate == 500_000
    commands = [m for m in DB.messages if EXECUTIVE_NODE in m.senders]
    statuses = [m for m in DB.messages if BASE_NODE in m.senders]
    assert len(commands) + len(statuses) == len(DB.messages) == 11
    assert max(m.frame_id for m in commands) < min(m.frame_id for m in statuses)
    for message in DB.messages:
        assert not message.is_extended_frame and message.frame_id < 0x800
        assert message.comment, f"{message.name} has no CM_"
        crc, counter = message.get_signal_by_name("CRC8"), message.get_signal_by_name("COUNTER")
        assert (crc.start, crc.length, counter.start, counter.length) == (0, 8, 8, 4)
        for signal in message.signals:
            assert signal.byte_order == "little_endian"
            assert signal.comment, f"{message.name}.{signal.name} has no CM_"
            assert signal.minimum is not None and signal.maximum is not None


def test_dbc_ranges_and_timing_fit_the_platform():
    motion = DB.get_message_by_name("MOTION_CMD")
    for name in ("V", "OMEGA"):
        signal = motion.get_signal_by_name(name)
        assert (signal.minimum, signal.maximum, signal.scale) == (-2.0, 2.0, 0.001)
    for name in ("PAN", "TILT"):
        signal = DB.get_message_by_name("PTU_STATE").get_signal_by_name(name)
        assert signal.scale == 0.0001 and signal.maximum > math.pi
    assert DB.get_message_by_name("WHEEL_SPEEDS").get_signal_by_name("FL").scale == 0.001
    assert DB.get_message_by_name("EXEC_HEARTBEAT").cycle_time <= 50  # 20 Hz at least
    assert DB.get_message_by_name("MOTION_CMD").cycle_time == 20  # 50 Hz
    assert message_timeout(DB, "EXEC_HEARTBEAT") == DEFAULT_WATCHDOG
    assert message_timeout(DB, "BASE_HEARTBEAT") == DEFAULT_BASE_TIMEOUT
    assert message_timeout(DB, "BASE_RESET") is None


@pytest.mark.parametrize(
    ("message", "signal", "enum"),
    [
        ("EXEC_HEARTBEAT", "STATE", ExecState),
        ("BASE_HEARTBEAT", "STATE", BaseState),
        ("BASE_STATUS", "FAULT", BaseFault),
    ],
)
def test_python_enums_are_the_dbc_value_tables(message, signal, enum):
    choices = DB.get_message_by_name(message).get_signal_by_name(signal).choices
    assert {k: str(v) for k, v in choices.items()} == {e.value: e.name for e in enum}


def _quantised(signal, value: float) -> float:
    raw = round((value - signal.offset) / signal.scale)
    return signal.offset + raw * signal.scale


def _mid(signal) -> float:
    if signal.choices:
        return float(sorted(signal.choices)[len(signal.choices) // 2])
    return _quantised(signal, (signal.minimum + signal.maximum) / 2.0)


@pytest.mark.parametrize("name", MESSAGES)
def test_every_signal_round_trips_at_min_mid_max(name):
    message = DB.get_message_by_name(name)
    mids = {s.name: _mid(s) for s in message.signals}
    for signal in message.signals:
        for value in (signal.minimum, mids[signal.name], signal.maximum):
            data = message.encode({**mids, signal.name: value})
            assert len(data) == message.length
            decoded = message.decode(data, decode_choices=False)
            for s in message.signals:
                want = value if s is signal else mids[s.name]
                assert decoded[s.name] == pytest.approx(want, abs=s.scale / 2 + 1e-9), s.name


@pytest.mark.parametrize("name", MESSAGES)
def test_every_message_passes_the_other_ends_checks(name):
    message = DB.get_message_by_name(name)
    sender = EXECUTIVE_NODE if EXECUTIVE_NODE in message.senders else BASE_NODE
    receiver = BASE_NODE if sender == EXECUTIVE_NODE else EXECUTIVE_NODE
    tx, rx = FrameCodec(DB, sender), FrameCodec(DB, receiver)
    values = {s.name: _mid(s) for s in message.signals if s.name not in ("CRC8", "COUNTER")}
    for counter in range(3):
        received = rx.check(tx.encode(name, values))
        assert received.verdict is Verdict.ACCEPTED
        assert received.signals["COUNTER"] == counter
        for key, value in values.items():
            assert received.signals[key] == pytest.approx(value, abs=1e-9)
    own = tx.check(tx.encode(name, values))
    assert own.verdict is Verdict.IGNORED  # a node never decodes its own messages


# -- checksum and counter ----------------------------------------------------------------
@pytest.mark.parametrize(
    ("data", "crc"),
    [
        (b"123456789", 0x4B),  # the catalogue's check value
        # AUTOSAR SWS CRC Library, 8-bit SAE J1850 test vectors
        (bytes.fromhex("00000000"), 0x59),
        (bytes.fromhex("F20183"), 0x37),
        (bytes.fromhex("0FAA0055"), 0x79),
        (bytes.fromhex("00FF5511"), 0xB8),
        (bytes.fromhex("332255AABBCCDDEEFF"), 0xCB),
        (bytes.fromhex("926B55"), 0x8C),
        (bytes.fromhex("FFFFFFFF"), 0x74),
    ],
)
def test_crc8_sae_j1850_known_vectors(data, crc):
    assert crc8_sae_j1850(data) == crc


def _crc8_bitwise(data: bytes) -> int:
    crc = 0xFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1D) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc ^ 0xFF


@given(st.binary(max_size=64))
def test_crc8_table_matches_the_bitwise_definition(data):
    assert crc8_sae_j1850(data) == _crc8_bitwise(data)


@given(st.binary(min_size=2, max_size=8), st.data())
def test_frame_checksum_covers_identifier_and_payload_not_itself(data, draw):
    crc = frame_checksum(0x100, data)
    assert frame_checksum(0x100, bytes([data[0] ^ 0xFF]) + data[1:]) == crc
    assert frame_checksum(0x101, data) != crc  # the same bytes under another identifier
    bit = draw.draw(st.integers(8, 8 * len(data) - 1))
    flipped = bytearray(data)
    flipped[bit // 8] ^= 1 << (bit % 8)
    assert frame_checksum(0x100, flipped) != crc  # a CRC catches every single-bit error


def test_rolling_counter_wraps_after_15():
    counter = RollingCounter(14)
    assert [counter.take() for _ in range(4)] == [14, 15, 0, 1]


@given(st.integers(0, 15), st.lists(st.integers(0, 15), max_size=60))
def test_counter_check_classifies_each_step(start, steps):
    """A step of 0 repeats the previous counter, 1 follows it, more skips frames."""
    check = CounterCheck()
    assert check.check(start) is CounterVerdict.OK
    counter = start
    for step in steps:
        counter = (counter + step) % 16
        expected = {0: CounterVerdict.REPEATED, 1: CounterVerdict.OK}.get(
            step, CounterVerdict.SKIPPED
        )
        assert check.check(counter) is expected
    assert check.lost == sum(step - 1 for step in steps if step > 1)


def test_counter_check_rejects_a_value_that_is_not_4_bits():
    with pytest.raises(ValueError):
        CounterCheck().check(16)


def test_latency_percentiles_are_nearest_rank():
    stats = latency_stats([k / 1000.0 for k in range(100, 0, -1)], count=250)
    assert (stats.count, stats.p50, stats.p99, stats.max) == (250, 0.050, 0.099, 0.100)
    assert math.isnan(latency_stats([], 0).p50)


def test_config_keeps_index_gaps_and_rejects_duplicates():
    config = BaseLinkConfig.from_indices({"ptz": 2, "front": 0})
    assert config.ptu_units == ("front", "", "ptz")
    assert config.unit_indices() == {"front": 0, "ptz": 2}
    with pytest.raises(ValueError):
        BaseLinkConfig(("front", "front"))
    with pytest.raises(ValueError):
        BaseLinkConfig(tuple(f"u{k}" for k in range(17)))


# -- both ends on a virtual bus ----------------------------------------------------------
def test_a_command_reaches_the_firmware_with_its_values(rig):
    rig.link.send(VelocityCommand(0.5, -0.25, {"ptz": PanTiltRate(0.3, -0.15)}), ExecState.RUNNING)
    assert rig.fw.poll() == 3  # MOTION_CMD, one PTU_CMD, EXEC_HEARTBEAT
    v, omega, rates = rig.fw.command()
    assert v == pytest.approx(0.5, abs=5e-4) and omega == pytest.approx(-0.25, abs=5e-4)
    assert rates["ptz"] == pytest.approx((0.3, -0.15), abs=5e-4)
    assert rates["front"] == rates["rear"] == (0.0, 0.0)
    assert rig.fw.exec_state is ExecState.RUNNING
    assert rig.fw.stats().accepted == 3


def test_sparse_unit_indices_reach_the_right_unit():
    r = make_rig(BaseLinkConfig.from_indices({"front": 0, "ptz": 2}))
    try:
        r.cycle(VelocityCommand(0.0, 0.0, {"ptz": PanTiltRate(0.4, 0.0)}))
        assert r.fw.command().pan_tilt["ptz"] == pytest.approx((0.4, 0.0), abs=5e-4)
    finally:
        close_rig(r)


def test_an_idle_executive_sends_enable_0_and_the_base_holds(rig):
    rig.link.send(FORWARD, ExecState.IDLE)
    rig.fw.poll()
    assert rig.fw.command().v == 0.0
    assert rig.fw.base_state() is BaseState.OK


@pytest.mark.parametrize(
    ("command", "why"),
    [
        (VelocityCommand(math.nan, 0.0), "V=nan m/s is not finite"),
        (VelocityCommand(0.5, math.inf), "OMEGA=inf rad/s is not finite"),
        (VelocityCommand(2.5, 0.0), "V=2.5 m/s is outside [-2, 2]"),
        (VelocityCommand(0.5, 0.0, {"front": PanTiltRate(math.nan, 0.0)}), "PAN_RATE=nan"),
        (VelocityCommand(0.5, 0.0, {"belly": PanTiltRate(0.1, 0.0)}), "unknown pan-tilt"),
    ],
)
def test_a_command_the_dbc_cannot_carry_is_refused_with_a_stop(rig, command, why):
    rig.cycle(VelocityCommand(0.5, 0.1, {"front": PanTiltRate(0.2, 0.2)}))
    assert not zero(rig)
    rig.cycle(command)
    assert zero(rig)  # a stop went out: nothing clamped to the range
    assert rig.link.stats().refused_commands == 1
    assert any(why in reason and "sent a stop" in reason for reason in rig.link.health())
    assert rig.fw.stats().out_of_range == 0  # the stop itself was valid


def test_a_frame_with_a_bad_checksum_is_dropped_by_the_base(rig):
    rig.cycle()
    forged = FrameCodec(DB, EXECUTIVE_NODE).encode(
        "MOTION_CMD", {"ENABLE": 1, "V": -1.5, "OMEGA": 0.0}
    )
    forged.data[0] ^= 0x5A
    rig.exec_bus.send(forged)
    rig.fw.poll()
    assert rig.fw.stats().bad_checksum == 1
    assert rig.fw.command().v == pytest.approx(0.8, abs=5e-4)


@pytest.mark.parametrize("length", [2, 8])
def test_a_frame_of_the_wrong_length_is_dropped_by_the_base(rig, length):
    rig.cycle()
    message = DB.get_message_by_name("MOTION_CMD")
    good = FrameCodec(DB, EXECUTIVE_NODE).encode("MOTION_CMD", {"ENABLE": 1, "V": -1, "OMEGA": 0})
    data = bytearray(good.data[:length].ljust(length, b"\0"))  # cut short or padded
    data[0] = frame_checksum(message.frame_id, data)
    rig.exec_bus.send(can.Message(arbitration_id=message.frame_id, data=data, is_extended_id=False))
    rig.fw.poll()
    assert rig.fw.stats().bad_length == 1
    assert rig.fw.command().v == pytest.approx(0.8, abs=5e-4)


def test_a_repeated_counter_is_dropped_by_the_base(rig):
    rig.spied("MOTION_CMD")
    rig.cycle()
    (last,) = rig.spied("MOTION_CMD")
    message = DB.get_message_by_name("MOTION_CMD")
    signals = message.decode(last.data, decode_choices=False)
    data = bytearray(message.encode({**signals, "V": -1.5}))  # same counter, new value
    data[0] = frame_checksum(message.frame_id, data)
    rig.exec_bus.send(can.Message(arbitration_id=message.frame_id, data=data, is_extended_id=False))
    rig.fw.poll()
    assert rig.fw.stats().repeated_counter == 1
    assert rig.fw.command().v == pytest.approx(0.8, abs=5e-4)


def test_the_watchdog_brakes_within_150_ms_of_the_last_heartbeat():
    r = make_rig(command_timeout=10.0)  # only the heartbeat can stop the base here
    try:
        for _ in range(10):  # 0.2 s at 50 Hz
            r.cycle()
            last_heartbeat = r.base_clock.t
            r.tick(0.02)
        assert r.fw.command().v == pytest.approx(0.8, abs=5e-4)
        r.publish()  # the base says OK
        while r.base_clock.t < last_heartbeat + 0.3:  # the executive is silent
            r.fw.poll()
            if r.base_clock.t < last_heartbeat + DEFAULT_WATCHDOG - 1e-6:
                assert not zero(r)
            r.tick(0.005)
        fired = r.fw.watchdog_fired_at
        assert fired is not None and DEFAULT_WATCHDOG < fired - last_heartbeat <= 0.150
        assert zero(r) and r.fw.base_state() is BaseState.BRAKING_WATCHDOG
        r.publish()
        assert any("braked on its watchdog" in h for h in r.link.holds())  # one trip: a hold
        r.cycle()  # heartbeats resume with a fresh command
        assert r.fw.command().v == pytest.approx(0.8, abs=5e-4)
        # the base says OK again at once; its braking is held as a hold for error_hold
        # (one late tick), and only repeated braking is a link fault
        r.publish()
        assert r.link.snapshot().base_state is BaseState.OK
        assert any("braked on its watchdog" in h for h in r.link.holds())
        assert r.link.health() == [] and r.link.watchdog_trips == 1
        r.tick(r.link.config.error_hold + 0.05)
        r.cycle()
        r.publish()
        assert r.link.holds() == []
    finally:
        close_rig(r)


def test_heartbeats_alone_do_not_keep_an_old_command_alive(rig):
    tx = FrameCodec(DB, EXECUTIVE_NODE)  # an executive whose control loop hangs
    rig.exec_bus.send(tx.encode("MOTION_CMD", {"ENABLE": 1, "V": 0.6, "OMEGA": 0.0}))
    rig.exec_bus.send(tx.encode("PTU_CMD", {"UNIT": 0, "PAN_RATE": 0.2, "TILT_RATE": 0.0}))
    for k in range(10):
        rig.exec_bus.send(tx.encode("EXEC_HEARTBEAT", {"STATE": ExecState.RUNNING}))
        rig.fw.poll()
        stale = k * 0.03 > DEFAULT_WATCHDOG
        v, _, rates = rig.fw.command()
        assert (v == 0.0, rates["front"] == (0.0, 0.0)) == (stale, stale)
        rig.tick(0.03)
    assert rig.fw.base_state() is BaseState.OK  # the watchdog is fed; the command is stale


def test_a_replayed_heartbeat_does_not_feed_the_watchdog(rig):
    rig.spied("EXEC_HEARTBEAT")
    rig.cycle()
    (frozen,) = rig.spied("EXEC_HEARTBEAT")
    for _ in range(30):  # a frozen transmit buffer re-sends the same bytes
        rig.tick(0.01)
        rig.exec_bus.send(frozen)
        rig.fw.poll()
    assert rig.fw.stats().repeated_counter == 30
    assert rig.fw.base_state() is BaseState.BRAKING_WATCHDOG
    assert zero(rig)


def test_the_bumper_latch_holds_until_a_reset_with_no_bumper_pressed(rig):
    rig.cycle()
    rig.publish(bumpers=(True, False))
    assert zero(rig) and rig.fw.base_state() is BaseState.BRAKING_BUMPER
    rig.publish(bumpers=(False, False))
    rig.cycle()
    assert zero(rig) and rig.fw.latched  # released, still latched
    snap = rig.link.snapshot()
    assert snap.latched and snap.reset_needed and not snap.bumpers.any
    # a hold, not a link fault: the run waits for the operator's reset
    assert "base braking: bumper latch set, an operator reset is needed" in rig.link.holds()
    assert rig.link.health() == []

    rig.publish(bumpers=(False, True))
    assert rig.link.send_reset()
    rig.fw.poll()
    assert rig.fw.latched and rig.fw.refused_resets == 1  # refused while pressed

    rig.publish(bumpers=(False, False))
    assert rig.link.send_reset()
    rig.cycle()
    assert not rig.fw.latched
    assert rig.fw.command().v == pytest.approx(0.8, abs=5e-4)
    rig.publish()
    assert rig.link.health() == []


def test_a_reset_without_the_magic_value_is_dropped(rig):
    rig.publish(bumpers=(True, False))
    rig.publish(bumpers=(False, False))
    message = DB.get_message_by_name("BASE_RESET")
    data = bytearray(message.encode({"CRC8": 0, "COUNTER": 0, "MAGIC": 0x1234}, strict=False))
    data[0] = frame_checksum(message.frame_id, data)
    rig.exec_bus.send(can.Message(arbitration_id=message.frame_id, data=data, is_extended_id=False))
    rig.fw.poll()
    assert rig.fw.latched and rig.fw.stats().out_of_range == 1


def test_the_snapshot_holds_the_latest_readings_stamped_on_arrival(rig):
    rig.exec_clock.t = 42.0
    rig.publish(
        wheels=(0.5, 0.7, 0.3, 0.9),
        yaw_rate=0.25,
        ax=0.4,
        ay=-0.1,
        ptu={"front": (0.1, -0.2), "ptz": (1.5, 0.3)},
        bumpers=(True, False),
        battery=(47.25, 80.5),
    )
    rig.exec_clock.t = 42.5
    snap = rig.link.snapshot()
    assert snap.stamp == 42.5
    assert (snap.wheels.stamp, snap.wheels.left, snap.wheels.right) == pytest.approx(
        (42.0, 0.4, 0.8)
    )
    assert (snap.imu.stamp, snap.imu.yaw_rate) == pytest.approx((42.0, 0.25))
    assert snap.acceleration == pytest.approx((0.4, -0.1))
    assert set(snap.pan_tilt) == {"front", "ptz"}
    ptz = snap.pan_tilt["ptz"]
    assert (ptz.stamp, ptz.pan, ptz.tilt) == pytest.approx((42.0, 1.5, 0.3))
    assert snap.bumpers == Bumpers(42.0, front=True, rear=False) and snap.latched
    assert (snap.battery_voltage, snap.battery_percent) == pytest.approx((47.25, 80.5))
    assert snap.fault is BaseFault.NONE and snap.heartbeat_at == 42.0
    assert snap.base_state is BaseState.BRAKING_BUMPER

    frame = snap.fill(SensorFrame(stamp=42.5))
    assert frame.wheels == snap.wheels and frame.imu == snap.imu
    assert frame.bumpers.front and dict(frame.pan_tilt) == dict(snap.pan_tilt)
    with pytest.raises(TypeError):
        snap.pan_tilt["rear"] = ptz  # type: ignore[index]
    with pytest.raises(dataclasses.FrozenInstanceError):
        snap.latched = False  # type: ignore[misc]


def test_bad_checksum_and_repeated_counter_from_the_base_are_dropped(rig):
    rig.publish(wheels=(0.2, 0.2, 0.2, 0.2))
    (last,) = rig.spied("WHEEL_SPEEDS")
    forged = FrameCodec(DB, BASE_NODE).encode(
        "WHEEL_SPEEDS", {"FL": 3.0, "FR": 3.0, "RL": 3.0, "RR": 3.0}
    )
    forged.data[3] ^= 0x01
    rig.from_base(lambda: rig.base_bus.send(forged), 1)
    rig.from_base(lambda: rig.base_bus.send(last), 1)  # the same frame again
    stats = rig.link.stats().frames
    assert (stats.bad_checksum, stats.repeated_counter) == (1, 1)
    assert rig.link.snapshot().wheels.left == pytest.approx(0.2)
    counter = int(DB.decode_message(last.arbitration_id, last.data)["COUNTER"])
    reason = f"stale frame from the base: WHEEL_SPEEDS repeated rolling counter {counter}"
    assert reason in rig.link.health()


def test_unknown_identifiers_are_counted_and_change_nothing(rig):
    rig.cycle()
    rig.publish(wheels=(0.2, 0.2, 0.2, 0.2), ptu={"rear": (0.1, 0.1)})
    before = rig.link.snapshot()
    strangers = [
        can.Message(arbitration_id=0x7FF, data=bytes(8), is_extended_id=False),
        can.Message(arbitration_id=0x190, data=bytes(8), is_extended_id=True),
        can.Message(arbitration_id=0x190, is_remote_frame=True, is_extended_id=False),
    ]
    for msg in strangers:
        rig.from_base(lambda msg=msg: rig.base_bus.send(msg), 1)
    echo = FrameCodec(DB, EXECUTIVE_NODE).encode("MOTION_CMD", {"ENABLE": 1, "V": 1, "OMEGA": 0})
    rig.from_base(lambda: rig.base_bus.send(echo), 1)  # a command id: not ours to decode
    stats = rig.link.stats().frames
    assert (stats.unknown_frames, stats.ignored_frames) == (3, 1)
    assert rig.link.snapshot() == before
    assert rig.link.health() == []


def test_a_pan_tilt_unit_nobody_configured_is_counted_not_decoded():
    r = make_rig(ptu_units=("front", "rear", "ptz", "belly"))
    try:
        r.publish(ptu={"belly": (0.5, 0.5)})
        assert r.link.stats().frames.unknown_units == 1
        assert r.link.snapshot().pan_tilt == {}
    finally:
        close_rig(r)


def test_health_names_a_lost_base_heartbeat(rig):
    rig.cycle()
    rig.publish()
    assert rig.link.health() == []
    rig.tick(0.06)
    rig.cycle()
    assert rig.link.health() == []
    rig.tick(0.06)
    rig.cycle()
    assert rig.link.health() == ["base heartbeat lost for 0.12 s"]
    rig.publish()
    assert rig.link.health() == []


def test_health_names_a_base_heartbeat_never_received(rig):
    assert rig.link.health() == []
    rig.tick(0.25)
    rig.cycle()
    assert rig.link.health() == ["base heartbeat never received (link open for 0.25 s)"]


def test_an_executive_that_stopped_sending_sees_the_base_brake(rig):
    rig.cycle()
    rig.publish()
    rig.tick(0.15)
    rig.fw.poll()
    rig.publish()
    assert rig.fw.base_state() is BaseState.BRAKING_WATCHDOG
    assert any(h.startswith("the base braked on its watchdog") for h in rig.link.holds())
    assert rig.link.health() == []  # once is a hold; WATCHDOG_TRIPS times is a fault


def test_health_names_a_failed_send_and_no_heartbeat_goes_out(rig, monkeypatch):
    rig.cycle()
    rig.tick(0.06)
    rig.publish()

    def full(msg: can.Message, timeout: float | None = None) -> None:
        raise can.CanOperationError("Transmit buffer full")

    monkeypatch.setattr(rig.exec_bus, "send", full)
    rig.link.send(FORWARD)  # does not raise
    assert rig.fw.poll() == 0
    assert "CAN send failed: Transmit buffer full" in rig.link.health()
    assert rig.link.stats().send_errors == 1
    assert not rig.link.send_reset()
    rig.tick(0.06)  # the failed cycle sent no heartbeat: the last one is 0.12 s old
    rig.fw.poll()
    assert rig.fw.base_state() is BaseState.BRAKING_WATCHDOG  # the base brakes by itself

    monkeypatch.undo()
    rig.tick(1.05)
    rig.cycle()
    rig.publish()
    assert rig.link.health() == []


def test_health_names_error_frames(rig):
    rig.cycle()
    rig.publish()
    error = can.Message(is_error_frame=True, arbitration_id=0x20000004, is_extended_id=True)
    rig.from_base(lambda: rig.base_bus.send(error), 1)
    assert rig.link.stats().error_frames == 1
    assert "CAN error frame received" in rig.link.health()


class BusOffBus(VirtualBus):
    """A virtual bus whose controller reports bus-off."""

    @property
    def state(self) -> can.BusState:
        return can.BusState.ERROR


def test_health_names_bus_off():
    r = make_rig(bus_class=BusOffBus)
    try:
        r.cycle()
        r.publish()
        assert r.link.health() == ["CAN bus-off: the controller is in its error state"]
    finally:
        close_rig(r)


def test_health_names_a_base_fault_and_the_base_brakes(rig):
    rig.cycle()
    rig.publish(fault=BaseFault.DRIVE_OVERTEMPERATURE)
    assert zero(rig) and rig.fw.base_state() is BaseState.FAULT
    assert rig.link.health() == ["base fault: DRIVE_OVERTEMPERATURE"]
    rig.publish()
    rig.cycle()
    assert not zero(rig) and rig.link.health() == []


def test_the_hardware_estop_is_a_hold_not_a_link_fault(rig):
    rig.cycle()
    rig.publish(estop=True)
    assert zero(rig) and rig.fw.base_state() is BaseState.ESTOP
    assert rig.link.health() == [] and rig.link.holds() == ["hardware e-stop pressed"]
    rig.publish()
    rig.cycle()
    assert not zero(rig) and rig.link.holds() == []


def test_latency_is_measured_from_the_bus_time_stamp(rig):
    for _ in range(5):
        rig.publish()
    latency = rig.link.stats().latency
    assert latency.count == 5 * 6  # six status frames per cycle
    assert 0.0 <= latency.p50 <= latency.p99 <= latency.max < 5.0


def test_close_stops_the_receive_thread(rig):
    rig.link.close()
    rig.link.close()  # idempotent
    rig.fw.publish()
    assert rig.exec_bus.recv(timeout=1.0) is not None  # left on the bus, nobody reads it


# -- the odometers ------------------------------------------------------------------------------
def test_the_odometers_integrate_the_wheel_speeds_and_reach_the_frame(rig):
    """WHEEL_TRAVEL: each side's distance since the firmware started, integrated from its
    wheels' speeds (trapezoids on the base's clock), in every frame the link reads."""
    rig.publish(wheels=(0.0, 0.0, 0.0, 0.0))
    assert rig.fw.travel == (0.0, 0.0)
    for _ in range(50):  # 1 s at 50 Hz: accelerating to 0.2 and 0.4 m/s in the first cycle
        rig.base_clock.t += 0.02
        rig.publish(wheels=(0.2, 0.4, 0.2, 0.4))
    assert rig.fw.travel == pytest.approx((0.198, 0.396))
    wheels = rig.link.snapshot().fill(SensorFrame(0.0)).wheels
    assert wheels is not None and wheels.travel == pytest.approx((0.198, 0.396), abs=1e-3)


@given(st.floats(-1e4, 1e4), st.floats(-30.0, 30.0))
def test_wrapped_odometer_differences_are_the_travel(start, travelled):
    """The 26-bit odometers wrap every 67 km; a difference of two readings is the travel
    in between, to the millimetre, wherever the counter stood."""
    for offset in (0.0, 33554.0, -33554.0):
        before = wrap_travel(start + offset)
        after = wrap_travel(start + offset + travelled)
        assert abs(travel_difference(after, before) - travelled) <= 1.5e-3
        assert -33554.432 <= after <= 33554.431


# -- a recorded run decodes with the shipped DBC ---------------------------------------------
@pytest.mark.parametrize("suffix", [".asc", ".blf"])
def test_a_recorded_log_decodes_with_the_shipped_dbc(rig, tmp_path, suffix):
    rig.spied()  # empty the spy
    for k in range(3):
        rig.cycle(VelocityCommand(0.1 * k, -0.1, {"front": PanTiltRate(0.2, 0.0)}))
        rig.fw.publish(
            wheels=(0.1, 0.2, 0.3, 0.4), ptu={"ptz": (0.5, -0.5)}, bumpers=(k == 1, False)
        )
    rig.link.send_reset()
    recorded = rig.spied()
    path = tmp_path / f"run{suffix}"
    logger = can.Logger(path)
    for msg in recorded:
        logger.on_message_received(msg)
    logger.stop()

    replayed = list(can.LogReader(path))
    assert len(replayed) == len(recorded) == 3 * (3 + 7) + 1
    db = load_dbc()
    names = set()
    for original, msg in zip(recorded, replayed, strict=True):
        assert (msg.arbitration_id, bytes(msg.data)) == (original.arbitration_id, original.data)
        message = db.get_message_by_frame_id(msg.arbitration_id)
        decoded = message.decode(msg.data)
        assert msg.data[0] == frame_checksum(msg.arbitration_id, msg.data)
        assert decoded == message.decode(original.data)
        names.add(message.name)
    assert names == set(MESSAGES)


def _watchdog_brake(r: Rig, stall: float = 0.15) -> list[str]:
    """One heartbeat of ours ``stall`` seconds late: the base brakes; the link's faults."""
    r.cycle()
    r.publish()  # OK
    r.tick(stall)
    r.fw.poll()
    r.publish()  # BRAKING_WATCHDOG
    return r.link.health()


def _drive_on(r: Rig, seconds: float) -> None:
    """Heartbeats on time (every 20 ms) for ``seconds``."""
    for _ in range(round(seconds / 0.02)):
        r.tick(0.02)
        r.cycle()
    r.publish()


def test_repeated_watchdog_braking_is_a_link_fault():
    from executive.robotlink.canbase import WATCHDOG_STALL_GAP, WATCHDOG_TRIPS

    r = make_rig(command_timeout=10.0)
    try:
        for trip in range(WATCHDOG_TRIPS):
            faults = _watchdog_brake(r)
            if trip < WATCHDOG_TRIPS - 1:
                assert not any("watchdog" in f for f in faults), (trip, faults)
                _drive_on(r, WATCHDOG_STALL_GAP + 0.2)  # separate stalls
        assert r.link.watchdog_trips == WATCHDOG_TRIPS
        assert any(f"watchdog in {WATCHDOG_TRIPS} stalls" in f for f in faults), faults
    finally:
        close_rig(r)


def test_one_stall_that_lets_several_heartbeats_run_late_only_holds_the_robot():
    """A slow machine for 0.4 s: three heartbeat gaps in a row pass the 100 ms watchdog.
    The base brakes each time (a hold); one hiccup is not a lost link."""
    from executive.robotlink.canbase import WATCHDOG_TRIPS

    r = make_rig(command_timeout=10.0)
    try:
        for _ in range(WATCHDOG_TRIPS):
            faults = _watchdog_brake(r, stall=0.11)
            assert faults == [], faults
            assert any("braked on its watchdog" in h for h in r.link.holds())
        assert r.link.watchdog_trips == WATCHDOG_TRIPS
    finally:
        close_rig(r)


def test_a_heartbeat_that_keeps_arriving_late_is_a_link_fault():
    from executive.robotlink.canbase import WATCHDOG_LONGEST_STALL

    r = make_rig(command_timeout=10.0)
    try:
        started = r.exec_clock.t
        faults: list[str] = []
        while not faults:
            assert r.exec_clock.t - started < WATCHDOG_LONGEST_STALL + 0.5, "never a fault"
            faults = _watchdog_brake(r, stall=0.11)
        assert r.exec_clock.t - started >= WATCHDOG_LONGEST_STALL
        assert any("keeps arriving late" in f for f in faults), faults
    finally:
        close_rig(r)


@given(st.lists(st.floats(0.0, 20.0), max_size=30), st.floats(0.01, 3.0))
def test_watchdog_stalls_partition_the_brakes_by_their_gaps(trips, gap):
    from executive.robotlink.canbase import watchdog_stalls

    trips = sorted(trips)
    stalls = watchdog_stalls(trips, gap)
    assert [t for s in stalls for t in s] == trips
    for s in stalls:
        assert all(b - a < gap for a, b in itertools.pairwise(s))
    for before, after in itertools.pairwise(stalls):
        assert after[0] - before[-1] >= gap
