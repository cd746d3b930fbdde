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


@runtime_checkable
class LinkHealth(Protocol):
    """A robot whose wires can fail on their own (the CAN base, not the simulator).

    The runtime asks every tick; any reason returned stops the robot and ends the run
    with that reason (a lost base heartbeat, bus-off, failed sends, a replayed frame
    counter). Sensors that only go quiet (a laser connection dropped) are not link
    faults: their readings go stale and the safety layer holds the robot until they
    are fresh again.
    """

    def link_faults(self) -> tuple[str, ...]:
        """Why the link to the robot cannot be trusted now; empty while it can."""
        ...
