"""Aircraft registration (behaviours.laws.registration): seed Algorithms 2.2 and 2.3.

Unit tests cast synthetic scans with sim2d's ray caster against the footprint placed in
an arbitrary airport frame, so that the expected pose comes from
``AircraftPlacement.pose_to_aircraft`` and not from the module's own frame code. The
acceptance tests run sim2d scenarios of the shipped A320 and B737-800 missions: parking
offsets up to 1.5 m and 10 deg, people and a vehicle by the gear, the prior taken
through the *nominal* parking pose, the truth through the scenario's true one.
"""

import math
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from shapely.geometry import Point

from behaviours.laws.registration import (
    FootprintModel,
    IcpSettings,
    LandmarkKind,
    Registration,
    RegistrationMethod,
    SightLines,
    extract_features,
    placement_covariance,
    placement_from_registration,
    points_from_scans,
    refine,
    register,
)
from executive.core.frames import AircraftPlacement, Pose2, wrap_angle
from executive.core.geometry import to_shapely
from executive.core.loader import load_mission
from executive.core.model import Aircraft, Circle
from sim2d.raycast import Scene
from sim2d.robot import SimRobot
from sim2d.sensors import LaserSensor
from tests.conftest import SHIPPED_MISSIONS
from tests.sim2d_helpers import heading_error, make_scenario, position_error, start

PLACEMENT = AircraftPlacement(12.0, -7.0, math.radians(70.0), 3.0)
"""Where the synthetic scans put the aircraft (any placement will do)."""

POSITION_TOL = 0.05
HEADING_TOL = math.radians(0.5)


@pytest.fixture(scope="module")
def a320():
    return load_mission(SHIPPED_MISSIONS["a320"])


@pytest.fixture(scope="module")
def b737():
    return load_mission(SHIPPED_MISSIONS["b737-800"])


@pytest.fixture(scope="module")
def models(a320, b737):
    return {
        "a320": FootprintModel.from_aircraft(a320.aircraft),
        "b737-800": FootprintModel.from_aircraft(b737.aircraft),
    }


def box_f(x, y, heading_deg, length, width):
    """Corners in F of a length x width box centred at (x, y)."""
    h = math.radians(heading_deg)
    u, v = np.array([math.cos(h), math.sin(h)]), np.array([-math.sin(h), math.cos(h)])
    return np.array(
        [
            (x, y) + sx * length / 2 * u + sy * width / 2 * v
            for sx, sy in ((1, 1), (-1, 1), (-1, -1), (1, -1))
        ]
    )


def cast(mission, pose_f, *, keep=None, people=(), boxes=(), sigma=0.0, seed=0):
    """Returns in R of both lasers of a robot at ``pose_f`` that sees the footprint (only
    the elements in ``keep`` when given), people (x, y) and boxes (x, y, heading_deg,
    length, width) given in F, with Gaussian range noise ``sigma``; and the sight lines."""
    parts = []
    for shape in mission.aircraft.footprint:
        if keep is not None and shape.id not in keep:
            continue
        if isinstance(shape, Circle):
            cx, cy = PLACEMENT.to_airport_xy((shape.cx, shape.cy))
            parts.append(Scene(circles=[(cx, cy, shape.radius)]))
        else:
            parts.append(Scene.from_polygon(PLACEMENT.to_airport_xy(np.array(shape.points))))
    for x, y in people:
        cx, cy = PLACEMENT.to_airport_xy((x, y))
        parts.append(Scene(circles=[(cx, cy, 0.3)]))
    for box in boxes:
        parts.append(Scene.from_polygon(PLACEMENT.to_airport_xy(box_f(*box))))
    scene = Scene.concat(parts)
    pose_a = PLACEMENT.pose_to_airport(pose_f)
    rng = np.random.default_rng(seed)
    lasers = mission.platform.lasers
    scans = {
        lid: LaserSensor(spec, sigma, rng).scan(scene, pose_a, 0.0) for lid, spec in lasers.items()
    }
    return points_from_scans(scans, lasers), SightLines.from_scans(scans, lasers)


def offset_prior(pose_f, dx=1.2, dy=-0.9, dtheta_deg=10.0):
    return Pose2(pose_f.x + dx, pose_f.y + dy, wrap_angle(pose_f.theta + math.radians(dtheta_deg)))


def assert_close(reg, truth_f, pos_tol=POSITION_TOL, heading_tol=HEADING_TOL):
    assert reg is not None
    assert position_error(reg.pose_f, truth_f) < pos_tol, (reg.pose_f, truth_f)
    assert heading_error(reg.pose_f, truth_f) < heading_tol, (reg.pose_f, truth_f)


# -- the model ------------------------------------------------------------------------------------
def test_model_samples_lie_on_the_outline_with_outward_normals(a320, models):
    model = models["a320"]
    shapes = [to_shapely(s) for s in a320.aircraft.footprint]
    samples_f = model.samples * (1.0, -1.0)
    normals_f = model.normals * (1.0, -1.0)
    for k, (element, shape) in enumerate(zip(a320.aircraft.footprint, shapes, strict=True)):
        mine = model.sample_element == k
        assert mine.any()
        for p, n in zip(samples_f[mine], normals_f[mine], strict=True):
            if isinstance(element, Circle):
                on = abs(math.hypot(p[0] - element.cx, p[1] - element.cy) - element.radius)
            else:
                on = shape.exterior.distance(Point(p))
            assert on < 1e-9
            assert not shape.contains(Point(p + 0.02 * n))
            assert shape.contains(Point(p - 0.02 * n))
    gaps = np.hypot(*np.diff(model.samples, axis=0).T)
    assert np.median(gaps) <= 0.05 + 1e-9


def test_distance_field_agrees_with_the_outline(a320, models):
    model = models["a320"]
    outline = to_shapely(a320.aircraft.footprint[0]).exterior
    for shape in a320.aircraft.footprint[1:]:
        outline = outline.union(to_shapely(shape).exterior)
    rng = np.random.default_rng(3)
    pts_f = np.column_stack((rng.uniform(3, 20, 400), rng.uniform(-8, 8, 400)))
    dist, nearest = model.lookup(pts_f * (1.0, -1.0))
    exact = np.array([outline.distance(Point(p)) for p in pts_f])
    near = exact < model.margin - model.resolution
    # a cell's value is the distance from its centre: off by at most half its diagonal
    assert np.all(np.abs(dist[near] - exact[near]) <= model.resolution * 0.71 + 0.01)
    assert np.all(nearest[near] >= 0)
    assert np.all(dist[exact > model.margin + model.resolution] == model.margin)


def test_landmarks_describe_each_element(a320, models):
    model = models["a320"]
    assert model.elements == tuple(s.id for s in a320.aircraft.footprint)
    nose = model.landmarks[model.elements.index("nose-gear")]
    assert nose.kind is LandmarkKind.CIRCLE
    assert nose.centre == (5.07, 0.0)
    assert nose.size == 0.6
    gear = model.landmarks[model.elements.index("main-gear-left")]
    assert gear.kind is LandmarkKind.POLYGON
    assert gear.centre == pytest.approx((17.71, 3.80))
    assert gear.size == pytest.approx(math.hypot(0.6, 0.7))
    assert model.landmark_centres().shape == (len(model.elements), 2)


def test_model_needs_a_footprint(a320):
    bare = Aircraft(
        "none", 1.0, a320.aircraft.dimensions, (), (), features={}, items={}, description=""
    )
    with pytest.raises(ValueError, match="no footprint"):
        FootprintModel.from_aircraft(bare)


def test_scan_characteristics_are_lines_and_model_sized_arcs(a320, models):
    """Behind the main gear: the left leg's corner gives two perpendicular lines; the nose
    gear's arc is recognised; a person (r 0.3) is no gear leg."""
    pose = Pose2(21.0, 1.5, math.radians(180.0))
    points, _ = cast(a320, pose, people=[(19.5, -0.5)])
    feats = extract_features(models["a320"], points)
    assert feats.n_lines >= 2
    assert len(feats.circles) == 1
    nose_r = robot_point(pose, (5.07, 0.0))
    assert np.hypot(*(feats.circles[0, :2] - nose_r)) < 0.05
    assert abs(feats.circles[0, 2] - 0.6) < 0.03
    # normals face the robot: a line's centre is on the far side of its normal
    assert np.all(np.einsum("ij,ij->i", feats.line_normal, feats.line_centre) < 0.0)


def robot_point(pose_f, p_f):
    """A point of F in R, through the placement (independent of the module)."""
    pose_a = PLACEMENT.pose_to_airport(pose_f)
    return pose_a.inverse().apply(PLACEMENT.to_airport_xy(p_f))


def test_sight_lines_end_at_the_returns_or_at_full_range(a320):
    pose = Pose2(9.0, 5.5, math.radians(10.0))
    points, lines = cast(a320, pose)
    assert len(lines.ends) == sum(spec.beam_count for spec in a320.platform.lasers.values())
    reach = np.hypot(*(lines.ends - lines.origins).T)
    returned = reach < 30.0 - 1e-6
    assert np.allclose(np.sort(lines.ends[returned], axis=0), np.sort(points, axis=0))
    assert np.allclose(reach[~returned], 30.0)
    mounts = {tuple(spec.mount[:2]) for spec in a320.platform.lasers.values()}
    assert {tuple(o) for o in lines.origins} == mounts


# -- global registration and ICP on synthetic scans -----------------------------------------------
A320_POSES = [
    Pose2(3.0, 2.5, math.radians(-30.0)),  # by the nose gear
    Pose2(20.0, 7.0, math.radians(200.0)),  # behind and outside the left main gear
    Pose2(16.0, -3.5, math.radians(95.0)),  # between the right gear and engine
    Pose2(9.0, 5.5, math.radians(10.0)),  # ahead of the left engine
    Pose2(24.0, -1.0, math.radians(170.0)),  # behind the main gear
]


SIGMA_THETA = math.radians(5.0)


def register_synthetic(
    model, cast_result, prior, sigma_xy=1.0, sigma_theta=SIGMA_THETA, *, free_space=True
):
    """``free_space=False`` when elements were left out of the scene (not hidden behind
    something): the beams pass where they stand, which the free-space test objects to."""
    points, lines = cast_result
    return register(
        model,
        points,
        prior,
        prior_sigma_xy=sigma_xy,
        prior_sigma_theta=sigma_theta,
        sight_lines=lines if free_space else None,
    )


@pytest.mark.parametrize("pose", A320_POSES)
def test_register_recovers_a_noise_free_pose_exactly(a320, models, pose):
    reg = register_synthetic(models["a320"], cast(a320, pose), offset_prior(pose))
    assert_close(reg, pose, 0.002, math.radians(0.02))
    assert reg.method is RegistrationMethod.GLOBAL
    assert reg.well_conditioned
    assert reg.hypotheses >= 1
    assert reg.rms < 0.005
    assert reg.inlier_fraction > 0.95
    assert reg.contradictions == 0


def test_register_with_range_noise_and_obstacles_by_the_gear(a320, models):
    pose = Pose2(20.0, 6.5, math.radians(200.0))
    people = [(19.0, 5.2), (16.5, 4.0), (18.8, 2.6), (13.0, 7.5)]
    truck = (22.5, 2.5, 20.0, 6.0, 2.4)
    scan = cast(a320, pose, people=people, boxes=[truck], sigma=0.01, seed=4)
    reg = register_synthetic(models["a320"], scan, offset_prior(pose, -1.5, 0.3, -10.0))
    assert_close(reg, pose, 0.02, math.radians(0.2))
    clean, _ = cast(a320, pose, sigma=0.01, seed=4)
    assert reg.n_points > len(clean) * 0.9  # the obstacles took part...
    assert reg.n_inliers < len(scan[0]) - 50  # ...and were rejected
    assert {"main-gear-left", "nacelle-engine-1"} <= set(reg.elements)


def test_register_uses_a_gear_leg_and_a_nacelle_alone(a320, models):
    """Only part of the aircraft in view: one main gear leg and the nacelle beside it."""
    pose = Pose2(17.5, 9.5, math.radians(-100.0))
    scan = cast(a320, pose, keep={"main-gear-left", "nacelle-engine-1"}, sigma=0.01)
    reg = register_synthetic(models["a320"], scan, offset_prior(pose), free_space=False)
    assert_close(reg, pose, 0.03, math.radians(0.3))
    assert set(reg.elements) == {"main-gear-left", "nacelle-engine-1"}


@pytest.mark.parametrize(
    ("pose", "keep", "observable"),
    [
        # one circle: the rotation about it is unobservable
        (Pose2(3.0, 2.0, 0.0), {"nose-gear"}, False),
        # one face of a leg, or two parallel faces: the position along them is
        (Pose2(17.7, 8.0, math.radians(-90.0)), {"main-gear-left"}, False),
        (Pose2(17.71, 0.0, math.radians(90.0)), {"main-gear-left", "main-gear-right"}, False),
        # one rectangle: observable, but too easily a vehicle of its size
        (Pose2(10.0, 8.5, math.radians(-90.0)), {"nacelle-engine-1"}, True),
        (Pose2(12.0, 0.0, 0.0), set(), False),  # nothing of the aircraft
    ],
    ids=["nose-gear-only", "one-face", "parallel-faces", "one-element", "no-aircraft"],
)
def test_register_returns_none_on_insufficient_evidence(a320, models, pose, keep, observable):
    people = [(pose.x + 2.0, pose.y + 1.0), (pose.x - 1.5, pose.y - 2.0)]
    truck = (pose.x + 6.0, pose.y - 3.0, 30.0, 8.0, 2.5)
    scan = cast(a320, pose, keep=keep, people=people, boxes=[truck], sigma=0.01)
    assert len(scan[0]) > 100
    model = models["a320"]
    prior = offset_prior(pose, 0.5, 0.5, 3.0)
    assert register_synthetic(model, scan, prior, free_space=False) is None
    if keep:  # what ICP makes of it, from the truth
        tracked = refine(model, scan[0], pose)
        assert tracked.well_conditioned == observable
    if keep and not observable:  # it says that it cannot tell
        tracked = refine(model, scan[0], pose)
        assert not tracked.well_conditioned
        assert tracked.conditioning < 1.0
        assert math.sqrt(np.max(np.linalg.eigvalsh(tracked.covariance))) > 0.05


def test_register_refuses_a_decoy_that_the_beams_pass_through(a320, models):
    """Two boxes the size and layout of the nacelles, and no aircraft: they fit the
    model's nacelles perfectly, but that aircraft's gear legs would stand where the
    beams pass freely. Without the sight lines the decoy is taken for the aircraft."""
    shift = (2.5, 1.0)
    decoys = [(13.3 + shift[0], 5.75 * side + shift[1], 0.0, 4.2, 2.2) for side in (1, -1)]
    pose = Pose2(6.5, -4.0, math.radians(-30.0))
    points, lines = cast(a320, pose, keep=set(), boxes=decoys, sigma=0.01)
    model = models["a320"]
    fooled = register(model, points, pose, prior_sigma_xy=1.0, prior_sigma_theta=0.05)
    assert fooled is not None
    assert fooled.pose_f.distance_to(Pose2(pose.x - shift[0], pose.y - shift[1], 0.0)) < 0.05
    assert fooled.contradictions == 0  # not tested without sight lines
    assert register_synthetic(model, (points, lines), pose, 1.0, 0.05) is None
    tracked = refine(model, points, fooled.pose_f, sight_lines=lines)
    assert tracked.contradictions > 0.5 * tracked.n_inliers


def test_register_rejects_empty_and_tiny_scans(models):
    model = models["a320"]
    prior = Pose2(10.0, 0.0, 0.0)
    assert register(model, np.zeros((0, 2)), prior, prior_sigma_xy=1, prior_sigma_theta=1) is None
    assert register(model, np.ones((5, 2)), prior, prior_sigma_xy=1, prior_sigma_theta=1) is None
    with pytest.raises(ValueError, match="positive"):
        register(model, np.ones((50, 2)), prior, prior_sigma_xy=0.0, prior_sigma_theta=1.0)


def test_register_does_not_search_beyond_the_prior_gate(a320, models):
    pose = Pose2(20.0, 7.0, math.radians(200.0))
    scan = cast(a320, pose, sigma=0.01)
    prior = offset_prior(pose, 0.0, 0.0, 20.0)  # 20 deg off, gate 3 x 3 deg
    assert register_synthetic(models["a320"], scan, prior, 1.0, math.radians(3.0)) is None


def test_refine_tracks_from_a_nearby_pose(a320, models):
    pose = Pose2(9.0, 5.5, math.radians(10.0))
    points, lines = cast(a320, pose, people=[(10.0, 3.8)], sigma=0.01, seed=2)
    start_pose = Pose2(pose.x + 0.2, pose.y - 0.15, pose.theta + math.radians(2.0))
    reg = refine(models["a320"], points, start_pose, sight_lines=lines)
    assert_close(reg, pose, 0.02, math.radians(0.2))
    assert reg.method is RegistrationMethod.ICP
    assert reg.hypotheses == 0
    assert reg.contradictions == 0
    assert reg.well_conditioned
    assert 1 < reg.iterations < IcpSettings().max_iterations
    assert 0.005 < reg.rms < 0.02  # the range noise is 1 cm
    # shuffled returns: ICP does not need the beam order
    order = np.random.default_rng(0).permutation(len(points))
    again = refine(models["a320"], points[order], start_pose)
    assert position_error(again.pose_f, reg.pose_f) < 1e-6


def test_covariance_is_in_the_aircraft_frame_and_consistent(a320, models):
    """Monte Carlo over the range noise: the errors (x_F, y_F, h) fall within the
    reported covariance, and its strongest correlations have the sign of the errors'."""
    model = models["a320"]
    pose = Pose2(17.5, 9.5, math.radians(-100.0))  # gear + nacelle only: correlated
    keep = {"main-gear-left", "nacelle-engine-1"}
    errors, covs = [], []
    for seed in range(25):
        points, _ = cast(a320, pose, keep=keep, sigma=0.01, seed=seed)
        reg = refine(model, points, pose)
        errors.append(
            (
                reg.pose_f.x - pose.x,
                reg.pose_f.y - pose.y,
                wrap_angle(reg.pose_f.theta - pose.theta),
            )
        )
        covs.append(reg.covariance)
    errors, cov = np.array(errors), np.mean(covs, axis=0)
    assert np.allclose(cov, cov.T) and np.all(np.linalg.eigvalsh(cov) > 0)
    nees = np.einsum("ij,jk,ik->i", errors, np.linalg.inv(cov), errors)
    # 3 would be exactly right; the covariance is inflated for correlated errors that
    # sim2d's white noise does not have, so it is conservative, but not absurdly so
    assert 0.1 < np.mean(nees) < 3.0
    empirical = np.cov(errors.T)
    rho = cov / np.sqrt(np.outer(np.diag(cov), np.diag(cov)))
    rho_emp = empirical / np.sqrt(np.outer(np.diag(empirical), np.diag(empirical)))
    strong = np.abs(rho) > 0.5
    np.fill_diagonal(strong, False)
    assert strong.any()
    assert np.all(np.sign(rho[strong]) == np.sign(rho_emp[strong]))


# -- airport <- aircraft ------------------------------------------------------------------------
def fake_registration(pose_f, covariance=None):
    return Registration(
        pose_f=pose_f,
        covariance=np.eye(3) * 1e-4 if covariance is None else covariance,
        rms=0.01,
        inlier_fraction=1.0,
        n_inliers=100,
        n_points=100,
        iterations=1,
        method=RegistrationMethod.ICP,
        conditioning=100.0,
        well_conditioned=True,
    )


coord = st.floats(-200, 200, allow_nan=False)
angle = st.floats(-math.pi, math.pi, allow_nan=False, exclude_max=True)


@given(coord, coord, angle, coord, coord, angle)
def test_placement_from_registration_round_trips(px, py, ph, ax, ay, ah):
    placement = AircraftPlacement(px, py, ph, 2.5)
    pose_a = Pose2(ax, ay, ah)
    pose_f = placement.pose_to_aircraft(pose_a)
    found = placement_from_registration(pose_a, fake_registration(pose_f), 2.5)
    assert found.x == pytest.approx(px, abs=1e-7)
    assert found.y == pytest.approx(py, abs=1e-7)
    assert abs(wrap_angle(found.heading - ph)) < 1e-9
    assert found.origin_height == 2.5
    again = found.pose_to_aircraft(pose_a)
    assert again.distance_to(pose_f) < 1e-7
    assert abs(wrap_angle(again.theta - pose_f.theta)) < 1e-9


def test_placement_covariance_is_the_first_order_propagation():
    pose_a = Pose2(30.0, -12.0, 0.7)
    pose_f = Pose2(17.0, 6.0, -2.1)
    rng = np.random.default_rng(1)
    m_a, m_f = rng.normal(size=(3, 3)), rng.normal(size=(3, 3))
    cov_a, cov_f = m_a @ m_a.T * 1e-3, m_f @ m_f.T * 1e-3

    def params(xa, xf):
        p = placement_from_registration(Pose2(*xa), fake_registration(Pose2(*xf)), 0.0)
        return np.array([p.x, p.y, p.heading])

    xa = np.array([pose_a.x, pose_a.y, pose_a.theta])
    xf = np.array([pose_f.x, pose_f.y, pose_f.theta])
    eps = 1e-6
    j_a = np.column_stack(
        [(params(xa + eps * e, xf) - params(xa - eps * e, xf)) / (2 * eps) for e in np.eye(3)]
    )
    j_f = np.column_stack(
        [(params(xa, xf + eps * e) - params(xa, xf - eps * e)) / (2 * eps) for e in np.eye(3)]
    )
    expected = j_a @ cov_a @ j_a.T + j_f @ cov_f @ j_f.T
    got = placement_covariance(pose_a, cov_a, fake_registration(pose_f, cov_f))
    assert np.allclose(got, expected, atol=1e-9)


# -- sim2d ground truth (the acceptance) -----------------------------------------------------------
PRIOR_NOISE = Pose2(0.2, -0.15, math.radians(1.0))
"""Added to the robot's true pose in A for the prior (as from a pose filter)."""

PARKING_SIGMA = (0.6, math.radians(4.0))
"""1-sigma of the parking pose about the nose: the prior's sigma grows with the distance."""

SPOTS = {
    # robot positions in F (metres) and headings (deg): by the nose gear, beside a main
    # gear, between the gear and the engine, behind the gear
    "a320": [(3.2, -2.2, 20.0), (19.5, 7.5, 215.0), (16.0, 3.4, 300.0), (24.0, -2.0, 160.0)],
    "b737-800": [(3.0, 2.2, -30.0), (19.7, -5.6, 120.0), (18.0, 4.6, 200.0), (23.5, 4.0, 170.0)],
}
OFFSETS = [(1.5, 0.0, 10.0), (-1.0, -1.1, -10.0), (0.3, 1.45, -6.0), (-1.5, 0.3, 8.0)]


def gear_obstacles(mission_type, placement, robot_f):
    """People (r 0.3) and a vehicle near the gear, in A; those too close to the robot's
    start are left out (the scenario loader refuses an overlap)."""
    if mission_type == "a320":
        people = [(6.3, 1.2), (4.0, -1.2), (16.4, 5.3), (19.2, 2.6), (18.9, -5.2), (16.2, -2.4)]
        vehicle = (22.0, 5.5, 15.0, 6.0, 2.4)
    else:
        people = [(5.3, 1.1), (3.0, -1.3), (18.3, 2.4), (21.2, 4.4), (21.0, -3.8), (18.2, -4.6)]
        vehicle = (24.5, -5.5, -10.0, 6.0, 2.4)
    body = []
    for k, (x, y) in enumerate(people):
        if math.hypot(x - robot_f[0], y - robot_f[1]) > 1.5:
            ax, ay = placement.to_airport_xy((x, y))
            body.append(
                f'<circle id="person-{k}" kind="person" x="{ax:.4f}" y="{ay:.4f}" radius="0.3"'
                ' height="1.8"/>'
            )
    vx, vy, vh, length, width = vehicle
    if math.hypot(vx - robot_f[0], vy - robot_f[1]) > 4.5:
        ax, ay = placement.to_airport_xy((vx, vy))
        heading = math.degrees(placement.x_axis_heading - math.radians(vh))
        body.append(
            f'<box id="truck" kind="vehicle" x="{ax:.4f}" y="{ay:.4f}" heading-deg="{heading:.3f}"'
            f' length="{length}" width="{width}" height="2.5"/>'
        )
    # a walker by the gear, at its first waypoint when the scans are taken
    gx, gy = people[2]
    w0, w1 = placement.to_airport_xy((gx + 1.5, gy + 1.5)), placement.to_airport_xy((gx, gy + 4))
    if math.hypot(gx + 1.5 - robot_f[0], gy + 1.5 - robot_f[1]) > 1.5:
        body.append(
            '<path id="walker" kind="person" radius="0.3" height="1.8" speed="1.2">'
            f'<waypoint x="{w0[0]:.4f}" y="{w0[1]:.4f}"/>'
            f'<waypoint x="{w1[0]:.4f}" y="{w1[1]:.4f}"/></path>'
        )
    return "<obstacles>" + "".join(body) + "</obstacles>"


def sim_registration(tmp_path, mission, model, mission_type, offset, spot, seed=1):
    """Build the scenario, read one frame, register: (registration, true robot pose in F,
    true robot pose in A)."""
    dx, dy, dh = offset
    nominal = mission.nominal_placement()
    placement = AircraftPlacement(
        nominal.x + dx, nominal.y + dy, nominal.heading + math.radians(dh), nominal.origin_height
    )
    x, y, h = spot
    pose_a = placement.pose_to_airport(Pose2(x, y, math.radians(h)))
    body = (
        f'<parking-offset dx="{dx}" dy="{dy}" dheading-deg="{dh}"/>'
        + start(round(pose_a.x, 4), round(pose_a.y, 4), round(math.degrees(pose_a.theta), 4))
        + gear_obstacles(mission_type, placement, spot)
    )
    scenario = make_scenario(tmp_path, body, mission_type=mission_type, seed=seed)
    true_placement = scenario.true_placement()
    assert true_placement.to_airport_xy((x, y)) == pytest.approx(placement.to_airport_xy((x, y)))
    robot = SimRobot(scenario)
    scans, lasers = robot.read().scans, scenario.mission.platform.lasers
    points = points_from_scans(scans, lasers)
    truth_a = robot.truth.robot
    believed_a = truth_a @ PRIOR_NOISE
    prior = scenario.mission.nominal_placement().pose_to_aircraft(believed_a)
    sigma_xy = PARKING_SIGMA[0] + math.hypot(prior.x, prior.y) * PARKING_SIGMA[1]
    reg = register(
        model,
        points,
        prior,
        prior_sigma_xy=sigma_xy,
        prior_sigma_theta=PARKING_SIGMA[1],
        sight_lines=SightLines.from_scans(scans, lasers),
    )
    return reg, true_placement.pose_to_aircraft(truth_a), truth_a


@pytest.mark.parametrize("offset", OFFSETS, ids=lambda o: f"off{o[0]:+}{o[1]:+}{o[2]:+}")
@pytest.mark.parametrize("mission_type", ["a320", "b737-800"])
def test_sim2d_registration_within_5cm_and_half_a_degree(
    tmp_path, a320, b737, models, mission_type, offset
):
    mission = a320 if mission_type == "a320" else b737
    for k, spot in enumerate(SPOTS[mission_type]):
        reg, truth_f, truth_a = sim_registration(
            tmp_path / str(k), mission, models[mission_type], mission_type, offset, spot
        )
        assert_close(reg, truth_f)
        assert reg.well_conditioned
        assert reg.n_points - reg.n_inliers > 30  # the people and the vehicle were seen
        # the airport <- aircraft transform it implies is the scenario's true one
        placement = placement_from_registration(truth_a, reg, mission.aircraft.origin_height)
        nominal = mission.nominal_placement()
        assert placement.heading == pytest.approx(
            nominal.heading + math.radians(offset[2]), abs=HEADING_TOL
        )
        nose = placement.to_airport_xy((0.0, 0.0))
        assert math.hypot(nose[0] - nominal.x - offset[0], nose[1] - nominal.y - offset[1]) < (
            POSITION_TOL + math.hypot(*spot[:2]) * HEADING_TOL
        )


@settings(max_examples=15, deadline=None)
@given(
    st.floats(-1.5, 1.5),
    st.floats(-1.5, 1.5),
    st.floats(-10.0, 10.0),
    st.integers(0, len(SPOTS["a320"]) - 1),
    st.integers(0, 1000),
)
def test_sim2d_registration_property(a320, models, dx, dy, dh, spot, seed):
    scale = min(1.0, 1.5 / max(math.hypot(dx, dy), 1e-9))
    offset = (round(dx * scale, 3), round(dy * scale, 3), round(dh, 3))
    with tempfile.TemporaryDirectory() as tmp:
        reg, truth_f, _ = sim_registration(
            Path(tmp), a320, models["a320"], "a320", offset, SPOTS["a320"][spot], seed
        )
    assert_close(reg, truth_f)
