"""The robot file: which wire carries what (schemas/robot.xsd, docs/robot.md).

One file configures both ends of every wire: ``walkaround run`` (the executive on the
robot) and ``walkaround sim-robot`` (the hardware-in-the-loop simulator that serves the
same wires). It is loaded like every other walkaround file: hardened parser, XSD with
physical ranges, then semantic checks, every problem at ``file:line:column``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from lxml import etree

from executive.core.model import Platform
from executive.core.problems import InvalidInputError, Problem, ProblemSink
from executive.core.resources import schema_path
from executive.core.xmlreader import ElementReader, display_path, open_validated

ROBOT_NS = "urn:walkaround:robot:1"


@dataclass(frozen=True, slots=True)
class CanConfig:
    """The drive base's bus: a python-can ``interface`` and ``channel`` (``port`` for
    udp_multicast), the base's watchdog on the executive's heartbeat and the executive's
    timeout on the base's heartbeat (s)."""

    interface: str
    channel: str
    port: int | None = None
    bitrate: int = 500_000
    watchdog: float = 0.1
    base_timeout: float = 0.1

    def bus_kwargs(self) -> dict[str, object]:
        """Keyword arguments of ``can.Bus`` for this configuration."""
        kwargs: dict[str, object] = {"interface": self.interface, "channel": self.channel}
        if self.interface == "udp_multicast":
            # hop limit 0: the frames never leave this machine (hardware in the loop)
            kwargs["hop_limit"] = 0
            if self.port is not None:
                kwargs["port"] = self.port
        elif self.interface == "virtual":
            kwargs["receive_own_messages"] = False
        else:
            kwargs["bitrate"] = self.bitrate
        return kwargs


@dataclass(frozen=True, slots=True)
class LaserConfig:
    id: str
    host: str
    port: int


@dataclass(frozen=True, slots=True)
class GpsConfig:
    """The NMEA stream (a pyserial URL or device) and where the airport frame A lies."""

    url: str
    latitude_deg: float
    longitude_deg: float
    x_axis_bearing_deg: float = 90.0
    baud: int = 38400


@dataclass(frozen=True, slots=True)
class OperatorConfig:
    host: str = "127.0.0.1"
    port: int = 0


@dataclass(frozen=True, slots=True)
class RobotConfig:
    id: str
    can: CanConfig
    ptus: dict[str, int]
    """Pan-tilt unit (platform camera unit id) -> its index in PTU_CMD / PTU_STATE."""
    lasers: tuple[LaserConfig, ...]
    gps: GpsConfig | None = None
    detections: str | None = None
    operator: OperatorConfig = OperatorConfig()
    source: str = ""

    def ptu_order(self) -> tuple[str, ...]:
        """The pan-tilt units by CAN index (the index of a unit absent here is unused)."""
        return tuple(unit for unit, _ in sorted(self.ptus.items(), key=lambda kv: kv[1]))

    def with_ports(self, **ports: int) -> RobotConfig:
        """A copy with laser ports replaced by id (tests pick free ports)."""
        lasers = tuple(
            dataclasses.replace(laser, port=ports.get(laser.id, laser.port))
            for laser in self.lasers
        )
        return dataclasses.replace(self, lasers=lasers)

    def problems_with(self, platform: Platform) -> list[str]:
        """What the mission's platform needs that this robot file does not wire."""
        missing = [
            f"laser '{lid}' of the platform has no <laser> in the robot file"
            for lid in platform.lasers
            if lid not in {laser.id for laser in self.lasers}
        ]
        missing += [
            f"camera unit '{unit}' of the platform has no <ptu> in the robot file"
            for unit in platform.cameras
            if unit not in self.ptus
        ]
        return missing


def load_robot(path: Path | str) -> RobotConfig:
    """Load and check a robot file; raise InvalidInputError with every problem."""
    path = Path(path)
    sink = ProblemSink(display_path(path))
    doc = open_validated(path, "robot", ROBOT_NS, schema_path("robot"), sink)
    config = _build(ElementReader(doc, sink), path) if doc is not None else None
    sink.raise_if_any()
    assert config is not None
    return config


def check_robot(path: Path | str) -> list[Problem]:
    """Every problem of a robot file (empty when valid); never raises."""
    try:
        load_robot(path)
    except InvalidInputError as exc:
        return list(exc.problems)
    return []


def _integer(r: ElementReader, el: etree._Element, name: str, default: int | None) -> int | None:
    return default if el.get(name) is None else r.integer(el, name)


def _build(r: ElementReader, path: Path) -> RobotConfig:
    root = r.doc.root
    can_el = r.child(root, "can")
    assert can_el is not None  # the XSD requires it
    can = CanConfig(
        interface=r.str_(can_el, "interface"),
        channel=r.str_(can_el, "channel"),
        port=_integer(r, can_el, "port", None),
        bitrate=_integer(r, can_el, "bitrate", 500_000) or 500_000,
        watchdog=r.num(can_el, "watchdog-ms", 100.0) / 1000.0,
        base_timeout=r.num(can_el, "base-timeout-ms", 100.0) / 1000.0,
    )
    ptu_els = r.children(root, "ptu")
    r.unique(ptu_els, "pan-tilt unit", attribute="unit")
    r.unique(ptu_els, "pan-tilt index", attribute="index")
    laser_els = r.children(root, "laser")
    r.unique(laser_els, "laser")
    lasers = tuple(
        LaserConfig(r.str_(el, "id"), r.str_(el, "host"), r.integer(el, "port")) for el in laser_els
    )
    for el, laser in zip(laser_els, lasers, strict=True):
        if laser.port == 0:
            r.problem(el, "port", f"laser '{laser.id}': port 0 names no device", "port")
    gps_el = r.child(root, "gps")
    gps = None
    if gps_el is not None:
        gps = GpsConfig(
            url=r.str_(gps_el, "url"),
            latitude_deg=r.num(gps_el, "latitude-deg"),
            longitude_deg=r.num(gps_el, "longitude-deg"),
            x_axis_bearing_deg=r.num(gps_el, "x-axis-bearing-deg", 90.0),
            baud=_integer(r, gps_el, "baud", 38400) or 38400,
        )
    det_el = r.child(root, "detections")
    op_el = r.child(root, "operator")
    operator = OperatorConfig()
    if op_el is not None:
        operator = OperatorConfig(
            host=r.str_(op_el, "host") or "127.0.0.1",
            port=_integer(r, op_el, "port", 0) or 0,
        )
    return RobotConfig(
        id=r.str_(root, "id"),
        can=can,
        ptus={r.str_(el, "unit"): r.integer(el, "index") for el in ptu_els},
        lasers=lasers,
        gps=gps,
        detections=r.str_(det_el, "endpoint") if det_el is not None else None,
        operator=operator,
        source=str(path),
    )


def describe(config: RobotConfig) -> str:
    """One line for ``walkaround validate``."""
    wires: Sequence[str] = [
        f"CAN {config.can.interface}:{config.can.channel}",
        f"{len(config.lasers)} lasers",
        *(["GPS"] if config.gps else []),
        *(["detections"] if config.detections else []),
    ]
    return f"robot '{config.id}': " + ", ".join(wires)
