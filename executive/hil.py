"""Judging a hardware-in-the-loop run on the simulator's ground truth (issue 14).

``walkaround sim-robot`` writes ``truth.jsonl`` (the true robot pose in A at 10 Hz with
the Unix time, collisions, watchdog braking) and ``walkaround run`` writes each
checkpoint's completion with its Unix time in ``metrics.json``; the two processes share
nothing else. :func:`judge_hil` pairs them: where the robot really was when the executive
said a checkpoint was done, against the checkpoint's true pose (the aircraft at its true
parking pose). The robot's executive never sees any of it.
"""

from __future__ import annotations

import bisect
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

from executive.core.frames import Pose2, wrap_angle
from sim2d.scenario import Scenario

TRUTH_FILE = "truth.jsonl"


@dataclass
class TruthLog:
    """The simulator's record: poses in A by Unix time, and events."""

    unix: list[float] = field(default_factory=list)
    poses: list[Pose2] = field(default_factory=list)
    events: list[dict[str, object]] = field(default_factory=list)

    @classmethod
    def read(cls, path: Path) -> TruthLog:
        log = cls()
        for line in path.read_text().splitlines():
            try:
                record = json.loads(line)
            except ValueError:  # a torn last line of a killed simulator
                continue
            if "robot" in record:
                log.unix.append(float(record["unix"]))
                log.poses.append(Pose2(*record["robot"]))
            else:
                log.events.append(record)
        return log

    def pose_at(self, unix: float) -> Pose2 | None:
        """The true pose at Unix time ``unix`` (the nearest earlier sample)."""
        k = bisect.bisect_right(self.unix, unix) - 1
        return self.poses[k] if k >= 0 else None

    def of_kind(self, kind: str) -> list[dict[str, object]]:
        return [e for e in self.events if e.get("event") == kind]


@dataclass(frozen=True)
class HilCheckpoint:
    id: str
    position_error: float
    heading_error_deg: float


def judge_hil(scenario: Scenario, truth: TruthLog, metrics: dict) -> list[HilCheckpoint]:
    """Each checkpoint the run completed, against where the robot really was then."""
    placement = scenario.true_placement()
    by_id = {cp.id: cp for cp in scenario.mission.checkpoints}
    judged = []
    for done in metrics.get("checkpoints", []):
        cp = by_id[done["id"]]
        true = truth.pose_at(float(done["unix"]))
        if true is None:
            continue
        goal = placement.pose_to_airport(cp.pose)
        judged.append(
            HilCheckpoint(
                cp.id,
                math.hypot(goal.x - true.x, goal.y - true.y),
                math.degrees(abs(wrap_angle(goal.theta - true.theta))),
            )
        )
    return judged
