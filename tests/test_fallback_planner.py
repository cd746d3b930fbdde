"""The fallback planner's follower (behaviours/controllers/fallback.py): the costmap is a
snapshot, so the path still ahead is checked against every new scan, and a return on it
(a mover that stopped there after the plan) makes the robot stop and plan again."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from behaviours.controllers.avoidance import AvoidanceSession
from behaviours.controllers.fallback import FollowPlannedPath, path_blocked_by
from behaviours.goals import Goal
from behaviours.keys import COMMAND, OBSTACLES, POSE
from behaviours.laws.costmap import PlannedPath
from behaviours.laws.go_to_goal import GoToGoalParams
from behaviours.laws.obstacles import mover_sweep
from executive.campaign.runner import episode_row
from executive.campaign.spec import load_campaign
from executive.core.frames import Pose2
from executive.core.loader import load_mission
from executive.core.model import Frame
from executive.core.records import Danger, Obstacles, PoseEstimate, TrackedObstacle
from tests.conftest import MISSIONS, blackboard_writer

pytestmark = pytest.mark.usefixtures("fresh_blackboard")


def test_path_blocked_by_measures_the_distance_to_the_polyline():
    path = np.array([[0.0, 0.0], [4.0, 0.0], [4.0, 4.0]])
    assert path_blocked_by(np.array([[2.0, 0.9]]), path, 1.0)
    assert not path_blocked_by(np.array([[2.0, 1.1]]), path, 1.0)
    assert path_blocked_by(np.array([[4.9, 3.0]]), path, 1.0)  # beside the second leg
    assert not path_blocked_by(np.array([[5.5, -0.5]]), path, 1.0)  # past the corner
    assert not path_blocked_by(np.zeros((0, 2)), path, 1.0)
    assert path_blocked_by(np.array([[0.5, 0.0]]), path[:1], 1.0)


def follower():
    mission = load_mission(MISSIONS / "track" / "avoidance-leg.xml")
    goal = Goal(Pose2(10.0, 0.0, 0.0), Frame.AIRPORT, mission.nominal_placement())
    node = FollowPlannedPath(
        goal, AvoidanceSession(margin=1.4), mission, 0.02, GoToGoalParams(), plan_delay=0.0
    )
    node.setup()
    node.initialise()
    return node


def tick(node, bb, t: float, points: list[tuple[float, float]]):
    """One tick with the robot at the origin facing +x and ``points`` in its frame."""
    p = Pose2(0.0, 0.0, 0.0)
    pts = np.array(points, dtype=float).reshape(-1, 2)
    closest = float(np.hypot(*pts.T).min()) if len(pts) else math.inf
    bb.set(OBSTACLES.name, Obstacles(t, closest, 0.0, pts), overwrite=True)
    bb.set(POSE.name, PoseEstimate(t, p, np.eye(3) * 1e-4, p, 1.0), overwrite=True)
    node.tick_once()
    return bb.get(COMMAND.name)


def test_a_return_on_the_path_ahead_stops_the_robot_and_plans_again():
    bb = blackboard_writer(OBSTACLES, POSE, COMMAND)
    node = follower()
    straight = np.array([[0.0, 0.0], [5.0, 0.0], [10.0, 0.0]])
    planned = PlannedPath(straight, 10.0, 0, 10.0, np.zeros((0, 2), dtype=int))
    assert tick(node, bb, 0.0, [(0.0, 3.0)]).v == 0.0  # the first tick asks for a plan
    node.path, node._future = planned, None  # this one, straight to the goal
    assert tick(node, bb, 0.0, [(0.0, 3.0)]).v > 0.0  # beside, far from the path: drive
    assert node.replans == 0
    # a trolley stops on the path 2.5 m ahead: within the turning radius plus r_ES of it
    out = tick(node, bb, 0.02, [(0.0, 3.0), (2.5, 0.3)])
    assert out.v == 0.0 and out.omega == 0.0
    assert node.replans == 1 and node.path is None and "blocked" in node.feedback_message
    # the next ticks plan again from here (and the new plan sees the trolley)
    tick(node, bb, 0.04, [(0.0, 3.0), (2.5, 0.3)])
    assert node._future is not None
    # a return beyond the lookahead, or about the robot's own spot, does not count
    node.path, node._future = (
        PlannedPath(straight, 10.0, 0, 10.0, np.zeros((0, 2), dtype=int)),
        None,
    )
    assert tick(node, bb, 0.06, [(8.0, 0.0), (0.5, 0.9)]).v > 0.0
    assert node.replans == 1


def test_what_the_plan_was_made_round_does_not_block_it():
    """A trapped robot stands closer to the obstacles than a path cell may (the costmap's
    escape region), so the first metres of its plan pass them within the blocking
    distance. Those returns were in the plan's snapshot: they do not block it, and the
    robot drives off instead of planning again for ever (campaign episodes 652 and 889
    stood 20 s re-planning). A return the plan did not know still blocks it."""
    bb = blackboard_writer(OBSTACLES, POSE, COMMAND)
    node = follower()
    # in a passage narrower than a path cell may be, its way out ahead (episode 652: two
    # discs a robot's width apart)
    wall = [(x, y) for x in np.arange(-2.0, 3.0, 0.05) for y in (-1.2, 1.2)]
    assert tick(node, bb, 0.0, wall).v == 0.0 and node._future is not None
    assert "planned" in (tick(node, bb, 0.02, wall), node.feedback_message)[1]
    assert node.path is not None and node.radius > 1.2  # the start is inside the inflation
    ahead = np.array(wall)
    reach = np.hypot(*ahead.T)
    known = ahead[(reach >= node.blocking) & (reach < node.lookahead + node.blocking)]
    assert path_blocked_by(known, node.path.waypoints, node.blocking)  # would have blocked
    speeds = [tick(node, bb, 0.04 + 0.02 * k, wall).v for k in range(20)]
    assert node.replans == 0 and max(np.abs(speeds)) > 0.0  # it backs out of the passage
    # a trolley that stops on the path after the plan does block it
    first = node.path.waypoints[1]
    trolley = [(float(first[0]), float(first[1]) + 0.2)]
    tick(node, bb, 0.5, wall + trolley)
    assert node.replans == 1 and "blocked" in node.feedback_message


@pytest.mark.parametrize("episode", [375, 487, 652, 976])
def test_campaign_episodes_that_timed_out_now_complete(episode):
    """Episodes of the shipped avoidance campaign that timed out (BENCHMARKS, M7, M10,
    M11): velocity obstacles stood 20 s between static obstacles, then the planner
    planned again at once for ever because its own way out passed the returns it was
    planned round (652); a slow chaser took the robot from the planner to velocity
    obstacles, which stood, again and again (976); the planner's follower stood 70 s at a
    waypoint 0.14 m past the last (375); and one the planner's first fix lost, whose robot
    was sent back to a planner that found no path every half second while a slow
    trolley walked into it (487). Run alone, they complete with no collision."""
    campaign = load_campaign(MISSIONS / "campaigns" / "avoidance-leg.xml")
    row = episode_row(campaign, episode)
    assert row["succeeded"], row["causes"]
    assert row["collisions"] == []


def test_the_plan_keeps_off_where_a_slow_mover_will_be():
    """The costmap holds each tracked mover's sweep over ``mover_horizon`` (where it will
    be at its tracked velocity), so the planner, which keeps the robot while movers
    slower than ``fast_speed`` come (campaign episodes 375 and 976), plans round their
    way, not only round where they stand."""
    bb = blackboard_writer(OBSTACLES, POSE, COMMAND)
    node = follower()  # goal 10 m ahead
    trolley = TrackedObstacle(
        7, "blob", (5.0, 2.5), (0.0, -0.12), np.eye(4), 0.5, 3.0, 2.0, Danger.NONE, ()
    )
    sweep = mover_sweep((trolley,), node.mover_horizon)
    assert sweep[:, 1].min() == pytest.approx(2.5 - 0.12 * node.mover_horizon - 0.5)
    p = Pose2(0.0, 0.0, 0.0)
    body = [(5.0 + 0.5 * math.cos(a), 2.5 + 0.5 * math.sin(a)) for a in np.linspace(0, 6.2, 30)]
    bb.set(OBSTACLES.name, Obstacles(0.0, 2.0, 0.0, np.array(body), (trolley,)), overwrite=True)
    bb.set(POSE.name, PoseEstimate(0.0, p, np.eye(3) * 1e-4, p, 1.0), overwrite=True)
    node.tick_once()
    node.tick_once()
    assert node.path is not None
    # the straight line to the goal passes 2 m from the trolley standing, 1.4 m from
    # where it will be in 5 s: the plan keeps the robot's radius from its whole sweep
    distance = min(
        float(np.hypot(*(pt - np.array(q)).T).min()) for pt in [node.path.waypoints] for q in sweep
    )
    assert distance >= node.radius - 0.1 - 0.15  # a cell's half diagonal, the margin
    # a standing obstacle has no sweep beyond itself; a zone or a big vehicle none at all
    still = dataclasses.replace(trolley, velocity=(0.0, 0.0))
    assert len(mover_sweep((still,), 5.0)) == 0
    assert len(mover_sweep((dataclasses.replace(trolley, size=2.0),), 5.0)) == 0
