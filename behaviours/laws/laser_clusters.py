"""Laser obstacle detection: merge, clean, cluster and classify (thesis Algorithm 2.1).

The thesis's obstacle pipeline (seed 000, lines 780-830, Algorithm 2.1 and Fig. 2.3):
read the raw scans, clean them "by removing isolated points or accumulations of points
that are below a predefined threshold", cluster the remaining points into obstacles, then
run a RANSAC on every cluster "to determine whether any of these obstacles are either
lines or circles". Tracking (the last step of Fig. 2.3) is :mod:`behaviours.laws.tracking`.

Steps of :meth:`ScanClusterer.detect`, all vectorised (no loop over points; the only
Python loops run over a few offsets, refinement rounds, candidate cluster pairs or the
few segments two tracked objects may share):

1. **Merge** (:func:`merge_scans`): every scan of both scanners into the robot frame R
   (:func:`behaviours.laws.obstacles.scan_to_robot`), keeping per point its range, scanner
   and beam index, so that neighbourhoods in beam order are known. No-return beams
   (``range_max``) are left out.
2. **Clean** (:func:`neighbour_mask`): a point is kept only if ``min_neighbours`` of its
   ``k`` nearest beams on either side (same scan) returned points within the adaptive
   breakpoint distance below; isolated points and pairs (spurious returns, rain, dust,
   the uniform outliers of a faulty scan) are removed.
3. **Segment** (:func:`segment`): the adaptive breakpoint detector of Borges & Aldon
   (2004) in beam order per scanner: two kept points ``p, q`` of one object satisfy
   ``|p - q| <= D_max`` with

       D_max = r * sin(dphi) / sin(lambda - dphi) + 3 sigma_r,     dphi = g * |dtheta|

   ``r`` the smaller range of the two, ``g`` their beam gap (removed points and no-return
   beams between them widen it), ``lambda`` the largest incidence angle of a surface still
   seen as one object, ``sigma_r`` the range noise. Each kept point is tested against the
   next ``skip`` kept points of its scan, and segments are the connected components of
   the links, so segments separated only by removed outliers (or by a few stray points
   kept among them) are one. Segments of fewer than ``min_points`` points are dropped
   (the thesis's small accumulations). Segments of two scanners whose points touch
   (within ``merge_distance``: an object beside the robot seen by both) are merged.
   :func:`occluded` flags the clusters whose view is cut by something in front. Given
   the tracker's predictions, :func:`split_by_tracks` cuts a segment that is two tracked
   objects touching (a walker against a post) back into the objects.
4. **Classify** (:func:`fit_clusters`): RANSAC (Fischler & Bolles 1981) with the MSAC
   truncated quadratic cost (Torr & Zisserman 2000), batched across clusters: a fixed
   number of hypotheses per cluster, lines from 2 points and circles from 3 points drawn
   in separate parts of the cluster (stratified in beam order, so that the points are
   spread), scored on an evenly strided subsample. The best hypothesis is refined on its
   inliers: a line by total least squares (principal axis of the inlier scatter), its
   end points the projections of the extreme inliers; a circle by the algebraic fit of
   Kasa (1976) then Gauss-Newton steps on the geometric distance. A cluster is a
   **circle** when the circle model is valid (inlier fraction, radius bounds, centre on
   the far side of the arc from the sensor) and it explains the points significantly
   better than a line: the likelihood-ratio statistic
   ``(cost_line - cost_circle) / sigma_r^2`` exceeds ``model_chi2`` (a line is the
   limit of a circle of infinite radius, so the test prefers the line whenever it fits
   within the noise: a short arc of a big circle stays a line); otherwise a **line** when
   the line model is valid, else a **blob** (an L-shaped corner, a noisy group). A
   blob that is a box has for tracked point the centre of the rectangle fitted to it
   (:func:`box_centres`, an L-shape fit), not its centroid: a box seen as an
   L (a trolley, a ground power unit) shows both its faces whole, so the rectangle is
   the box whatever the view, while the centroid slides towards whichever face and
   corner return the most points (a static box seemed to move at 0.1-0.2 m/s as the
   robot drove round it, a crossing trolley to slow down).
5. **Line ends** (:func:`line_ends_visible`): whether each end of a line is the object's
   true end or only where the view of it stops (the next beam is out of the field of view,
   hits something in front of the line's extension, or hits the extension itself: the
   surface goes on). A line is tracked by its fitted position across itself, and along
   itself only when both ends are true (:mod:`behaviours.laws.tracking`): the visible part
   of a wall longer than the view slides along it as the robot moves.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from functools import lru_cache
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from behaviours.laws.obstacles import footprint_distances, scan_to_robot
from executive.core.frames import FloatArray, Pose2
from executive.core.records import LaserScan

IntArray = NDArray[np.intp]
BoolArray = NDArray[np.bool_]

#: Cluster kind codes (:attr:`Clusters.kind`) and their names (:data:`KIND_NAMES`).
LINE, CIRCLE, BLOB = 0, 1, 2
KIND_NAMES = ("line", "circle", "blob")


@dataclass(frozen=True, slots=True)
class ClusterParams:
    """Parameters of the detector; the defaults suit a Hokuyo UTM-30LX (0.25 deg, 30 m).

    ``range_sigma`` (m): 1-sigma range noise sigma_r (the UTM-30LX is specified at
    +-30 mm up to 10 m; sim2d's default noise is 0.01 m). It sets the breakpoint margin
    (3 sigma_r), the RANSAC inlier band (``inlier_sigmas`` sigma_r) and the scale of the
    line/circle test.
    ``incidence_limit`` (rad): lambda of the adaptive breakpoint detector; 10 deg as
    recommended by Borges & Aldon (2004).
    ``neighbour_beams``: k, the beams on either side searched for neighbours when
    removing isolated points; ``min_neighbours`` of them must return within D_max at one
    beam's gap (2: a pair of stray returns is removed too; a surface keeps its points).
    ``skip``: each kept point is linked to the next ``skip`` kept points of its scan, so
    that stray points kept among a surface's returns do not split it.
    ``max_gap``: the largest beam gap (removed or no-return beams in between) across which
    two points are still linked; D_max grows with the gap up to ``gap_scale_limit``
    beams (``gap_scale_limit * |dtheta| < incidence_limit``), then stays there, so that a
    hole does not link objects far apart in depth.
    ``min_points``: segments with fewer points are dropped (the thesis's accumulations
    below a threshold; 5 returns is a walker at about 25 m).
    ``split_margin`` (m): a tracked object's enclosing disc, grown by this, holds its
    returns when a segment is split between tracked objects (:func:`split_by_tracks`):
    the fits' bias and one scan's prediction error (a walker's position is known to a few
    centimetres; ten times the range noise).
    ``merge_distance`` (m): segments of two scanners are merged when a point of one is
    this close to a point of the other.
    ``range_margin`` (m): a cluster with a return this close to the range limit is cut by
    it (:attr:`Clusters.occluded`), and a line's end is true only if the beam beyond it
    would meet the line's extension this much within the limit.
    ``ransac_hypotheses``: hypotheses per cluster and model; ``ransac_points``: at most
    this many points of each cluster (evenly strided) score them.
    ``refinements``: least-squares refits on the current inliers after RANSAC.
    ``geometric_steps``: Gauss-Newton steps on the geometric circle distance after Kasa.
    ``inlier_sigmas``: the inlier band is ``inlier_sigmas * range_sigma``.
    ``min_inlier_fraction``: a model is valid only if it explains this share of points.
    ``min_radius``, ``max_radius`` (m): bounds of a circle (poles to gear legs).
    ``model_chi2``: likelihood-ratio threshold to prefer a circle over a line (9: about
    0.3 % false circles for one extra degree of freedom).
    ``seed``: seed of the RANSAC sampler (deterministic detector).
    """

    range_sigma: float = 0.02
    incidence_limit: float = math.radians(10.0)
    neighbour_beams: int = 4
    min_neighbours: int = 2
    max_gap: int = 16
    gap_scale_limit: int = 4
    skip: int = 3
    min_points: int = 5
    merge_distance: float = 0.3
    split_margin: float = 0.2
    range_margin: float = 1.0
    ransac_hypotheses: int = 12
    ransac_points: int = 16
    refinements: int = 1
    geometric_steps: int = 1
    inlier_sigmas: float = 3.0
    min_inlier_fraction: float = 0.8
    min_radius: float = 0.05
    max_radius: float = 2.0
    model_chi2: float = 9.0
    seed: int = 0

    def __post_init__(self) -> None:
        if not self.range_sigma > 0.0:
            raise ValueError("range_sigma must be > 0")
        if not 0.0 < self.incidence_limit < math.pi / 2:
            raise ValueError("incidence_limit must be in (0, pi/2)")
        if not 1 <= self.min_neighbours <= 2 * self.neighbour_beams:
            raise ValueError("need 1 <= min_neighbours <= 2 * neighbour_beams")
        if not 1 <= self.gap_scale_limit <= self.max_gap or self.skip < 1:
            raise ValueError("need 1 <= gap_scale_limit <= max_gap and skip >= 1")
        if self.min_points < 3:
            raise ValueError("min_points must be >= 3 (a circle needs 3 points)")
        if self.ransac_hypotheses < 1 or self.ransac_points < 3:
            raise ValueError("need ransac_hypotheses >= 1 and ransac_points >= 3")
        if not 0.0 < self.min_radius < self.max_radius:
            raise ValueError("need 0 < min_radius < max_radius")
        if not 0.0 < self.min_inlier_fraction <= 1.0:
            raise ValueError("min_inlier_fraction must be in (0, 1]")
        if not self.split_margin >= 0.0:
            raise ValueError("split_margin must be >= 0")

    @property
    def inlier_band(self) -> float:
        """epsilon (m): residuals below it are inliers; the MSAC cost saturates at it."""
        return self.inlier_sigmas * self.range_sigma


def breakpoint_distance(
    ranges: FloatArray | float, dphi: FloatArray | float, incidence_limit: float, sigma: float
) -> FloatArray:
    """D_max of the adaptive breakpoint detector (Borges & Aldon 2004).

    ``r sin(dphi) / sin(lambda - dphi) + 3 sigma``: the largest distance between two
    returns of one surface seen at range ``r`` by beams ``dphi`` apart, when the surface
    makes at least ``lambda`` with the beams, plus the range noise.
    """
    dphi = np.asarray(dphi, dtype=float)
    return np.asarray(ranges) * np.sin(dphi) / np.sin(incidence_limit - dphi) + 3.0 * sigma


@lru_cache(maxsize=32)
def _ratio_table(increments: tuple[float, ...], incidence_limit: float, gaps: int) -> FloatArray:
    """``sin(g dphi) / sin(lambda - g dphi)`` per scanner (rows) and beam gap g from 0 to
    ``gaps`` (columns)."""
    dphi = np.abs(np.asarray(increments))[:, None] * np.arange(gaps + 1)
    if np.any(dphi[:, -1] >= incidence_limit):
        raise ValueError("gap_scale_limit beams must span less than the incidence limit")
    table = breakpoint_distance(1.0, dphi, incidence_limit, 0.0)
    table.flags.writeable = False
    return table


# -- 1. merge -------------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True, eq=False)
class ScanPoints:
    """The returns of several scans in the robot frame R, scan after scan, in beam order.

    ``x``, ``y`` (N,) in R; ``ranges`` (N,); ``scanner`` (N,) the index of the scan in
    the input sequence; ``beam`` (N,) the beam index in its scan. ``sensors`` (S, 2) are
    the scanners' positions in R and ``increments`` (S,) their angle increments.
    """

    stamp: float
    x: FloatArray
    y: FloatArray
    ranges: FloatArray
    scanner: IntArray
    beam: IntArray
    sensors: FloatArray
    increments: tuple[float, ...]

    def __len__(self) -> int:
        return len(self.ranges)


def merge_scans(
    scans: Sequence[tuple[LaserScan, Pose2]], robot_points: Sequence[FloatArray] | None = None
) -> ScanPoints:
    """Step 1: the returns of every ``(scan, mount)`` in R; ``mount`` is R <- scanner.

    The stamp is the latest scan's (the caller passes the robot pose at that time).
    ``robot_points``: each scan's returns in R if the caller has them already
    (:func:`behaviours.laws.obstacles.scan_to_robot` of it), else they are computed.
    """
    xy, ranges, scanner, beam = [np.zeros((0, 2))], [np.zeros(0)], [], []
    for k, (scan, mount) in enumerate(scans):
        r = scan.ranges
        if robot_points is None:
            xy.append(scan_to_robot(r, scan.angle_min, scan.angle_increment, scan.range_max, mount))
        else:
            xy.append(robot_points[k])
        hit = (r < scan.range_max).nonzero()[0]
        beam.append(hit)
        ranges.append(r[hit])
        scanner.append(np.full(len(hit), k, dtype=np.intp))
    x, y = np.concatenate(xy).T.copy()
    return ScanPoints(
        stamp=max((s.stamp for s, _ in scans), default=0.0),
        x=x,
        y=y,
        ranges=np.concatenate(ranges),
        scanner=np.concatenate(scanner or [np.zeros(0, dtype=np.intp)]),
        beam=np.concatenate(beam or [np.zeros(0, dtype=np.intp)]),
        sensors=np.array([(m.x, m.y) for _, m in scans], dtype=float).reshape(-1, 2),
        increments=tuple(float(s.angle_increment) for s, _ in scans),
    )


# -- 2. clean -------------------------------------------------------------------------------------
class _Links:
    """The breakpoint test between pairs of points of :class:`ScanPoints` (or a subset)."""

    def __init__(
        self, points: ScanPoints, params: ClusterParams, idx: IntArray | None = None
    ) -> None:
        table = _ratio_table(points.increments, params.incidence_limit, params.gap_scale_limit)
        self.table = table.ravel()
        self.columns = table.shape[1]
        self.margin = 3.0 * params.range_sigma
        sel = slice(None) if idx is None else idx
        self.x, self.y, self.r = points.x[sel], points.y[sel], points.ranges[sel]
        self.scanner, self.beam = points.scanner[sel], points.beam[sel]

    def __call__(
        self,
        a: IntArray | slice | tuple[None, slice],
        b: IntArray | slice,
        max_gap: int,
        scale: int,
    ) -> BoolArray:
        """True for the pairs (a, b) of one scanner, 1 to ``max_gap`` beams apart, closer
        than D_max (:func:`breakpoint_distance` at the smaller range and their gap, the
        gap counted at most ``scale`` beams)."""
        sa = self.scanner[a]
        gap = self.beam[b] - self.beam[a]
        ok = (sa == self.scanner[b]) & (gap <= max_gap)
        ratio = self.table.take(sa * self.columns + np.minimum(np.abs(gap), scale))
        threshold = np.minimum(self.r[a], self.r[b]) * ratio + self.margin
        dx = self.x[b] - self.x[a]
        dy = self.y[b] - self.y[a]
        ok &= dx * dx + dy * dy <= threshold * threshold
        return ok

    def window(self, count: int, max_gap: int, scale: int) -> tuple[IntArray, IntArray]:
        """The linked pairs (a, b) with ``a < b <= a + count`` (positions in this
        subset), as two arrays, by offset ``b - a`` then by ``a``."""
        n = len(self.x)
        m = min(count, n - 1)
        if m < 1:
            return np.zeros(0, np.intp), np.zeros(0, np.intp)
        b, inside = _pair_grid(n, m)
        offset, a = (self((None, slice(None)), b, max_gap, scale) & inside).nonzero()
        return a, a + offset + 1


@lru_cache(maxsize=256)
def _pair_grid(n: int, m: int) -> tuple[IntArray, BoolArray]:
    """The pairs ``(a, a + j)`` of ``n`` points, ``a`` from 0 to ``n - 1`` (columns) and
    the offset j from 1 to ``m`` (rows): the grid (m, n) of ``a + j`` (clipped to the last
    point), and the mask of the pairs that exist (``a + j < n``)."""
    b = np.arange(n) + np.arange(1, m + 1)[:, None]
    inside = b < n
    b = np.minimum(b, n - 1)
    for grid in (b, inside):
        grid.flags.writeable = False
    return b, inside


def neighbour_mask(points: ScanPoints, params: ClusterParams) -> BoolArray:
    """Step 2: True for points with at least ``min_neighbours`` neighbours among their
    ``neighbour_beams`` nearest beams on either side (same scan) within the breakpoint
    distance D_max of one beam's gap."""
    a, b = _Links(points, params).window(params.neighbour_beams, params.neighbour_beams, 1)
    n = len(points)
    return np.bincount(a, minlength=n) + np.bincount(b, minlength=n) >= params.min_neighbours


# -- 3. segment -----------------------------------------------------------------------------------
def segment(points: ScanPoints, kept: BoolArray, params: ClusterParams) -> IntArray:
    """Step 3: a cluster label per point (-1: removed, or in a dropped accumulation).

    Kept points are linked to each of the next ``skip`` kept points of their scan when
    within the breakpoint distance D_max (their beam gap, at most ``max_gap``, counted
    at most ``gap_scale_limit`` beams): a hole of removed points or no-return beams does
    not split a surface, and a few stray points kept among its returns are skipped (they
    form their own small groups). Segments are the connected components of these links;
    those of fewer than ``min_points`` points are dropped; then segments of different
    scanners that touch are merged (:func:`_merge_across_scanners`). Labels are
    consecutive from 0.
    """
    labels = np.full(len(points), -1, dtype=np.intp)
    idx = kept.nonzero()[0]
    n = len(idx)
    if n < params.min_points:
        return labels
    linked = _Links(points, params, idx)
    a, b = linked.window(params.skip, params.max_gap, params.gap_scale_limit)
    root = _components(n, a, b)
    size = np.bincount(root, minlength=n)
    members = (size[root] >= params.min_points).nonzero()[0]
    if len(members) == 0:
        return labels
    label = _renumber(root[members], n)
    labels[idx[members]] = _merge_across_scanners(
        linked.x[members],
        linked.y[members],
        linked.scanner[members],
        label,
        params.merge_distance,
    )
    return labels


def _renumber(root: IntArray, n: int) -> IntArray:
    """Map node ids below ``n`` to consecutive labels from 0, in increasing order."""
    used = np.zeros(n, dtype=np.intp)
    used[root] = 1
    return (used.cumsum() - 1)[root]


def _components(n: int, a: IntArray, b: IntArray) -> IntArray:
    """Connected components of the graph of ``n`` nodes and edges (a, b): the smallest
    node of each node's component. Hook and compress (Shiloach & Vishkin 1982): every
    root is hooked to the smallest root it shares an edge with, then every node is
    pointed at its root by pointer jumping; repeated until no edge joins two roots."""
    parent = np.arange(n)
    while True:
        ra, rb = parent[a], parent[b]
        join = ra != rb
        if not join.any():
            return parent
        np.minimum.at(parent, np.maximum(ra, rb)[join], np.minimum(ra, rb)[join])
        while True:
            up = parent[parent]
            if (up == parent).all():
                break
            parent = up


def _merge_across_scanners(
    x: FloatArray, y: FloatArray, scanner: IntArray, label: IntArray, distance: float
) -> IntArray:
    """Union the clusters of different scanners whose points come within ``distance``.

    Where two scanners see one surface, their returns interleave in bearing about the
    robot's centre, or abut where their views meet: sorted by that bearing, a point of
    one scanner has a point of the other among its next :data:`_ANGULAR_NEIGHBOURS`.
    Those pairs closer than ``distance`` link their clusters. Returns the labels
    renumbered from 0.
    """
    order = np.arctan2(y, x).argsort()
    n = len(order)
    m = min(_ANGULAR_NEIGHBOURS, n - 1)
    if m < 1:
        return label
    j, inside = _pair_grid(n, m)  # every point and each of its next m in bearing order
    i, j = order, order[j]
    dx, dy = x[j] - x[i], y[j] - y[i]
    hit = ((dx * dx + dy * dy) <= distance * distance) & (scanner[j] != scanner[i]) & inside
    if not hit.any():
        return label
    a_all, b_all = label[i[hit.nonzero()[1]]], label[j[hit]]
    n = int(label.max()) + 1
    return _renumber(_components(n, a_all, b_all), n)[label]


#: neighbours in bearing order searched for a point of another scanner
_ANGULAR_NEIGHBOURS = 3


@dataclass(frozen=True, slots=True, eq=False)
class TrackHints:
    """The small objects a tracker predicts at the scans' stamp, for
    :func:`split_by_tracks`: ``position`` (k, 2) in R and enclosing ``radius`` (k,) of
    each; ``moving`` (k,): whether each one is a mover (none by default); ``ids`` (k,):
    the tracker's name for each (-1 by default), handed back with the segments cut out
    for a mover (:attr:`Clusters.carved_by`)."""

    position: FloatArray
    radius: FloatArray
    moving: BoolArray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    ids: IntArray = field(default_factory=lambda: np.zeros(0, dtype=np.intp))

    def __post_init__(self) -> None:
        k = len(self.radius)
        if len(self.moving) != k:
            object.__setattr__(self, "moving", np.zeros(k, dtype=bool))
        if len(self.ids) != k:
            object.__setattr__(self, "ids", np.full(k, -1, dtype=np.intp))


class Split(NamedTuple):
    """What :func:`split_by_tracks` made of the segments, per point: ``labels``;
    ``partial``, whether its segment was cut around a mover (both parts are then
    partial views); ``carver``, the index of the hinted mover whose own part it is
    (-1: none)."""

    labels: IntArray
    partial: BoolArray
    carver: IntArray


def _one_object(hints: TrackHints, rows: IntArray) -> bool:
    """Whether two of the hinted objects ``rows`` have each the other's centre inside
    its disc (one object tracked twice)."""
    p, r = hints.position[rows], hints.radius[rows]
    d = np.hypot(p[:, None, 0] - p[None, :, 0], p[:, None, 1] - p[None, :, 1])
    inside = d < np.minimum(r[:, None], r[None, :])
    np.fill_diagonal(inside, False)
    return bool(inside.any())


def split_by_tracks(
    x: FloatArray,
    y: FloatArray,
    labels: IntArray,
    hints: TrackHints,
    margin: float,
    min_points: int,
) -> Split:
    """Step 3b: split a segment that is tracked objects touching (track-aided
    segmentation).

    A walker or a trolley that comes against a post or a parked cart is one segment for
    the breakpoint detector: nothing separates their returns. Their union is another
    shape than either, bigger, its tracked point the middle of other points: the
    tracker can only re-anchor a track on it (or take it for structure), and the
    mover's track loses its velocity while it still moves (avoidance campaign episode
    979: a chaser at 0.32 m/s tracked at 0.03 m/s against a round blocker, until it
    struck the robot), while the other object's track, unfed, is deleted. The tracks
    already say where each object is: a segment whose every point lies within
    ``radius + margin`` of a hinted object is cut between those objects by the power
    diagram of their discs (a point goes to the object minimising ``d^2 - radius^2``, so
    a box's returns inside its enclosing circle stay its own beside a smaller post),
    provided at least two objects get ``min_points`` points each (the points of objects
    that get fewer go to their next best). Two hinted objects whose discs each hold the
    other's centre are one object tracked twice, not two: they never cut a segment.

    A segment that the hints do not cover whole (structure, a wall with a walker against
    it, an object not yet tracked, one too big to be hinted) is cut only for the hinted
    *movers* (``hints.moving``): the points within a mover's grown disc (between two
    movers, by power) become its own segment, if they are ``min_points`` or more and
    leave as many; everything else stays together. A chaser passing between a parked
    cart and a long box, all three one segment, was fed to its track as that 2.7 m
    blob, which only re-anchors a track: the chaser was taken for still until it struck
    the robot (avoidance campaign episode 558). A standing object's disc does not
    compete here (its track, fed such merged views, is anchored on their middle, and its
    disc there would hide the mover beside it), and a standing object's track loses
    nothing by a merge: it is still either way. Both parts of such a cut are partial
    views: the mover's is bounded by its disc and may hold a little of what it touches,
    the rest lacks what the mover hides.

    Returns the :class:`Split`: the labels (the new segments numbered after the existing
    ones), and per point whether its segment was cut around a mover and by which.
    """
    k = len(hints.radius)
    members = (labels >= 0).nonzero()[0]
    partial = np.zeros(len(labels), dtype=bool)
    carver = np.full(len(labels), -1, dtype=np.intp)
    if k == 0 or (k < 2 and not hints.moving.any()) or len(members) == 0:
        return Split(labels, partial, carver)
    lab = labels[members]
    n = int(lab.max()) + 1
    count = np.bincount(lab, minlength=n)
    cx = np.bincount(lab, x[members], n) / np.maximum(count, 1)
    cy = np.bincount(lab, y[members], n) / np.maximum(count, 1)
    r2 = np.zeros(n)
    np.maximum.at(r2, lab, (x[members] - cx[lab]) ** 2 + (y[members] - cy[lab]) ** 2)
    size = np.sqrt(r2)
    # a hint can cover part of a segment only if its disc reaches the segment's circle
    reach = size[:, None] + hints.radius[None, :] + margin
    gap_x = cx[:, None] - hints.position[:, 0]
    gap_y = cy[:, None] - hints.position[:, 1]
    close = gap_x * gap_x + gap_y * gap_y <= reach * reach
    candidates = ((close.sum(axis=1) >= 2) | (close & hints.moving).any(axis=1)).nonzero()[0]
    if len(candidates) == 0:
        return Split(labels, partial, carver)
    out = labels.copy()
    for s in candidates.tolist():
        idx = (labels == s).nonzero()[0]
        near = close[s].nonzero()[0]
        dx = x[idx, None] - hints.position[near, 0]
        dy = y[idx, None] - hints.position[near, 1]
        d2 = dx * dx + dy * dy
        radius = hints.radius[near]
        power = np.where(d2 <= (radius + margin) ** 2, d2 - radius * radius, np.inf)
        owner = power.argmin(axis=1)
        rows = np.arange(len(idx))
        if not np.isfinite(power[rows, owner]).all():
            # points no hinted object explains: not (only) these objects; the movers'
            # own points are cut out of the rest
            mover_power = np.where(hints.moving[near], power, np.inf)
            mover = mover_power.argmin(axis=1)
            mine = np.isfinite(mover_power[rows, mover])
            n = _cut_movers(out, carver, partial, idx, near[mover], mine, min_points, n)
            continue
        if len(near) < 2:
            continue  # one object, whole
        held = np.bincount(owner, minlength=len(near)) >= min_points
        if np.count_nonzero(held) < 2 or _one_object(hints, near[held]):
            continue
        power[:, ~held] = np.inf
        owner = power.argmin(axis=1)
        if not np.isfinite(power[rows, owner]).all():
            continue  # points only an object of too few points explains
        for part in np.unique(owner)[1:].tolist():
            out[idx[owner == part]] = n
            n += 1
    return Split(out, partial, carver)


def _cut_movers(
    out: IntArray,
    carver: IntArray,
    partial: BoolArray,
    idx: IntArray,
    owner: IntArray,
    mine: BoolArray,
    min_points: int,
    n: int,
) -> int:
    """Give each hinted mover ``owner`` the points of ``idx`` (one segment) that are
    ``mine`` (in a mover's grown disc) a segment of its own, numbered from ``n``, where
    it holds ``min_points`` or more and the rest keeps as many (``out``, ``carver`` and
    ``partial`` written in place); returns the next free number."""
    rest = len(idx) - int(np.count_nonzero(mine))
    for part in np.unique(owner[mine]).tolist():
        taken = mine & (owner == part)
        if np.count_nonzero(taken) < min_points or rest < min_points:
            continue
        out[idx[taken]] = n
        carver[idx[taken]] = part
        partial[idx] = True
        n += 1
    return n


def _run_ends(
    scanner: NDArray[np.integer], first: NDArray[np.integer]
) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    """The first (``lo``) and last (``hi``) point of each cluster's run of beams in one
    scan: clusters start at ``first``; a change of scanner inside a cluster starts a run."""
    n = len(scanner)
    lo = np.zeros(n, dtype=bool)
    lo[first] = True
    lo[1:] |= scanner[1:] != scanner[:-1]
    hi = np.zeros(n, dtype=bool)
    hi[:-1] = lo[1:]
    hi[-1] = True
    return lo, hi


def occluded(
    points: ScanPoints, kept: BoolArray, order: IntArray, first: IntArray, params: ClusterParams
) -> BoolArray:
    """Per cluster, True when something in front cuts the view of it.

    ``order`` indexes the clustered points, grouped by cluster (starting at ``first``),
    in scan and beam order within a cluster. At each end of a cluster's run of beams in
    one scan, the next kept return beyond that end (same scan, within ``max_gap`` beams)
    is compared: nearer to the scanner by more than D_max, it hides part of the cluster,
    whose centroid (or partial arc) is then biased.
    """
    n = len(order)
    lo, hi = _run_ends(points.scanner[order], first)
    kidx = kept.nonzero()[0]
    rank = kept.cumsum() - 1  # the index in kidx of each kept point
    table = _ratio_table(points.increments, params.incidence_limit, params.gap_scale_limit)
    # both ends at once: the low ends look one kept return back, the high ends one ahead
    at_lo, at_hi = lo.nonzero()[0], hi.nonzero()[0]
    n_lo = len(at_lo)
    at = np.concatenate((at_lo, at_hi))
    step = np.ones(len(at), dtype=np.intp)
    step[:n_lo] = -1
    p = order[at]
    q = kidx[np.minimum(np.maximum(rank[p] + step, 0), len(kidx) - 1)]
    gap = np.abs(points.beam[q] - points.beam[p])
    scanner = points.scanner[p]
    ok = (points.scanner[q] == scanner) & (gap > 0) & (gap <= params.max_gap)
    r = points.ranges[q]
    ahead = r + r * table[scanner, np.minimum(gap, params.gap_scale_limit)]
    verdict = ok & (ahead + 3.0 * params.range_sigma < points.ranges[p])
    hidden = np.zeros(n, dtype=bool)
    hidden[at_lo] = verdict[:n_lo]
    hidden[at_hi] = verdict[n_lo:]  # a run of one point: its high end's verdict
    return np.logical_or.reduceat(hidden, first)


def line_ends_visible(
    scans: Sequence[tuple[LaserScan, Pose2]],
    points: ScanPoints,
    order: IntArray,
    start: IntArray,
    line: FloatArray,
    params: ClusterParams,
) -> BoolArray:
    """Step 5: per cluster (C, 2), True where the line's end (``line`` (C, 4): end points
    ``(x0, y0, x1, y1)`` in R, NaN rows for other kinds: False) is the object's true end.

    The view of a surface stops at an end of a run of beams of one scan; the beam just
    beyond that end tells why. Cast along that beam, the line's extension would be met at
    range ``r_ext``; the end is true only when the beam is in the field of view, ``r_ext``
    is ``range_margin`` within the range limit (the beam could have seen the extension)
    and the beam returned nothing or something farther than ``r_ext``: it saw *past*
    where the line would go on. A
    return nearer than ``r_ext`` hides the rest (occlusion); one at ``r_ext`` is the same
    surface going on (split off by the breakpoint detector: a wall seen at grazing
    incidence, or beyond a gap); no beam beyond (the edge of the field of view) proves
    nothing. The tolerance is the inlier band stretched by the incidence,
    ``eps / max(|n . u|, sin(lambda))`` (``n`` the line's normal, ``u`` the beam).

    Each of the line's ends is judged on the run end, among the cluster's runs (one per
    scanner that sees it), whose return lies farthest along the line that way: the one
    that actually bounds the fitted segment (another scanner may see farther than one
    whose field of view stops short of the end).
    """
    n_clusters = len(start) - 1
    visible = np.zeros((n_clusters, 2), dtype=bool)
    is_line = np.isfinite(line).all(axis=1)
    if not is_line.any():
        return visible
    first = start[:-1]
    lo, hi = _run_ends(points.scanner[order], first)
    at_lo = lo.nonzero()[0]
    at = np.concatenate((at_lo, hi.nonzero()[0]))
    step = np.ones(len(at), dtype=np.intp)
    step[: len(at_lo)] = -1
    cluster = start.searchsorted(at, side="right") - 1
    keep = is_line[cluster]
    at, step, cluster = at[keep], step[keep], cluster[keep]
    p = order[at]
    scanner, beam = points.scanner[p], points.beam[p] + step
    # the line of each run end's cluster: unit direction d (end 0 -> end 1), normal n
    x0, y0, x1, y1 = line[cluster].T
    length = np.hypot(x1 - x0, y1 - y0)
    dx, dy = (x1 - x0) / length, (y1 - y0) / length
    nx, ny = -dy, dx
    offset = nx * x0 + ny * y0
    # the next beam: its direction u in R, its range, and where it would meet the line
    ok = np.ones(len(at), dtype=bool)
    angle = np.zeros(len(at))
    measured = np.full(len(at), np.inf)
    range_max = np.zeros(len(at))
    for k, (scan, mount) in enumerate(scans):
        mine = scanner == k
        inside = mine & (beam >= 0) & (beam < len(scan.ranges))
        ok[mine & ~inside] = False  # the edge of the field of view
        b = beam[inside]
        angle[inside] = mount.theta + scan.angle_min + scan.angle_increment * b
        measured[inside] = scan.ranges[b]
        range_max[mine] = scan.range_max
    ux, uy = np.cos(angle), np.sin(angle)
    facing = nx * ux + ny * uy
    sensor = points.sensors[scanner]
    with np.errstate(divide="ignore", invalid="ignore"):
        r_ext = (offset - nx * sensor[:, 0] - ny * sensor[:, 1]) / facing
    ok &= np.isfinite(r_ext) & (r_ext > 0.0) & (r_ext < range_max - params.range_margin)
    tolerance = params.inlier_band / np.maximum(np.abs(facing), math.sin(params.incidence_limit))
    returned = np.isfinite(measured) & (measured < range_max)
    past = ~returned | (measured > r_ext + tolerance)
    verdict = ok & past
    # each end of the line is judged by the run end that reaches farthest that way
    along = dx * points.x[p] + dy * points.y[p]
    for end, sign in ((0, 1.0), (1, -1.0)):
        rank = np.lexsort((sign * along, cluster))
        head = np.ones(len(rank), dtype=bool)
        head[1:] = cluster[rank][1:] != cluster[rank][:-1]
        chosen = rank[head]
        visible[cluster[chosen], end] = verdict[chosen]
    return visible


# -- 4. classify ----------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True, eq=False)
class ClusterFits:
    """Per cluster: ``kind`` code, ``centroid`` (C, 2), ``size`` (enclosing radius about the
    centroid), ``line`` (C, 4) end
    points, ``circle`` (C, 3) centre and radius (NaN rows unless that kind), ``rms``
    residual of the chosen model over its inliers (NaN for a blob)."""

    kind: NDArray[np.int8]
    centroid: FloatArray
    size: FloatArray
    line: FloatArray
    circle: FloatArray
    rms: FloatArray


_BOX_ANGLES = np.radians(np.arange(0.0, 90.0, 1.0))
_BOX_AXES = np.stack([np.cos(_BOX_ANGLES), np.sin(_BOX_ANGLES)])  # (2, A): one side's axis
_BOX_NEAR = 0.01  # m: closer to an edge than this counts as on it (the range noise)


def box_centres(
    xy: FloatArray,
    start: IntArray,
    which: Sequence[int] | NDArray[np.intp],
    tolerance: float,
    min_fraction: float,
) -> tuple[FloatArray, FloatArray, BoolArray]:
    """For the clusters ``which`` (indices into ``start``; cluster i is
    ``xy[start[i]:start[i + 1]]``): the centre of the rectangle that fits the points as
    a box's visible faces, (K, 2), the largest distance of a point from it, (K,), and
    whether the cluster is a box at all, (K,): at least ``min_fraction`` of its points
    within ``tolerance`` of the rectangle's edges (a piece of a curved fuselage or a
    group of walkers is not, and keeps its centroid).

    The rectangle is the bounding box of the points in the orientation (1 deg steps) that
    maximises the closeness criterion of Zhang et al. (2017, "Efficient L-shape fitting
    for vehicle detection using laser scanners"): the sum over the points of
    ``1 / max(d, d0)``, ``d`` a point's distance to the nearest edge of the box. The
    minimum-area rectangle is no good here: an L's hull is a triangle, and the rectangle
    along its hypotenuse has the same area as the box.
    """
    centres = np.zeros((len(which), 2))
    radii = np.zeros(len(which))
    boxes = np.zeros(len(which), dtype=bool)
    for k, i in enumerate(which):
        pts = xy[start[i] : start[i + 1]]
        u = pts @ _BOX_AXES  # (N, A) along one side
        v = pts[:, 1:2] * _BOX_AXES[0] - pts[:, 0:1] * _BOX_AXES[1]
        du = np.minimum(u - u.min(axis=0), u.max(axis=0) - u)
        dv = np.minimum(v - v.min(axis=0), v.max(axis=0) - v)
        score = (1.0 / np.maximum(np.minimum(du, dv), _BOX_NEAR)).sum(axis=0)
        a = int(np.argmax(score))
        on_edge = np.minimum(du[:, a], dv[:, a]) <= tolerance
        boxes[k] = np.count_nonzero(on_edge) >= min_fraction * len(pts)
        mid_u = 0.5 * (u[:, a].min() + u[:, a].max())
        mid_v = 0.5 * (v[:, a].min() + v[:, a].max())
        c, s = _BOX_AXES[:, a]
        centres[k] = c * mid_u - s * mid_v, s * mid_u + c * mid_v
        radii[k] = float(np.sqrt(((pts - centres[k]) ** 2).sum(axis=1).max()))
    return centres, radii, boxes


def _solve_sym3(s: FloatArray) -> FloatArray:
    """Batched symmetric 3x3 solve by the adjugate (Cramer's rule): ``s`` (9, C) as
    (a11, a12, a13, a22, a23, a33, b1, b2, b3) per column; returns x (3, C), inf or NaN
    where the system is singular."""
    a11, a12, a13, a22, a23, a33, b1, b2, b3 = s
    c11, c12, c13 = a22 * a33 - a23 * a23, a13 * a23 - a12 * a33, a12 * a23 - a13 * a22
    c22, c23, c33 = a11 * a33 - a13 * a13, a12 * a13 - a11 * a23, a11 * a22 - a12 * a12
    det = a11 * c11 + a12 * c12 + a13 * c13
    x1 = c11 * b1 + c12 * b2 + c13 * b3  # the adjugate times b
    x2 = c12 * b1 + c22 * b2 + c23 * b3
    x3 = c13 * b1 + c23 * b2 + c33 * b3
    return np.array((x1, x2, x3)) / det


class _Batch:
    """Cluster-centred coordinates of every point and the group structure; the strata of
    the RANSAC sampler; an evenly strided subsample of ``n_sub`` points per cluster
    (repeating points of smaller clusters) that scores the hypotheses."""

    #: sampler strata as fractions part/parts of a cluster: halves for the two points of
    #: a line, thirds for the three points of a circle
    PARTS = np.array([0, 1, 0, 1, 2])[:, None], np.array([2, 2, 3, 3, 3])[:, None]

    def __init__(self, xy: FloatArray, start: IntArray, n_sub: int) -> None:
        first = start[:-1]
        self.start = first
        self.count = count = start[1:] - first
        self.of = np.arange(len(first)).repeat(count)
        self.centroid = np.add.reduceat(xy, first, axis=0) / count[:, None]
        u = (xy - self.centroid[self.of]).T.copy()
        self.x, self.y = u[0], u[1]
        self.r2 = self.x * self.x + self.y * self.y  # squared distances to the centroid
        sub = first[:, None] + (np.arange(n_sub) * count[:, None]) // n_sub
        self.sub_x, self.sub_y = self.x[sub], self.y[sub]
        part, parts = self.PARTS
        lo = count * part // parts
        self.width = count * (part + 1) // parts - lo
        self.base = first + lo

    def draw(self, u: FloatArray) -> IntArray:
        """Point indices (5, H, C) drawn in the strata from uniforms ``u`` (5, H, C):
        rows 0-1 for lines, 2-4 for circles."""
        return self.base[:, None, :] + (u * self.width[:, None, :]).astype(np.intp)

    def sums(self, *rows: FloatArray) -> FloatArray:
        """Per-cluster sums of each row: (len(rows), C)."""
        return np.add.reduceat(np.array(rows, dtype=float), self.start, axis=1)

    @staticmethod
    def best(residual: FloatArray, valid: BoolArray, eps: float) -> tuple[IntArray, BoolArray]:
        """Per cluster, the hypothesis of least MSAC cost on the subsample (``residual``
        (H, C, n_sub), overwritten), and whether it is valid."""
        np.square(residual, out=residual)
        np.minimum(residual, eps * eps, out=residual)
        cost = np.where(valid, np.add.reduce(residual, axis=2), np.inf)
        return cost.argmin(axis=0), np.isfinite(np.minimum.reduce(cost, axis=0))

    def score(
        self, residual: FloatArray, eps: float
    ) -> tuple[FloatArray, FloatArray, FloatArray, BoolArray]:
        """MSAC cost, inlier fraction and inlier rms of per-point residuals (C each), and
        the inlier mask (per point)."""
        inlier = residual < eps
        sq = residual * residual
        cost, n_in, sq_in = self.sums(np.minimum(sq, eps * eps), inlier, np.where(inlier, sq, 0))
        return cost, n_in / self.count, np.sqrt(sq_in / n_in), inlier


def _fit_lines(
    b: _Batch, params: ClusterParams, idx: IntArray
) -> tuple[FloatArray, FloatArray, FloatArray, BoolArray]:
    """RANSAC + total least squares lines: end points (C, 4) in the centred frame, MSAC
    cost and inlier rms (C each), and the validity mask."""
    eps = params.inlier_band
    x, y, of = b.x, b.y, b.of
    x1, y1 = x[idx[0]], y[idx[0]]
    dx, dy = x[idx[1]] - x1, y[idx[1]] - y1
    length = np.sqrt(dx * dx + dy * dy)  # 0 for a degenerate pair: NaN normal, invalid
    nx, ny = -dy / length, dx / length
    off = nx * x1 + ny * y1
    res = np.abs(nx[..., None] * b.sub_x + ny[..., None] * b.sub_y - off[..., None])
    best, ok = b.best(res, length > 0.0, eps)
    cols = np.arange(len(best))
    nx, ny, off = nx[best, cols], ny[best, cols], off[best, cols]
    for _ in range(params.refinements):  # principal axis of the inliers' scatter
        w = (np.abs(nx[of] * x + ny[of] * y - off[of]) < eps).astype(float)
        wx, wy = x * w, y * w
        s = b.sums(w, wx, wy, wx * x, wx * y, wy * y)
        mx, my, mxx, mxy, myy = s[1:] / s[0]  # the inliers' means of x, y, x^2, xy, y^2
        theta = 0.5 * np.arctan2(2.0 * (mxy - mx * my), mxx - mx * mx - myy + my * my)
        nx, ny = -np.sin(theta), np.cos(theta)
        off = nx * mx + ny * my
    nx_of, ny_of = nx[of], ny[of]
    res = np.abs(nx_of * x + ny_of * y - off[of])
    cost, frac, rms, inlier = b.score(res, eps)
    t = ny_of * x - nx_of * y  # along the direction (ny, -nx)
    t0 = np.minimum.reduceat(np.where(inlier, t, np.inf), b.start)
    t1 = np.maximum.reduceat(np.where(inlier, t, -np.inf), b.start)
    ends = np.empty((len(best), 4))
    ends[:, 0], ends[:, 1] = off * nx + t0 * ny, off * ny - t0 * nx
    ends[:, 2], ends[:, 3] = off * nx + t1 * ny, off * ny - t1 * nx
    ok &= (frac >= params.min_inlier_fraction) & np.isfinite(ends).all(axis=1)
    return ends, cost, rms, ok


def _fit_circles(
    b: _Batch, params: ClusterParams, idx: IntArray, outward: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray, BoolArray]:
    """RANSAC + Kasa + Gauss-Newton circles: (C, 3) centre (centred frame) and radius,
    MSAC cost and inlier rms (C each), and the validity mask (radius bounds, centre on the
    far side: along ``outward`` (C, 2), the sensor-to-centroid directions)."""
    eps = params.inlier_band
    x, y, of = b.x, b.y, b.of
    ax, ay = x[idx[2]], y[idx[2]]
    bx, by = x[idx[3]] - ax, y[idx[3]] - ay
    cx, cy = x[idx[4]] - ax, y[idx[4]] - ay
    den = 2.0 * (bx * cy - by * cx)
    b2, c2 = bx * bx + by * by, cx * cx + cy * cy
    ox, oy = (cy * b2 - by * c2) / den, (bx * c2 - cx * b2) / den
    px, py, radius = ax + ox, ay + oy, np.sqrt(ox * ox + oy * oy)
    gx, gy = b.sub_x - px[..., None], b.sub_y - py[..., None]
    res = np.abs(np.sqrt(gx * gx + gy * gy) - radius[..., None])
    best, ok = b.best(res, _circle_ok(px, py, radius, outward, params), eps)
    cols = np.arange(len(best))
    px, py, radius = px[best, cols], py[best, cols], radius[best, cols]
    for rnd in range(params.refinements):
        gx, gy = x - px[of], y - py[of]
        w = (np.abs(np.sqrt(gx * gx + gy * gy) - radius[of]) < eps).astype(float)
        if rnd == 0:  # Kasa: x^2 + y^2 + D x + E y + F = 0 in least squares
            z = b.r2
            wx, wy, wz = x * w, y * w, z * w
            d, e, f = _solve_sym3(b.sums(wx * x, wx * y, wx, wy * y, wy, w, -wx * z, -wy * z, -wz))
            px, py = -0.5 * d, -0.5 * e
            radius = np.sqrt(px * px + py * py - f)
        for _ in range(params.geometric_steps):  # Gauss-Newton on |p - c| - r
            gx, gy = x - px[of], y - py[of]
            dist = np.sqrt(gx * gx + gy * gy)
            gx, gy = gx / dist, gy / dist
            err = dist - radius[of]
            wgx, wgy = gx * w, gy * w
            da, db, dr = _solve_sym3(
                b.sums(wgx * gx, wgx * gy, wgx, wgy * gy, wgy, w, wgx * err, wgy * err, err * w)
            )
            px, py, radius = px + da, py + db, radius + dr
    gx, gy = x - px[of], y - py[of]
    res = np.abs(np.sqrt(gx * gx + gy * gy) - radius[of])
    res[np.isnan(res)] = np.inf
    cost, frac, rms, _ = b.score(res, eps)
    ok &= (frac >= params.min_inlier_fraction) & _circle_ok(px, py, radius, outward, params)
    circle = np.empty((len(best), 3))
    circle[:, 0], circle[:, 1], circle[:, 2] = px, py, radius
    return circle, cost, rms, ok


def _circle_ok(
    px: FloatArray, py: FloatArray, radius: FloatArray, outward: FloatArray, params: ClusterParams
) -> BoolArray:
    """Radius within bounds (so finite), centre beyond the centroid seen from the sensor."""
    ok = (radius >= params.min_radius) & (radius <= params.max_radius)
    ok &= px * outward[:, 0] + py * outward[:, 1] > 0.0
    return ok


def fit_clusters(
    xy: FloatArray,
    start: IntArray,
    sensors: FloatArray,
    params: ClusterParams,
    rng: np.random.Generator,
) -> ClusterFits:
    """Step 4: classify every cluster as line, circle or blob and fit it (batched).

    ``xy`` (M, 2): the points in R, grouped by cluster, in beam order within a cluster;
    cluster i is ``xy[start[i]:start[i + 1]]`` (each has >= 3 points); ``sensors``
    (C, 2): the position in R of the scanner that saw each cluster. See the module
    docstring for the RANSAC, the refinements and the decision rule.
    """
    b = _Batch(xy, start, params.ransac_points)
    idx = b.draw(rng.random((5, params.ransac_hypotheses, len(b.start))))
    with np.errstate(invalid="ignore", divide="ignore"):  # degenerate fits turn invalid
        ends, cost_l, rms_l, line_ok = _fit_lines(b, params, idx)
        circle, cost_c, rms_c, circle_ok = _fit_circles(b, params, idx, b.centroid - sensors)
        evidence = (cost_l - cost_c) / (params.range_sigma * params.range_sigma)
        is_circle = circle_ok & (~line_ok | (evidence >= params.model_chi2))
    kind = np.full(len(b.start), BLOB, dtype=np.int8)
    kind[line_ok] = LINE
    kind[is_circle] = CIRCLE
    is_line = (kind == LINE)[:, None]
    ends[:, :2] += b.centroid
    ends[:, 2:] += b.centroid
    circle[:, :2] += b.centroid
    return ClusterFits(
        kind=kind,
        centroid=b.centroid,
        size=np.sqrt(np.maximum.reduceat(b.r2, b.start)),
        line=np.where(is_line, ends, np.nan),
        circle=np.where(is_circle[:, None], circle, np.nan),
        rms=np.where(is_line[:, 0], rms_l, np.where(is_circle, rms_c, np.nan)),
    )


# -- the detector ---------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True, eq=False)
class Cluster:
    """One detected obstacle in the robot frame R (see :class:`Clusters`)."""

    kind: str
    points: FloatArray
    centroid: tuple[float, float]
    position: tuple[float, float]
    size: float
    shape: tuple[float, ...]
    rms: float
    clearance: float

    @property
    def n_points(self) -> int:
        return len(self.points)


@dataclass(frozen=True, slots=True, eq=False)
class Clusters:
    """The obstacles detected in one set of scans, as arrays over C clusters, in R.

    ``points`` (M, 2): the clustered points, cluster after cluster: cluster i is
    ``points[start[i]:start[i + 1]]`` (``start`` has C + 1 entries). ``kind``: codes
    :data:`LINE`, :data:`CIRCLE`, :data:`BLOB`. ``centroid`` (C, 2); ``position`` (C, 2)
    the point to track: the circle centre, the middle of a line, the centre of the
    rectangle fitted to a blob that is a box (:func:`box_centres`), else the centroid;
    ``size`` the radius of a circle enclosing the obstacle: the fitted radius of a circle,
    else the largest distance of a point from ``position`` (it covers the obstacle about
    it); ``line`` (C, 4) the end points
    (x0, y0, x1, y1) of a line and ``circle`` (C, 3) the centre and radius of a circle
    (NaN rows otherwise); ``rms`` the residual of the fitted model over its inliers
    (NaN for a blob);
    ``clearance`` the distance from the robot's footprint to the nearest point;
    ``occluded`` True when something in front cuts the view of the cluster (its
    centroid, or its partial arc, is then biased: see :func:`occluded`), or the range
    limit does (a return within ``range_margin`` of it).
    ``ends_visible`` (C, 2): for a line, whether its end ``(x0, y0)``, resp. ``(x1, y1)``,
    is the object's true end rather than where the view of it stops
    (:func:`line_ends_visible`); False for other kinds. A line's ``position`` is the
    middle of its fitted segment (not the centroid of its returns, whose density varies
    along it with the range and the incidence).
    ``boxed``: for a blob, whether it is a box and ``position`` its rectangle's centre.
    ``returns`` and ``isolated`` count the returns and the removed isolated points.
    ``carved_by``: the id of the tracked mover whose own part of a segment the cluster
    is (:func:`split_by_tracks`; such a cluster, and the rest of its segment, are
    ``occluded``), -1 for the others.
    """

    stamp: float
    points: FloatArray
    start: IntArray
    kind: NDArray[np.int8]
    centroid: FloatArray
    position: FloatArray
    size: FloatArray
    line: FloatArray
    circle: FloatArray
    rms: FloatArray
    clearance: FloatArray
    occluded: BoolArray
    ends_visible: BoolArray
    boxed: BoolArray
    returns: int = 0
    isolated: int = 0
    carved_by: IntArray = field(default_factory=lambda: np.zeros(0, dtype=np.intp))

    def __post_init__(self) -> None:
        if len(self.carved_by) != len(self.kind):
            object.__setattr__(self, "carved_by", np.full(len(self.kind), -1, dtype=np.intp))

    @staticmethod
    def empty(stamp: float, returns: int = 0, isolated: int = 0) -> Clusters:
        z2, z = np.zeros((0, 2)), np.zeros(0)
        return Clusters(
            stamp,
            z2,
            np.zeros(1, dtype=np.intp),
            np.zeros(0, dtype=np.int8),
            z2,
            z2,
            z,
            np.zeros((0, 4)),
            np.zeros((0, 3)),
            z,
            z,
            np.zeros(0, dtype=bool),
            np.zeros((0, 2), dtype=bool),
            np.zeros(0, dtype=bool),
            returns,
            isolated,
        )

    def __len__(self) -> int:
        return len(self.kind)

    def __getitem__(self, i: int) -> Cluster:
        k = int(self.kind[i])
        shape = self.line[i] if k == LINE else self.circle[i] if k == CIRCLE else ()
        return Cluster(
            kind=KIND_NAMES[k],
            points=self.points[self.start[i] : self.start[i + 1]],
            centroid=(float(self.centroid[i, 0]), float(self.centroid[i, 1])),
            position=(float(self.position[i, 0]), float(self.position[i, 1])),
            size=float(self.size[i]),
            shape=tuple(float(v) for v in shape),
            rms=float(self.rms[i]),
            clearance=float(self.clearance[i]),
        )

    def __iter__(self) -> Iterator[Cluster]:
        return (self[i] for i in range(len(self)))


def _as_blobs(fits: ClusterFits, rows: BoolArray) -> ClusterFits:
    """``fits`` with clusters ``rows`` taken as blobs: a mover's part cut out by its disc
    has the cut's shape, not the object's (the disc's edge across a wall is an arc, whose
    circle fit put a trolley's "centre" 2 m away); its centroid is where it is."""
    kind = np.where(rows, BLOB, fits.kind).astype(np.int8)
    return ClusterFits(
        kind=kind,
        centroid=fits.centroid,
        size=fits.size,
        line=np.where(rows[:, None], np.nan, fits.line),
        circle=np.where(rows[:, None], np.nan, fits.circle),
        rms=np.where(rows, np.nan, fits.rms),
    )


def _carved_by(split: Split | None, hints: TrackHints | None, first: IntArray) -> IntArray:
    """Per cluster (its first point at ``first``), the id of the hinted mover it was cut
    out for (:attr:`TrackHints.ids`), -1 for the others."""
    none = np.full(len(first), -1, dtype=np.intp)
    if split is None or hints is None or not (split.carver >= 0).any():
        return none
    carver = split.carver[first]
    return np.where(carver >= 0, hints.ids[np.maximum(carver, 0)], none)


class ScanClusterer:
    """Thesis Algorithm 2.1 (seed lines 780-830) for a robot of footprint
    ``length`` x ``width`` (m, centred on the axle): scans in, :class:`Clusters` out.

    Deterministic: the RANSAC sampler is seeded with ``params.seed`` once, at
    construction (pass ``rng`` to share another generator).
    """

    def __init__(
        self,
        length: float,
        width: float,
        params: ClusterParams | None = None,
        rng: np.random.Generator | None = None,
    ) -> None:
        self.length = length
        self.width = width
        self.params = params or ClusterParams()
        self.rng = rng or np.random.default_rng(self.params.seed)

    def _at_range_limit(
        self,
        scans: Sequence[tuple[LaserScan, Pose2]],
        points: ScanPoints,
        order: IntArray,
        first: IntArray,
    ) -> BoolArray:
        """Per cluster, True when one of its returns is within ``range_margin`` of its
        scanner's range limit: the rest of the object may lie beyond it, so the view is
        cut as by an occluder (approaching it, the robot sees more and more of it)."""
        limit = np.array([scan.range_max for scan, _ in scans]) - self.params.range_margin
        far = points.ranges[order] >= limit[points.scanner[order]]
        return np.logical_or.reduceat(far, first)

    def detect(
        self,
        scans: Sequence[tuple[LaserScan, Pose2]],
        robot_points: Sequence[FloatArray] | None = None,
        hints: TrackHints | None = None,
    ) -> Clusters:
        """Detect the obstacles in ``scans``: ``(scan, mount)`` pairs, ``mount`` the
        scanner's pose in R. Pass every new scan of every scanner, together when they
        were taken together; the result is stamped with the latest scan's stamp.
        ``robot_points``: optionally, each scan's returns in R already computed
        (:func:`merge_scans`). ``hints``: the tracked small objects at that stamp, to
        split segments of objects touching (:func:`split_by_tracks`)."""
        p = self.params
        pts = merge_scans(scans, robot_points)
        kept = neighbour_mask(pts, p)
        labels = segment(pts, kept, p)
        split = None
        if hints is not None:
            split = split_by_tracks(pts.x, pts.y, labels, hints, p.split_margin, p.min_points)
            labels = split.labels
        members = (labels >= 0).nonzero()[0]
        returns, isolated = len(pts), len(pts) - int(np.count_nonzero(kept))
        if len(members) == 0:
            return Clusters.empty(pts.stamp, returns, isolated)
        order = members[labels[members].argsort(kind="stable")]
        count = np.bincount(labels[order])
        start = np.concatenate(([0], count.cumsum()))
        xy = np.column_stack((pts.x[order], pts.y[order]))
        first = start[:-1]
        fits = fit_clusters(xy, start, pts.sensors[pts.scanner[order[first]]], p, self.rng)
        carved_by = _carved_by(split, hints, order[first])
        if (carved_by >= 0).any():
            fits = _as_blobs(fits, carved_by >= 0)
        is_circle = (fits.kind == CIRCLE)[:, None]
        middle = 0.5 * (fits.line[:, :2] + fits.line[:, 2:])
        position = np.where(
            is_circle,
            fits.circle[:, :2],
            np.where(fits.kind[:, None] == LINE, middle, fits.centroid),
        )
        size = np.where(is_circle[:, 0], fits.circle[:, 2], fits.size)
        cut = np.zeros(len(first), dtype=bool) if split is None else split.partial[order[first]]
        blobs = ((fits.kind == BLOB) & (carved_by < 0)).nonzero()[0]
        boxed = np.zeros(len(fits.kind), dtype=bool)
        if len(blobs):
            band = p.inlier_sigmas * p.range_sigma
            centre, radius, box = box_centres(xy, start, blobs, band, p.min_inlier_fraction)
            boxes = blobs[box]
            position[boxes], size[boxes] = centre[box], radius[box]
            boxed[boxes] = True
        return Clusters(
            stamp=pts.stamp,
            points=xy,
            start=start,
            kind=fits.kind,
            centroid=fits.centroid,
            position=position,
            size=size,
            line=fits.line,
            circle=fits.circle,
            rms=fits.rms,
            clearance=np.minimum.reduceat(footprint_distances(xy, self.length, self.width), first),
            occluded=occluded(pts, kept, order, first, p)
            | self._at_range_limit(scans, pts, order, first)
            | cut,
            # where a segment was cut, its ends are the cut's, not the object's
            ends_visible=line_ends_visible(scans, pts, order, start, fits.line, p) & ~cut[:, None],
            boxed=boxed,
            returns=returns,
            isolated=isolated,
            carved_by=carved_by,
        )
