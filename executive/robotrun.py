"""``walkaround run``: the executive on the robot (issue 14).

The same compiled tree, safety layer, journal and runtime as a dry-run, on the wall
clock, against a :class:`~executive.robotlink.link.RobotLink` instead of sim2d. What a
dry-run's judge measures on ground truth is not known here: the report says what the
executive knows (outcome and reason, checkpoints completed and when, the estimate's own
uncertainty, safety stops, tick deadlines, link statistics), and the CAN traffic of the
run is logged (``can.blf``) so that cantools or any python-can tool can replay it.
Checkpoint completions carry the wall-clock time (``unix``) so that a hardware-in-the-
loop simulator's ground truth can judge the run afterwards (:mod:`executive.hil`).
"""

from __future__ import annotations

import gc
import json
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TextIO

import py_trees

from behaviours.keys import POSE, PROGRESS, MissionProgress
from behaviours.sensing.localisation import Localise
from executive.compiler import CompileOptions, compile_mission
from executive.core.files import write_atomic
from executive.core.frames import Pose2
from executive.core.model import Mission
from executive.core.records import PoseEstimate, SensorFrame, VelocityCommand
from executive.journal import Journal, JournalState, MissionBinding
from executive.operator import OperatorState
from executive.recording import Recorder, chain
from executive.robotlink.canbase import travel_difference
from executive.runtime import (
    DEFAULT_MAX_MISSED_DEADLINES,
    Clock,
    RunResult,
    Runtime,
    StopRequest,
    TickHook,
    WallClock,
)
from executive.safety import SafetyLayer

REPORT_FILES = ("metrics.json", "events.jsonl")
POSE_PERIOD = 0.2
"""Seconds between the pose records of a robot run's journal. A run killed mid-leg
resumes from the last of them plus the motion the base's odometers counted since (the
robot drove on until its watchdog braked it)."""


@dataclass
class CheckpointDone:
    """A checkpoint the executive completed: when (run clock and Unix time) and where it
    believed the robot was in F, with its own position uncertainty."""

    id: str
    t: float
    unix: float
    pose_f: tuple[float, float, float] | None
    sigma_f: float | None


@dataclass
class RobotRun:
    mission: Mission
    result: RunResult
    checkpoints: list[CheckpointDone]
    link: dict[str, object]
    resumed_from: tuple[str, ...] = ()
    wall_start: float = 0.0
    moved_while_down: tuple[float, float] | None = None
    """A resumed run: how far (m) the base's odometers say the left and right sides
    travelled between the journal's last pose and the start (the robot coasting and
    braking after the executive died); the start pose includes it."""
    recording: Path | None = None
    """The run's MCAP recording for Foxglove (issue 15), when one was asked for."""
    recording_error: str | None = None
    """Why the recording stopped early or never started (the run went on), or None."""

    @property
    def succeeded(self) -> bool:
        return self.result.outcome == "completed"


class _Watcher:
    """Per tick: checkpoint completions with their time, and the progress line (on a
    terminal only: a log file gets the summary line)."""

    def __init__(self, mission: Mission, out: TextIO | None, done: tuple[str, ...]) -> None:
        self.n = len(mission.checkpoints)
        self.seen = set(done)
        self.checkpoints: list[CheckpointDone] = []
        self.out = out
        self._next_print = 0.0

    def __call__(self, t: float, frame: SensorFrame, sent: VelocityCommand, rt: Runtime) -> None:
        progress = rt._get(PROGRESS.name)
        if isinstance(progress, MissionProgress):
            pose = rt._get(POSE.name)
            for cp in progress.completed:
                if cp in self.seen:
                    continue
                self.seen.add(cp)
                pf = pose.pose_f if isinstance(pose, PoseEstimate) else None
                self.checkpoints.append(
                    CheckpointDone(
                        cp,
                        round(t, 3),
                        time.time(),
                        (round(pf.x, 4), round(pf.y, 4), round(pf.theta, 5)) if pf else None,
                        pose.sigma_f if isinstance(pose, PoseEstimate) else None,
                    )
                )
        if self.out is not None and t >= self._next_print and self.out.isatty():
            self._next_print = t + 1.0
            self.out.write(
                f"\r{t:6.1f} s  {len(self.seen)}/{self.n} checkpoints  "
                f"{rt.controller[:40]:<40}  v {sent.v:+.2f} m/s"
            )
            self.out.flush()

    def close(self) -> None:
        if self.out is not None and self.out.isatty():
            self.out.write("\n")


class NotStartedError(Exception):
    """A signal came while the base was being brought up: nothing was changed."""


def robot_run(
    mission: Mission,
    link: object,
    *,
    clock: Clock | None = None,
    rate_hz: float = 50.0,
    journal_path: Path | None = None,
    resume: JournalState | None = None,
    operator: OperatorState | None = None,
    stop: StopRequest | None = None,
    max_missed_deadlines: int | None = DEFAULT_MAX_MISSED_DEADLINES,
    max_time: float | None = None,
    progress_out: TextIO | None = None,
    servo: bool | None = None,
    before_start: Callable[[], None] | None = None,
    record: Path | None = None,
    observers: Sequence[TickHook] = (),
) -> RobotRun:
    """Run ``mission`` on the robot behind ``link`` (a RobotInterface) on the wall clock.

    ``clock`` must be the one the link stamps its readings with (default: a new
    :class:`WallClock`). Everything slow (compiling the tree, a full garbage collection,
    after which the run's long-lived objects are frozen) happens before the link is
    brought up (its ``wait_ready``, if it has one): from then on a tick feeds the base's
    watchdog every period. Then ``before_start`` (the CLI clears the old report) and the
    journal. Raises what ``wait_ready`` raises when the base is not ready, and
    :class:`NotStartedError` when ``stop`` was set meanwhile. ``record`` names an MCAP
    file to record the run to for Foxglove; ``observers`` are called after every tick (the
    HUD's telemetry) (:mod:`executive.recording`; message times are
    Unix times), opened with the journal; a recording that fails never stops the robot.
    """
    stop = stop if stop is not None else StopRequest()
    clock = clock or WallClock()
    progress = resume.progress if resume is not None else None
    where = resume.last_pose or resume.pose_a if resume is not None else None
    start = Pose2(*where) if where else None  # where the robot stood when it stopped
    compiled = compile_mission(
        mission,
        CompileOptions(
            rate_hz=rate_hz,
            start=start,
            resume=progress,
            servo=servo,
            ask_operator=operator is not None,
        ),
    )
    safety = SafetyLayer(
        mission, compiled.placement, 1.0 / rate_hz, geofence_margin=mission.safety.geofence_margin
    )
    done = progress.completed if progress is not None else ()
    watcher = _Watcher(mission, progress_out, done)
    gc.collect()
    gc.freeze()  # no full collection walks the tree and maps mid-run (see runtime)
    try:
        ready = getattr(link, "wait_ready", None)
        if callable(ready) and not ready(should_stop=lambda: bool(stop)):
            raise NotStartedError(f"{stop.reason} before the run started; nothing changed")
        moved = _moved_while_down(resume, link)
        if moved is not None:
            _localiser(compiled.root).moved_before_start(*moved)
        if before_start is not None:
            before_start()
        journal = None
        if journal_path is not None:
            journal = Journal(
                journal_path,
                MissionBinding.of(mission),
                append=resume is not None,
                keep_bytes=resume.keep_bytes if resume is not None else None,
                pose_period=POSE_PERIOD,
            )
            if progress is not None:
                journal.resume_from(progress)
                journal.write({"event": "resume", "t": round(clock.now(), 3)})
        recorder, recording_error = None, None
        if record is not None:
            try:
                recorder = Recorder.open(
                    record, mission, placement=compiled.placement, epoch=time.time() - clock.now()
                )
            except OSError as exc:
                recording_error = f"cannot record to {record}: {exc.strerror or exc}"
        runtime = Runtime(
            compiled,
            link,  # type: ignore[arg-type]
            clock,
            safety,
            rate_hz=rate_hz,
            journal=journal,
            operator=operator,
            on_tick=chain(watcher, recorder.on_tick if recorder is not None else None, *observers),
            stop=stop,
            max_missed_deadlines=max_missed_deadlines,
        )
        wall_start = time.time()
        try:
            result = runtime.run(max_time if max_time is not None else float("inf"))
            if recorder is not None:
                recorder.close(runtime, result)
        finally:
            watcher.close()
            if recorder is not None:
                recorder.close(runtime)  # when the run raised; else already closed
    finally:
        gc.unfreeze()
    if journal is not None:
        t_end = round(clock.now(), 3)
        end: dict[str, object] = (
            {"t": t_end, "event": "interrupted", "reason": result.reason}
            if result.outcome == "interrupted"
            else {"t": t_end, "event": "mission-end", "outcome": result.outcome}
        )
        try:
            journal.write(end)
        finally:
            journal.close()
    stats = getattr(link, "statistics", None)
    return RobotRun(
        mission=mission,
        result=result,
        checkpoints=watcher.checkpoints,
        link=stats() if callable(stats) else {},
        resumed_from=tuple(done),
        wall_start=wall_start,
        moved_while_down=moved,
        recording=record if recorder is not None else None,
        recording_error=recorder.error if recorder is not None else recording_error,
    )


def _moved_while_down(resume: JournalState | None, link: object) -> tuple[float, float] | None:
    """(left, right) travel (m) of the base's odometers since the journal's last pose
    record, when both that record and the base carry them (WHEEL_TRAVEL); None otherwise
    (the run starts at the recorded pose, up to the braking distance off)."""
    if resume is None or resume.last_pose is None or resume.last_travel is None:
        return None
    read = getattr(link, "read", None)
    wheels = read().wheels if callable(read) else None
    if wheels is None or wheels.travel is None:
        return None
    (left, right), (left0, right0) = wheels.travel, resume.last_travel
    return travel_difference(left, left0), travel_difference(right, right0)


def _localiser(root: py_trees.behaviour.Behaviour) -> Localise:
    return next(node for node in root.iterate() if isinstance(node, Localise))


def robot_metrics(run: RobotRun) -> dict[str, object]:
    """metrics.json of a robot run: what the executive knows, without ground truth."""
    result = run.result
    return {
        "mission": run.mission.id,
        "outcome": result.outcome,
        "succeeded": run.succeeded,
        "reason": result.reason,
        "traceback": result.traceback,
        "stop_sent": result.stop_sent,
        "wall_start_unix": run.wall_start,
        "duration_s": round(result.duration, 3),
        "checkpoints_total": len(run.mission.checkpoints),
        "checkpoints_completed": len(result.progress.completed),
        "resumed_after": list(run.resumed_from),
        "moved_while_down_m": (
            None if run.moved_while_down is None else [round(v, 4) for v in run.moved_while_down]
        ),
        "checkpoints": [cp.__dict__ for cp in run.checkpoints],
        "tick_timing": result.stats.summary(),
        "link": run.link,
        "safety_stops": [
            e.as_dict() for e in result.events if e.kind in ("safety", "link-lost", "fault")
        ],
        "recording": run.recording.name if run.recording is not None else None,
        "recording_error": run.recording_error,
    }


def write_robot_report(run: RobotRun, out: Path) -> None:
    """metrics.json and events.jsonl, each written whole (temporary file + rename)."""
    out.mkdir(parents=True, exist_ok=True)
    write_atomic(out / "metrics.json", (json.dumps(robot_metrics(run), indent=2) + "\n").encode())
    events = "".join(
        json.dumps(e.as_dict(), separators=(",", ":")) + "\n" for e in run.result.events
    )
    write_atomic(out / "events.jsonl", events.encode())
