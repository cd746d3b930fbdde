"""The repeat controller (behaviours.controllers.repeat, seed 002 §3) on the blackboard:
eq. 12 against the line through the next key pose, key switches without a jump in omega,
routes taught backwards, events with the lateral error, its trap guard."""

import math
from pathlib import Path

import numpy as np
import py_trees
import pytest

from behaviours.controllers.repeat import (
    FollowTaughtRoute,
    RouteGoal,
    RouteProgressing,
    RouteSession,
)
from behaviours.keys import COMMAND, POSE
from behaviours.laws.routes import gains_for_settling_distance
from behaviours.laws.vnhv import state_from_poses, vnhv_command
from executive.core.frames import Pose2, wrap_angle
from executive.core.model import KeyImage, TaughtRoute
from executive.core.records import PoseEstimate
from tests.conftest import MISSIONS, blackboard_writer

S = py_trees.common.Status
pytestmark = pytest.mark.usefixtures("fresh_blackboard")


def platform():
    from executive.core.loader import load_mission

    return load_mission(MISSIONS / "track" / "straight-run.xml").platform


def route(poses: list[Pose2], speed: float = 0.5, settling: float = 1.0) -> TaughtRoute:
    keys = tuple(KeyImage(f"k{i}", p, frozenset({"L"})) for i, p in enumerate(poses))
    return TaughtRoute("r", Path("m.npz"), 10.0, speed, settling, math.radians(10.0), keys)


def estimate(pose: Pose2, t: float) -> PoseEstimate:
    return PoseEstimate(t, pose, np.eye(3) * 1e-4, pose, 1.0)


def drive(node: FollowTaughtRoute, start: Pose2, seconds: float, dt: float = 0.02):
    """Tick the node, apply its command to a unicycle; (poses, commands, statuses)."""
    bb = blackboard_writer(POSE)
    pose, t = start, 0.0
    poses, commands, statuses = [], [], []
    while t < seconds:
        bb.set(POSE.name, estimate(pose, t), overwrite=True)
        node.tick_once()
        command = py_trees.blackboard.Blackboard.get(COMMAND.name)
        poses.append(pose)
        commands.append(command)
        statuses.append(node.status)
        if node.status != S.RUNNING:
            break
        pose = pose @ Pose2(command.v * dt, 0.0, command.omega * dt)  # small steps
        t += dt
    return poses, commands, statuses


TURN = (
    [Pose2(0.0, 0.0, 0.0), Pose2(4.0, 0.0, 0.0)]
    + [
        Pose2(4.0 + 2.0 * math.sin(a), 2.0 - 2.0 * math.cos(a), a)
        for a in np.radians(np.arange(8.0, 90.1, 8.0))
    ]
    + [Pose2(6.0, 6.0, math.pi / 2)]
)
"""4 m east, a left turn of radius 2 m in 8 degree key images, 2 m north."""


def test_the_command_is_eq12_against_the_line_of_the_next_key():
    session = RouteSession(route([Pose2(0, 0, 0), Pose2(5, 0, 0), Pose2(10, 0, 0)]), platform())
    node = FollowTaughtRoute(session)
    bb = blackboard_writer(POSE)
    pose = Pose2(1.0, 0.02, 0.01)
    bb.set(POSE.name, estimate(pose, 0.0), overwrite=True)
    node.tick_once()
    command = py_trees.blackboard.Blackboard.get(COMMAND.name)
    state = state_from_poses(pose, Pose2(5, 0, 0))
    gains = gains_for_settling_distance(1.0)
    expected = vnhv_command(state, command.v, gains, platform().max_angular_speed)
    assert command.v == pytest.approx(0.5)
    assert command.omega == pytest.approx(expected.omega)
    assert expected.omega < 0.0  # left of the line, heading further left: turn right
    assert node.status == S.RUNNING and "to key k1" in node.feedback_message


def test_no_pose_no_motion():
    node = FollowTaughtRoute(RouteSession(route(TURN), platform()))
    node.tick_once()
    assert py_trees.blackboard.Blackboard.get(COMMAND.name).v == 0.0
    assert node.status == S.RUNNING


def test_the_route_is_followed_key_by_key_to_success():
    session = RouteSession(route(TURN), platform())
    start = Pose2(0.0, 0.3, math.radians(10.0))
    poses, commands, statuses = drive(FollowTaughtRoute(session), start, 60.0)
    assert statuses[-1] == S.SUCCESS and commands[-1].v == 0.0
    events = session.drain_events()
    assert [e.key for e in events] == [f"k{i}" for i in range(1, len(TURN))]
    assert events[-1].kind == "route-done"
    assert all(abs(e.lateral_error) < 0.05 for e in events[1:])  # converged by the turn
    end = poses[-1]
    assert math.hypot(end.x - 6.0, end.y - 6.0) < 0.05
    assert abs(wrap_angle(end.theta - math.pi / 2)) < math.radians(3.0)


def test_omega_is_continuous_across_the_key_switches():
    session = RouteSession(route(TURN), platform())
    _, commands, _ = drive(FollowTaughtRoute(session), TURN[0], 60.0)
    omega = np.array([c.omega for c in commands[:-1]])
    switches = [e.stamp for e in session.drain_events()]
    assert len(switches) == len(TURN) - 1
    jumps = np.abs(np.diff(omega))
    assert jumps.max() < 0.04  # 20 ms ticks: no step at any of the 11 switches


def test_a_route_taught_backwards_is_reversed_along():
    facing_east = [Pose2(-x, 0.05 * x, 0.0) for x in np.arange(0.0, 8.1, 2.0)]  # going west
    session = RouteSession(route(facing_east, speed=-0.4), platform())
    poses, commands, statuses = drive(FollowTaughtRoute(session), Pose2(0.0, 0.2, 0.1), 60.0)
    assert statuses[-1] == S.SUCCESS
    assert all(c.v < 0.0 for c in commands[:-1])
    assert poses[-1].x == pytest.approx(-8.0, abs=0.05)
    assert abs(wrap_angle(poses[-1].theta)) < math.radians(5.0)  # still facing east


def test_the_speed_limit_caps_v_and_keeps_the_sign():
    facing_east = [Pose2(-x, 0.0, 0.0) for x in np.arange(0.0, 8.1, 2.0)]  # going west
    session = RouteSession(route(facing_east, speed=-1.0), platform())
    node = FollowTaughtRoute(session, speed_limit=lambda pose: 0.3)
    bb = blackboard_writer(POSE)
    bb.set(POSE.name, estimate(Pose2(-0.5, 0.0, 0.0), 0.0), overwrite=True)
    node.tick_once()
    assert py_trees.blackboard.Blackboard.get(COMMAND.name).v == pytest.approx(-0.3)


def test_the_route_goal_is_the_current_key():
    session = RouteSession(route(TURN), platform())
    goal = RouteGoal(TURN[-1], session=session)
    assert goal.in_airport(None) == TURN[1]
    session.step(0.0, Pose2(4.01, 0.0, 0.0), None)
    assert goal.in_airport(None) == TURN[2]


def test_route_progressing_fails_when_the_route_does_not_advance():
    session = RouteSession(route(TURN), platform())
    guard = RouteProgressing(session, period=5.0)
    bb = blackboard_writer(POSE)
    for t in np.arange(0.0, 3.0, 0.1):  # 0.5 m/s along the first leg
        bb.set(POSE.name, estimate(Pose2(0.5 * t, 0.0, 0.0), t), overwrite=True)
        guard.tick_once()
        assert guard.status == S.SUCCESS
    for t in np.arange(3.0, 9.0, 0.1):
        bb.set(POSE.name, estimate(Pose2(1.5, 0.0, 0.0), t), overwrite=True)
        guard.tick_once()
    assert guard.status == S.FAILURE and "no progress" in guard.feedback_message
