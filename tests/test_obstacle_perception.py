"""Laser obstacle perception: thesis Algorithm 2.1 (seed 000, lines 780-830) and tracking.

Synthetic scans of two Hokuyo UTM-30LX (270 deg, 0.25 deg, 1081 beams, 30 m) mounted as
on the A320 platform (front x = +0.65 m, rear x = -0.65 m facing back), ray-cast with
:func:`sim2d.raycast.cast_scan` against analytic shapes, plus Gaussian range noise.
"""

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from behaviours.laws.laser_clusters import (
    BLOB,
    CIRCLE,
    LINE,
    ClusterParams,
    Clusters,
    ScanClusterer,
    TrackHints,
    breakpoint_distance,
    merge_scans,
    neighbour_mask,
    split_by_tracks,
)
from behaviours.laws.tracking import (
    DangerParams,
    ObstacleTracker,
    danger_level,
    path_distance,
)
from executive.campaign.runner import episode_row
from executive.campaign.spec import load_campaign
from executive.core.frames import Pose2
from executive.core.records import Danger, LaserScan
from sim2d.raycast import Scene, cast_scan
from tests.conftest import MISSIONS

AMIN, INC, BEAMS, RMAX = -3 * math.pi / 4, math.pi / 720, 1081, 30.0
MOUNTS = (Pose2(0.65, 0.0, 0.0), Pose2(-0.65, 0.0, math.pi))
LENGTH, WIDTH = 1.4, 1.0


def scan_pair(scene, robot=None, sigma=0.01, rng=None, stamp=0.0, outliers=0.0):
    """Both scans of the robot at ``robot`` (world frame of ``scene``), with range noise
    ``sigma`` and a share ``outliers`` of beams replaced by uniform ranges in [0, 30 m]."""
    rng = rng if rng is not None else np.random.default_rng(0)
    robot = robot or Pose2(0.0, 0.0, 0.0)
    out = []
    for mount in MOUNTS:
        sensor = robot @ mount
        ranges = cast_scan(scene, (sensor.x, sensor.y), sensor.theta, AMIN, INC, BEAMS, RMAX)
        hit = ranges < RMAX
        ranges[hit] += rng.normal(0.0, sigma, hit.sum())
        bad = rng.random(BEAMS) < outliers
        ranges[bad] = rng.uniform(0.0, RMAX, bad.sum())
        out.append((LaserScan(stamp, AMIN, INC, RMAX, np.minimum(ranges, RMAX)), mount))
    return out


def detect(scene, **kwargs):
    return ScanClusterer(LENGTH, WIDTH).detect(scan_pair(scene, **kwargs))


def angle_between(a, b):
    d = abs(a - b) % math.pi
    return min(d, math.pi - d)


# -- detection ---------------------------------------------------------------------------
def test_breakpoint_distance_is_borges_aldon():
    lam, sigma = math.radians(10), 0.02
    for r, dphi in ((1.0, INC), (10.0, INC), (10.0, 4 * INC)):
        expected = r * math.sin(dphi) / math.sin(lam - dphi) + 3 * sigma
        assert breakpoint_distance(r, dphi, lam, sigma) == pytest.approx(expected)
    # at 10 m and one beam: about 0.32 m, and it grows with range and gap
    assert 0.3 < breakpoint_distance(10.0, INC, lam, sigma) < 0.35


def test_merge_keeps_scanner_beam_and_robot_frame():
    wall_ahead = Scene(segments=[(5.0, -20.0, 5.0, 20.0)])
    wall_behind = Scene(segments=[(-5.0, -20.0, -5.0, 20.0)])
    pts = merge_scans(scan_pair(Scene.concat([wall_ahead, wall_behind]), sigma=0.0))
    front, rear = pts.scanner == 0, pts.scanner == 1
    assert np.allclose(np.abs(pts.x), 5.0)  # every return on one of the walls
    assert np.all(np.diff(pts.beam[front]) > 0) and np.all(np.diff(pts.beam[rear]) > 0)
    # the middle beam of each scanner looks along its mount's heading
    middle = BEAMS // 2
    for scanner, x in ((front, 5.0), (rear, -5.0)):
        k = np.flatnonzero(scanner & (pts.beam == middle))
        assert pts.x[k] == pytest.approx([x]) and pts.y[k] == pytest.approx([0.0], abs=1e-9)
    angles = AMIN + INC * pts.beam[front]
    assert np.allclose(pts.ranges[front], np.hypot(pts.x[front] - 0.65, pts.y[front]))
    assert np.allclose(np.arctan2(pts.y[front], pts.x[front] - 0.65), angles)


def test_isolated_returns_are_removed_and_make_no_cluster():
    scans = scan_pair(Scene(), sigma=0.0)  # nothing in view
    spikes = scans[0][0].ranges.copy()
    spikes[[100, 300, 301, 700]] = (4.0, 7.0, 12.0, 2.0)  # lone returns, a pair far apart
    scans[0] = (LaserScan(0.0, AMIN, INC, RMAX, spikes), MOUNTS[0])
    pts = merge_scans(scans)
    assert len(pts) == 4
    assert not neighbour_mask(pts, ClusterParams()).any()
    assert len(ScanClusterer(LENGTH, WIDTH).detect(scans)) == 0


def test_line_classified_with_end_points_and_angle():
    a, b = np.array([6.0, -2.0]), np.array([6.8, 2.5])  # a wall, seen at an angle
    clusters = detect(Scene(segments=[(*a, *b)]), sigma=0.02)
    assert len(clusters) == 1
    wall = clusters[0]
    assert wall.kind == "line"
    x0, y0, x1, y1 = wall.shape
    ends = sorted([(x0, y0), (x1, y1)], key=lambda p: p[1])
    assert np.hypot(*(np.array(ends[0]) - a)) < 0.05
    assert np.hypot(*(np.array(ends[1]) - b)) < 0.05
    fitted = math.atan2(y1 - y0, x1 - x0)
    assert math.degrees(angle_between(fitted, math.atan2(*(b - a)[::-1]))) < 1.0
    assert wall.rms < 0.04


@pytest.mark.parametrize(
    ("centre", "radius"),
    [((4.0, 1.0), 0.3), ((-5.0, -3.0), 0.6), ((2.5, -6.0), 0.3), ((-1.0, 8.0), 1.2)],
    ids=["pedestrian-ahead", "gear-leg-behind", "pedestrian-side", "big-circle"],
)
def test_circle_classified_with_centre_and_radius(centre, radius):
    clusters = detect(Scene(circles=[(*centre, radius)]), sigma=0.02)
    assert len(clusters) == 1
    obstacle = clusters[0]
    assert obstacle.kind == "circle"
    cx, cy, r = obstacle.shape
    assert math.hypot(cx - centre[0], cy - centre[1]) < 0.04
    assert abs(r - radius) < 0.04
    assert obstacle.position == pytest.approx((cx, cy))
    assert obstacle.size == pytest.approx(r)


def test_box_corner_is_a_blob_and_box_face_a_line():
    corner = detect(Scene.from_box(5.0, 0.0, math.radians(45), 2.0, 1.2), sigma=0.01)
    face = detect(Scene.from_box(6.0, 0.0, 0.0, 0.8, 3.0), sigma=0.01)
    assert [c.kind for c in corner] == ["blob"]
    assert [c.kind for c in face] == ["line"]


def test_short_arc_of_a_huge_circle_is_a_line():
    # a drum of 6 m radius seen from 4 m: the radius bound rules out a circle
    clusters = detect(Scene(circles=[(10.0, 0.0, 6.0)]), sigma=0.01)
    assert len(clusters) == 1 and clusters[0].kind in ("line", "blob")


def test_object_beside_the_robot_seen_by_both_scanners_is_one_cluster():
    clusters = detect(Scene(segments=[(-3.0, 1.5, 3.0, 1.5)]), sigma=0.01)
    assert [c.kind for c in clusters] == ["line"]
    x0, _, x1, _ = clusters[0].shape
    assert min(x0, x1) < -2.5 and max(x0, x1) > 2.5  # both halves, one line


def test_clearance_is_measured_from_the_footprint():
    clusters = detect(Scene(circles=[(3.0, 0.0, 0.3)]), sigma=0.0)
    assert clusters[0].clearance == pytest.approx(3.0 - 0.3 - LENGTH / 2, abs=0.01)


def test_a_partly_hidden_cluster_is_occluded():
    scene = Scene(circles=[(3.0, 0.0, 0.3), (6.0, 0.8, 0.3)])  # the far one half hidden
    clusters = detect(scene, sigma=0.01)
    by_range = sorted(range(len(clusters)), key=lambda i: clusters.centroid[i, 0])
    assert [bool(clusters.occluded[i]) for i in by_range] == [False, True]


@pytest.mark.parametrize(
    ("scene", "expected"),
    [
        (Scene(segments=[(6.0, -2.0, 6.8, 2.5)]), [True, True]),  # a short wall in the open
        (Scene.from_box(6.0, 0.0, 0.0, 0.8, 3.0), [True, True]),  # a box's face: corners
        (Scene(segments=[(-40.0, 2.0, 40.0, 2.0)]), [False, False]),  # grazing both ways
        (Scene(segments=[(25.0, -60.0, 25.0, 60.0)]), [False, False]),  # to the range limit
    ],
    ids=["short-wall", "box-face", "long-wall-beside", "long-wall-ahead"],
)
def test_a_line_end_is_true_only_where_the_beam_beyond_sees_past_it(scene, expected):
    (wall,) = [i for i, k in enumerate(detect(scene, sigma=0.01).kind) if k == LINE]
    assert detect(scene, sigma=0.01).ends_visible[wall].tolist() == expected


def test_a_line_end_hidden_by_something_in_front_is_not_true():
    """A wall with a pole in front of its left part: the end beside the pole's shadow is
    where the view stops, not the wall's end; the right end is the wall's."""
    clusters = detect(Scene(segments=[(6.0, -2.0, 6.0, 2.0)], circles=[(3.0, 0.8, 0.3)]))
    (wall,) = [i for i in range(len(clusters)) if clusters.kind[i] == LINE]
    x0, y0, x1, y1 = clusters.line[wall]
    left = 0 if y0 > y1 else 1  # the end nearer the pole's side (+y)
    assert not clusters.ends_visible[wall, left] and clusters.ends_visible[wall, 1 - left]
    assert clusters.position[wall] == pytest.approx(
        ((x0 + x1) / 2.0, (y0 + y1) / 2.0)
    )  # a line is tracked by its middle


OUTLIER_SCENE = Scene.concat(
    [
        Scene(circles=[(4.0, 1.0, 0.3), (6.0, -3.0, 0.6), (-3.0, -4.0, 0.25)]),
        Scene.from_box(-5.0, 2.0, 0.3, 2.0, 1.0),
        Scene(segments=[(8.0, -6.0, 8.0, 6.0)]),
    ]
)


KIND = {LINE: "line", CIRCLE: "circle", BLOB: "blob"}


def _summary(clusters: Clusters):
    """(kind, centroid) per cluster, sorted by bearing."""
    order = np.argsort(np.arctan2(clusters.centroid[:, 1], clusters.centroid[:, 0]))
    return [(KIND[clusters.kind[i]], clusters.centroid[i], clusters[i]) for i in order]


@pytest.mark.parametrize("seed", range(4))
def test_thirty_percent_outliers_yield_the_same_clusters(seed):
    clean = _summary(detect(OUTLIER_SCENE, sigma=0.01))
    noisy = _summary(
        detect(OUTLIER_SCENE, sigma=0.01, rng=np.random.default_rng(seed), outliers=0.3)
    )
    assert [k for k, _, _ in noisy] == [k for k, _, _ in clean]
    assert len(clean) == 7  # 3 circles, the wall in 3 pieces (occluded), the box corner
    for (kind, centroid, a), (_, other, b) in zip(clean, noisy, strict=True):
        if kind == "circle":
            assert np.hypot(a.shape[0] - b.shape[0], a.shape[1] - b.shape[1]) < 0.04
            assert abs(a.shape[2] - b.shape[2]) < 0.04
        elif kind == "line":  # on the wall x = 8 (a piece may lose an end point or two)
            x0, y0, x1, y1 = b.shape
            assert abs(x0 - 8.0) < 0.03 and abs(x1 - 8.0) < 0.03
            assert math.degrees(angle_between(math.atan2(y1 - y0, x1 - x0), math.pi / 2)) < 2.0
            assert abs(b.size - a.size) < 0.2
        else:
            assert np.hypot(*(centroid - other)) < 0.15


def test_detection_is_deterministic():
    scans = scan_pair(OUTLIER_SCENE, outliers=0.2)
    a = ScanClusterer(LENGTH, WIDTH).detect(scans)
    b = ScanClusterer(LENGTH, WIDTH).detect(scans)
    assert np.array_equal(a.kind, b.kind)
    assert np.array_equal(np.nan_to_num(a.circle), np.nan_to_num(b.circle))
    assert np.array_equal(np.nan_to_num(a.line), np.nan_to_num(b.line))


@settings(max_examples=40, deadline=None)
@given(
    radius=st.floats(0.2, 1.5),
    gap=st.floats(1.5, 8.0),
    bearing=st.floats(-math.pi, math.pi),
    seed=st.integers(0, 2**32 - 1),
)
@example(radius=1.28125, gap=1.5, bearing=2.625, seed=0)  # the grazing fragment, see below
def test_random_circles_are_circles(radius, gap, bearing, seed):
    d = radius + gap  # the surface at least 1.5 m from the robot's centre
    centre = (d * math.cos(bearing), d * math.sin(bearing))
    clusters = detect(
        Scene(circles=[(*centre, radius)]), sigma=0.01, rng=np.random.default_rng(seed)
    )
    kinds = [c.kind for c in clusters]
    assert kinds.count("circle") == 1
    circle = clusters[kinds.index("circle")]
    cx, cy, r = circle.shape
    assert math.hypot(cx - centre[0], cy - centre[1]) < 0.04
    assert abs(r - radius) < 0.04
    # A big circle beside the robot can also show a few grazing returns to the other
    # scanner, too far from the main arc to merge (found by hypothesis in CI: r 1.28 m,
    # 1.5 m away, bearing 150 deg -> a 6-point fragment): such a fragment must be small
    # and lie on the same surface, never a phantom obstacle.
    for c in clusters:
        if c.kind != "circle":
            assert c.n_points < 0.1 * circle.n_points
            d_surface = np.abs(np.hypot(*(c.points - centre).T) - radius)
            assert np.all(d_surface < 0.05)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.integers(0, 2**32 - 1),
    no_return=st.sampled_from([RMAX, RMAX + 5.0, math.inf, math.nan]),
)
def test_no_return_beams_are_never_points(seed, no_return):
    """Clusters do not depend on what a no-return beam reads (range_max, beyond, inf,
    NaN), nor on dropping the beams at either end of the scan that saw nothing."""
    rng = np.random.default_rng(seed)
    circles = [(*rng.uniform(-12, 12, 2), rng.uniform(0.2, 1.0)) for _ in range(5)]
    circles = [c for c in circles if math.hypot(c[0], c[1]) > c[2] + 1.5]
    scene = Scene(circles=circles) if circles else Scene()
    scans = scan_pair(scene, rng=rng, outliers=0.05)
    reference = ScanClusterer(LENGTH, WIDTH).detect(scans)
    changed = []
    for scan, mount in scans:
        ranges = np.where(scan.ranges >= RMAX, no_return, scan.ranges)
        hits = np.flatnonzero(scan.ranges < RMAX)
        lo = hits[0] if len(hits) else 0
        hi = hits[-1] + 1 if len(hits) else 0
        angle_min = AMIN + lo * INC  # the first and last beams with a return
        changed.append((LaserScan(0.0, angle_min, INC, RMAX, ranges[lo:hi]), mount))
    again = ScanClusterer(LENGTH, WIDTH).detect(changed)
    assert np.array_equal(reference.kind, again.kind)
    assert np.allclose(reference.centroid, again.centroid)
    assert np.allclose(reference.points, again.points)


def _arc(cx, cy, r, a0, a1, n):
    a = np.linspace(a0, a1, n)
    return np.column_stack((cx + r * np.cos(a), cy + r * np.sin(a)))


def test_split_by_tracks_cuts_a_segment_between_the_tracked_objects_it_holds():
    face = np.column_stack((np.full(30, 3.0), np.linspace(-0.6, 0.6, 30)))  # a trolley
    post = _arc(3.5, 0.95, 0.33, math.pi * 0.6, math.pi * 1.4, 12)
    xy = np.vstack((face, post))
    labels = np.zeros(len(xy), dtype=np.intp)
    hints = TrackHints(np.array([[3.0, 0.0], [3.5, 0.95]]), np.array([0.6, 0.33]))
    out = split_by_tracks(xy[:, 0], xy[:, 1], labels, hints, 0.2, 5).labels
    assert set(out[:30]) == {0} and set(out[30:]) == {1}
    # a segment the hints do not cover whole is left as it is: a wall behind both
    wall = np.column_stack((np.full(60, 4.0), np.linspace(-1.0, 2.0, 60)))
    xy2 = np.vstack((xy, wall))
    whole = np.zeros(len(xy2), dtype=np.intp)
    assert (split_by_tracks(xy2[:, 0], xy2[:, 1], whole, hints, 0.2, 5).labels == 0).all()
    # one object tracked twice (each centre inside the other's disc) is not cut
    twice = TrackHints(np.array([[3.0, -0.2], [3.0, 0.2]]), np.array([0.5, 0.5]))
    assert (split_by_tracks(face[:, 0], face[:, 1], labels[:30], twice, 0.2, 5).labels == 0).all()
    # an object that would get too few points is no object: its points go to the other
    few = TrackHints(np.array([[3.0, 0.0], [3.0, 0.7]]), np.array([0.55, 0.1]))
    assert (split_by_tracks(face[:, 0], face[:, 1], labels[:30], few, 0.2, 5).labels == 0).all()


def test_split_by_tracks_cuts_a_mover_out_of_structure_it_touches():
    """A segment the hints do not cover whole (a long box, too big to be hinted, with a
    trolley against it) is cut only for a hinted mover: the points within its grown disc
    become their own segment, whatever a standing object's disc says there, and both
    parts are flagged partial views (avoidance campaign episode 558)."""
    wall = np.column_stack((np.linspace(3.0, 6.0, 60), np.full(60, 1.0)))
    trolley = np.column_stack((np.full(12, 6.02), np.linspace(1.0, 0.4, 12)))
    xy = np.vstack((wall, trolley))
    labels = np.zeros(len(xy), dtype=np.intp)
    at = np.array([[6.02, 0.7]])
    mover = TrackHints(at, np.array([0.3]), np.array([True]), np.array([7]))
    out, partial, carver = split_by_tracks(xy[:, 0], xy[:, 1], labels, mover, 0.2, 5)
    assert set(out[60:]) == {1} and partial.all() and set(carver[60:]) == {0}
    assert set(carver[out == 0]) == {-1}
    assert (out[:60] == 0).sum() >= 60 - 8  # the wall keeps all but its end by the trolley
    # a standing object's disc over the trolley does not hide it
    box = TrackHints(np.vstack((at, [[5.3, 1.2]])), np.array([0.3, 0.9]), np.array([True, False]))
    out = split_by_tracks(xy[:, 0], xy[:, 1], labels, box, 0.2, 5).labels
    assert set(out[60:]) == {1}
    # a standing object alone cuts nothing; nor a mover that would get too few points
    still = TrackHints(at, np.array([0.3]), np.array([False]))
    out, partial, _ = split_by_tracks(xy[:, 0], xy[:, 1], labels, still, 0.2, 5)
    assert (out == 0).all() and not partial.any()
    out, partial, _ = split_by_tracks(xy[:, 0], xy[:, 1], labels, mover, 0.2, 40)
    assert (out == 0).all() and not partial.any()


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.tuples(st.floats(-5, 5), st.floats(-5, 5)), min_size=1, max_size=40),
    st.lists(
        st.tuples(st.floats(-5, 5), st.floats(-5, 5), st.floats(0.05, 1.5), st.booleans()),
        max_size=6,
    ),
    st.integers(1, 4),
    st.integers(0, 2**31 - 1),
)
def test_split_by_tracks_only_refines_the_segments(points, hinted, n_labels, seed):
    rng = np.random.default_rng(seed)
    xy = np.array(points, dtype=float)
    labels = rng.integers(-1, n_labels, len(xy))
    labels[labels >= 0] = np.unique(labels[labels >= 0], return_inverse=True)[1]
    h = np.array([m[:3] for m in hinted], dtype=float).reshape(-1, 3)
    hints = TrackHints(h[:, :2], h[:, 2], np.array([m[3] for m in hinted], dtype=bool))
    out, partial, carver = split_by_tracks(xy[:, 0], xy[:, 1], labels, hints, 0.2, 3)
    assert ((out < 0) == (labels < 0)).all()
    assert not partial[labels < 0].any() and (carver[labels < 0] == -1).all()
    assert partial[carver >= 0].all()  # a mover's part is a partial view
    for label in np.unique(out[out >= 0]):  # flags hold for a whole segment
        assert len(np.unique(partial[out == label])) == 1
        assert len(np.unique(carver[out == label])) == 1
    assert hints.moving[carver[carver >= 0]].all()  # only movers carve
    used = np.unique(out[out >= 0])
    assert (used == np.arange(len(used))).all()  # consecutive from 0
    for label in used:  # each new segment lies in one old one, with enough points
        assert len(np.unique(labels[out == label])) == 1
        if label > labels.max():
            assert np.count_nonzero(out == label) >= 3


# -- tracking ----------------------------------------------------------------------------
def walkers(t, offset=0.8):
    """Two walkers crossing in an X at (6, 0), 1.2 m/s, B 0.8 s behind A."""
    s = 1.2 / math.sqrt(2.0)
    va, vb = np.array([s, s]), np.array([s, -s])
    pa = np.array([3.5, -2.5]) + va * t
    pb = np.array([3.5, 2.5]) - vb * offset + vb * t
    return (pa, va), (pb, vb)


@pytest.mark.parametrize(
    ("v", "omega"), [(0.0, 0.0), (0.8, 0.0), (0.5, 0.2)], ids=["still", "ahead", "turning"]
)
def test_two_walkers_crossing_keep_identities_and_velocities(v, omega):
    rng = np.random.default_rng(7)
    clusterer = ScanClusterer(LENGTH, WIDTH)
    tracker = ObstacleTracker(DangerParams(LENGTH, WIDTH))
    x = y = heading = 0.0
    ids: dict[str, int] = {}
    clear_errors = []
    for k in range(200):  # 5 s at 40 Hz
        t = k / 40.0
        robot = Pose2(x, y, heading)
        (pa, va), (pb, vb) = walkers(t)
        scene = Scene(circles=[(*pa, 0.3), (*pb, 0.3)])
        tracks = tracker.update(
            clusterer.detect(scan_pair(scene, robot, rng=rng, stamp=t)), robot, (v, omega)
        )
        to_r = robot.inverse()
        bearings = [math.atan2(*(to_r.apply(p) - (0.65, 0.0))[::-1]) for p in (pa, pb)]
        apart = abs(bearings[0] - bearings[1]) > 0.6 / np.hypot(*to_r.apply(pa)) + 0.05
        for name, p, vel in (("A", pa, va), ("B", pb, vb)):
            if t < 1.0:
                continue
            near = [o for o in tracks if np.hypot(*(np.array(o.position) - to_r.apply(p))) < 0.3]
            assert len(near) == 1, f"{name} at t={t}: {near}"
            assert ids.setdefault(name, near[0].id) == near[0].id, f"{name} swapped at t={t}"
            error = np.hypot(*(np.array(near[0].velocity) - vel @ robot.rotation()))
            assert error < 0.25, f"{name} at t={t}: {error}"
            if apart:  # neither hides the other
                clear_errors.append(error)
        x += v * math.cos(heading) / 40.0
        y += v * math.sin(heading) / 40.0
        heading += omega / 40.0
    assert ids["A"] != ids["B"]
    assert max(clear_errors) < 0.1
    assert len(clear_errors) > 200


def test_identities_survive_a_blackout_while_walkers_pass():
    """Two walkers pass each other on lanes 0.8 m apart while the lasers see nothing for
    0.8 s: each walks 0.96 m, so each re-appears nearer the other's last position; only
    the constant-velocity prediction gives the tracks back to the right walkers."""
    rng = np.random.default_rng(11)
    clusterer = ScanClusterer(LENGTH, WIDTH)
    tracker = ObstacleTracker(DangerParams(LENGTH, WIDTH))
    robot = Pose2(0.0, 0.0, 0.0)
    ids = {}
    for k in range(140):
        t = k / 40.0
        pa, pb = np.array([5.0, -1.8 + 1.2 * t]), np.array([5.8, 1.8 - 1.2 * t])
        scans = scan_pair(Scene(circles=[(*pa, 0.3), (*pb, 0.3)]), robot, rng=rng, stamp=t)
        blackout = 1.1 <= t < 1.9
        clusters = Clusters.empty(t) if blackout else clusterer.detect(scans)
        tracks = tracker.update(clusters, robot)
        if t >= 1.0 and not blackout:
            for name, p in (("A", pa), ("B", pb)):
                (near,) = [o for o in tracks if np.hypot(*(np.array(o.position) - p)) < 0.3]
                assert ids.setdefault(name, near.id) == near.id, f"{name} swapped at t={t}"
    assert ids["A"] != ids["B"]


def test_static_obstacle_from_a_turning_robot_has_no_velocity():
    rng = np.random.default_rng(3)
    clusterer = ScanClusterer(LENGTH, WIDTH)
    tracker = ObstacleTracker(DangerParams(LENGTH, WIDTH))
    scene = Scene(circles=[(5.0, 2.0, 0.4)])
    x = y = heading = 0.0
    for k in range(120):
        robot = Pose2(x, y, heading)
        tracks = tracker.update(
            clusterer.detect(scan_pair(scene, robot, rng=rng, stamp=k / 40.0)), robot, (1.0, 0.3)
        )
        x += math.cos(heading) / 40.0
        y += math.sin(heading) / 40.0
        heading += 0.3 / 40.0
    (pole,) = tracks
    assert pole.kind == "circle"
    assert np.hypot(*pole.velocity) < 0.1
    assert np.allclose(pole.position, robot.inverse().apply((5.0, 2.0)), atol=0.05)
    assert pole.shape[:2] == pytest.approx(pole.position)
    assert pole.age == pytest.approx(119 / 40.0)
    cov = pole.covariance
    assert cov.shape == (4, 4) and np.allclose(cov, cov.T)
    assert np.all(np.linalg.eigvalsh(cov) > 0.0)


def test_tracks_are_confirmed_then_deleted_after_coasting():
    clusterer = ScanClusterer(LENGTH, WIDTH)
    tracker = ObstacleTracker(DangerParams(LENGTH, WIDTH))
    robot = Pose2(0.0, 0.0, 0.0)
    seen = Scene(circles=[(4.0, 0.0, 0.3)])
    counts = []
    for k in range(100):
        scene = seen if k < 20 else Scene()
        scans = scan_pair(scene, robot, rng=np.random.default_rng(k), stamp=k / 40.0)
        counts.append(len(tracker.update(clusterer.detect(scans), robot)))
    assert counts[:2] == [0, 0] and counts[2] == 1  # confirmed at the third hit
    coast = tracker.params.coast_time
    assert all(c == 1 for c in counts[2 : 20 + int(coast * 40)])
    assert counts[-1] == 0 and len(tracker) == 0


def _clusters(stamp, position, size, kind):
    n = len(position)
    circle = np.column_stack((position, size))
    return Clusters(
        stamp=stamp,
        points=np.repeat(position, 3, axis=0),
        start=np.arange(0, 3 * n + 1, 3),
        kind=kind.astype(np.int8),
        centroid=position,
        position=position,
        size=size,
        line=np.where((kind == LINE)[:, None], np.tile(position, 2), np.nan),
        circle=np.where((kind == CIRCLE)[:, None], circle, np.nan),
        rms=np.zeros(n),
        clearance=np.hypot(position[:, 0], position[:, 1]),
        occluded=np.zeros(n, dtype=bool),
        ends_visible=np.zeros((n, 2), dtype=bool),
        boxed=np.zeros(n, dtype=bool),
    )


@settings(max_examples=30, deadline=None)
@given(
    steps=st.lists(
        st.tuples(
            st.floats(0.0, 0.5),  # dt, 0 included
            st.lists(
                st.tuples(
                    st.floats(-20, 20),
                    st.floats(-20, 20),
                    st.floats(0.0, 3.0),
                    st.sampled_from([LINE, CIRCLE, BLOB]),
                ),
                max_size=6,
            ),
            st.tuples(st.floats(-50, 50), st.floats(-50, 50), st.floats(-4, 4)),
            st.tuples(st.floats(-2, 2), st.floats(-1, 1)),
        ),
        min_size=1,
        max_size=25,
    )
)
def test_tracker_never_produces_nan(steps):
    tracker = ObstacleTracker(DangerParams(LENGTH, WIDTH))
    t = 0.0
    for dt, measured, pose, velocity in steps:
        t += dt
        arr = np.array([m[:3] for m in measured], dtype=float).reshape(-1, 3)
        kind = np.array([m[3] for m in measured], dtype=np.intp)
        clusters = _clusters(t, arr[:, :2], arr[:, 2], kind)
        for track in tracker.update(clusters, Pose2(*pose), velocity):
            values = (*track.position, *track.velocity, track.size, track.clearance, track.age)
            assert np.all(np.isfinite(values)), track
            assert np.all(np.isfinite(track.covariance))
            assert np.all(np.isfinite(track.shape))
    assert np.all(np.isfinite(tracker.state)) and np.all(np.isfinite(tracker.covariance))


def test_a_well_tracked_walker_does_not_take_a_post_seen_a_metre_away():
    """Avoidance campaign episode 979: a round post, hidden for over a second by a chaser
    passing in front of it (its track deleted), was seen again, cut by the chaser, 1.2 m
    from the chaser's track, in a scan that did not show the chaser. The partial view's
    inflated variance and a fixed 1 m allowance beyond the two sizes let the chaser's
    track take it: the track jumped to the post and back, scan after scan, and the post
    got no track of its own. How far a track's object may lie from its prediction now
    follows the track's own uncertainty (at most that 1 m)."""
    tracker = ObstacleTracker(DangerParams(LENGTH, WIDTH))
    robot = Pose2(0.0, 0.0, 0.0)
    velocity = np.array([-0.3, 0.0])
    walker = np.zeros(2)
    for k in range(81):  # 2 s at 40 Hz
        walker = np.array([5.0, 0.0]) + velocity * k / 40.0
        tracker.update(
            _clusters(k / 40.0, walker[None], np.array([0.3]), np.array([CIRCLE])), robot
        )
    seen = walker + np.array([0.0, 1.2])
    post = _clusters(81 / 40.0, seen[None], np.array([0.33]), np.array([CIRCLE]))
    tracker.update(dataclasses.replace(post, occluded=np.ones(1, dtype=bool)), robot)
    assert len(tracker) == 2  # the post starts a track of its own
    (row,) = (tracker.hits >= tracker.params.confirm_hits).nonzero()[0]
    assert np.hypot(*(tracker.state[row, :2] - (walker + velocity / 40.0))) < 0.05
    assert tracker.state[row, 2:] == pytest.approx(velocity, abs=0.05)


def test_a_trolley_sliding_past_a_post_keeps_its_speed_and_the_post_its_track():
    """A trolley pushed sideways at 0.32 m/s slides past a post 2 cm from its side
    (avoidance campaign episode 979's chaser against its round blocker): for 2.5 s the
    breakpoint detector sees the trolley's face and the post as one segment, whose
    middle is neither. Without the tracks' help the trolley's track, fed that merged
    view, fell to 0.15 m/s and the post's track was deleted. The clusterer, given the
    tracks' predictions (:meth:`ObstacleTracker.hints`), cuts the segment back into the
    two objects."""
    rng = np.random.default_rng(3)
    clusterer = ScanClusterer(LENGTH, WIDTH)
    tracker = ObstacleTracker(DangerParams(LENGTH, WIDTH))
    robot = Pose2(0.0, 0.0, 0.0)
    post = (4.0, 0.9, 0.333)
    merged, speeds, post_ids, post_speeds = 0, [], set(), []
    for k in range(480):  # 12 s at 40 Hz
        t = k / 40.0
        trolley = Scene.from_box(6.5 - 0.32 * t, 0.9 - 0.333 - 0.6 - 0.02, math.pi / 2, 1.2, 0.8)
        scans = scan_pair(Scene.concat([trolley, Scene(circles=[post])]), robot, rng=rng, stamp=t)
        merged += len(ScanClusterer(LENGTH, WIDTH).detect(scans)) == 1  # the detector alone
        tracks = tracker.update(clusterer.detect(scans, None, tracker.hints(t, robot)), robot)
        if t >= 1.0:
            (near_post,) = [
                o for o in tracks if np.hypot(o.position[0] - 4.0, o.position[1] - 0.9) < 0.1
            ]
            post_ids.add(near_post.id)
            post_speeds.append(near_post.speed)
            speeds += [o.speed for o in tracks if o.id != near_post.id]
    assert merged > 80  # over 2 s of scans see one segment
    assert len(post_ids) == 1 and max(post_speeds) < 0.05
    assert len(speeds) == 440 and min(speeds) > 0.25 and max(speeds) < 0.36  # 0.15 unhelped


def test_a_trolley_sliding_along_a_long_box_keeps_its_speed():
    """A trolley pushed at 0.4 m/s along the face of a parked box too big to be hinted
    (2.6 x 1 m, 1.4 m enclosing radius), 2 cm off it: for seconds the breakpoint detector
    sees the two as one segment, a blob over ``max_blob_size`` that only re-anchors a
    track. The trolley's track, fed it, was taken for still (avoidance campaign episode
    558, where such a chaser struck the robot). Its points, cut out by its own disc,
    keep it moving, and the box's track stays still."""
    rng = np.random.default_rng(5)
    clusterer = ScanClusterer(LENGTH, WIDTH)
    tracker = ObstacleTracker(DangerParams(LENGTH, WIDTH))
    robot = Pose2(0.0, 0.0, 0.0)
    box = Scene.from_box(5.0, 2.0, 0.0, 2.6, 1.0)  # its near face at y = 1.5, x 3.7..6.3
    merged, speeds, box_speeds = 0, [], []
    for k in range(400):  # 10 s at 40 Hz: the trolley from x = 8.2 to 4.2
        t = k / 40.0
        trolley = Scene.from_box(8.2 - 0.4 * t, 1.5 - 0.02 - 0.4, 0.0, 1.2, 0.8)
        scans = scan_pair(Scene.concat([box, trolley]), robot, rng=rng, stamp=t)
        merged += len(ScanClusterer(LENGTH, WIDTH).detect(scans)) == 1  # the detector alone
        tracks = tracker.update(clusterer.detect(scans, None, tracker.hints(t, robot)), robot)
        if t >= 2.0:
            near_box = [o for o in tracks if o.position[1] > 1.6]
            box_speeds += [o.speed for o in near_box]
            trolleys = [o for o in tracks if o.position[1] <= 1.6]
            speeds.append(max((o.speed for o in trolleys), default=0.0))
    assert merged > 200  # over 5 s of scans see one segment
    assert min(speeds) > 0.25 and max(speeds) < 0.55
    assert box_speeds and max(box_speeds) < 0.05


@pytest.mark.parametrize("episode", [558, 323])
def test_campaign_episodes_a_mover_cut_out_of_structure(episode):
    """Avoidance campaign episode 558: a chaser (a trolley at 0.54 m/s) seen only in part
    past a parked cart lost its hint a second after it was first seen; merged with the
    cart and a long box into one 2.7 m segment, it was tracked as that blob at 0 m/s and
    struck the robot. Hinted while seen in part and cut out of the merge, it is seen
    moving. Episode 323 holds the cut to movers: a parked box's track, its view shrunk to
    a fragment that slid, cut the box's face for itself, sped along it at 0.9 m/s and
    held the robot still while the real chaser struck it; a track once seen whole bigger
    than ``max_blob_size`` never cuts. Both legs complete with no collision."""
    campaign = load_campaign(MISSIONS / "campaigns" / "avoidance-leg.xml")
    row = episode_row(campaign, episode)
    assert row["succeeded"], row["causes"]
    assert row["collisions"] == []


# -- danger --------------------------------------------------------------------------------
DANGER = DangerParams(LENGTH, WIDTH, margin=0.2, r_oa_trigger=2.5, horizon=3.0, imminent_time=1.0)


def levels(positions, velocities, sizes, v, omega):
    p = np.array(positions, dtype=float)
    clearance = np.hypot(
        np.maximum(np.abs(p[:, 0]) - LENGTH / 2, 0), np.maximum(np.abs(p[:, 1]) - WIDTH / 2, 0)
    ) - np.array(sizes)
    return [
        Danger(d).name
        for d in danger_level(
            p, np.array(velocities, float), np.array(sizes, float), clearance, v, omega, DANGER
        )
    ]


def test_danger_levels_straight():
    # at 1 m/s over 3 s the path ends 3 m + half the length ahead
    assert levels(
        [(3.0, 0.0), (4.1, 0.0), (4.8, 0.0), (2.0, 2.0), (10.0, 5.0), (3.0, -2.5), (1.6, 0.2)],
        [(0, 0), (0, 0), (0, 0), (0, 0), (0, 0), (0, 1.0), (0, 0)],
        [0.3] * 7,
        1.0,
        0.0,
    ) == ["ON_PATH", "ON_PATH", "NONE", "NEAR", "NONE", "ON_PATH", "IMMINENT"]
    # a walker crossing ahead, 4 m away, will be in the corridor within 3 s; one
    # walking away from the path is not on it
    assert levels([(4.0, -3.0), (4.0, -2.0)], [(0, 1.2), (0, -1.2)], [0.3, 0.3], 1.0, 0.0) == [
        "ON_PATH",
        "NONE",
    ]


def test_danger_levels_on_an_arc_and_standing_still():
    # turning left on a 2 m radius: a point on that arc is on the path, the point
    # straight ahead is not
    on_arc = (2.0 * math.sin(1.4), 2.0 * (1.0 - math.cos(1.4)))
    assert levels([on_arc, (4.0, -0.6)], [(0, 0), (0, 0)], [0.2, 0.2], 1.0, 0.5) == [
        "ON_PATH",
        "NONE",
    ]
    assert levels([(4.0, -0.6)], [(0, 0)], [0.2], 1.0, 0.0) == ["ON_PATH"]
    # standing still: only what comes at the robot is on its path
    assert levels([(3.0, 0.0), (3.0, 0.0)], [(0, 0), (-2.0, 0)], [0.3, 0.3], 0.0, 0.0) == [
        "NEAR",
        "IMMINENT",
    ]
    assert levels([(4.0, 0.0), (4.0, 0.0)], [(0, 0), (-1.0, 0)], [0.3, 0.3], 0.0, 0.0) == [
        "NONE",
        "ON_PATH",
    ]


def test_path_distance_arc_and_segment():
    # straight, 5 m ahead: a point 1 m aside at 2 m along, one behind the start
    d = path_distance(np.array([[2.0, 1.0], [-1.0, 0.0], [7.0, 0.0]]), 1.0, 0.0, 5.0)
    assert d == pytest.approx([1.0, 1.0, 2.0])
    # an arc of radius 2 (v=1, omega=0.5) over a quarter turn
    rho = 2.0
    pts = np.array([[rho * math.sin(0.5), rho * (1 - math.cos(0.5))], [0.0, rho], [0, -1.0]])
    d = path_distance(pts, 1.0, 0.5, rho * math.pi / 2)
    assert d == pytest.approx([0.0, rho, 1.0])
    # reversing: the path runs along -x
    assert path_distance(np.array([[-2.0, 0.5]]), -1.0, 0.0, 5.0) == pytest.approx([0.5])


def test_a_trolley_seen_as_an_l_keeps_its_speed():
    """A 1.2 x 0.8 m trolley passing behind the robot at 0.5 m/s, seen by the rear laser
    as an L (campaign episode 42, in the robot frame): about its centroid, pulled to the
    dense near corner, the cluster measured more than ``max_blob_size``, so the tracker
    only re-anchored it and its speed decayed (in the episode the trolley was "slowed to
    0.08 m/s" and struck the robot). The tracked point, the centre of the rectangle fitted
    to the L, is the trolley's centre whatever the view, and about it the trolley
    measures its half-diagonal: the speed holds."""
    rng = np.random.default_rng(3)
    clusterer = ScanClusterer(LENGTH, WIDTH)
    tracker = ObstacleTracker(DangerParams(LENGTH, WIDTH))
    robot = Pose2(0.0, 0.0, 0.0)
    heading = 0.62
    velocity = 0.5 * np.array([math.cos(heading), math.sin(heading)])
    start = np.array([-1.5, -2.8]) - 3.0 * velocity
    biggest, speeds = 0.0, []
    for k in range(240):  # 6 s at 40 Hz
        t = k / 40.0
        scene = Scene.from_box(*(start + velocity * t), heading, 1.2, 0.8)
        clusters = clusterer.detect(scan_pair(scene, robot, rng=rng, stamp=t))
        # about the rectangle's centre the trolley measures its half-diagonal, 0.72 m
        assert np.all(clusters.size <= math.hypot(0.6, 0.4) + 0.05)
        for i in range(len(clusters)):  # the enclosing radius about the centroid
            pts = clusters.points[clusters.start[i] : clusters.start[i + 1]]
            radius = np.hypot(*(pts - clusters.centroid[i]).T).max()
            biggest = max(biggest, float(radius))
        tracks = tracker.update(clusters, robot)
        if t >= 1.5:
            (track,) = tracks
            speeds.append(track.speed)
    assert biggest > tracker.params.max_blob_size  # the view that fooled the old rule
    assert min(speeds) > 0.4 and np.median(speeds) == pytest.approx(0.5, abs=0.03)


def test_a_static_box_driven_round_stays_static():
    """A 1.4 x 0.9 m equipment box the robot drives round at 2-3 m (campaign episode 141):
    the centroid of the returns slides along the faces as the view changes, and the
    box's track seemed to move at 0.1-0.2 m/s, which switched the avoidance between
    the spiral and velocity obstacles for a whole minute. The rectangle's centre does
    not slide."""
    rng = np.random.default_rng(5)
    clusterer = ScanClusterer(LENGTH, WIDTH)
    tracker = ObstacleTracker(DangerParams(LENGTH, WIDTH))
    scene = Scene.from_box(0.0, 0.0, math.radians(49), 1.4, 0.9)
    speeds, kinds = [], set()
    for k in range(400):  # 10 s at 40 Hz: a quarter of a circle of 2.6 m
        t = k / 40.0
        angle = -math.pi / 2 + (math.pi / 2) * t / 10.0
        centre = 2.6 * np.array([math.cos(angle), math.sin(angle)])
        robot = Pose2(*centre, angle + math.pi / 2)  # driving anticlockwise round it
        tracks = tracker.update(clusterer.detect(scan_pair(scene, robot, rng=rng, stamp=t)), robot)
        if t >= 1.0:
            (track,) = tracks
            speeds.append(track.speed)
            kinds.add(track.kind)
    assert kinds == {"blob", "line"}  # seen as an L, then as one face
    assert max(speeds) < 0.08  # below slow_speed: never taken for a mover


def test_two_people_standing_side_by_side_stay_static_from_a_turning_robot():
    """Two people standing shoulder to shoulder 2 m from a robot that turns on the spot,
    one way then the other (campaign episode 976): a scan sees one of them as a circle,
    the next sees both as one blob whose centroid lies between them. Read as motion, the
    0.2 m jump made the pair a mover at up to 0.7 m/s, which kept taking the robot from
    the planner to velocity obstacles for a minute. A view grown or shrunk beyond the
    size tolerance is another set of points: it re-anchors the track."""
    rng = np.random.default_rng(13)
    clusterer = ScanClusterer(LENGTH, WIDTH)
    tracker = ObstacleTracker(DangerParams(LENGTH, WIDTH))
    scene = Scene(circles=[(1.97, -0.50, 0.3), (2.30, -1.03, 0.3)])
    heading, speeds, sizes = math.radians(60.0), [], set()
    for k in range(800):  # 20 s at 40 Hz, turning at 1 rad/s, the other way every 1.5 s
        t = k / 40.0
        omega = 1.0 if int(t / 1.5) % 2 == 0 else -1.0
        robot = Pose2(0.0, 0.0, heading)
        clusters = clusterer.detect(scan_pair(scene, robot, rng=rng, stamp=t))
        sizes.update(np.round(clusters.size, 1))
        tracks = tracker.update(clusters, robot, (0.0, omega))
        if t >= 1.0:
            speeds += [o.speed for o in tracks]
        heading += omega / 40.0
    assert max(sizes) > 0.6  # both as one cluster in some views
    assert max(speeds) < 0.15  # below the avoidance policy's fast_speed


def test_a_trolley_long_seen_face_on_is_tracked_once_it_turns_and_rolls():
    """A trolley stands face-on to the robot for 5 s (a line in every scan), is turned
    45 deg in a second and rolls away at 0.55 m/s, seen corner-on (a blob in every scan;
    campaign episode 203). The track's kind is a vote over its whole life, so it stayed a
    line track for as long as the trolley had stood; a line track seen as another shape
    only re-anchored, scan after scan, and the trolley rolled on at a tracked 0 m/s for
    6 s, into the robot. The change of kind re-anchors once; the blobs after it are
    measured."""
    rng = np.random.default_rng(3)
    clusterer = ScanClusterer(LENGTH, WIDTH)
    tracker = ObstacleTracker(DangerParams(LENGTH, WIDTH))
    robot = Pose2(0.0, 0.0, 0.0)
    kinds, speeds = [], []
    for k in range(360):  # 9 s at 40 Hz
        t = k / 40.0
        heading = math.pi / 2 - math.pi / 4 * min(1.0, max(0.0, t - 5.0))  # face-on, turned
        s = 0.55 * max(0.0, t - 6.0)  # rolled along its heading
        trolley = Scene.from_box(
            4.0 + s * math.cos(heading), s * math.sin(heading), heading, 1.2, 0.8
        )
        clusters = clusterer.detect(scan_pair(trolley, robot, rng=rng, stamp=t))
        tracks = tracker.update(clusters, robot)
        kinds.append(tuple(int(kind) for kind in clusters.kind))
        if t >= 7.0:
            (track,) = tracks
            speeds.append(track.speed)
    assert set(kinds[:200]) == {(LINE,)}  # face-on while it stands
    assert set(kinds[240:]) == {(BLOB,)}  # corner-on while it rolls
    assert min(speeds) > 0.45 and max(speeds) < 0.65
