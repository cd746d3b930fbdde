"""The dynamic-window baseline of the avoidance campaign (benchmarks/dwa.py): the law only.

``benchmarks/`` is not a package (its scripts run as ``python benchmarks/x.py``), so the
module is loaded from its path with importlib and registered under a private name.
"""

import importlib.util
import math
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from shapely.geometry import Point
from shapely.geometry import Polygon as ShapelyPolygon

from behaviours.laws.spiral import SpiralObstacle
from behaviours.laws.velocity_obstacles import MovingDisc
from executive.core.frames import Pose2
from executive.core.model import Platform
from tests.conftest import REPO


def _load_dwa():
    name = "walkaround_benchmarks_dwa"
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, REPO / "benchmarks" / "dwa.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses look their module up while building
    spec.loader.exec_module(module)
    return module


dwa = _load_dwa()
PARAMS = dwa.DwaParams()
START = Pose2(0.0, 0.0, 0.0)


def footprint_clearance(pose: Pose2, disc: MovingDisc, t: float, params) -> float:
    """Independent check with shapely: the robot's rectangle to the disc at time t."""
    hl, hw = params.length / 2, params.width / 2
    foot = ShapelyPolygon(pose.apply([(hl, hw), (-hl, hw), (-hl, -hw), (hl, -hw)]))
    x = disc.position[0] + disc.velocity[0] * t
    y = disc.position[1] + disc.velocity[1] * t
    centre = Point(x, y)
    if foot.contains(centre):
        return -disc.radius
    return foot.distance(centre) - disc.radius


def arc_min_clearance(v: float, omega: float, disc: MovingDisc, params, substeps: int = 5):
    """Smallest clearance of the constant (v, omega) arc over the horizon, on a grid
    ``substeps`` times finer than the law's, integrated exactly (circular arc)."""
    n = round(params.horizon / params.step) * substeps
    best = math.inf
    for k in range(n + 1):
        t = params.horizon * k / n
        th = omega * t
        if abs(omega) < 1e-9:
            x, y = v * t, 0.0
        else:
            x, y = v / omega * math.sin(th), v / omega * (1 - math.cos(th))
        best = min(best, footprint_clearance(Pose2(x, y, th), disc, t, params))
    return best


def test_nothing_around_it_drives_straight_at_the_target():
    v, omega = dwa.dwa_command(START, (PARAMS.v_max, 0.0), (10.0, 0.0), [], PARAMS)
    assert v == pytest.approx(PARAMS.v_max)
    assert omega == pytest.approx(0.0, abs=1e-9)
    # from rest: as fast as one window of acceleration allows, still straight
    v, omega = dwa.dwa_command(START, (0.0, 0.0), (10.0, 0.0), [], PARAMS)
    assert v == pytest.approx(PARAMS.max_acceleration * PARAMS.window)
    assert omega == pytest.approx(0.0, abs=1e-9)


def test_it_turns_towards_a_target_on_its_left_and_right():
    _, left = dwa.dwa_command(START, (0.3, 0.0), (2.0, 5.0), [], PARAMS)
    _, right = dwa.dwa_command(START, (0.3, 0.0), (2.0, -5.0), [], PARAMS)
    assert left > 0.2 and right < -0.2


def test_it_steers_round_a_disc_on_the_way():
    disc = MovingDisc((3.0, 0.1), (0.0, 0.0), 0.5)
    choice = dwa.dwa_choose(START, (0.6, 0.0), (10.0, 0.0), [disc], PARAMS)
    assert choice.mode == "free"
    assert abs(choice.omega) > 0.1  # away from the straight line into the disc
    assert arc_min_clearance(choice.v, choice.omega, disc, PARAMS) >= PARAMS.margin - 0.05


discs_ahead = st.builds(
    lambda x, y, r: MovingDisc((x, y), (0.0, 0.0), r),
    st.floats(0.5, 5.0),
    st.floats(-2.5, 2.5),
    st.floats(0.05, 1.0),
)


@settings(max_examples=60, deadline=None)
@given(disc=discs_ahead, v0=st.floats(0.0, 0.6), w0=st.floats(-1.0, 1.0))
def test_never_picks_a_velocity_that_collides_with_a_static_disc_within_the_horizon(disc, v0, w0):
    if footprint_clearance(START, disc, 0.0, PARAMS) <= PARAMS.margin:
        return  # already inside the margin: not the case under test
    choice = dwa.dwa_choose(START, (v0, w0), (12.0, 0.0), [disc], PARAMS)
    if choice.n_free:
        # a collision-free arc exists: the chosen one is collision-free, on a finer grid
        # and against an independent footprint model (5 cm: one law step at 0.6 m/s)
        assert choice.mode == "free"
        assert arc_min_clearance(choice.v, choice.omega, disc, PARAMS) >= PARAMS.margin - 0.05
    else:
        # every arc in the window meets the disc: the robot can still stop short of it
        assert choice.mode in ("admissible", "brake")
        lowest = max(PARAMS.v_min, v0 - PARAMS.max_acceleration * PARAMS.window)
        if choice.mode == "brake":
            assert choice.v == pytest.approx(lowest)
        else:
            travelled = choice.v * choice.contact
            assert choice.v**2 / (2 * PARAMS.max_acceleration) <= travelled + 1e-9


@settings(max_examples=40, deadline=None)
@given(disc=discs_ahead, tx=st.floats(-10.0, 12.0), ty=st.floats(-10.0, 10.0))
def test_standing_still_there_is_always_a_collision_free_choice(disc, tx, ty):
    if footprint_clearance(START, disc, 0.0, PARAMS) <= PARAMS.margin:
        return
    choice = dwa.dwa_choose(START, (0.0, 0.0), (tx, ty), [disc], PARAMS)
    assert choice.mode == "free"  # (0, 0) is in the window (odd grid) and never moves
    assert arc_min_clearance(choice.v, choice.omega, disc, PARAMS) >= PARAMS.margin - 0.05


@settings(max_examples=60, deadline=None)
@given(
    v0=st.floats(-0.3, 1.0),
    w0=st.floats(-1.5, 1.5),
    x=st.floats(1.0, 6.0),
    y=st.floats(-3.0, 3.0),
    speed=st.floats(-1.2, 1.2),
)
def test_stays_within_the_dynamic_window_and_the_limits(v0, w0, x, y, speed):
    mover = MovingDisc((x, y), (speed, -speed / 2), 0.4)
    p = PARAMS
    v, omega = dwa.dwa_command(START, (v0, w0), (12.0, 1.0), [mover], p)
    assert p.v_min - 1e-12 <= v <= p.v_max + 1e-12
    assert abs(omega) <= p.omega_max + 1e-12
    dv, dw = p.max_acceleration * p.window, p.max_angular_acceleration * p.window
    if p.v_min <= v0 <= p.v_max:
        assert abs(v - v0) <= dv + 1e-9
    if abs(w0) <= p.omega_max:
        assert abs(omega - w0) <= dw + 1e-9
    vs, ws = dwa.candidates((v0, w0), p)
    assert vs.min() - 1e-12 <= v <= vs.max() + 1e-12
    assert ws.min() - 1e-12 <= omega <= ws.max() + 1e-12


def test_params_are_clipped_to_the_platform():
    platform = Platform(
        length=1.2,
        width=0.8,
        max_speed=0.5,
        max_angular_speed=0.7,
        max_acceleration=0.5,
        max_angular_acceleration=1.0,
        max_jerk=5.0,
        cameras={},
        lasers={},
    )
    p = dwa.DwaParams(v_max=0.6, omega_max=1.0).within(platform)
    assert (p.v_max, p.omega_max, p.max_acceleration, p.max_angular_acceleration) == (
        0.5,
        0.7,
        0.5,
        1.0,
    )
    assert (p.length, p.width) == (1.2, 0.8)


@settings(max_examples=40, deadline=None)
@given(
    x=st.floats(-4.0, 4.0),
    y=st.floats(-4.0, 4.0),
    th=st.floats(-math.pi, math.pi),
    r=st.floats(0.05, 1.0),
)
def test_footprint_clearance_matches_shapely(x, y, th, r):
    disc = MovingDisc((x, y), (0.0, 0.0), r)
    pose = Pose2(0.3, -0.2, th)
    poses = np.array([[[pose.x, pose.y, pose.theta]]])
    foot = dwa.arc_clearances(poses, [disc], PARAMS).footprint
    expected = footprint_clearance(pose, disc, 0.0, PARAMS)
    if expected == -r:  # centre inside the rectangle: the law goes deeper, by how far in
        assert foot[0, 0] <= -r
    else:
        assert foot[0, 0] == pytest.approx(expected, abs=1e-9)


def test_a_line_track_becomes_a_row_of_small_discs_along_it():
    wall = SpiralObstacle((2.0, 0.0), (0.0, 0.0), 1.0, (2.0, -1.0, 2.0, 1.0))
    discs = dwa.obstacle_discs(wall)
    ys = sorted(d.position[1] for d in discs)
    assert ys[0] == pytest.approx(-1.0) and ys[-1] == pytest.approx(1.0)
    assert max(np.diff(ys)) <= dwa.LINE_DISC_SPACING + 1e-9
    assert all(d.radius == dwa.LINE_DISC_RADIUS and d.position[0] == 2.0 for d in discs)
    circle = SpiralObstacle((5.0, 1.0), (0.05, 0.0), 0.4, (5.0, 1.0, 0.4))
    (disc,) = dwa.obstacle_discs(circle)
    assert disc.velocity == (0.0, 0.0)  # slower than static_speed: tracker noise
    assert disc.radius == pytest.approx(0.4)
