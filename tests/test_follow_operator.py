"""Collaborative mode, follow the operator (issue 15; seed 000 lines 1379-1452, Table 2.3,
figure 2.21): the follower law, its tree branch, and the end-to-end runs in sim2d.

Distances are *gaps*: from the robot's footprint to the person's edge, the quantity r_ES
is measured on (behaviours/laws/follow.py). The end-to-end runs measure the straight gap on
ground truth (the true robot pose and the true walker position): the acceptance asks
for the distance kept, and the straight gap is what r_ES and a person standing beside
the robot see; the law regulates it with half the trail's detour added, which differs
only round corners (the measured error includes the corners).
"""

import dataclasses
import math
from functools import partial

import numpy as np
import py_trees
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import behaviours.controllers.follow as follow_controllers
from behaviours.controllers.follow import (
    AskOperator,
    FollowOperator,
    FollowRequested,
    FollowSession,
    OperatorLost,
)
from behaviours.controllers.joystick import JoystickActive, JoystickControl
from behaviours.keys import QUESTION
from behaviours.laws.follow import (
    FOLLOWING,
    LOST,
    SEARCHING,
    UNSEEN,
    FollowParams,
    OperatorFollower,
    PersonTrack,
    Trail,
    braking_speed,
    choose_person,
    follow_speed,
    footprint_gap,
    pursuit_command,
    reassociate,
    yield_speed,
)
from behaviours.laws.obstacles import footprint_distances
from behaviours.laws.velocity_obstacles import MovingDisc, time_to_collision, velocity_vector
from executive.compiler import GuardedBranch, GuardSelector, compile_mission
from executive.core.frames import Pose2, wrap_angle
from executive.core.loader import load_mission
from executive.core.records import FollowRequest, OperatorRequests
from executive.dryrun import dry_run
from executive.operator import OperatorState
from sim2d.robot import SimRobot
from tests.conftest import MISSIONS
from tests.sim2d_helpers import make_scenario

P = FollowParams()


def person(ident: int, x: float, y: float, kind: str = "circle", size: float = 0.3, v=(0.0, 0.0)):
    return PersonTrack(ident, kind, (x, y), v, size)


# -- choosing the person ------------------------------------------------------------------------
def test_the_closest_most_circular_track_near_the_tap_is_chosen():
    tracks = [
        person(1, 1.0, 0.0, kind="blob"),  # closest, not round
        person(2, 1.3, 0.0),  # a little further, round: chosen (bonus 0.5 m)
        person(3, 0.2, 0.0, kind="line", size=0.2),  # a wall: never
        person(4, 0.1, 0.1, size=1.5),  # too big for a person
    ]
    assert choose_person(tracks, (0.0, 0.0), P).ident == 2
    assert choose_person(tracks[:1], (0.0, 0.0), P).ident == 1  # a blob if nothing else
    assert choose_person(tracks, (10.0, 0.0), P) is None  # nothing within pick_radius


def test_reassociation_takes_a_new_id_near_the_prediction_only():
    last = person(7, 0.0, 0.0, v=(1.0, 0.0))
    near = person(9, 0.9, 0.1)  # where the person walked to in 1 s
    far = person(10, 5.0, 0.0)
    assert reassociate([near, far], last, 1.0, P).ident == 9
    assert reassociate([far], last, 1.0, P) is None
    assert reassociate([near], last, 1.0, P, exclude=frozenset({9})) is None  # a neighbour


def _walk(follower: OperatorFollower, t0: float, t1: float, tracks_at) -> None:
    robot, t = Pose2(-3.0, 0.0, 0.0), t0
    while t <= t1 + 1e-9:
        follower.observe(t, robot, tracks_at(t))
        t += 0.025


def test_the_follower_keeps_the_person_through_an_id_change_and_loses_them_later():
    follower = OperatorFollower(P)
    follower.designate(0.0, (0.0, 0.0), 1.5)
    assert follower.state == SEARCHING
    # id 3 walks east at 1 m/s; at t = 2 s the tracker re-creates it as id 8
    _walk(follower, 0.0, 2.0, lambda t: [person(3, t, 0.0, v=(1, 0)), person(5, t, 4.0)])
    assert follower.state == FOLLOWING and follower.track_id == 3
    _walk(follower, 2.025, 3.0, lambda t: [person(8, t, 0.0, v=(1, 0)), person(5, t, 4.0)])
    assert follower.state == FOLLOWING and follower.track_id == 8
    assert [k for _, k, _ in follower.events] == ["acquired", "re-associated"]
    # then the person vanishes: unseen at first, lost after lost_after
    _walk(follower, 3.025, 3.5, lambda t: [person(5, t, 4.0)])
    assert follower.state == UNSEEN
    _walk(follower, 3.525, 4.2, lambda t: [person(5, t, 4.0)])
    assert follower.state == LOST and follower.track_id == 8
    assert "operator lost" in follower.reason and "designate again" in follower.reason
    # lost stays lost, even if someone turns up there: only a new designation restarts
    _walk(follower, 4.225, 5.0, lambda t: [person(11, 3.2, 0.0)])
    assert follower.state == LOST
    assert follower.command(Pose2(0, 0, 0)).v == 0.0
    follower.designate(5.0, (3.2, 0.0), 1.5)
    _walk(follower, 5.0, 5.1, lambda t: [person(11, 3.2, 0.0)])
    assert follower.state == FOLLOWING and follower.track_id == 11


def test_a_track_that_keeps_the_persons_id_but_cannot_be_them_is_not_followed():
    """A tracker may hand an occluded person's id to a vehicle's side next to them: a line
    (or anything out of the gate) with the person's id is the person unseen, not them."""
    follower = OperatorFollower(P)
    follower.designate(0.0, (0.0, 0.0), 1.5)
    _walk(follower, 0.0, 1.0, lambda t: [person(3, t, 0.0, v=(1, 0))])
    assert follower.state == FOLLOWING
    _walk(follower, 1.025, 1.5, lambda t: [person(3, 3.0, -2.5, kind="line", size=3.3)])
    assert follower.state == UNSEEN and follower.person.kind == "circle"
    assert [k for _, k, _ in follower.events] == ["acquired", "id taken"]
    _walk(follower, 1.525, 1.8, lambda t: [person(3, 9.0, 0.0, v=(1, 0))])  # 7 m on: no
    assert follower.state == UNSEEN
    _walk(follower, 1.825, 2.0, lambda t: [person(3, t, 0.0, v=(1, 0))])  # there: yes
    assert follower.state == FOLLOWING


def test_a_neighbours_id_swapped_onto_the_person_is_taken_back_but_a_neighbour_is_not():
    """The tracker swaps the walking person's id with a parked car's blob beside them: the
    car's old id, now where the person is heading, is the person again. A neighbour that
    stayed where it was never is."""
    follower = OperatorFollower(P)
    follower.designate(0.0, (0.0, 0.0), 1.5)
    car = person(5, 1.0, 2.7, kind="blob", size=0.5)
    _walk(follower, 0.0, 1.0, lambda t: [person(3, t, 0.0, v=(1, 0)), car])
    assert follower.state == FOLLOWING and follower.track_id == 3
    # the swap: id 3 on the car, id 5 on the person (1.3 m/s on from where they were)
    _walk(follower, 1.025, 1.2, lambda t: [person(3, 1.0, 2.7), person(5, t, 0.0, v=(1, 0))])
    assert follower.state == FOLLOWING and follower.track_id == 5
    assert [k for _, k, _ in follower.events] == ["acquired", "id taken", "re-associated"]
    # a neighbour walking beside the person, who vanishes: never taken for them
    follower = OperatorFollower(P)
    follower.designate(0.0, (0.0, 0.0), 1.5)
    _walk(follower, 0.0, 1.0, lambda t: [person(3, t, 0.0, v=(1, 0)), person(6, t, 1.2)])
    _walk(follower, 1.025, 2.2, lambda t: [person(6, t, 1.2, v=(1, 0))])
    assert follower.state == LOST


def test_nobody_at_the_designated_point_is_lost_after_the_acquisition_timeout():
    follower = OperatorFollower(P)
    follower.designate(0.0, (0.0, 0.0), 1.5)
    _walk(follower, 0.0, P.acquire_timeout + 0.1, lambda t: [person(1, 5.0, 5.0)])
    assert follower.state == LOST and "no person" in follower.reason


# -- the command: properties --------------------------------------------------------------------
def test_braking_speed_is_the_root_of_one_period_then_braking():
    for room in (0.05, 0.5, 2.0, 10.0):
        v = braking_speed(room, P.brake, P.period)
        assert v * P.period + v * v / (2 * P.brake) == pytest.approx(room)
    assert braking_speed(0.0, P.brake, P.period) == 0.0
    assert braking_speed(-1.0, P.brake, P.period) == 0.0


coord = st.floats(-8.0, 8.0, allow_nan=False)


@settings(max_examples=300, deadline=None)
@given(
    x=coord,
    y=coord,
    theta=st.floats(-math.pi, math.pi),
    vx=st.floats(-2.5, 2.5),
    vy=st.floats(-2.5, 2.5),
    distance=st.floats(0.0, 6.0),
    crumbs=st.lists(st.tuples(coord, coord), max_size=6),
)
def test_the_command_never_brings_the_robot_within_r_es_and_stays_within_limits(
    x, y, theta, vx, vy, distance, crumbs
):
    """Whatever the person does and wherever the trail goes: 0 <= v <= max_speed,
    |omega| <= max_omega, and one period at v then braking at ``brake`` stops the robot
    outside r_ES + margin of the person even if they stop dead."""
    follower = OperatorFollower(P)
    follower.designate(0.0, (x, y), distance)
    for c in crumbs:
        follower.trail.add(c)
    robot = Pose2(0.0, 0.0, theta)
    follower.observe(0.0, robot, [person(1, x, y, v=(vx, vy))])
    out = follower.command(robot)
    assert 0.0 <= out.v <= P.max_speed
    assert abs(out.omega) <= P.max_omega + 1e-12
    room = max(0.0, out.gap - P.r_es - P.margin)
    assert out.v * P.period + out.v**2 / (2 * P.brake) <= room + 1e-9


@settings(max_examples=200, deadline=None)
@given(
    gap=st.floats(-1.0, 10.0),
    distance=st.floats(P.r_es, 6.0),
    v_away=st.floats(0.0, 3.0),
    detour=st.floats(0.0, 5.0),
)
def test_follow_speed_bounds_and_stop_at_the_set_distance(gap, distance, v_away, detour):
    v = follow_speed(gap, distance, v_away, P, detour)
    assert 0.0 <= v <= P.max_speed
    if gap <= P.min_distance:
        assert v == 0.0
    if gap <= distance:  # a still person at (or inside) the set gap on a straight trail
        assert follow_speed(gap, distance, 0.0, P, 0.0) == 0.0


@settings(max_examples=200, deadline=None)
@given(
    theta=st.floats(-math.pi, math.pi),
    tx=coord,
    ty=coord,
    v=st.floats(0.0, 1.5),
)
def test_pure_pursuit_respects_the_turn_rate_and_never_reverses(theta, tx, ty, v):
    v_out, omega = pursuit_command(Pose2(0.0, 0.0, theta), (tx, ty), v, P)
    assert 0.0 <= v_out <= v + 1e-12
    assert abs(omega) <= P.max_omega + 1e-9


def _unicycle(pose: Pose2, v: float, omega: float, dt: float) -> Pose2:
    mid = pose.theta + 0.5 * omega * dt
    return Pose2(
        pose.x + v * dt * math.cos(mid),
        pose.y + v * dt * math.sin(mid),
        wrap_angle(pose.theta + omega * dt),
    )


def test_the_robot_stops_at_the_set_distance_behind_a_still_person():
    follower = OperatorFollower(P)
    follower.designate(0.0, (8.0, 1.0), 2.0)
    robot, dt, gaps = Pose2(0.0, 0.0, 0.0), P.period, []
    for k in range(int(30.0 / dt)):
        follower.observe(k * dt, robot, [person(4, 8.0, 1.0)])
        out = follower.command(robot)
        robot = _unicycle(robot, out.v, out.omega, dt)
        gaps.append(footprint_gap(robot, (8.0, 1.0), 0.3, P))
    assert min(gaps) >= 2.0 - 1e-6  # never closer than the set gap (so never within r_ES)
    assert gaps[-1] == pytest.approx(2.0, abs=0.02)
    assert out.v < 1e-3


def _distance_to_path(p: np.ndarray, path: np.ndarray) -> float:
    a, b = path[:-1], path[1:]
    ab = b - a
    s = np.clip(np.einsum("ij,ij->i", p - a, ab) / np.einsum("ij,ij->i", ab, ab), 0.0, 1.0)
    q = a + s[:, None] * ab
    return float(np.hypot(*(p - q).T).min())


def test_the_robot_follows_the_trail_round_a_corner_not_the_straight_line():
    """The person walks east then turns north round a parked vehicle: the robot keeps to
    the person's path (a straight chase would cut the corner through the vehicle)."""
    path = np.array([[2.5, 0.0], [10.0, 0.0], [10.0, 8.0]])
    legs = np.hypot(*np.diff(path, axis=0).T)
    follower = OperatorFollower(P)
    follower.designate(0.0, tuple(path[0]), 1.5)
    robot, dt, off, gaps = Pose2(0.0, 0.0, 0.0), P.period, [], []
    for k in range(int(24.0 / dt)):
        t = k * dt
        s = min(0.8 * t, legs.sum())
        leg = 0 if s <= legs[0] else 1
        u = (path[leg + 1] - path[leg]) / legs[leg]
        pos = path[leg] + u * (s - legs[:leg].sum())
        vel = tuple(0.8 * u) if s < legs.sum() else (0.0, 0.0)
        follower.observe(t, robot, [person(1, *pos, v=vel)])
        out = follower.command(robot)
        robot = _unicycle(robot, out.v, out.omega, dt)
        if robot.x >= path[0, 0]:  # on the trail (it starts at the person's first spot)
            off.append(_distance_to_path(np.array([[robot.x, robot.y]]), path))
        gaps.append(footprint_gap(robot, tuple(pos), 0.3, P))
    assert robot.y > 5.0  # it went round
    assert max(off) < 0.45, max(off)
    assert min(gaps) > P.r_es


def test_the_trail_drops_crumbs_behind_the_robot():
    trail = Trail(spacing=0.5)
    for x in np.arange(0.0, 10.0, 0.1):
        trail.add((float(x), 0.0))
    assert len(trail.crumbs) == 20
    trail.prune((4.2, 0.3), (10.0, 0.0), window=20.0)
    assert trail.crumbs[0][0] == pytest.approx(4.0)
    assert trail.pursuit_point((4.2, 0.3), (10.0, 0.0), 1.0) == pytest.approx((5.2, 0.0))


# -- the tree -----------------------------------------------------------------------------------
def test_the_collaborative_branch_follows_asks_or_holds():
    compiled = compile_mission(load_mission(MISSIONS / "track" / "straight-run.xml"))
    mode = next(n for n in compiled.root.iterate() if n.name == "mode")
    collaborative = mode.children[0]
    assert isinstance(collaborative, GuardedBranch)
    control = collaborative.children[1]
    assert isinstance(control, GuardSelector)
    kinds = [type(b.children[-1]) for b in control.children[:-1]]
    assert kinds == [JoystickControl, AskOperator, FollowOperator]  # a stick in hand first
    guards = [type(b.children[0]) for b in control.children[:-1]]
    assert guards == [JoystickActive, OperatorLost, FollowRequested]
    assert control.children[-1].name == "operator control"  # hold still by default


def test_an_abort_ends_the_follow_and_a_new_one_is_followed():
    """The operator's abort clears its follow request (the robot goes back to P); a follow
    asked for afterwards is the operator taking the robot again."""
    platform = load_mission(MISSIONS / "track" / "straight-run.xml").platform
    session = FollowSession(platform, 0.6, 0.02)
    state = OperatorState()
    state.apply("follow", {"x": 3.0, "y": 0.0, "distance": 2.0})
    session.observe(state(0.0), None, None)
    assert session.requested
    state.apply("abort")
    session.observe(state(0.1), None, None)
    assert not session.requested
    state.apply("follow", {"x": 3.0, "y": 0.0, "distance": 2.0})
    session.observe(state(0.2), None, None)
    assert session.requested


# -- yielding to a crossing (obstacle avoidance on the trail, Table 2.3) -------------------------
def test_a_crossing_walker_is_yielded_to_and_one_walking_away_is_not():
    robot = Pose2(0.0, 0.0, 0.0)
    # a walker 3 m ahead, 3 m to the right, walking north at 1 m/s: at 1 m/s the robot
    # would meet them where their paths cross in 3 s
    crossing = MovingDisc((3.0, -3.0), (0.0, 1.0), 0.3)
    v, omega = yield_speed(robot, 1.0, 0.0, [crossing], P)
    assert v < 1.0 and omega == 0.0
    radius = 0.5 * math.hypot(P.length, P.width) + P.r_es
    u = velocity_vector(robot.theta, v, omega, 0.5)
    assert v == 0.0 or time_to_collision(np.zeros(2), u, crossing, radius) >= P.yield_horizon
    away = MovingDisc((3.0, -3.0), (0.0, -1.0), 0.3)
    assert yield_speed(robot, 1.0, 0.2, [away], P) == (1.0, 0.2)
    assert yield_speed(robot, 1.0, 0.2, [], P) == (1.0, 0.2)


@settings(max_examples=200, deadline=None)
@given(
    st.floats(0.0, 1.5),
    st.floats(-1.0, 1.0),
    st.lists(
        st.tuples(st.floats(-8, 8), st.floats(-8, 8), st.floats(-2, 2), st.floats(-2, 2)),
        max_size=4,
    ),
)
def test_yielding_only_slows_keeps_the_arc_and_clears_the_horizon(v, omega, movers):
    """Never faster than asked, the same arc (omega / v kept), and either clear of every
    mover for the yield horizon or the latest contact there is."""
    discs = [MovingDisc((x, y), (vx, vy), 0.3) for x, y, vx, vy in movers]
    robot = Pose2(0.0, 0.0, 0.3)
    out_v, out_omega = yield_speed(robot, v, omega, discs, P)
    assert 0.0 <= out_v <= v + 1e-12
    if v > 0.0:
        assert out_omega * v == pytest.approx(omega * out_v, abs=1e-12)
    if discs and out_v > 0.0:
        radius = 0.5 * math.hypot(P.length, P.width) + P.r_es
        u = velocity_vector(robot.theta, out_v, out_omega, 0.5)
        ttc = min(time_to_collision(np.zeros(2), u, d, radius) for d in discs)
        if ttc < P.yield_horizon:  # nothing was clear: it is the latest contact
            for k in range(P.yield_steps + 1):
                share = k / P.yield_steps
                uk = velocity_vector(robot.theta, v * share, omega * share, 0.5)
                assert min(time_to_collision(np.zeros(2), uk, d, radius) for d in discs) <= ttc


# -- end to end in sim2d ------------------------------------------------------------------------
SET_GAP = 2.0
WALKER_SPEED = 0.8
"""A slow walk: the pace of someone walking a 230 kg robot between parked vehicles."""

# The track (missions/track): open sky, the robot at (0, 0) facing east, the target board
# 43 m out. The operator walks 60 m: 16.5 m east, 12 m north, 15 m east, 16.5 m south,
# between eight parked vehicles 1.6 to 2.5 m from their path.
APRON = """
<obstacles>
  <box id="car-1" kind="vehicle" x="10" y="3.2" heading-deg="0" length="4.5" width="1.8"
       height="1.5"/>
  <box id="van-1" kind="vehicle" x="12" y="-3.5" heading-deg="0" length="5.5" width="2.2"
       height="2.5"/>
  <box id="car-2" kind="vehicle" x="16.5" y="7" heading-deg="90" length="4.5" width="2.0"
       height="1.5"/>
  <box id="car-3" kind="vehicle" x="23" y="6" heading-deg="90" length="4.5" width="1.8"
       height="1.5"/>
  <box id="truck-1" kind="vehicle" x="27" y="9.0" heading-deg="0" length="7" width="2.4"
       height="3.2"/>
  <box id="car-4" kind="vehicle" x="28" y="14.5" heading-deg="0" length="4.5" width="1.8"
       height="1.5"/>
  <box id="car-5" kind="vehicle" x="37.5" y="4" heading-deg="90" length="4.5" width="1.8"
       height="1.5"/>
  <box id="car-6" kind="vehicle" x="32.5" y="0" heading-deg="90" length="4" width="1.8"
       height="1.5"/>
  <path id="operator" kind="person" radius="0.3" height="1.8" speed="SPEED" start-time="2"
        loop="false">
    <waypoint x="3.5" y="0"/><waypoint x="20" y="0"/><waypoint x="20" y="12"/>
    <waypoint x="35" y="12"/><waypoint x="35" y="-4.5"/>
  </path>
</obstacles>
""".replace("SPEED", str(WALKER_SPEED))
WALKER_PATH = np.array([[3.5, 0.0], [20.0, 0.0], [20.0, 12.0], [35.0, 12.0], [35.0, -4.5]])

# The apron, and someone else crossing between the operator and the robot 3 s after the
# operator passed their crossing point (1 m/s, south to north)
CROSSING = APRON.replace(
    "</obstacles>",
    """  <path id="crosser" kind="person" radius="0.3" height="1.8" speed="1.0" start-time="CROSS"
        loop="false">
    <waypoint x="6.5" y="-7"/><waypoint x="6.5" y="7"/>
  </path>
</obstacles>""",
)


# A van; the operator walks past its east end, behind it, and gets in (the path ends
# inside the van's box): from the robot's side they vanish behind the vehicle.
VANISH = """
<obstacles>
  <box id="van" kind="vehicle" x="18" y="2.5" heading-deg="0" length="6" width="2.4"
       height="2.5"/>
  <path id="operator" kind="person" radius="0.3" height="1.8" speed="0.8" start-time="2"
        loop="false">
    <waypoint x="3.5" y="0"/><waypoint x="22.5" y="0"/><waypoint x="22.5" y="4.8"/>
    <waypoint x="19" y="4.8"/><waypoint x="19" y="2.8"/>
  </path>
</obstacles>
"""


def _follow_run(tmp_path, body: str, duration: float):
    """Take over at once and designate the walker at its start; log the truth per tick:
    (t, robot x, y, theta, walker x, y)."""
    scenario = make_scenario(tmp_path, body, mission_type="track", mission="straight-run.xml")
    scenario = dataclasses.replace(scenario, duration=duration)
    robot = SimRobot(scenario)
    log: list[tuple[float, ...]] = []

    def operator(t: float) -> OperatorRequests:
        world = robot.world
        p = world.robot_pose
        wx, wy = next((x, y) for i, x, y, _ in world.obstacle_poses() if i == "operator")
        log.append((t, p.x, p.y, p.theta, wx, wy))
        return OperatorRequests(take_over=True, follow=FollowRequest(t, 3.5, 0.0, SET_GAP))

    run = dry_run(scenario, operator=operator, robot=robot)
    return run, robot, np.array(log)


def _true_gaps(log: np.ndarray, length: float, width: float, radius: float) -> np.ndarray:
    """Straight gap, footprint to the walker's edge, from ground truth."""
    _, x, y, th, wx, wy = log.T
    c, s = np.cos(th), np.sin(th)
    dx, dy = wx - x, wy - y
    in_r = np.column_stack((c * dx + s * dy, -s * dx + c * dy))
    return footprint_distances(in_r, length, width) - radius


@pytest.mark.slow
def test_follow_the_operator_60_m_among_parked_vehicles(tmp_path):
    duration = 2.0 + 60.0 / WALKER_SPEED + 12.0
    run, robot, log = _follow_run(tmp_path, APRON, duration)
    mission = run.scenario.mission
    gaps = _true_gaps(log, mission.platform.length, mission.platform.width, 0.3)
    t = log[:, 0]
    # the run went the whole walk (a fault would have ended it early: say which)
    assert run.result.outcome == "timeout" and t[-1] > duration - 0.5, (
        run.result.outcome,
        run.result.reason,
        [e for e in run.result.events if e.kind != "localisation"],
    )
    # caught up: from the first time the gap is within 0.1 m of the set gap, to the end
    # (the walker's stop included)
    start = int(np.flatnonzero((t > 2.0) & (np.abs(gaps - SET_GAP) < 0.1))[0])
    err = gaps[start:] - SET_GAP
    walked = np.hypot(*np.diff(log[start:, 4:6], axis=0).T).sum()
    print(
        f"follow 60 m: from t = {t[start]:.1f} s over {walked:.1f} m, gap error "
        f"{err.min():+.3f} .. {err.max():+.3f} m (rms {np.sqrt(np.mean(err**2)):.3f}), "
        f"min gap {gaps.min():.3f} m, min clearance "
        f"{min(s.clearance for s in run.samples):.3f} m"
    )
    assert walked > 50.0  # the walk was followed, not just its start
    assert np.all(np.abs(err) <= 0.5), (err.min(), err.max())
    assert gaps.min() > mission.safety.r_es
    assert not robot.world.collisions
    assert min(s.clearance for s in run.samples) > mission.safety.r_es
    assert not [e for e in run.result.events if e.detail.get("kind") == "estop-latched"]
    # the robot kept to the operator's path, between the vehicles (once on it)
    on_path = log[start:, 1:3][log[start:, 1] >= WALKER_PATH[0, 0]]
    off = max(_distance_to_path(p[None, :], WALKER_PATH) for p in on_path)
    print(f"farthest from the operator's path: {off:.3f} m")
    assert off < 0.5, off
    names = [e.detail["to"] for e in run.result.events if e.kind == "controller"]
    assert names == ["follow operator"]
    assert np.hypot(*(log[-1, 4:6] - WALKER_PATH[-1])) < 0.1  # the walk was finished


def _crossing_run(tmp_path, duration: float):
    return _follow_run(tmp_path, CROSSING.replace("CROSS", "4.0"), duration)


def _estops(run) -> int:
    return sum(e.detail.get("kind") == "estop-latched" for e in run.result.events)


@pytest.mark.slow
def test_someone_crossing_between_operator_and_robot_is_yielded_to(tmp_path, monkeypatch):
    """Obstacle avoidance in the collaborative mode (Table 2.3): a person crossing the
    trail between the operator and the robot at 1 m/s makes it wait until they have
    passed, with no e-stop and everything outside r_ES; without yielding (horizon 0) the
    same crossing ends in the e-stop. The crosser hides the operator, and the laser
    tracker swaps the operator's id with a parked car's blob: the follower refuses the
    car (no longer person-like, out of the gate) and takes the operator's new id back,
    and follows the whole 60 m walk."""
    run, robot, log = _crossing_run(tmp_path / "yield", 2.0 + 60.0 / WALKER_SPEED + 12.0)
    mission = run.scenario.mission
    clearance = min(s.clearance for s in run.samples)
    print(f"yielding: min clearance {clearance:.2f} m, e-stops {_estops(run)}")
    assert not robot.world.collisions and _estops(run) == 0
    assert clearance > mission.safety.r_es
    names = [e.detail["to"] for e in run.result.events if e.kind == "controller"]
    assert names == ["follow operator"]
    gaps = _true_gaps(log, mission.platform.length, mission.platform.width, 0.3)
    assert np.hypot(*(log[-1, 4:6] - WALKER_PATH[-1])) < 0.1  # the walk was finished
    assert abs(gaps[-1] - SET_GAP) < 0.5  # and followed to its end
    # the same crossing with a follower that never yields (horizon 0)
    monkeypatch.setattr(follow_controllers, "FollowParams", partial(FollowParams, yield_horizon=0))
    blind, _, _ = _crossing_run(tmp_path / "blind", 20.0)
    blind_clearance = min(s.clearance for s in blind.samples)
    print(f"not yielding: min clearance {blind_clearance:.2f} m, e-stops {_estops(blind)}")
    assert _estops(blind) > 0 or blind_clearance <= mission.safety.r_es


@pytest.mark.slow
def test_the_operator_vanishing_behind_a_vehicle_stops_the_robot_and_asks(tmp_path):
    run, robot, log = _follow_run(tmp_path, VANISH, 50.0)
    events = [e for e in run.result.events if e.kind == "controller"]
    lost = [e for e in events if e.detail["to"] == "hold: operator lost"]
    assert [e.detail["to"] for e in events] == ["follow operator", "hold: operator lost"]
    reason = lost[0].detail["reason"]
    assert "operator lost" in reason and "designate again" in reason, reason
    # the robot stops: no true motion from a second after the loss to the end
    after = log[log[:, 0] >= lost[0].t + 1.0]
    assert np.hypot(*(after[:, 1:3] - after[0, 1:3]).T).max() < 0.02
    # it had followed the walker up to the van
    assert after[0, 1] > 19.0
    assert not robot.world.collisions
    assert min(s.clearance for s in run.samples) > run.scenario.mission.safety.r_es
    question = py_trees.blackboard.Blackboard.storage.get(QUESTION.name)
    assert question is not None and question.text == "operator lost: designate again"
