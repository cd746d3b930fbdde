"""Append-only mission journal (JSONL), flushed per line, tolerant of a torn last line.

Each line is one event: a checkpoint started, reached or completed, an item result, the
mission's end. A run killed at any instant leaves at worst a torn last line, which
:func:`read_journal` ignores; ``--resume`` then continues after the last completed
checkpoint, so none is repeated or skipped.
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict
from pathlib import Path
from typing import IO

from behaviours.keys import ItemResult, MissionProgress


class Journal:
    """Writes progress events as they happen; one JSON object per line, fsync'ed."""

    def __init__(self, path: Path, mission_id: str, *, append: bool = False) -> None:
        self.path = path
        path.parent.mkdir(parents=True, exist_ok=True)
        self._out: IO[str] = path.open("a" if append else "w", encoding="utf-8")
        self._last = MissionProgress()
        if not append:
            self.write({"event": "mission-start", "mission": mission_id})

    def write(self, record: dict[str, object]) -> None:
        self._out.write(json.dumps(record, separators=(",", ":")) + "\n")
        self._out.flush()
        os.fsync(self._out.fileno())

    def resume_from(self, progress: MissionProgress) -> None:
        self._last = progress

    def record(self, t: float, progress: MissionProgress, pose: tuple[float, ...] | None) -> None:
        """Write what changed since the last call."""
        last = self._last
        if progress.checkpoint != last.checkpoint and progress.checkpoint is not None:
            self.write(
                {"t": round(t, 3), "event": "checkpoint-start", "checkpoint": progress.checkpoint}
            )
        for result in progress.results[len(last.results) :]:
            self.write({"t": round(t, 3), "event": "item", **asdict(result)})
        for cp in progress.completed[len(last.completed) :]:
            record: dict[str, object] = {
                "t": round(t, 3),
                "event": "checkpoint-done",
                "checkpoint": cp,
            }
            if pose is not None:
                record["pose_a"] = [round(v, 6) for v in pose]
            self.write(record)
        if progress.phase != last.phase:
            self.write({"t": round(t, 3), "event": "phase", "phase": progress.phase})
        self._last = progress

    def close(self) -> None:
        self._out.close()


def read_journal(path: Path) -> tuple[MissionProgress, tuple[float, float, float] | None]:
    """The progress a journal records, and the pose (in A) of its last completed
    checkpoint; a torn or unreadable last line is ignored."""
    completed: list[str] = []
    results: list[ItemResult] = []
    phase, checkpoint = "approach", None
    pose = None
    if not path.exists():
        return MissionProgress(), None
    lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    for number, line in enumerate(lines):
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            if number == len(lines) - 1:
                break  # torn by a crash mid-write
            raise
        event = record.get("event")
        if event == "checkpoint-done":
            completed.append(record["checkpoint"])
            checkpoint = record["checkpoint"]
            if "pose_a" in record:
                pose = tuple(record["pose_a"])
        elif event == "item":
            fields = {k: record[k] for k in ItemResult.__dataclass_fields__}
            fields["pose_f"] = tuple(fields["pose_f"])
            results.append(ItemResult(**fields))
        elif event == "phase":
            phase = record["phase"]
    # Items of a checkpoint that was not finished are inspected again on resume.
    kept = tuple(r for r in results if r.checkpoint in completed)
    progress = MissionProgress(
        phase=phase, checkpoint=checkpoint, completed=tuple(completed), results=kept
    )
    return progress, pose  # type: ignore[return-value]
