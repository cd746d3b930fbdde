"""The avoidance policy (which obstacle, which mode, when it ends) on synthetic tracks,
the velocity-obstacle controller's discs, and the adversarial trolley's give-up."""

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from behaviours.controllers.avoidance import (
    DODGE,
    REPLAN,
    SPIRAL,
    AvoidanceParams,
    AvoidancePolicy,
    AvoidanceSession,
    AvoidObstacle,
    DodgeObstacle,
    obstacle_discs,
)
from behaviours.goals import Goal
from behaviours.keys import COMMAND, OBSTACLES, POSE, SENSOR_FRAME
from behaviours.laws.obstacles import is_mover, vouched_velocity
from behaviours.laws.spiral import SpiralObstacle
from executive.campaign.runner import episode_row
from executive.campaign.spec import load_campaign
from executive.compiler import CompileOptions, compile_mission
from executive.core.frames import Pose2
from executive.core.loader import load_mission
from executive.core.model import Frame
from executive.core.records import (
    Danger,
    ImuReading,
    Obstacles,
    PoseEstimate,
    SensorFrame,
    TrackedObstacle,
    WheelSpeeds,
)
from tests.conftest import MISSIONS, blackboard_writer

GOAL = Goal(Pose2(20.0, 0.0, 0.0), Frame.AIRPORT)


def pose(x: float = 0.0, y: float = 0.0, theta: float = 0.0, t: float = 0.0) -> PoseEstimate:
    p = Pose2(x, y, theta)
    return PoseEstimate(t, p, np.eye(3) * 1e-4, p, 1.0)


def track(
    ident: int,
    x: float,
    y: float,
    *,
    v: tuple[float, float] = (0.0, 0.0),
    size: float = 0.4,
    kind: str = "circle",
    danger: Danger = Danger.NONE,
    robot: Pose2 | None = None,
) -> TrackedObstacle:
    """A track given in A for a robot at ``robot`` (converted to the robot frame)."""
    robot = robot or Pose2(0.0, 0.0, 0.0)
    local = robot.inverse().apply(np.array([x, y]))
    c, s = math.cos(-robot.theta), math.sin(-robot.theta)
    vr = (c * v[0] - s * v[1], s * v[0] + c * v[1])
    clearance = max(0.0, math.hypot(*local) - size - 0.7)
    shape = (float(local[0]), float(local[1]), size) if kind == "circle" else ()
    return TrackedObstacle(
        ident, kind, (float(local[0]), float(local[1])), vr, np.eye(4), size, clearance, 2.0,
        danger, shape,
    )  # fmt: skip


def obstacles(t: float, *tracks: TrackedObstacle) -> Obstacles:
    closest = min((tr.clearance for tr in tracks), default=math.inf)
    return Obstacles(t, closest, 0.0, np.zeros((0, 2)), tracks)


def run(policy: AvoidancePolicy, frames) -> list[str | None]:
    return [policy.decide(obstacles(t, *tracks), est) for t, est, tracks in frames]


def test_an_obstacle_on_the_way_engages_the_spiral_one_beside_it_does_not():
    policy = AvoidancePolicy(GOAL, AvoidanceParams())
    assert policy.decide(obstacles(0.0, track(1, 3.0, 3.5)), pose()) is None  # beside
    assert policy.decide(obstacles(0.1, track(1, 3.0, 3.5), track(2, 3.5, 0.2)), pose()) == SPIRAL
    assert policy.session.obstacle_id == 2 and "on the way" in policy.message
    far = AvoidancePolicy(GOAL, AvoidanceParams())
    assert far.decide(obstacles(0.0, track(2, 6.0, 0.0)), pose()) is None  # beyond r_OA


def test_a_fast_obstacle_is_dodged_and_a_slow_one_spiralled():
    fast = AvoidancePolicy(GOAL, AvoidanceParams())
    assert fast.decide(obstacles(0.0, track(1, 3.0, 0.0, v=(-0.8, 0.0))), pose()) == DODGE
    slow = AvoidancePolicy(GOAL, AvoidanceParams())
    assert slow.decide(obstacles(0.0, track(1, 3.0, 0.0, v=(0.1, 0.0))), pose()) == SPIRAL


def test_a_trolley_coming_from_the_side_engages_early_and_even_at_the_goal():
    side = track(1, 3.0, 4.0, v=(0.0, -0.7), danger=Danger.ON_PATH)
    assert side.clearance > 2.5  # beyond r_OA, but met 2 s of its motion earlier
    policy = AvoidancePolicy(GOAL, AvoidanceParams())
    assert policy.decide(obstacles(0.0, side), pose()) == DODGE
    at_goal = AvoidancePolicy(GOAL, AvoidanceParams())
    robot = pose(19.5, 0.0)
    parked = track(2, 21.5, 0.0, robot=robot.pose_a)
    coming = track(3, 19.5, 3.0, v=(0.0, -0.7), danger=Danger.IMMINENT, robot=robot.pose_a)
    assert at_goal.decide(obstacles(0.0, parked), robot) is None
    assert at_goal.message == "at the goal"
    assert at_goal.decide(obstacles(0.1, parked, coming), robot) == DODGE


def test_velocity_obstacles_end_once_the_obstacle_is_off_the_path():
    policy = AvoidancePolicy(GOAL, AvoidanceParams(clear_after=1.0))
    assert policy.decide(obstacles(0.0, track(1, 3.0, 0.0, v=(0.0, 0.8))), pose()) == DODGE
    gone = track(1, 3.0, 3.0, v=(0.0, 0.8))
    modes, messages = [], []
    for k in range(1, 15):
        modes.append(policy.decide(obstacles(0.1 * k, gone), pose()))
        messages.append(policy.message)
    assert modes[:9] == [DODGE] * 9 and modes[-1] is None
    assert "off the path" in messages[modes.index(None)]


def test_a_released_obstacle_does_not_engage_again_at_once():
    """No re-trigger loop (figure 4.15): after a release the same obstacle is held off."""
    policy = AvoidancePolicy(GOAL, AvoidanceParams(hold_off=3.0))
    blocking = track(1, 3.5, 0.0)
    assert policy.decide(obstacles(0.0, blocking), pose()) == SPIRAL
    policy.session.released, policy.session.reason = True, "beta_c past the release angle"
    assert policy.decide(obstacles(0.1, blocking), pose()) is None
    assert policy.decide(obstacles(0.2, blocking), pose()) is None
    assert policy.decide(obstacles(3.2, blocking), pose()) == SPIRAL
    assert policy.session.count == 2


def test_no_progress_for_trapped_after_hands_over_to_the_planner():
    policy = AvoidancePolicy(GOAL, AvoidanceParams(trapped_after=5.0))
    wall = track(1, 3.5, 0.0, size=0.9)
    modes = [policy.decide(obstacles(0.5 * k, wall), pose()) for k in range(12)]
    assert modes[:11] == [SPIRAL] * 11 and modes[11] == REPLAN
    assert "trapped" in policy.message
    # progress towards the goal resets the clock
    moving = AvoidancePolicy(GOAL, AvoidanceParams(trapped_after=5.0))
    modes = [
        moving.decide(obstacles(0.5 * k, track(1, 3.5, 0.0, robot=Pose2(0.3 * k, 0.0, 0.0))),
                      pose(0.3 * k, 0.0))
        for k in range(12)
    ]  # fmt: skip
    assert REPLAN not in modes


def test_what_follows_the_planner_gets_a_trap_clock_of_its_own():
    """A planner that ends (no path on the costmap, or the end of its path) leaves the
    avoidance that follows a fresh ``trapped_after``: sharing the clock sent the robot
    straight back to a planner that found no path, every half second, while a slow
    trolley walked into it (campaign episode 487)."""
    params = AvoidanceParams(trapped_after=5.0, hold_off=3.0)
    policy = AvoidancePolicy(GOAL, params)
    wall = track(1, 2.6, 0.0, size=0.9)  # closer than r_OA / 2: never held off
    modes = [policy.decide(obstacles(0.5 * k, wall), pose()) for k in range(12)]
    assert modes[-1] == REPLAN
    policy.session.released, policy.session.reason = True, "no path on the costmap"
    assert policy.decide(obstacles(6.0, wall), pose()) is None
    after = [policy.decide(obstacles(6.5 + 0.5 * k, wall), pose()) for k in range(14)]
    assert after[:10] == [SPIRAL] * 10  # 5 s of its own...
    assert after[-1] == REPLAN  # ...before it is trapped again


def test_a_big_static_obstacle_whose_centroid_slides_is_not_taken_for_a_mover():
    policy = AvoidancePolicy(GOAL, AvoidanceParams())
    truck = track(1, 4.0, 0.0, v=(0.0, 0.3), size=2.5, kind="blob")
    assert policy.decide(obstacles(0.0, truck), pose()) == SPIRAL


def line(
    ident: int, x: float, y: float, v: tuple[float, float], *, measured: bool
) -> TrackedObstacle:
    """A 1.4 m line track along A's y axis (a trolley's side face) centred at (x, y), for
    a robot at the origin facing +x; ``measured``: its motion along itself was measured
    (both ends seen)."""
    clearance = max(0.0, x - 0.7 - 0.7)
    return TrackedObstacle(
        ident, "line", (x, y), v, np.eye(4), 0.7, clearance, 5.0, Danger.NONE,
        (x, y - 0.7, x, y + 0.7), motion_measured=measured,
    )  # fmt: skip


def test_a_line_counts_its_motion_along_itself_only_once_measured():
    """The aperture problem: a line followed in part has no vouched motion along itself
    (a wall's visible part slides with the view), one whose ends were seen has."""
    for measured in (False, True):
        across = line(1, 3.0, 0.0, (0.5, 0.0), measured=measured)
        assert vouched_velocity(across) == pytest.approx((0.5, 0.0))
    along = line(1, 3.0, 0.0, (0.0, 0.5), measured=False)
    assert vouched_velocity(along) == pytest.approx((0.0, 0.0))
    assert not is_mover(along)
    seen_whole = line(1, 3.0, 0.0, (0.0, 0.5), measured=True)
    assert vouched_velocity(seen_whole) == pytest.approx((0.0, 0.5))
    assert is_mover(seen_whole)


def test_a320_campaign_episode_55_a_trolley_rolling_along_its_face_misses_the_robot():
    """The episode behind the test below, until well after the trolley has passed: it
    struck the robot's rear at 21.8 s (its track said 0.17 m/s); it is dodged now."""
    campaign = load_campaign(MISSIONS / "campaigns" / "a320-busy-apron.xml")
    row = episode_row(campaign, 55, max_time=35.0)
    assert row["outcome"] != "crashed", row["first_cause"]
    assert row["collisions"] == [], row["causes"]


def test_a_trolley_rolling_along_its_own_face_at_the_robot_is_dodged():
    """A trolley rolls at 1.15 m/s along its side face, seen as a line with both ends in
    view, into the robot's way (A320 busy-apron campaign episode 55: counted at its
    across-line 0.17 m/s, it was left to the spiral and struck the robot). Its measured
    motion is a collision course: velocity obstacles. The same line followed only in
    part says nothing about its motion along itself."""
    coming = line(1, 3.0, 3.0, (0.0, -1.15), measured=True)
    policy = AvoidancePolicy(GOAL, AvoidanceParams())
    assert policy.decide(obstacles(0.0, coming), pose()) == DODGE
    unmeasured = AvoidancePolicy(GOAL, AvoidanceParams())
    assert (
        unmeasured.decide(obstacles(0.0, line(1, 3.0, 3.0, (0.0, -1.15), measured=False)), pose())
        != DODGE
    )


@settings(max_examples=40, deadline=None)
@given(st.floats(-5, 5), st.floats(-5, 5), st.floats(-5, 5), st.floats(-5, 5), st.floats(0.2, 0.6))
def test_line_discs_cover_the_segment(x0, y0, x1, y1, spacing):
    line = SpiralObstacle(((x0 + x1) / 2, (y0 + y1) / 2), (0.0, 0.0), 1.0, (x0, y0, x1, y1))
    discs = obstacle_discs(line, spacing)
    for s in np.linspace(0.0, 1.0, 50):
        p = np.array([x0 + s * (x1 - x0), y0 + s * (y1 - y0)])
        assert min(np.hypot(*(p - d.position)) - d.radius for d in discs) <= 1e-9


def test_a_chaser_on_a_collision_course_engages_velocity_obstacles_from_behind():
    """A walker coming at the robot from behind is neither on the way to the goal nor on
    the robot's path ahead, but its motion meets the robot's (driving on, or standing):
    velocity obstacles take over, and stay on while it keeps coming."""
    chaser = track(1, -3.0, -1.0, v=(0.5, 0.15))
    assert chaser.danger == Danger.NONE and chaser.clearance < 2.5 + 2.0 * 0.5
    policy = AvoidancePolicy(GOAL, AvoidanceParams())
    assert policy.decide(obstacles(0.0, chaser), pose()) == DODGE
    for k in range(1, 15):  # it follows the robot: never harmless
        assert policy.decide(obstacles(0.1 * k, chaser), pose()) == DODGE
    walking_away = AvoidancePolicy(GOAL, AvoidanceParams())
    assert walking_away.decide(obstacles(0.0, track(1, -3.0, -1.0, v=(-0.5, 0.0))), pose()) is None


def test_the_spiral_hands_over_to_velocity_obstacles_when_anything_comes_too_close():
    """The spiral steers round one obstacle; another one within ``too_close`` (r_ES +
    0.3 m in the compiled tree) hands over to velocity obstacles, which see every
    obstacle; the spiral comes back only with ``too_close_hysteresis`` to spare."""
    params = AvoidanceParams(too_close=0.9, too_close_hysteresis=0.5)
    policy = AvoidancePolicy(GOAL, params)
    ahead = track(1, 3.5, 0.0)
    assert policy.decide(obstacles(0.0, ahead), pose()) == SPIRAL
    beside = track(2, 0.0, -2.0)  # 0.9 m: not on the way, but too close
    assert beside.clearance == pytest.approx(0.9)
    assert policy.decide(obstacles(0.1, ahead, track(2, 0.0, -1.95)), pose()) == DODGE
    assert policy.session.obstacle_id == 2 and "< 0.90 m" in policy.message


def test_the_spiral_moves_to_a_closer_obstacle_on_the_way():
    policy = AvoidancePolicy(GOAL, AvoidanceParams(closer_by=0.3))
    assert policy.decide(obstacles(0.0, track(1, 3.4, 0.3)), pose()) == SPIRAL
    nearer = track(2, 2.6, -0.2)
    assert policy.decide(obstacles(0.1, track(1, 3.4, 0.3), nearer), pose()) == SPIRAL
    assert policy.session.obstacle_id == 2 and "closer than obstacle 1" in policy.message


def test_back_to_back_avoidances_share_the_trap_clock():
    """An engage/release loop that makes no progress ends in the planner: an avoidance
    that starts within ``hold_off`` of the last one keeps its trap clock."""
    params = AvoidanceParams(trapped_after=5.0, hold_off=1.0)
    policy = AvoidancePolicy(GOAL, params)
    modes = []
    for k in range(30):
        t = 0.25 * k
        ident = 1 + (k // 4) % 2  # two obstacles taking turns in the way
        mode = policy.decide(obstacles(t, track(ident, 3.5, 0.0)), pose())
        modes.append(mode)
        if mode == SPIRAL and k % 4 == 3:
            policy.session.released, policy.session.reason = True, "released"
    assert REPLAN in modes
    assert modes.index(REPLAN) * 0.25 <= 5.0 + 1.0 + 0.25


def test_a_slow_walker_crossing_in_front_is_dodged_one_walking_off_is_not():
    """Between slow_speed and fast_speed the spiral would be chosen by speed alone; a walker
    crossing the robot's way at 0.12 m/s is on a collision course (the spiral would let it
    walk into the robot), one walking off the track is not."""
    crossing = track(1, 3.0, -2.2, v=(0.0, 0.12))
    assert crossing.clearance < 2.5 + 2.0 * 0.12
    policy = AvoidancePolicy(GOAL, AvoidanceParams())
    assert policy.decide(obstacles(0.0, crossing), pose()) == DODGE
    leaving = AvoidancePolicy(GOAL, AvoidanceParams())
    assert leaving.decide(obstacles(0.0, track(1, 3.0, -2.2, v=(0.0, -0.12))), pose()) is None


def test_the_compiled_velocity_obstacles_never_dodge_slower_than_the_cruise_speed():
    """A robot that slows down to dodge a slow walker crossing its way stays in that
    walker's way for longer (campaign episode 190: a 0.14 m/s trolley): the compiler
    gives every velocity-obstacle controller the navigation's cruise speed as its
    floor."""
    mission = load_mission(MISSIONS / "track" / "avoidance-leg.xml")
    root = compile_mission(mission, CompileOptions(avoidance=True)).root
    dodges = [node for node in root.iterate() if isinstance(node, DodgeObstacle)]
    assert dodges
    assert all(d.nu_min == mission.navigation.cruise_speed for d in dodges)


def test_only_a_mover_faster_than_fast_speed_takes_the_robot_from_the_planner():
    """The planner plans round where the slower movers will be (their sweep is in its
    costmap, ``test_fallback_planner.py``): a slow trolley (0.11 m/s) coming while it
    drives leaves the robot to it (campaign episodes 375 and 976: a slow chaser took the
    robot from the planner to velocity obstacles, which stood, again and again until the
    timeout). A trolley faster than ``fast_speed`` on a collision course hands over to
    velocity obstacles (campaign episode 122: one walked into the robot), which get a
    trap clock of their own, so the two do not alternate while it keeps coming."""
    p = AvoidanceParams(trapped_after=5.0)
    policy = AvoidancePolicy(GOAL, p)
    wall = track(1, 3.5, 0.0, size=0.9)
    modes = [policy.decide(obstacles(0.5 * k, wall), pose()) for k in range(12)]
    assert modes[-1] == REPLAN
    slow = track(2, 2.0, -2.2, v=(0.0, 0.11), size=0.7)
    modes = [policy.decide(obstacles(6.0 + 0.1 * k, wall, slow), pose()) for k in range(30)]
    assert modes == [REPLAN] * 30
    fast = track(2, 2.0, -2.2, v=(0.0, 2.0 * p.fast_speed), size=0.7)
    after, messages = [], []
    for k in range(120):  # 12 s: more than twice trapped_after
        after.append(policy.decide(obstacles(9.0 + 0.1 * k, wall, fast), pose()))
        messages.append(policy.message)
    first = after.index(DODGE)  # once its low-passed speed says it is fast (< 1 s)
    assert first < 10 and "while the planner drives" in messages[first]
    assert after[:first] == [REPLAN] * first and after[first:] == [DODGE] * (120 - first)


def test_velocity_obstacles_remember_how_fast_a_track_was():
    """A chaser passing a static obstacle merges with it into one cluster and its track's
    velocity collapses for a moment (campaign episode 199): for ``velocity_memory``
    seconds the controller keeps the speed it had, in the direction the track moves
    now (or the old velocity when it seems to stand), then believes the track again."""
    mission = load_mission(MISSIONS / "track" / "avoidance-leg.xml")
    dodge = DodgeObstacle(GOAL, AvoidanceSession(margin=1.4), mission.platform, 0.02)
    chaser = SpiralObstacle((3.0, 0.0), (-0.45, 0.0), 0.4, ident=7)
    assert dodge._remembered(chaser, 0.0) == chaser
    merged = dataclasses.replace(chaser, velocity=(-0.06, -0.08), size=0.9)
    kept = dodge._remembered(merged, 0.5)
    assert kept.speed == pytest.approx(0.45)
    assert kept.velocity[0] / kept.velocity[1] == pytest.approx(0.06 / 0.08)
    standing = dodge._remembered(dataclasses.replace(chaser, velocity=(0.0, 0.01)), 1.0)
    assert standing.velocity == chaser.velocity
    later = dataclasses.replace(chaser, velocity=(-0.1, 0.0))
    assert dodge._remembered(later, 1.6) == later  # the memory is over
    other = SpiralObstacle((3.0, 1.0), (0.0, 0.0), 0.4, ident=8)  # per track
    assert dodge._remembered(other, 1.6) == other


@pytest.mark.usefixtures("fresh_blackboard")
def test_velocity_obstacles_reverse_from_a_chaser_as_fast_as_they_would_drive():
    """A walker comes head-on at 1.5 m/s, 3.5 m ahead: turning away takes too long, and
    backing off at 1 m/s (the old cap on reversing) lets it close within the horizon
    (A320 campaign episode 65: caught backing away from a 1.2 m/s trolley at 1 m/s,
    while the safety layer's retreat that followed backed off at up to 1.64 m/s). The
    controller reverses as fast as it would drive forwards (the escape factor x the
    walker's speed, within the platform's), and that way out is clear."""
    mission = load_mission(MISSIONS / "track" / "avoidance-leg.xml")
    bb = blackboard_writer(OBSTACLES, POSE, COMMAND)
    chaser = track(1, 3.5, 0.0, v=(-1.5, 0.0), size=0.3)
    choices = {}
    for cap in (None, 1.0):
        session = AvoidanceSession(margin=1.4, obstacle_id=1, mode=DODGE)
        dodge = DodgeObstacle(GOAL, session, mission.platform, 0.02, reverse_max=cap)
        dodge.setup()
        dodge.initialise()
        bb.set(POSE.name, pose(t=0.5), overwrite=True)
        bb.set(OBSTACLES.name, obstacles(0.5, chaser), overwrite=True)
        dodge.tick_once()
        choices[cap] = dodge.last
    fast, capped = choices[None], choices[1.0]
    assert fast.reverse and fast.feasible and fast.speed > 1.0
    assert abs(math.remainder(fast.heading - math.pi, 2 * math.pi)) < math.radians(45)
    assert not capped.feasible  # at 1 m/s no way out was clear


def test_a_dodge_handed_back_for_slowing_down_needs_fast_speed_to_come_back():
    """Hysteresis between the two switches (campaign episode 141: a trolley standing in
    the way, its speed estimate hovering about ``slow_speed``, switched velocity obstacles
    and the spiral every second for 15 s and the robot never got past). Once a dodge has
    handed a track back to the spiral because it slowed, a collision course at a speed
    between ``slow_speed`` and ``fast_speed`` keeps the spiral; faster than
    ``fast_speed``, it is dodged again."""
    p = AvoidanceParams()
    policy = AvoidancePolicy(GOAL, p)
    crossing = track(1, 3.0, -2.2, v=(0.0, 0.3))
    assert policy.decide(obstacles(0.0, crossing), pose()) == DODGE
    stopped = track(1, 3.0, -0.5, v=(0.0, 0.0))
    modes = [policy.decide(obstacles(0.1 * k, stopped), pose()) for k in range(1, 40)]
    assert modes[-1] == SPIRAL and "slowed" in policy.message
    jitter = track(1, 3.0, -0.5, v=(0.0, 0.5 * (p.slow_speed + p.fast_speed)))
    modes = [policy.decide(obstacles(4.0 + 0.1 * k, jitter), pose()) for k in range(40)]
    assert modes == [SPIRAL] * 40
    walks = track(1, 3.0, -0.5, v=(0.0, 2.0 * p.fast_speed))
    modes = [policy.decide(obstacles(8.0 + 0.1 * k, walks), pose()) for k in range(20)]
    assert modes[-1] == DODGE
    # the same collision course at the in-between speed, never handed back: dodged
    fresh = AvoidancePolicy(GOAL, p)
    first = track(1, 3.0, -0.5, v=(0.0, 0.5 * (p.slow_speed + p.fast_speed)))
    assert fresh.decide(obstacles(0.0, first), pose()) == DODGE


def test_velocity_obstacles_standing_among_static_obstacles_are_trapped_at_once():
    """Velocity obstacles that find no admissible motion (the robot stands) for
    ``stalled_after`` with nothing around faster than ``fast_speed`` hand over to the
    planner long before ``trapped_after``: obstacles that stand do not step aside
    (campaign episodes 652, 889, 890 waited 20 s each). A robot that moves again, or a
    mover still coming, keeps the dodge."""
    params = AvoidanceParams(stalled_after=3.0, trapped_after=20.0)
    policy = AvoidancePolicy(GOAL, params)
    near = track(1, 2.0, 0.1)  # the walker stopped in the way, too close to spiral
    assert policy.decide(obstacles(0.0, track(1, 3.0, -1.0, v=(0.0, 0.4))), pose()) == DODGE
    modes, messages = [], []
    for k in range(1, 60):  # the walker stopped; the controller finds no way out
        t = 0.1 * k
        if t >= 1.0 and policy.session.stalled_since is None:
            policy.session.stalled_since = t
        modes.append(policy.decide(obstacles(t, near), pose()))
        messages.append(policy.message)
    first = modes.index(REPLAN)
    assert 0.1 * (first + 1) == pytest.approx(4.0)  # stalled at 1.0 s, plus 3 s
    assert "velocity obstacles found no way" in messages[first]
    # moving again restarts the stall clock: no planner
    moving = AvoidancePolicy(GOAL, params)
    assert moving.decide(obstacles(0.0, track(1, 3.0, -1.0, v=(0.0, 0.4))), pose()) == DODGE
    modes = []
    for k in range(1, 60):
        t = 0.1 * k
        moving.session.stalled_since = None if k % 20 == 0 else moving.session.stalled_since or t
        modes.append(moving.decide(obstacles(t, near), pose()))
    assert REPLAN not in modes
    # a walker that keeps coming is no trap however long the robot stands
    coming = AvoidancePolicy(GOAL, params)
    walker = track(1, 3.0, -1.0, v=(0.0, 0.4))
    assert coming.decide(obstacles(0.0, walker), pose()) == DODGE
    coming.session.stalled_since = 0.0
    modes = [coming.decide(obstacles(0.1 * k, walker), pose()) for k in range(1, 60)]
    assert REPLAN not in modes


@pytest.mark.usefixtures("fresh_blackboard")
def test_the_velocity_obstacle_controller_reports_when_it_stands():
    """:class:`DodgeObstacle` marks the session stalled while its chosen speed is zero
    (hemmed in by static obstacles closer than its disc), and clears it once it moves."""
    mission = load_mission(MISSIONS / "track" / "avoidance-leg.xml")
    session = AvoidanceSession(margin=1.4, obstacle_id=1, mode=DODGE)
    dodge = DodgeObstacle(GOAL, session, mission.platform, 0.02)
    bb = blackboard_writer(OBSTACLES, POSE, COMMAND)
    dodge.setup()
    dodge.initialise()
    angles = np.linspace(0.0, 2 * math.pi, 12, endpoint=False)
    ring = [track(k, 1.9 * math.cos(a), 1.9 * math.sin(a), size=0.3) for k, a in enumerate(angles)]
    bb.set(POSE.name, pose(t=0.5), overwrite=True)
    bb.set(OBSTACLES.name, obstacles(0.5, *ring), overwrite=True)
    dodge.tick_once()
    assert dodge.last.speed == 0.0 and session.stalled_since == 0.5
    bb.set(OBSTACLES.name, obstacles(0.6, *ring), overwrite=True)
    dodge.tick_once()
    assert session.stalled_since == 0.5  # since then, not reset every tick
    bb.set(OBSTACLES.name, obstacles(0.7, track(1, 6.0, 3.0)), overwrite=True)
    dodge.tick_once()
    assert dodge.last.speed > 0.0 and session.stalled_since is None


def test_campaign_episode_527_escapes_at_the_speed_it_will_get():
    """Episode 527 of the shipped avoidance campaign: a trolley crossing at 0.11 m/s, a
    vehicle parked beyond it. Velocity obstacles backed away from the trolley towards the
    vehicle at a commanded 0.2 m/s that the safety layer's slowdown zone cut to 0.05 m/s,
    and the trolley ran into the robot. Judged at the speed each way out really gets,
    the escape keeps ahead: the episode completes with no collision."""
    campaign = load_campaign(MISSIONS / "campaigns" / "avoidance-leg.xml")
    row = episode_row(campaign, 527)
    assert row["succeeded"], row["causes"]
    assert row["collisions"] == []


@pytest.mark.usefixtures("fresh_blackboard")
@settings(max_examples=30, deadline=None)
@given(
    controller=st.sampled_from(["spiral", "velocity obstacles"]),
    v=st.floats(-1.0, 1.2),
    omega=st.floats(-0.5, 0.5),
    imu=st.booleans(),
    chaser=st.floats(-6.0, 6.0),
)
def test_an_avoidance_takes_over_from_the_motion_the_robot_has(controller, v, omega, imu, chaser):
    """The avoidance controllers' first command is one tick's acceleration away from the
    motion the robot has when they take over (its wheels, its IMU's yaw rate), whatever
    the law asks: started from rest, velocity obstacles told a robot fleeing a chaser at
    1.2 m/s to drive at 0.02 m/s, and the drive base braked it into the chaser's way
    (A320 busy-apron campaign episode 66, three times in one run)."""
    mission = load_mission(MISSIONS / "track" / "avoidance-leg.xml")
    platform = mission.platform
    session = AvoidanceSession(margin=1.4, obstacle_id=1)
    if controller == "spiral":
        session.mode = SPIRAL
        node = AvoidObstacle(GOAL, session, platform, 0.02)
    else:
        session.mode = DODGE
        node = DodgeObstacle(GOAL, session, platform, 0.02)
    bb = blackboard_writer(OBSTACLES, POSE, COMMAND, SENSOR_FRAME)
    track_width = platform.odometry_track
    half = 0.5 * omega * track_width
    frame = SensorFrame(
        1.0,
        wheels=WheelSpeeds(1.0, v - half, v + half),
        imu=ImuReading(1.0, omega) if imu else None,
    )
    bb.set(SENSOR_FRAME.name, frame, overwrite=True)
    bb.set(POSE.name, pose(t=1.0), overwrite=True)
    bb.set(OBSTACLES.name, obstacles(1.0, track(1, chaser, 0.5, v=(1.2, 0.0))), overwrite=True)
    node.setup()
    node.tick_once()
    command = bb.get(COMMAND.name)
    assert abs(command.v - v) <= platform.max_acceleration * 0.02 + 1e-9
    assert abs(command.omega - omega) <= platform.max_angular_acceleration * 0.02 + 1e-9


@pytest.mark.usefixtures("fresh_blackboard")
def test_an_avoidance_without_wheel_speeds_starts_from_rest():
    """No wheel speeds read yet: the limiter starts from rest (the one motion it may
    assume), so the first command is within one tick's acceleration of a stop."""
    mission = load_mission(MISSIONS / "track" / "avoidance-leg.xml")
    session = AvoidanceSession(margin=1.4, obstacle_id=1, mode=DODGE)
    node = DodgeObstacle(GOAL, session, mission.platform, 0.02)
    bb = blackboard_writer(OBSTACLES, POSE, COMMAND, SENSOR_FRAME)
    bb.set(SENSOR_FRAME.name, SensorFrame(1.0), overwrite=True)
    bb.set(POSE.name, pose(t=1.0), overwrite=True)
    bb.set(OBSTACLES.name, obstacles(1.0, track(1, -3.0, 0.0, v=(1.2, 0.0))), overwrite=True)
    node.setup()
    node.tick_once()
    command = bb.get(COMMAND.name)
    assert abs(command.v) <= mission.platform.max_acceleration * 0.02 + 1e-9
