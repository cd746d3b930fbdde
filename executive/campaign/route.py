"""The route an episode's robot drives, and the placement rules random obstacles obey.

The route is the robot's start, the approach waypoints, P, every checkpoint (with its
``via`` points), the return waypoints, P and the station, joined by straight legs, in the
airport frame A. Points given in the aircraft frame F move with the aircraft, so the
route is laid at the true parking pose (where the checkpoints really are) and at the
nominal one (where the executive heads before it has registered the aircraft); the rules
hold for both (missions/a320/scenarios/busy-apron.xml states them in its comments).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import shapely
from shapely.geometry import LineString, MultiLineString, Point
from shapely.geometry.base import BaseGeometry
from shapely.ops import unary_union

from executive.core.frames import AircraftPlacement
from executive.core.geometry import to_shapely
from executive.core.model import Circle, Frame, Mission, Polygon
from sim2d.scenario import (
    Chaser,
    LoiteringGroup,
    Obstacle,
    PathMover,
    Scenario,
    StaticObstacle,
)

XY = tuple[float, float]


@dataclass(frozen=True, slots=True)
class Leg:
    """A straight leg of the route from ``a`` to ``b`` (A, metres)."""

    a: XY
    b: XY

    @property
    def length(self) -> float:
        return math.dist(self.a, self.b)

    def at(self, s: float, lateral: float = 0.0) -> XY:
        """The point ``s`` metres along the leg and ``lateral`` metres to its left."""
        ux, uy = (self.b[0] - self.a[0]) / self.length, (self.b[1] - self.a[1]) / self.length
        return (self.a[0] + s * ux - lateral * uy, self.a[1] + s * uy + lateral * ux)

    @property
    def heading(self) -> float:
        return math.atan2(self.b[1] - self.a[1], self.b[0] - self.a[0])


def route_points(mission: Mission, start: XY, placement: AircraftPlacement) -> list[XY]:
    """The route's points in A with the aircraft at ``placement``, from the robot's start."""

    def in_a(x: float, y: float, frame: Frame) -> XY:
        if frame is Frame.AIRCRAFT:
            ax, ay = placement.to_airport_xy((x, y))
            return float(ax), float(ay)
        return x, y

    station = (mission.airport.station.x, mission.airport.station.y)
    handover = in_a(mission.handover.x, mission.handover.y, mission.handover.frame)
    pts: list[XY] = [start]
    pts += [in_a(w.x, w.y, w.frame) for w in mission.approach]
    pts.append(handover)
    for cp in mission.checkpoints:
        pts += [in_a(x, y, Frame.AIRCRAFT) for x, y in cp.via]
        pts.append(in_a(cp.pose.x, cp.pose.y, Frame.AIRCRAFT))
    pts += [in_a(w.x, w.y, w.frame) for w in mission.return_route]
    pts += [handover, station]
    return pts


def legs_of(points: list[XY], min_length: float = 1e-6) -> list[Leg]:
    """Successive points joined, legs shorter than ``min_length`` left out."""
    legs = [Leg(a, b) for a, b in itertools.pairwise(points)]
    return [leg for leg in legs if leg.length >= max(min_length, 1e-6)]


def _placed(shape: Polygon | Circle, placement: AircraftPlacement | None) -> BaseGeometry:
    geom = to_shapely(shape)
    if placement is None:
        return geom
    if isinstance(shape, Circle):
        cx, cy = placement.to_airport_xy((shape.cx, shape.cy))
        return Point(float(cx), float(cy)).buffer(shape.radius)
    return shapely.Polygon(placement.to_airport_xy(geom.exterior.coords))


def obstacle_geometry(obstacle: Obstacle) -> BaseGeometry:
    """Where a static obstacle stands (a mover: where it starts; a group: its circle)."""
    if isinstance(obstacle, LoiteringGroup):
        return Point(*obstacle.center).buffer(obstacle.radius + obstacle.person_radius)
    if isinstance(obstacle, StaticObstacle):
        body, pose = obstacle.body, obstacle.pose
        if body.radius is not None:
            return Point(pose.x, pose.y).buffer(body.radius)
        return to_shapely(body.polygon(pose))
    first = obstacle.waypoints[0] if isinstance(obstacle, PathMover) else obstacle.start
    return Point(*first).buffer(obstacle.body.bounding_radius)


def sweep_geometry(obstacle: PathMover) -> BaseGeometry:
    """The ground a path mover covers, its body included."""
    return LineString(obstacle.waypoints).buffer(obstacle.body.bounding_radius)


class RouteMap:
    """The route, zones, aircraft footprint and base obstacles of one episode's scenario
    (at its true parking pose), with the distance tests the sampler's rules need."""

    def __init__(self, scenario: Scenario) -> None:
        mission = scenario.mission
        true, nominal = scenario.true_placement(), mission.nominal_placement()
        start = (scenario.start.x, scenario.start.y)
        self.true_points = route_points(mission, start, true)
        self.points = self.true_points + route_points(mission, start, nominal)
        self.true_legs = legs_of(self.true_points)
        self.legs = self.true_legs + legs_of(route_points(mission, start, nominal))
        self.lines = MultiLineString([[leg.a, leg.b] for leg in self.legs])
        self.vertices = shapely.MultiPoint(self.points)
        zones = []
        for zone in mission.airport.zones:
            if zone.frame is Frame.AIRCRAFT:
                zones += [_placed(zone.shape, true), _placed(zone.shape, nominal)]
            else:
                zones.append(_placed(zone.shape, None))
        self.zones = unary_union(zones) if zones else None
        self.footprint = unary_union([_placed(s, true) for s in mission.aircraft.footprint])
        # what the loader keeps clear: the disc the robot sweeps turning at its start and
        # at the station
        turn = mission.platform.turning_radius
        station = mission.airport.station
        self.spots = unary_union(
            [Point(start).buffer(turn), Point(station.x, station.y).buffer(turn)]
        )
        statics = [obstacle_geometry(o) for o in scenario.obstacles]
        statics += [sweep_geometry(o) for o in scenario.obstacles if isinstance(o, PathMover)]
        self.base = unary_union(statics) if statics else None
        for geom in (self.lines, self.vertices, self.footprint, self.spots):
            shapely.prepare(geom)
        xs = [p[0] for p in self.points]
        ys = [p[1] for p in self.points]
        self.bounds = (min(xs), min(ys), max(xs), max(ys))

    def route_distance(self, geom: BaseGeometry) -> float:
        """Distance from ``geom`` to the nearest leg (at either parking pose)."""
        return float(self.lines.distance(geom))

    def point_distance(self, geom: BaseGeometry) -> float:
        """Distance from ``geom`` to the nearest route point (checkpoints, waypoints, ...)."""
        return float(self.vertices.distance(geom))

    def forbidden(self, geom: BaseGeometry) -> bool:
        """Whether ``geom`` enters a forbidden zone, the aircraft footprint, the robot's
        start or station discs, or a base scenario obstacle."""
        if self.zones is not None and self.zones.intersects(geom):
            return True
        if self.base is not None and self.base.intersects(geom):
            return True
        return bool(self.footprint.intersects(geom) or self.spots.intersects(geom))


def passable(leg: Leg, blockers: list[BaseGeometry], corridor: float, gap: float) -> bool:
    """Whether the robot can drive ``leg`` between ``blockers`` with a passage at least
    ``gap`` wide inside a corridor of ``corridor`` metres each side of it (the free space
    eroded by half the gap still joins the leg's two ends)."""
    lane = LineString([leg.a, leg.b]).buffer(corridor, cap_style="square")
    free = lane.difference(unary_union(blockers)) if blockers else lane
    eroded = free.buffer(-gap / 2.0)
    ends = Point(leg.a), Point(leg.b)
    parts = getattr(eroded, "geoms", [eroded])
    return any(part.covers(ends[0]) and part.covers(ends[1]) for part in parts)


def chaser_geometry(chaser: Chaser) -> BaseGeometry:
    return Point(*chaser.start).buffer(chaser.body.bounding_radius)
