"""sim2d.raycast: every beam against analytic geometry, and against brute force.

The analytic tests compare every beam of a Hokuyo UTM-30LX scan (270 deg, 1081 beams,
30 m) with closed-form distances (wall: normal form, circle: d cos - sqrt(r^2 - (d sin)^2),
box: slab method) within 1e-9 m. The property tests compare :func:`cast_scan` and
:func:`cast_rays` with a brute-force reference (every ray against every shape, plain
numpy, world frame) on random scenes and poses: within 1e-9 m, widened only by the
float64 conditioning of the answer in the beam angle (grazing incidence, tangent beams);
beams within 1e-10 rad of a shape's angular border are left out, since hit or miss
there is decided by rounding.
"""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sim2d.raycast import Scene, box_corners, cast_rays, cast_scan

AMIN, INC, N, RMAX = -3 * math.pi / 4, math.pi / 720, 1081, 30.0
HOKUYO = (AMIN, INC, N, RMAX)
EXACT = 1e-9


def scan(scene, origin=(0.0, 0.0), heading=0.0, params=HOKUYO):
    return cast_scan(scene, origin, heading, *params)


def beam_angles(heading=0.0, params=HOKUYO):
    amin, inc, n, _ = params
    return heading + amin + inc * np.arange(n)


def unit(angle):
    return np.array([math.cos(angle), math.sin(angle)])


# -- analytic references ------------------------------------------------------------------
def wall_ranges(p1, p2, origin, angles, rmax=RMAX):
    """Normal form of the wall's line, t = rho / cos(phi - alpha), kept inside the wall."""
    p1, p2, o = np.asarray(p1, float), np.asarray(p2, float), np.asarray(origin, float)
    along = (p2 - p1) / np.linalg.norm(p2 - p1)
    normal = np.array([-along[1], along[0]])
    rho = float(np.dot(p1 - o, normal))
    if rho < 0:
        normal, rho = -normal, -rho
    alpha = math.atan2(normal[1], normal[0])
    cos = np.cos(angles - alpha)
    with np.errstate(divide="ignore"):
        t = np.where(cos > 0, rho / cos, np.inf)
    finite = np.where(np.isfinite(t), t, 0.0)
    hit = o + finite[:, None] * np.column_stack((np.cos(angles), np.sin(angles)))
    s = (hit - p1) @ along
    inside = np.isfinite(t) & (s >= -1e-9) & (s <= np.linalg.norm(p2 - p1) + 1e-9)
    return np.minimum(np.where(inside, t, np.inf), rmax)


def circle_ranges(centre, r, origin, angles, rmax=RMAX):
    """d cos(delta) - sqrt(r^2 - (d sin(delta))^2) where the beam meets the circle."""
    v = np.asarray(centre, float) - np.asarray(origin, float)
    d, gamma = math.hypot(*v), math.atan2(v[1], v[0])
    delta = angles - gamma
    disc = r * r - (d * np.sin(delta)) ** 2
    hit = (disc >= 0) & (np.cos(delta) > 0)
    t = d * np.cos(delta) - np.sqrt(np.maximum(disc, 0.0))
    return np.minimum(np.where(hit, t, np.inf), rmax)


def box_ranges(x, y, heading, length, width, origin, angles, rmax=RMAX):
    """Slab method in the box frame."""
    c, s = math.cos(heading), math.sin(heading)
    ox, oy = origin[0] - x, origin[1] - y
    px, py = c * ox + s * oy, -s * ox + c * oy
    dx, dy = np.cos(angles - heading), np.sin(angles - heading)
    with np.errstate(divide="ignore", invalid="ignore"):
        tx1, tx2 = (-length / 2 - px) / dx, (length / 2 - px) / dx
        ty1, ty2 = (-width / 2 - py) / dy, (width / 2 - py) / dy
    near = np.maximum(np.minimum(tx1, tx2), np.minimum(ty1, ty2))
    far = np.minimum(np.maximum(tx1, tx2), np.maximum(ty1, ty2))
    hit = (near <= far) & (near > 0)
    return np.minimum(np.where(hit, near, np.inf), rmax)


# -- brute-force reference -----------------------------------------------------------------
def brute_force(scene, origin, angles):
    """Every ray against every shape, in the world frame, with no culling tricks.

    Returns the (R, K) distances (inf: no hit) with the owner of each column, the nearest
    distance per ray, the per-ray tolerance (1e-9 m plus the effect of a 1e-13 rad error
    in the ray's angle) and the *border* rays, where hit or miss is up to rounding: within
    1e-10 rad of a shape's angular border, or hitting a shape that the documented rules
    only just ignore or keep (sensor within ~1e-9 of a segment's line, or within 1e-12
    of a circle) nearer than the answer.
    """
    ox, oy = origin
    c, s = np.cos(angles)[:, None], np.sin(angles)[:, None]
    seg, cen, rad = scene.segments, scene.centers, scene.radii
    ax, ay, bx, by = seg[:, 0] - ox, seg[:, 1] - oy, seg[:, 2] - ox, seg[:, 3] - oy
    ex, ey = bx - ax, by - ay
    length = np.hypot(ex, ey)
    cross = ax * ey - ay * ex  # = a x b, without its cancellation
    span = np.hypot(ax, ay) + np.hypot(bx, by)
    # The documented rules: a segment whose line passes within 4e-12 (|a| + |b|) of the
    # sensor is ignored, so is a polygon edge seen from its interior side.
    usable = (length > 0) & (np.abs(cross) > 4e-12 * span * length)
    usable &= ~(scene.one_sided & (cross > 0))
    doubtful_seg = (length > 0) & (np.abs(cross) <= 1e-9 * span * length)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        den = c * ey - s * ex
        t_seg = cross / den
        u = (ax * s - ay * c) / den
        sens_seg = np.abs(t_seg * (c * ex + s * ey) / den)
    geometric = (den != 0) & (t_seg >= 0) & (u >= 0) & (u <= 1)
    hit = usable & geometric
    t_doubt = np.where(doubtful_seg & geometric, t_seg, np.inf)
    t_seg = np.where(hit, t_seg, np.inf)
    tol_seg = np.where(hit, 1e-13 * sens_seg, 0.0)

    def off(px, py):  # angle between the ray and the direction of a point
        return np.abs(np.arctan2(c * py - s * px, c * px + s * py))

    border_seg = usable & ((off(ax, ay) < 1e-10) | (off(bx, by) < 1e-10))

    cx, cy, r = cen[:, 0] - ox, cen[:, 1] - oy, rad
    d = np.hypot(cx, cy)
    p = c * cx + s * cy
    q = c * cy - s * cx
    disc = r * r - q * q
    outside = d > r
    hit = outside & (disc >= 0) & (p > 0)
    root = np.sqrt(np.maximum(disc, 0.0))
    t_circ = np.where(hit, p - root, np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        steep = np.where(root > 0, np.abs(q * p) / root, np.inf)
        half = np.arcsin(np.minimum(r / d, 1.0))
        border_circ = outside & (np.abs(np.abs(np.arcsin(np.clip(q / d, -1, 1))) - half) < 1e-10)
    tol_circ = np.where(
        hit, 1e-13 * d + np.minimum(1e-13 * steep, np.sqrt(2e-13 * np.abs(q) * d)), 0.0
    )
    doubtful_circ = np.abs(d - r) <= 1e-12 * d
    t_doubt_circ = np.where(doubtful_circ & (disc >= 0) & (p >= 0), 0.0, np.inf)

    t = np.hstack((t_seg, t_circ))
    tol = np.hstack((tol_seg, tol_circ))
    best = t.min(axis=1, initial=np.inf)
    ray_tol = np.full(len(best), EXACT)
    if t.shape[1]:
        ray_tol += np.take_along_axis(tol, t.argmin(axis=1)[:, None], axis=1)[:, 0]
    border = np.hstack((border_seg, border_circ)).any(axis=1)
    doubt = np.hstack((t_doubt, t_doubt_circ)).min(axis=1, initial=np.inf)
    border |= np.isfinite(doubt) & (doubt <= best + ray_tol)
    owners = np.concatenate((scene.segment_owner, scene.circle_owner))
    return t, owners, best, ray_tol, border


# -- geometry, every beam ------------------------------------------------------------------
@pytest.mark.parametrize(
    ("p1", "p2", "origin", "heading"),
    [
        ((5.0, -10.0), (5.0, 10.0), (0.0, 0.0), 0.0),  # straight ahead
        ((2.0, 7.0), (-6.0, 1.5), (0.3, -0.4), 1.1),  # rotated, to the left
        ((12.0, -3.0), (25.0, 8.0), (-1.0, 2.0), -0.2),  # partly beyond 30 m
        ((-3.0, 0.5), (3.0, 0.5), (0.0, 0.0), math.pi / 2),  # very close, 160 deg wide
    ],
)
def test_wall_every_beam(p1, p2, origin, heading):
    expected = wall_ranges(p1, p2, origin, beam_angles(heading))
    for scene in (Scene([(*p1, *p2)]), Scene([(*p2, *p1)])):
        got = scan(scene, origin, heading)
        np.testing.assert_allclose(got, expected, rtol=0, atol=EXACT)
    assert (expected < RMAX).sum() > 50


@pytest.mark.parametrize(
    ("centre", "r", "origin", "heading"),
    [
        ((6.0, 0.0), 1.0, (0.0, 0.0), 0.0),
        ((-2.0, 9.0), 2.5, (0.5, 0.5), 2.0),
        ((1.2, 0.0), 1.0, (0.0, 0.0), 0.0),  # 0.2 m away: 112 deg wide
        ((29.5, 0.0), 0.8, (0.0, 0.0), 0.0),  # near side within range, the rest beyond
    ],
)
def test_circle_every_beam(centre, r, origin, heading):
    got = scan(Scene(circles=[(*centre, r)]), origin, heading)
    expected = circle_ranges(centre, r, origin, beam_angles(heading))
    np.testing.assert_allclose(got, expected, rtol=0, atol=EXACT)
    assert (expected < RMAX).any()


@pytest.mark.parametrize(
    ("box", "origin", "heading"),
    [
        ((4.0, 1.0, 0.0, 2.0, 1.0), (0.0, 0.0), 0.0),  # axis-aligned
        ((-3.0, 5.0, 0.7, 4.5, 2.0), (0.4, -0.3), 2.3),  # rotated
        ((1.0, 5.0, -1.2, 9.0, 2.5), (0.0, 0.0), 1.0),  # fuel truck, close
    ],
)
def test_box_every_beam(box, origin, heading):
    got = scan(Scene.from_box(*box), origin, heading)
    expected = box_ranges(*box, origin, beam_angles(heading))
    np.testing.assert_allclose(got, expected, rtol=0, atol=EXACT)
    # the same edges as two-sided segments (no back-face culling) give the same scan
    two_sided = Scene(Scene.from_box(*box).segments)
    np.testing.assert_allclose(scan(two_sided, origin, heading), expected, rtol=0, atol=EXACT)


def test_occlusion_nearer_shape_wins():
    boxes = [(8.0, 0.0, 0.3, 2.0, 3.0), (4.0, -3.0, 0.0, 1.0, 1.0)]
    circles = [(5.0, 1.5, 0.7), (-2.0, 6.0, 1.0)]
    wall = ((12.0, -20.0), (12.0, 20.0))
    scene = Scene.concat(
        [Scene([(*wall[0], *wall[1])]), Scene(circles=circles)]
        + [Scene.from_box(*b) for b in boxes]
    )
    origin, heading = (0.5, 0.2), 0.1
    a = beam_angles(heading)
    expected = np.minimum.reduce(
        [wall_ranges(*wall, origin, a)]
        + [circle_ranges(c[:2], c[2], origin, a) for c in circles]
        + [box_ranges(*b, origin, a) for b in boxes]
    )
    np.testing.assert_allclose(scan(scene, origin, heading), expected, rtol=0, atol=EXACT)
    # the circle in front of the box and the box in front of the wall do hide them
    hidden = circle_ranges(circles[0][:2], circles[0][2], origin, a) < box_ranges(
        *boxes[0], origin, a
    )
    assert hidden.sum() > 10


def test_max_range():
    far = Scene.concat(
        [
            Scene([(31.0, -5.0, 31.0, 5.0)], circles=[(0.0, 40.0, 9.9)]),
            Scene.from_box(-35.0, 0.0, 0.4, 3.0, 3.0),
        ]
    )
    assert np.all(scan(far) == RMAX)
    ranges = cast_scan(Scene([(10.0, -50.0, 10.0, 50.0)]), (0, 0), 0.0, AMIN, INC, N, 12.0)
    expected = wall_ranges((10.0, -50.0), (10.0, 50.0), (0, 0), beam_angles(), rmax=12.0)
    np.testing.assert_allclose(ranges, expected, rtol=0, atol=EXACT)
    assert (ranges == 12.0).sum() > 500 and (ranges < 12.0).sum() > 200


def test_behind_the_scanner_never_seen():
    behind = Scene.concat(
        [
            Scene(circles=[(-3.0, 0.0, 1.5)]),  # within the 90 deg blind sector
            Scene.from_box(-6.0, 0.5, 0.3, 1.0, 1.0),
            Scene([(-2.0, -1.0, -2.0, 1.0)]),
        ]
    )
    assert np.all(scan(behind) == RMAX)
    # a wall just behind the sensor reaches into both ends of the field of view, and the
    # beams exactly at its borders (+-135 deg) see it
    wall = ((-0.5, -50.0), (-0.5, 50.0))
    got = scan(Scene([(*wall[0], *wall[1])]))
    expected = wall_ranges(*wall, (0, 0), beam_angles())
    np.testing.assert_allclose(got, expected, rtol=0, atol=EXACT)
    assert got[0] < RMAX and got[-1] < RMAX and got[N // 2] == RMAX


def test_wrap_around_of_world_angles():
    # heading pi: the wall straddles the +-pi direction of atan2
    wall = ((-5.0, -3.0), (-5.0, 3.0))
    for heading in (math.pi, -math.pi, 3 * math.pi, math.pi - 1e-12):
        got = scan(Scene([(*wall[0], *wall[1])]), (0.0, 0.0), heading)
        expected = wall_ranges(*wall, (0.0, 0.0), beam_angles(heading))
        np.testing.assert_allclose(got, expected, rtol=0, atol=EXACT)
        assert (got < RMAX).sum() > 200


def test_wrap_around_at_the_first_beam():
    # a circle straddling the direction of beam 0: only the first beams see it
    centre = 5.0 * unit(AMIN)
    got = scan(Scene(circles=[(*centre, 1.0)]))
    expected = circle_ranges(centre, 1.0, (0, 0), beam_angles())
    np.testing.assert_allclose(got, expected, rtol=0, atol=EXACT)
    assert got[0] < RMAX and got[-1] == RMAX
    # a full-circle scanner sees it at both ends
    ring = (-math.pi, 2 * math.pi / 1440, 1440, RMAX)
    centre = 5.0 * unit(-math.pi)
    got = scan(Scene(circles=[(*centre, 1.0)]), params=ring)
    expected = circle_ranges(centre, 1.0, (0, 0), beam_angles(params=ring))
    np.testing.assert_allclose(got, expected, rtol=0, atol=EXACT)
    assert got[0] < RMAX and got[-1] < RMAX and got[720] == RMAX


def test_overlapping_full_circle_scanner():
    # -pi..pi inclusive: beams 0 and 1440 point the same way and must agree
    ring = (-math.pi, 2 * math.pi / 1440, 1441, RMAX)
    centre = 5.0 * unit(math.pi)
    got = scan(Scene(circles=[(*centre, 1.0)]), params=ring)
    assert got[0] == pytest.approx(4.0, abs=EXACT) and got[-1] == pytest.approx(4.0, abs=EXACT)


# -- borders of intervals --------------------------------------------------------------------
@pytest.mark.parametrize("k", [0, 17, 540, 1079, 1080])
@pytest.mark.parametrize("heading", [0.0, 2.9, -1.3])
def test_beam_exactly_at_a_segment_end_point_hits_it(k, heading):
    theta = heading + AMIN + k * INC
    origin = np.array([0.7, -0.2])
    end = origin + 8.0 * unit(theta)
    for other in (origin + 9.0 * unit(theta + 0.2), origin + 9.0 * unit(theta - 0.2)):
        for seg in ((*end, *other), (*other, *end)):
            got = scan(Scene([seg]), tuple(origin), heading)
            assert got[k] == pytest.approx(8.0, abs=EXACT)
            expected = wall_ranges(end, other, origin, beam_angles(heading))
            np.testing.assert_allclose(got, expected, rtol=0, atol=EXACT)


@pytest.mark.parametrize("k", [3, 540, 1077])
def test_beam_exactly_at_a_box_corner(k):
    theta = AMIN + k * INC
    corner = 6.0 * unit(theta)
    # a square with that corner nearest to the sensor, its diagonal along the beam
    centre = corner + math.sqrt(2.0) * unit(theta)
    box = (*centre, theta + math.pi / 4, 2.0, 2.0)
    got = scan(Scene.from_box(*box))
    assert got[k] == pytest.approx(6.0, abs=1e-9)
    np.testing.assert_allclose(got, box_ranges(*box, (0, 0), beam_angles()), atol=1e-9)


@pytest.mark.parametrize("side", [1.0, -1.0])
@pytest.mark.parametrize(("d", "r"), [(6.0, 1.0), (20.0, 0.3), (2.0, 1.9)])
def test_beam_grazing_a_circle(side, d, r):
    k = 600
    theta = AMIN + k * INC
    centre = d * unit(theta + side * math.asin(r / d))
    got = scan(Scene(circles=[(*centre, r)]))
    # tangent: the answer is ill-conditioned in the beam angle (~1e-8 m per 1e-16 rad)
    assert got[k] == pytest.approx(math.sqrt(d * d - r * r), abs=1e-6)
    assert got[k - int(side)] == RMAX  # the next beam away from the centre misses
    assert got[k + int(side)] < RMAX


# -- sensor inside or on a shape -------------------------------------------------------------
def test_sensor_inside_or_on_a_circle_ignores_it():
    wall = Scene([(10.0, -20.0, 10.0, 20.0)])
    alone = scan(wall)
    for circle in [(0.5, 0.0, 2.0), (0.0, 0.0, 1.0), (1.0, 0.0, 1.0), (0.0, -3.0, 3.0)]:
        got = scan(Scene.concat([wall, Scene(circles=[circle])]))
        np.testing.assert_array_equal(got, alone)


def test_sensor_on_a_segment_ignores_it():
    wall = Scene([(10.0, -20.0, 10.0, 20.0)])
    alone = scan(wall)
    for seg in [(-1.0, -1.0, 1.0, 1.0), (0.0, -2.0, 0.0, 3.0), (0.0, 0.0, 5.0, 1.0)]:
        got = scan(Scene.concat([wall, Scene([seg])]))
        np.testing.assert_array_equal(got, alone)
    # on the line but off the segment: the segment is seen edge-on, so not at all
    got = scan(Scene.concat([wall, Scene([(2.0, 0.0, 5.0, 0.0)])]))
    np.testing.assert_array_equal(got, alone)


def test_sensor_inside_or_on_a_box_ignores_it():
    wall = Scene([(10.0, -20.0, 10.0, 20.0)])
    box = Scene.from_box(0.0, 0.0, 0.4, 3.0, 2.0)
    corner = tuple(box.segments[0, :2])
    middle = tuple(0.5 * (box.segments[1, :2] + box.segments[1, 2:]))
    for origin in [(0.0, 0.0), (0.5, 0.3), corner, middle]:
        got = cast_scan(Scene.concat([wall, box]), origin, 0.0, *HOKUYO)
        expected = cast_scan(wall, origin, 0.0, *HOKUYO)
        np.testing.assert_allclose(got, expected, rtol=0, atol=EXACT)


def test_non_convex_polygon_from_inside_sees_only_front_faces():
    # a U shape; from inside its left arm the right arm's outer faces are hidden, the
    # faces turned towards the sensor are seen
    ring = [(0, 0), (6, 0), (6, 4), (5, 4), (5, 1), (1, 1), (1, 4), (0, 4)]
    scene = Scene.from_polygon(ring)
    got = cast_scan(scene, (0.5, 2.0), 0.0, 0.0, INC, 1, RMAX)  # beam along +x
    assert got[0] == pytest.approx(4.5, abs=EXACT)  # the inner face of the right arm


@pytest.mark.filterwarnings("error")
def test_degenerate_shapes_are_ignored_quietly():
    wall = Scene([(10.0, -20.0, 10.0, 20.0)])
    alone = scan(wall)
    degenerate = [
        Scene([(0.0, 0.0, 0.0, 0.0)]),  # zero length, at the sensor
        Scene([(3.0, 1.0, 3.0, 1.0)]),  # zero length, elsewhere
        Scene([(0.0, 0.0, 4.0, 2.0)]),  # starts at the sensor
        Scene([(1e-300, 0.0, 0.0, 1e-300)]),  # tiny, around the sensor
        Scene(circles=[(0.0, 0.0, 0.5)]),  # centred on the sensor
    ]
    for extra in degenerate:
        np.testing.assert_array_equal(scan(Scene.concat([wall, extra])), alone)
        dist, _ = cast_rays(Scene.concat([wall, extra]), (0, 0), beam_angles(), np.inf)
        np.testing.assert_allclose(np.minimum(dist, RMAX), alone, rtol=0, atol=EXACT)


# -- API --------------------------------------------------------------------------------------
def test_from_polygon_orientation_and_validation():
    ring = [(2, -1), (4, -1), (4, 1), (2, 1)]
    expected = scan(Scene.from_polygon(ring))
    np.testing.assert_array_equal(scan(Scene.from_polygon(ring[::-1])), expected)
    np.testing.assert_array_equal(scan(Scene.from_polygon([*ring, ring[0]])), expected)
    assert Scene.from_polygon(ring).one_sided.all()
    with pytest.raises(ValueError, match="intersect"):
        Scene.from_polygon([(0, 0), (3, 3), (3, 0), (0, 1)])
    with pytest.raises(ValueError, match="area"):
        Scene.from_polygon([(0, 0), (1, 1), (2, 2)])
    with pytest.raises(ValueError):
        Scene.from_polygon([(0, 0), (1, 1)])
    with pytest.raises(ValueError, match="radii"):
        Scene(circles=[(0, 0, 0.0)])
    with pytest.raises(ValueError):
        Scene(segments=[(0, 0, 1)])


def test_concat_keeps_order_and_owners():
    a = Scene([(1, 2, 3, 4)], [(5, 6, 1)], segment_owner=[7], circle_owner=[8])
    b = Scene.from_box(0, 0, 0, 2, 1, owner=9)
    c = Scene.concat([a, b])
    assert (c.n_segments, c.n_circles) == (5, 1)
    np.testing.assert_array_equal(c.segments[0], (1, 2, 3, 4))
    np.testing.assert_array_equal(c.segment_owner, [7, 9, 9, 9, 9])
    np.testing.assert_array_equal(c.circle_owner, [8])
    np.testing.assert_array_equal(c.circles, [(5, 6, 1)])
    np.testing.assert_array_equal(c.one_sided, [False, True, True, True, True])
    assert Scene.concat([]).n_segments == 0


def test_moving_obstacles_are_rewritten_in_place():
    scene = Scene.concat(
        [
            Scene([(5, -1, 5, 1)]),
            Scene.from_box(8, 3, 0, 2, 1, owner=1),
            Scene(circles=[(0, 6, 0.5), (-4, 4, 0.3)]),
        ]
    )
    buffers = (scene._z, scene._radii)
    poses = [(8.0, 3.0, 0.0), (7.0, -2.0, 0.8), (3.0, 4.0, -2.0)]
    for step, (x, y, h) in enumerate(poses):
        scene.set_polygon(box_corners(x, y, h, 2, 1), start=1)
        scene.set_circles([(0.5 * step, 6.0, 0.5)], start=0)
        scene.centers[1] = (-4.0 + step, 4.0)
        scene.segments[0] = (5, -1 - step, 5, 1)
        fresh = Scene.concat(
            [
                Scene([(5, -1 - step, 5, 1)]),
                Scene.from_box(x, y, h, 2, 1),
                Scene(circles=[(0.5 * step, 6, 0.5), (-4 + step, 4, 0.3)]),
            ]
        )
        np.testing.assert_allclose(scan(scene), scan(fresh), rtol=0, atol=1e-12)
    assert scene._z is buffers[0] and scene._radii is buffers[1]
    with pytest.raises(IndexError):
        scene.set_polygon(box_corners(0, 0, 0, 1, 1), start=0)  # row 0 is not an edge
    with pytest.raises(IndexError):
        scene.set_circles([(0, 0, 1)], start=2)


def test_out_parameter_and_negative_increment():
    scene = Scene.concat([Scene.from_box(3, 1, 0.2, 1, 2), Scene(circles=[(-2, 4, 1)])])
    out = np.full(N, -1.0)
    assert cast_scan(scene, (0, 0), 0.3, *HOKUYO, out=out) is out
    np.testing.assert_array_equal(out, scan(scene, (0, 0), 0.3))
    # the same beams listed the other way round
    reverse = cast_scan(scene, (0, 0), 0.3, -AMIN, -INC, N, RMAX)
    np.testing.assert_allclose(reverse[::-1], out, rtol=0, atol=1e-12)
    with pytest.raises(ValueError):
        cast_scan(scene, (0, 0), 0.0, *HOKUYO, out=np.empty(N - 1))
    with pytest.raises(ValueError):
        cast_scan(scene, (0, 0), 0.0, AMIN, 0.0, N, RMAX)


def test_empty_scene_and_no_beams():
    assert np.all(scan(Scene()) == RMAX)
    assert cast_scan(Scene(circles=[(1, 0, 0.5)]), (0, 0), 0, AMIN, INC, 0, RMAX).shape == (0,)
    dist, owner = cast_rays(Scene(), (0, 0), [0.0, 1.0], 10.0)
    assert np.all(np.isinf(dist)) and np.all(owner == -1)


def test_cast_rays_owner_and_max_dist():
    scene = Scene.concat(
        [
            Scene.from_box(5, 0, 0, 2, 2, owner=3),
            Scene(circles=[(0, 5, 1)], circle_owner=[4]),
            Scene([(-5, -5, -5, 5)], segment_owner=[5]),
        ]
    )
    angles = [0.0, math.pi / 2, math.pi, -math.pi, 3 * math.pi, -math.pi / 2, 0.0]
    limits = [10.0, 10.0, 10.0, 10.0, 4.0, 10.0, 3.9]
    dist, owner = cast_rays(scene, (0.0, 0.0), angles, limits)
    np.testing.assert_allclose(dist, [4, 4, 5, 5, np.inf, np.inf, np.inf], rtol=0, atol=EXACT)
    np.testing.assert_array_equal(owner, [3, 4, 5, 5, -1, -1, -1])
    dist, owner = cast_rays(scene, (0.0, 0.0), np.zeros((2, 3)), 4.0)  # at max_dist: a hit
    assert dist.shape == owner.shape == (2, 3)
    assert np.all(dist == 4.0) and np.all(owner == 3)


# -- properties: brute force -------------------------------------------------------------------
coord = st.floats(-15, 15, allow_nan=False)
segments = st.lists(st.tuples(coord, coord, coord, coord), max_size=6)
circles = st.lists(st.tuples(coord, coord, st.floats(0.05, 4.0)), max_size=6)
boxes = st.lists(
    st.tuples(coord, coord, st.floats(-4, 4), st.floats(0.05, 6.0), st.floats(0.05, 6.0)),
    max_size=4,
)
origins = st.tuples(st.floats(-6, 6), st.floats(-6, 6))
headings = st.floats(-7, 7)
scanners = st.sampled_from(
    [
        HOKUYO,
        (-math.pi, 2 * math.pi / 720, 720, 20.0),  # full circle
        (-0.5, 0.01, 101, 40.0),  # narrow
        (3 * math.pi / 4, -INC, N, RMAX),  # clockwise
    ]
)


@st.composite
def scenes(draw):
    segs, circs, bxs = draw(segments), draw(circles), draw(boxes)
    parts = [
        Scene(
            segs,
            circs,
            segment_owner=np.arange(len(segs)),
            circle_owner=100 + np.arange(len(circs)),
        )
    ]
    parts += [Scene.from_box(*b, owner=200 + i) for i, b in enumerate(bxs)]
    return Scene.concat(parts)


@settings(max_examples=300, deadline=None)
@given(scenes(), origins, headings, scanners)
def test_cast_scan_equals_brute_force(scene, origin, heading, scanner):
    amin, inc, n, rmax = scanner
    got = cast_scan(scene, origin, heading, amin, inc, n, rmax)
    angles = heading + amin + inc * np.arange(n)
    _, _, best, tol, border = brute_force(scene, origin, angles)
    expected = np.minimum(best, rmax)
    ok = np.abs(got - expected) <= tol
    assert np.all(ok | border), (np.flatnonzero(~ok), got[~ok], expected[~ok])


@settings(max_examples=300, deadline=None)
@given(
    scenes(),
    origins,
    st.lists(st.floats(-10, 10), min_size=1, max_size=300),
    st.one_of(st.floats(0, 40), st.just(math.inf)),
    st.booleans(),
)
def test_cast_rays_equals_brute_force(scene, origin, angles, limit, per_ray):
    angles = np.array(angles)
    limits = np.where(np.arange(len(angles)) % 3, limit, 0.4 * limit) if per_ray else limit
    dist, owner = cast_rays(scene, origin, angles, limits)
    t, owners, best, tol, border = brute_force(scene, origin, angles)
    limits = np.broadcast_to(limits, angles.shape)
    expected = np.where(best <= limits, best, np.inf)
    both_inf = np.isinf(dist) & np.isinf(expected)
    with np.errstate(invalid="ignore"):
        border |= np.abs(best - limits) <= tol  # hit or miss at exactly max_dist
        ok = both_inf | (np.abs(dist - expected) <= tol)
    assert np.all(ok | border), (np.flatnonzero(~ok), dist[~ok], expected[~ok])
    for i in np.flatnonzero(~border):
        if np.isinf(expected[i]):
            assert owner[i] == -1
        else:  # any shape hit at the same distance may be reported
            assert owner[i] in owners[t[i] <= best[i] + tol[i]]
