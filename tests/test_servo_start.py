"""A servo start the robot cannot turn at slides towards its checkpoint (issue 16: the A320
busy apron's CP10 beside the fuel truck): the law (behaviours/laws/servo_start.py), the
behaviour that moves the goal (:class:`SlideServoStart`), and the compiled tree."""

from __future__ import annotations

import math

import numpy as np
import py_trees
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from behaviours.controllers.servo import ServoSession, ServoStartGoal, SlideServoStart
from behaviours.goals import Goal
from behaviours.keys import OBSTACLES, POSE
from behaviours.laws.obstacles import closest_obstacle
from behaviours.laws.servo_start import (
    SERVO_START_MARGIN,
    SHORTEST_RUN,
    SLIDE_STEP,
    candidate_distances,
    start_distance,
)
from executive.compiler import CompileOptions, compile_mission
from executive.core.frames import Pose2
from executive.core.loader import load_mission
from executive.core.model import Frame
from executive.core.records import Obstacles, PoseEstimate, TrackedObstacle
from tests.conftest import MISSIONS, blackboard_writer

S = py_trees.common.Status


# -- the law --------------------------------------------------------------------------------------
def test_candidates_run_from_the_start_to_the_shortest_run():
    d = candidate_distances(1.0)
    assert d[0] == 1.0 and d[-1] == pytest.approx(SHORTEST_RUN)
    assert np.allclose(np.diff(d), -SLIDE_STEP)
    assert list(candidate_distances(0.3, 0.5)) == [0.3]  # already shorter: stays
    assert list(candidate_distances(0.0)) == [0.0]  # on the checkpoint


def test_a_start_slides_along_the_heading_line_until_the_robot_can_turn_there():
    """The checkpoint at the origin facing +x, so its start is on the -x axis; a wall
    across the line 2.5 m behind the checkpoint (as the truck's flank behind CP10)."""
    need = math.hypot(1.4, 1.0) / 2 + 0.6 + SERVO_START_MARGIN  # turning radius
    wall = np.column_stack((np.full(21, -2.5), np.linspace(-1.0, 1.0, 21)))
    distance, gap = start_distance(wall, (0.0, 0.0, 0.0), candidate_distances(1.0), need)
    assert gap >= need and 2.5 - distance == pytest.approx(gap)
    assert 2.5 - (distance + SLIDE_STEP) < need  # the next longer one is not clear
    # nothing seen: the compiler's start; heading the other way: the wall is ahead, far
    assert start_distance(np.zeros((0, 2)), (0.0, 0.0, 0.0), [1.0, 0.5], need) == (1.0, math.inf)
    assert start_distance(wall, (-6.0, 0.0, math.pi), candidate_distances(1.0), need)[0] == 1.0
    # nothing clear anywhere: the start furthest from the returns, when it gains
    tight = np.array([[0.05, 0.0], [-1.8, 0.0]])
    distance, gap = start_distance(tight, (0.0, 0.0, 0.0), candidate_distances(1.0), need)
    assert distance == pytest.approx(0.9) and gap == pytest.approx(0.9)  # 0.8 at 1.0
    flat = np.column_stack((np.linspace(-2.0, 1.0, 31), np.full(31, 0.8)))  # 0.8 all along
    assert start_distance(flat, (0.0, 0.0, 0.0), candidate_distances(1.0), need)[0] == 1.0


@settings(max_examples=200, deadline=None)
@given(
    st.lists(st.tuples(st.floats(-4.0, 2.0), st.floats(-3.0, 3.0)), min_size=1, max_size=20),
    st.floats(-math.pi, math.pi),
)
def test_property_the_start_is_the_longest_run_the_robot_can_turn_at(returns, heading):
    """Whatever the returns: when some candidate start clears them by ``need``, the one
    chosen does, and no longer one does; otherwise it is the furthest from them, or the
    longest when that gains less than the margin."""
    pts = np.array(returns)
    need = 1.56
    distances = candidate_distances(1.0)
    distance, gap = start_distance(pts, (0.0, 0.0, heading), distances, need)
    centres = -np.outer(distances, [math.cos(heading), math.sin(heading)])
    gaps = np.hypot(*(pts[None, :, :] - centres[:, None, :]).transpose(2, 0, 1)).min(axis=1)
    k = int(np.flatnonzero(distances == distance)[0])
    assert gap == pytest.approx(gaps[k])
    if (gaps >= need).any():
        assert gaps[k] >= need and not (gaps[:k] >= need).any()
    elif gaps.max() >= gaps[0] + SERVO_START_MARGIN:
        assert gaps[k] == gaps.max()
    else:
        assert k == 0


# -- the behaviour --------------------------------------------------------------------------------
@pytest.fixture()
def lab_cp2():
    mission = load_mission(MISSIONS / "lab" / "visual-servoing.xml")
    cp = next(c for c in mission.checkpoints if c.id == "CP2")
    target = mission.aircraft.features[cp.target]
    session = ServoSession(
        cp.id, target, cp.pose, mission.platform, mission.aircraft.origin_height, "pbvs"
    )
    return mission, cp, session


def _estimate(mission, pose_a: Pose2, t: float) -> PoseEstimate:
    pl = mission.nominal_placement()
    return PoseEstimate(t, pose_a, np.eye(3) * 1e-4, pl.pose_to_aircraft(pose_a), 1.0)


def _seen(t: float, robot: Pose2, world: np.ndarray, tracks=()) -> Obstacles:
    points = robot.inverse().apply(world)
    r_c, bearing = closest_obstacle(points, 1.4, 1.0)
    return Obstacles(t, r_c, bearing, points, tuple(tracks))


def _cone(centre: tuple[float, float], radius: float = 0.25, n: int = 24) -> np.ndarray:
    a = np.linspace(0.0, 2.0 * math.pi, n, endpoint=False)
    return np.column_stack((centre[0] + radius * np.cos(a), centre[1] + radius * np.sin(a)))


@pytest.mark.usefixtures("fresh_blackboard")
def test_slide_servo_start_moves_the_goal_forwards_only_and_not_for_a_mover(lab_cp2):
    """Lab CP2 (its start 1 m behind it: A (3.5, -4.0), facing +y) with a cone 0.64 m
    behind the footprint standing there (its near side 2.34 - s from a start s m short of
    CP2, 1.56 m needed to turn): the goal slides to 0.75 m and the servo's approach line
    with it; the cone gone, it stays; a walker there moves nothing."""
    mission, cp, session = lab_cp2
    placement = mission.nominal_placement()
    slide = SlideServoStart(
        session, Goal(cp.pose, Frame.AIRCRAFT, placement), mission.platform, 0.6, "slide"
    )
    goal = ServoStartGoal(session.start_f(), Frame.AIRCRAFT, placement, session)
    robot = Pose2(2.0, -6.0, 0.5)
    bb = blackboard_writer(OBSTACLES, POSE)
    est = _estimate(mission, robot, 0.0)
    before = goal.in_airport(est)
    assert (before.x, before.y) == pytest.approx((3.5, -4.0))
    # a walker (a tracked mover) standing there: not a reason to slide
    seen = _seen(0.0, robot, _cone((3.5, -5.59)))
    at = robot.inverse().apply(np.array([[3.5, -5.59]]))[0]
    walker = TrackedObstacle(1, "circle", tuple(at), (0.5, 0.0), np.eye(4), 0.25, 1.0, 3.0)
    passing = Obstacles(0.0, seen.closest, seen.bearing, seen.points, (walker,))
    bb.set(OBSTACLES.name, passing, overwrite=True)
    bb.set(POSE.name, est, overwrite=True)
    slide.tick_once()
    assert slide.status == S.SUCCESS and session.start_distance == 1.0
    # the cone, standing: slid forwards to the longest start it can be turned at
    bb.set(OBSTACLES.name, seen, overwrite=True)
    slide.tick_once()
    assert session.start_distance == pytest.approx(0.75)
    assert session.params.line_from == session.start_distance
    after = goal.in_airport(est)
    assert (after.x, after.y, after.theta) == pytest.approx((3.5, -3.75, before.theta))
    assert "from 1.00 m to 0.75 m" in session.start_note
    assert session.status().start == pytest.approx(0.75)
    # the cone taken away: the start does not slide back (the goal settles)
    bb.set(OBSTACLES.name, _seen(0.1, robot, _cone((30.0, 30.0))), overwrite=True)
    slide.tick_once()
    assert session.start_distance == pytest.approx(0.75)


def test_the_compiled_tree_slides_each_servo_start_before_its_trap():
    lab = load_mission(MISSIONS / "lab" / "visual-servoing.xml")
    compiled = compile_mission(lab, CompileOptions(servo=True))
    navigations = [
        n
        for n in compiled.root.iterate()
        if n.name.startswith("navigate ") and n.name.endswith("servo start")
    ]
    assert [n.name for n in navigations] == [f"navigate CP{k} servo start" for k in (1, 2, 3)]
    for nav in navigations:
        first, trap = nav.children[0], nav.children[1]
        assert isinstance(first, SlideServoStart)
        assert trap.name.startswith(("not trapped", "trapped"))
        assert first.session.checkpoint == nav.name.split()[1]
