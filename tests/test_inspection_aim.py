"""InspectItems turns its unit the way that stays within the unit's pan limits.

A pan-tilt unit whose pan spans the whole circle (limits +-180 deg) cannot cross from
+179 deg to -179 deg: the short way round (the wrapped pan error) would push it against
its limit until the item times out (found by `walkaround plan`'s B737 drafts, issue 18).
"""

from __future__ import annotations

import dataclasses
import math

from hypothesis import example, given, settings
from hypothesis import strategies as st

from behaviours.keys import COMMAND, POSE, SENSOR_FRAME
from executive.core.frames import Pose2, aircraft_from_robot, pan_tilt_towards
from executive.core.records import PanTilt, SensorFrame
from tests.test_stale_sensors import Inspection

DT = 0.04
WHOLE_CIRCLE = (-math.pi, math.pi)


def _turn_from(
    start_pan: float, limits: tuple[float, float], turn: float = 0.0
) -> tuple[float, float]:
    """Closed loop for as long as the node has to aim and still look before the item
    times out (``item_timeout - look_time``), the robot standing on the checkpoint turned
    by ``turn`` (rad): the unit integrates the node's pan rate (clamped by its rate and
    its limits, as sim2d's units do) from ``start_pan``; returns (final pan, the pan that
    aims at the item)."""
    run = Inspection()
    unit = dataclasses.replace(run.unit, pan_limits=limits)
    run.node.unit = unit
    p = run.pose.pose_f
    pose_f = Pose2(p.x, p.y, p.theta + turn)
    run.pose = dataclasses.replace(run.pose, pose_a=pose_f, pose_f=pose_f)
    target = (
        aircraft_from_robot(pose_f, run.m.aircraft.origin_height)
        .inverse()
        .apply(run.m.aircraft.feature_of(run.item).centroid())
    )
    aim_pan, aim_tilt = pan_tilt_towards(unit.mount, unit.mount_yaw, target)
    pan = start_pan
    for _ in range(round((run.node.item_timeout - run.node.look_time) / DT)):
        frame = SensorFrame(run.t, pan_tilt={unit.id: PanTilt(run.t, pan, aim_tilt)})
        run.bb.set(SENSOR_FRAME.name, frame, overwrite=True)
        run.bb.set(POSE.name, dataclasses.replace(run.pose, stamp=run.t), overwrite=True)
        run.node.tick_once()
        rate = run.bb.get(COMMAND.name).pan_tilt[unit.id].pan
        rate = max(-unit.pan_rate, min(unit.pan_rate, rate))
        pan = max(limits[0], min(limits[1], pan + rate * DT))
        run.t = round(run.t + DT, 9)
    return pan, aim_pan


@settings(max_examples=25, deadline=None)
@given(st.floats(-math.pi, math.pi), st.floats(-math.pi, math.pi))
@example(3.0, math.pi)  # the aim on one limit, the unit near the other: 352 deg to turn
def test_a_whole_circle_unit_reaches_its_aim_from_any_pan(start: float, turn: float) -> None:
    pan, aim = _turn_from(start, WHOLE_CIRCLE, turn)
    assert abs(pan - aim) < math.radians(1.0), (start, pan, aim)


def test_the_way_across_the_limit_is_not_taken() -> None:
    """The robot turned so that the item is 150 deg to one side and the unit starts just
    inside the limit on the other: the short way round crosses the limit; the way within
    the limits is more than half a turn."""
    for turn in (math.radians(150.0), math.radians(-150.0)):
        _, aim = _turn_from(0.0, WHOLE_CIRCLE, turn)
        start = -math.copysign(math.pi - 0.02, aim)
        assert abs(aim - start) > math.pi
        pan, _ = _turn_from(start, WHOLE_CIRCLE, turn)
        assert abs(pan - aim) < math.radians(1.0), (turn, start, pan, aim)
