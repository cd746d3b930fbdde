"""The free space of a draft mission, in the aircraft frame F: where the robot may stop
and where it may drive.

The validator's rules (:func:`executive.core.checks.clearance_problems` and
:func:`executive.core.checks.leg_problems`) written as regions, so that the planner can
test thousands of poses and legs at once:

* a *stop* (checkpoint, via point, handover) keeps half the robot's diagonal (it turns on
  the spot) plus r_ES from the aircraft footprint, and half its diagonal plus the geofence
  margin from every forbidden zone;
* a *leg* keeps half the robot's width plus r_ES from the footprint, and half its width
  plus the geofence margin from every zone.

The draft keeps more than the validator's bounds, so that the robot drives it at speed:
a leg keeps the half diagonal (a robot off its heading sweeps more than its half width),
a stop adds the position tolerance (:data:`STOP_SLACK`), and both keep
:data:`ZONE_COMFORT` beyond the geofence margin from the zones (the safety layer slows
any motion towards a zone that could not stop in the margin). The planner still checks
every pose and leg it writes with the validator's own functions.
Zones given in the airport frame A are mapped into F with the nominal parking pose (the
airport <-> aircraft map is rigid, so distances are the same in both frames).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import shapely
from shapely.geometry import Point
from shapely.geometry import Polygon as ShapelyPolygon
from shapely.geometry.base import BaseGeometry
from shapely.ops import unary_union

from executive.core.frames import AircraftPlacement, FloatArray
from executive.core.geometry import to_shapely
from executive.core.model import Circle, Frame, Mission, Shape

STOP_SLACK = 0.20
"""Metres a planned stop keeps beyond the validator's stop clearance: the position
tolerance the robot stops within (0.15 m in the shipped missions) and rounding."""

LEG_SLACK = 0.05
"""Metres a planned leg keeps beyond the clearance it needs at any heading."""

ZONE_COMFORT = 0.5
"""Metres the draft's stops and legs keep from forbidden zones beyond the geofence margin.
The safety layer (:mod:`executive.safety`) lets a motion towards a zone through only
while its stopping distance fits in the clearance left beyond the margin, so a route that
grazes the margin crawls (a planned B737 leg at the validator's bound made no progress
for 120 s); 0.5 m is about the stopping distance from cruise speed (0.1 s of reaction at
1 m/s plus 1 / (2 x 1 m/s^2))."""

VERTEX_SLACK = 0.10
"""Metres the corners of the visibility graph stand outside the stop region."""

_CORNER_SEGMENTS = 2
"""Segments per quarter circle of the polygons drawn around circles (an octagon)."""


@dataclass(frozen=True)
class FreeSpace:
    """The regions the validator forbids, in F, and the named shapes behind them.

    ``no_stop`` holds every point closer than a stop's clearance (plus slack) to the
    footprint or a zone; ``no_leg`` every point closer than a leg's clearance. ``corners``
    are the vertices of a polygon that contains ``no_stop`` (circles drawn round them,
    polygons grown with mitred corners), a little outside it: the nodes from which
    shortest paths round the obstacles are built (:mod:`executive.planning.tour`).
    """

    mission: Mission
    placement: AircraftPlacement
    footprint: tuple[tuple[str, BaseGeometry], ...]
    zones: tuple[tuple[str, BaseGeometry], ...]
    no_stop: BaseGeometry
    no_leg: BaseGeometry
    corners: FloatArray

    @property
    def stop_clearance_footprint(self) -> float:
        """The validator's stop clearance from the footprint (m)."""
        return self.mission.platform.turning_radius + self.mission.safety.r_es

    @property
    def stop_clearance_zones(self) -> float:
        """The validator's stop clearance from the zones (m)."""
        return self.mission.platform.turning_radius + self.mission.safety.geofence_margin

    def can_stop(self, xy_f: FloatArray) -> np.ndarray:
        """Which positions (N, 2) in F are clear for a stop."""
        xy = np.atleast_2d(np.asarray(xy_f, dtype=float))
        return ~shapely.intersects_xy(self.no_stop, xy[:, 0], xy[:, 1])

    def can_drive(self, a_f: FloatArray, b_f: FloatArray) -> np.ndarray:
        """Which straight legs from ``a_f`` (N, 2) to ``b_f`` (N, 2) are clear."""
        a = np.atleast_2d(np.asarray(a_f, dtype=float))
        b = np.atleast_2d(np.asarray(b_f, dtype=float))
        lines = shapely.linestrings(np.stack([a, b], axis=1))
        return ~shapely.intersects(lines, self.no_leg)


def shape_in_aircraft(shape: Shape, frame: Frame, placement: AircraftPlacement) -> BaseGeometry:
    """A footprint or zone shape as a shapely geometry in F."""
    geom = to_shapely(shape)
    if frame is Frame.AIRCRAFT:
        return geom
    return ShapelyPolygon(placement.to_aircraft_xy(np.asarray(geom.exterior.coords)))


def _grown(shape: Shape, geom: BaseGeometry, distance: float) -> BaseGeometry:
    """A polygon that contains every point within ``distance`` of the shape, with few
    vertices: an octagon round a circle (its edges touch the grown circle), mitred
    corners round a polygon."""
    if isinstance(shape, Circle) and distance >= 0.0:
        radius = (shape.radius + distance) / math.cos(math.pi / (4 * _CORNER_SEGMENTS))
        return Point(shape.cx, shape.cy).buffer(radius, quad_segs=_CORNER_SEGMENTS)
    return geom.buffer(distance, join_style="mitre", mitre_limit=3.0)


def free_space(mission: Mission) -> FreeSpace:
    """The free space of ``mission``'s robot round its aircraft, at the nominal parking."""
    placement = mission.nominal_placement()
    platform, safety = mission.platform, mission.safety
    turn, half = platform.turning_radius, platform.half_width
    footprint = [(s.id, s, to_shapely(s)) for s in mission.aircraft.footprint]
    zones = []
    for zone in mission.airport.zones:
        geom = shape_in_aircraft(zone.shape, zone.frame, placement)
        shape = zone.shape if zone.frame is Frame.AIRCRAFT else _as_polygon(zone.id, geom)
        zones.append((zone.id, shape, geom))
    # a leg is driven at some heading error: its clearance is the half diagonal's, not
    # the half width's the validator asks for
    stop_fp = turn + safety.r_es + STOP_SLACK
    stop_zone = turn + safety.geofence_margin + ZONE_COMFORT + STOP_SLACK
    leg_fp = max(half, turn) + safety.r_es + LEG_SLACK
    leg_zone = max(half, turn) + safety.geofence_margin + ZONE_COMFORT + LEG_SLACK
    no_stop = unary_union(
        [g.buffer(stop_fp) for _, _, g in footprint] + [g.buffer(stop_zone) for _, _, g in zones]
    )
    no_leg = unary_union(
        [g.buffer(leg_fp) for _, _, g in footprint] + [g.buffer(leg_zone) for _, _, g in zones]
    )
    hull = unary_union(
        [_grown(s, g, stop_fp + VERTEX_SLACK) for _, s, g in footprint]
        + [_grown(s, g, stop_zone + VERTEX_SLACK) for _, s, g in zones]
    )
    corners = _vertices(hull)
    if len(corners):
        corners = corners[~shapely.intersects_xy(no_stop, corners[:, 0], corners[:, 1])]
    shapely.prepare(no_stop)
    shapely.prepare(no_leg)
    return FreeSpace(
        mission=mission,
        placement=placement,
        footprint=tuple((i, g) for i, _, g in footprint),
        zones=tuple((i, g) for i, _, g in zones),
        no_stop=no_stop,
        no_leg=no_leg,
        corners=corners,
    )


def _as_polygon(shape_id: str, geom: BaseGeometry) -> Shape:
    from executive.core.model import Polygon

    return Polygon(shape_id, tuple((float(x), float(y)) for x, y in geom.exterior.coords[:-1]))


def _vertices(geom: BaseGeometry) -> FloatArray:
    """Every ring vertex of a (multi)polygon, once."""
    rings = []
    for poly in getattr(geom, "geoms", [geom]):
        if poly.is_empty:
            continue
        rings.append(np.asarray(poly.exterior.coords)[:-1])
        rings += [np.asarray(r.coords)[:-1] for r in poly.interiors]
    if not rings:
        return np.zeros((0, 2))
    return np.unique(np.round(np.concatenate(rings), 6), axis=0)
