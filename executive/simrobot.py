"""``walkaround sim-robot``: sim2d in real time, serving exactly the robot's wires.

Hardware in the loop without the hardware (ARCHITECTURE §8): the scenario runs on the
wall clock in its own process and speaks what the robot speaks, on the addresses of a
robot file:

* CAN frames per the shipped DBC on the configured python-can interface, through
  :class:`~executive.robotlink.canbase.SimulatedBaseFirmware` — the base's own rules:
  the watchdog brakes when the executive's heartbeat stops, a bumper contact latches
  until a BASE_RESET, repeated or corrupt frames feed nothing;
* one SCIP 2.0 server per laser (a UTM-30LX-EW as the executive's client sees it);
* an NMEA 0183 stream (GGA + GST) of the simulated GPS, no fix under the wings;
* the camera detections on ZeroMQ, as the on-board vision process publishes them.

The motors get only what the firmware lets through. The ground truth is written to
``truth.jsonl`` with the Unix time of each sample (and collisions and watchdog braking as
events) so that :mod:`executive.hil` can judge the run of ``walkaround run``, which never
sees it.
"""

from __future__ import annotations

import datetime as dt
import gc
import json
import math
import threading
import time
from collections.abc import Callable
from pathlib import Path
from types import MappingProxyType

import can
import numpy as np

from executive.core.records import PanTiltRate, SensorFrame, VelocityCommand
from executive.hil import TRUTH_FILE
from executive.robotlink.canbase import SimulatedBaseFirmware
from executive.robotlink.config import RobotConfig
from executive.robotlink.detections import DetectionPublisher
from executive.robotlink.nmea import GeoReference, NmeaServer
from executive.robotlink.scip import ScipServer
from sim2d.robot import SimRobot
from sim2d.scenario import FaultKind, Scenario

STEP = 0.01
"""Seconds of the serving loop: the physics rate of sim2d (100 Hz)."""
BASE_RATE_HZ = 50.0
"""The base's status frames (wheels, IMU, pan-tilt, bumpers, heartbeat), on the wall
clock."""
TRUTH_RATE_HZ = 10.0


class FirmwareClock:
    """The base firmware's clock: ``wall`` less the time this process did not run.

    A real base is a microcontroller of its own: when the computer beside it stalls, its
    watchdog keeps time and never brakes for a stall it did not live through. Here the
    base is a thread sharing the machine (and a virtual machine's stalls) with the
    executive, so a stall of the machine silences both at once and then shows the
    firmware a heartbeat gap the executive never made (a CI's CAN log: both sides silent
    for 106 and 129 ms together, then the base braked on its 100 ms watchdog). A gap
    between two readings longer than ``max_gap`` is such time: all of it beyond
    ``max_gap`` is left out, and counted (:attr:`stalls`, :attr:`stalled_s`). The
    serving loop and the base's timer read the clock every 10 and 20 ms, so a heartbeat
    that really stops (a killed executive) still trips the watchdog on time.
    """

    def __init__(self, wall: Callable[[], float], max_gap: float = 0.05) -> None:
        self._wall = wall
        self.max_gap = max_gap
        self._lock = threading.Lock()
        self._last = wall()
        self.stalls = 0
        self.stalled_s = 0.0
        """The time left out, s."""

    def __call__(self) -> float:
        with self._lock:
            now = self._wall()
            gap = now - self._last
            if gap > self.max_gap:
                self.stalls += 1
                self.stalled_s += gap - self.max_gap
            self._last = now
            return now - self.stalled_s


def _port_of(url: str) -> int:
    """The port of ``socket://host:port``."""
    return int(url.rsplit(":", 1)[1])


class _Wires:
    """The servers of every wire, and what each last published."""

    def __init__(self, config: RobotConfig, clock: Callable[[], float]) -> None:
        self.bus = can.Bus(**config.can.bus_kwargs())
        self.firmware_clock = FirmwareClock(clock)
        self.firmware = SimulatedBaseFirmware(
            self.bus,
            clock=self.firmware_clock,
            watchdog=config.can.watchdog,
            ptu_units=_units(config),
        )
        self.lasers = {laser.id: ScipServer(port=laser.port) for laser in config.lasers}
        self.gps = None
        if config.gps is not None and config.gps.url.startswith("socket://"):
            geo = GeoReference(
                config.gps.latitude_deg, config.gps.longitude_deg, config.gps.x_axis_bearing_deg
            )
            self.gps = NmeaServer(geo, port=_port_of(config.gps.url))
        self.detections = (
            DetectionPublisher(config.detections) if config.detections is not None else None
        )
        self.base = BaseTimer(self.bus, self.firmware, clock)
        self.base.start()
        self._sent: dict[str, float] = {}
        self._dropped: set[str] = set()

    def _new(self, key: str, stamp: float) -> bool:
        if self._sent.get(key) == stamp:
            return False
        self._sent[key] = stamp
        return True

    def drop_lasers(self, scenario: Scenario, t: float) -> None:
        """A scenario's ``laser-dropout`` is, on the wire, the scanner's TCP connection
        dropped at the fault's start (sim2d produces no scan while it lasts, and the
        client reconnects to a silent device until it ends)."""
        for fault in scenario.faults:
            key = f"drop:{fault.target}:{fault.at}"
            if (
                fault.kind is FaultKind.LASER_DROPOUT
                and fault.active(t)
                and key not in self._dropped
            ):
                self._dropped.add(key)
                for lid, server in self.lasers.items():
                    if fault.target in (None, lid):
                        server.drop_connections()

    def publish_sensors(self, frame: SensorFrame) -> None:
        for lid, scan in frame.scans.items():
            server = self.lasers.get(lid)
            if server is not None and self._new(f"laser:{lid}", scan.stamp):
                server.publish(np.asarray(scan.ranges), int(scan.stamp * 1000) % (1 << 24))
        if self.detections is not None:
            for cam, image in frame.cameras.items():
                if self._new(f"camera:{cam}", image.stamp):
                    self.detections.publish(cam, image)

    def publish_gps(self, frame: SensorFrame, t: float, rate_hz: float) -> None:
        if self.gps is None:
            return
        fix = frame.gps
        if fix is not None and self._new("gps", fix.stamp):
            self.gps.publish(fix, dt.datetime.now(dt.UTC))
        elif fix is None and self._new("gps-none", math.floor(t * rate_hz)):
            self.gps.publish(None, dt.datetime.now(dt.UTC))  # a GGA without a fix

    def close(self) -> None:
        self.base.close()
        for server in self.lasers.values():
            server.close()
        if self.gps is not None:
            self.gps.close()
        if self.detections is not None:
            self.detections.close()
        self.bus.shutdown()


class BaseTimer(can.Listener):
    """The base's microcontroller beside the simulation, on its own wall-clock timer.

    A real base receives frames and sends its status at a fixed rate whatever the
    computer beside it does. So here a python-can Notifier hands every received frame to
    the firmware as it arrives (its watchdog sees our heartbeat's real arrival times), and
    this thread sends the status frames and BASE_HEARTBEAT every 1/BASE_RATE_HZ s of wall
    time with the latest simulated inputs. A simulator that falls behind real time (a
    busy machine) then delays its sensors, which the executive judges as stale data, not
    the base's heartbeat, which it would rightly judge as a lost link. A bumper contact
    seen between two status frames still reaches the firmware (its latch).
    """

    def __init__(
        self, bus: can.BusABC, firmware: SimulatedBaseFirmware, clock: Callable[[], float]
    ) -> None:
        self._firmware = firmware
        self._clock = clock
        self._lock = threading.Lock()
        self._inputs: dict[str, object] = {}
        self._pressed = (False, False)
        """The bumper switches at the last physics step."""
        self._contact = (False, False)
        """Any contact since the last status frame, per bumper."""
        self._stop = threading.Event()
        self.error: BaseException | None = None
        """Why the base went silent (a failed send, a failed receive); the serving loop
        re-raises it (:meth:`check`)."""
        self._bus = bus
        self._notifier: can.Notifier | None = None
        self._thread = threading.Thread(target=self._run, name="base-firmware", daemon=True)

    def check(self) -> None:
        """Raise what stopped the sending thread or the receiving Notifier, if anything
        did: a base that went silent must end the simulator, not brake without a cause."""
        if self.error is not None:
            raise self.error

    def start(self) -> None:
        """Power the base on: receive and send from now on."""
        self._notifier = can.Notifier(self._bus, [self], 0.05)
        self._thread.start()

    def sense(self, frame: SensorFrame) -> None:
        """Take the simulated inputs of one physics step."""
        wheels = frame.wheels
        left, right = (wheels.left, wheels.right) if wheels is not None else (0.0, 0.0)
        bumpers = (frame.bumpers.front, frame.bumpers.rear)
        inputs = {
            "wheels": (left, right, left, right),
            "yaw_rate": frame.imu.yaw_rate if frame.imu is not None else 0.0,
            "ptu": {unit: (pt.pan, pt.tilt) for unit, pt in frame.pan_tilt.items()},
        }
        with self._lock:
            self._inputs = inputs
            self._pressed = bumpers
            self._contact = (self._contact[0] or bumpers[0], self._contact[1] or bumpers[1])

    # the Notifier's listener: frames to the firmware, a failed receive to :meth:`check`
    def on_message_received(self, msg: can.Message) -> None:
        self._firmware.on_message_received(msg)

    def on_error(self, exc: Exception) -> None:
        self.error = exc

    def stop(self) -> None:
        """Nothing to release: :meth:`close` ends the base."""

    def take(self) -> dict[str, object]:
        """The inputs of the next status frame."""
        with self._lock:
            inputs = {**self._inputs, "bumpers": self._contact}
            self._contact = self._pressed
        return inputs

    def _run(self) -> None:
        period = 1.0 / BASE_RATE_HZ
        due = self._clock()
        try:
            while not self._stop.wait(max(0.0, due - self._clock())):
                self._firmware.publish(**self.take())  # type: ignore[arg-type]
                due += period
                if self._clock() - due > period:  # starved: the next frame now, not a burst
                    due = self._clock()
        except Exception as exc:  # any failure ends the heartbeat: serve raises it
            self.error = exc

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=1.0)
        if self._notifier is not None:
            self._notifier.stop(timeout=1.0)


def _units(config: RobotConfig) -> tuple[str, ...]:
    units = [""] * (max(config.ptus.values(), default=-1) + 1)
    for unit, index in config.ptus.items():
        units[index] = unit
    return tuple(units)


def serve(
    scenario: Scenario,
    config: RobotConfig,
    out: Path,
    *,
    should_stop: Callable[[], bool] = lambda: False,
    max_time: float | None = None,
) -> str:
    """Run ``scenario`` in real time serving ``config``'s wires until ``should_stop`` or
    ``max_time`` (s); returns a one-line summary. Writes ``out/truth.jsonl``."""
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()

    def clock() -> float:
        return time.monotonic() - t0

    sim = SimRobot(scenario)
    end = min(max_time if max_time is not None else math.inf, scenario.duration)
    next_truth = 0.0
    braked_at: float | None = None
    collisions = 0
    gps_rate = scenario.gps.rate_hz
    with (out / TRUTH_FILE).open("w", encoding="utf-8") as truth:
        wires = _Wires(config, clock)  # the base powers on: from here on it is closed
        gc.collect()
        gc.freeze()  # the scene and the wires: no full collection stalls the base's heartbeat
        try:
            while not should_stop() and sim.time < end:
                wires.base.check()
                command = wires.firmware.command()
                sim.send(
                    VelocityCommand(
                        command.v,
                        command.omega,
                        MappingProxyType(
                            {u: PanTiltRate(p, t) for u, (p, t) in command.pan_tilt.items()}
                        ),
                    )
                )
                sim.advance(STEP)
                frame = sim.read()
                wires.drop_lasers(scenario, sim.time)
                wires.publish_sensors(frame)
                wires.publish_gps(frame, sim.time, gps_rate)
                wires.base.sense(frame)
                fired = wires.firmware.watchdog_fired_at
                if fired is not None and fired != braked_at:
                    braked_at = fired
                    _event(
                        truth,
                        {
                            "event": "watchdog",
                            "unix": time.time(),
                            "base_clock": fired,
                            "after_s": wires.firmware.watchdog_fired_after,
                            "v": wires.firmware.command().v,
                        },
                    )
                    truth.flush()
                world = sim.world
                for c in world.collisions[collisions:]:
                    _event(truth, {"event": "collision", "with": c.other, "t": c.time})
                collisions = len(world.collisions)
                if sim.time >= next_truth:
                    next_truth += 1.0 / TRUTH_RATE_HZ
                    pose = world.robot_pose
                    _event(
                        truth,
                        {
                            "t": round(sim.time, 3),
                            "unix": time.time(),
                            "robot": [pose.x, pose.y, pose.theta],
                        },
                    )
                    truth.flush()
                delay = sim.time - clock()
                if delay > 0:
                    time.sleep(delay)
        finally:
            wires.close()
            gc.unfreeze()
    lag = clock() - sim.time
    stalls = wires.firmware_clock
    return (
        f"sim-robot: {sim.time:.1f} s served ({lag:+.2f} s behind real time), "
        f"{collisions} collisions, {stalls.stalls} stalls of this process "
        f"({stalls.stalled_s:.2f} s, not counted by the base's watchdog); "
        f"truth in {out / TRUTH_FILE}"
    )


def _event(out: object, record: dict[str, object]) -> None:
    out.write(json.dumps(record, separators=(",", ":")) + "\n")  # type: ignore[attr-defined]
