"""RobotLink: the robot as the runtime sees it, composed from one client per wire.

Like python-can's ``BusABC`` and its backends, each wire is a small client with the same
shape (a background thread, ``latest()`` that never blocks, its own health and
statistics); :class:`RobotLink` composes them from a robot file into the one seam the
runtime knows (:class:`~executive.core.robot.RobotInterface`):

* the drive base, IMU, pan-tilt units and bumpers: :class:`~.canbase.CanBaseLink` on a
  python-can bus, with the DBC shipped with walkaround;
* the lasers: one :class:`~.scip.ScipClient` per scanner (SCIP 2.0 over TCP);
* the GPS: :class:`~.nmea.NmeaClient` (NMEA 0183 over TCP or a serial port);
* the cameras' feature detections: :class:`~.detections.DetectionSubscriber` (ZeroMQ).

Every reading is stamped on arrival with the run's clock. :meth:`RobotLink.read` puts
the latest of each in a :class:`SensorFrame`; the safety layer judges freshness, so a
laser whose connection dropped simply goes stale (the robot is held) and comes back by
itself. :meth:`RobotLink.link_faults` names what makes the base itself untrustworthy
(its heartbeat lost, bus-off, error frames, failed sends, a replayed counter): the
runtime then stops the run. Closing the link stops our heartbeat, so the base's watchdog
brakes even if the last stop frame were lost.
"""

from __future__ import annotations

import contextlib
import math
import time
from collections import deque
from collections.abc import Callable, Mapping
from pathlib import Path
from types import MappingProxyType

import can
import numpy as np

from executive.core.model import Platform
from executive.core.records import CameraFrame, SensorFrame, VelocityCommand, camera_ids
from executive.robotlink.canbase import BaseLinkConfig, CanBaseLink, ExecState
from executive.robotlink.config import RobotConfig
from executive.robotlink.detections import DetectionSubscriber
from executive.robotlink.nmea import GeoReference, NmeaClient
from executive.robotlink.scip import ScipClient

Clock = Callable[[], float]


TIMING_WINDOW = 200_000
"""Ticks of latency samples kept (an hour at 50 Hz)."""
NMEA_BAD_LIMIT = 3
NMEA_BAD_WINDOW = 1.0


def _percentiles(samples: deque[float]) -> dict[str, float | int | None]:
    if not samples:
        return {"count": 0, "p50": None, "p99": None, "max": None}
    ms = np.asarray(samples) * 1e3
    return {
        "count": len(ms),
        "p50": round(float(np.percentile(ms, 50)), 3),
        "p99": round(float(np.percentile(ms, 99)), 3),
        "max": round(float(ms.max()), 3),
    }


class LinkError(Exception):
    """The robot's wires could not be opened; the message says which and why."""


class RobotLink:
    """The robot's wires composed into a :class:`RobotInterface` with link health."""

    def __init__(
        self,
        bus: can.BusABC,
        base: CanBaseLink,
        lasers: dict[str, ScipClient],
        gps: NmeaClient | None,
        detections: DetectionSubscriber | None,
        clock: Clock,
    ) -> None:
        self.bus = bus
        self.base = base
        self.lasers = lasers
        self.gps = gps
        self.detections = detections
        self.clock = clock
        self._reset_requested = False
        self._closed = False
        self._read_at = math.nan
        self._newest_scan = math.nan
        self.command_latency: deque[float] = deque(maxlen=TIMING_WINDOW)
        """Seconds from a tick's read to its command handed to the bus."""
        self.scan_to_command: deque[float] = deque(maxlen=TIMING_WINDOW)
        """Seconds from the arrival of the newest laser scan a tick used to its command."""
        self._nmea_errors: deque[tuple[float, int]] = deque()
        self._faults: tuple[str, ...] = ()

    @classmethod
    def open(
        cls,
        config: RobotConfig,
        platform: Platform,
        *,
        clock: Clock | None = None,
        can_log: Path | None = None,
    ) -> RobotLink:
        """Open every wire of ``config`` for a robot with ``platform``'s sensors; whatever
        was opened is closed again when a later wire cannot be (:class:`LinkError`)."""
        t0 = time.monotonic()
        clock = clock or (lambda: time.monotonic() - t0)
        with contextlib.ExitStack() as opened:
            try:
                bus = can.Bus(**config.can.bus_kwargs())
                opened.callback(bus.shutdown)
                base = CanBaseLink(
                    bus,
                    BaseLinkConfig.from_indices(
                        config.ptus,
                        watchdog=config.can.watchdog,
                        base_timeout=config.can.base_timeout,
                    ),
                    clock=clock,
                )
                opened.callback(base.close)
                logger = None
                if can_log is not None:  # both directions, on the link's own bus
                    logger = can.Logger(str(can_log))
                    opened.callback(logger.stop)
                    base.add_listener(logger)
            except (can.CanError, OSError, ValueError, ImportError) as exc:
                raise LinkError(f"CAN {config.can.interface}:{config.can.channel}: {exc}") from exc
            lasers = {}
            for laser in config.lasers:
                lasers[laser.id] = ScipClient(laser.host, laser.port, clock=clock, name=laser.id)
                opened.callback(lasers[laser.id].close)
            gps = None
            if config.gps is not None:
                geo = GeoReference(
                    config.gps.latitude_deg, config.gps.longitude_deg, config.gps.x_axis_bearing_deg
                )
                gps = NmeaClient(config.gps.url, geo, clock, baudrate=config.gps.baud)
                opened.callback(gps.close)
            detections = None
            if config.detections is not None:
                cameras = [cam for unit in platform.cameras for cam in camera_ids(platform, unit)]
                try:
                    detections = DetectionSubscriber(config.detections, cameras, clock)
                except Exception as exc:  # zmq.ZMQError, a malformed endpoint
                    raise LinkError(f"detections {config.detections}: {exc}") from exc
            opened.pop_all()  # everything is open: the link owns it now
        return cls(bus, base, lasers, gps, detections, clock)

    def wait_ready(
        self,
        timeout: float = 10.0,
        period: float = 0.02,
        should_stop: Callable[[], bool] = lambda: False,
    ) -> bool:
        """Bring the base up: send stop commands with our heartbeat (state IDLE, ENABLE 0)
        until the base answers with its own heartbeat and no reason to distrust the link
        remains (a base braking on its watchdog releases once it sees our heartbeat; a
        pending operator's reset goes out too). False when ``should_stop`` (a signal)
        ended the wait; raises :class:`LinkError` naming what is still wrong after
        ``timeout`` seconds."""
        deadline = time.monotonic() + timeout
        while not should_stop():
            self._send_pending_reset()
            self.base.send(VelocityCommand.stop(), ExecState.IDLE)
            faults = self.link_faults()
            if not faults and self.base.snapshot().heartbeat_at is not None:
                return True
            if time.monotonic() >= deadline:
                raise LinkError(
                    f"the base is not ready after {timeout:g} s: "
                    + ("; ".join(faults) or "no base heartbeat")
                )
            time.sleep(period)
        return False

    # -- RobotInterface ---------------------------------------------------------------------------
    def read(self) -> SensorFrame:
        now = self.clock()
        self._read_at = now
        snapshot = self.base.snapshot()
        scans = {lid: scan for lid, client in self.lasers.items() if (scan := client.latest())}
        self._newest_scan = max((scan.stamp for scan in scans.values()), default=math.nan)
        cameras: dict[str, CameraFrame] = (
            self.detections.latest() if self.detections is not None else {}
        )
        frame = SensorFrame(
            stamp=now,
            scans=MappingProxyType(scans),
            cameras=MappingProxyType(cameras),
            gps=self.gps.latest() if self.gps is not None else None,
        )
        return snapshot.fill(frame)

    def send(self, command: VelocityCommand) -> None:
        """One control cycle on the bus; raises :class:`LinkError` when its frames did not
        all go out (the runtime then reports the stop as not confirmed)."""
        self._send_pending_reset()
        if not self.base.send(command, ExecState.RUNNING):
            raise LinkError("the control cycle's frames did not all go out on the CAN bus")
        sent = self.clock()
        if math.isfinite(self._read_at):
            self.command_latency.append(sent - self._read_at)
        if math.isfinite(self._newest_scan):
            self.scan_to_command.append(sent - self._newest_scan)

    # -- health -----------------------------------------------------------------------------------
    def link_faults(self) -> tuple[str, ...]:
        self._faults = (*self.base.health(), *self._nmea_faults())
        return self._faults

    def _nmea_faults(self) -> tuple[str, ...]:
        """A GPS stream that keeps failing its checksums (a wiring or baud-rate fault, not
        one flipped bit: :data:`NMEA_BAD_LIMIT` bad sentences within
        :data:`NMEA_BAD_WINDOW` seconds) cannot be trusted; one bad sentence is dropped
        and counted."""
        if self.gps is None:
            return ()
        now = self.clock()
        bad = self.gps.counts().bad_checksum
        window = self._nmea_errors
        window.append((now, bad))
        while window and now - window[0][0] > NMEA_BAD_WINDOW:
            window.popleft()
        recent = bad - window[0][1]
        if recent >= NMEA_BAD_LIMIT:
            return (f"GPS: {recent} bad NMEA checksums within {NMEA_BAD_WINDOW:g} s",)
        return ()

    def _send_pending_reset(self) -> None:
        if self._reset_requested:
            self._reset_requested = False
            self.base.send_reset()

    def request_reset(self) -> None:
        """Send the base a BASE_RESET with the next command (the operator's reset of a
        latched bumper; the base refuses it while a bumper is still pressed)."""
        self._reset_requested = True

    def status(self) -> dict[str, object]:
        """What the operator's status request shows about the wires."""
        snapshot = self.base.snapshot()
        return {
            "base_state": snapshot.base_state.name.lower() if snapshot.base_state else None,
            "battery_percent": snapshot.battery_percent,
            "link_faults": list(self._faults),  # as the last tick judged them (read-only)
            "base_holds": self.base.holds(),
            "lasers": {lid: client.health() for lid, client in self.lasers.items()},
            "gps": self.gps.status() if self.gps is not None else [],
        }

    def statistics(self) -> dict[str, object]:
        """Counters and latencies of every wire, for the run's metrics.json."""
        stats = self.base.stats()
        latency = stats.latency

        def ms(x: float) -> float | None:
            return round(x * 1e3, 3) if math.isfinite(x) else None

        out: dict[str, object] = {
            "command_latency_ms": _percentiles(self.command_latency),
            "scan_to_command_ms": _percentiles(self.scan_to_command),
            "can": {
                "frames": _plain(stats.frames),
                "error_frames": stats.error_frames,
                "watchdog_trips": self.base.watchdog_trips,
                "send_errors": stats.send_errors,
                "refused_commands": stats.refused_commands,
                "receive_latency_ms": {
                    "count": latency.count,
                    "p50": ms(latency.p50),
                    "p99": ms(latency.p99),
                    "max": ms(latency.max),
                },
            },
            "lasers": {lid: _plain(client.stats()) for lid, client in self.lasers.items()},
        }
        if self.gps is not None:
            out["gps"] = _plain(self.gps.counts())
        if self.detections is not None:
            out["detections"] = _plain(self.detections.counts())
        return out

    def close(self) -> None:
        """Close every wire (idempotent), the base last but for its bus: a final stop with
        ENABLE 0 goes out, then our heartbeat stops and the base's watchdog holds it."""
        if self._closed:
            return
        self._closed = True
        with contextlib.ExitStack() as closing:  # each closed even if another one raises
            closing.callback(self.bus.shutdown)
            closing.callback(self.base.close)  # stops the notifier and the CAN log with it
            for client in (*self.lasers.values(), self.gps, self.detections):
                if client is not None:
                    closing.callback(client.close)
            with contextlib.suppress(Exception):  # the link may be what failed
                self.base.send(VelocityCommand.stop(), ExecState.IDLE)


def _plain(value: object) -> object:
    """A statistics record as JSON-able data."""
    import dataclasses

    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, tuple | list):
        return [_plain(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value
