"""Strict loading of aircraft and mission XML into the mission model.

The pipeline for every file is: hardened parse (:mod:`executive.core.xmlsafe`) -> root
element and namespace -> XSD -> build with semantic checks. Every problem of every stage
that can run is collected, each at ``file:line:column``; if there is any, the loader
raises :class:`~executive.core.problems.InvalidInputError` and returns nothing.

>>> mission = load_mission(Path("missions/a320/preflight.xml"))      # doctest: +SKIP
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from pathlib import Path
from types import MappingProxyType

from lxml import etree

from executive.core import checks
from executive.core.frames import Pose2
from executive.core.model import (
    DEFAULT_GEOFENCE_MARGIN,
    Aircraft,
    Airport,
    CameraKind,
    CameraSpec,
    CeilingCameraSpec,
    Checkpoint,
    Circle,
    Dimensions,
    Feature,
    ForbiddenZone,
    Frame,
    InspectionItem,
    InspectionMethod,
    LaserSpec,
    Mission,
    Navigation,
    Platform,
    Point3,
    SafetyRadii,
    ServoMethod,
    Shape,
    TaughtRoute,
    TurnMode,
    Waypoint,
    ZoneKind,
)
from executive.core.mosaicfile import MosaicFormatError, read_mosaic
from executive.core.problems import InvalidInputError, Problem, ProblemSink, SourceLocation
from executive.core.taught_route import load_route
from executive.core.xmlreader import (
    ElementReader,
    display_path,
    library_root_of,
    load_document,
    load_reference,
)
from executive.core.xmlsafe import XmlDocument, parse_xml

AIRCRAFT_NS = "urn:walkaround:aircraft:1"
MISSION_NS = "urn:walkaround:mission:1"
TRACK_OF_WIDTH = 0.85
"""Wheel track as a fraction of the platform width when a mission does not give it."""

KNOWN_ROOTS = {
    "aircraft": AIRCRAFT_NS,
    "mission": MISSION_NS,
}


def root_name(path: Path) -> str | None:
    """The local name of the file's root element, without validating; None if unreadable."""
    doc = parse_xml(path, ProblemSink(path))
    return None if doc is None else etree.QName(doc.root).localname


def detect_kind(path: Path) -> str | None:
    """``aircraft`` or ``mission`` from the root element's name, without validating.

    The namespace is not looked at here: a ``<mission>`` in the wrong namespace is a
    mission with a mistake, reported by the mission loader.
    """
    name = root_name(path)
    return name if name in KNOWN_ROOTS else None


# -- aircraft ------------------------------------------------------------------------------------
def load_aircraft(path: Path | str) -> Aircraft:
    """Load and check an aircraft type file; raise :class:`InvalidInputError` on any problem."""
    return load_document(path, "aircraft", AIRCRAFT_NS, _build_aircraft, None, 0)


def _build_aircraft(
    doc: XmlDocument, sink: ProblemSink, path: Path, root_dir: Path
) -> Aircraft | None:
    r = ElementReader(doc, sink)
    root = doc.root
    origin_height = r.num(root, "origin-height")
    dim = r.child(root, "dimensions")
    assert dim is not None
    dimensions = Dimensions(
        r.num(dim, "length"), r.num(dim, "span"), r.num(dim, "height"), r.num(dim, "fuselage-width")
    )
    footprint_el = r.elements(r.child(root, "footprint"))
    outline_el = r.children(r.child(root, "outline"), "polygon")
    r.unique([*footprint_el, *outline_el], "shape")
    footprint = tuple(r.shape(e, r.str_(e, "id")) for e in footprint_el)
    _check_footprint_extent(r, r.child(root, "footprint"), footprint)
    outline = tuple(r.polygon(e, r.str_(e, "id")) for e in outline_el)

    feature_el = r.children(r.child(root, "features"), "feature")
    item_el = r.children(r.child(root, "items"), "item")
    r.unique(feature_el, "feature")
    r.unique(item_el, "item")

    features: dict[str, Feature] = {}
    for fe in feature_el:
        fid = r.str_(fe, "id")
        points = []
        for pe in r.children(fe, "point"):
            has_z, has_h = pe.get("z") is not None, pe.get("h") is not None
            if has_z == has_h:
                r.problem(
                    pe,
                    "point-height",
                    f"feature '{fid}': a point needs exactly one of 'z' (in F, down) or "
                    f"'h' (height above the ground)" + (", not both" if has_z else ""),
                )
                z = 0.0
            elif has_z:
                z = r.num(pe, "z")
            else:
                z = origin_height - r.num(pe, "h")
            points.append(Point3(r.num(pe, "x"), r.num(pe, "y"), z))
        normal_el = r.child(fe, "normal")
        normal = None
        if normal_el is not None:
            normal = Point3(r.num(normal_el, "x"), r.num(normal_el, "y"), r.num(normal_el, "z"))
            if math.hypot(normal.x, normal.y, normal.z) < 1e-9:
                r.problem(normal_el, "zero-normal", f"feature '{fid}': the normal is zero")
        features.setdefault(
            fid,
            Feature(
                id=fid,
                kind=r.str_(fe, "kind"),
                points=tuple(points),
                detection_range=r.num(fe, "detection-range"),
                servo=r.enum(fe, "servo", ServoMethod),
                normal=normal,
                where=r.where(fe),
            ),
        )

    items: dict[str, InspectionItem] = {}
    for ie in item_el:
        iid, feature = r.str_(ie, "id"), r.str_(ie, "feature")
        if feature not in features:
            r.problem(
                ie,
                "unknown-reference",
                f"item '{iid}' refers to feature '{feature}', which is not defined"
                + checks.suggest(feature, features),
                "feature",
            )
        items.setdefault(
            iid,
            InspectionItem(
                iid, feature, r.enum(ie, "method", InspectionMethod), r.text(ie), r.where(ie)
            ),
        )
    if sink:
        return None
    return Aircraft(
        type=r.str_(root, "type"),
        origin_height=origin_height,
        dimensions=dimensions,
        footprint=footprint,
        outline=outline,
        features=MappingProxyType(features),
        items=MappingProxyType(items),
        description=r.text(r.child(root, "description")),
        source=sink.file,
    )


MAX_FOOTPRINT_EXTENT = 80.0
"""Metres the footprint may span along x and along y. The largest airliners' gear and
engines span about 30 m x 50 m (A380); the localisation builds a distance field over the
footprint at 5 cm, so a larger one would need hundreds of megabytes."""


def _check_footprint_extent(
    r: ElementReader, element: etree._Element | None, footprint: tuple[Shape, ...]
) -> None:
    xs: list[float] = []
    ys: list[float] = []
    for shape in footprint:
        if isinstance(shape, Circle):
            xs += [shape.cx - shape.radius, shape.cx + shape.radius]
            ys += [shape.cy - shape.radius, shape.cy + shape.radius]
        else:
            xs += [x for x, _ in shape.points]
            ys += [y for _, y in shape.points]
    if element is None or not xs or not all(map(math.isfinite, xs + ys)):
        return
    dx, dy = max(xs) - min(xs), max(ys) - min(ys)
    if max(dx, dy) > MAX_FOOTPRINT_EXTENT:
        r.problem(
            element,
            "footprint-extent",
            f"the footprint spans {dx:.1f} m x {dy:.1f} m; at most {MAX_FOOTPRINT_EXTENT:g} m "
            "either way (the gear and engines of the largest airliners span 30 m x 50 m)",
        )


# -- mission ---------------------------------------------------------------------------------------
def default_library_root(mission_path: Path) -> Path:
    """The mission library a mission file belongs to: ``<root>/<type>/<mission>.xml``."""
    return library_root_of(mission_path, 2)


def load_mission(path: Path | str, library_root: Path | str | None = None) -> Mission:
    """Load and check a mission and its aircraft; raise :class:`InvalidInputError` on any problem.

    The aircraft file is resolved relative to the mission file and must stay inside
    ``library_root`` (default: the mission file's grandparent directory).
    """
    return load_document(path, "mission", MISSION_NS, _build_mission, library_root, 2)


def _build_mission(
    doc: XmlDocument, sink: ProblemSink, path: Path, root_dir: Path
) -> Mission | None:
    r = ElementReader(doc, sink)
    root = doc.root
    aircraft, aircraft_problems = load_reference(
        r, "aircraft", path, root_dir, load_aircraft, "mission"
    )
    sink.extend(aircraft_problems)

    if aircraft is not None and r.str_(root, "aircraft-type") != aircraft.type:
        r.problem(
            root,
            "aircraft-type",
            f"aircraft-type '{r.str_(root, 'aircraft-type')}' does not match the aircraft "
            f"file's type '{aircraft.type}'",
            "aircraft-type",
        )

    platform = _build_platform(r, r.child(root, "platform"))
    safety_el = r.child(root, "safety")
    assert safety_el is not None
    safety = SafetyRadii(
        r.num(safety_el, "r-es"),
        r.num(safety_el, "r-oa-trigger"),
        r.num(safety_el, "estop-hold"),
        r.num(safety_el, "geofence-margin", DEFAULT_GEOFENCE_MARGIN),
    )
    if not safety.r_es < safety.r_oa_trigger:
        r.problem(
            safety_el,
            "safety-radii",
            f"r-es ({safety.r_es:g} m) must be smaller than r-oa-trigger "
            f"({safety.r_oa_trigger:g} m): avoidance must start before the emergency stop",
            "r-es",
        )

    nav_el = r.child(root, "navigation")
    assert nav_el is not None
    navigation = Navigation(
        cruise_speed=r.num(nav_el, "cruise-speed"),
        inspection_speed=r.num(nav_el, "inspection-speed"),
        position_tolerance=r.num(nav_el, "position-tolerance"),
        heading_tolerance=r.angle(nav_el, "heading-tolerance-deg"),
        turn_mode=r.enum(nav_el, "turn-mode", TurnMode),
    )
    for attr in ("cruise-speed", "inspection-speed"):
        value = r.num(nav_el, attr)
        if value > platform.max_speed:
            r.problem(
                nav_el,
                "speed-limit",
                f"{attr} {value:g} m/s exceeds the platform's max-speed {platform.max_speed:g} m/s",
                attr,
            )

    speeds = {
        "cruise-speed": navigation.cruise_speed,
        "inspection-speed": navigation.inspection_speed,
    }
    speed_el = [
        *r.children(r.child(root, "approach"), "waypoint"),
        *r.children(r.child(root, "return"), "waypoint"),
    ]
    for we in speed_el:
        if we.get("speed") is not None:
            speeds[f"waypoint '{r.str_(we, 'id')}' speed"] = r.num(we, "speed")
    # a speed above max-speed is reported as such (speed-limit), not a second time here
    speeds = {k: v for k, v in speeds.items() if v <= platform.max_speed}
    stopping = checks.stopping_problem(safety.r_es, speeds, platform.max_acceleration)
    if stopping:
        r.problem(safety_el, "stopping-distance", stopping, "r-es")

    airport_el = r.child(root, "airport")
    assert airport_el is not None
    zone_el = r.children(airport_el, "zone")
    r.unique(zone_el, "zone")
    zones = []
    for ze in zone_el:
        zid = r.str_(ze, "id")
        shape_el = r.elements(ze)[0]
        zones.append(
            ForbiddenZone(
                zid,
                r.enum(ze, "kind", ZoneKind),
                r.enum(ze, "frame", Frame),
                r.shape(shape_el, zid),
                r.where(ze),
            )
        )
    station_el, parking_el = r.child(airport_el, "station"), r.child(airport_el, "parking")
    assert station_el is not None and parking_el is not None
    airport = Airport(r.pose(station_el), r.pose(parking_el), tuple(zones))
    mosaic_el = r.child(airport_el, "ceiling-mosaic")
    ceiling_mosaic = None
    if mosaic_el is not None:
        ceiling_mosaic, mosaic_problems = load_reference(
            r, "file", path, root_dir, _checked_mosaic, "mission", mosaic_el, "ceiling-mosaic"
        )
        sink.extend(mosaic_problems)

    approach_el = r.child(root, "approach")
    return_el = r.child(root, "return")
    approach_wp = r.children(approach_el, "waypoint")
    return_wp = r.children(return_el, "waypoint")
    r.unique([*approach_wp, *return_wp], "waypoint")
    approach = tuple(_waypoint(r, e, platform) for e in approach_wp)
    return_route = tuple(_waypoint(r, e, platform) for e in return_wp)
    handover_el = r.child(approach_el, "handover") if approach_el is not None else None
    assert handover_el is not None
    hpose = r.pose(handover_el)
    handover = Waypoint(
        "handover", hpose.x, hpose.y, Frame.AIRPORT, hpose.theta, None, r.where(handover_el)
    )
    taught_route = _taught_route(
        r, r.child(approach_el, "taught-route"), path, root_dir, platform, hpose, ceiling_mosaic
    )

    checkpoint_el = r.children(r.child(root, "inspection"), "checkpoint")
    r.unique(checkpoint_el, "checkpoint")
    checkpoints = tuple(_checkpoint(r, e, platform, aircraft) for e in checkpoint_el)

    if aircraft is None:
        return None
    mission = Mission(
        id=r.str_(root, "id"),
        aircraft=aircraft,
        platform=platform,
        safety=safety,
        navigation=navigation,
        airport=airport,
        approach=approach,
        handover=handover,
        checkpoints=checkpoints,
        return_route=return_route,
        description=r.text(r.child(root, "description")),
        source=sink.file,
        ceiling_mosaic=ceiling_mosaic,
        taught_route=taught_route,
    )
    # Geometry runs even when other problems were found, so all are reported at once;
    # it skips references that did not resolve (already reported).
    _check_placement(r, mission, checkpoint_el, [*approach_wp, *return_wp], station_el, handover_el)
    return None if sink else mission


ROUTE_END_NEAR_P = 1.0
"""Metres from the handover point P within which a taught approach route must end (the
approach's last navigation, metric go-to-goal, covers the rest)."""


def _taught_route(
    r: ElementReader,
    el: etree._Element | None,
    path: Path,
    root_dir: Path,
    platform: Platform,
    handover: Pose2,
    mosaic: Path | None,
) -> TaughtRoute | None:
    """The approach's ``<taught-route>`` (issue 17): loaded, ending near P, at a speed the
    platform has, on the mission's mosaic if it names one."""
    if el is None:
        return None
    route, problems = load_reference(
        r, "file", path, root_dir, lambda p: load_route(p, root_dir), "mission", el, "taught-route"
    )
    r.sink.extend(problems)
    if route is None:
        return None
    gap = math.hypot(route.end.x - handover.x, route.end.y - handover.y)
    if gap > ROUTE_END_NEAR_P:
        r.problem(
            el,
            "taught-route-end",
            f"taught route '{route.id}' ends {gap:.2f} m from the handover point P "
            f"({route.end.x:g}, {route.end.y:g} vs {handover.x:g}, {handover.y:g}); it must "
            f"end within {ROUTE_END_NEAR_P:g} m",
            "file",
        )
    if abs(route.speed) > platform.max_speed:
        r.problem(
            el,
            "speed-limit",
            f"taught route '{route.id}' speed {abs(route.speed):g} m/s exceeds the "
            f"platform's max-speed {platform.max_speed:g} m/s",
            "file",
        )
    if mosaic is not None and mosaic.resolve() != route.mosaic.resolve():
        r.problem(
            el,
            "taught-route-mosaic",
            f"taught route '{route.id}' was taught on mosaic '{display_path(route.mosaic)}', "
            f"not the airport's ceiling-mosaic '{display_path(mosaic)}'",
            "file",
        )
    return route


def _checked_mosaic(path: Path) -> Path:
    """``path`` once :func:`~executive.core.mosaicfile.read_mosaic` has read it whole."""
    try:
        read_mosaic(path)
    except MosaicFormatError as exc:
        where = SourceLocation(display_path(path))
        raise InvalidInputError([Problem(where, "mosaic-format", str(exc))]) from None
    return path


def _build_platform(r: ElementReader, el: etree._Element | None) -> Platform:
    assert el is not None
    camera_el = r.children(el, "camera")
    laser_el = r.children(el, "laser")
    r.unique(camera_el, "camera")
    r.unique(laser_el, "laser")
    cameras: dict[str, CameraSpec] = {}
    for ce in camera_el:
        cid = r.str_(ce, "id")
        width_px, height_px = int(r.num(ce, "width-px")), int(r.num(ce, "height-px"))
        image_w = int(r.num(ce, "image-width-px", float(width_px)))
        image_h = int(r.num(ce, "image-height-px", float(height_px)))
        pan = (r.angle(ce, "pan-min-deg"), r.angle(ce, "pan-max-deg"))
        tilt = (r.angle(ce, "tilt-min-deg"), r.angle(ce, "tilt-max-deg"))
        for name, (lo, hi) in (("pan", pan), ("tilt", tilt)):
            if not lo < hi:
                r.problem(
                    ce,
                    "limits-order",
                    f"camera '{cid}': {name}-min-deg must be smaller than {name}-max-deg",
                    f"{name}-min-deg",
                )
        if image_w > width_px or image_h > height_px:
            r.problem(
                ce,
                "image-size",
                f"camera '{cid}': the output image ({image_w}x{image_h}) is larger than the "
                f"sensor ({width_px}x{height_px})",
                "image-width-px",
            )
        kind = r.enum(ce, "kind", CameraKind)
        baseline = r.opt_num(ce, "baseline")
        if kind is CameraKind.STEREO and baseline is None:
            r.problem(ce, "missing", f"stereo camera '{cid}' needs a 'baseline'")
        cameras.setdefault(
            cid,
            CameraSpec(
                id=cid,
                kind=kind,
                mount=(r.num(ce, "x"), r.num(ce, "y"), r.num(ce, "z")),
                mount_yaw=r.angle(ce, "yaw-deg"),
                width_px=width_px,
                height_px=height_px,
                pixel_size=r.num(ce, "pixel-um") * 1e-6,
                focal_length=r.num(ce, "focal-mm") * 1e-3,
                image_width_px=image_w,
                image_height_px=image_h,
                pan_limits=pan,
                tilt_limits=tilt,
                pan_rate=r.angle(ce, "pan-rate-deg"),
                tilt_rate=r.angle(ce, "tilt-rate-deg"),
                rate_hz=r.num(ce, "rate-hz"),
                baseline=baseline,
                where=r.where(ce),
            ),
        )
    lasers: dict[str, LaserSpec] = {}
    for le in laser_el:
        lid = r.str_(le, "id")
        lasers.setdefault(
            lid,
            LaserSpec(
                id=lid,
                mount=(r.num(le, "x"), r.num(le, "y"), r.num(le, "z")),
                mount_yaw=r.angle(le, "yaw-deg"),
                fov=r.angle(le, "fov-deg"),
                resolution=r.angle(le, "resolution-deg"),
                range=r.num(le, "range"),
                rate_hz=r.num(le, "rate-hz"),
                where=r.where(le),
            ),
        )
    width = r.num(el, "width")
    track = r.num(el, "track", TRACK_OF_WIDTH * width)
    if track > width:
        r.problem(
            el,
            "track-width",
            f"track {track:g} m is wider than the platform ({width:g} m)",
            "track",
        )
    length = r.num(el, "length")
    return Platform(
        length=length,
        width=width,
        track=track,
        max_speed=r.num(el, "max-speed"),
        max_angular_speed=r.num(el, "max-angular-speed"),
        max_acceleration=r.num(el, "max-acceleration"),
        max_angular_acceleration=r.num(el, "max-angular-acceleration"),
        max_jerk=r.num(el, "max-jerk"),
        cameras=MappingProxyType(cameras),
        lasers=MappingProxyType(lasers),
        ceiling_camera=_ceiling_camera(r, r.child(el, "ceiling-camera"), length, width),
    )


def _ceiling_camera(
    r: ElementReader, el: etree._Element | None, length: float, width: float
) -> CeilingCameraSpec | None:
    """The platform's upward camera (issue 17), which must sit on the robot's footprint."""
    if el is None:
        return None
    spec = CeilingCameraSpec(
        mount_x=r.num(el, "x"),
        mount_y=r.num(el, "y"),
        mount_z=r.num(el, "z", 0.6),
        mount_yaw=r.angle(el, "yaw-deg"),
        width_px=int(r.num(el, "width-px")),
        height_px=int(r.num(el, "height-px")),
        hfov=r.angle(el, "hfov-deg"),
        rate_hz=r.num(el, "rate-hz"),
        where=r.where(el),
    )
    if abs(spec.mount_x) > length / 2.0 or abs(spec.mount_y) > width / 2.0:
        r.problem(
            el,
            "ceiling-camera-mount",
            f"ceiling-camera at ({spec.mount_x:g}, {spec.mount_y:g}) m is off the robot's "
            f"{length:g} m x {width:g} m footprint",
            "x",
        )
    return spec


def _waypoint(r: ElementReader, el: etree._Element, platform: Platform) -> Waypoint:
    wid = r.str_(el, "id")
    speed = r.opt_num(el, "speed")
    if speed is not None and speed > platform.max_speed:
        r.problem(
            el,
            "speed-limit",
            f"waypoint '{wid}': speed {speed:g} m/s exceeds the platform's max-speed "
            f"{platform.max_speed:g} m/s",
            "speed",
        )
    frame = Frame(r.str_(el, "frame")) if el.get("frame") else Frame.AIRPORT
    return Waypoint(
        wid,
        r.num(el, "x"),
        r.num(el, "y"),
        frame,
        r.opt_angle(el, "heading-deg"),
        speed,
        r.where(el),
    )


def _checkpoint(
    r: ElementReader, el: etree._Element, platform: Platform, aircraft: Aircraft | None
) -> Checkpoint:
    cid = r.str_(el, "id")
    item_refs = r.children(el, "inspect")
    items = tuple(r.str_(ie, "item") for ie in item_refs)
    r.unique(
        item_refs,
        "item",
        "item",
        f"checkpoint '{cid}' inspects item '{{key}}' twice (first at line {{line}})",
    )
    camera = el.get("camera")
    target = el.get("target")
    if camera is not None and camera not in platform.cameras:
        r.problem(
            el,
            "unknown-reference",
            f"checkpoint '{cid}': camera '{camera}' is not a platform camera"
            + checks.suggest(camera, platform.cameras),
            "camera",
        )
    if target is not None and camera is None:
        r.problem(
            el,
            "target-without-camera",
            f"checkpoint '{cid}': a servo target needs a camera (add camera=\"...\")",
            "target",
        )
    if aircraft is not None:
        if target is not None and target not in aircraft.features:
            r.problem(
                el,
                "unknown-reference",
                f"checkpoint '{cid}': target '{target}' is not a feature of the aircraft"
                + checks.suggest(target, aircraft.features),
                "target",
            )
        for ie, item in zip(item_refs, items, strict=True):
            if item not in aircraft.items:
                r.problem(
                    ie,
                    "unknown-reference",
                    f"checkpoint '{cid}': item '{item}' is not an inspection item of the "
                    f"aircraft" + checks.suggest(item, aircraft.items),
                    "item",
                )
    servo = el.get("servo")
    return Checkpoint(
        id=cid,
        name=r.str_(el, "name") or cid,
        pose=r.pose(el),
        items=items,
        camera=camera,
        target=target,
        servo=ServoMethod(servo) if servo else None,
        dwell=r.num(el, "dwell", 0.0),
        via=tuple((r.num(v, "x"), r.num(v, "y")) for v in r.children(el, "via")),
        where=r.where(el),
    )


def _check_placement(
    r: ElementReader,
    mission: Mission,
    checkpoint_el: list[etree._Element],
    waypoint_el: list[etree._Element],
    station_el: etree._Element,
    handover_el: etree._Element,
) -> None:
    """Geometry across the two files: clearances, zones, visibility of targets and items."""
    placement = mission.nominal_placement()
    places: list[tuple[etree._Element, str, float, float, Frame]] = []
    for ce, cp in zip(checkpoint_el, mission.checkpoints, strict=True):
        places.append((ce, f"checkpoint '{cp.id}'", cp.pose.x, cp.pose.y, Frame.AIRCRAFT))
        for k, (ve, (vx, vy)) in enumerate(zip(r.children(ce, "via"), cp.via, strict=True)):
            places.append((ve, f"via point {k + 1} of '{cp.id}'", vx, vy, Frame.AIRCRAFT))
    for we, wp in zip(waypoint_el, (*mission.approach, *mission.return_route), strict=True):
        places.append((we, f"waypoint '{wp.id}'", wp.x, wp.y, wp.frame))
    st = mission.airport.station
    places.append((station_el, "the charging station", st.x, st.y, Frame.AIRPORT))
    places.append(
        (handover_el, "the handover point", mission.handover.x, mission.handover.y, Frame.AIRPORT)
    )
    # Clearances depend on r_ES: when the radii are wrong (already reported) skip them.
    radii_ok = 0.0 < mission.safety.r_es < mission.safety.r_oa_trigger
    blocked: set[etree._Element] = set()  # stops with a problem: their legs would repeat it
    for element, label, x, y, frame in places if radii_ok else ():
        for message in checks.clearance_problems(mission, placement, label, x, y, frame):
            r.problem(element, "clearance", message)
            blocked.add(element)

    # The route as the robot drives it, straight from stop to stop, in A.
    def in_a(x: float, y: float, frame: Frame) -> tuple[float, float]:
        if frame is Frame.AIRCRAFT:
            ax, ay = placement.to_airport_xy((x, y))
            return float(ax), float(ay)
        return x, y

    n_approach = len(mission.approach)
    station = (station_el, "the charging station", (st.x, st.y))
    handover = (handover_el, "the handover point", (mission.handover.x, mission.handover.y))
    route = [station]
    route += [
        (we, f"waypoint '{wp.id}'", in_a(wp.x, wp.y, wp.frame))
        for we, wp in zip(waypoint_el[:n_approach], mission.approach, strict=True)
    ]
    route.append(handover)
    for ce, cp in zip(checkpoint_el, mission.checkpoints, strict=True):
        for k, (ve, (vx, vy)) in enumerate(zip(r.children(ce, "via"), cp.via, strict=True)):
            route.append((ve, f"via point {k + 1} of '{cp.id}'", in_a(vx, vy, Frame.AIRCRAFT)))
        route.append((ce, f"checkpoint '{cp.id}'", in_a(cp.pose.x, cp.pose.y, Frame.AIRCRAFT)))
    route += [
        (we, f"waypoint '{wp.id}'", in_a(wp.x, wp.y, wp.frame))
        for we, wp in zip(waypoint_el[n_approach:], mission.return_route, strict=True)
    ]
    route += [handover, station]
    for (start, a_label, a), (element, b_label, b) in itertools.pairwise(route):
        if not radii_ok or start in blocked or element in blocked:
            continue
        leg = f"the leg from {a_label} to {b_label}"
        for message in checks.leg_problems(mission, placement, leg, a, b):
            r.problem(element, "leg-clearance", message)

    for ce, cp in zip(checkpoint_el, mission.checkpoints, strict=True):
        known_target = cp.target in mission.aircraft.features
        if known_target and cp.camera in mission.platform.cameras:
            assert cp.target is not None and cp.camera is not None
            camera = mission.platform.cameras[cp.camera]
            feature = mission.aircraft.features[cp.target]
            reason = checks.why_not_visible(
                camera, feature, cp.pose, mission.aircraft.origin_height
            )
            if reason:
                r.problem(
                    ce,
                    "target-not-visible",
                    f"checkpoint '{cp.id}': servo target '{cp.target}' {reason}",
                    "target",
                )
        for ie, item_id in zip(r.children(ce, "inspect"), cp.items, strict=True):
            if item_id not in mission.aircraft.items:
                continue
            feature = mission.aircraft.feature_of(item_id)
            reason = checks.why_no_camera_sees(
                mission.platform.cameras.values(), feature, cp.pose, mission.aircraft.origin_height
            )
            if reason:
                r.problem(
                    ie,
                    "item-not-visible",
                    f"checkpoint '{cp.id}': item '{item_id}' cannot be inspected from here: "
                    f"its feature '{feature.id}' {reason}",
                    "item",
                )


# -- any file ----------------------------------------------------------------------
def check_file(path: Path | str, library_root: Path | str | None = None) -> list[Problem]:
    """Every problem of an aircraft or mission file (empty when valid); never raises."""
    path = Path(path)
    kind = detect_kind(path)
    loaders: dict[str, Callable[[Path], object]] = {
        "aircraft": load_aircraft,
        "mission": lambda p: load_mission(p, library_root),
    }
    try:
        if kind is None:
            sink = ProblemSink(display_path(path))
            doc = parse_xml(path, sink)
            if doc is not None:
                qname = etree.QName(doc.root)
                line, column = doc.locate(doc.root)
                known = ", ".join(f"<{k}> ({ns})" for k, ns in KNOWN_ROOTS.items())
                ns = (
                    f" in namespace '{qname.namespace}'"
                    if qname.namespace
                    else " with no namespace"
                )
                sink.add(
                    "wrong-root",
                    f"unknown document <{qname.localname}>{ns}; expected one of {known}",
                    line,
                    column,
                )
            return list(sink.problems)
        loaders[kind](path)
    except InvalidInputError as exc:
        return list(exc.problems)
    return []
