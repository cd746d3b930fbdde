"""Forbidden zones as virtual obstacles (seed lines 3596-3620): behaviours.laws.zones."""

import math

import numpy as np
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st
from shapely.geometry import Point
from shapely.geometry import Polygon as ShapelyPolygon

from behaviours.laws.zones import VirtualWalls
from executive.core.frames import AircraftPlacement, Pose2
from executive.core.geometry import to_shapely
from executive.core.loader import load_mission
from executive.core.model import Frame
from tests.conftest import SHIPPED_MISSIONS

MISSION = load_mission(SHIPPED_MISSIONS["a320"])
PLATFORM = MISSION.platform
NOMINAL = MISSION.nominal_placement()


def zone_rings(placement: AircraftPlacement) -> dict[str, shapely.LinearRing]:
    rings = {}
    for zone in MISSION.airport.zones:
        geom = to_shapely(zone.shape)
        if zone.frame is Frame.AIRCRAFT:
            geom = ShapelyPolygon(placement.to_airport_xy(geom.exterior.coords))
        rings[zone.id] = geom.exterior
    return rings


def walls() -> VirtualWalls:
    return VirtualWalls(MISSION.airport.zones, PLATFORM.length, PLATFORM.width, radius=6.0)


@settings(max_examples=40, deadline=None)
@given(
    x=st.floats(-30.0, 30.0),
    y=st.floats(-45.0, 10.0),
    heading=st.floats(-math.pi, math.pi),
    dx=st.floats(-1.5, 1.5),
    dh=st.floats(-0.17, 0.17),
)
def test_virtual_points_lie_on_zone_edges_within_range(x, y, heading, dx, dh):
    placement = AircraftPlacement(NOMINAL.x + dx, NOMINAL.y, NOMINAL.heading + dh)
    pose = Pose2(x, y, heading)
    points, found = walls().sense(pose, placement)
    rings = zone_rings(placement)
    union = shapely.union_all(list(rings.values()))
    if len(points):
        in_a = pose.apply(points)
        d_edge = shapely.distance(union, shapely.points(in_a))
        assert np.all(d_edge < 1e-6)  # every virtual return is on a zone edge
        assert np.all(np.hypot(*(in_a - pose.position).T) <= 6.0 + 1e-9)
    # every zone whose edge comes within 5.9 m of the robot's centre is reported, and
    # none beyond the 6 m radius
    reported = {w.zone for w in found}
    assert {z for z, ring in rings.items() if ring.distance(Point(x, y)) < 5.9} <= reported
    assert reported <= {z for z, ring in rings.items() if ring.distance(Point(x, y)) <= 6.0}
    for w in found:
        nearest_a = pose.apply(np.array(w.nearest))
        assert rings[w.zone].distance(Point(*nearest_a)) < 1e-6
        assert w.clearance >= 0.0


def test_an_aircraft_frame_zone_moves_with_the_placement():
    """The refuelling zone is given in F: moving the aircraft 1 m moves its wall 1 m."""
    zone = next(z for z in MISSION.airport.zones if z.id == "refuel-rh")
    ring = to_shapely(zone.shape).exterior
    edge_f = np.array(ring.coords[0])
    pose_a = Pose2(*NOMINAL.to_airport_xy(edge_f + np.array([0.0, 0.0])), 0.0)
    vw = VirtualWalls([zone], PLATFORM.length, PLATFORM.width, radius=3.0)
    _, before = vw.sense(pose_a, NOMINAL)
    assert before and before[0].clearance == 0.0  # the robot stands on the corner
    moved = AircraftPlacement(NOMINAL.x + 1.0, NOMINAL.y, NOMINAL.heading)
    pts, after = vw.sense(pose_a, moved)
    assert after
    corner = pose_a.inverse().apply(moved.to_airport_xy(edge_f))
    assert np.min(np.hypot(*(pts - corner).T)) < 0.11  # sampled every 0.1 m
    assert after[0].clearance > 0.0


def test_far_from_every_zone_there_is_nothing():
    points, found = walls().sense(Pose2(-60.0, 10.0, 0.0), NOMINAL)
    assert len(points) == 0 and found == []
