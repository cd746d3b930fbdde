"""Grid costmap and A* planner: the fallback of the spiral avoidance when trapped (issue 6).

When the spiral cannot make progress (a concave obstacle, a wall longer than its radius)
the robot plans a path on a costmap built from the laser returns, the virtual zone walls
and the known aircraft footprint, then follows the waypoints with go-to-goal. A pure law:
numpy, scipy.ndimage and heapq; every quantity is in the airport frame A (metres).

Grid
----
A :class:`Costmap` is a window of ``rows x cols`` square cells of side ``resolution``
whose lower-left corner is ``origin``; cell ``(i, j)`` (row i along y, column j along x)
covers ``origin + [j, j + 1) x [i, i + 1) * resolution`` and its centre is at
``origin + (j + 1/2, i + 1/2) * resolution``. A map is built fresh for one request:
:meth:`Costmap.around` sizes the window, :meth:`Costmap.add_points` and
:meth:`Costmap.add_polygons` mark occupied cells, :meth:`Costmap.inflate` sets the robot's
size and :meth:`Costmap.plan` searches.

Inflation
---------
``d`` is the Euclidean distance transform of the free cells: the distance from a cell's
centre to the nearest occupied cell's centre. A cell is *lethal* when some point of it
may be closer than ``robot_radius`` to an occupied cell's centre, i.e. when
``d < r_lethal = robot_radius + resolution / sqrt(2)`` (half a cell diagonal). A path
through non-lethal cells therefore keeps ``robot_radius`` from every occupied cell centre
and at least ``robot_radius - resolution / sqrt(2)`` from every obstacle point (a point
lies within half a diagonal of its cell's centre). Beyond the lethal region the cost
decays *linearly* from 1 at ``d = r_lethal`` to 0 at ``d = r_lethal + clearance``, so that
the path keeps away from obstacles when it can. :meth:`Costmap.inflate` only records the
two distances; the layers are computed, lazily, from the obstacles present when a plan is
requested, so obstacles may be added before or after it. Without a call to it the robot
is a point (``robot_radius = clearance = 0``).

Search
------
A* on the 8-connected grid. A step from cell a to a neighbour b of length ``l`` (one or
sqrt(2) cells) costs ``l * (1 + w (c_a + c_b) / 2)`` metres, with ``c`` the cell cost and
``w = cost_weight`` (default 5: a cell at the lethal edge costs six times a free one). A
diagonal step is forbidden when either of the two cells it squeezes between is blocked
(no corner cutting). The heuristic is the octile distance to the goal cell less the
largest octile distance from the goal cell to an accepted goal cell: a lower bound of
the path length, admissible and consistent since every step costs at least its length.

Trapped start. The robot is next to an obstacle when it is trapped, so its cell is often
lethal. The search may then traverse the *escape region*: the 8-connected component,
containing the start cell, of the lethal cells that are unoccupied, within ``2 r_lethal``
of the start cell and no closer to an obstacle than the start cell less one cell
(``d >= d_start - resolution``). The robot thus leaves the lethal region nearby (far
enough to back out of a corner) without getting closer to the obstacles than it already
is, and a too-narrow gap elsewhere stays blocked. Occupied cells are never entered (the
start cell itself may always be left). Inside the region the cost is ``1 + (r_lethal - d)
/ r_lethal`` (from 1 at the lethal edge to 2 on an obstacle), so the search leaves it by
the shallowest way out.

Goal. If the goal cell is not lethal the path ends at the goal itself. Otherwise any
non-lethal cell whose centre is within ``goal_tolerance`` of the goal is accepted and the
path ends at that cell's centre; no such cell, or no path, gives None.

Simplification. The cell path (start, cell centres, end) is shortcut by line of sight:
from the last kept waypoint the path is pulled forward while the straight segment to the
next raw point only touches cells the search could use (supercover walk: every cell the
segment touches, corners included) and its cost under the search's own metric (length
times ``1 + w c`` averaged along the segment, sampled every quarter cell) does not exceed
the cost of the raw steps it replaces by more than the fraction ``shortcut_slack``
(default 0.01). A shortcut that would graze an obstacle the grid path kept away from
costs more than that path, so it is refused; the remaining waypoints can be followed one
after the other with go-to-goal.
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from executive.core.frames import FloatArray

__all__ = ["Costmap", "PlannedPath"]

COST_WEIGHT = 5.0
"""Default ``w`` of the step cost ``length * (1 + w * cost)``."""
SHORTCUT_SLACK = 0.01
"""Default relative cost increase a shortcut may add over the raw steps it replaces."""

_SQRT2 = math.sqrt(2.0)
_EIGHT = np.ones((3, 3), dtype=bool)
_EPS = 1e-9

BoolArray = NDArray[np.bool_]
IntArray = NDArray[np.int64]


@dataclass(frozen=True, slots=True, eq=False)
class PlannedPath:
    """A path found by :meth:`Costmap.plan` (frame A, metres; compared by identity)."""

    waypoints: FloatArray
    """K x 2 simplified waypoints, from the start to the goal (or the accepted goal cell)."""
    length: float
    """Length of the waypoint polyline."""
    cells_expanded: int
    """Cells the A* search expanded."""
    cost: float
    """A* cost of the raw cell path (metres weighted by ``1 + w * cost``)."""
    cells: IntArray
    """N x 2 raw cell path as (row, column) indices, start cell first."""


@dataclass(slots=True)
class _Layers:
    """Inflated layers of a costmap, valid for one set of obstacles and distances."""

    distance: FloatArray
    lethal: BoolArray
    cost: FloatArray
    r_lethal: float


class Costmap:
    """Occupancy grid in frame A, inflated by the robot's size, with an A* planner.

    Built fresh for one planning request; see the module docstring for the conventions.
    """

    __slots__ = ("_clearance", "_layers", "_occupied", "_robot_radius", "origin", "resolution")

    def __init__(
        self, origin: tuple[float, float], resolution: float, shape: tuple[int, int]
    ) -> None:
        """An empty map: lower-left corner ``origin``, ``shape = (rows, cols)`` cells."""
        if not resolution > 0.0:
            raise ValueError("resolution must be > 0")
        rows, cols = int(shape[0]), int(shape[1])
        if rows < 1 or cols < 1:
            raise ValueError("a costmap has at least one cell")
        self.origin = (float(origin[0]), float(origin[1]))
        self.resolution = float(resolution)
        self._occupied = np.zeros((rows, cols), dtype=bool)
        self._robot_radius = 0.0
        self._clearance = 0.0
        self._layers: _Layers | None = None

    @classmethod
    def around(
        cls,
        start: tuple[float, float],
        goal: tuple[float, float],
        margin: float = 8.0,
        resolution: float = 0.1,
        max_cells: int = 400_000,
    ) -> Costmap:
        """A window covering start and goal plus ``margin`` on every side.

        The resolution is coarsened (by the smallest factor found) when the window would
        need more than ``max_cells`` cells.
        """
        if not (margin >= 0.0 and resolution > 0.0 and max_cells >= 1):
            raise ValueError("margin >= 0, resolution > 0 and max_cells >= 1 required")
        x0 = min(start[0], goal[0]) - margin
        y0 = min(start[1], goal[1]) - margin
        width = abs(goal[0] - start[0]) + 2.0 * margin
        height = abs(goal[1] - start[1]) + 2.0 * margin
        res = float(resolution)
        while True:
            cols = max(1, math.ceil(width / res - _EPS))
            rows = max(1, math.ceil(height / res - _EPS))
            if rows * cols <= max_cells:
                break
            res *= max(1.001, math.sqrt(rows * cols / max_cells))
        # centre the window on the requested area
        x0 -= 0.5 * (cols * res - width)
        y0 -= 0.5 * (rows * res - height)
        return cls((x0, y0), res, (rows, cols))

    # -- geometry ------------------------------------------------------------------------------
    @property
    def shape(self) -> tuple[int, int]:
        """(rows, cols)."""
        return self._occupied.shape[0], self._occupied.shape[1]

    @property
    def occupied(self) -> BoolArray:
        """Occupied cells (rows x cols, read-only view)."""
        view = self._occupied.view()
        view.flags.writeable = False
        return view

    @property
    def lethal(self) -> BoolArray:
        """Lethal cells for the current obstacles and robot size (read-only)."""
        view = self._inflated().lethal.view()
        view.flags.writeable = False
        return view

    @property
    def cost(self) -> FloatArray:
        """Cost of the cells in [0, 1] (1 on lethal cells; read-only)."""
        view = self._inflated().cost.view()
        view.flags.writeable = False
        return view

    def cell_of(self, point: tuple[float, float] | FloatArray) -> tuple[int, int] | None:
        """(row, col) of the cell containing ``point``, None outside the window."""
        j = math.floor((float(point[0]) - self.origin[0]) / self.resolution)
        i = math.floor((float(point[1]) - self.origin[1]) / self.resolution)
        rows, cols = self.shape
        return (i, j) if 0 <= i < rows and 0 <= j < cols else None

    def _centres(self, cells: IntArray) -> FloatArray:
        """Centres (x, y) of N x 2 (row, col) cells."""
        cells = np.asarray(cells, dtype=float).reshape(-1, 2)
        x = self.origin[0] + (cells[:, 1] + 0.5) * self.resolution
        y = self.origin[1] + (cells[:, 0] + 0.5) * self.resolution
        return np.column_stack([x, y])

    # -- obstacles -----------------------------------------------------------------------------
    def add_points(self, points: FloatArray) -> None:
        """Mark the cells containing ``points`` (N x 2) occupied; points outside are ignored."""
        pts = np.asarray(points, dtype=float).reshape(-1, 2)
        if pts.size == 0:
            return
        j = np.floor((pts[:, 0] - self.origin[0]) / self.resolution)
        i = np.floor((pts[:, 1] - self.origin[1]) / self.resolution)
        rows, cols = self.shape
        keep = (i >= 0) & (i < rows) & (j >= 0) & (j < cols)
        self._occupied[i[keep].astype(np.int64), j[keep].astype(np.int64)] = True
        self._layers = None

    def add_polygons(self, polygons: Iterable[FloatArray]) -> None:
        """Fill polygons (each M x 2, closed implicitly) occupied.

        A cell is occupied when its centre is inside (even-odd rule, vectorised over the
        cells of the polygon's bounding box) or when the outline crosses it, so a polygon
        thinner than a cell is not missed.
        """
        res = self.resolution
        rows, cols = self.shape
        for polygon in polygons:
            poly = np.asarray(polygon, dtype=float).reshape(-1, 2)
            if len(poly) == 0:
                continue
            # outline: sample every edge finer than a quarter cell
            ends = np.roll(poly, -1, axis=0)
            for a, b in zip(poly, ends, strict=True):
                n = max(2, math.ceil(4.0 * float(np.hypot(*(b - a))) / res) + 1)
                t = np.linspace(0.0, 1.0, n)[:, None]
                self.add_points(a + t * (b - a))
            if len(poly) < 3:
                continue
            lo = np.floor((poly.min(axis=0) - self.origin) / res).astype(int)
            hi = np.floor((poly.max(axis=0) - self.origin) / res).astype(int)
            j0, j1 = max(lo[0], 0), min(hi[0], cols - 1)
            i0, i1 = max(lo[1], 0), min(hi[1], rows - 1)
            if j0 > j1 or i0 > i1:
                continue
            jj, ii = np.meshgrid(np.arange(j0, j1 + 1), np.arange(i0, i1 + 1))
            px = self.origin[0] + (jj + 0.5) * res
            py = self.origin[1] + (ii + 0.5) * res
            inside = np.zeros(px.shape, dtype=bool)
            for (xa, ya), (xb, yb) in zip(poly, ends, strict=True):
                if ya == yb:
                    continue
                crosses = (ya > py) != (yb > py)
                x_cross = xa + (py - ya) * (xb - xa) / (yb - ya)
                inside ^= crosses & (px < x_cross)
            self._occupied[i0 : i1 + 1, j0 : j1 + 1] |= inside
            self._layers = None

    def inflate(self, robot_radius: float, clearance: float) -> None:
        """Set the robot's radius and the clearance band (in place; see the module docstring).

        Cells with ``d < robot_radius + resolution / sqrt(2)`` are lethal; the cost decays
        linearly from 1 to 0 over the next ``clearance`` metres. The layers follow the
        obstacles present when they are used.
        """
        if not (robot_radius >= 0.0 and clearance >= 0.0):
            raise ValueError("robot_radius and clearance must be >= 0")
        self._robot_radius = float(robot_radius)
        self._clearance = float(clearance)
        self._layers = None

    def _inflated(self) -> _Layers:
        if self._layers is not None:
            return self._layers
        r_lethal = self._robot_radius + self.resolution / _SQRT2
        if self._occupied.any():
            distance = np.asarray(
                ndimage.distance_transform_edt(~self._occupied, sampling=self.resolution),
                dtype=float,
            )
        else:
            distance = np.full(self.shape, np.inf)
        lethal = distance < r_lethal
        if self._clearance > 0.0:
            cost = np.clip((r_lethal + self._clearance - distance) / self._clearance, 0.0, 1.0)
        else:
            cost = lethal.astype(float)
        cost[lethal] = 1.0
        self._layers = _Layers(distance, lethal, cost, r_lethal)
        return self._layers

    # -- planning ------------------------------------------------------------------------------
    def plan(
        self,
        start: tuple[float, float],
        goal: tuple[float, float],
        goal_tolerance: float = 0.3,
        *,
        cost_weight: float = COST_WEIGHT,
        shortcut_slack: float = SHORTCUT_SLACK,
    ) -> PlannedPath | None:
        """A* from ``start`` to ``goal`` (both inside the window); None when unreachable.

        See the module docstring for the step cost, the trapped start, the goal tolerance
        and the line-of-sight simplification.
        """
        if not (goal_tolerance >= 0.0 and cost_weight >= 0.0 and shortcut_slack >= 0.0):
            raise ValueError("goal_tolerance, cost_weight and shortcut_slack must be >= 0")
        s_cell, g_cell = self.cell_of(start), self.cell_of(goal)
        if s_cell is None or g_cell is None:
            raise ValueError("start and goal must lie inside the costmap window")
        layers = self._inflated()

        # passable cells and their extended cost (escape region above 1)
        passable = ~layers.lethal
        ext = layers.cost.copy()
        if layers.lethal[s_cell]:
            escape = self._escape_region(layers, s_cell)
            passable |= escape
            depth = np.clip(1.0 - layers.distance / layers.r_lethal, 0.0, 1.0)
            ext[escape] = 1.0 + depth[escape]

        # accepted goal cells
        if not layers.lethal[g_cell]:
            goal_cells = np.zeros(self.shape, dtype=bool)
            goal_cells[g_cell] = True
            goal_xy = np.array(goal, dtype=float)
        else:
            ii, jj = np.indices(self.shape)
            centres_x = self.origin[0] + (jj + 0.5) * self.resolution
            centres_y = self.origin[1] + (ii + 0.5) * self.resolution
            near = np.hypot(centres_x - goal[0], centres_y - goal[1]) <= goal_tolerance
            goal_cells = near & ~layers.lethal
            if not goal_cells.any():
                return None
            goal_xy = None

        found = _astar(passable, ext, s_cell, g_cell, goal_cells, cost_weight, self.resolution)
        if found is None:
            return None
        cells, g_cost, expanded = found
        end_xy = goal_xy if goal_xy is not None else self._centres(cells[-1:])[0]
        raw = self._centres(cells)
        raw[0] = start
        if len(cells) == 1:
            raw = np.vstack([raw, end_xy])
            cumulative = np.zeros(2)
        else:
            raw[-1] = end_xy
            mult = 1.0 + cost_weight * ext[cells[:, 0], cells[:, 1]]
            steps = np.hypot(*np.diff(raw, axis=0).T)  # the true ends, not their centres
            cumulative = np.concatenate([[0.0], np.cumsum(steps * 0.5 * (mult[:-1] + mult[1:]))])
        waypoints = self._shortcut(raw, cumulative, passable, ext, cost_weight, shortcut_slack)
        length = float(np.sum(np.hypot(*np.diff(waypoints, axis=0).T)))
        return PlannedPath(waypoints, length, expanded, g_cost, cells)

    def _escape_region(self, layers: _Layers, s_cell: tuple[int, int]) -> BoolArray:
        """Lethal cells the search may cross from a lethal start (module docstring)."""
        rows, cols = self.shape
        si, sj = s_cell
        k = math.ceil(2.0 * layers.r_lethal / self.resolution)
        i0, i1, j0, j1 = (
            max(si - k, 0),
            min(si + k + 1, rows),
            max(sj - k, 0),
            min(sj + k + 1, cols),
        )
        ii, jj = np.indices((i1 - i0, j1 - j0))
        near = np.hypot(ii + i0 - si, jj + j0 - sj) * self.resolution <= 2.0 * layers.r_lethal
        distance = layers.distance[i0:i1, j0:j1]
        seed = (
            near
            & layers.lethal[i0:i1, j0:j1]
            & ~self._occupied[i0:i1, j0:j1]
            & (distance >= layers.distance[s_cell] - self.resolution)
        )
        seed[si - i0, sj - j0] = True
        labels, _ = ndimage.label(seed, structure=_EIGHT)
        escape = np.zeros(self.shape, dtype=bool)
        escape[i0:i1, j0:j1] = labels == labels[si - i0, sj - j0]
        return escape

    def _shortcut(
        self,
        raw: FloatArray,
        cumulative: FloatArray,
        passable: BoolArray,
        ext: FloatArray,
        weight: float,
        slack: float,
    ) -> FloatArray:
        """Line-of-sight simplification of the raw point path (module docstring).

        ``cumulative[k]`` is the search's cost from the start to raw point k.
        """
        kept = [0]
        anchor = 0
        for j in range(1, len(raw) - 1):
            budget = (cumulative[j + 1] - cumulative[anchor]) * (1.0 + slack) + _EPS
            if not self._segment_fits(raw[anchor], raw[j + 1], passable, ext, weight, budget):
                kept.append(j)
                anchor = j
        kept.append(len(raw) - 1)
        return raw[kept].copy()

    def _segment_fits(
        self,
        a: FloatArray,
        b: FloatArray,
        passable: BoolArray,
        ext: FloatArray,
        weight: float,
        budget: float,
    ) -> bool:
        """Whether the segment a -> b touches only passable cells and costs <= budget."""
        origin = np.asarray(self.origin)
        ga, gb = (a - origin) / self.resolution, (b - origin) / self.resolution
        i, j = _supercover(ga, gb)
        rows, cols = self.shape
        if not ((i >= 0) & (i < rows) & (j >= 0) & (j < cols)).all():
            return False
        if not passable[i, j].all():
            return False
        cells_long = float(np.hypot(*(gb - ga)))
        n = max(1, math.ceil(4.0 * cells_long))
        t = (np.arange(n) + 0.5) / n
        pts = np.floor(ga + t[:, None] * (gb - ga)).astype(np.int64)
        mean_cost = float(ext[pts[:, 1], pts[:, 0]].mean())
        return cells_long * self.resolution * (1.0 + weight * mean_cost) <= budget


def _supercover(a: FloatArray, b: FloatArray) -> tuple[IntArray, IntArray]:
    """(rows, cols) of every unit cell the segment a -> b (grid units, x then y) touches.

    The cells around each crossing of a grid line (four around a crossed corner) and the
    cells of the two ends; duplicates are kept.
    """
    d = b - a
    ts = [np.array([0.0, 1.0])]
    for k in (0, 1):
        if abs(d[k]) > _EPS:
            lo, hi = sorted((a[k], b[k]))
            lines = np.arange(math.floor(lo) + 1, math.ceil(hi))
            ts.append((lines - a[k]) / d[k])
    t = np.concatenate(ts)
    pts = a + t[:, None] * d
    off = np.array([[-_EPS, -_EPS], [-_EPS, _EPS], [_EPS, -_EPS], [_EPS, _EPS]]) * 1e3
    around = np.floor(pts[:, None, :] + off[None, :, :]).reshape(-1, 2).astype(np.int64)
    ends = np.floor(np.vstack([a, b])).astype(np.int64)
    cells = np.vstack([around, ends])
    return cells[:, 1], cells[:, 0]


def _astar(
    passable: BoolArray,
    ext: FloatArray,
    s_cell: tuple[int, int],
    g_cell: tuple[int, int],
    goal_cells: BoolArray,
    weight: float,
    resolution: float,
) -> tuple[IntArray, float, int] | None:
    """A* over flat indices of the grid padded by one blocked cell on every side.

    Returns the cell path (start first), its cost in metres and the expanded count.
    """
    rows, cols = passable.shape
    width = cols + 2
    n = (rows + 2) * width
    pad_pass = np.zeros((rows + 2, cols + 2), dtype=bool)
    pad_pass[1:-1, 1:-1] = passable
    s_pad = (s_cell[0] + 1, s_cell[1] + 1)
    pad_pass[s_pad] = True
    mult_grid = np.full((rows + 2, cols + 2), math.inf)
    mult_grid[1:-1, 1:-1] = 1.0 + weight * ext
    mult_grid[~pad_pass] = math.inf
    mult: list[float] = (0.5 * resolution * mult_grid).ravel().tolist()
    pad_goal = np.zeros((rows + 2, cols + 2), dtype=bool)
    pad_goal[1:-1, 1:-1] = goal_cells
    is_goal = bytearray(pad_goal.ravel().tobytes())

    # octile heuristic, less the spread of the accepted goal cells
    gi, gj = np.nonzero(goal_cells)
    spread = _octile(gi - g_cell[0], gj - g_cell[1]).max()
    ii, jj = np.indices((rows + 2, cols + 2))
    h_grid = _octile(ii - 1 - g_cell[0], jj - 1 - g_cell[1]) - spread
    h: list[float] = (resolution * np.maximum(h_grid, 0.0)).ravel().tolist()

    inf = math.inf
    sq2 = _SQRT2
    # (flat offset, step length in cells, orthogonal offsets squeezed by a diagonal)
    moves = [
        (1, 1.0, 0, 0),
        (-1, 1.0, 0, 0),
        (width, 1.0, 0, 0),
        (-width, 1.0, 0, 0),
        (width + 1, sq2, width, 1),
        (width - 1, sq2, width, -1),
        (-width + 1, sq2, -width, 1),
        (-width - 1, sq2, -width, -1),
    ]
    start = s_pad[0] * width + s_pad[1]
    g = [inf] * n
    parent = [-1] * n
    closed = bytearray(n)
    g[start] = 0.0
    heap: list[tuple[float, float, int]] = [(h[start], h[start], start)]
    expanded = 0
    reached = -1
    heappop, heappush = heapq.heappop, heapq.heappush
    while heap:
        _, _, a = heappop(heap)
        if closed[a]:
            continue
        closed[a] = 1
        expanded += 1
        if is_goal[a]:
            reached = a
            break
        ga = g[a]
        ma = mult[a]
        for off, step, o1, o2 in moves:
            b = a + off
            if closed[b]:
                continue
            mb = mult[b]
            if mb == inf or (o1 and (mult[a + o1] == inf or mult[a + o2] == inf)):
                continue
            nb = ga + step * (ma + mb)
            if nb < g[b]:
                g[b] = nb
                parent[b] = a
                hb = h[b]
                heappush(heap, (nb + hb, hb, b))
    if reached < 0:
        return None
    path = [reached]
    while path[-1] != start:
        path.append(parent[path[-1]])
    flat = np.array(path[::-1], dtype=np.int64)
    cells = np.column_stack([flat // width - 1, flat % width - 1])
    return cells, g[reached], expanded


def _octile(di: IntArray, dj: IntArray) -> FloatArray:
    """Octile distance in cells for index offsets (di, dj)."""
    adi, adj = np.abs(di), np.abs(dj)
    return np.maximum(adi, adj) + (_SQRT2 - 1.0) * np.minimum(adi, adj)
