"""A track's shape follows the track (issue 16, avoidance campaign episode 254).

A track last seen whole as a line, then followed as a blob to a walker 3.5 m away, kept
the segment of its last whole line view: the avoidance policy found that ghost off the
path and drove into the walker, who then held the robot inside r_ES for good.
:func:`behaviours.laws.tracking.line_through` moves a line track's last whole view with
the tracked position.
"""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from behaviours.controllers.avoidance import AvoidanceParams, obstacle_in_airport
from behaviours.laws import tracking
from behaviours.laws.laser_clusters import BLOB, LINE, Clusters
from behaviours.laws.spiral import path_blocked
from behaviours.laws.tracking import DangerParams, ObstacleTracker, line_through
from executive.core.frames import Pose2

LENGTH, WIDTH = 1.4, 1.0
coordinate = st.floats(-20.0, 20.0)


@settings(max_examples=60, deadline=None)
@given(coordinate, coordinate, coordinate, coordinate, coordinate, coordinate)
def test_the_moved_segment_keeps_its_length_and_direction_and_passes_through_the_point(
    x0, y0, x1, y1, px, py
):
    ends = np.array([[x0, y0, x1, y1]])
    moved = line_through(ends, np.array([[px, py]]))[0]
    assert moved[2:] - moved[:2] == pytest.approx(ends[0, 2:] - ends[0, :2], abs=1e-9)
    a, b, p = moved[:2], moved[2:], np.array([px, py])
    d = b - a
    s = np.clip(np.dot(p - a, d) / max(np.dot(d, d), 1e-300), 0.0, 1.0)
    assert np.hypot(*(a + s * d - p)) == pytest.approx(0.0, abs=1e-6)


@settings(max_examples=60, deadline=None)
@given(coordinate, coordinate, coordinate, coordinate, st.floats(0.0, 1.0))
def test_a_segment_through_its_point_is_unchanged(x0, y0, x1, y1, s):
    ends = np.array([[x0, y0, x1, y1]])
    point = ends[:, :2] + s * (ends[:, 2:] - ends[:, :2])
    assert line_through(ends, point) == pytest.approx(ends, abs=1e-9)


def test_a_zero_length_segment_becomes_the_point():
    moved = line_through(np.zeros((1, 4)), np.array([[3.0, -2.0]]))
    assert moved[0] == pytest.approx([3.0, -2.0, 3.0, -2.0])


def _cluster(stamp: float, position: tuple[float, float], kind: int, half: float) -> Clusters:
    """One cluster at ``position`` (robot frame): a line of half-length ``half`` along y
    (both ends true), or a blob."""
    p = np.array([position], dtype=float)
    line = np.array([[p[0, 0], p[0, 1] - half, p[0, 0], p[0, 1] + half]])
    return Clusters(
        stamp=stamp,
        points=np.repeat(p, 3, axis=0),
        start=np.array([0, 3]),
        kind=np.array([kind], dtype=np.int8),
        centroid=p,
        position=p,
        size=np.array([half]),
        line=line if kind == LINE else np.full((1, 4), np.nan),
        circle=np.full((1, 3), np.nan),
        rms=np.zeros(1),
        clearance=np.array([max(0.0, abs(p[0, 0]) - LENGTH / 2 - half)]),
        occluded=np.zeros(1, dtype=bool),
        ends_visible=np.ones((1, 2), dtype=bool),
        boxed=np.zeros(1, dtype=bool),
    )


def _walk_away(tracker: ObstacleTracker):
    """A walker 0.6 m across seen side-on as a line for 4 s at (6, 3), then as a blob for
    2.5 s while it walks to (6, 0.5) across the robot's way (robot at the origin facing
    +x, the goal 20 m ahead): it is still voted a line."""
    tracks = ()
    for k in range(160):
        tracks = tracker.update(_cluster(k / 40.0, (6.0, 3.0), LINE, 0.3), Pose2(0.0, 0.0, 0.0))
    for k in range(100):
        y = 3.0 - 2.5 * (k + 1) / 100
        tracks = tracker.update(
            _cluster(4.0 + (k + 1) / 40.0, (6.0, y), BLOB, 0.3), Pose2(0.0, 0.0, 0.0)
        )
    (walker,) = tracks
    return walker


def test_a_line_track_seen_as_a_blob_while_it_moves_keeps_its_shape_on_it():
    walker = _walk_away(ObstacleTracker(DangerParams(LENGTH, WIDTH)))
    assert walker.kind == "line"
    assert walker.position == pytest.approx((6.0, 0.5), abs=0.2)
    x0, y0, x1, y1 = walker.shape
    assert math.hypot(x1 - x0, y1 - y0) == pytest.approx(0.6, abs=0.05)
    a, b, p = np.array([x0, y0]), np.array([x1, y1]), np.array(walker.position)
    s = np.clip(np.dot(p - a, b - a) / np.dot(b - a, b - a), 0.0, 1.0)
    assert np.hypot(*(a + s * (b - a) - p)) < 1e-6  # the segment passes through it
    # the avoidance policy now sees it on the way to a goal straight ahead
    robot = Pose2(0.0, 0.0, 0.0)
    obstacle = obstacle_in_airport(walker, robot)
    margin = AvoidanceParams().margin
    assert path_blocked(np.zeros(2), np.array([20.0, 0.0]), obstacle, margin)


def test_without_the_move_the_shape_is_the_ghost_of_episode_254(monkeypatch):
    """The mechanism this guards against (the law replaced by the identity): the segment
    stays where the walker was last seen as a line, off the path."""
    monkeypatch.setattr(tracking, "line_through", lambda ends, points: ends)
    walker = _walk_away(ObstacleTracker(DangerParams(LENGTH, WIDTH)))
    obstacle = obstacle_in_airport(walker, Pose2(0.0, 0.0, 0.0))
    assert obstacle.shape[1] == pytest.approx(2.7, abs=0.05)
    assert not path_blocked(np.zeros(2), np.array([20.0, 0.0]), obstacle, 1.4)
