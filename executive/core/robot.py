"""The single seam between the executive and a robot (ARCHITECTURE.md §8).

Like python-can's ``BusABC``, one abstract interface and several implementations: the
simulator (:class:`sim2d.robot.SimRobot`) and, later, the CAN drive base. Behaviours
never touch it; the runtime reads a frame, ticks the tree, and sends one command.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from executive.core.records import SensorFrame, VelocityCommand


@runtime_checkable
class RobotInterface(Protocol):
    """What the runtime needs from a robot, real or simulated."""

    def read(self) -> SensorFrame:
        """The latest reading of every sensor; never blocks."""
        ...

    def send(self, command: VelocityCommand) -> None:
        """Command the base and the pan-tilt units until the next command."""
        ...
