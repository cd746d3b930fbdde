"""Spiral obstacle avoidance laws (thesis §4.2), velocity obstacles, rate limiter.

Unit tests against the equations, plus closed-loop unicycle runs in pure numpy.
"""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from behaviours.laws.rate_limit import RateLimiter, RateLimits
from behaviours.laws.spiral import (
    CCW,
    CW,
    SpiralAvoidance,
    SpiralObstacle,
    SpiralParams,
    alpha_d_dynamic,
    alpha_d_target_reaching,
    angular_velocity,
    beta_passed,
    frame_e_polar,
    lambda_weight,
    line_of_sight_rate,
    linear_velocity,
    normalised_xi,
    path_blocked,
    release_condition,
    sense_of_motion,
    should_engage,
    spiral_angle,
    spiral_centre_point,
    spiral_radius,
    target_side_som,
)
from behaviours.laws.velocity_obstacles import (
    MovingDisc,
    VoParams,
    choose_velocity,
    in_velocity_obstacle,
    time_to_collision,
    velocity_vector,
)
from executive.core.frames import Pose2

DT = 0.05


def _step(x, y, th, v, w, dt=DT):
    return x + v * math.cos(th) * dt, y + v * math.sin(th) * dt, th + w * dt


def _circle(x, y, r, **kw):
    return SpiralObstacle((x, y), size=r, shape=(x, y, r), **kw)


# -- eq. 4.1 / frame F_E ---------------------------------------------------------------------------
def test_eq_4_1_three_cases():
    r0, beta0 = 2.0, math.pi
    for som in (CCW, CW):
        beta_later = beta0 + som * 1.0  # one radian swept in the sense of motion
        assert spiral_radius(r0, math.pi / 2, beta0, beta_later, som) == pytest.approx(r0)
        assert spiral_radius(r0, 2.0, beta0, beta_later, som) > r0  # outward
        assert spiral_radius(r0, 1.0, beta0, beta_later, som) < r0  # inward
    with pytest.raises(ValueError):
        spiral_radius(r0, math.pi, beta0, beta0)


def test_constant_alpha_path_is_the_eq_4_1_spiral():
    """Kinematics of the module doc: a path with alpha_c = alpha_d constant is eq. 4.1."""
    scp = np.zeros(2)
    target = np.array([10.0, 0.0])
    for som, alpha in ((CCW, 2.0), (CW, 1.2)):
        x, y = -2.0, 0.0
        th = math.atan2(-y, -x) - som * alpha  # heading such that alpha_c = alpha
        r0, beta0 = frame_e_polar(np.array([x, y]), scp, target)
        for _ in range(400):
            pose = Pose2(x, y, th)
            assert spiral_angle(pose, scp, som) == pytest.approx(alpha, abs=1e-9)
            x, y = x + 0.002 * math.cos(th), y + 0.002 * math.sin(th)
            th = math.atan2(-y, -x) - som * alpha
        r, beta = frame_e_polar(np.array([x, y]), scp, target)
        beta_unwrapped = beta0 + som * ((som * (beta - beta0)) % (2 * math.pi))
        assert r == pytest.approx(spiral_radius(r0, alpha, beta0, beta_unwrapped, som), rel=2e-3)


def test_frame_e_and_scp():
    scp = np.array([1.0, 1.0])
    r_t, beta_t = frame_e_polar(np.array([4.0, 5.0]), scp, np.array([4.0, 5.0]))
    assert (r_t, beta_t) == pytest.approx((5.0, 0.0))  # eq. 4.2: target on x_E
    r, beta = frame_e_polar(np.array([1.0, -1.0]), scp, np.array([1.0, 5.0]))
    assert (r, beta) == pytest.approx((2.0, math.pi))  # behind the SCP
    circle = _circle(3.0, 0.0, 0.5)
    c, depth = spiral_centre_point(circle, np.zeros(2))
    assert c == pytest.approx([3.0, 0.0]) and depth == 0.5
    wall = SpiralObstacle((5.0, 0.0), size=3.0, shape=(5.0, -3.0, 5.0, 3.0))
    c, depth = spiral_centre_point(wall, np.array([0.0, 1.0]))
    assert c == pytest.approx([5.0, 1.0]) and depth == 0.0


# -- alpha_d ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("som", [CCW, CW])
@pytest.mark.parametrize("r_target", [1.2, 2.0, 3.5, 6.0])
def test_eq_4_5_spiral_passes_through_target(som, r_target):
    scp = np.array([2.0, -1.0])
    target = scp + r_target * np.array([math.cos(0.3), math.sin(0.3)])
    robot = scp + 2.0 * np.array([math.cos(0.3 + 2.8), math.sin(0.3 + 2.8)])
    r0, beta0 = frame_e_polar(robot, scp, target)
    alpha = alpha_d_target_reaching(r0, r_target, beta0, 0.0, som)
    assert 0.0 < alpha < math.pi
    beta_end = beta0 + som * ((som * (0.0 - beta0)) % (2 * math.pi))
    r_end = spiral_radius(r0, alpha, beta0, beta_end, som)
    assert r_end == pytest.approx(r_target, rel=1e-9)
    point = scp + r_end * np.array([math.cos(0.3 + beta_end), math.sin(0.3 + beta_end)])
    assert point == pytest.approx(target)
    assert (alpha > math.pi / 2) == (r_target > r0)  # farther target: outward spiral


def test_eq_4_5_closed_loop_reaches_target():
    """The robot following the eq. 4.5 spiral (no release) passes through the target."""
    params = SpiralParams(dynamic_alpha=False, target_reaching_distance=10.0)
    law = SpiralAvoidance(params)
    obstacle = _circle(0.0, 0.0, 0.5)
    target = np.array([4.0, 0.5])
    x, y, th = -2.5, 0.2, 0.0
    best = math.inf
    for _ in range(int(60 / DT)):
        out = law.command(Pose2(x, y, th), target, obstacle, DT)
        x, y, th = _step(x, y, th, out.v, out.omega)
        best = min(best, math.hypot(x - target[0], y - target[1]))
        assert obstacle.surface_distance(np.array([x, y])) > 1.0
    assert best < 0.25


def test_xi_normalisation_and_dynamic_alpha():
    assert normalised_xi(0.1, 0.14, 4.2) == 0.0  # static: below xi_min
    assert normalised_xi(-0.1, 0.14, 4.2) == 0.0
    assert normalised_xi(5.0, 0.14, 4.2) == 1.0
    assert normalised_xi(-5.0, 0.14, 4.2) == -1.0
    assert normalised_xi(2.17, 0.14, 4.2) == pytest.approx(0.5)
    assert alpha_d_dynamic(0.0) == pytest.approx(math.pi / 2)
    m = math.radians(5.0)
    assert alpha_d_dynamic(-1.0) == pytest.approx(math.pi - m)  # extrema reached (a=4, b=3)
    assert alpha_d_dynamic(1.0) == pytest.approx(m)
    xs = np.linspace(-1, 1, 101)
    alphas = [alpha_d_dynamic(x, margin=1e-6) for x in xs]
    assert all(np.diff(alphas) <= 1e-12)  # xi~ < 0 -> outward (alpha_d > pi/2)
    assert alpha_d_dynamic(-1.0, max_delta=0.5) == pytest.approx(math.pi / 2 + 0.5)


# -- eq. 4.12-4.16 ---------------------------------------------------------------------------------
def test_nu_oa_shape():
    assert linear_velocity(0.0, 0.4) == pytest.approx(0.4)
    es = np.linspace(0.0, math.pi, 50)
    vs = [linear_velocity(e, 0.4) for e in es]
    assert all(np.diff(vs) < 0) and vs[-1] == pytest.approx(0.4 * math.exp(-math.pi))
    assert linear_velocity(-0.7, 0.4) == linear_velocity(0.7, 0.4)
    assert min(vs) > 0.0  # always a non-zero speed (no local minimum)


def test_lambda_shape():
    es = np.linspace(0.0, math.pi, 50)
    lams = [lambda_weight(e, 0.2, 2.0, 0.3) for e in es]
    assert lams[0] == pytest.approx(2.0)
    assert all(np.diff(lams) < 0) and min(lams) > 0.2
    assert lambda_weight(50.0, 0.2, 2.0, 0.3) == pytest.approx(0.2)
    assert lambda_weight(-0.4, 0.2, 2.0, 0.3) == lambda_weight(0.4, 0.2, 2.0, 0.3)


def test_eq_4_14_sign_of_som():
    assert angular_velocity(CCW, 0.3, 0.5, 2.0) == pytest.approx(1.3)
    assert angular_velocity(CW, 0.3, 0.5, 2.0) == pytest.approx(-1.3)


@pytest.mark.parametrize("start_theta, som", [(0.0, CCW), (math.pi, CW)])
def test_static_alpha_keeps_the_circle(start_theta, som):
    """alpha_d = pi/2 around a static circular obstacle: r stays within a few cm of r_0."""
    law = SpiralAvoidance(SpiralParams(target_reaching=False))
    obstacle = _circle(0.0, 0.0, 0.5)
    target = np.array([20.0 * math.cos(start_theta), 0.0])
    x, y, th = 0.0, -3.0, start_theta  # tangent to the circle r_0 = 3
    rs = []
    for _ in range(int(60 / DT)):
        out = law.command(Pose2(x, y, th), target, obstacle, DT)
        assert out.som == som and out.alpha_d == pytest.approx(math.pi / 2)
        x, y, th = _step(x, y, th, out.v, out.omega)
        rs.append(math.hypot(x, y))
    assert max(abs(r - 3.0) for r in rs) < 0.03
    assert out.v == pytest.approx(0.4, abs=0.01)


# -- Algorithm 4.2 ---------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "rate, static, expected",
    [
        (0.0, CCW, CCW),  # |beta dot| < threshold: static choice
        (0.0, CW, CW),
        (0.04, CW, CW),
        (-0.04, CCW, CCW),
        (0.05, CW, CCW),  # at the threshold: the moving branch
        (0.8, CW, CCW),  # beta dot > 0: ccw
        (-0.05, CCW, CW),
        (-0.8, CCW, CW),  # beta dot < 0: cw
    ],
)
def test_algorithm_4_2_decision_table(rate, static, expected):
    assert sense_of_motion(rate, 0.05, static) == expected


def test_static_som_and_line_of_sight_rate():
    robot, obstacle = np.zeros(2), np.array([3.0, 0.0])
    assert target_side_som(robot, 0.0, obstacle, np.array([6.0, 1.0])) == CW  # target left
    assert target_side_som(robot, 0.0, obstacle, np.array([6.0, -1.0])) == CCW
    assert target_side_som(robot, 0.2, obstacle, np.array([6.0, 0.0])) == CW  # heading left
    assert target_side_som(robot, -0.2, obstacle, np.array([6.0, 0.0])) == CCW
    right_to_left = SpiralObstacle((3.0, 0.0), velocity=(0.0, 1.0), size=0.4)
    left_to_right = SpiralObstacle((3.0, 0.0), velocity=(0.0, -1.0), size=0.4)
    assert line_of_sight_rate(robot, right_to_left) == pytest.approx(1.0 / 3.0)
    assert line_of_sight_rate(robot, left_to_right) == pytest.approx(-1.0 / 3.0)
    assert line_of_sight_rate(robot, SpiralObstacle((3.0, 0.0), velocity=(2.0, 0.0))) == 0.0


# -- release guard (figure 4.15) -------------------------------------------------------------------
def test_beta_passed_half_plane():
    assert not beta_passed(math.pi)
    assert not beta_passed(3 * math.pi / 2 - 0.01)  # ccw, not yet
    assert beta_passed(3 * math.pi / 2 + 0.01)
    assert not beta_passed(math.pi / 2 + 0.01)  # cw, not yet
    assert beta_passed(math.pi / 2 - 0.01)


@pytest.mark.parametrize("r, beta", [(3.0, 3 * math.pi / 2 + 0.2), (3.3, math.pi / 2 - 0.2)])
def test_figure_4_15_release_without_re_trigger(r, beta):
    """Robots A and B of figure 4.15: still within r_OA-trigger when beta_c passes; the
    release guard lets them go and the engage guard does not catch them again."""
    params = SpiralParams()
    obstacle = _circle(0.0, 0.0, 1.0)
    target = np.array([8.0, 0.0])
    robot = r * np.array([math.cos(beta), math.sin(beta)])
    assert obstacle.surface_distance(robot) < params.r_trigger  # distance alone re-triggers
    released, reason = release_condition(beta, robot, target, obstacle, params.path_margin)
    assert released, reason
    assert not should_engage(robot, target, obstacle, params.r_trigger, params.path_margin)


def test_release_held_while_obstacle_between_robot_and_target():
    margin = 0.8
    wall = SpiralObstacle((0.0, 0.0), size=4.0, shape=(0.0, -4.0, 0.0, 4.0))
    target = np.array([5.0, 0.0])
    robot = np.array([0.0, -3.0])  # beta = 3 pi / 2 with respect to the wall's midpoint
    _, beta = frame_e_polar(robot, np.zeros(2), target)
    assert beta_passed(beta)
    released, reason = release_condition(beta, robot, target, wall, margin)
    assert not released and "between" in reason
    assert should_engage(robot, target, wall, 2.5, margin)
    # target in front of the obstacle: not in the way, however close
    obstacle = _circle(3.0, 0.0, 0.5)
    assert not path_blocked(np.zeros(2), np.array([1.5, 0.0]), obstacle, margin)
    assert path_blocked(np.zeros(2), np.array([6.0, 0.0]), obstacle, margin)


def test_release_matches_engage_along_a_whole_avoidance():
    """Whenever the law reports a release, the engage guard is false (no loop)."""
    params = SpiralParams()
    law = SpiralAvoidance(params)
    obstacle = _circle(5.0, 0.0, 0.6)
    target = np.array([12.0, 0.2])
    x, y, th = 2.0, 0.0, 0.0
    for _ in range(int(60 / DT)):
        out = law.command(Pose2(x, y, th), target, obstacle, DT)
        robot = np.array([x, y])
        if out.released:
            assert not should_engage(robot, target, obstacle, params.r_trigger, params.path_margin)
            break
        x, y, th = _step(x, y, th, out.v, out.omega)
    else:
        pytest.fail("never released")


# -- closed loop -----------------------------------------------------------------------------------
def _mission(obstacle_at, target, law, t_max=90.0):
    """Go-to-goal + spiral avoidance switched by the engage / release guards."""
    p = law.params
    x, y, th = 0.0, 0.0, 0.0
    avoiding, engagements, min_clearance = False, 0, math.inf
    for k in range(int(t_max / DT)):
        obstacle = obstacle_at(k * DT)
        robot = np.array([x, y])
        if not avoiding and should_engage(robot, target, obstacle, p.r_trigger, p.path_margin):
            avoiding, engagements = True, engagements + 1
            law.reset()
        if avoiding:
            out = law.command(Pose2(x, y, th), target, obstacle, DT)
            v, w = out.v, out.omega
            avoiding = not out.released
        else:
            e = math.remainder(math.atan2(target[1] - y, target[0] - x) - th, 2 * math.pi)
            v, w = 0.4 * max(0.0, math.cos(e)), max(-1.0, min(1.0, 2.0 * e))
        x, y, th = _step(x, y, th, v, w)
        min_clearance = min(min_clearance, obstacle.surface_distance(np.array([x, y])))
        if math.hypot(target[0] - x, target[1] - y) < 0.1:
            return True, engagements, min_clearance
    return False, engagements, min_clearance


@pytest.mark.parametrize("offset", [-0.3, 0.0, 0.3])
def test_closed_loop_static_obstacle_on_the_line(offset):
    law = SpiralAvoidance()
    obstacle = _circle(6.0, offset, 0.6)
    reached, engagements, clearance = _mission(lambda t: obstacle, np.array([13.0, 0.0]), law)
    assert reached and engagements == 1
    assert clearance > 1.5


def test_closed_loop_wall_trap_recomputes_the_scp():
    """A wall longer than r_0 (the 'trap' of figure 4.18) needs SCP recomputations."""
    law = SpiralAvoidance()
    wall = SpiralObstacle((6.0, 0.0), size=4.0, shape=(6.0, -4.0, 6.0, 4.0), ident=7)
    reached, engagements, clearance = _mission(lambda t: wall, np.array([14.0, 0.5]), law, 120)
    assert reached and engagements == 1
    assert law.recomputations >= 2
    assert clearance > 1.0


@pytest.mark.parametrize("speed", [0.5, -0.5])
def test_closed_loop_moving_obstacle_crossing(speed):
    y0 = -6.0 if speed > 0 else 6.0

    def obstacle_at(t):
        y = y0 + speed * t
        return SpiralObstacle((7.0, y), velocity=(0.0, speed), size=0.4, shape=(7.0, y, 0.4))

    law = SpiralAvoidance()
    reached, engagements, clearance = _mission(obstacle_at, np.array([14.0, 0.0]), law)
    assert reached and engagements >= 1
    assert clearance > 1.0


# -- velocity obstacles ----------------------------------------------------------------------------
def test_time_to_collision_and_cone():
    disc = MovingDisc((5.0, 0.0), (0.0, 0.0), 0.5)
    assert time_to_collision(np.zeros(2), np.array([1.0, 0.0]), disc, 0.5) == pytest.approx(4.0)
    assert time_to_collision(np.zeros(2), np.array([0.0, 1.0]), disc, 0.5) == math.inf
    assert time_to_collision(np.zeros(2), np.array([-1.0, 0.0]), disc, 0.5) == math.inf
    assert time_to_collision(np.array([4.5, 0.0]), np.zeros(2), disc, 0.5) == 0.0
    assert in_velocity_obstacle(np.zeros(2), np.array([1.0, 0.0]), disc, 0.5, 5.0)
    assert not in_velocity_obstacle(np.zeros(2), np.array([1.0, 0.0]), disc, 0.5, 3.0)
    mover = MovingDisc((5.0, -5.0), (0.0, 1.0), 0.5)  # crosses the robot's path
    assert in_velocity_obstacle(np.zeros(2), np.array([1.0, 0.0]), mover, 0.5, 10.0)


def test_vo_keeps_preferred_velocity_when_free():
    params = VoParams()
    choice = choose_velocity(np.zeros(2), 0.0, (0.8, 0.1), (), params)
    assert (choice.v, choice.omega, choice.feasible) == (pytest.approx(0.8), 0.1, True)


_discs = st.builds(
    MovingDisc,
    st.tuples(st.floats(-8, 8), st.floats(-8, 8)),
    st.tuples(st.floats(-3, 3), st.floats(-3, 3)),
    st.floats(0.1, 1.5),
)


@settings(max_examples=40, deadline=None)
@given(
    obstacles=st.lists(_discs, max_size=3).map(tuple),
    theta=st.floats(-math.pi, math.pi),
    preferred=st.tuples(st.floats(-2.0, 2.0), st.floats(-2.0, 2.0)),
    current=st.tuples(st.floats(0.0, 1.2), st.floats(-1.0, 1.0)),
)
def test_vo_choice_outside_cones_and_within_limits(obstacles, theta, preferred, current):
    params = VoParams(n_v=7, n_omega=9, max_acceleration=1.0, max_angular_acceleration=2.0)
    choice = choose_velocity(np.zeros(2), theta, preferred, obstacles, params, current, 0.1)
    assert params.v_min - 1e-12 <= choice.v <= params.v_max + 1e-12
    assert abs(choice.omega) <= params.omega_max + 1e-12
    assert abs(choice.v - current[0]) <= 0.1 + 1e-9
    assert abs(choice.omega - current[1]) <= 0.2 + 1e-9
    u = velocity_vector(theta, choice.v, choice.omega, params.heading_lead)
    inside = [
        in_velocity_obstacle(np.zeros(2), u, o, params.robot_radius, params.horizon)
        for o in obstacles
    ]
    assert choice.feasible == (not any(inside))


def test_vo_avoids_a_fast_crossing_obstacle_in_closed_loop():
    params = VoParams(max_acceleration=1.0, max_angular_acceleration=2.0)
    x, y, th, v, w = 0.0, 0.0, 0.0, 0.8, 0.0
    target = np.array([12.0, 0.0])
    for k in range(int(30 / 0.1)):
        t = k * 0.1
        cart = MovingDisc((6.0, -8.0 + 2.5 * t), (0.0, 2.5), 0.6)  # 2.5 m/s across the path
        e = math.remainder(math.atan2(target[1] - y, target[0] - x) - th, 2 * math.pi)
        preferred = (0.8 * max(0.0, math.cos(e)), max(-1.0, min(1.0, 2.0 * e)))
        choice = choose_velocity(np.array([x, y]), th, preferred, (cart,), params, (v, w), 0.1)
        v, w = choice.v, choice.omega
        x, y, th = _step(x, y, th, v, w, 0.1)
        gap = math.hypot(x - cart.position[0], y - cart.position[1]) - 0.6 - params.robot_radius
        assert gap > 0.0
        if math.hypot(target[0] - x, target[1] - y) < 0.2:
            return
    pytest.fail("target not reached")


# -- rate limiter ----------------------------------------------------------------------------------
@settings(max_examples=40, deadline=None)
@given(
    commands=st.lists(st.tuples(st.floats(-2, 2), st.floats(-2, 2)), min_size=1, max_size=40),
    jerk=st.one_of(st.none(), st.floats(0.5, 20.0)),
    dt=st.floats(0.01, 0.2),
)
def test_rate_limiter_bounds(commands, jerk, dt):
    limits = RateLimits(0.5, 1.0, jerk, max_speed=1.2, max_angular_speed=1.0)
    limiter = RateLimiter(limits)
    v0, w0, a0 = 0.0, 0.0, 0.0
    for v_cmd, w_cmd in commands:
        v, w = limiter.step(v_cmd, w_cmd, dt)
        assert abs(v - v0) <= 0.5 * dt + 1e-9
        assert abs(w - w0) <= 1.0 * dt + 1e-9
        assert abs(w) <= 1.0 + 1e-9 and abs(v) <= 1.2 + 1e-9
        if jerk is not None:
            assert abs(limiter.acceleration - a0) <= jerk * dt + 1e-9
        v0, w0, a0 = v, w, limiter.acceleration


@pytest.mark.parametrize("jerk", [None, 2.0])
def test_rate_limiter_settles_without_oscillation(jerk):
    limiter = RateLimiter(RateLimits(0.5, 1.0, jerk))
    vs = [limiter.step(0.4, -0.6, 0.05) for _ in range(200)]
    assert vs[-1] == (pytest.approx(0.4, abs=1e-3), pytest.approx(-0.6))
    speeds = [v for v, _ in vs]
    assert max(speeds) <= 0.4 + 0.01  # no overshoot to speak of
    assert all(np.diff(speeds) >= -1e-9)  # monotone approach
