"""Camera occlusion: which lines of sight an obstacle taller than the line blocks."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from sim2d.raycast import Scene
from sim2d.sensors import sight_lines_blocked

ORIGIN = np.array([0.0, 0.0, 1.5])


def _scene_box(x, y, length, width, owner=0):
    return Scene.from_box(x, y, 0.0, length, width, owner)


def test_tall_box_blocks_low_box_does_not():
    scene = _scene_box(5.0, 0.0, 1.0, 2.0)
    targets = np.array([[10.0, 0.0, 2.0], [10.0, 5.0, 2.0], [3.0, 0.0, 2.0]])
    tall = sight_lines_blocked(scene, np.array([3.0]), ORIGIN, targets)
    low = sight_lines_blocked(scene, np.array([0.5]), ORIGIN, targets)
    assert tall.tolist() == [True, False, False]  # beside it, or in front of it: visible
    assert low.tolist() == [False, False, False]


def test_line_passes_over_a_box_when_high_enough():
    scene = _scene_box(5.0, 0.0, 1.0, 2.0)
    # From 1.5 m to 6.5 m over 10 m: at the box (x 4.5..5.5) the line is at 3.75..4.25 m.
    target = np.array([[10.0, 0.0, 6.5]])
    assert not sight_lines_blocked(scene, np.array([3.5]), ORIGIN, target)[0]
    assert sight_lines_blocked(scene, np.array([4.5]), ORIGIN, target)[0]


def test_circle_blocks_only_lines_through_it():
    scene = Scene(circles=[(5.0, 0.0, 0.5)], circle_owner=[0])
    heights = np.array([2.0])
    targets = np.array([[10.0, 0.0, 1.5], [10.0, 1.2, 1.5], [4.0, 0.0, 1.5]])
    assert sight_lines_blocked(scene, heights, ORIGIN, targets).tolist() == [True, False, False]


def test_a_low_obstacle_in_front_does_not_hide_a_tall_one_behind():
    scene = Scene.concat([_scene_box(3.0, 0.0, 0.5, 2.0, 0), _scene_box(6.0, 0.0, 0.5, 2.0, 1)])
    blocked = sight_lines_blocked(scene, np.array([0.3, 4.0]), ORIGIN, np.array([[10.0, 0, 2]]))
    assert blocked[0]


@settings(max_examples=200, deadline=None)
@given(
    st.floats(2, 20),
    st.floats(-10, 10),
    st.floats(0.2, 3),
    st.floats(0.2, 3),
    st.floats(0.1, 5),
    st.floats(-10, 10),
    st.floats(0, 8),
)
def test_matches_a_dense_sampling_of_the_line(bx, by, length, width, height, ty, tz):
    """Reference: walk along the line of sight in small steps and look for a point that is
    inside the box and below its top."""
    scene = _scene_box(bx, by, length, width)
    target = np.array([25.0, ty, tz])
    s = np.linspace(0.0, 1.0, 20001)[1:-1]
    pts = ORIGIN + s[:, None] * (target - ORIGIN)
    inside = (np.abs(pts[:, 0] - bx) < length / 2) & (np.abs(pts[:, 1] - by) < width / 2)
    margin = (np.abs(np.abs(pts[:, 0] - bx) - length / 2) < 2e-3) | (
        np.abs(np.abs(pts[:, 1] - by) - width / 2) < 2e-3
    )
    low = pts[:, 2] < height
    hits = inside & low
    near_top = inside & (np.abs(pts[:, 2] - height) < 2e-3)
    if (margin & low).any() or near_top.any():
        return  # the line grazes an edge or the top: either answer is right
    got = sight_lines_blocked(scene, np.array([height]), ORIGIN, target[None, :])[0]
    assert got == bool(hits.any())
