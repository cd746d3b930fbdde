"""The operator's virtual joystick while they have the robot (issue 15).

:class:`JoystickActive` holds while a fresh joystick command is on the blackboard (the
operator state drops one older than its dead-man time, :data:`executive.operator.DEADMAN_S`,
so a tablet whose stream stops no longer drives); :class:`JoystickControl` sends it,
limited to the joystick's own speed and turn rate. Every command still goes through the
safety layer (e-stop, geofence, slowdown, platform limits), like the tree's own.
"""

from __future__ import annotations

import py_trees

from behaviours.base import Controller, Guard
from behaviours.keys import COMMAND, OPERATOR
from executive.core.records import OperatorRequests, VelocityCommand

Status = py_trees.common.Status


class JoystickActive(Guard):
    """SUCCESS while the operator's joystick stream is fresh."""

    reads = (OPERATOR,)

    def __init__(self, name: str = "joystick held?") -> None:
        super().__init__(name)

    def update(self) -> Status:
        operator: OperatorRequests = self.read(OPERATOR, OperatorRequests())
        stick = operator.joystick
        if stick is None:
            self.feedback_message = "no joystick stream"
            return Status.FAILURE
        self.feedback_message = f"v {stick.v:+.2f} m/s, omega {stick.omega:+.2f} rad/s"
        return Status.SUCCESS


class JoystickControl(Controller):
    """The joystick's command, within ``max_speed`` (m/s) and ``max_omega`` (rad/s); a
    stop when the stream is stale."""

    reads = (OPERATOR,)
    writes = (COMMAND,)

    def __init__(self, max_speed: float, max_omega: float, name: str = "joystick") -> None:
        super().__init__(name)
        self.max_speed = max_speed
        self.max_omega = max_omega

    def update(self) -> Status:
        operator: OperatorRequests = self.read(OPERATOR, OperatorRequests())
        stick = operator.joystick
        if stick is None:
            self.write(COMMAND, VelocityCommand.stop())
            self.feedback_message = "joystick stream stopped: stop"
            return Status.RUNNING
        v = max(-self.max_speed, min(self.max_speed, stick.v))
        omega = max(-self.max_omega, min(self.max_omega, stick.omega))
        self.write(COMMAND, VelocityCommand(v, omega))
        self.feedback_message = f"v {v:+.2f} m/s, omega {omega:+.2f} rad/s"
        return Status.RUNNING
