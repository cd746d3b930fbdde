"""Static structure is not reported as moving (issue 12, section 5).

A line seen only in part (a wall longer than the view, or cut by something in front) shows
a visible part that changes as the robot moves; tracked by the middle of that part, a
static wall slid along itself at up to the robot's speed (the empty lab's fence at
0.19 m/s, enough to engage avoidance). The tracker now measures a line across itself, and
along itself only when both its ends are the object's true ends
(:mod:`behaviours.laws.tracking`, :func:`behaviours.laws.laser_clusters.line_ends_visible`).

Three levels: the law on synthetic scans (hypothesis: random static lines seen in part
from a moving robot stay still; moving lines and circles keep their speed), the worst case
(driving along a long wall), and every shipped scenario in sim2d: the robot follows its
route for a bounded time and no static obstacle's track within reach of the danger
levels exceeds 0.1 m/s at p99.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from behaviours.laws.laser_clusters import ScanClusterer
from behaviours.laws.obstacles import vouched_velocity
from behaviours.laws.tracking import DangerParams, ObstacleTracker
from executive.core.frames import Pose2, wrap_angle
from executive.core.records import TrackedObstacle, VelocityCommand
from executive.dryrun import dry_run
from executive.report import TRACK_SETTLED_AGE, avoidance_metrics
from sim2d.raycast import Scene
from sim2d.robot import SimRobot
from sim2d.scenario import load_scenario
from sim2d.view import route_points
from tests.conftest import MISSIONS
from tests.test_obstacle_perception import LENGTH, WIDTH, scan_pair

#: the bound of the issue: no static obstacle's track faster than this at p99 (m/s)
STATIC_SPEED = 0.1
RATE = 40.0  # the scans' rate (Hz)


def track_scene(
    scene_at: object, robot_at: object, seconds: float, seed: int = 0
) -> list[tuple[float, Pose2, tuple[TrackedObstacle, ...]]]:
    """Scans of ``scene_at(t)`` from the robot at ``robot_at(t)`` (world poses), 40 Hz,
    through the clusterer and the tracker (given the true pose): (t, pose, tracks)."""
    rng = np.random.default_rng(seed)
    clusterer = ScanClusterer(LENGTH, WIDTH)
    tracker = ObstacleTracker(DangerParams(LENGTH, WIDTH))
    out = []
    for k in range(round(seconds * RATE)):
        t = k / RATE
        robot = robot_at(t)  # type: ignore[operator]
        scans = scan_pair(scene_at(t), robot, rng=rng, stamp=t)  # type: ignore[operator]
        out.append((t, robot, tracker.update(clusterer.detect(scans), robot)))
    return out


def world_velocity(track: TrackedObstacle, robot: Pose2) -> np.ndarray:
    return robot.rotation() @ np.array(track.velocity)


def straight(v: float, heading: float = 0.0, x0: float = 0.0, y0: float = 0.0) -> object:
    c, s = math.cos(heading), math.sin(heading)
    return lambda t: Pose2(x0 + v * t * c, y0 + v * t * s, heading)


# -- the worst case: driving along a long wall ---------------------------------------------------
@pytest.mark.parametrize("side", [1.5, -3.0], ids=["wall-1.5m-left", "wall-3m-right"])
def test_driving_along_a_long_wall_does_not_move_it(side: float) -> None:
    """A 200 m wall beside the robot, driving along it at 1 m/s for 15 s: the view of it
    is a window that moves with the robot (both its ends are cut: the grazing incidence
    far ahead and behind), whose middle slides at exactly the robot's speed."""
    wall = Scene(segments=[(-100.0, side, 100.0, side)])
    samples = track_scene(lambda t: wall, straight(1.0), 15.0)
    speeds = [
        float(np.hypot(*world_velocity(o, robot)))
        for t, robot, tracks in samples
        for o in tracks
        if t > 0.5
    ]
    kinds = {o.kind for _, _, tracks in samples for o in tracks}
    assert kinds == {"line"} and len(speeds) > 500
    assert max(speeds) < STATIC_SPEED


def test_a_wall_cut_by_a_pillar_in_front_does_not_move() -> None:
    """A wall behind a pillar: the pillar's shadow on the wall moves as the robot drives
    past, cutting the wall in two pieces whose visible parts change every scan."""
    scene = Scene(segments=[(-5.0, 6.0, 25.0, 6.0)], circles=[(8.0, 3.0, 0.4)])
    samples = track_scene(lambda t: scene, straight(1.0), 15.0, seed=3)
    speeds = [
        float(np.hypot(*world_velocity(o, robot)))
        for t, robot, tracks in samples
        for o in tracks
        if t > 0.5
    ]
    assert len(speeds) > 500
    assert float(np.percentile(speeds, 99)) < STATIC_SPEED


# -- properties of the law -----------------------------------------------------------------------
@settings(max_examples=12, deadline=None)
@given(
    length=st.floats(6.0, 60.0),
    start=st.floats(-10.0, 8.0),
    distance=st.floats(1.5, 8.0),
    angle=st.floats(0.0, 0.5),
    speed=st.floats(0.3, 1.5),
    omega=st.floats(-0.08, 0.0),
    seed=st.integers(0, 2**16),
)
def test_a_static_line_seen_in_part_from_a_moving_robot_stays_still(
    length: float,
    start: float,
    distance: float,
    angle: float,
    speed: float,
    omega: float,
    seed: int,
) -> None:
    """Random wall (where it starts along the robot's course, how far to the left, its
    length and its angle away from the course) and robot motion (a straight line, or an
    arc turning away from the wall): every confirmed track of the wall, once it is 1 s
    old, moves at less than 0.1 m/s, however the visible part of the wall changes."""
    x0, y0 = start, distance
    wall = Scene(segments=[(x0, y0, x0 + length * math.cos(angle), y0 + length * math.sin(angle))])

    def robot_at(t: float) -> Pose2:
        if abs(omega) < 1e-6:
            return Pose2(speed * t, 0.0, 0.0)
        th = omega * t
        return Pose2(speed * math.sin(th) / omega, speed * (1 - math.cos(th)) / omega, th)

    samples = track_scene(lambda t: wall, robot_at, 8.0, seed=seed)
    speeds = [
        float(np.hypot(*world_velocity(o, robot)))
        for _, robot, tracks in samples
        for o in tracks
        if o.age >= 1.0
    ]
    assert speeds, "the wall was never tracked"
    assert max(speeds) < STATIC_SPEED


@settings(max_examples=12, deadline=None)
@given(
    shape=st.sampled_from(["line", "circle"]),
    heading=st.floats(-math.pi, math.pi),
    tilt=st.floats(-0.8, 0.8),
    speed=st.floats(0.3, 1.5),
    robot_speed=st.sampled_from([0.0, 0.8]),
    seed=st.integers(0, 2**16),
)
def test_a_moving_line_or_circle_keeps_its_speed(
    shape: str, heading: float, tilt: float, speed: float, robot_speed: float, seed: int
) -> None:
    """A trolley face (a 1.2 m segment facing the robot within 45 deg, its two ends
    seen) or a walker (0.3 m circle) crossing 7 m ahead in any direction at 0.3-1.5 m/s,
    the robot standing or driving: once the track is 1.5 s old its velocity is within
    0.15 m/s of the truth at the median, 0.35 m/s at worst (the line model must not cost
    the movers their speed: the motion along a face is measured through its ends)."""
    vel = speed * np.array([math.cos(heading), math.sin(heading)])
    start = np.array([7.0, 0.0]) - 1.5 * vel  # in front of the robot mid-run

    def scene_at(t: float) -> Scene:
        p = start + vel * t
        if shape == "circle":
            return Scene(circles=[(*p, 0.3)])
        robot = robot_at(t)
        bearing = math.atan2(p[1] - robot.y, p[0] - robot.x)  # the face across the view
        d = np.array([-math.sin(bearing + tilt), math.cos(bearing + tilt)]) * 0.6
        return Scene(segments=[(*(p - d), *(p + d))])

    robot_at = straight(robot_speed)

    samples = track_scene(scene_at, robot_at, 3.0, seed=seed)
    errors = []
    for t, robot, tracks in samples:
        if t < 1.5:
            continue
        truth = start + vel * t
        near = [o for o in tracks if np.hypot(*(robot.apply(np.array(o.position)) - truth)) < 0.8]
        assert len(near) == 1, f"t={t}: {near}"
        errors.append(float(np.hypot(*(world_velocity(near[0], robot) - vel))))
    assert float(np.median(errors)) < 0.15
    assert max(errors) < 0.35


def test_a_line_seen_whole_and_moving_along_itself_is_tracked_along() -> None:
    """A 1.2 m trolley side passing across the robot's view along its own direction, its
    two ends seen: the along-line motion is observable and tracked, and the track says it
    was measured, so avoidance counts it (:func:`vouched_velocity`)."""
    vel = np.array([0.0, 0.8])

    def scene_at(t: float) -> Scene:
        y = -2.5 + 0.8 * t
        return Scene(segments=[(6.0, y - 0.6, 6.0, y + 0.6)])

    samples = track_scene(scene_at, straight(0.0), 5.0, seed=5)
    late = [o for t, _, tracks in samples if t > 2.0 for o in tracks]
    assert late and all(o.kind == "line" for o in late)
    errors = [float(np.hypot(*(np.array(o.velocity) - vel))) for o in late]
    assert float(np.median(errors)) < 0.1
    assert all(o.motion_measured for o in late)
    vouched = [float(np.hypot(*(np.array(vouched_velocity(o)) - vel))) for o in late]
    assert float(np.median(vouched)) < 0.1


# -- every shipped scenario ----------------------------------------------------------------------
SCENARIOS = sorted(MISSIONS.glob("*/scenarios/*.xml"))
CONTROL_HZ = 50.0
SCENARIO_SECONDS = 30.0
#: a track this close to a mover (beyond the mover's own bounding radius) may from then on
#: be the mover's: its cluster may merge with the mover's, or the tracker's gate hand it
#: the mover's measurements (the 40 m run's bin took 0.6 m/s from a trolley passing 1-2 m
#: away); its samples from then on are not judged
MOVER_RADIUS = 2.0
#: static tracks farther than this from the robot are left out: nothing there can be
#: ON_PATH or NEAR (:func:`behaviours.laws.tracking.danger_level`: a 3 s horizon at up to
#: 2 m/s, plus a spurious 0.5 m/s of the obstacle's, plus sizes, is about 10 m). Beyond,
#: partial views at 15-30 m (the range limit cuts the aircraft's gear and engines) still
#: give young tracks up to ~0.2 m/s at p99 in the hangar scenarios: see the issue report.
RELEVANT_RANGE = 15.0


def _follow(route: list[tuple[float, float]], pose: Pose2, i: int) -> tuple[VelocityCommand, int]:
    """Turn towards the next route point, drive when roughly aligned (bench_sim's)."""
    if i >= len(route):
        return VelocityCommand(), i
    tx, ty = route[i]
    if math.hypot(tx - pose.x, ty - pose.y) < 0.3:
        return VelocityCommand(), i + 1
    error = wrap_angle(math.atan2(ty - pose.y, tx - pose.x) - pose.theta)
    v = 1.0 if abs(error) < 0.3 else 0.0
    return VelocityCommand(v, max(-0.8, min(0.8, 1.5 * error))), i


@dataclasses.dataclass
class TrackLog:
    """One track's samples: time, speed (m/s), kind, size, range and position in A."""

    samples: list[tuple[float, float, str, float, float, float, float]] = dataclasses.field(
        default_factory=list
    )
    mover: bool = False
    near_mover: list[bool] = dataclasses.field(default_factory=list)
    """Per sample: a mover's body was within MOVER_RADIUS of the track."""

    @property
    def first_near_mover(self) -> int:
        """The index of the first sample near a mover (all samples: never near one)."""
        return next((k for k, near in enumerate(self.near_mover) if near), len(self.samples))


def scenario_tracks(path: Path, seconds: float) -> dict[int, TrackLog]:
    """Drive sim2d's robot along the scenario's route from its first checkpoint (where
    the structure is: the aircraft, the fence, the track's obstacles) for ``seconds``,
    every new pair of scans through the clusterer and the tracker (given the true pose;
    the cameras are not simulated: they play no part). Returns every confirmed track's
    samples, each marked whether a mover's body was within ``MOVER_RADIUS`` of it."""
    scenario = load_scenario(path)
    mission = scenario.mission
    route = route_points(mission)
    first = next(k for k, (name, _, _) in enumerate(route) if name == mission.checkpoints[0].id)
    _, x0, y0 = route[first]
    _, x1, y1 = route[first + 1]
    start = Pose2(x0, y0, math.atan2(y1 - y0, x1 - x0))
    robot = SimRobot(dataclasses.replace(scenario, start=start))
    robot.rigs = []
    platform = mission.platform
    mounts = {lid: Pose2(s.mount[0], s.mount[1], s.mount_yaw) for lid, s in platform.lasers.items()}
    clusterer = ScanClusterer(platform.length, platform.width)
    tracker = ObstacleTracker(DangerParams(platform.length, platform.width))
    points = [(x, y) for _, x, y in route[first + 1 :]]
    i = 0
    seen: dict[str, float] = {}
    logs: dict[int, TrackLog] = {}
    command = VelocityCommand()
    control = round(scenario.physics_rate / CONTROL_HZ)
    for step in range(round(seconds * scenario.physics_rate)):
        if step % control == 0:
            command, i = _follow(points, robot.world.robot_pose, i)
            robot.send(command)
        # one physics step at a time: the scans are taken at its end, so that the true
        # pose read now is the pose of the scans (a pose 10 ms late, turning at
        # 0.8 rad/s, moves a gear leg 8 m away by 6 cm: a velocity of its own)
        robot.advance(1.0 / scenario.physics_rate)
        frame = robot.read()
        fresh = [(s, mounts[lid]) for lid, s in frame.scans.items() if seen.get(lid) != s.stamp]
        if not fresh:
            continue
        seen.update((lid, s.stamp) for lid, s in frame.scans.items())
        pose = robot.truth.robot
        tracks = tracker.update(clusterer.detect(fresh), pose, (command.v, command.omega))
        movers = [(m.agent.x, m.agent.y, m.shape_body.bounding_radius) for m in robot.world.moving]
        for track in tracks:
            x, y = pose.apply(np.array(track.position))
            log = logs.setdefault(track.id, TrackLog())
            near = any(math.hypot(mx - x, my - y) - r <= MOVER_RADIUS for mx, my, r in movers)
            log.mover = log.mover or near
            log.near_mover.append(near)
            log.samples.append(
                (
                    robot.time,
                    math.hypot(*track.velocity),
                    track.kind,
                    track.size,
                    math.hypot(*track.position),
                    float(x),
                    float(y),
                )
            )
    return logs


@pytest.mark.parametrize("path", SCENARIOS, ids=lambda p: f"{p.parent.parent.name}/{p.stem}")
def test_no_static_obstacle_of_a_shipped_scenario_is_tracked_as_moving(path: Path) -> None:
    """Every static track's samples within ``RELEVANT_RANGE`` of the robot, once the track
    has settled (``TRACK_SETTLED_AGE``, as the dry-run's tracking metrics count): p99 of
    the speed at most 0.1 m/s. A track's samples count until a mover first comes within
    ``MOVER_RADIUS`` of it (from then on it may be the mover's, or merged with it): a
    walker passing along the lab's fence would otherwise leave no static structure."""
    logs = scenario_tracks(path, SCENARIO_SECONDS)
    speeds = [
        speed
        for log in logs.values()
        for (t, speed, _, _, distance, _, _) in log.samples[: log.first_near_mover]
        if distance <= RELEVANT_RANGE and t - log.samples[0][0] >= TRACK_SETTLED_AGE
    ]
    assert len(speeds) > 100, "the robot saw no static structure"
    p99 = float(np.percentile(speeds, 99))
    assert p99 <= STATIC_SPEED, f"static tracks at {p99:.3f} m/s (p99), max {max(speeds):.3f}"


def test_the_scenarios_cover_the_lab_and_every_mission() -> None:
    names = {f"{p.parent.parent.name}/{p.stem}" for p in SCENARIOS}
    assert "lab/clear-apron" in names
    assert {p.parent.parent.name for p in SCENARIOS} == {
        d.name for d in MISSIONS.iterdir() if (d / "scenarios").is_dir()
    }


def test_the_empty_lab_is_inspected_without_avoiding_anything() -> None:
    """The defect as it was seen: the whole lab mission through the executive (dry-run,
    perception in the odometry frame, safety layer, avoidance): the fence, the duct and
    the tyre are static, so no track of them moves and avoidance never engages (it did,
    for the fence tracked at 0.19 m/s)."""
    run = dry_run(load_scenario(MISSIONS / "lab" / "scenarios" / "clear-apron.xml"), max_time=150.0)
    assert run.result.outcome == "completed"
    assert avoidance_metrics(run)["engagements"] == 0
    speeds = [math.hypot(s.vx, s.vy) for s in run.tracks if s.mover is None]
    assert len(speeds) > 500
    assert float(np.percentile(speeds, 99)) <= STATIC_SPEED
