"""Ceiling-landmark localisation (behaviours.laws.ceiling, seed 002 §2.1-2.2, eq. 1-4).

Synthetic landmarks lie on a horizontal ceiling plane Z metres above the camera. They are
projected into an upward-looking pinhole camera written here in 3D, independently of the
module's 2D algebra: the camera frame has z_C vertical up, x_C horizontal (the robot's
forward axis turned by the mount yaw) and y_C = z_C x x_C; a landmark's image pose is the
pixel of its origin and the image angle (from +u towards +v) of its x axis.
"""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from behaviours.laws.ceiling import (
    CeilingCamera,
    LandmarkObservation,
    camera_from_landmark_eq1,
    fuse_poses_eq3,
    landmark_in_mosaic_eq4,
    landmark_pose_variances,
    localise,
    relative_landmark_pose,
    robot_pose_from_landmark_eq2,
    weighted_circular_mean,
)
from executive.core.frames import Pose2, wrap_angle

CAMERA = CeilingCamera(focal_px=500.0, cu=320.0, cv=240.0, height=3.0)


def project(point_m: np.ndarray, robot: Pose2, camera: CeilingCamera) -> np.ndarray:
    """Pinhole projection of a ceiling point (x, y in M, z = camera.height above the
    optical centre) for a robot at ``robot`` (in M)."""
    mount = camera.robot_from_camera
    yaw = robot.theta + mount.theta
    z_c = np.array([0.0, 0.0, 1.0])  # optical axis up
    x_c = np.array([math.cos(yaw), math.sin(yaw), 0.0])
    y_c = np.cross(z_c, x_c)  # ViSP: right-handed, x right, y down in the image
    world_from_camera = np.column_stack([x_c, y_c, z_c])
    assert np.linalg.det(world_from_camera) == pytest.approx(1.0)
    centre = np.array([*robot.apply(mount.position), 0.0])
    p_c = world_from_camera.T @ (np.array([point_m[0], point_m[1], camera.height]) - centre)
    return np.array(
        [
            camera.cu + camera.focal_px * p_c[0] / p_c[2],
            camera.cv + camera.focal_px * p_c[1] / p_c[2],
        ]
    )


def image_pose(landmark: Pose2, robot: Pose2, camera: CeilingCamera = CAMERA) -> Pose2:
    """The landmark's image pose (u, v, phi) from two projected points of its frame."""
    origin = project(landmark.position, robot, camera)
    tip = project(landmark.apply([0.2, 0.0]), robot, camera)
    du, dv = tip - origin
    return Pose2(float(origin[0]), float(origin[1]), math.atan2(dv, du))


def assert_pose_close(a: Pose2, b: Pose2, pos: float = 1e-9, ang: float = 1e-9) -> None:
    assert (a.x, a.y) == pytest.approx((b.x, b.y), abs=pos)
    assert wrap_angle(a.theta - b.theta) == pytest.approx(0.0, abs=ang)


pose_st = st.builds(
    Pose2,
    st.floats(-30.0, 30.0),
    st.floats(-30.0, 30.0),
    st.floats(-math.pi, math.pi, exclude_max=True),
)
offset_st = st.builds(
    Pose2, st.floats(-1.5, 1.5), st.floats(-1.2, 1.2), st.floats(-math.pi, math.pi)
)


# -- image conventions ---------------------------------------------------------------------
def test_image_axes_of_the_upward_camera():
    """Default mount: x_C = robot forward, y_C = robot left; the image is not flipped."""
    robot = Pose2(0.0, 0.0, 0.0)
    ahead_left = project(np.array([1.0, 0.5]), robot, CAMERA)
    assert ahead_left[0] > CAMERA.cu  # ahead -> u increases
    assert ahead_left[1] > CAMERA.cv  # left -> v increases (down on the screen)
    assert ahead_left == pytest.approx([320.0 + 500.0 / 3.0, 240.0 + 250.0 / 3.0])
    # the landmark's x axis along M's x, seen by a robot turned +30 deg (counter-clockwise
    # seen from above): its image angle, from +u towards +v, is -30 deg
    landmark = Pose2(0.3, -0.2, 0.0)
    turned = image_pose(landmark, Pose2(0.0, 0.0, math.radians(30.0)))
    assert turned.theta == pytest.approx(math.radians(-30.0))
    # the floor-camera habit atan2(-dv, du) would read +30 deg and get the heading wrong
    origin = project(landmark.position, Pose2(0.0, 0.0, math.radians(30.0)), CAMERA)
    tip = project(landmark.apply([0.2, 0.0]), Pose2(0.0, 0.0, math.radians(30.0)), CAMERA)
    wrong = math.atan2(-(tip[1] - origin[1]), tip[0] - origin[0])
    assert wrong == pytest.approx(math.radians(30.0))


def test_eq1_scales_pixels_about_the_principal_point():
    lifted = camera_from_landmark_eq1(Pose2(420.0, 190.0, 0.3), CAMERA)
    assert (lifted.x, lifted.y, lifted.theta) == pytest.approx((0.6, -0.3, 0.3))
    assert CAMERA.scale == pytest.approx(3.0 / 500.0)


# -- eq. 1-2: pose from one landmark -------------------------------------------------------
@given(robot=pose_st, offset=offset_st, mount=offset_st)
def test_eq2_recovers_the_robot_pose_exactly(robot, offset, mount):
    camera = CeilingCamera(500.0, 320.0, 240.0, 2.7, Pose2(mount.x / 5, mount.y / 5, mount.theta))
    landmark = robot @ offset  # within the field of view
    observed = image_pose(landmark, robot, camera)
    assert_pose_close(robot_pose_from_landmark_eq2(landmark, observed, camera), robot, 1e-8)


def test_eq2_uses_the_metric_scale():
    """A wrong ceiling height scales the offset from the landmark: the scale matters."""
    robot, landmark = Pose2(2.0, 1.0, 0.4), Pose2(3.0, 0.5, 1.0)
    observed = image_pose(landmark, robot)
    wrong = CeilingCamera(500.0, 320.0, 240.0, 3.3)
    est = robot_pose_from_landmark_eq2(landmark, observed, wrong)
    assert est.distance_to(landmark) == pytest.approx(1.1 * robot.distance_to(landmark))
    assert est.theta == pytest.approx(robot.theta)


# -- eq. 3: weighted mean ------------------------------------------------------------------
def test_weighted_mean_beats_single_landmarks_under_pixel_noise():
    """Five landmarks, pixel noise from 0.3 to 4 px (angle noise alike), 400 trials."""
    rng = np.random.default_rng(7)
    robot = Pose2(4.0, -2.0, 0.7)
    offsets = [(1.2, 0.8), (-1.0, 0.6), (0.4, -1.0), (-0.7, -0.7), (1.0, -0.2)]
    sigmas = [0.3, 0.6, 1.0, 2.0, 4.0]
    mosaic = {f"m{k}": robot @ Pose2(dx, dy, 0.5 * k) for k, (dx, dy) in enumerate(offsets)}
    truth = {k: image_pose(lm, robot) for k, lm in mosaic.items()}
    errors = {"fused": [], "plain": [], **{k: [] for k in mosaic}}
    heading_errors = {"fused": [], **{k: [] for k in mosaic}}
    fixes = []
    for _ in range(400):
        observations = []
        for (k, clean), sigma in zip(truth.items(), sigmas, strict=True):
            sigma_phi = sigma / 60.0  # ~ the angle of a 120 px wide pattern
            noisy = Pose2(
                clean.x + rng.normal(0.0, sigma),
                clean.y + rng.normal(0.0, sigma),
                clean.theta + rng.normal(0.0, sigma_phi),
            )
            observations.append(LandmarkObservation(k, noisy, sigma, sigma_phi))
            single = robot_pose_from_landmark_eq2(mosaic[k], noisy, CAMERA)
            errors[k].append(single.distance_to(robot))
            heading_errors[k].append(wrap_angle(single.theta - robot.theta))
        fix = localise(observations, mosaic, CAMERA)
        assert fix is not None
        fixes.append(fix)
        errors["fused"].append(fix.pose.distance_to(robot))
        heading_errors["fused"].append(wrap_angle(fix.pose.theta - robot.theta))
        plain = fuse_poses_eq3(
            [
                robot_pose_from_landmark_eq2(mosaic[o.landmark_id], o.image_pose, CAMERA)
                for o in observations
            ],
            [1.0] * len(observations),
        )
        errors["plain"].append(plain.distance_to(robot))

    def rms(values: list[float]) -> float:
        return float(np.sqrt(np.mean(np.square(values))))

    singles = [rms(errors[k]) for k in mosaic]
    assert rms(errors["fused"]) < max(singles)  # beats the worst landmark ...
    assert rms(errors["fused"]) < min(singles)  # ... and even the best one
    assert rms(errors["fused"]) < 0.7 * rms(errors["plain"])  # the weights matter
    assert rms(heading_errors["fused"]) < min(rms(heading_errors[k]) for k in mosaic)
    # the covariance of the fix predicts its error (within 25 %)
    predicted_pos = math.sqrt(2.0 * fixes[0].covariance[0, 0])
    predicted_h = math.sqrt(fixes[0].covariance[2, 2])
    assert rms(errors["fused"]) == pytest.approx(predicted_pos, rel=0.25)
    assert rms(heading_errors["fused"]) == pytest.approx(predicted_h, rel=0.25)
    assert fixes[0].used == tuple(mosaic)


def test_circular_mean_across_pi():
    assert abs(weighted_circular_mean([3.1, -3.1], [1.0, 1.0])) == pytest.approx(math.pi)
    fused = fuse_poses_eq3([Pose2(0, 0, 3.0), Pose2(2, 0, -3.0)], [1.0, 3.0])
    assert fused.x == pytest.approx(1.5)
    assert abs(fused.theta) > 3.0  # not the arithmetic mean (-1.5)


@given(
    poses=st.lists(pose_st, min_size=1, max_size=6),
    weights=st.lists(st.floats(0.01, 100.0), min_size=6, max_size=6),
    shift=pose_st,
)
def test_eq3_is_equivariant_under_a_change_of_mosaic_frame(poses, weights, shift):
    """Fusing then moving the frame equals moving then fusing (for agreeing headings)."""
    close = [Pose2(p.x, p.y, poses[0].theta + 0.1 * k) for k, p in enumerate(poses)]
    w = weights[: len(close)]
    assert_pose_close(
        shift @ fuse_poses_eq3(close, w), fuse_poses_eq3([shift @ p for p in close], w), 1e-7
    )


def test_variances_grow_with_the_lever_arm():
    near = LandmarkObservation("a", Pose2(330.0, 240.0, 0.0), 1.0, 0.01)
    far = LandmarkObservation("b", Pose2(620.0, 240.0, 0.0), 1.0, 0.01)
    var_near, var_h = landmark_pose_variances(near, CAMERA)
    var_far, _ = landmark_pose_variances(far, CAMERA)
    assert var_h == pytest.approx(1e-4)
    assert var_near == pytest.approx(0.006**2 + 0.5 * 0.06**2 * 1e-4)
    assert var_far > 5 * var_near


def test_localise_skips_unknown_landmarks():
    robot = Pose2(1.0, 1.0, 0.2)
    mosaic = {"a": Pose2(1.5, 1.2, 0.0)}
    seen = [
        LandmarkObservation("a", image_pose(mosaic["a"], robot)),
        LandmarkObservation("zz", Pose2(10.0, 10.0, 0.0)),
    ]
    fix = localise(seen, mosaic, CAMERA)
    assert fix is not None
    assert fix.used == ("a",)
    assert_pose_close(fix.pose, robot, 1e-9)
    assert localise(seen[1:], mosaic, CAMERA) is None


def test_invalid_inputs_are_refused():
    with pytest.raises(ValueError):
        LandmarkObservation("a", Pose2(0, 0, 0), sigma_px=0.0)
    with pytest.raises(ValueError):
        CeilingCamera(0.0, 320.0, 240.0, 3.0)
    with pytest.raises(ValueError):
        fuse_poses_eq3([Pose2(0, 0, 0)], [1.0, 2.0])
    with pytest.raises(ValueError):
        fuse_poses_eq3([], [])


# -- eq. 4: building the mosaic ------------------------------------------------------------
def test_eq4_chains_three_landmarks_to_their_true_mosaic_poses():
    """m0 defines M; images A, B, C each show two successive landmarks, never m0 with m2."""
    truth = [Pose2(0.0, 0.0, 0.0), Pose2(1.6, 0.4, 0.9), Pose2(3.1, -0.3, -2.2)]
    truth.append(Pose2(4.4, 0.5, 2.9))
    robots = [Pose2(0.8, 0.1, 0.3), Pose2(2.3, 0.2, -0.4), Pose2(3.8, 0.0, 1.2)]
    built = [truth[0]]
    for k, robot in enumerate(robots):
        seen_j, seen_i = image_pose(truth[k], robot), image_pose(truth[k + 1], robot)
        built.append(landmark_in_mosaic_eq4(built[k], seen_j, seen_i, CAMERA))
    for got, want in zip(built, truth, strict=True):
        assert_pose_close(got, want, 1e-9)
    # and the robot localises from the last landmark alone
    robot = Pose2(4.0, 0.9, -1.0)
    located = robot_pose_from_landmark_eq2(built[3], image_pose(truth[3], robot), CAMERA)
    assert_pose_close(located, robot, 1e-9)


@given(robot=pose_st, off_j=offset_st, off_i=offset_st, mosaic_j=pose_st)
@settings(max_examples=60)
def test_relative_pose_is_independent_of_the_robot_pose(robot, off_j, off_i, mosaic_j):
    """j_T_i is a property of the ceiling; it does not depend on where the image was taken."""
    landmark_j, landmark_i = robot @ off_j, robot @ off_i
    rel = relative_landmark_pose(
        image_pose(landmark_j, robot), image_pose(landmark_i, robot), CAMERA
    )
    assert_pose_close(rel, landmark_j.inverse() @ landmark_i, 1e-8)
    # eq. 4 through any known pose of j
    placed = landmark_in_mosaic_eq4(
        mosaic_j, image_pose(landmark_j, robot), image_pose(landmark_i, robot), CAMERA
    )
    assert_pose_close(placed, mosaic_j @ landmark_j.inverse() @ landmark_i, 1e-7)
