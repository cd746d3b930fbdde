"""Costmap and A* fallback planner of the spiral avoidance (behaviours.laws.costmap, issue 6).

Clearances are checked on ground truth: the waypoint segments are sampled densely and
measured against the obstacle points (or the polygon) the map was built from.
"""

import heapq
import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial import cKDTree

from behaviours.laws.costmap import Costmap, PlannedPath

R = 0.4
"""Robot radius of the tests (m)."""
CLEARANCE = 0.5
RES = 0.1


def _samples(waypoints, step=0.01):
    out = []
    for a, b in itertools.pairwise(waypoints):
        n = max(2, math.ceil(float(np.hypot(*(b - a))) / step) + 1)
        out.append(a + np.linspace(0.0, 1.0, n)[:, None] * (b - a))
    return np.vstack(out)


def _clearance(path: PlannedPath, points) -> float:
    return float(cKDTree(points).query(_samples(path.waypoints))[0].min())


def _segment_points(a, b, step=0.05):
    a, b = np.asarray(a, float), np.asarray(b, float)
    n = max(2, math.ceil(float(np.hypot(*(b - a))) / step) + 1)
    return a + np.linspace(0.0, 1.0, n)[:, None] * (b - a)


def _circle_points(centre, radius, step=0.05):
    n = max(8, math.ceil(2.0 * math.pi * radius / step))
    a = np.linspace(0.0, 2.0 * math.pi, n, endpoint=False)
    return np.asarray(centre, float) + radius * np.column_stack([np.cos(a), np.sin(a)])


def _rectangle_distance(p, x0, x1, y0, y1):
    """Signed distance of points to an axis-aligned rectangle (negative inside)."""
    dx = np.maximum(x0 - p[:, 0], p[:, 0] - x1)
    dy = np.maximum(y0 - p[:, 1], p[:, 1] - y1)
    outside = np.hypot(np.maximum(dx, 0.0), np.maximum(dy, 0.0))
    return np.where((dx <= 0.0) & (dy <= 0.0), np.maximum(dx, dy), outside)


def _map(start, goal, points=None, polygons=(), margin=4.0):
    cm = Costmap.around(start, goal, margin=margin, resolution=RES)
    if points is not None:
        cm.add_points(points)
    cm.add_polygons(polygons)
    cm.inflate(R, CLEARANCE)
    return cm


def _octile(di, dj):
    di, dj = abs(di), abs(dj)
    return max(di, dj) + (math.sqrt(2.0) - 1.0) * min(di, dj)


def _check_polyline(path: PlannedPath, start, goal, tolerance=0.0):
    wp = path.waypoints
    assert wp.shape[1] == 2 and len(wp) >= 2
    np.testing.assert_allclose(wp[0], start)
    assert np.hypot(*(wp[-1] - np.asarray(goal))) <= tolerance + 1e-9
    assert path.length == pytest.approx(float(np.sum(np.hypot(*np.diff(wp, axis=0).T))))
    assert path.length >= np.hypot(*(wp[-1] - wp[0])) - 1e-9
    steps = np.abs(np.diff(path.cells, axis=0))
    assert np.all(steps.max(axis=1) == 1), "the raw cell path is 8-connected"


# -- window ---------------------------------------------------------------------------------------
def test_around_covers_start_goal_and_margin():
    cm = Costmap.around((2.0, -1.0), (12.0, 5.0), margin=3.0, resolution=0.1)
    rows, cols = cm.shape
    x0, y0 = cm.origin
    assert x0 <= 2.0 - 3.0 + 1e-9 and y0 <= -1.0 - 3.0 + 1e-9
    assert x0 + cols * cm.resolution >= 12.0 + 3.0 - 1e-9
    assert y0 + rows * cm.resolution >= 5.0 + 3.0 - 1e-9
    assert cm.resolution == 0.1 and (rows, cols) == (120, 160)


def test_around_coarsens_resolution_beyond_max_cells():
    cm = Costmap.around((0.0, 0.0), (100.0, 60.0), margin=8.0, resolution=0.05, max_cells=50_000)
    rows, cols = cm.shape
    assert rows * cols <= 50_000
    assert cm.resolution > 0.05
    assert cm.origin[0] + cols * cm.resolution >= 108.0 - 1e-9
    assert cm.origin[1] + rows * cm.resolution >= 68.0 - 1e-9
    assert rows * cols > 0.9 * 50_000, "coarsened no more than needed"


def test_add_points_marks_cells_and_ignores_outside():
    cm = Costmap((0.0, 0.0), 0.5, (4, 6))
    cm.add_points(np.array([[0.1, 0.1], [2.9, 1.9], [-0.1, 1.0], [3.0, 0.2], [1.0, 5.0]]))
    expected = np.zeros((4, 6), dtype=bool)
    expected[0, 0] = expected[3, 5] = True
    np.testing.assert_array_equal(cm.occupied, expected)
    assert cm.cell_of((2.9, 1.9)) == (3, 5) and cm.cell_of((3.0, 0.0)) is None


def test_polygon_is_filled_and_clipped_to_the_window():
    cm = Costmap((0.0, 0.0), 0.1, (50, 50))
    cm.add_polygons([np.array([[1.0, 1.0], [3.0, 1.0], [3.0, 2.0], [1.0, 2.0]])])
    occ = cm.occupied
    assert occ[15, 20] and occ[10:20, 10:30].all()
    assert not occ[25, 20] and not occ[15, 35]
    # a polygon sticking out of the window fills its part inside
    cm.add_polygons([np.array([[4.0, -1.0], [6.0, -1.0], [6.0, 1.0], [4.0, 1.0]])])
    assert cm.occupied[0:10, 40:50].all()


def test_thin_polygon_is_not_missed():
    sliver = np.array([[5.0, -4.0], [5.02, -4.0], [5.02, 4.0], [5.0, 4.0]])
    cm = Costmap((0.0, -6.0), RES, (120, 100))
    cm.add_polygons([sliver])
    assert cm.occupied.sum(axis=1)[20:100].min() >= 1, "every row crossed by the sliver"
    cm.inflate(R, CLEARANCE)
    path = cm.plan((1.0, 0.0), (9.0, 0.0))
    assert path is not None
    d = _rectangle_distance(_samples(path.waypoints), 5.0, 5.02, -4.0, 4.0)
    assert d.min() >= R
    assert np.abs(path.waypoints[:, 1]).max() > 4.0 + R


# -- inflation ------------------------------------------------------------------------------------
def test_inflation_lethal_radius_and_linear_cost():
    cm = Costmap((0.0, 0.0), RES, (41, 41))
    cm.add_points(np.array([[2.05, 2.05]]))
    cm.inflate(R, CLEARANCE)
    ii, jj = np.indices(cm.shape)
    d = RES * np.hypot(ii - 20, jj - 20)
    r_lethal = R + RES / math.sqrt(2.0)
    np.testing.assert_array_equal(cm.lethal, d < r_lethal)
    band = (d >= r_lethal) & (d < r_lethal + CLEARANCE)
    np.testing.assert_allclose(cm.cost[band], 1.0 - (d[band] - r_lethal) / CLEARANCE)
    assert np.all(cm.cost[d >= r_lethal + CLEARANCE] == 0.0)
    assert np.all(cm.cost[cm.lethal] == 1.0)


def test_obstacles_added_after_inflate_are_inflated():
    start, goal = (0.0, 0.0), (10.0, 0.0)
    cm = Costmap.around(start, goal, margin=4.0)
    cm.inflate(R, CLEARANCE)
    wall = _segment_points((5.0, -3.0), (5.0, 3.0))
    cm.add_points(wall)
    path = cm.plan(start, goal)
    assert path is not None and len(path.waypoints) > 2
    assert _clearance(path, wall) >= R


# -- planning -------------------------------------------------------------------------------------
def test_empty_map_gives_the_straight_segment():
    start, goal = (0.0, 0.0), (10.0, 3.0)
    path = _map(start, goal).plan(start, goal)
    assert path is not None
    assert path.waypoints.shape == (2, 2)
    np.testing.assert_allclose(path.waypoints, [start, goal])
    assert abs(path.length - math.hypot(10.0, 3.0)) <= RES


@pytest.mark.parametrize(
    "start, goal",
    [((0.0, 0.0), (10.0, 3.0)), ((0.05, 0.05), (0.05, 7.95)), ((3.3, -1.2), (-4.1, 6.6))],
)
def test_raw_path_cost_is_the_octile_distance_on_an_empty_grid(start, goal):
    cm = _map(start, goal)
    path = cm.plan(start, goal)
    assert path is not None
    (si, sj), (gi, gj) = cm.cell_of(start), cm.cell_of(goal)
    assert path.cost == pytest.approx(RES * _octile(gi - si, gj - sj), rel=1e-12)
    assert tuple(path.cells[0]) == (si, sj) and tuple(path.cells[-1]) == (gi, gj)


def test_wall_with_a_gap_is_passed_through_the_gap():
    start, goal = (0.0, 0.0), (10.0, 0.0)
    wall = np.vstack(
        [_segment_points((5.0, -6.0), (5.0, 1.5)), _segment_points((5.0, 3.0), (5.0, 9.0))]
    )
    cm = _map(start, goal, wall, margin=4.0)
    path = cm.plan(start, goal)
    assert path is not None
    _check_polyline(path, start, goal)
    s = _samples(path.waypoints)
    crossing = s[np.argmin(np.abs(s[:, 0] - 5.0))]
    assert 1.5 < crossing[1] < 3.0
    assert _clearance(path, wall) >= R
    # the cost band keeps the path near the middle of the gap
    assert abs(crossing[1] - 2.25) < 0.2


def _u_trap():
    """A parked vehicle seen from behind: a U open towards -x, bottom at x = 4."""
    return np.vstack(
        [
            _segment_points((1.0, 1.5), (4.0, 1.5)),
            _segment_points((4.0, 1.5), (4.0, -1.5)),
            _segment_points((4.0, -1.5), (1.0, -1.5)),
        ]
    )


def test_u_shaped_trap_is_escaped_through_its_opening():
    start, goal = (2.5, 0.0), (9.0, 0.0)
    u = _u_trap()
    path = _map(start, goal, u, margin=4.0).plan(start, goal)
    assert path is not None
    _check_polyline(path, start, goal)
    assert path.waypoints[:, 0].min() < 1.0 - R, "leaves the U through its opening"
    assert _clearance(path, u) >= R
    assert path.length > 2.0 * (goal[0] - start[0])


def test_lethal_start_next_to_the_u_still_plans():
    start, goal = (3.7, 0.0), (9.0, 0.0)
    u = _u_trap()
    start_clear = float(cKDTree(u).query(start)[0])
    assert start_clear < R
    cm = _map(start, goal, u, margin=4.0)
    assert cm.lethal[cm.cell_of(start)]
    path = cm.plan(start, goal)
    assert path is not None
    _check_polyline(path, start, goal)
    assert _clearance(path, u) >= start_clear - RES, "never closer than the robot already is"
    # once out of the start's neighbourhood the full radius is kept
    far = _samples(path.waypoints)
    far = far[np.hypot(*(far - start).T) > 2.0 * R]
    assert cKDTree(u).query(far)[0].min() >= R


def test_start_on_an_occupied_cell_still_plans():
    start, goal = (0.0, 0.0), (6.0, 0.0)
    junk = np.array([[0.02, 0.03]])
    path = _map(start, goal, junk).plan(start, goal)
    assert path is not None
    _check_polyline(path, start, goal)


def test_lethal_cells_away_from_the_start_stay_blocked():
    # the start is lethal next to a post; a second wall far away must still be avoided
    start, goal = (0.0, 0.0), (8.0, 0.0)
    post = np.array([[0.0, 0.3]])
    wall = _segment_points((4.0, -3.0), (4.0, 3.0))
    path = _map(start, goal, np.vstack([post, wall])).plan(start, goal)
    assert path is not None
    assert _clearance(path, wall) >= R


def test_narrow_gap_is_not_squeezed_through_from_a_lethal_start():
    # the robot is lethal next to a long wall; the lethal band along the wall reaches a
    # gap too narrow for it: the escape region is local, so the gap stays blocked
    start, goal = (0.0, 0.3), (3.0, -2.0)
    cm = Costmap((-4.0, -4.0), RES, (80, 80))

    def wall(gap):
        left = _segment_points((-4.0, 0.0), (3.0 - gap / 2.0, 0.0))
        return np.vstack([left, _segment_points((3.0 + gap / 2.0, 0.0), (4.0, 0.0))])

    cm.add_points(wall(0.6))
    cm.inflate(R, CLEARANCE)
    assert cm.lethal[cm.cell_of(start)]
    assert cm.plan(start, goal) is None
    wide = Costmap((-4.0, -4.0), RES, (80, 80))
    wide.add_points(wall(1.6))
    wide.inflate(R, CLEARANCE)
    path = wide.plan(start, goal)
    assert path is not None
    _check_polyline(path, start, goal)


def test_no_corner_cutting_between_diagonal_cells():
    # a point robot and a staircase wall of cells touching only at their corners
    cm = Costmap((0.0, 0.0), RES, (30, 30))
    cm.add_points(RES * (np.arange(30)[:, None] + 0.5) * np.ones((1, 2)))
    assert cm.plan((2.55, 0.55), (0.55, 2.55)) is None
    assert cm.plan((2.55, 0.55), (2.55, 1.55)) is not None


@pytest.mark.parametrize("obstacle", ["gap", "box"])
def test_without_cost_weight_shortcuts_still_respect_the_lethal_cells(obstacle):
    # w = 0: the shortcut's cost test reduces to length, only the lethal cells guard it
    start, goal = (0.0, 0.0), (10.0, 0.0)
    if obstacle == "gap":
        wall = np.vstack(
            [_segment_points((5.0, -6.0), (5.0, 1.5)), _segment_points((5.0, 3.0), (5.0, 9.0))]
        )
        cm = _map(start, goal, wall)
    else:
        box = np.array([[3.0, -2.0], [7.0, -2.0], [7.0, 2.0], [3.0, 2.0]])
        cm = _map(start, goal, polygons=[box])
    path = cm.plan(start, goal, cost_weight=0.0)
    assert path is not None
    _check_polyline(path, start, goal)
    guaranteed = R - RES / math.sqrt(2.0)
    if obstacle == "gap":
        clear = _clearance(path, wall)
    else:
        clear = _rectangle_distance(_samples(path.waypoints), 3.0, 7.0, -2.0, 2.0).min()
    assert guaranteed <= clear < R + 2.0 * RES, "hugs the obstacle, never closer than guaranteed"


def test_rectangle_keep_out_is_gone_around():
    start, goal = (0.0, 0.0), (10.0, 0.0)
    box = np.array([[3.0, -2.0], [7.0, -2.0], [7.0, 2.0], [3.0, 2.0]])
    cm = _map(start, goal, polygons=[box], margin=4.0)
    path = cm.plan(start, goal)
    assert path is not None
    _check_polyline(path, start, goal)
    d = _rectangle_distance(_samples(path.waypoints), 3.0, 7.0, -2.0, 2.0)
    assert d.min() >= R, "no segment enters the keep-out inflated by the robot radius"
    assert np.abs(path.waypoints[:, 1]).max() > 2.0 + R


def test_enclosed_goal_is_unreachable():
    start, goal = (0.0, 0.0), (8.0, 0.0)
    ring = _circle_points(goal, 1.5)
    assert _map(start, goal, ring).plan(start, goal) is None
    # the same ring with a wide door is entered
    door = ring[ring[:, 0] > 8.0 - 1.5 * math.cos(0.6)]
    path = _map(start, goal, door).plan(start, goal)
    assert path is not None
    _check_polyline(path, start, goal)
    assert _clearance(path, door) >= R


def test_goal_inside_an_obstacle_ends_within_tolerance():
    start, goal = (0.0, 0.0), (8.0, 0.0)
    block = np.array([[7.8, -0.2], [8.2, -0.2], [8.2, 0.2], [7.8, 0.2]])
    cm = _map(start, goal, polygons=[block])
    assert cm.lethal[cm.cell_of(goal)]
    path = cm.plan(start, goal, goal_tolerance=1.0)
    assert path is not None
    _check_polyline(path, start, goal, tolerance=1.0)
    end = path.waypoints[-1:]
    assert not cm.lethal[cm.cell_of(end[0])]
    assert _rectangle_distance(end, 7.8, 8.2, -0.2, 0.2)[0] >= R
    assert _rectangle_distance(_samples(path.waypoints), 7.8, 8.2, -0.2, 0.2).min() >= R
    # too tight a tolerance: no free cell near the goal
    assert cm.plan(start, goal, goal_tolerance=0.3) is None


def test_points_outside_the_window_and_goal_outside_raise():
    cm = Costmap.around((0.0, 0.0), (4.0, 0.0), margin=1.0)
    with pytest.raises(ValueError):
        cm.plan((0.0, 0.0), (40.0, 0.0))
    with pytest.raises(ValueError):
        cm.inflate(-0.1, 0.2)


# -- optimality against a reference Dijkstra ------------------------------------------------------
def _dijkstra(cm: Costmap, start_cell, goal_cells, weight):
    """Reference search: same step cost, no heuristic, no corner cutting."""
    rows, cols = cm.shape
    blocked = cm.lethal.copy()
    mult = 1.0 + weight * cm.cost
    dist = {start_cell: 0.0}
    heap = [(0.0, start_cell)]
    done = set()
    while heap:
        d, (i, j) = heapq.heappop(heap)
        if (i, j) in done:
            continue
        done.add((i, j))
        if goal_cells[i, j]:
            return d
        for di in (-1, 0, 1):
            for dj in (-1, 0, 1):
                ni, nj = i + di, j + dj
                if (di, dj) == (0, 0) or not (0 <= ni < rows and 0 <= nj < cols):
                    continue
                if blocked[ni, nj] or (di and dj and (blocked[i + di, j] or blocked[i, j + dj])):
                    continue
                step = math.hypot(di, dj) * RES * 0.5 * (mult[i, j] + mult[ni, nj])
                if d + step < dist.get((ni, nj), math.inf):
                    dist[(ni, nj)] = d + step
                    heapq.heappush(heap, (d + step, (ni, nj)))
    return None


@settings(max_examples=15, deadline=None)
@given(
    seed=st.integers(0, 2**31),
    goal_in_obstacle=st.booleans(),
)
def test_astar_cost_matches_reference_dijkstra(seed, goal_in_obstacle):
    rng = np.random.default_rng(seed)
    start, goal = (0.5, 0.5), (5.5, 4.5)
    cm = Costmap((0.0, 0.0), RES, (50, 60))
    pts = [
        _circle_points(rng.uniform([1.5, 1.0], [4.5, 4.0]), rng.uniform(0.2, 0.8)) for _ in range(4)
    ]
    cm.add_points(np.vstack(pts))
    if goal_in_obstacle:
        cm.add_points(np.array([goal]))
    cm.inflate(0.2, 0.4)
    tol = 0.5
    path = cm.plan(start, goal, goal_tolerance=tol, cost_weight=5.0)
    if cm.lethal[cm.cell_of(start)]:
        return
    ii, jj = np.indices(cm.shape)
    if cm.lethal[cm.cell_of(goal)]:
        centres = np.stack([(jj + 0.5) * RES, (ii + 0.5) * RES], axis=-1)
        goal_cells = (np.hypot(*(centres - goal).transpose(2, 0, 1)) <= tol) & ~cm.lethal
    else:
        goal_cells = np.zeros(cm.shape, dtype=bool)
        goal_cells[cm.cell_of(goal)] = True
    reference = _dijkstra(cm, cm.cell_of(start), goal_cells, 5.0)
    if reference is None:
        assert path is None
    else:
        assert path is not None
        assert path.cost == pytest.approx(reference, rel=1e-9)


# -- property: random disc obstacles --------------------------------------------------------------
discs = st.lists(
    st.tuples(st.floats(2.0, 8.0), st.floats(-3.0, 3.0), st.floats(0.2, 1.2)),
    min_size=1,
    max_size=6,
)


@settings(max_examples=30, deadline=None)
@given(discs=discs)
def test_random_discs_paths_are_clear_and_reach_the_goal(discs):
    start, goal = (0.0, 0.0), (10.0, 0.0)
    tol = 0.3
    points = np.vstack([_circle_points((x, y), r) for x, y, r in discs])
    cm = _map(start, goal, points, margin=3.0)
    path = cm.plan(start, goal, goal_tolerance=tol)
    if path is None:
        return
    _check_polyline(path, start, goal, tolerance=tol)
    assert path.length >= math.hypot(goal[0] - start[0], goal[1] - start[1]) - 1e-9
    assert _clearance(path, points) >= R - RES
    assert path.cells_expanded >= len(path.cells)
