"""VNHV line-following law (behaviours.laws.vnhv, seed 002 §3, eq. 5-12).

Closed-loop runs integrate eq. 5 with a fixed-step RK4 in time, the step chosen so that
the cart covers ``DS`` = 2 mm along its path per step, and compare ``y`` as a function of
the distance travelled along the line, ``d = |s - s0|``, with the exact solution of eq. 10.
"""

import math
from collections.abc import Callable

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from behaviours.laws.ceiling import CeilingCamera
from behaviours.laws.vnhv import (
    DEFAULT_THETA_MAX,
    Damping,
    VnhvGains,
    VnhvState,
    damping_ratio,
    eq10_response,
    image_transform_s31,
    initial_slope,
    kinematics_eq5,
    limit_speed,
    m1_eq6,
    m2_eq11,
    m2_from_omega_eq8,
    m3_eq9,
    natural_frequency,
    omega_eq12,
    omega_from_m2_eq8,
    second_order_theory,
    settling_distance,
    settling_distance_envelope,
    state_from_image_poses,
    state_from_poses,
    to_chained,
    vnhv_command,
)
from executive.core.frames import Pose2, wrap_angle

DS = 2e-3
UNDER = VnhvGains(kp=4.0, kd=1.6)  # zeta 0.4, omega_n 2 /m
CRITICAL = VnhvGains(kp=4.0, kd=4.0)  # zeta 1
OVER = VnhvGains(kp=1.0, kd=4.0)  # zeta 2, omega_n 1 /m
ALL_GAINS = pytest.mark.parametrize(
    "gains", [UNDER, CRITICAL, OVER], ids=["under", "critical", "over"]
)
SPEEDS = [0.3, 1.0, 2.5, -0.5, -2.0]


def simulate(
    state: VnhvState,
    distance: float,
    speed: Callable[[VnhvState], float],
    steer: Callable[[VnhvState, float], float],
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """RK4 on eq. 5 until ``|s - s0| >= distance``; V is held over each step.

    Returns (d, y, theta) sampled at every step, d the distance along the line."""
    s0 = state.s
    x = np.array([state.s, state.y, state.theta])
    ds, ys, ths = [0.0], [state.y], [state.theta]

    def f(x: np.ndarray, v: float) -> np.ndarray:
        st_ = VnhvState(*x)
        return np.array(kinematics_eq5(st_, v, steer(st_, v)))

    max_steps = int(20 * distance / DS)  # a law that stalls on the line fails, not hangs
    while abs(x[0] - s0) < distance:
        assert len(ds) < max_steps, "the cart stopped progressing along the line"
        v = speed(VnhvState(*x))
        dt = DS / abs(v)
        k1 = f(x, v)
        k2 = f(x + 0.5 * dt * k1, v)
        k3 = f(x + 0.5 * dt * k2, v)
        k4 = f(x + dt * k3, v)
        x = x + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        ds.append(abs(x[0] - s0))
        ys.append(x[1])
        ths.append(x[2])
    return np.array(ds), np.array(ys), np.array(ths)


def run_eq12(gains: VnhvGains, state: VnhvState, v: float, distance: float):
    return simulate(state, distance, lambda _s: v, lambda s, vv: omega_eq12(s, vv, gains))


def measured_settling(d: np.ndarray, y: np.ndarray, fraction: float = 0.05) -> float:
    """Last exit of |y| from the band fraction * max|y|, linearly interpolated."""
    band = fraction * float(np.max(np.abs(y)))
    k = int(np.nonzero(np.abs(y) > band)[0][-1])
    y1, y2 = abs(y[k]), abs(y[k + 1])
    return float(d[k] + (d[k + 1] - d[k]) * (y1 - band) / (y1 - y2))


# -- eq. 10: closed loop -------------------------------------------------------------------
@ALL_GAINS
@pytest.mark.parametrize("v", SPEEDS)
def test_closed_loop_converges_and_follows_eq10(gains, v):
    """From y0 = 0.4 m, theta0 = 0.3 rad (a large deviation: the chained form is exact),
    y and theta converge and y(d) is eq. 10's exact solution for every V, backwards too."""
    start = VnhvState(s=-10.0 if v > 0 else 10.0, y=0.4, theta=0.3)
    horizon = 3.0 * settling_distance(gains, 0.4, initial_slope(start, v))
    d, y, theta = run_eq12(gains, start, v, horizon)
    assert abs(y[-1]) < 0.4 * 0.01
    assert abs(theta[-1]) < 0.01
    expected = eq10_response(gains, 0.4, initial_slope(start, v), d)
    assert np.max(np.abs(y - expected)) < 1e-6
    # tan(theta) is eq. 10's derivative along the direction of travel
    slope = np.gradient(expected, d)[1:-1]  # central differences
    assert np.allclose(np.tan(theta[1:-1]) * math.copysign(1.0, v), slope, atol=1e-4)


@ALL_GAINS
def test_path_y_of_distance_is_independent_of_speed(gains):
    """Runs at different V (both signs, theta0 = 0) agree at equal distance travelled."""
    start = VnhvState(0.0, -0.25, 0.0)
    horizon = 2.0 * settling_distance(gains, 0.25)
    grid = np.linspace(0.0, horizon * 0.99, 500)
    runs = {v: run_eq12(gains, start, v, horizon) for v in SPEEDS}
    reference = np.interp(grid, runs[1.0][0], runs[1.0][1])
    assert np.max(np.abs(reference)) == pytest.approx(0.25)
    for v, (d, y, _th) in runs.items():
        assert np.max(np.abs(np.interp(grid, d, y) - reference)) < 1e-6, v


@ALL_GAINS
def test_backwards_mirrors_forwards_with_opposite_initial_heading(gains):
    """With theta0 != 0 reversing sees the slope -tan(theta0): y(d) equals the forward run
    from -theta0, and theta(d) is its opposite."""
    horizon = 1.5 * settling_distance(gains, 0.2, 0.2)
    d_b, y_b, th_b = run_eq12(gains, VnhvState(0.0, 0.2, 0.2), -1.0, horizon)
    d_f, y_f, th_f = run_eq12(gains, VnhvState(0.0, 0.2, -0.2), 0.7, horizon)
    grid = np.linspace(0.0, horizon * 0.99, 300)
    assert np.allclose(np.interp(grid, d_b, y_b), np.interp(grid, d_f, y_f), atol=1e-6)
    assert np.allclose(np.interp(grid, d_b, th_b), -np.interp(grid, d_f, th_f), atol=1e-6)
    # and it differs from the forward run from +theta0 (the check can fail)
    d_p, y_p, _ = run_eq12(gains, VnhvState(0.0, 0.2, 0.2), 1.0, horizon)
    assert np.max(np.abs(np.interp(grid, d_p, y_p) - np.interp(grid, d_b, y_b))) > 0.02


@ALL_GAINS
@pytest.mark.parametrize("v", [1.0, 0.4, -1.5])
def test_settling_distance_within_5_percent_of_eq10_theory(gains, v):
    """Initial conditions y0 = 5 cm, theta0 = 0 (small, parallel to the line)."""
    theory = settling_distance(gains, 0.05, 0.0)
    d, y, _ = run_eq12(gains, VnhvState(0.0, 0.05, 0.0), v, 2.0 * theory)
    measured = measured_settling(d, y)
    assert measured == pytest.approx(theory, rel=0.05)
    assert measured == pytest.approx(theory, rel=5e-3)  # the chained form is exact


def test_settling_theory_regimes_and_definition():
    assert damping_ratio(UNDER) == pytest.approx(0.4)
    assert natural_frequency(UNDER) == pytest.approx(2.0)
    assert second_order_theory(UNDER).damping is Damping.UNDER
    assert second_order_theory(CRITICAL).damping is Damping.CRITICAL
    assert second_order_theory(OVER).damping is Damping.OVER
    # critically damped from rest: e^(-w d)(1 + w d) = 0.05, solved here by bisection
    w = natural_frequency(CRITICAL)
    lo, hi = 0.0, 20.0
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if math.exp(-w * mid) * (1 + w * mid) > 0.05 else (lo, mid)
    assert settling_distance(CRITICAL) == pytest.approx(lo, rel=1e-9)
    # the envelope approximation misses the critical case by far (why we solve exactly)
    assert settling_distance_envelope(CRITICAL) < 0.7 * settling_distance(CRITICAL)
    # settling distance scales with the initial value only through the band: invariant
    assert settling_distance(OVER, 0.05) == pytest.approx(settling_distance(OVER, 3.0))


@given(
    kp=st.floats(0.05, 20.0),
    kd=st.floats(0.05, 20.0),
    y0=st.floats(-2.0, 2.0).filter(lambda v: abs(v) > 1e-3),
    slope0=st.floats(-2.0, 2.0),
)
@settings(max_examples=40, deadline=None)
def test_settling_distance_is_the_last_exit_from_the_band(kp, kd, y0, slope0):
    gains = VnhvGains(kp, kd)
    d_s = settling_distance(gains, y0, slope0, samples=20_001)
    after = np.linspace(d_s, d_s + 40.0 / min(1.0, kd), 20_000)
    y_after = np.abs(eq10_response(gains, y0, slope0, after))
    grid = np.linspace(0.0, max(d_s, 1e-3), 1_000_001)  # the peak comes before d_s
    band = 0.05 * max(abs(y0), float(np.max(np.abs(eq10_response(gains, y0, slope0, grid)))))
    assert np.all(y_after <= band * (1 + 1e-6))
    if d_s > 0.0:
        assert abs(float(eq10_response(gains, y0, slope0, d_s))) == pytest.approx(band, rel=1e-4)


# -- eq. 8, 11, 12 -------------------------------------------------------------------------
gains_st = st.builds(VnhvGains, kp=st.floats(0.01, 50.0), kd=st.floats(0.01, 50.0))
speed_st = st.floats(-5.0, 5.0).filter(lambda v: abs(v) > 1e-3)


@given(
    gains=gains_st,
    v=speed_st,
    y=st.floats(-10.0, 10.0),
    theta=st.floats(-1.55, 1.55),
    s=st.floats(-50.0, 50.0),
)
def test_eq12_is_eq8_solved_with_eq11(gains, v, y, theta, s):
    state = VnhvState(s, y, theta)
    chained = to_chained(state)
    assert (chained.a1, chained.a2) == (s, y)
    assert chained.a3 == pytest.approx(math.tan(theta), rel=1e-12)
    m1 = m1_eq6(v, theta)
    m2 = m2_eq11(chained, m1, gains)
    omega = omega_from_m2_eq8(m2, theta)
    scale = abs(v) * (gains.kp * abs(y) + gains.kd) + 1e-12
    assert omega_eq12(state, v, gains) == pytest.approx(omega, rel=1e-9, abs=1e-12 * scale)
    # eq. 11 is eq. 9 (m2 = m3 m1) for the direction of travel, and eq. 8 inverts back
    eq9_along_travel = math.copysign(1.0, m1) * -gains.kd * chained.a3 - gains.kp * chained.a2
    assert m2 / m1 == pytest.approx(eq9_along_travel, rel=1e-9, abs=1e-12 * scale)
    if m1 > 0:
        assert m2 / m1 == pytest.approx(m3_eq9(chained, gains), rel=1e-9, abs=1e-12 * scale)
    assert m2_from_omega_eq8(omega, theta) == pytest.approx(m2, rel=1e-9, abs=1e-12 * scale)


@given(theta=st.floats(-1.5, 1.5), omega=st.floats(-2.0, 2.0))
def test_eq8_m2_is_the_derivative_of_a3(theta, omega):
    """m2 = d/dt tan(theta) along theta' = omega (the definition behind eq. 8)."""
    h = 1e-6
    derivative = (math.tan(theta + omega * h) - math.tan(theta - omega * h)) / (2 * h)
    assert m2_from_omega_eq8(omega, theta) == pytest.approx(derivative, rel=1e-5, abs=1e-8)
    # the paper's printed eq. 8 (cos^2 theta omega) is not that derivative
    if abs(omega) > 0.1 and abs(theta) > 0.3:
        assert math.cos(theta) ** 2 * omega != pytest.approx(derivative, rel=0.05)


@given(
    gains=gains_st,
    v=st.floats(-5.0, 5.0),
    y=st.floats(-1e3, 1e3),
    theta=st.floats(-math.pi, math.pi, exclude_min=True, exclude_max=True),
    omega_max=st.floats(0.05, 3.0),
)
def test_omega_is_finite_and_odd_in_y_theta(gains, v, y, theta, omega_max):
    a = VnhvState(0.0, y, theta)
    b = VnhvState(0.0, -y, -theta)
    assert math.isfinite(omega_eq12(a, v, gains))
    assert omega_eq12(b, v, gains) == pytest.approx(-omega_eq12(a, v, gains), abs=1e-12)
    ca, cb = vnhv_command(a, v, gains, omega_max), vnhv_command(b, v, gains, omega_max)
    assert math.isfinite(ca.omega)
    assert abs(ca.omega) <= omega_max
    assert cb.omega == pytest.approx(-ca.omega, abs=1e-12)
    assert ca.in_domain == cb.in_domain == (abs(theta) < DEFAULT_THETA_MAX)


@given(theta=st.floats(-100.0, 100.0), y=st.floats(-1e3, 1e3), v=st.floats(-5.0, 5.0))
def test_omega_finite_for_any_heading(theta, y, v):
    command = vnhv_command(VnhvState(0.0, y, theta), v, UNDER, 1.0)
    assert math.isfinite(command.omega)
    assert math.isfinite(omega_eq12(VnhvState(0.0, y, theta), v, UNDER))


@pytest.mark.parametrize("theta", [math.pi / 2, -math.pi / 2, 3 * math.pi / 2, math.pi / 2 + 1e-12])
def test_singularity_pi_over_2_is_handled(theta):
    state = VnhvState(0.0, 0.7, theta)
    # eq. 12 itself tends to 0 there (the cart would cross the line for ever)
    assert abs(omega_eq12(state, 1.0, UNDER)) < 1e-9
    # the chained-form helpers refuse rather than divide by zero
    with pytest.raises(ValueError, match="pi/2"):
        to_chained(state)
    with pytest.raises(ValueError, match="pi/2"):
        m2_from_omega_eq8(0.1, theta)
    # the command: out of domain, saturated turn back towards Gamma's direction
    command = vnhv_command(state, 1.0, UNDER, omega_max=0.8)
    assert not command.in_domain
    assert command.saturated
    assert command.omega == pytest.approx(-math.copysign(0.8, wrap_angle(theta)))


def test_eq12_vanishes_continuously_near_the_singularity():
    for eps in (1e-1, 1e-2, 1e-3):
        omega = omega_eq12(VnhvState(0.0, 2.0, math.pi / 2 - eps), 1.5, UNDER)
        assert abs(omega) <= 1.5 * (UNDER.kp * 2.0 * eps**3 + UNDER.kd * eps**2) * 1.01


@pytest.mark.parametrize("theta0", [math.pi / 2, -math.pi / 2, 2.5, -3.0])
@pytest.mark.parametrize("v", [0.5, -0.5])
def test_recovers_from_outside_the_domain(theta0, v):
    """Starting across the line or facing backwards, the saturated turn brings the cart
    into the domain, and eq. 12 then takes it to the line (y, theta -> 0)."""
    seen = []

    def steer(state: VnhvState, vv: float) -> float:
        command = vnhv_command(state, vv, CRITICAL, omega_max=1.0)
        seen.append(command.in_domain)
        return command.omega

    _d, y, theta = simulate(VnhvState(0.0, 0.5, theta0), 15.0, lambda _s: v, steer)
    assert not seen[0]
    assert seen[-1]
    assert abs(y[-1]) < 1e-3
    assert abs(wrap_angle(theta[-1])) < 1e-3


@given(
    gains=gains_st,
    v=speed_st,
    y=st.floats(-5.0, 5.0),
    theta=st.floats(-1.5, 1.5),
    omega_max=st.floats(0.01, 2.0),
)
def test_limit_speed_respects_the_limit_and_keeps_direction(gains, v, y, theta, omega_max):
    state = VnhvState(0.0, y, theta)
    limited = limit_speed(v, state, gains, omega_max)
    assert math.copysign(1.0, limited) == math.copysign(1.0, v)
    assert abs(limited) <= abs(v)
    assert abs(omega_eq12(state, limited, gains)) <= omega_max * (1 + 1e-9)
    if abs(omega_eq12(state, v, gains)) <= omega_max:
        assert limited == v


def test_speed_limited_run_keeps_the_eq10_path():
    """V varying with the state (the paper's answer to saturation) leaves y(d) unchanged."""
    start = VnhvState(0.0, 1.0, 0.4)
    omega_max = 0.3
    d, y, _ = simulate(
        start,
        8.0,
        lambda s: limit_speed(2.0, s, UNDER, omega_max),
        lambda s, vv: omega_eq12(s, vv, UNDER),
    )
    assert np.max(np.abs(y - eq10_response(UNDER, 1.0, math.tan(0.4), d))) < 1e-6
    # the unlimited speed would have needed more than omega_max at the start
    assert abs(omega_eq12(start, 2.0, UNDER)) > 2 * omega_max


# -- state from poses and images -----------------------------------------------------------
def test_state_from_poses_known_geometry():
    desired = Pose2(2.0, 1.0, math.pi / 2)  # the line Gamma points along +y
    current = Pose2(1.5, -3.0, math.pi / 2 + 0.1)
    state = state_from_poses(current, desired)
    assert state.s == pytest.approx(-4.0)  # 4 m before the desired pose
    assert state.y == pytest.approx(0.5)  # to the left of +y is -x
    assert state.theta == pytest.approx(0.1)


pose_st = st.builds(
    Pose2,
    st.floats(-50.0, 50.0),
    st.floats(-50.0, 50.0),
    st.floats(-math.pi, math.pi, exclude_max=True),
)


@given(current=pose_st, desired=pose_st, v=speed_st, omega=st.floats(-1.0, 1.0))
def test_state_from_poses_is_consistent_with_eq5(current, desired, v, omega):
    state = state_from_poses(current, desired)
    back = desired @ Pose2(state.s, state.y, state.theta)
    assert (back.x, back.y) == pytest.approx((current.x, current.y), abs=1e-9)
    assert wrap_angle(back.theta - current.theta) == pytest.approx(0.0, abs=1e-9)
    # a small unicycle step of the robot changes the state by eq. 5
    dt = 1e-6
    moved = current @ Pose2(v * dt, 0.0, omega * dt)
    after = state_from_poses(moved, desired)
    rate = ((after.s - state.s) / dt, (after.y - state.y) / dt)
    expected = kinematics_eq5(state, v, omega)
    assert rate == pytest.approx(expected[:2], abs=1e-4)
    assert wrap_angle(after.theta - state.theta) / dt == pytest.approx(omega, abs=1e-4)


def _image_pose(robot: Pose2, landmark: Pose2, camera: CeilingCamera) -> Pose2:
    """Image pose (u, v, phi) of a landmark for a robot pose (eq. 1-2 inverted)."""
    in_camera = (robot @ camera.robot_from_camera).inverse() @ landmark
    k = camera.scale
    return Pose2(camera.cu + in_camera.x / k, camera.cv + in_camera.y / k, in_camera.theta)


@given(current=pose_st, desired=pose_st, landmark=pose_st, mount=pose_st)
@settings(max_examples=50)
def test_state_from_image_poses_equals_state_from_poses(current, desired, landmark, mount):
    camera = CeilingCamera(
        500.0, 320.0, 240.0, 2.5, Pose2(mount.x / 100, mount.y / 100, mount.theta)
    )
    img_now = _image_pose(current, landmark, camera)
    img_key = _image_pose(desired, landmark, camera)
    got = state_from_image_poses(img_now, img_key, camera)
    want = state_from_poses(current, desired)
    assert (got.s, got.y) == pytest.approx((want.s, want.y), abs=1e-7)
    assert wrap_angle(got.theta - want.theta) == pytest.approx(0.0, abs=1e-9)
    # §3.1's (R, t) is I_L (I_L*)^-1
    rt = image_transform_s31(img_now, img_key)
    ref = img_now @ img_key.inverse()
    assert (rt.x, rt.y) == pytest.approx((ref.x, ref.y), abs=1e-6)
    assert wrap_angle(rt.theta - ref.theta) == pytest.approx(0.0, abs=1e-9)


def test_invalid_parameters_are_refused():
    with pytest.raises(ValueError):
        VnhvGains(0.0, 1.0)
    with pytest.raises(ValueError):
        VnhvGains(1.0, -1.0)
    with pytest.raises(ValueError):
        vnhv_command(VnhvState(0, 0, 0), 1.0, UNDER, omega_max=0.0)
    with pytest.raises(ValueError):
        vnhv_command(VnhvState(0, 0, 0), 1.0, UNDER, omega_max=1.0, theta_max=math.pi / 2)
