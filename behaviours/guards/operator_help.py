"""The operator asked for help when the robot is trapped (seed 000 lines 1415-1430: "a
message is sent to the operator asking him / her to help the robot"; issue 15).

With an operator at hand (the HUD of a live dry-run or of the robot), a navigation that
made no progress for the trap period does not fail the mission: :class:`AskWhenTrapped`
holds the robot still and asks "wait, take over, or skip the checkpoint?" (the
``QUESTION`` key, which the HUD shows), then follows the answer:

* ``wait``: the trap period starts again;
* ``take-over``: the operator has the robot (the operator state takes over on that
  answer; the collaborative branch pre-empts the mission) and the trap period starts
  again for when they hand it back;
* ``skip``: the navigation fails with the reason, and :class:`SkipCheckpoint`, the
  checkpoint's fallback, records it completed *and* skipped in the progress (journaled);
  the mission goes on to the next checkpoint.
"""

from __future__ import annotations

import dataclasses

import py_trees

from behaviours.base import Node
from behaviours.guards.conditions import NotTrapped
from behaviours.keys import OPERATOR, PROGRESS, QUESTION, SENSOR_FRAME, MissionProgress
from behaviours.keys import OperatorQuestion as Question
from executive.core.records import OperatorRequests, SensorFrame

Status = py_trees.common.Status

CHOICES = ("wait", "take-over", "skip")


class SkipRequests:
    """The checkpoints the operator chose to skip (shared by the ask and the fallback)."""

    def __init__(self) -> None:
        self.checkpoints: set[str] = set()


class AskWhenTrapped(Node):
    """Behind a :class:`NotTrapped` guard in a selector: RUNNING (the robot holds still,
    the question asked) until the operator answers; SUCCESS on ``wait`` and
    ``take-over``, FAILURE on ``skip``."""

    reads = (OPERATOR, SENSOR_FRAME)
    writes = (QUESTION,)

    def __init__(
        self, trap: NotTrapped, checkpoint: str, skips: SkipRequests, name: str = "ask operator"
    ) -> None:
        super().__init__(name)
        self.trap = trap
        self.checkpoint = checkpoint
        self.skips = skips
        self._asked = 0

    def update(self) -> Status:
        operator: OperatorRequests = self.read(OPERATOR, OperatorRequests())
        frame: SensorFrame | None = self.read(SENSOR_FRAME)
        now = frame.stamp if frame is not None else 0.0
        if operator.answer in ("wait", "take-over"):
            self.trap.restart(now)
            self.feedback_message = f"operator: {operator.answer}"
            return Status.SUCCESS
        if operator.answer == "skip":
            self.skips.checkpoints.add(self.checkpoint)
            self.feedback_message = f"operator: skip {self.checkpoint}"
            return Status.FAILURE
        if self.status != Status.RUNNING:
            self._asked += 1
        text = (
            f"{self.checkpoint}: the robot is trapped ({self.trap.feedback_message}). "
            "Wait, take over, or skip the checkpoint?"
        )
        self.write(QUESTION, Question(now, f"{self.checkpoint}/{self._asked}", text, CHOICES))
        self.feedback_message = f"trapped: asking the operator ({self.trap.feedback_message})"
        return Status.RUNNING


class SkipCheckpoint(Node):
    """The checkpoint's fallback: SUCCESS, recording it completed and skipped, once the
    operator chose to skip it; FAILURE (the mission fails as before) otherwise."""

    reads = (PROGRESS,)
    writes = (PROGRESS,)

    def __init__(self, checkpoint: str, skips: SkipRequests, name: str = "") -> None:
        super().__init__(name or f"skip {checkpoint}?")
        self.checkpoint = checkpoint
        self.skips = skips

    def update(self) -> Status:
        if self.checkpoint not in self.skips.checkpoints:
            self.feedback_message = "not skipped"
            return Status.FAILURE
        progress: MissionProgress = self.read(PROGRESS, MissionProgress())
        if self.checkpoint not in progress.completed:
            progress = dataclasses.replace(
                progress,
                completed=(*progress.completed, self.checkpoint),
                skipped=(*progress.skipped, self.checkpoint),
            )
            self.write(PROGRESS, progress)
        self.feedback_message = f"{self.checkpoint} skipped by the operator"
        return Status.SUCCESS
