"""The vectorised steps of the obstacle pipeline against their plain definitions.

The breakpoint links of every offset at once (:meth:`_Links.window`), the cross-scanner
merge over a grid of bearing neighbours, the cofactor solve of the refinements, and the
robot-frame points shared between r_c and the detector must give exactly what the
per-offset loops, a dense solver and a fresh conversion give.
"""

import math

import numpy as np

from behaviours.laws.laser_clusters import (
    _ANGULAR_NEIGHBOURS,
    ClusterParams,
    ScanClusterer,
    _components,
    _Links,
    _merge_across_scanners,
    _renumber,
    _solve_sym3,
    merge_scans,
)
from behaviours.laws.obstacles import scan_to_robot
from executive.core.frames import Pose2
from executive.core.records import LaserScan

AMIN, INC, BEAMS, RMAX = -3 * math.pi / 4, math.pi / 720, 1081, 30.0
MOUNTS = (Pose2(0.65, 0.0, 0.0), Pose2(-0.65, 0.0, math.pi))


def _scans(seed: int) -> list[tuple[LaserScan, Pose2]]:
    """Two scans of smooth random surfaces with gaps, outliers and no-return beams."""
    rng = np.random.default_rng(seed)
    out = []
    for mount in MOUNTS:
        ranges = 4.0 + np.cumsum(rng.normal(0.0, 0.05, BEAMS))
        ranges[rng.random(BEAMS) < 0.3] = RMAX
        bad = rng.random(BEAMS) < 0.05
        ranges[bad] = rng.uniform(0.5, RMAX, bad.sum())
        out.append((LaserScan(0.0, AMIN, INC, RMAX, np.clip(ranges, 0.1, RMAX)), mount))
    return out


def _window_by_offset(links: _Links, count: int, max_gap: int, scale: int):
    n = len(links.x)
    a, b = [np.zeros(0, np.intp)], [np.zeros(0, np.intp)]
    for j in range(1, min(count, n - 1) + 1):
        a.append(np.flatnonzero(links(slice(0, n - j), slice(j, n), max_gap, scale)))
        b.append(a[-1] + j)
    return np.concatenate(a), np.concatenate(b)


def test_window_is_the_per_offset_loop():
    params = ClusterParams()
    for seed in range(5):
        points = merge_scans(_scans(seed))
        for idx in (None, np.flatnonzero(np.random.default_rng(seed).random(len(points)) < 0.7)):
            links = _Links(points, params, idx)
            for count, max_gap, scale in ((4, 4, 1), (3, 16, 4), (1, 2, 1)):
                a, b = links.window(count, max_gap, scale)
                ra, rb = _window_by_offset(links, count, max_gap, scale)
                np.testing.assert_array_equal(a, ra)
                np.testing.assert_array_equal(b, rb)


def test_merge_across_scanners_is_the_per_neighbour_loop():
    rng = np.random.default_rng(3)
    for _ in range(20):
        n = int(rng.integers(3, 60))
        x, y = rng.uniform(-3.0, 3.0, n), rng.uniform(-3.0, 3.0, n)
        scanner = rng.integers(0, 2, n)
        label = np.sort(rng.integers(0, max(n // 4, 1), n))
        label = _renumber(label, n)
        # the reference: a loop over the bearing neighbours
        order = np.argsort(np.arctan2(y, x))
        xs, ys, ss, ls = x[order], y[order], scanner[order], label[order]
        a, b = [], []
        for j in range(1, min(_ANGULAR_NEIGHBOURS, n - 1) + 1):
            dx, dy = xs[j:] - xs[:-j], ys[j:] - ys[:-j]
            hit = ((dx * dx + dy * dy) <= 0.3 * 0.3) & (ss[j:] != ss[:-j])
            a.append(ls[:-j][hit])
            b.append(ls[j:][hit])
        a_all, b_all = np.concatenate(a), np.concatenate(b)
        if len(a_all):
            m = int(label.max()) + 1
            expected = _renumber(_components(m, a_all, b_all), m)[label]
        else:
            expected = label
        got = _merge_across_scanners(x, y, scanner, label, 0.3)
        np.testing.assert_array_equal(got, expected)


def test_solve_sym3_solves_the_systems():
    rng = np.random.default_rng(1)
    m = rng.normal(size=(7, 3, 3))
    a = m @ m.transpose(0, 2, 1) + 0.1 * np.eye(3)
    rhs = rng.normal(size=(7, 3))
    s = np.stack([a[:, 0, 0], a[:, 0, 1], a[:, 0, 2], a[:, 1, 1], a[:, 1, 2], a[:, 2, 2]])
    x = _solve_sym3(np.concatenate((s, rhs.T)))
    np.testing.assert_allclose(x.T, np.linalg.solve(a, rhs[:, :, None])[:, :, 0], rtol=1e-9)


def test_shared_robot_points_detect_the_same():
    for seed in range(3):
        scans = _scans(seed)
        points = [
            scan_to_robot(s.ranges, s.angle_min, s.angle_increment, s.range_max, m)
            for s, m in scans
        ]
        a = ScanClusterer(1.4, 1.0).detect(scans)
        b = ScanClusterer(1.4, 1.0).detect(scans, points)
        for field in ("points", "start", "kind", "position", "size", "line", "circle"):
            np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
        np.testing.assert_array_equal(a.occluded, b.occluded)
        np.testing.assert_array_equal(a.ends_visible, b.ends_visible)
