"""The sensing behaviours of issue 5 in sim2d: every scan processed, tracks of a walker,
the aircraft registered from the lasers, virtual zone walls, and the fallback frame."""

import math

import numpy as np
import py_trees
import pytest

from behaviours.keys import OBSTACLES, POSE, SENSOR_FRAME
from behaviours.sensing.localisation import Localise
from behaviours.sensing.obstacles import SenseObstacles
from behaviours.sensing.registration import AircraftRegistrar
from executive.core.frames import wrap_angle
from executive.core.records import FrameReference, VelocityCommand
from executive.dryrun import dry_run
from executive.report import tracking_metrics
from sim2d.robot import SimRobot
from tests.sim2d_helpers import make_scenario, start

RATE = 50.0


class Sensing:
    """Localise + SenseObstacles ticked against a SimRobot, like the compiled tree does."""

    def __init__(self, scenario, registrar: bool = True) -> None:
        py_trees.blackboard.Blackboard.enable_activity_stream(0)
        py_trees.blackboard.Blackboard.clear()
        self.robot = SimRobot(scenario)
        m = scenario.mission
        self.localise = Localise(
            scenario.start,
            m.platform.track,
            m.nominal_placement(),
            AircraftRegistrar(m.aircraft, m.platform.lasers) if registrar else None,
        )
        self.obstacles = SenseObstacles(m.platform, m.airport.zones, m.safety.r_oa_trigger)
        self.root = py_trees.composites.Sequence(
            "sensing", memory=False, children=[self.localise, self.obstacles]
        )
        self.bb = py_trees.blackboard.Client(name="test")
        self.bb.register_key(key=SENSOR_FRAME.name, access=py_trees.common.Access.WRITE)
        self.bb.register_key(key=POSE.name, access=py_trees.common.Access.READ)
        self.bb.register_key(key=OBSTACLES.name, access=py_trees.common.Access.READ)
        self.scans_seen: set[tuple[str, float]] = set()

    def run(self, seconds: float, v: float = 0.0, omega: float = 0.0) -> None:
        for _ in range(round(seconds * RATE)):
            frame = self.robot.read()
            self.scans_seen.update((lid, s.stamp) for lid, s in frame.scans.items())
            self.bb.set(SENSOR_FRAME.name, frame, overwrite=True)
            self.root.tick_once()
            self.robot.send(VelocityCommand(v, omega))
            self.robot.advance(1.0 / RATE)

    @property
    def pose(self):
        return self.bb.get(POSE.name)

    @property
    def seen(self):
        return self.bb.get(OBSTACLES.name)


WALKER = (
    '<obstacles><path id="walker" kind="person" radius="0.3" height="1.8" speed="1.0">'
    '<waypoint x="-52" y="2"/><waypoint x="-52" y="18"/></path></obstacles>'
)


def test_every_scan_is_processed_and_a_walker_is_tracked(tmp_path):
    # the robot waits at the station (-60, 10) facing east; a walker crosses 8 m ahead,
    # walking north at 1 m/s
    sensing = Sensing(make_scenario(tmp_path, WALKER), registrar=False)
    sensing.run(6.0)
    assert sensing.obstacles.scans_processed == len(sensing.scans_seen)
    walker = [t for t in sensing.seen.tracks if t.kind != "zone" and t.speed > 0.5]
    assert len(walker) == 1
    track = walker[0]
    truth = sensing.robot.world.moving[0].agent
    robot = sensing.robot.world.robot_pose
    position_a = robot.apply(np.array(track.position))
    assert math.dist(position_a, (truth.x, truth.y)) < 0.15
    c, s = math.cos(robot.theta), math.sin(robot.theta)
    vx, vy = track.velocity
    velocity_a = (c * vx - s * vy, s * vx + c * vy)
    assert math.dist(velocity_a, (truth.vx, truth.vy)) < 0.1
    assert track.age > 1.0
    assert track.covariance.shape == (4, 4)


OFFSET = '<parking-offset dx="1.2" dy="-1.0" dheading-deg="-8"/>'


@pytest.mark.parametrize(
    ("kind", "where"),
    [("a320", start(-9.0, -12.0, -90.0)), ("b737-800", start(-9.0, -10.0, -90.0))],
)
def test_the_aircraft_is_registered_and_the_pose_in_f_follows(kind, where, tmp_path):
    """Beside the left main gear, aircraft 1.6 m and 8 deg off its mark: after the first
    registration the pose in F is within 5 cm / 0.5 deg of the truth, and stays there
    while the robot drives (ICP tracking)."""
    scenario = make_scenario(tmp_path, OFFSET + where, mission_type=kind)
    sensing = Sensing(scenario)
    truth_placement = scenario.true_placement()
    sensing.run(0.5)
    assert sensing.pose.reference is FrameReference.AIRCRAFT
    sensing.run(4.0, v=0.5, omega=0.05)
    pose = sensing.pose
    truth_f = truth_placement.pose_to_aircraft(sensing.robot.world.robot_pose)
    assert pose.pose_f.distance_to(truth_f) < 0.05
    assert abs(wrap_angle(pose.pose_f.theta - truth_f.theta)) < math.radians(0.5)
    registrar = sensing.localise.registrar
    assert registrar.accepted["global"] >= 1 and registrar.accepted["icp"] >= 5
    assert pose.confidence_f > 0.9


def test_without_the_aircraft_in_view_the_pose_stays_nominal(tmp_path):
    sensing = Sensing(make_scenario(tmp_path, OFFSET))  # at the station, 60 m away
    sensing.run(1.0)
    assert sensing.pose.reference is FrameReference.NOMINAL
    assert sensing.localise.registrar.attempts["global"] == 0


def test_zone_walls_are_virtual_obstacles_near_a_zone(tmp_path):
    # A320 refuelling zone (F) spans A x 6.7..16.6, y -26.6..-13.9 at the nominal pose
    sensing = Sensing(make_scenario(tmp_path, start(18.0, -20.0, 180.0)), registrar=False)
    sensing.run(0.2)
    seen = sensing.seen
    zones = [t for t in seen.tracks if t.kind == "zone"]
    assert zones and zones[0].clearance < 1.5
    assert len(seen.virtual) > 10
    assert seen.closest_virtual == pytest.approx(zones[0].clearance)
    assert seen.closest_any <= seen.closest


def test_a_lost_registration_falls_back_to_the_last_checkpoint_frame_and_recovers(tmp_path):
    """Both lasers drop out for 8 s after the aircraft was registered: the estimate says
    its pose in F is carried from the last checkpoint (seed lines 1030-1040), then the
    registration comes back with the lasers."""
    faults = (
        '<faults><laser-dropout laser="front" at="2" duration="8"/>'
        '<laser-dropout laser="rear" at="2" duration="8"/></faults>'
    )
    scenario = make_scenario(tmp_path, OFFSET + start(-9.0, -12.0, -90.0) + faults)
    sensing = Sensing(scenario)
    sensing.run(1.5)
    assert sensing.pose.reference is FrameReference.AIRCRAFT
    sensing.run(8.0)  # t = 9.5 s: no scan for 7.5 s > lost_after
    assert sensing.pose.reference is FrameReference.CHECKPOINT
    sensing.run(3.0)
    pose = sensing.pose
    assert pose.reference is FrameReference.AIRCRAFT
    truth_f = scenario.true_placement().pose_to_aircraft(sensing.robot.world.robot_pose)
    assert pose.pose_f.distance_to(truth_f) < 0.05


def test_a_confidence_drop_triggers_a_global_registration(tmp_path):
    scenario = make_scenario(tmp_path, OFFSET + start(-9.0, -12.0, -90.0))
    sensing = Sensing(scenario)
    sensing.run(1.0)
    registrar = sensing.localise.registrar
    assert registrar.accepted["global"] == 1
    pose_filter = sensing.localise.filter
    # doubt where the aircraft is (GPS cannot help with that; only the lasers can)
    pose_filter.reset_placement(pose_filter.pose_f, np.diag([0.3**2, 0.3**2, 0.05**2]))
    assert pose_filter.confidence_f < registrar.policy.relocalise_confidence
    sensing.run(1.5)
    assert registrar.attempts["global"] == 2 and registrar.accepted["global"] == 2
    assert sensing.pose.confidence_f > 0.9


def test_the_report_measures_tracking_against_the_movers_truth(tmp_path):
    run = dry_run(make_scenario(tmp_path, WALKER), max_time=20.0)
    report = tracking_metrics(run)
    assert report["movers_tracked"] == ["walker"]
    assert report["position_error_m"]["p95"] < 0.05
    assert report["velocity_error_mps"]["p95"] < 0.15
