"""Draft a mission from an aircraft file (issue 18): candidates, cover, tour, checks.

:func:`plan_mission` takes the aircraft and a template mission (the robot, its safety
radii and navigation settings, the apron's forbidden zones; the station and the parking
pose unless given) and returns a :class:`Plan`:

1. candidate poses and what the inspection camera sees from each
   (:mod:`executive.planning.candidates`);
2. a small set of checkpoints seeing every coverable item (:mod:`executive.planning.cover`);
3. the handover point P on the first clear leg from the station towards the checkpoint
   that inspects the aircraft file's first item, :data:`HANDOVER_STANDOFF` from the
   airframe (the walk-around starts there, as the flight crew's does);
4. a tour P -> checkpoints -> P round the footprint and the zones, via points where a
   straight leg would not keep its clearance (:mod:`executive.planning.tour`);
5. on each checkpoint, where one exists, the servo camera unit and target that visual
   servoing reaches it on, and the template's dwell (:mod:`executive.planning.targets`);
6. every stop, leg, item and servo target checked with the validator's own functions
   (:mod:`executive.core.checks`): a plan that fails them is a planner bug and raises.

Items no candidate sees, or that no clear path reaches, are listed with the reason.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from dataclasses import dataclass, field

import numpy as np
import shapely
from shapely.ops import unary_union

from executive.core import checks
from executive.core.frames import Pose2, wrap_angle
from executive.core.geometry import to_shapely
from executive.core.model import (
    Aircraft,
    Airport,
    CameraKind,
    Checkpoint,
    Frame,
    Mission,
    Waypoint,
)
from executive.planning.candidates import (
    CandidateViews,
    candidate_views,
    feature_views,
    inspection_unit,
    pan_tilt,
)
from executive.planning.cover import Cover, set_cover
from executive.planning.space import FreeSpace, free_space
from executive.planning.targets import choose_servo_target, template_dwell
from executive.planning.tour import Roadmap, plan_tour, roadmap

HANDOVER_STANDOFF = 5.0
"""Metres from the airframe (outline and footprint) at which the approach hands over to
the inspection: outside the 3 m band where the inspection speed applies."""

HANDOVER_STEP = 0.25
"""Metres between the positions tried for P along the first leg."""


class PlanningError(RuntimeError):
    """The planner produced a stop, leg or view the validator would refuse (a bug)."""


@dataclass(frozen=True)
class PlannedCheckpoint:
    """A checkpoint of the draft and why it is where it is."""

    checkpoint: Checkpoint
    why: tuple[str, ...]


@dataclass(frozen=True)
class Plan:
    """A draft mission: the model (validated by the planner's checks) and its story."""

    mission: Mission
    checkpoints: tuple[PlannedCheckpoint, ...]
    uncovered: dict[str, str]
    handover_why: str
    return_why: tuple[str, ...]
    candidates: int
    tour_length: float
    """Metres from P through every checkpoint (and via point) back to P."""
    notes: tuple[str, ...] = field(default_factory=tuple)

    @property
    def covered(self) -> tuple[str, ...]:
        return tuple(i for c in self.checkpoints for i in c.checkpoint.items)


def draft_base(
    template: Mission,
    aircraft: Aircraft,
    station: Pose2 | None = None,
    parking: Pose2 | None = None,
    mission_id: str | None = None,
) -> Mission:
    """The template's robot, safety, navigation and zones for ``aircraft``, no route yet."""
    airport = Airport(
        station or template.airport.station,
        parking or template.airport.parking,
        template.airport.zones,
    )
    handover = Waypoint("handover", airport.station.x, airport.station.y, Frame.AIRPORT, 0.0)
    return dataclasses.replace(
        template,
        id=mission_id or f"{_slug(aircraft.type)}-draft",
        aircraft=aircraft,
        airport=airport,
        approach=(),
        handover=handover,
        checkpoints=(),
        return_route=(),
        description="",
        source="",
    )


def _slug(text: str) -> str:
    out = "".join(c.lower() if c.isalnum() else "-" for c in text).strip("-")
    return out or "aircraft"


def polyline_length(points: list[tuple[float, float]]) -> float:
    return float(sum(math.dist(a, b) for a, b in itertools.pairwise(points)))


def route_points(mission: Mission) -> list[tuple[float, float]]:
    """Every stop of ``mission`` in the order driven, in A (as the validator walks it)."""
    placement = mission.nominal_placement()

    def in_a(x: float, y: float, frame: Frame) -> tuple[float, float]:
        if frame is Frame.AIRCRAFT:
            ax, ay = placement.to_airport_xy((x, y))
            return float(ax), float(ay)
        return x, y

    st = mission.airport.station
    hand = (mission.handover.x, mission.handover.y)
    pts = [(st.x, st.y)]
    pts += [in_a(w.x, w.y, w.frame) for w in mission.approach]
    pts.append(hand)
    for cp in mission.checkpoints:
        pts += [in_a(x, y, Frame.AIRCRAFT) for x, y in cp.via]
        pts.append(in_a(cp.pose.x, cp.pose.y, Frame.AIRCRAFT))
    pts += [in_a(w.x, w.y, w.frame) for w in mission.return_route]
    pts += [hand, (st.x, st.y)]
    return pts


def route_length(mission: Mission) -> float:
    """Metres of straight legs from the station round the checkpoints and back."""
    return polyline_length(route_points(mission))


def inspection_tour_length(mission: Mission) -> float:
    """Metres from P through the checkpoints (and via points) back to P."""
    pts = route_points(mission)
    return polyline_length(pts[1 + len(mission.approach) : len(pts) - 1])


# -- the steps ----------------------------------------------------------------------------
def _airframe(aircraft: Aircraft) -> shapely.Geometry:
    return unary_union([to_shapely(s) for s in (*aircraft.outline, *aircraft.footprint)])


def _nearest_shapes(space: FreeSpace, x: float, y: float) -> str:
    """'2.1 m from the footprint ('nose-gear'), 3.0 m from zone 'refuel'' for a comment."""
    p = shapely.Point(x, y)
    parts = []
    if space.footprint:
        sid, g = min(space.footprint, key=lambda s: s[1].distance(p))
        parts.append(f"{g.distance(p):.1f} m from the footprint ('{sid}')")
    if space.zones:
        zid, g = min(space.zones, key=lambda s: s[1].distance(p))
        parts.append(f"{g.distance(p):.1f} m from zone '{zid}'")
    return ", ".join(parts) if parts else "nothing to keep clear of"


def _nearest_obstacle(space: FreeSpace, x: float, y: float) -> str:
    """'the footprint ('nose-gear'), 1.6 m away' or 'zone 'refuel', 1.3 m away'."""
    p = shapely.Point(x, y)
    named = [(g.distance(p), f"the footprint ('{i}')") for i, g in space.footprint]
    named += [(g.distance(p), f"zone '{i}'") for i, g in space.zones]
    if not named:
        return "nothing"
    d, name = min(named)
    return f"{name}, {d:.1f} m away"


PAN_ARC = math.radians(170.0)
"""Widest spread (rad) of the items' bearings from one checkpoint. The checkpoint faces
the middle of the spread, so every pan the inspection unit takes there is within
+-85 deg and two successive pans never differ by half a turn: the inspection behaviour
turns the unit the short way round, which for a unit with +-180 deg limits would push it
against the limit instead of through it. Items spread wider are inspected from a second
checkpoint at the same place, facing the other way."""


def _bearing_groups(bearings: list[float]) -> list[list[int]]:
    """Indices of ``bearings`` (rad) in groups that each span at most PAN_ARC, swept from
    the largest gap between them."""
    order = sorted(range(len(bearings)), key=lambda i: bearings[i] % (2 * math.pi))
    angles = [bearings[i] % (2 * math.pi) for i in order]
    gaps = [(angles[(k + 1) % len(angles)] - angles[k]) % (2 * math.pi) for k in range(len(angles))]
    if len(angles) == 1:
        return [order]
    start = (int(np.argmax(gaps)) + 1) % len(angles)
    swept = [(order[(start + k) % len(order)]) for k in range(len(order))]
    unwrapped = np.unwrap([bearings[i] for i in swept])
    groups: list[list[int]] = []
    first = 0.0
    for i, a in zip(swept, unwrapped, strict=True):
        if not groups or a - first > PAN_ARC:
            groups.append([])
            first = a
        groups[-1].append(i)
    return groups


def _checkpoint_poses(
    space: FreeSpace, views: CandidateViews, row: int, items: list[str]
) -> list[tuple[Pose2, list[str], str]]:
    """The pose(s) at a chosen candidate: facing the middle of its items' bearings, one
    pose per PAN_ARC of them; each item checked again with the final heading."""
    aircraft = space.mission.aircraft
    x, y = float(views.poses[row][0]), float(views.poses[row][1])
    cents = [aircraft.feature_of(i).centroid() for i in items]
    bearings = [math.atan2(c[1] - y, c[0] - x) for c in cents]
    groups = _bearing_groups(bearings)
    out = []
    for g, members in enumerate(groups):
        arc = np.unwrap([bearings[i] for i in members])
        heading = wrap_angle(float(arc.min() + arc.max()) / 2.0)
        pose = np.array([[x, y, heading]])
        for i in members:
            feature = aircraft.feature_of(items[i])
            pan = pan_tilt(views.unit, pose, feature.centroid(), aircraft.origin_height)[0][0]
            seen = feature_views(space, views.unit, feature, pose)[0][0]
            if not seen or abs(pan) > PAN_ARC / 2 + math.radians(1.0):
                raise PlanningError(
                    f"item '{items[i]}' is not seen from ({x:.2f}, {y:.2f}) facing "
                    f"{math.degrees(heading):.0f} deg (a camera off the robot's axis?)"
                )
        spread = math.degrees(float(arc.max() - arc.min()))
        why = f"faces the middle of its items (spread over {spread:.0f} deg"
        if len(groups) > 1:
            why += (
                f"; stop {g + 1} of {len(groups)} at this place: its items are spread over more "
                f"than {math.degrees(PAN_ARC):.0f} deg"
            )
        why += ")"
        out.append((Pose2(x, y, heading), [items[i] for i in sorted(members)], why))
    return out


def _handover(
    space: FreeSpace, station_f: np.ndarray, first: list[tuple[float, float]]
) -> tuple[np.ndarray, str]:
    """P on the first straight leg of the path from the station to the first checkpoint:
    the point nearest the aircraft that is still HANDOVER_STANDOFF from the airframe."""
    end = np.asarray(first[0], dtype=float)
    airframe = _airframe(space.mission.aircraft)
    leg = end - station_f
    length = float(np.hypot(*leg))
    if length < 1e-9:
        return station_f, "at the station: the station is already by the aircraft"
    steps = np.arange(length, -1e-9, -HANDOVER_STEP)
    pts = station_f + np.outer(steps / length, leg)
    clear = space.can_stop(pts)
    far = shapely.distance(airframe, shapely.points(pts)) >= HANDOVER_STANDOFF
    ok = np.flatnonzero(clear & far)
    if len(ok):
        k = int(ok[0])
        return pts[k], (
            "on the straight leg from the station towards the checkpoint of the first item, "
            f"where it comes within {HANDOVER_STANDOFF:g} m of the airframe "
            f"({steps[k]:.1f} m from the station)"
        )
    return station_f, (
        f"at the station: the station is within {HANDOVER_STANDOFF:g} m of the airframe"
    )


def _reachable_views(
    space: FreeSpace, views: CandidateViews, station_f: np.ndarray
) -> CandidateViews:
    """The candidates the robot can drive to from the station: in the part of the plane
    clear for legs that holds the station. An item seen only from elsewhere (a pocket
    closed by the footprint and the zones) is reported so."""
    if len(views.poses) == 0:
        return views
    pts = np.concatenate([views.poses[:, :2], station_f[None, :]])
    lo, hi = pts.min(axis=0) - 10.0, pts.max(axis=0) + 10.0
    free = shapely.box(lo[0], lo[1], hi[0], hi[1]).difference(space.no_leg)
    station = shapely.Point(station_f[0], station_f[1])
    parts = [g for g in getattr(free, "geoms", [free]) if g.intersects(station)]
    region = parts[0] if parts else shapely.Point(station_f).buffer(0.0)
    shapely.prepare(region)
    ok = shapely.intersects_xy(region, views.poses[:, 0], views.poses[:, 1])
    if ok.all():
        return views
    sees = views.sees & ok[:, None]
    reasons = dict(views.reasons)
    for col in np.flatnonzero(views.sees.any(axis=0) & ~sees.any(axis=0)):
        item = views.items[col]
        feature = space.mission.aircraft.items[item].feature
        reasons[item] = (
            f"its feature '{feature}' is seen only from poses closed in by the footprint "
            "and the zones, which the robot cannot reach from the station"
        )
    return dataclasses.replace(
        views, sees=sees, distance=np.where(sees, views.distance, math.inf), reasons=reasons
    )


def _verify(mission: Mission, placement_checks: bool = True) -> list[str]:
    """Every message the validator's geometry checks give for ``mission``'s route."""
    placement = mission.nominal_placement()
    problems: list[str] = []
    for cp in mission.checkpoints:
        stops = [(f"checkpoint '{cp.id}'", cp.pose.x, cp.pose.y)]
        stops += [(f"via {k} of '{cp.id}'", x, y) for k, (x, y) in enumerate(cp.via, 1)]
        for label, x, y in stops:
            problems += checks.clearance_problems(mission, placement, label, x, y, Frame.AIRCRAFT)
        for item in cp.items:
            reason = checks.why_no_camera_sees(
                mission.platform.cameras.values(),
                mission.aircraft.feature_of(item),
                cp.pose,
                mission.aircraft.origin_height,
            )
            if reason:
                problems.append(f"checkpoint '{cp.id}' item '{item}': {reason}")
        if cp.target is not None and cp.camera is not None:
            reason = checks.why_not_visible(
                mission.platform.cameras[cp.camera],
                mission.aircraft.features[cp.target],
                cp.pose,
                mission.aircraft.origin_height,
            )
            if reason:
                problems.append(f"checkpoint '{cp.id}' servo target '{cp.target}': {reason}")
    for wp in (*mission.approach, *mission.return_route, mission.handover):
        problems += checks.clearance_problems(
            mission, placement, f"waypoint '{wp.id}'", wp.x, wp.y, wp.frame
        )
    pts = route_points(mission)
    for k, (a, b) in enumerate(itertools.pairwise(pts)):
        problems += checks.leg_problems(mission, placement, f"leg {k + 1}", a, b)
    return problems


def plan_mission(
    template: Mission,
    aircraft: Aircraft,
    station: Pose2 | None = None,
    parking: Pose2 | None = None,
    mission_id: str | None = None,
    dwell: float | None = None,
) -> Plan:
    """Draft a mission for ``aircraft`` with ``template``'s robot and apron. ``dwell``:
    seconds at every checkpoint (None: the template's, :func:`template_dwell`)."""
    base = draft_base(template, aircraft, station, parking, mission_id)
    space = free_space(base)
    placement = space.placement
    st = base.airport.station
    station_f = placement.to_aircraft_xy((st.x, st.y))
    views = _reachable_views(space, candidate_views(space), station_f)
    cover: Cover = set_cover(views)
    uncovered = {views.items[c]: views.reasons.get(views.items[c], "") for c in cover.uncovered}
    unit = inspection_unit(base)
    named_camera = unit.id if unit.kind is not CameraKind.PTZ else None
    template_items = {i for cp in template.checkpoints for i in cp.items}

    cps_xy = np.array([views.poses[r][:2] for r in cover.chosen]).reshape(-1, 2)

    # P: on the first leg of the shortest path from the station to the checkpoint that
    # inspects the aircraft file's first item (the walk-around starts there)
    if len(cps_xy):
        to_station = roadmap(space, np.concatenate([station_f[None, :], cps_xy]))
        reach = to_station.dist[0, 1 : 1 + len(cps_xy)]
        ranked = sorted(range(len(cps_xy)), key=lambda k: min(cover.assigned[k]))
        first = next((k for k in ranked if math.isfinite(reach[k])), ranked[0])
        if math.isfinite(reach[first]):
            path = [*to_station.corners(0, first + 1), tuple(cps_xy[first])]
            hand_f, handover_why = _handover(space, station_f, path)
        else:  # left to the tour to report: every checkpoint unreachable
            hand_f, handover_why = station_f, "at the station: no checkpoint can be reached"
    else:
        hand_f, handover_why = station_f, "at the station: nothing to inspect"

    # the tour from P
    terminals = np.concatenate([hand_f[None, :], cps_xy])
    roads: Roadmap = roadmap(space, terminals)
    reachable = [k for k in range(1, len(terminals)) if math.isfinite(roads.dist[0, k])]
    for k in range(1, len(terminals)):
        if k not in reachable:
            for col in cover.assigned[k - 1]:
                uncovered[views.items[col]] = (
                    "the only checkpoint that sees it cannot be reached from P round the "
                    "footprint and the zones"
                )
    idx = [0, *reachable]
    sub = roads.dist[np.ix_(idx, idx)]
    rank = {pos: float(min(cover.assigned[idx[pos] - 1])) for pos in range(1, len(idx))}
    order = [idx[k] for k in plan_tour(sub, rank)]

    planned: list[PlannedCheckpoint] = []
    units = (named_camera,) if named_camera is not None else None
    here = (float(hand_f[0]), float(hand_f[1]))  # where the robot comes from
    for n, k in enumerate(order[1:], start=1):
        row = cover.chosen[k - 1]
        items = [views.items[c] for c in cover.assigned[k - 1]]
        prev = order[n - 1]
        via = tuple(roads.corners(prev, k))
        for g, (pose, members, facing) in enumerate(_checkpoint_poses(space, views, row, items)):
            came_from = via[-1] if via and g == 0 else here
            target, target_why = choose_servo_target(space, pose, members, units, came_from)
            here = (pose.x, pose.y)
            cp_dwell = template_dwell(template, members) if dwell is None else dwell
            cols = [views.items.index(i) for i in members]
            distances = [float(views.distance[row, c]) for c in cols]
            why = [
                f"sees {len(members)} item(s) with camera '{unit.id}' from "
                f"{min(distances):.1f}-{max(distances):.1f} m; {facing}",
                f"{_nearest_shapes(space, pose.x, pose.y)} (a stop needs "
                f"{space.stop_clearance_footprint:.2f} m from the footprint, "
                f"{space.stop_clearance_zones:.2f} m from zones)",
            ]
            if via and g == 0:
                why.append(
                    "via "
                    + "; ".join(
                        f"({x:.1f}, {y:.1f}) round {_nearest_obstacle(space, x, y)}" for x, y in via
                    )
                    + ": a straight leg would not keep its clearance"
                )
            why.append(target_why if target is not None else f"no servo target: {target_why}")
            why.append(
                f"dwell {cp_dwell:g} s "
                + (
                    "(as given)"
                    if dwell is not None
                    else "(the template's longest dwell at these items)"
                    if any(i in template_items for i in members)
                    else "(the template's median dwell)"
                )
            )
            names: list[str] = []
            for i in members:
                f = aircraft.items[i].feature
                if f not in names:
                    names.append(f)
            checkpoint = Checkpoint(
                id=f"CP{len(planned) + 1:02d}",
                name=", ".join(names[:3]) + (f" (+{len(names) - 3})" if len(names) > 3 else ""),
                pose=pose,
                items=tuple(members),
                camera=target.camera if target is not None else named_camera,
                target=target.feature if target is not None else None,
                servo=target.method if target is not None else None,
                dwell=cp_dwell,
                via=tuple((round(x, 3), round(y, 3)) for x, y in via) if g == 0 else (),
            )
            planned.append(PlannedCheckpoint(checkpoint, tuple(why)))

    back = roads.corners(order[-1], 0) if len(order) > 1 else []
    return_route = tuple(
        Waypoint(f"wp-return-{k}", round(x, 3), round(y, 3), Frame.AIRCRAFT)
        for k, (x, y) in enumerate(back, start=1)
    )
    return_why = tuple(
        f"wp-return-{k} ({x:.1f}, {y:.1f}) in F: round {_nearest_obstacle(space, x, y)}, "
        "on the shortest clear path back to P"
        for k, (x, y) in enumerate(back, start=1)
    )
    hand_a = placement.to_airport_xy(hand_f)
    towards = (
        placement.to_airport_xy(
            planned[0].checkpoint.via[0]
            if planned[0].checkpoint.via
            else (planned[0].checkpoint.pose.x, planned[0].checkpoint.pose.y)
        )
        if planned
        else hand_a
    )
    heading = (
        math.atan2(towards[1] - hand_a[1], towards[0] - hand_a[0])
        if math.dist(towards, hand_a) > 1e-6
        else 0.0
    )
    handover = Waypoint(
        "handover",
        round(float(hand_a[0]), 3),
        round(float(hand_a[1]), 3),
        Frame.AIRPORT,
        heading,
    )
    mission = dataclasses.replace(
        base,
        handover=handover,
        checkpoints=tuple(p.checkpoint for p in planned),
        return_route=return_route,
    )
    problems = _verify(mission)
    if problems:
        raise PlanningError("the draft fails the validator's checks:\n" + "\n".join(problems))
    length = inspection_tour_length(mission)
    return Plan(
        mission=mission,
        checkpoints=tuple(planned),
        uncovered=dict(sorted(uncovered.items(), key=lambda kv: views.items.index(kv[0]))),
        handover_why=handover_why,
        return_why=return_why,
        candidates=len(views.poses),
        tour_length=length,
    )
