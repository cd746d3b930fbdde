"""``walkaround sim-robot``'s base: the simulated firmware on its own wall-clock timer,
whatever the physics loop beside it does (a simulator that falls behind real time must not
look like a lost base to the executive)."""

from __future__ import annotations

import time
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from types import MappingProxyType, SimpleNamespace

import can
import pytest
from can.interfaces.virtual import VirtualBus

from executive.core.records import PanTilt, VelocityCommand
from executive.robotlink.canbase import (
    CanBaseLink,
    ExecState,
    SimulatedBaseFirmware,
    load_dbc,
)
from executive.simrobot import BaseTimer, FirmwareClock
from tests.conftest import wait_until

DB = load_dbc()


def _frame(front: bool = False, rear: bool = False, speed: float = 0.0) -> SimpleNamespace:
    """The parts of a sim2d SensorFrame the base reads."""
    return SimpleNamespace(
        wheels=SimpleNamespace(left=speed, right=speed),
        imu=SimpleNamespace(yaw_rate=0.0),
        pan_tilt=MappingProxyType({"front": PanTilt(0.0, 0.1, -0.2)}),
        bumpers=SimpleNamespace(front=front, rear=rear),
    )


@dataclass
class Base:
    """The sim-robot's base on a virtual channel, and the executive's bus on it."""

    channel: str
    timer: BaseTimer
    firmware: SimulatedBaseFirmware
    exec_bus: can.BusABC


@pytest.fixture
def base() -> Iterator[Base]:
    channel = "simrobot-" + uuid.uuid4().hex
    base_bus, exec_bus = VirtualBus(channel=channel), VirtualBus(channel=channel)
    firmware = SimulatedBaseFirmware(base_bus, DB, ptu_units=("front",))
    rig = Base(channel, BaseTimer(base_bus, firmware, time.monotonic), firmware, exec_bus)
    yield rig
    rig.timer.close()
    base_bus.shutdown()
    exec_bus.shutdown()


def test_the_base_heartbeats_while_the_simulation_stands_still(base):
    """No physics step at all (sense never called): the executive still hears the base,
    several times, and its link finds nothing wrong."""
    spy = VirtualBus(channel=base.channel)
    link = CanBaseLink(base.exec_bus, db=DB)
    try:
        base.timer.start()
        heartbeat = DB.get_message_by_name("BASE_HEARTBEAT").frame_id
        seen: list[can.Message] = []

        def heard() -> bool:
            while (msg := spy.recv(timeout=0.0)) is not None:
                seen.append(msg)
            return sum(m.arbitration_id == heartbeat for m in seen) >= 3

        wait_until(heard, 10.0, "three base heartbeats")
        assert link.snapshot().heartbeat_at is not None
        assert link.health() == []
    finally:
        link.close()
        spy.shutdown()


def test_the_executive_heartbeat_reaches_the_watchdog_without_the_physics_loop(base):
    """Frames are consumed as they arrive (a Notifier), not when the loop polls: the
    firmware sees the executive's heartbeat with nobody calling poll()."""
    link = CanBaseLink(base.exec_bus, db=DB)
    try:
        base.timer.start()
        link.send(VelocityCommand(0.0, 0.0), ExecState.IDLE)
        wait_until(lambda: base.firmware.heartbeat_at is not None, 10.0, "the executive heartbeat")
    finally:
        link.close()


def test_a_contact_between_two_status_frames_latches_the_base(base):
    """The physics saw the bumper pressed and released within one status period: the next
    status frame still carries the contact (the firmware latches), the one after it the
    released switch."""
    timer, firmware = base.timer, base.firmware
    timer.sense(_frame(front=True))
    timer.sense(_frame())
    first = timer.take()
    assert first["bumpers"] == (True, False)
    firmware.publish(**first)
    assert firmware.latched
    assert timer.take()["bumpers"] == (False, False)


def test_status_frames_carry_the_latest_step(base):
    timer = base.timer
    timer.sense(_frame(speed=0.1))
    timer.sense(_frame(speed=0.3))
    inputs = timer.take()
    assert inputs["wheels"] == (0.3, 0.3, 0.3, 0.3)
    assert inputs["ptu"] == {"front": (0.1, -0.2)}


def test_a_contact_latches_the_running_base(base):
    """The same through the thread: one physics step with the bumper pressed, the next
    released; the base latches."""
    base.timer.start()
    base.timer.sense(_frame(front=True))
    base.timer.sense(_frame())
    wait_until(lambda: base.firmware.latched, 10.0, "the bumper latch")


def test_a_base_that_cannot_send_ends_the_simulator(base):
    """A failed send stops the heartbeat thread; the serving loop's check raises it
    instead of letting the base go silent without a cause."""
    base.timer.start()
    base.timer.check()  # nothing wrong yet
    base.timer._bus.shutdown()  # the adapter is gone

    def raised() -> bool:
        try:
            base.timer.check()
        except Exception:
            return True
        return False

    wait_until(raised, 10.0, "the failure to surface")


class _Wall:
    """A wall clock the test moves by hand."""

    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def test_a_stall_of_the_whole_machine_does_not_trip_the_base_watchdog():
    """The firmware's clock leaves out what this process did not live: a 130 ms stall of
    the machine (both processes silent, as a CI's CAN log showed) is not a 130 ms gap in
    the executive's heartbeat. A heartbeat that really stops, the clock read every 20 ms
    by the base's timer, still trips the 100 ms watchdog within one reading of it."""
    wall = _Wall()
    clock = FirmwareClock(wall)
    channel = "fwclock-" + uuid.uuid4().hex
    exec_bus, base_bus = VirtualBus(channel=channel), VirtualBus(channel=channel)
    link = CanBaseLink(exec_bus, clock=wall, db=DB)
    firmware = SimulatedBaseFirmware(base_bus, DB, clock=clock, watchdog=0.1)
    try:

        def cycle(dt: float) -> None:
            wall.t += dt
            link.send(VelocityCommand(0.3, 0.0))
            firmware.poll()

        for _ in range(10):
            cycle(0.02)
        assert firmware.command().v == pytest.approx(0.3)
        cycle(0.13)  # the machine stood still for 130 ms, then both ran on
        assert firmware.watchdog_fired_at is None
        assert clock.stalls == 1 and clock.stalled_s == pytest.approx(0.08)
        for _ in range(5):
            cycle(0.02)
        assert firmware.command().v == pytest.approx(0.3)
        silent_from = clock()
        for _ in range(10):  # the executive is killed; the base's timer reads on
            wall.t += 0.02
            firmware.poll()
        assert firmware.watchdog_fired_at is not None
        assert firmware.watchdog_fired_at - silent_from <= 0.1 + 0.02 + 1e-9
        assert firmware.command().v == 0.0
    finally:
        link.close()
        for bus in (exec_bus, base_bus):
            bus.shutdown()
