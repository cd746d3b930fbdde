"""sim2d.cameras: pan-tilt units, camera rigs, the feature cloud and the pinhole detector.

Expected pixels are worked out by hand from docs/mission-format.md (robot x forward,
y left, z up; camera x right, y down, z optical axis; pan positive left, tilt positive up),
not with the module's own transforms.
"""

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from executive.core.frames import (
    AircraftPlacement,
    Pose2,
    robot_from_camera,
    rot_z,
    wrap_angle,
)
from executive.core.loader import load_mission
from executive.core.model import (
    Aircraft,
    CameraKind,
    Dimensions,
    Feature,
    Point3,
    ServoMethod,
)
from executive.core.records import CameraFrame, PanTilt
from sim2d.cameras import (
    CameraRig,
    FeatureCloud,
    PanTiltUnit,
    airport_from_camera,
    camera_rigs,
    detect,
)

# -- fixtures and helpers ------------------------------------------------------------------


@pytest.fixture(scope="module")
def a320(a320_path):
    return load_mission(a320_path)


@pytest.fixture(scope="module")
def rigs(a320):
    return {rig.id: rig for rig in camera_rigs(a320.platform.cameras)}


@pytest.fixture(scope="module")
def mono(a320):
    """The shipped front camera as a mono camera on a unit at (0, 0, 1.2), facing forward."""
    spec = dataclasses.replace(
        a320.platform.cameras["front"],
        id="cam",
        kind=CameraKind.MONO,
        baseline=None,
        mount=(0.0, 0.0, 1.2),
    )
    (rig,) = camera_rigs({"cam": spec})
    return rig


# A placement under which A and F differ only by mirroring y and z: x_F = x_A,
# y_F = -y_A, z_F = -z_A (nose pointing west, so +x_F points east).
MIRROR = AircraftPlacement(0.0, 0.0, math.pi, 0.0)
ORIGIN = Pose2(0.0, 0.0, 0.0)


def make_aircraft(features):
    return Aircraft(
        type="test",
        origin_height=1.0,
        dimensions=Dimensions(10.0, 10.0, 3.0, 2.0),
        footprint=(),
        outline=(),
        features={f.id: f for f in features},
        items={},
    )


def feature(fid, points_f, *, detection_range=100.0, normal_f=None):
    return Feature(
        id=fid,
        kind="target",
        points=tuple(Point3(*map(float, p)) for p in points_f),
        detection_range=detection_range,
        servo=ServoMethod.IBVS,
        normal=None if normal_f is None else Point3(*map(float, normal_f)),
    )


def cloud_of(points_a, *, detection_range=100.0, normal_a=None, fid="f"):
    """One feature whose points (and normal) are given in A, placed with MIRROR."""
    flip = np.array([1.0, -1.0, -1.0])
    pts_f = [np.asarray(p, dtype=float) * flip for p in points_a]
    normal_f = None if normal_a is None else np.asarray(normal_a, dtype=float) * flip
    ac = make_aircraft([feature(fid, pts_f, detection_range=detection_range, normal_f=normal_f)])
    return FeatureCloud.from_aircraft(ac, MIRROR)


def shoot(
    rig,
    cloud,
    pose=ORIGIN,
    pan=0.0,
    tilt=0.0,
    *,
    rng=None,
    noise=0.0,
    dropout=0.0,
    occluded=None,
    stamp=0.0,
):
    return detect(
        rig, pan, tilt, pose, cloud,
        rng=rng if rng is not None else np.random.default_rng(0),
        pixel_noise=noise, dropout=dropout, occluded=occluded, stamp=stamp,
    )  # fmt: skip


def seen(frame):
    return {(d.feature, d.point): (d.u, d.v) for d in frame.detections}


def centre(rig):
    return rig.spec.image_width_px / 2.0, rig.spec.image_height_px / 2.0


# -- pan-tilt unit -----------------------------------------------------------------------

rates = st.floats(-5.0, 5.0, allow_nan=False)
steps = st.lists(st.tuples(rates, rates, st.floats(0.0, 0.5)), min_size=1, max_size=40)


@given(steps)
def test_pan_tilt_stays_within_rate_and_angle_limits(a320, commands):
    spec = a320.platform.cameras["front"]
    unit = PanTiltUnit(spec)
    for pan_rate, tilt_rate, dt in commands:
        before = (unit.pan, unit.tilt)
        unit.command(pan_rate, tilt_rate)
        unit.step(dt)
        assert spec.pan_limits[0] <= unit.pan <= spec.pan_limits[1]
        assert spec.tilt_limits[0] <= unit.tilt <= spec.tilt_limits[1]
        assert abs(unit.pan - before[0]) <= spec.pan_rate * dt + 1e-12
        assert abs(unit.tilt - before[1]) <= spec.tilt_rate * dt + 1e-12
        # the commanded rate is followed exactly unless a rate or angle limit applies
        expected_pan = before[0] + max(-spec.pan_rate, min(spec.pan_rate, pan_rate)) * dt
        if spec.pan_limits[0] <= expected_pan <= spec.pan_limits[1]:
            assert unit.pan == pytest.approx(expected_pan, abs=1e-12)


def test_pan_tilt_rate_limit_and_stop_at_angle_limit(a320):
    spec = a320.platform.cameras["front"]  # pan +-170 deg at 60 deg/s, tilt -30..60 deg
    unit = PanTiltUnit(spec)
    assert (unit.pan, unit.tilt) == (0.0, 0.0)
    unit.command(10.0, -10.0)  # far above the rate limit
    assert unit.commanded == (10.0, -10.0)
    unit.step(0.1)
    assert unit.pan == pytest.approx(math.radians(6.0))
    assert unit.tilt == pytest.approx(math.radians(-6.0))
    for _ in range(100):  # pushing against the limits: stops there
        unit.step(0.1)
    assert unit.pan == spec.pan_limits[1]
    assert unit.tilt == spec.tilt_limits[0]
    unit.command(-math.radians(30.0), 0.0)  # back off at half the rate
    unit.step(1.0)
    assert unit.pan == pytest.approx(spec.pan_limits[1] - math.radians(30.0))
    assert unit.reading(12.5) == PanTilt(12.5, unit.pan, unit.tilt)


def test_pan_tilt_initial_angles_clamped_and_bad_input(a320):
    spec = dataclasses.replace(
        a320.platform.cameras["front"], tilt_limits=(0.2, 0.8), pan_limits=(-1.0, -0.5)
    )
    unit = PanTiltUnit(spec)
    assert (unit.pan, unit.tilt) == (-0.5, 0.2)
    assert unit.id == "front"
    with pytest.raises(ValueError):
        unit.command(math.nan, 0.0)
    with pytest.raises(ValueError):
        unit.step(-0.1)


# -- rigs ----------------------------------------------------------------------------------


def test_shipped_platform_has_five_cameras(a320):
    rigs = camera_rigs(a320.platform.cameras)
    assert [r.id for r in rigs] == ["front-left", "front-right", "rear-left", "rear-right", "ptz"]
    assert [r.unit for r in rigs] == ["front", "front", "rear", "rear", "ptz"]
    assert [r.lateral for r in rigs] == [0.15, -0.15, 0.15, -0.15, 0.0]
    assert all(r.spec is a320.platform.cameras[r.unit] for r in rigs)


def test_mono_rig_and_stereo_without_baseline(a320):
    spec = a320.platform.cameras["front"]
    mono_spec = dataclasses.replace(spec, kind=CameraKind.MONO, baseline=None)
    assert camera_rigs({"front": mono_spec}) == (CameraRig("front", "front", mono_spec, 0.0),)
    with pytest.raises(ValueError, match="baseline"):
        camera_rigs({"front": dataclasses.replace(spec, baseline=None)})


def test_camera_positions_on_the_robot(rigs):
    # front-left: mount (0.55, 0, 1.2) + 0.15 to the left; rear units face backwards, so
    # their left camera is on the robot's right
    expected = {
        "front-left": (0.55, 0.15, 1.2),
        "front-right": (0.55, -0.15, 1.2),
        "rear-left": (-0.55, -0.15, 1.2),
        "rear-right": (-0.55, 0.15, 1.2),
        "ptz": (0.0, 0.0, 1.6),
    }
    for rid, position in expected.items():
        t = airport_from_camera(rigs[rid], 0.0, 0.0, ORIGIN)
        assert t.translation == pytest.approx(position, abs=1e-12), rid
    # panned 90 deg left, the front unit's left camera moves behind the mount
    t = airport_from_camera(rigs["front-left"], math.pi / 2, 0.3, ORIGIN)
    assert t.translation == pytest.approx((0.55 - 0.15, 0.0, 1.2), abs=1e-12)


# -- feature cloud -------------------------------------------------------------------------


def test_feature_cloud_places_points_and_normals(a320):
    heading = math.radians(30.0)
    placement = AircraftPlacement(10.0, -5.0, heading, 3.5)
    ac = make_aircraft(
        [
            feature("b", [(2.0, 1.0, 0.5), (4.0, -1.0, 1.5)], normal_f=(0.0, 2.0, 0.0)),
            feature("a", [(1.0, 0.0, 3.5)], detection_range=7.0),
        ]
    )
    cloud = FeatureCloud.from_aircraft(ac, placement)
    assert cloud.feature_ids == ("a", "b")
    assert len(cloud) == 3
    assert cloud.feature_index.tolist() == [0, 1, 1]
    assert cloud.point_index.tolist() == [0, 0, 1]
    assert cloud.detection_range.tolist() == [7.0, 100.0, 100.0]
    # by hand: +x_F points along heading + 180 deg, +y_F (port) along heading + 90 deg,
    # height above ground = origin height - z_F
    tail = np.array([math.cos(heading + math.pi), math.sin(heading + math.pi), 0.0])
    port = np.array([math.cos(heading + math.pi / 2), math.sin(heading + math.pi / 2), 0.0])
    nose = np.array([10.0, -5.0, 0.0])
    up = np.array([0.0, 0.0, 1.0])
    for k, (x, y, z) in enumerate([(1.0, 0.0, 3.5), (2.0, 1.0, 0.5), (4.0, -1.0, 1.5)]):
        assert cloud.points[k] == pytest.approx(nose + x * tail + y * port + (3.5 - z) * up)
    assert np.isnan(cloud.normals[0]).all()
    assert cloud.normals[1] == pytest.approx(port)  # unit length, rotation only
    assert cloud.normals[2] == pytest.approx(port)
    with pytest.raises(ValueError):
        cloud.points[0, 0] = 1.0  # read-only


def test_a320_cloud_has_every_feature_point(a320):
    cloud = FeatureCloud.from_aircraft(a320.aircraft, a320.nominal_placement())
    total = sum(len(f.points) for f in a320.aircraft.features.values())
    assert len(cloud) == total
    assert cloud.points.shape == cloud.normals.shape == (total, 3)
    assert list(cloud.feature_ids) == sorted(a320.aircraft.features)
    assert (cloud.points[:, 2] > 0.0).all()  # all above the ground


# -- projection ----------------------------------------------------------------------------


def test_point_on_optical_axis_projects_to_image_centre(mono):
    frame = shoot(mono, cloud_of([(7.0, 0.0, 1.2)]), stamp=3.25)
    assert frame.stamp == 3.25
    ((u, v),) = seen(frame).values()
    assert (u, v) == pytest.approx(centre(mono), abs=1e-9)


def test_point_at_known_offset_projects_by_hand(mono):
    # camera at (0, 0, 1.2) looking along +x_A: X_C = -y_A, Y_C = -(z_A - 1.2), Z_C = x_A
    x_c, y_c, z_c = 0.4, -0.3, 5.0
    frame = shoot(mono, cloud_of([(z_c, -x_c, 1.2 - y_c)]))
    f = mono.spec.focal_length / mono.spec.pixel_size * 800 / 1384
    cx, cy = 400.0, 300.0
    ((u, v),) = seen(frame).values()
    assert u == pytest.approx(cx + f * x_c / z_c, abs=1e-9)
    assert v == pytest.approx(cy + f * y_c / z_c, abs=1e-9)
    assert v < cy  # above the optical axis: upper half of the image


def test_point_behind_camera_not_seen(mono):
    assert shoot(mono, cloud_of([(-5.0, 0.0, 1.2)])).detections == ()


@pytest.mark.parametrize("eps", [1e-6, -1e-6])
def test_field_of_view_edges(mono, eps):
    """Points just inside (eps > 0) / just outside (eps < 0) each edge of the image."""
    spec = mono.spec
    half_h = spec.horizontal_fov / 2
    half_v = math.atan((spec.image_height_px / 2) / spec.focal_px)
    d = 8.0
    inside = eps > 0
    angle_h = half_h - eps
    angle_v = half_v - eps
    # left edge (u = 0): +y_A; right edge (u = W): -y_A; top (v = 0): up; bottom: down
    points = [
        (d, d * math.tan(angle_h), 1.2),
        (d, -d * math.tan(angle_h), 1.2),
        (d, 0.0, 1.2 + d * math.tan(angle_v)),
        (d, 0.0, 1.2 - d * math.tan(angle_v)),
    ]
    for k, p in enumerate(points):
        frame = shoot(mono, cloud_of([p]))
        assert bool(frame.detections) is inside, (k, eps)
        if inside:
            (det,) = frame.detections
            assert 0.0 <= det.u < spec.image_width_px
            assert 0.0 <= det.v < spec.image_height_px


def test_horizontal_half_angle_matches_output_image(mono):
    spec = mono.spec
    assert spec.focal_px * math.tan(spec.horizontal_fov / 2) == pytest.approx(
        spec.image_width_px / 2
    )


def test_detection_range_is_3d_distance(mono):
    # 6 m range; point 1 m above the optical axis, so the 3D distance counts the height
    def at(dist):
        return (math.sqrt(dist**2 - 1.0), 0.0, 2.2)

    assert shoot(mono, cloud_of([at(5.999)], detection_range=6.0)).detections
    assert not shoot(mono, cloud_of([at(6.001)], detection_range=6.0)).detections


def test_facing(mono):
    p = (6.0, 0.0, 1.2)
    assert shoot(mono, cloud_of([p], normal_a=(-1.0, 0.0, 0.0))).detections  # towards us
    assert shoot(mono, cloud_of([p], normal_a=(-1.0, 3.0, 0.5))).detections  # obliquely
    assert not shoot(mono, cloud_of([p], normal_a=(1.0, 0.0, 0.0))).detections  # away
    assert not shoot(mono, cloud_of([p], normal_a=(0.0, 1.0, 0.0))).detections  # edge-on
    assert shoot(mono, cloud_of([p])).detections  # no normal: always facing


def test_occlusion_callback(mono):
    cloud = cloud_of([(6.0, 1.0, 1.2), (6.0, -1.0, 1.2), (6.0, 0.0, 1.2), (-6.0, 0.0, 1.2)])
    calls = []

    def left_blocked(camera, points):
        calls.append((camera.copy(), points.copy()))
        return points[:, 1] > 0.5

    frame = shoot(mono, cloud, occluded=left_blocked)
    assert sorted(seen(frame)) == [("f", 1), ("f", 2)]
    ((camera, points),) = calls
    assert camera == pytest.approx((0.0, 0.0, 1.2))
    # asked only about the points in view (not the one behind), in cloud order
    assert points == pytest.approx(np.array([(6.0, 1.0, 1.2), (6.0, -1.0, 1.2), (6, 0, 1.2)]))

    # nothing in view: the callback is not asked
    calls.clear()
    assert shoot(mono, cloud_of([(-6.0, 0.0, 1.2)]), occluded=left_blocked).detections == ()
    assert calls == []


def test_occlusion_callback_wrong_shape(mono):
    with pytest.raises(ValueError, match="shape"):
        shoot(mono, cloud_of([(6.0, 0.0, 1.2)]), occluded=lambda c, p: np.zeros(3, dtype=bool))


def test_pan_turns_the_view(rigs):
    cloud = cloud_of([(0.0, 5.0, 1.2)])  # 5 m to the robot's left
    for rid in ("front-left", "front-right", "ptz"):
        assert not shoot(rigs[rid], cloud).detections, rid
        assert shoot(rigs[rid], cloud, pan=math.pi / 2).detections, rid
        assert not shoot(rigs[rid], cloud, pan=-math.pi / 2).detections, rid


def test_pan_and_tilt_centre_a_point(mono):
    # unit at (0, 0, 1.2): pan 30 deg left and tilt 20 deg up puts this point on the axis
    pan, tilt, d = math.radians(30.0), math.radians(20.0), 9.0
    p = (
        d * math.cos(tilt) * math.cos(pan),
        d * math.cos(tilt) * math.sin(pan),
        1.2 + d * math.sin(tilt),
    )
    ((u, v),) = seen(shoot(mono, cloud_of([p]), pan=pan, tilt=tilt)).values()
    assert (u, v) == pytest.approx(centre(mono), abs=1e-9)


@pytest.mark.parametrize("pan", [0.0, math.pi / 2, -2.5])
def test_stereo_disparity(rigs, pan):
    left, right = rigs["front-left"], rigs["front-right"]
    z = 7.0
    # straight ahead of the unit (mount (0.55, 0, 1.2)) along the panned axis
    p = (0.55 + z * math.cos(pan), z * math.sin(pan), 1.2)
    cloud = cloud_of([p])
    ((ul, vl),) = seen(shoot(left, cloud, pan=pan)).values()
    ((ur, vr),) = seen(shoot(right, cloud, pan=pan)).values()
    f, b = left.spec.focal_px, left.spec.baseline
    assert ul > ur
    assert ul - ur == pytest.approx(f * b / z, rel=1e-9)
    assert ul == pytest.approx(400.0 + f * (b / 2) / z, rel=1e-9)
    assert vl == pytest.approx(vr, abs=1e-9)
    assert vl == pytest.approx(300.0, abs=1e-9)


def test_rear_cameras_look_backwards(rigs):
    behind = cloud_of([(-8.0, 0.0, 1.2)])
    ahead = cloud_of([(8.0, 0.0, 1.2)])
    for rid in ("rear-left", "rear-right"):
        assert shoot(rigs[rid], behind).detections, rid
        assert not shoot(rigs[rid], ahead).detections, rid
    for rid in ("front-left", "front-right"):
        assert not shoot(rigs[rid], behind).detections, rid
        assert shoot(rigs[rid], ahead).detections, rid
    # looking backwards, the robot's left (+y) appears on the right of the image
    rear = rigs["rear-left"]
    ((u, _),) = seen(shoot(rear, cloud_of([(-8.0, 1.0, 1.2)]))).values()
    assert u > 400.0
    # and the rear pair's disparity has the same sign as the front's
    ((ul, _),) = seen(shoot(rigs["rear-left"], behind)).values()
    ((ur, _),) = seen(shoot(rigs["rear-right"], behind)).values()
    assert ul - ur == pytest.approx(rear.spec.focal_px * 0.3 / (8.0 - 0.55), rel=1e-9)


def test_robot_pose_and_rotated_aircraft_compose(mono):
    """A feature given in F, aircraft parked rotated; robot placed in A by hand to centre it."""
    heading = math.radians(-120.0)
    placement = AircraftPlacement(-20.0, 35.0, heading, 3.0)
    x_f, y_f, h = 6.0, -2.5, 2.0  # 6 m aft of the nose, 2.5 m to starboard, 2 m high
    ac = make_aircraft([feature("probe", [(x_f, y_f, 3.0 - h)], detection_range=20.0)])
    cloud = FeatureCloud.from_aircraft(ac, placement)
    # by hand: the aft direction is heading + 180 deg, port is heading + 90 deg
    px = -20.0 + x_f * math.cos(heading + math.pi) + y_f * math.cos(heading + math.pi / 2)
    py = 35.0 + x_f * math.sin(heading + math.pi) + y_f * math.sin(heading + math.pi / 2)
    # robot 8 m away, facing the point from bearing 200 deg; the mono unit is at the axle
    # centre, 1.2 m up, so tilt up by atan(0.8 / 8)
    facing = math.radians(200.0)
    d = 8.0
    robot = Pose2(px - d * math.cos(facing), py - d * math.sin(facing), facing)
    tilt = math.atan2(h - 1.2, d)
    ((u, v),) = seen(shoot(mono, cloud, robot, tilt=tilt)).values()
    assert (u, v) == pytest.approx(centre(mono), abs=1e-7)
    # robot turned 10 deg to the right: the point is now 10 deg to its left, so it moves
    # left in the image; in C: X = -d sin(10 deg), Z = d cos(10 deg) cos(tilt) + 0.8 sin(tilt)
    a = math.radians(10.0)
    turned = Pose2(robot.x, robot.y, facing - a)
    ((u2, _),) = seen(shoot(mono, cloud, turned, tilt=tilt)).values()
    z_c = d * math.cos(a) * math.cos(tilt) + (h - 1.2) * math.sin(tilt)
    assert u2 == pytest.approx(400.0 - mono.spec.focal_px * d * math.sin(a) / z_c, abs=1e-7)


def test_detections_sorted_by_feature_then_point(mono):
    ac = make_aircraft(
        [
            feature("zeta", [(5.0, 0.5, -0.2), (5.0, -0.5, -0.2)]),
            feature("alpha", [(6.0, 0.0, -0.2), (6.0, 0.3, -0.2), (6.0, -0.3, -0.2)]),
        ]
    )
    frame = shoot(mono, FeatureCloud.from_aircraft(ac, MIRROR))
    keys = [(d.feature, d.point) for d in frame.detections]
    assert keys == [("alpha", 0), ("alpha", 1), ("alpha", 2), ("zeta", 0), ("zeta", 1)]


# -- noise, dropouts, determinism -------------------------------------------------------------


def grid_cloud(n=15):
    """n x n points well inside the mono camera's image, 10 m ahead."""
    ys = np.linspace(-2.0, 2.0, n)
    zs = np.linspace(0.0, 2.4, n)
    return cloud_of([(10.0, y, z) for y in ys for z in zs])


def test_same_seed_same_frames(rigs, a320):
    cloud = FeatureCloud.from_aircraft(a320.aircraft, a320.nominal_placement())
    pose = a320.nominal_placement().pose_to_airport(a320.checkpoints[0].pose)

    def run(seed):
        rng = np.random.default_rng(seed)
        return [
            shoot(rig, cloud, pose, 0.1 * k, 0.2, rng=rng, noise=0.7, dropout=0.2, stamp=k)
            for k in range(6)
            for rig in rigs.values()
        ]

    first, again, other = run(42), run(42), run(43)
    assert first == again
    assert sum(len(f.detections) for f in first) > 10
    assert first != other


def test_noise_free_frames_do_not_use_the_generator(mono):
    rng = np.random.default_rng(5)
    state = rng.bit_generator.state
    shoot(mono, grid_cloud(), rng=rng)
    assert rng.bit_generator.state == state


def test_pixel_noise_and_dropout_statistics(mono):
    cloud = grid_cloud()
    exact = seen(shoot(mono, cloud))
    assert len(exact) == 225
    rng = np.random.default_rng(7)
    sigma, dropout, runs = 1.5, 0.2, 40
    du, dv, kept = [], [], 0
    for _ in range(runs):
        frame = shoot(mono, cloud, rng=rng, noise=sigma, dropout=dropout)
        kept += len(frame.detections)
        for d in frame.detections:
            u0, v0 = exact[(d.feature, d.point)]
            du.append(d.u - u0)
            dv.append(d.v - v0)
    total = runs * len(exact)
    # 9000 trials: binomial std of the rate is 0.004
    assert 1.0 - kept / total == pytest.approx(dropout, abs=0.02)
    for err in (np.array(du), np.array(dv)):
        assert abs(err.mean()) < 0.1
        assert err.std() == pytest.approx(sigma, rel=0.05)


def test_noisy_pixels_stay_inside_the_image(mono):
    # a point 0.2 px inside the right edge: with 2 px noise about half the frames lose it
    spec = mono.spec
    u_target = spec.image_width_px - 0.2
    y = -10.0 * (u_target - 400.0) / spec.focal_px
    cloud = cloud_of([(10.0, y, 1.2)])
    rng = np.random.default_rng(3)
    frames = [shoot(mono, cloud, rng=rng, noise=2.0) for _ in range(400)]
    us = [d.u for f in frames for d in f.detections]
    assert all(0.0 <= u < spec.image_width_px for u in us)
    assert 100 < len(us) < 300


def test_bad_noise_parameters(mono):
    cloud = cloud_of([(6.0, 0.0, 1.2)])
    with pytest.raises(ValueError):
        shoot(mono, cloud, noise=-1.0)
    with pytest.raises(ValueError):
        shoot(mono, cloud, dropout=1.5)
    assert shoot(mono, cloud, dropout=1.0).detections == ()


def test_empty_frame_is_a_camera_frame(mono):
    frame = shoot(mono, cloud_of([(-6.0, 0.0, 1.2)]), stamp=1.5)
    assert frame == CameraFrame(1.5)


# -- against a point-by-point reference --------------------------------------------------------


def reference(rig, pan, tilt, pose, cloud, margin=1e-6):
    """Point by point with frames.py: (visible keys -> (u, v), keys too close to call)."""
    spec = rig.spec
    mount = np.array(spec.mount) + rig.lateral * rot_z(spec.mount_yaw + pan)[:, 1]
    r_from_c = robot_from_camera(mount, spec.mount_yaw, pan, tilt)
    c_from_r = r_from_c.inverse()
    f, (cx, cy) = spec.focal_px, centre(rig)
    cam_a = rot_z(pose.theta) @ r_from_c.translation + np.array([pose.x, pose.y, 0.0])
    visible, unsure = {}, set()
    for k in range(len(cloud)):
        key = (cloud.feature_ids[cloud.feature_index[k]], int(cloud.point_index[k]))
        p_a = cloud.points[k]
        p_r = rot_z(-pose.theta) @ (p_a - np.array([pose.x, pose.y, 0.0]))
        x, y, z = c_from_r.apply(p_r)
        n = cloud.normals[k]
        margins = [z, cloud.detection_range[k] - np.linalg.norm(p_a - cam_a)]
        if not np.isnan(n).any():
            margins.append(float(n @ (cam_a - p_a)))
        if z > 0:
            u, v = cx + f * x / z, cy + f * y / z
            margins += [u, 2 * cx - u, v, 2 * cy - v]
        if min(abs(m) for m in margins) < margin:
            unsure.add(key)
        elif min(margins) > 0:
            visible[key] = (u, v)
    return visible, unsure


@settings(max_examples=80, deadline=None)
@given(
    k=st.integers(0, 10_000),
    r=st.floats(1.0, 15.0),
    bearing=st.floats(-math.pi, math.pi),
    theta=st.floats(-math.pi, math.pi),
    off_axis=st.floats(-0.6, 0.6),
    tilt=st.floats(-0.5, 1.0),
    which=st.sampled_from(["front-left", "front-right", "rear-left", "rear-right", "ptz"]),
)
def test_matches_point_by_point_reference(a320, rigs, k, r, bearing, theta, off_axis, tilt, which):
    """Vectorised detect() against the reference, the unit turned towards some feature."""
    placement = AircraftPlacement(3.0, -4.0, math.radians(75.0), a320.aircraft.origin_height)
    cloud = _a320_cloud(a320, placement)
    rig = rigs[which]
    target = cloud.points[k % len(cloud)]
    pose = Pose2(target[0] - r * math.cos(bearing), target[1] - r * math.sin(bearing), theta)
    pan = wrap_angle(bearing - theta - rig.spec.mount_yaw + off_axis)
    visible, unsure = reference(rig, pan, tilt, pose, cloud)
    got = seen(shoot(rig, cloud, pose, pan, tilt))
    assert set(got) - unsure == set(visible)
    for key, uv in visible.items():
        assert got[key] == pytest.approx(uv, abs=1e-6)


_CLOUDS = {}


def _a320_cloud(a320, placement):
    if placement not in _CLOUDS:
        _CLOUDS[placement] = FeatureCloud.from_aircraft(a320.aircraft, placement)
    return _CLOUDS[placement]
