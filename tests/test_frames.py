"""Frames and transforms: conventions of ARCHITECTURE.md §4 and round trips."""

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from executive.core.frames import (
    AircraftPlacement,
    Pose2,
    Transform3,
    aircraft_from_robot,
    aircraft_points_from_robot,
    mirror_pose,
    moved_in_aircraft,
    pan_tilt_towards,
    robot_from_camera,
    robot_points_from_aircraft,
    rot_x,
    rot_y,
    rot_z,
    wrap_angle,
)

coord = st.floats(-500, 500, allow_nan=False)
angle = st.floats(-math.pi, math.pi, allow_nan=False, exclude_max=True)
small = st.floats(-5, 5, allow_nan=False)


def poses():
    return st.builds(Pose2, coord, coord, angle)


def placements():
    return st.builds(AircraftPlacement, coord, coord, angle, st.floats(0, 6))


def transforms():
    @st.composite
    def build(draw):
        r = rot_z(draw(angle)) @ rot_y(draw(angle)) @ rot_x(draw(angle))
        return Transform3(r, np.array([draw(coord), draw(coord), draw(coord)]))

    return build()


def same_angle(a, b, tol=1e-9):
    return abs(wrap_angle(a - b)) < tol


@given(poses(), poses())
def test_se2_compose_inverse_round_trip(a, b):
    back = (a @ b) @ b.inverse()
    assert math.isclose(back.x, a.x, abs_tol=1e-7)
    assert math.isclose(back.y, a.y, abs_tol=1e-7)
    assert same_angle(back.theta, a.theta, 1e-9)


@given(poses(), st.lists(st.tuples(coord, coord), min_size=1, max_size=5))
def test_se2_apply_matches_matrix_and_inverts(pose, pts):
    pts = np.array(pts)
    homog = np.column_stack((pts, np.ones(len(pts))))
    assert np.allclose(pose.apply(pts), (homog @ pose.matrix().T)[:, :2], atol=1e-7)
    assert np.allclose(pose.inverse().apply(pose.apply(pts)), pts, atol=1e-6)


@given(transforms(), transforms())
def test_se3_round_trip_and_matrix(a, b):
    assert ((a @ b) @ b.inverse()).allclose(a, atol=1e-6)
    assert np.allclose((a @ b).matrix(), a.matrix() @ b.matrix(), atol=1e-6)
    assert np.isclose(np.linalg.det(a.rotation), 1.0)


@given(placements(), st.lists(st.tuples(coord, coord), min_size=1, max_size=5))
def test_aircraft_airport_points_round_trip(placement, pts):
    pts = np.array(pts)
    assert np.allclose(placement.to_aircraft_xy(placement.to_airport_xy(pts)), pts, atol=1e-6)


@given(placements(), poses())
def test_aircraft_airport_pose_round_trip(placement, pose):
    back = placement.pose_to_aircraft(placement.pose_to_airport(pose))
    assert math.isclose(back.x, pose.x, abs_tol=1e-6)
    assert math.isclose(back.y, pose.y, abs_tol=1e-6)
    assert same_angle(back.theta, pose.theta)


@given(placements(), st.tuples(coord, coord, small))
def test_2d_map_is_the_ground_projection_of_the_3d_transform(placement, p):
    a_from_f = placement.airport_from_aircraft()
    p_a = a_from_f.apply(np.array(p))
    assert np.allclose(p_a[:2], placement.to_airport_xy(p[:2]), atol=1e-6)
    assert math.isclose(p_a[2], placement.origin_height - p[2], abs_tol=1e-9)  # z down in F
    assert np.isclose(np.linalg.det(a_from_f.rotation), 1.0)  # a proper rotation


def test_aircraft_frame_conventions_nose_north():
    """Nose pointing north: tail is south, +y_F (port) is west, z_F points down."""
    placement = AircraftPlacement(100.0, 50.0, math.radians(90), origin_height=3.5)
    tail = placement.to_airport_xy((10.0, 0.0))
    port = placement.to_airport_xy((0.0, 4.0))
    assert np.allclose(tail, (100.0, 40.0))
    assert np.allclose(port, (96.0, 50.0))
    nose_height = placement.airport_from_aircraft().apply((0.0, 0.0, 0.0))[2]
    ground = placement.airport_from_aircraft().apply((0.0, 0.0, 3.5))[2]
    assert nose_height == pytest.approx(3.5)
    assert ground == pytest.approx(0.0)
    # Robot heading in F: 0 faces the tail (south in A), 90 deg faces port (west).
    assert same_angle(placement.pose_to_airport(Pose2(0, 0, 0)).theta, -math.pi / 2)
    assert same_angle(placement.pose_to_airport(Pose2(0, 0, math.pi / 2)).theta, math.pi)


@given(poses(), st.floats(0, 6))
def test_robot_in_aircraft_frame_matches_2d_heading(pose, origin_height):
    f_from_r = aircraft_from_robot(pose, origin_height)
    forward = f_from_r.apply((1.0, 0.0, 0.0)) - f_from_r.apply((0.0, 0.0, 0.0))
    up = f_from_r.apply((0.0, 0.0, 1.0)) - f_from_r.apply((0.0, 0.0, 0.0))
    assert np.allclose(forward, (math.cos(pose.theta), math.sin(pose.theta), 0.0), atol=1e-9)
    assert np.allclose(up, (0.0, 0.0, -1.0))
    assert math.isclose(f_from_r.apply((0.0, 0.0, 0.0))[2], origin_height)
    assert np.isclose(np.linalg.det(f_from_r.rotation), 1.0)


def test_camera_frame_is_visp_at_rest():
    r_from_c = robot_from_camera((0.5, 0.0, 1.2), 0.0, 0.0, 0.0)
    assert np.allclose(r_from_c.rotation @ (0, 0, 1), (1, 0, 0))  # optical axis forward
    assert np.allclose(r_from_c.rotation @ (1, 0, 0), (0, -1, 0))  # x right
    assert np.allclose(r_from_c.rotation @ (0, 1, 0), (0, 0, -1))  # y down
    rear = robot_from_camera((-0.5, 0.0, 1.2), math.pi, 0.0, 0.0)
    assert np.allclose(rear.rotation @ (0, 0, 1), (-1, 0, 0))


@given(
    st.tuples(small, small, st.floats(0, 2)),
    angle,
    st.tuples(coord, coord, small).filter(lambda p: math.hypot(p[0], p[1]) > 1.0),
)
def test_pan_tilt_towards_puts_target_on_optical_axis(mount, yaw, target):
    if math.hypot(target[0] - mount[0], target[1] - mount[1]) < 0.5:
        return
    pan, tilt = pan_tilt_towards(mount, yaw, target)
    c_from_r = robot_from_camera(mount, yaw, pan, tilt).inverse()
    p_c = c_from_r.apply(np.array(target, dtype=float))
    assert p_c[2] > 0
    assert np.allclose(p_c[:2] / p_c[2], 0.0, atol=1e-6)


@given(pose_f=poses(), delta=poses(), pts=st.lists(st.tuples(small, small), min_size=1, max_size=5))
def test_moving_in_the_aircraft_frame_agrees_with_the_airport_frame(pose_f, delta, pts):
    """A motion delta in R moves the robot the same whether composed in A or in F."""
    placement = AircraftPlacement(3.0, -2.0, 1.1)
    pose_a = placement.pose_to_airport(pose_f)
    after_a = pose_a @ delta
    after_f = moved_in_aircraft(pose_f, delta)
    expected = placement.pose_to_aircraft(after_a)
    assert after_f.distance_to(expected) < 1e-6
    assert abs(wrap_angle(after_f.theta - expected.theta)) < 1e-9
    back = mirror_pose(mirror_pose(pose_f))
    assert (back.x, back.y) == (pose_f.x, pose_f.y)
    assert abs(wrap_angle(back.theta - pose_f.theta)) < 1e-12
    # points seen from the robot land on the same aircraft points either way
    p = np.array(pts)
    in_f = aircraft_points_from_robot(pose_f, p)
    assert np.allclose(in_f, placement.to_aircraft_xy(pose_a.apply(p)), atol=1e-6)
    assert np.allclose(robot_points_from_aircraft(pose_f, in_f), p, atol=1e-6)
