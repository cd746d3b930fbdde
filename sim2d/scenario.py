"""Scenarios: how sim2d stages a mission (docs/scenario-format.md).

A :class:`Scenario` holds the validated mission plus the true parking offset, the robot's
start, obstacles and their motions, noise and slip levels, GPS conditions, faults on a
timeline and the seed. :func:`load_scenario` reads one with the same hardened front end
as missions and reports every problem with ``file:line:column``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path

import numpy as np
from lxml import etree
from shapely.geometry import Point
from shapely.geometry.base import BaseGeometry

from executive.core.frames import AircraftPlacement, Pose2
from executive.core.geometry import to_shapely
from executive.core.loader import load_mission
from executive.core.model import Mission, Polygon
from executive.core.problems import Problem, ProblemSink
from executive.core.xmlreader import (
    ElementReader,
    library_root_of,
    load_document,
    load_reference,
    local_name,
    problems_of,
)
from executive.core.xmlsafe import XmlDocument
from sim2d.cameras import camera_rigs
from sim2d.ceiling import CeilingSpec

SCENARIO_NS = "urn:walkaround:scenario:1"


class ObstacleKind(StrEnum):
    VEHICLE = "vehicle"
    CONE = "cone"
    EQUIPMENT = "equipment"
    PERSON = "person"
    TROLLEY = "trolley"
    OTHER = "other"


class FaultKind(StrEnum):
    LASER_DROPOUT = "laser-dropout"
    CAMERA_FREEZE = "camera-freeze"
    GPS_LOSS = "gps-loss"
    SLIP_BURST = "slip-burst"
    BUMPER_HIT = "bumper-hit"
    WHEEL_FREEZE = "wheel-freeze"
    IMU_FREEZE = "imu-freeze"
    PTU_FREEZE = "ptu-freeze"


@dataclass(frozen=True, slots=True)
class NoiseLevels:
    """1-sigma noise: laser range (m), pixels, camera dropout probability, wheel speed
    (m/s), IMU yaw-rate noise and bias (rad/s), GPS (m)."""

    laser_range: float = 0.01
    pixel: float = 0.5
    camera_dropout: float = 0.02
    wheel: float = 0.01
    imu_rate: float = 0.002
    imu_bias: float = 0.002
    gps: float = 0.03


@dataclass(frozen=True, slots=True)
class SlipLevels:
    """Skid-steer slip: fraction of wheel speed lost straight ahead, fraction of the
    wheels' yaw rate lost in turns, and the lateral slip gain (m/s per (m/s * rad/s))."""

    longitudinal: float = 0.02
    turn: float = 0.2
    lateral: float = 0.05

    def scaled(self, factor: float) -> SlipLevels:
        return SlipLevels(
            min(self.longitudinal * factor, 0.9),
            min(self.turn * factor, 0.9),
            self.lateral * factor,
        )


@dataclass(frozen=True, slots=True)
class GpsConditions:
    denied: bool = False
    rate_hz: float = 5.0
    shadow_margin: float = 1.0


@dataclass(frozen=True, slots=True)
class Body:
    """An obstacle's shape: a disc of ``radius``, or a ``length`` x ``width`` box."""

    radius: float | None = None
    length: float = 0.0
    width: float = 0.0

    @property
    def is_circle(self) -> bool:
        return self.radius is not None

    @property
    def bounding_radius(self) -> float:
        if self.radius is not None:
            return self.radius
        return math.hypot(self.length, self.width) / 2.0

    def polygon(self, pose: Pose2) -> Polygon:
        """The box's corners at ``pose`` (counter-clockwise)."""
        hl, hw = self.length / 2.0, self.width / 2.0
        corners = pose.apply([(hl, hw), (-hl, hw), (-hl, -hw), (hl, -hw)])
        return Polygon("", tuple((float(x), float(y)) for x, y in corners))


@dataclass(frozen=True, slots=True)
class StaticObstacle:
    id: str
    kind: ObstacleKind
    pose: Pose2
    body: Body
    height: float


@dataclass(frozen=True, slots=True)
class PathMover:
    """Moves along ``waypoints`` at ``speed`` from ``start_time``, or once the robot is
    within ``trigger_radius`` of the first waypoint; ``loop`` goes round for ever."""

    id: str
    kind: ObstacleKind
    body: Body
    height: float
    speed: float
    waypoints: tuple[tuple[float, float], ...]
    start_time: float = 0.0
    trigger_radius: float | None = None
    loop: bool = False


@dataclass(frozen=True, slots=True)
class LoiteringGroup:
    """``count`` people walking at random inside a circle."""

    id: str
    center: tuple[float, float]
    radius: float
    count: int
    speed: float
    person_radius: float
    height: float


@dataclass(frozen=True, slots=True)
class Chaser:
    """The adversarial trolley: steers towards the robot at ``speed`` once triggered."""

    id: str
    kind: ObstacleKind
    start: tuple[float, float]
    body: Body
    height: float
    speed: float
    trigger_radius: float | None = None
    pursuit: float | None = None
    """Seconds of chase once triggered; then back to ``start`` for good (None: forever)."""


Obstacle = StaticObstacle | PathMover | LoiteringGroup | Chaser


@dataclass(frozen=True, slots=True)
class Fault:
    """A fault active during [at, at + duration). ``target`` names the laser, camera or
    bumper; ``factor`` multiplies the slip levels of a slip burst."""

    kind: FaultKind
    at: float
    duration: float
    target: str | None = None
    factor: float = 1.0

    def active(self, t: float) -> bool:
        return self.at <= t < self.at + self.duration


@dataclass(frozen=True, slots=True)
class LampSwitch:
    """Lamps switched ``off`` (or on) at ``at`` (s): those of ``ids``, or a ``fraction``
    of the candidates (the lamps on, to switch off; those off, to switch on)."""

    at: float
    off: bool
    ids: tuple[int, ...] | None = None
    fraction: float | None = None


@dataclass(frozen=True, slots=True)
class ScenarioCeiling:
    """A hangar ceiling over the scene (issue 17): the pattern ``spec``
    (:class:`sim2d.ceiling.CeilingSpec`), the lamp ``switches`` and the imaging of the
    upward camera's images (:func:`sim2d.ceiling.render`). Which lamps a ``fraction``
    switches depends on the scenario's seed: :meth:`timeline`."""

    spec: CeilingSpec
    switches: tuple[LampSwitch, ...] = ()
    exposure: float = 1.0
    noise_grey: float = 2.0
    blur_px: float = 0.0
    vignetting: float = 0.0

    def timeline(self, seed: int) -> tuple[tuple[float, frozenset[int]], ...]:
        """:func:`lamp_timeline` of the switches for a scenario seeded with ``seed``."""
        return lamp_timeline(self.switches, len(self.spec.lamp_centres()), seed)

    def lamps_off(self, t: float, seed: int) -> frozenset[int]:
        """The lamps off at time ``t`` (s) for a scenario seeded with ``seed``."""
        return lamps_off_at(self.timeline(seed), t)


def lamps_off_at(timeline: Iterable[tuple[float, frozenset[int]]], t: float) -> frozenset[int]:
    """The lamps off at time ``t`` (s) on a :func:`lamp_timeline`."""
    off: frozenset[int] = frozenset()
    for at, lamps in timeline:
        if at > t:
            break
        off = lamps
    return off


LAMP_SEED_KEY = 0x17CE
"""Mixed with the scenario's seed and a switch's index for its random fraction of lamps."""


def lamp_timeline(
    switches: Iterable[LampSwitch], lamp_count: int, seed: int
) -> tuple[tuple[float, frozenset[int]], ...]:
    """The lamps off from each switch's time on, switches applied in time order (ties in
    the given order). A fraction switches ``round(fraction * candidates)`` lamps drawn
    without replacement by a generator seeded with (``seed``, :data:`LAMP_SEED_KEY`, the
    switch's index in ``switches``), so a scenario file always gives the same lamps.
    Ids at or above ``lamp_count`` raise ValueError."""
    ordered = sorted(enumerate(switches), key=lambda item: item[1].at)
    off: set[int] = set()
    timeline: list[tuple[float, frozenset[int]]] = []
    for index, switch in ordered:
        if switch.ids is not None:
            bad = [i for i in switch.ids if not 0 <= i < lamp_count]
            if bad:
                raise ValueError(f"lamp id {bad[0]} does not exist (lamps 0 to {lamp_count - 1})")
            chosen = set(switch.ids)
        else:
            fraction = switch.fraction or 0.0
            candidates = sorted(set(range(lamp_count)) - off if switch.off else off)
            rng = np.random.default_rng([seed, LAMP_SEED_KEY, index])
            count = round(fraction * len(candidates))
            chosen = {int(i) for i in rng.choice(candidates, size=count, replace=False)}
        off = off | chosen if switch.off else off - chosen
        timeline.append((switch.at, frozenset(off)))
    return tuple(timeline)


@dataclass(frozen=True, slots=True)
class Scenario:
    id: str
    mission: Mission
    seed: int
    duration: float
    parking_offset: Pose2
    start: Pose2
    physics_rate: float
    noise: NoiseLevels
    slip: SlipLevels
    gps: GpsConditions
    obstacles: tuple[Obstacle, ...] = ()
    faults: tuple[Fault, ...] = ()
    description: str = ""
    source: str = ""
    ceiling: ScenarioCeiling | None = None

    def true_placement(self) -> AircraftPlacement:
        """Where the aircraft really stands: the mission's nominal pose plus the offset."""
        nominal = self.mission.nominal_placement()
        off = self.parking_offset
        return AircraftPlacement(
            nominal.x + off.x,
            nominal.y + off.y,
            nominal.heading + off.theta,
            nominal.origin_height,
        )


def default_library_root(scenario_path: Path) -> Path:
    """``<library>/<type>/scenarios/<name>.xml`` -> ``<library>``."""
    return library_root_of(scenario_path, 3)


def load_scenario(path: Path | str, library_root: Path | str | None = None) -> Scenario:
    """Load and check a scenario and its mission; raise InvalidInputError on any problem."""
    return load_document(path, "scenario", SCENARIO_NS, _build, library_root, 3)


def check_scenario(path: Path | str, library_root: Path | str | None = None) -> list[Problem]:
    """Every problem of a scenario file (empty when valid); never raises."""
    return problems_of(lambda: load_scenario(path, library_root))


# -- building ---------------------------------------------------------------------------------
def _body(r: ElementReader, el: etree._Element, label: str) -> Body:
    radius = r.opt_num(el, "radius")
    length, width = r.opt_num(el, "length"), r.opt_num(el, "width")
    if radius is not None and length is None and width is None:
        return Body(radius=radius)
    if radius is None and length is not None and width is not None:
        return Body(length=length, width=width)
    r.problem(
        el,
        "obstacle-shape",
        f"{label}: give either 'radius' (a disc) or both 'length' and 'width' (a box)",
    )
    return Body(radius=0.3)


def _obstacle(r: ElementReader, el: etree._Element) -> Obstacle:
    oid = r.str_(el, "id")
    tag = local_name(el)
    height = r.num(el, "height")
    if tag == "box":
        body = Body(length=r.num(el, "length"), width=r.num(el, "width"))
        return StaticObstacle(oid, ObstacleKind(r.str_(el, "kind")), r.pose(el), body, height)
    if tag == "circle":
        body = Body(radius=r.num(el, "radius"))
        pose = Pose2(r.num(el, "x"), r.num(el, "y"), 0.0)
        return StaticObstacle(oid, ObstacleKind(r.str_(el, "kind")), pose, body, height)
    if tag == "path":
        return PathMover(
            id=oid,
            kind=ObstacleKind(r.str_(el, "kind")),
            body=_body(r, el, f"path '{oid}'"),
            height=height,
            speed=r.num(el, "speed"),
            waypoints=tuple((r.num(w, "x"), r.num(w, "y")) for w in r.children(el, "waypoint")),
            start_time=r.num(el, "start-time", 0.0),
            trigger_radius=r.opt_num(el, "trigger-radius"),
            loop=r.str_(el, "loop") in ("true", "1"),
        )
    if tag == "group":
        return LoiteringGroup(
            id=oid,
            center=(r.num(el, "x"), r.num(el, "y")),
            radius=r.num(el, "radius"),
            count=int(r.num(el, "count")),
            speed=r.num(el, "speed"),
            person_radius=r.num(el, "person-radius"),
            height=height,
        )
    return Chaser(
        id=oid,
        kind=ObstacleKind(r.str_(el, "kind")),
        start=(r.num(el, "x"), r.num(el, "y")),
        body=_body(r, el, f"chaser '{oid}'"),
        height=height,
        speed=r.num(el, "speed"),
        trigger_radius=r.opt_num(el, "trigger-radius"),
        pursuit=r.opt_num(el, "pursuit"),
    )


def _fault(r: ElementReader, el: etree._Element) -> Fault:
    kind = FaultKind(local_name(el))
    target = el.get("laser") or el.get("camera") or el.get("bumper")
    return Fault(
        kind=kind,
        at=r.num(el, "at"),
        duration=r.num(el, "duration"),
        target=target.strip() if target else None,
        factor=r.num(el, "factor", 1.0),
    )


def _attrs(r: ElementReader, el: etree._Element | None, names: Iterable[str]) -> dict[str, float]:
    if el is None:
        return {}
    return {n.replace("-", "_"): r.num(el, n) for n in names if el.get(n) is not None}


def _build(doc: XmlDocument, sink: ProblemSink, path: Path, root_dir: Path) -> Scenario | None:
    r = ElementReader(doc, sink)
    root = doc.root
    mission, mission_problems = load_reference(
        r, "mission", path, root_dir, lambda target: load_mission(target, root_dir), "scenario"
    )
    sink.extend(mission_problems)

    offset_el = r.child(root, "parking-offset")
    offset = (
        Pose2(r.num(offset_el, "dx"), r.num(offset_el, "dy"), r.angle(offset_el, "dheading-deg"))
        if offset_el is not None
        else Pose2(0.0, 0.0, 0.0)
    )
    start_el = r.child(root, "start")
    physics_el = r.child(root, "physics")
    noise = NoiseLevels(
        **_attrs(
            r,
            r.child(root, "noise"),
            ("laser-range", "pixel", "camera-dropout", "wheel", "imu-rate", "imu-bias", "gps"),
        )
    )
    slip = SlipLevels(**_attrs(r, r.child(root, "slip"), ("longitudinal", "turn", "lateral")))
    gps_el = r.child(root, "gps")
    gps = GpsConditions(
        denied=gps_el is not None and r.str_(gps_el, "mode") == "denied",
        **_attrs(r, gps_el, ("rate-hz", "shadow-margin")),
    )

    ceiling_el = r.child(root, "ceiling")
    ceiling = _ceiling(r, ceiling_el) if ceiling_el is not None else None
    obstacle_el = r.elements(r.child(root, "obstacles"))
    fault_el = r.elements(r.child(root, "faults"))
    r.unique(obstacle_el, "obstacle")
    obstacles = tuple(_obstacle(r, e) for e in obstacle_el)
    faults = tuple(_fault(r, e) for e in fault_el)
    if mission is None:
        return None

    start = r.pose(start_el) if start_el is not None else mission.airport.station
    scenario = Scenario(
        id=r.str_(root, "id"),
        mission=mission,
        seed=r.integer(root, "seed"),
        duration=r.num(root, "duration", 3600.0),
        parking_offset=offset,
        start=start,
        physics_rate=r.num(physics_el, "rate-hz", 100.0) if physics_el is not None else 100.0,
        noise=noise,
        slip=slip,
        gps=gps,
        obstacles=obstacles,
        faults=faults,
        description=r.text(r.child(root, "description")),
        source=sink.file,
        ceiling=ceiling,
    )
    _check_references(r, scenario, fault_el)
    _check_ceiling_camera(r, scenario, ceiling_el)
    _check_overlaps(r, scenario, obstacle_el)
    return None if sink else scenario


_CEILING_ATTRS = {
    # attribute -> CeilingSpec field (pairs of attributes make the tuple fields)
    "x-min": "x_min",
    "y-min": "y_min",
    "x-max": "x_max",
    "y-max": "y_max",
    "height": "height",
    "texel": "texel",
    "lamp-radius": "lamp_radius",
    "beam-spacing": "beam_spacing",
    "beam-offset": "beam_offset",
    "beam-width": "beam_width",
    "purlin-spacing": "purlin_spacing",
    "purlin-width": "purlin_width",
    "mark-density": "mark_density",
    "tile-size": "tile_size",
}
_CEILING_PAIRS = {
    "lamp_spacing": ("lamp-spacing-x", "lamp-spacing-y"),
    "lamp_offset": ("lamp-offset-x", "lamp-offset-y"),
    "panel_size": ("panel-x", "panel-y"),
}


def _ceiling(r: ElementReader, el: etree._Element) -> ScenarioCeiling | None:
    """The ``<ceiling>`` element; None (with the problems recorded) when it is not one."""
    defaults = CeilingSpec()
    values: dict[str, object] = {
        field: r.num(el, attr) for attr, field in _CEILING_ATTRS.items() if el.get(attr)
    }
    for field, (ax, ay) in _CEILING_PAIRS.items():
        dx, dy = getattr(defaults, field)
        values[field] = (r.num(el, ax, dx), r.num(el, ay, dy))
    if el.get("seed") is not None:
        values["seed"] = r.integer(el, "seed")
    if el.get("repeated-tiles") is not None:
        values["repeated_tiles"] = r.integer(el, "repeated-tiles")
    try:
        spec = CeilingSpec(**values)  # type: ignore[arg-type]
    except ValueError as exc:
        r.problem(el, "ceiling", str(exc))
        return None
    lamp_count = len(spec.lamp_centres())
    switches: list[LampSwitch] = []
    usable = True
    for se in r.elements(el):
        ids_text, fraction = se.get("ids"), r.opt_num(se, "fraction")
        if (ids_text is None) == (fraction is None):
            r.problem(se, "lamp-switch", "give either 'ids' or 'fraction' (exactly one)")
            usable = False
            continue
        ids = None if ids_text is None else tuple(int(i) for i in ids_text.split())
        bad = [i for i in ids or () if i >= lamp_count]
        if bad:
            r.problem(
                se,
                "unknown-reference",
                f"lamp {bad[0]} does not exist: this ceiling has {lamp_count} lamps "
                f"(ids 0 to {lamp_count - 1})",
                "ids",
            )
            usable = False
            continue
        switches.append(LampSwitch(r.num(se, "at"), local_name(se) == "lamps-off", ids, fraction))
    if not usable:
        return None
    return ScenarioCeiling(
        spec=spec,
        switches=tuple(switches),
        exposure=r.num(el, "exposure", 1.0),
        noise_grey=r.num(el, "noise-grey", 2.0),
        blur_px=r.num(el, "blur-px", 0.0),
        vignetting=r.num(el, "vignetting", 0.0),
    )


def _check_ceiling_camera(
    r: ElementReader, scenario: Scenario, ceiling_el: etree._Element | None
) -> None:
    """The ceiling must be above the platform's ceiling camera."""
    camera = scenario.mission.platform.ceiling_camera
    ceiling = scenario.ceiling
    if ceiling_el is None or ceiling is None or camera is None:
        return
    if not ceiling.spec.height > camera.mount_z + 0.5:
        r.problem(
            ceiling_el,
            "ceiling-height",
            f"the ceiling ({ceiling.spec.height:g} m) must be more than 0.5 m above the "
            f"platform's ceiling-camera ({camera.mount_z:g} m)",
            "height",
        )


def _check_references(r: ElementReader, scenario: Scenario, fault_el: list) -> None:
    lasers = scenario.mission.platform.lasers
    cameras = [rig.id for rig in camera_rigs(scenario.mission.platform.cameras)]
    for el, fault in zip(fault_el, scenario.faults, strict=True):
        if fault.kind is FaultKind.LASER_DROPOUT and fault.target not in lasers:
            known = ", ".join(lasers) or "none"
            r.problem(
                el,
                "unknown-reference",
                f"laser '{fault.target}' is not a platform laser (known: {known})",
                "laser",
            )
        if fault.kind is FaultKind.CAMERA_FREEZE and fault.target not in cameras:
            r.problem(
                el,
                "unknown-reference",
                f"camera '{fault.target}' is not a camera of the platform "
                f"(known: {', '.join(cameras)})",
                "camera",
            )
        units = scenario.mission.platform.cameras
        if fault.kind is FaultKind.PTU_FREEZE and fault.target not in units:
            r.problem(
                el,
                "unknown-reference",
                f"camera '{fault.target}' is not a camera unit of the platform "
                f"(known: {', '.join(units) or 'none'})",
                "camera",
            )


MAX_MOVING_AGENTS = 500
"""Moving obstacles a scenario may hold (paths, chasers and every person of every group):
each is simulated at the physics rate, so more would make a run crawl."""


def _initial_geometry(obstacle: Obstacle) -> BaseGeometry:
    """Where an obstacle is at the start of the run (a group: the circle it walks in)."""
    if isinstance(obstacle, LoiteringGroup):
        return Point(*obstacle.center).buffer(obstacle.radius + obstacle.person_radius)
    if isinstance(obstacle, StaticObstacle):
        pose, body = obstacle.pose, obstacle.body
    else:
        first = obstacle.waypoints[0] if isinstance(obstacle, PathMover) else obstacle.start
        heading = 0.0
        if isinstance(obstacle, PathMover) and len(obstacle.waypoints) > 1:
            (x0, y0), (x1, y1) = obstacle.waypoints[0], obstacle.waypoints[1]
            heading = math.atan2(y1 - y0, x1 - x0)
        pose, body = Pose2(first[0], first[1], heading), obstacle.body
    if body.radius is not None:
        return Point(pose.x, pose.y).buffer(body.radius)
    return to_shapely(body.polygon(pose))


def _check_overlaps(r: ElementReader, scenario: Scenario, obstacle_el: list) -> None:
    """Nothing may stand where the robot starts or charges, nor a static obstacle in the
    aircraft: the aircraft footprint at its *true* parking pose (nominal + offset) and every
    obstacle where it is at the start (a mover's first point, a group's circle) must
    leave the robot's start and the charging station clear (the robot turning on the spot
    there sweeps a disc of half its diagonal)."""
    placement = scenario.true_placement()
    footprint = []
    for shape in scenario.mission.aircraft.footprint:
        pts = placement.to_airport_xy(to_shapely(shape).exterior.coords)
        footprint.append((shape.id, to_shapely(Polygon(shape.id, tuple(map(tuple, pts))))))
    platform = scenario.mission.platform
    half_diag = platform.turning_radius
    body = Body(length=platform.length, width=platform.width)
    start, station = scenario.start, scenario.mission.airport.station
    poses = [("the robot's start", start)]
    if math.hypot(start.x - station.x, start.y - station.y) > 1e-6:
        poses.append(("the charging station", station))
    # obstacles: the disc the robot sweeps turning on the spot there (they may come
    # closer than the aircraft, whose clearance the mission checks); the aircraft: the
    # robot's own outline at the pose (a test may start it just beside a gear leg)
    spots = [(label, Point(pose.x, pose.y).buffer(half_diag)) for label, pose in poses]
    outlines = [(label, to_shapely(body.polygon(pose))) for label, pose in poses]
    offset_el = r.child(r.doc.root, "parking-offset")
    aircraft_el = offset_el if offset_el is not None else r.doc.root
    for shape_id, poly in footprint:
        for label, outline in outlines:
            if poly.intersects(outline):
                r.problem(
                    aircraft_el,
                    "aircraft-overlap",
                    f"the aircraft footprint '{shape_id}' (at the true parking pose, nominal "
                    f"+ parking offset) overlaps {label}: the robot would start inside it",
                )
    moving = 0
    for el, obstacle in zip(obstacle_el, scenario.obstacles, strict=True):
        if isinstance(obstacle, LoiteringGroup):
            moving += obstacle.count
        elif not isinstance(obstacle, StaticObstacle):
            moving += 1
        if isinstance(obstacle, PathMover) and not obstacle.waypoints:
            continue  # the XSD requires waypoints; nothing to place
        geom = _initial_geometry(obstacle)
        if isinstance(obstacle, StaticObstacle):
            for shape_id, poly in footprint:
                if geom.intersects(poly):
                    r.problem(
                        el,
                        "obstacle-overlap",
                        f"obstacle '{obstacle.id}' overlaps the aircraft footprint "
                        f"'{shape_id}' (at the true parking pose)",
                    )
        for label, disc in spots:
            if geom.intersects(disc):
                r.problem(el, "obstacle-overlap", f"obstacle '{obstacle.id}' overlaps {label}")
    if moving > MAX_MOVING_AGENTS:
        r.problem(
            r.child(r.doc.root, "obstacles"),
            "too-many-obstacles",
            f"{moving} moving obstacles (people in groups included); the limit is "
            f"{MAX_MOVING_AGENTS}",
        )


# -- writing ----------------------------------------------------------------------------------
def _num(value: float) -> str:
    """A number that reads back as the very same float."""
    return repr(float(value))


def _deg(angle: float) -> str:
    """Radians as degrees that read back (through ``math.radians``) as the same radians
    for every angle that was read from degrees with at most nine decimals."""
    return repr(round(math.degrees(angle), 9))


def _xml_attrs(**attrs: object) -> str:
    from xml.sax.saxutils import quoteattr

    parts = []
    for name, value in attrs.items():
        if value is None:
            continue
        text = value if isinstance(value, str) else _num(value)  # type: ignore[arg-type]
        parts.append(f"{name.rstrip('_').replace('_', '-')}={quoteattr(text)}")
    return " ".join(parts)


def _shape_attrs(body: Body) -> dict[str, object]:
    if body.radius is not None:
        return {"radius": body.radius}
    return {"length": body.length, "width": body.width}


def _obstacle_xml(obstacle: Obstacle) -> str:
    if isinstance(obstacle, StaticObstacle):
        if obstacle.body.radius is not None:
            attrs = _xml_attrs(
                id=obstacle.id,
                kind=str(obstacle.kind),
                x=obstacle.pose.x,
                y=obstacle.pose.y,
                radius=obstacle.body.radius,
                height=obstacle.height,
            )
            return f"<circle {attrs}/>"
        attrs = _xml_attrs(
            id=obstacle.id,
            kind=str(obstacle.kind),
            x=obstacle.pose.x,
            y=obstacle.pose.y,
            heading_deg=_deg(obstacle.pose.theta),
            length=obstacle.body.length,
            width=obstacle.body.width,
            height=obstacle.height,
        )
        return f"<box {attrs}/>"
    if isinstance(obstacle, PathMover):
        attrs = _xml_attrs(
            id=obstacle.id,
            kind=str(obstacle.kind),
            **_shape_attrs(obstacle.body),
            height=obstacle.height,
            speed=obstacle.speed,
            start_time=obstacle.start_time,
            trigger_radius=obstacle.trigger_radius,
            loop="true" if obstacle.loop else "false",
        )
        points = "".join(f"<waypoint {_xml_attrs(x=x, y=y)}/>" for x, y in obstacle.waypoints)
        return f"<path {attrs}>{points}</path>"
    if isinstance(obstacle, LoiteringGroup):
        attrs = _xml_attrs(
            id=obstacle.id,
            x=obstacle.center[0],
            y=obstacle.center[1],
            radius=obstacle.radius,
            count=str(obstacle.count),
            speed=obstacle.speed,
            person_radius=obstacle.person_radius,
            height=obstacle.height,
        )
        return f"<group {attrs}/>"
    attrs = _xml_attrs(
        id=obstacle.id,
        kind=str(obstacle.kind),
        x=obstacle.start[0],
        y=obstacle.start[1],
        **_shape_attrs(obstacle.body),
        height=obstacle.height,
        speed=obstacle.speed,
        trigger_radius=obstacle.trigger_radius,
        pursuit=obstacle.pursuit,
    )
    return f"<chaser {attrs}/>"


_FAULT_TARGET = {
    FaultKind.LASER_DROPOUT: "laser",
    FaultKind.CAMERA_FREEZE: "camera",
    FaultKind.PTU_FREEZE: "camera",
    FaultKind.BUMPER_HIT: "bumper",
}


def _fault_xml(fault: Fault) -> str:
    target = _FAULT_TARGET.get(fault.kind)
    attrs: dict[str, object] = {target: fault.target} if target else {}
    attrs |= {"at": fault.at, "duration": fault.duration}
    if fault.kind is FaultKind.SLIP_BURST:
        attrs["factor"] = fault.factor
    return f"<{fault.kind} {_xml_attrs(**attrs)}/>"


def _ceiling_xml(ceiling: ScenarioCeiling) -> list[str]:
    from xml.sax.saxutils import quoteattr

    spec = ceiling.spec
    attrs: dict[str, object] = {a: getattr(spec, f) for a, f in _CEILING_ATTRS.items()}
    for field, names in _CEILING_PAIRS.items():
        attrs |= dict(zip(names, getattr(spec, field), strict=True))
    attrs |= {
        "seed": str(spec.seed),
        "repeated-tiles": str(spec.repeated_tiles),
        "exposure": ceiling.exposure,
        "noise-grey": ceiling.noise_grey,
        "blur-px": ceiling.blur_px,
        "vignetting": ceiling.vignetting,
    }
    text = " ".join(
        f"{name}={quoteattr(value if isinstance(value, str) else _num(value))}"  # type: ignore[arg-type]
        for name, value in attrs.items()
    )
    lines = [f"  <ceiling {text}>"]
    for switch in ceiling.switches:
        which = "lamps-off" if switch.off else "lamps-on"
        ids = None if switch.ids is None else " ".join(str(i) for i in switch.ids)
        lines.append(
            f"    <{which} {_xml_attrs(at=switch.at, ids=ids, fraction=switch.fraction)}/>"
        )
    return [*lines, "  </ceiling>"]


def scenario_xml(scenario: Scenario, mission_ref: str) -> str:
    """The scenario as a scenario file whose ``mission`` attribute is ``mission_ref`` (a
    path relative to where the file will be written): every element :func:`load_scenario`
    reads, written out in full (defaults included), so that loading the text gives back
    ``scenario`` (its ``source`` aside)."""
    from xml.sax.saxutils import escape

    off, start, noise, slip, gps = (
        scenario.parking_offset,
        scenario.start,
        scenario.noise,
        scenario.slip,
        scenario.gps,
    )
    root = _xml_attrs(
        id=scenario.id, mission=mission_ref, seed=str(scenario.seed), duration=scenario.duration
    )
    lines = [
        '<?xml version="1.0" encoding="UTF-8"?>',
        f'<scenario xmlns="{SCENARIO_NS}" {root}>',
        f"  <description>{escape(scenario.description)}</description>",
        f"  <parking-offset {_xml_attrs(dx=off.x, dy=off.y, dheading_deg=_deg(off.theta))}/>",
        f"  <start {_xml_attrs(x=start.x, y=start.y, heading_deg=_deg(start.theta))}/>",
        f"  <physics {_xml_attrs(rate_hz=scenario.physics_rate)}/>",
        "  <noise "
        + _xml_attrs(
            laser_range=noise.laser_range,
            pixel=noise.pixel,
            camera_dropout=noise.camera_dropout,
            wheel=noise.wheel,
            imu_rate=noise.imu_rate,
            imu_bias=noise.imu_bias,
            gps=noise.gps,
        )
        + "/>",
        "  <slip "
        + _xml_attrs(longitudinal=slip.longitudinal, turn=slip.turn, lateral=slip.lateral)
        + "/>",
        "  <gps "
        + _xml_attrs(
            mode="denied" if gps.denied else "open",
            rate_hz=gps.rate_hz,
            shadow_margin=gps.shadow_margin,
        )
        + "/>",
        "  <obstacles>",
        *(f"    {_obstacle_xml(o)}" for o in scenario.obstacles),
        "  </obstacles>",
        "  <faults>",
        *(f"    {_fault_xml(f)}" for f in scenario.faults),
        "  </faults>",
        *(_ceiling_xml(scenario.ceiling) if scenario.ceiling is not None else ()),
        "</scenario>",
    ]
    return "\n".join(lines) + "\n"
