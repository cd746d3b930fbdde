"""Property (ISSUE 4): in randomised scenarios the robot never enters a forbidden zone.

Random starts near the A320's zones, random piecewise-constant commands aimed at them,
the real safety layer, and sim2d's dynamics (acceleration limits, slip): the robot's true
footprint never intersects a zone. The estimate given to the safety layer is the true
pose, so this checks the layer's geometry and braking, not the localisation.
"""

import math
import tempfile
from pathlib import Path

import numpy as np
import shapely
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from shapely.geometry import Polygon as ShapelyPolygon

from behaviours.laws.obstacles import closest_obstacle, scan_to_robot
from executive.core.frames import Pose2
from executive.core.problems import InvalidInputError
from executive.core.records import Obstacles, PoseEstimate, VelocityCommand
from executive.safety import SafetyLayer
from sim2d.robot import SimRobot
from tests.sim2d_helpers import make_scenario

RATE = 20.0


def _footprint(pose, length, width):
    hl, hw = length / 2, width / 2
    return ShapelyPolygon(pose.apply([(hl, hw), (-hl, hw), (-hl, -hw), (hl, -hw)]))


@settings(
    max_examples=12,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
@given(
    zone_index=st.integers(0, 3),
    bearing=st.floats(0, 2 * math.pi),
    distance=st.floats(1.6, 4.0),
    heading=st.floats(-math.pi, math.pi),
    commands=st.lists(
        st.tuples(st.floats(-1.0, 2.0), st.floats(-1.0, 1.0)), min_size=8, max_size=15
    ),
)
def test_random_runs_never_enter_a_forbidden_zone(zone_index, bearing, distance, heading, commands):
    with tempfile.TemporaryDirectory() as tmp:
        probe = make_scenario(Path(tmp))
        mission = probe.mission
        placement = probe.true_placement()
        zones = []
        for zone in mission.airport.zones:
            geom = ShapelyPolygon(placement.to_airport_xy(np.array(zone.shape.vertices(48))))
            zones.append(
                geom if zone.frame.value == "aircraft" else ShapelyPolygon(zone.shape.vertices(48))
            )
        target = zones[zone_index % len(zones)]
        edge = target.exterior.interpolate(bearing / (2 * math.pi), normalized=True)
        c = target.centroid
        away = np.array([edge.x - c.x, edge.y - c.y])
        away /= max(np.linalg.norm(away), 1e-9)
        start = Pose2(edge.x + away[0] * distance, edge.y + away[1] * distance, heading)
        platform = mission.platform
        foot = _footprint(start, platform.length, platform.width)
        if any(foot.distance(z) < mission.safety.geofence_margin + 0.05 for z in zones):
            return  # the draw starts too close: not a valid start
        body = f'<start x="{start.x}" y="{start.y}" heading-deg="{math.degrees(heading)}"/>'
        try:
            robot = SimRobot(make_scenario(Path(tmp), body, name="p.xml"))
        except InvalidInputError:  # the loader refuses a start inside the aircraft
            return
        if robot.truth.collisions:
            return
        safety = SafetyLayer(mission, placement, 1.0 / RATE)
        mounts = {
            lid: Pose2(s.mount[0], s.mount[1], s.mount_yaw) for lid, s in platform.lasers.items()
        }
        for k in range(round(len(commands) * RATE)):
            frame = robot.read()
            pose = robot.truth.robot
            cov = np.diag([1e-4, 1e-4, 1e-4])
            estimate = PoseEstimate(frame.stamp, pose, cov, placement.pose_to_aircraft(pose), 1.0)
            points = np.vstack(
                [
                    scan_to_robot(
                        s.ranges, s.angle_min, s.angle_increment, s.range_max, mounts[lid]
                    )
                    for lid, s in frame.scans.items()
                ]
            )
            r_c, bearing_c = closest_obstacle(points, platform.length, platform.width)
            obstacles = Obstacles(frame.stamp, r_c, bearing_c, points)
            v, omega = commands[int(k / RATE)]
            sent = safety.filter(
                VelocityCommand(v, omega),
                now=frame.stamp,
                frame=frame,
                pose=estimate,
                obstacles=obstacles,
            )
            robot.send(sent)
            robot.advance(1.0 / RATE)
            true_foot = _footprint(robot.truth.robot, platform.length, platform.width)
            assert not any(shapely.intersects(true_foot, z) for z in zones), k
