"""sim2d end to end: the world, its sensors and faults, through SimRobot (RobotInterface)."""

import io
import math

import numpy as np
import pytest
from shapely.geometry import Polygon as ShapelyPolygon

from executive.core.frames import Pose2
from executive.core.geometry import to_shapely
from executive.core.records import PanTiltRate, VelocityCommand
from executive.core.robot import RobotInterface
from sim2d.robot import SimRobot
from sim2d.scenario import Body
from sim2d.world import STILL_SPEED
from tests.sim2d_helpers import (
    NO_NOISE,
    NO_SLIP,
    drive,
    heading_error,
    make_scenario,
    odometry_run,
    position_error,
    start,
)

# A320 nominal parking: nose at (0, 0) of A pointing north, so F (x, y) is A (-y, -x).


def test_sim_robot_is_a_robot_interface(tmp_path):
    robot = SimRobot(make_scenario(tmp_path))
    assert isinstance(robot, RobotInterface)
    frame = robot.read()
    assert set(frame.scans) == {"front", "rear"}
    assert set(frame.cameras) == {"front-left", "front-right", "rear-left", "rear-right", "ptz"}
    assert len(frame.scans["front"].ranges) == 1081  # 270 deg in 0.25 deg steps, both ends


def test_laser_sees_a_box_exactly(tmp_path):
    """Without noise, the front scan of a wall-like box is exact (flat face at 1.85 m)."""
    body = (
        start(-60, 10, 0)
        + NO_NOISE
        + (
            '<obstacles><box id="wall" kind="other" x="-57" y="10" heading-deg="0" length="1"'
            ' width="4" height="2"/></obstacles>'
        )
    )
    robot = SimRobot(make_scenario(tmp_path, body))
    scan = robot.read().scans["front"]
    mount_x = robot.scenario.mission.platform.lasers["front"].mount[0]
    face = -57.5 - (-60 + mount_x)
    angles = scan.angles()
    on_face = np.abs(face * np.tan(angles)) < 1.9  # beams that hit the 4 m wide face
    on_face &= np.abs(angles) < math.pi / 2
    expected = face / np.cos(angles[on_face])
    assert np.max(np.abs(scan.ranges[on_face] - expected)) < 1e-6
    assert scan.ranges[540] == pytest.approx(face, abs=1e-9)  # beam straight ahead


def test_scenario_run_is_deterministic_byte_for_byte(tmp_path):
    body = (
        start(-30, 0, 0)
        + '<obstacles><path id="walker" kind="person" radius="0.3" height="1.8" speed="1.2">'
        '<waypoint x="-24" y="-5"/><waypoint x="-24" y="5"/></path>'
        '<group id="crew" x="-35" y="8" radius="3" count="3" speed="0.5" person-radius="0.3"'
        ' height="1.8"/>'
        '<chaser id="trolley" kind="trolley" x="-20" y="-8" length="1.2" width="0.8"'
        ' height="1" speed="0.5"/></obstacles>'
    )

    def run(seed):
        truth, sensors = io.StringIO(), io.StringIO()
        robot = SimRobot(make_scenario(tmp_path, body, seed=seed), truth, sensors)
        drive(robot, 0.8, 0.0, 3.0)
        drive(robot, 0.3, 0.6, 3.0)
        robot.close()
        return truth.getvalue(), sensors.getvalue()

    first, second, other = run(7), run(7), run(8)
    assert first == second
    assert len(first[0]) > 1000 and len(first[1]) > 10000
    assert first[1] != other[1]  # the seed matters


def test_odometry_drifts_more_in_tight_turns_than_straight(tmp_path):
    """Skid-steer slip: the wheels over-report rotation, most when turning on the spot."""
    body = start(-60, 10, 0) + NO_NOISE
    straight, truth_s = odometry_run(SimRobot(make_scenario(tmp_path, body)), 0.6, 0.0, 10.0)
    turning, truth_t = odometry_run(SimRobot(make_scenario(tmp_path, body)), 0.2, 0.8, 10.0)
    assert heading_error(turning, truth_t) > 10 * max(heading_error(straight, truth_s), 0.01)
    assert position_error(turning, truth_t) > position_error(straight, truth_s)
    assert position_error(straight, truth_s) > 0.0  # longitudinal slip exists, but is small


def test_no_slip_means_exact_odometry(tmp_path):
    body = start(-60, 10, 0) + NO_NOISE + NO_SLIP
    odo, truth = odometry_run(SimRobot(make_scenario(tmp_path, body)), 0.3, 0.5, 5.0)
    assert position_error(odo, truth) < 0.02
    assert heading_error(odo, truth) < 0.02


def test_gps_lost_under_the_wing_degraded_at_its_edge(tmp_path):
    open_sky = SimRobot(make_scenario(tmp_path, start(-60, 10, 0), name="a.xml"))
    open_sky.advance(0.5)
    fix = open_sky.read().gps
    assert fix is not None and fix.sigma == pytest.approx(open_sky.scenario.noise.gps)
    gps = open_sky.gps
    # The deepest spot under the left wing (F x 13..23, y 4..16, i.e. A x -16..-4).
    grid = [
        (float(x), float(y)) for x in np.arange(-16, -4, 0.25) for y in np.arange(-23, -13, 0.25)
    ]
    # (the deepest where the robot does not stand in a gear leg: the loader refuses that)
    deep = max(
        (p for p in grid if not _in_footprint(open_sky, *p)),
        key=lambda p: gps.depth_under_outline(*p),
    )
    assert gps.depth_under_outline(*deep) > robot_margin(open_sky)
    under = SimRobot(make_scenario(tmp_path, start(*deep, 0), name="b.xml"))
    under.advance(1.0)
    assert under.read().gps is None
    # Near the leading edge the fix degrades before it is lost.
    across_wing = [(-10.0, float(y)) for y in np.linspace(-14, -22, 81)]
    shallow = [p for p in across_wing if 0.1 < gps.depth_under_outline(*p) < 0.9]
    assert shallow
    sigma = gps.sigma_at(*shallow[0])
    assert sigma is not None and sigma > gps.sigma


def _in_footprint(robot, x, y):
    """Would the robot at (x, y), heading 0, overlap the aircraft footprint?"""
    platform = robot.scenario.mission.platform
    outline = to_shapely(Body(length=platform.length, width=platform.width).polygon(Pose2(x, y, 0)))
    placement = robot.scenario.true_placement()
    return any(
        ShapelyPolygon(placement.to_airport_xy(to_shapely(s).exterior.coords)).intersects(outline)
        for s in robot.scenario.mission.aircraft.footprint
    )


def robot_margin(robot):
    return robot.scenario.gps.shadow_margin


def test_gps_denied_in_a_hangar(tmp_path):
    robot = SimRobot(make_scenario(tmp_path, start(-60, 10, 0) + '<gps mode="denied"/>'))
    robot.advance(1.0)
    assert robot.read().gps is None


def test_contact_presses_the_bumper_and_is_a_collision(tmp_path):
    body = start(-60, 10, 0) + (
        '<obstacles><box id="crate" kind="equipment" x="-57.5" y="10" heading-deg="0"'
        ' length="1" width="2" height="1"/></obstacles>'
    )
    robot = SimRobot(make_scenario(tmp_path, body))
    drive(robot, 0.5, 0.0, 6.0)
    truth = robot.truth
    assert truth.collisions, "driving into a crate must be recorded"
    assert truth.collisions[0].other == "crate"
    assert truth.collisions[0].x > 0.0  # at the front of the robot
    assert robot.read().bumpers.front
    # The platform brakes on its bumper: it does not keep pushing.
    x_before = truth.robot.x
    drive(robot, 0.5, 0.0, 2.0)
    assert robot.truth.robot.x == pytest.approx(x_before, abs=0.05)


def test_pedestrian_path_starts_on_trigger(tmp_path):
    body = start(-60, 10, 0) + (
        '<obstacles><path id="walker" kind="person" radius="0.3" height="1.8" speed="1.0"'
        ' trigger-radius="6"><waypoint x="-50" y="5"/><waypoint x="-50" y="15"/></path>'
        "</obstacles>"
    )
    robot = SimRobot(make_scenario(tmp_path, body))
    robot.advance(3.0)
    assert robot.truth.obstacles[0][1:3] == pytest.approx((-50, 5))  # robot far: waits
    drive(robot, 1.0, 0.0, 10.0)  # the robot comes within 6 m of (-50, 5)
    assert robot.truth.obstacles[0][2] > 6.0


def test_chaser_steers_towards_the_robot(tmp_path):
    body = start(-60, 10, 0) + (
        '<obstacles><chaser id="trolley" kind="trolley" x="-50" y="10" length="1.2"'
        ' width="0.8" height="1" speed="0.8"/></obstacles>'
    )
    robot = SimRobot(make_scenario(tmp_path, body))
    robot.advance(5.0)
    _, x, y, _ = robot.truth.obstacles[0]
    assert x == pytest.approx(-54.0, abs=0.1) and y == pytest.approx(10.0, abs=0.05)


def test_chaser_gives_up_after_its_pursuit_time_and_goes_back(tmp_path):
    body = start(-60, 10, 0) + (
        '<obstacles><chaser id="trolley" kind="trolley" x="-50" y="10" length="1.2"'
        ' width="0.8" height="1" speed="0.8" pursuit="3"/></obstacles>'
    )
    robot = SimRobot(make_scenario(tmp_path, body))
    robot.advance(3.0)
    _, x, _, _ = robot.truth.obstacles[0]
    assert x == pytest.approx(-52.4, abs=0.1)  # chased for 3 s
    robot.advance(5.0)
    _, x, y, _ = robot.truth.obstacles[0]
    assert (x, y) == (pytest.approx(-50.0, abs=0.06), pytest.approx(10.0, abs=0.05))  # back
    robot.advance(5.0)
    _, x2, _, _ = robot.truth.obstacles[0]
    assert x2 == pytest.approx(x, abs=1e-6)  # and stays: never triggered again


def test_camera_sees_target_and_obstacle_occludes_it(tmp_path):
    # CP01 of the A320 mission: F (6.5, 5.0) heading -90 is A (-5, -6.5) facing east.
    clear = SimRobot(make_scenario(tmp_path, start(-5, -6.5, 0) + NO_NOISE, name="c.xml"))
    seen = {d.feature for d in clear.read().cameras["front-left"].detections}
    assert "static-ports-left" in seen
    wall = (
        '<obstacles><box id="board" kind="equipment" x="-3" y="-6.6" heading-deg="0"'
        ' length="0.2" width="2.5" height="3"/></obstacles>'
    )
    blocked = SimRobot(make_scenario(tmp_path, start(-5, -6.5, 0) + NO_NOISE + wall, name="d.xml"))
    seen = {d.feature for d in blocked.read().cameras["front-left"].detections}
    assert "static-ports-left" not in seen
    low = wall.replace('height="3"', 'height="0.3"')  # a low board does not hide the ports
    over = SimRobot(make_scenario(tmp_path, start(-5, -6.5, 0) + NO_NOISE + low, name="e.xml"))
    seen = {d.feature for d in over.read().cameras["front-left"].detections}
    assert "static-ports-left" in seen


def test_pan_tilt_units_follow_rate_commands(tmp_path):
    robot = SimRobot(make_scenario(tmp_path, start(-60, 10, 0)))
    robot.send(VelocityCommand(0.0, 0.0, {"ptz": PanTiltRate(pan=0.5, tilt=0.0)}))
    robot.advance(1.0)
    assert robot.read().pan_tilt["ptz"].pan == pytest.approx(0.5, abs=0.02)


def test_faults_laser_dropout_camera_freeze_gps_loss_bumper_hit(tmp_path):
    body = start(-60, 10, 0) + (
        "<faults>"
        '<laser-dropout laser="front" at="1" duration="2"/>'
        '<camera-freeze camera="ptz" at="1" duration="2"/>'
        '<gps-loss at="1" duration="2"/>'
        '<bumper-hit bumper="rear" at="1" duration="0.5"/>'
        "</faults>"
    )
    robot = SimRobot(make_scenario(tmp_path, body))
    robot.send(VelocityCommand(0.0, 0.0, {"ptz": PanTiltRate(pan=0.8)}))
    robot.advance(1.2)
    frame = robot.read()
    assert frame.scans["front"].stamp < 1.0 + 1e-9  # no new front scans
    assert frame.scans["rear"].stamp > 1.1
    assert frame.gps is None
    assert frame.bumpers.rear and not frame.bumpers.front
    frozen = frame.cameras["ptz"].detections
    robot.advance(1.0)
    later = robot.read()
    assert later.cameras["ptz"].detections == frozen  # stale content, fresh stamps
    assert later.cameras["ptz"].stamp > 2.0
    robot.advance(1.5)
    after = robot.read()
    assert after.scans["front"].stamp > 3.0 and after.gps is not None
    assert not after.bumpers.rear


def cart_from_to(a: tuple[float, float], b: tuple[float, float]) -> str:
    """A trolley 'cart' driving at 1 m/s from ``a`` to ``b``, as scenario obstacles."""
    return (
        '<obstacles><path id="cart" kind="trolley" length="1.2" width="0.8" height="1.0"'
        ' speed="1.0" start-time="0.0" loop="false">'
        f'<waypoint x="{a[0]}" y="{a[1]}"/><waypoint x="{b[0]}" y="{b[1]}"/></path></obstacles>'
    )


def test_a_collision_says_whether_the_robot_moved_or_was_struck_standing_still(tmp_path):
    """Driving into a crate is the robot's collision; a trolley that runs into the robot
    standing still struck it: the campaign report tells one from the other."""
    crate = start(-60, 10, 0) + (
        '<obstacles><box id="crate" kind="equipment" x="-57.5" y="10" heading-deg="0"'
        ' length="1" width="2" height="1"/></obstacles>'
    )
    robot = SimRobot(make_scenario(tmp_path / "crate", crate))
    drive(robot, 0.5, 0.0, 6.0)
    hit = robot.truth.collisions[0]
    assert hit.robot_moving and 0.3 < hit.robot_speed < 0.6, hit
    assert hit.robot_closing > STILL_SPEED  # into it
    assert "moving at" in hit.describe()
    trolley = start(-60, 10, 0) + cart_from_to((-60, 14), (-60, 6))
    robot = SimRobot(make_scenario(tmp_path / "trolley", trolley))
    drive(robot, 0.0, 0.0, 6.0)
    struck = robot.truth.collisions[0]
    assert struck.other == "cart"
    assert not struck.robot_moving and struck.robot_speed < STILL_SPEED, struck
    assert "standing still: struck" in struck.describe()


def test_a_robot_backing_away_from_what_strikes_it_is_told_apart(tmp_path):
    """A trolley faster than the robot catches it up from behind while it drives away:
    the robot moved, but away from the contact (its e-stop retreat, struck anyway), not
    into it."""
    chased = start(-60, 10, 0) + cart_from_to((-63, 10), (-50, 10))
    robot = SimRobot(make_scenario(tmp_path / "chased", chased))
    drive(robot, 0.2, 0.0, 6.0)
    hit = robot.truth.collisions[0]
    assert hit.other == "cart" and hit.robot_moving
    assert hit.robot_closing < 0.0, hit
    assert "moving away at" in hit.describe()
