"""Navigation goals, each in the frame its mission gives it.

Approach waypoints and the charging station are fixed in the airport frame A; checkpoints
(and waypoints written in F) move with the aircraft. A :class:`Goal` keeps the frame, and
the behaviours resolve it in A at every tick through the pose estimate's *current*
aircraft placement, so a laser registration that moves the aircraft moves the goals with
it (ARCHITECTURE.md §4).
"""

from __future__ import annotations

from dataclasses import dataclass

from executive.core.frames import AircraftPlacement, Pose2
from executive.core.model import Frame
from executive.core.records import PoseEstimate


@dataclass(frozen=True, slots=True)
class Goal:
    """A goal pose in ``frame``; ``nominal`` resolves an aircraft-frame goal when the pose
    estimate carries no placement (the mission's parking pose)."""

    pose: Pose2
    frame: Frame = Frame.AIRPORT
    nominal: AircraftPlacement | None = None

    def in_airport(self, estimate: PoseEstimate | None) -> Pose2:
        """The goal in A with the estimate's aircraft placement (heading in A)."""
        return self.resolve(self.pose, estimate)

    def resolve(self, pose: Pose2, estimate: PoseEstimate | None) -> Pose2:
        """``pose``, given in this goal's frame, in A with the estimate's aircraft
        placement (heading in A)."""
        if self.frame is Frame.AIRPORT:
            return pose
        placement = estimate.placement if estimate is not None else None
        placement = placement or self.nominal
        if placement is None:
            raise ValueError("an aircraft-frame goal needs a placement")
        return placement.pose_to_airport(pose)
