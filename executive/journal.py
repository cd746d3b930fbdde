"""Append-only mission journal (JSONL), bound to one mission, written line by line.

Each line is one JSON object, one event: the mission's binding (first line), a
checkpoint started or completed, an item result, a phase, the dry-run judge's ground
truth for a completed checkpoint, an interruption, the mission's end.

The journal is what ``--resume`` trusts to move a robot, so it is strict both ways:

* **Writing**: each record is one ``write`` of a whole line, then ``fsync``; a write that
  fails part-way (a full disk) is cut back to the last whole line before the error is
  raised (:class:`JournalWriteError`), so a journal never holds a torn line written by us.
  A process killed mid-write may still leave one: it is the only thing repaired.
* **Binding**: the first line names the mission (id, SHA-256 of the mission and aircraft
  files, the checkpoints with their poses in F). Resuming with another mission's journal,
  or after the mission or aircraft file changed, is refused with what differs.
* **Reading** (:func:`read_journal`): only a regular file, at most
  :data:`MAX_JOURNAL_BYTES`; a last line without its newline that is not valid JSON is a
  torn write (dropped, and cut off before appending); anything else that is not a known
  record with its fields of the right types is an error at ``journal:line``
  (:class:`~executive.core.problems.InvalidInputError`, exit status 2).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import os
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path

from behaviours.keys import ItemResult, MissionProgress
from executive.core.files import UnusableFileError, describe_os_error, read_regular
from executive.core.model import Mission
from executive.core.problems import InvalidInputError, Problem, SourceLocation

FORMAT = 2
"""Journal format version, in the binding line."""

MAX_JOURNAL_BYTES = 64 << 20
"""A journal longer than this is not one we wrote (a whole A320 mission is ~30 kB)."""

MAX_LINE_BYTES = 64 << 10
"""The longest line we write is an item record (~300 bytes)."""

PHASES = ("approach", "inspection", "return", "done")
MOVED_TOLERANCE = 1e-6
"""A checkpoint whose pose in F changed by more than this (m or rad) has moved."""


class JournalWriteError(OSError):
    """The journal could not be written (disk full, I/O error); it holds whole lines only."""


# -- the binding: which mission a journal belongs to -------------------------------------------
def _sha256(path: str) -> str:
    if not path:
        return ""
    try:
        return hashlib.sha256(read_regular(path, 64 << 20)).hexdigest()
    except UnusableFileError:
        return ""


@dataclass(frozen=True)
class MissionBinding:
    """What binds a journal to one mission: its id, the content hashes of the mission and
    aircraft files, and the checkpoints (id and pose in F) in order."""

    mission_id: str
    mission_sha256: str
    aircraft_sha256: str
    checkpoints: tuple[tuple[str, float, float, float], ...]

    @classmethod
    def of(cls, mission: Mission) -> MissionBinding:
        return cls(
            mission.id,
            _sha256(mission.source),
            _sha256(mission.aircraft.source),
            tuple((c.id, c.pose.x, c.pose.y, c.pose.theta) for c in mission.checkpoints),
        )

    def as_record(self) -> dict[str, object]:
        return {
            "event": "mission-start",
            "format": FORMAT,
            "mission": self.mission_id,
            "mission_sha256": self.mission_sha256,
            "aircraft_sha256": self.aircraft_sha256,
            "checkpoints": [
                [c, round(x, 9), round(y, 9), round(t, 9)] for c, x, y, t in self.checkpoints
            ],
        }

    def differences(self, current: MissionBinding) -> list[str]:
        """What differs between the journal's mission (self) and ``current``; empty when
        the journal belongs to it."""
        if self.mission_id != current.mission_id:
            return [f"it belongs to mission '{self.mission_id}', not '{current.mission_id}'"]
        out: list[str] = []
        mine = {c[0]: c[1:] for c in self.checkpoints}
        theirs = {c[0]: c[1:] for c in current.checkpoints}
        added = [c for c in theirs if c not in mine]
        removed = [c for c in mine if c not in theirs]
        moved = [
            c
            for c in mine
            if c in theirs
            and any(abs(a - b) > MOVED_TOLERANCE for a, b in zip(mine[c], theirs[c], strict=True))
        ]
        if added:
            out.append("checkpoints added since: " + ", ".join(added))
        if removed:
            out.append("checkpoints removed since: " + ", ".join(removed))
        if moved:
            out.append("checkpoints moved since: " + ", ".join(moved))
        kept = [c for c in mine if c in theirs]
        if not (added or removed) and kept != [c for c in theirs if c in mine]:
            out.append("checkpoints reordered since")
        if self.aircraft_sha256 != current.aircraft_sha256:
            out.append("the aircraft file changed since")
        if self.mission_sha256 != current.mission_sha256 and not out:
            out.append("the mission file changed since (its checkpoints did not)")
        return out


# -- writing -------------------------------------------------------------------------------------
class Journal:
    """Writes progress events as they happen; one JSON object per line, fsync'ed.

    ``append`` continues an existing journal (after :func:`read_journal` checked it):
    its torn last line, if any, is cut off first (``keep_bytes``).
    """

    def __init__(
        self,
        path: Path,
        binding: MissionBinding | str,
        *,
        append: bool = False,
        keep_bytes: int | None = None,
        pose_period: float | None = None,
    ) -> None:
        """``pose_period``: also record the pose estimate every so many seconds (a robot
        run: a resume starts from where the robot stood, not its last checkpoint)."""
        self.path = path
        self.pose_period = pose_period
        self._pose_at = -math.inf
        if isinstance(binding, str):  # a bare mission id: a journal for tests and tools
            binding = MissionBinding(binding, "", "", ())
        self.binding = binding
        flags = os.O_RDWR | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0) | os.O_APPEND
        if not append:
            flags |= os.O_TRUNC
        try:
            self._fd: int | None = os.open(path, flags, 0o644)
        except OSError as exc:
            raise JournalWriteError(exc.errno, describe_os_error(exc, path, "opening")) from None
        if append and keep_bytes is not None:
            os.ftruncate(self._fd, keep_bytes)
        self._size = os.fstat(self._fd).st_size
        if append and self._size and os.pread(self._fd, 1, self._size - 1) != b"\n":
            self._append(b"\n")  # a whole last line that lost only its newline
        self._last = MissionProgress()
        if not append:
            self.write(binding.as_record())

    def write(self, record: Mapping[str, object]) -> None:
        """Append one record as one whole line, or raise :class:`JournalWriteError` with
        the journal cut back to its last whole line."""
        if self._fd is None:
            raise JournalWriteError(0, f"journal {self.path} is closed")
        self._append((json.dumps(record, separators=(",", ":"), allow_nan=False) + "\n").encode())

    def _append(self, data: bytes) -> None:
        assert self._fd is not None
        try:
            view = memoryview(data)
            while view:
                view = view[os.write(self._fd, view) :]
            os.fsync(self._fd)
        except OSError as exc:
            with contextlib.suppress(OSError):
                os.ftruncate(self._fd, self._size)
            raise JournalWriteError(exc.errno, describe_os_error(exc, self.path)) from None
        self._size += len(data)

    def resume_from(self, progress: MissionProgress) -> None:
        self._last = progress

    def record(
        self,
        t: float,
        progress: MissionProgress,
        pose: tuple[float, ...] | None,
        *,
        sigma_f: float | None = None,
        travel: tuple[float, float] | None = None,
    ) -> None:
        """Write what changed since the last call; a completed checkpoint carries the pose
        (in A) and the estimate's position uncertainty (``sigma_f``, m) it was completed
        with. A pose record (every ``pose_period``) carries the base's odometers
        (``travel``, :class:`executive.core.records.WheelSpeeds`) when known."""
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
            if pose is not None and all(math.isfinite(v) for v in pose):
                record["pose_a"] = [round(v, 6) for v in pose]
            if sigma_f is not None and math.isfinite(sigma_f):
                record["sigma_f"] = round(sigma_f, 4)
            if cp in progress.skipped:
                record["skipped"] = True  # by the operator, trapped: not inspected
            self.write(record)
        if progress.phase != last.phase:
            self.write({"t": round(t, 3), "event": "phase", "phase": progress.phase})
        self._last = progress
        period = self.pose_period
        due = period is not None and t - self._pose_at >= period
        if due and pose is not None and all(math.isfinite(v) for v in pose):
            self._pose_at = t
            pose_a = [round(v, 6) for v in pose]
            line: dict[str, object] = {"t": round(t, 3), "event": "pose", "pose_a": pose_a}
            if travel is not None and all(math.isfinite(v) for v in travel):
                line["travel"] = [round(v, 4) for v in travel]
            self.write(line)

    def close(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None

    def __enter__(self) -> Journal:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# -- reading -------------------------------------------------------------------------------------
@dataclass
class JournalState:
    """What a journal says: the progress to resume, where the last checkpoint was
    completed (pose in A), the ground truth the dry-run judge recorded per checkpoint,
    and how it ended (None: it did not)."""

    binding: MissionBinding
    progress: MissionProgress
    pose_a: tuple[float, float, float] | None
    truth: dict[str, dict[str, object]] = field(default_factory=dict)
    ended: str | None = None
    end_t: float | None = None
    keep_bytes: int = 0
    """Bytes of whole lines: a torn last line starts here and is cut off on append."""
    last_pose: tuple[float, float, float] | None = None
    """The latest pose estimate in A the journal recorded (``pose`` records of a robot
    run, every :data:`POSE_PERIOD`): where a robot stopped mid-leg really stands, which
    its last checkpoint's pose is not."""
    last_travel: tuple[float, float] | None = None
    """The base's odometers (left, right, m) when :attr:`last_pose` was recorded, if it
    reports them: with the odometers now, how far the robot moved since."""


MAX_MAGNITUDE = 1e6
"""No time (s) or coordinate (m) a journal records is larger: anything beyond is not ours."""


def _number(v: object) -> bool:
    if isinstance(v, bool) or not isinstance(v, int | float):
        return False
    if isinstance(v, int):
        return abs(v) <= MAX_MAGNITUDE  # a 400-digit integer: no float conversion
    return math.isfinite(v) and abs(v) <= MAX_MAGNITUDE


def _str(v: object) -> bool:
    return isinstance(v, str) and 0 < len(v) <= 200


def _triple(v: object) -> bool:
    return isinstance(v, list) and len(v) == 3 and all(_number(x) for x in v)


def _pair(v: object) -> bool:
    return isinstance(v, list) and len(v) == 2 and all(_number(x) for x in v)


def _bool(v: object) -> bool:
    return isinstance(v, bool)


def _optional_number(v: object) -> bool:
    return v is None or _number(v)


Check = Callable[[object], bool]
_FIELDS: dict[str, dict[str, tuple[Check, str]]] = {
    "mission-start": {
        "format": (lambda v: v == FORMAT, f"the format number {FORMAT}"),
        "mission": (_str, "a string"),
        "mission_sha256": (lambda v: isinstance(v, str), "a string"),
        "aircraft_sha256": (lambda v: isinstance(v, str), "a string"),
        "checkpoints": (
            lambda v: (
                isinstance(v, list)
                and all(
                    isinstance(c, list) and len(c) == 4 and _str(c[0]) and all(map(_number, c[1:]))
                    for c in v
                )
            ),
            "a list of [id, x, y, theta]",
        ),
    },
    "checkpoint-start": {"t": (_number, "a number"), "checkpoint": (_str, "a string")},
    "checkpoint-done": {"t": (_number, "a number"), "checkpoint": (_str, "a string")},
    "item": {
        "t": (_number, "a number"),
        "checkpoint": (_str, "a string"),
        "item": (_str, "a string"),
        "stamp": (_number, "a number"),
        "detected": (_bool, "true or false"),
        "camera": (_str, "a string"),
        "pan": (_number, "a number"),
        "tilt": (_number, "a number"),
        "pose_f": (_triple, "three numbers"),
    },
    "phase": {
        "t": (_number, "a number"),
        "phase": (lambda v: v in PHASES, "one of " + ", ".join(PHASES)),
    },
    "checkpoint-truth": {
        "checkpoint": (_str, "a string"),
        "time": (_number, "a number"),
        "position_error": (_optional_number, "a number or null"),
        "heading_error_deg": (_optional_number, "a number or null"),
    },
    "resume": {"t": (_number, "a number")},
    "pose": {"t": (_number, "a number"), "pose_a": (_triple, "three numbers")},
    "interrupted": {"t": (_number, "a number"), "reason": (_str, "a string")},
    "stopped": {"t": (_number, "a number"), "reason": (_str, "a string")},
    "mission-end": {"t": (_number, "a number"), "outcome": (_str, "a string")},
}
_OPTIONAL: dict[str, dict[str, tuple[Check, str]]] = {
    "checkpoint-done": {"pose_a": (_triple, "three numbers"), "sigma_f": (_number, "a number")},
    "item": {"stale": (_bool, "true or false")},
    "pose": {"travel": (_pair, "two numbers")},
}


def _problem(path: Path, line: int, message: str, code: str = "journal") -> InvalidInputError:
    return InvalidInputError([Problem(SourceLocation(str(path), line, 0), code, message)])


def read_journal(path: Path) -> JournalState:
    """Read and check a journal (see the module docstring); raises
    :class:`~executive.core.problems.InvalidInputError` naming the journal's line."""
    try:
        data = read_regular(path, MAX_JOURNAL_BYTES)
    except UnusableFileError as exc:
        raise _problem(path, 0, str(exc).removeprefix(f"{path}: "), "journal-file") from None
    lines = data.split(b"\n")
    keep = len(data)
    if lines and lines[-1] == b"":
        lines.pop()
    elif lines:  # the last line has no newline: a write cut short, or whole but unterminated
        try:
            json.loads(lines[-1])
        except (ValueError, RecursionError):
            keep -= len(lines[-1])
            lines.pop()
    if not lines:
        raise _problem(path, 1, "the journal is empty: there is nothing to resume")

    binding: MissionBinding | None = None
    completed: list[str] = []
    skipped: list[str] = []
    results: list[ItemResult] = []
    truth: dict[str, dict[str, object]] = {}
    phase, checkpoint = "approach", None
    pose = last_pose = None
    last_travel: tuple[float, float] | None = None
    ended = end_t = None
    for number, raw in enumerate(lines, start=1):
        if len(raw) > MAX_LINE_BYTES:
            raise _problem(path, number, f"a line longer than {MAX_LINE_BYTES} bytes")
        try:
            record = json.loads(raw)
        except (ValueError, RecursionError) as exc:
            msg = getattr(exc, "msg", "nested too deeply")
            raise _problem(path, number, f"not a JSON line ({msg})") from None
        if not isinstance(record, dict):
            raise _problem(
                path, number, f"a journal line is a JSON object, not {type(record).__name__}"
            )
        event = record.get("event")
        if not isinstance(event, str) or event not in _FIELDS:
            raise _problem(path, number, f"unknown journal event {event!r}")
        for name, (ok, what) in _FIELDS[event].items():
            if name not in record:
                raise _problem(path, number, f"'{event}' record without its '{name}' field")
            if not ok(record[name]):
                raise _problem(path, number, f"'{event}' field '{name}' must be {what}")
        for name, (ok, what) in _OPTIONAL.get(event, {}).items():
            if name in record and not ok(record[name]):
                raise _problem(path, number, f"'{event}' field '{name}' must be {what}")
        if (number == 1) != (event == "mission-start"):
            raise _problem(
                path,
                number,
                "the first line binds the journal to its mission ('mission-start')"
                if number == 1
                else "a second 'mission-start' record",
            )
        if event == "mission-start":
            binding = MissionBinding(
                record["mission"],
                record["mission_sha256"],
                record["aircraft_sha256"],
                tuple((c[0], float(c[1]), float(c[2]), float(c[3])) for c in record["checkpoints"]),
            )
            continue
        assert binding is not None
        known = {c[0] for c in binding.checkpoints}
        cp = record.get("checkpoint")
        if cp is not None and cp not in known:
            raise _problem(path, number, f"checkpoint '{cp}' is not one of the journal's mission")
        if event == "checkpoint-done":
            if cp in completed:
                raise _problem(path, number, f"checkpoint '{cp}' completed twice")
            order = [c[0] for c in binding.checkpoints]
            expected = order[len(completed)] if len(completed) < len(order) else None
            if cp != expected:
                raise _problem(
                    path,
                    number,
                    f"checkpoint '{cp}' completed before '{expected}': checkpoints are "
                    "completed in the mission's order",
                )
            completed.append(cp)
            if record.get("skipped") is True:
                skipped.append(cp)
            checkpoint = cp
            if "pose_a" in record:
                pose = tuple(float(v) for v in record["pose_a"])
        elif event == "item":
            fields = {k: record[k] for k in ItemResult.__dataclass_fields__ if k in record}
            fields["pose_f"] = tuple(fields["pose_f"])
            results.append(ItemResult(**fields))
        elif event == "phase":
            phase = record["phase"]
        elif event == "checkpoint-truth":
            truth[cp] = {k: v for k, v in record.items() if k != "event"}
        elif event == "mission-end":
            ended, end_t = record["outcome"], float(record["t"])
        elif event == "pose":
            last_pose = tuple(float(v) for v in record["pose_a"])
            travel = record.get("travel")
            last_travel = (float(travel[0]), float(travel[1])) if travel is not None else None
        elif event == "resume":  # what a stopped attempt inspected is done again
            ended = end_t = None
            results = [r for r in results if r.checkpoint in completed]
    assert binding is not None
    # Items of a checkpoint that was not finished are inspected again on resume.
    kept = tuple(r for r in results if r.checkpoint in completed)
    progress = MissionProgress(
        phase=phase,
        checkpoint=checkpoint,
        completed=tuple(completed),
        results=kept,
        skipped=tuple(skipped),
    )
    return JournalState(
        binding=binding,
        progress=progress,
        pose_a=pose,  # type: ignore[arg-type]
        truth={k: v for k, v in truth.items() if k in completed},
        ended=ended,
        end_t=end_t,
        keep_bytes=keep,
        last_pose=last_pose,  # type: ignore[arg-type]
        last_travel=last_travel,
    )


def check_resumable(state: JournalState, mission: Mission, path: Path) -> None:
    """Refuse a journal that does not belong to ``mission`` as it is now (exit status 2)."""
    differences = state.binding.differences(MissionBinding.of(mission))
    if differences:
        raise _problem(
            path,
            1,
            f"cannot resume {mission.id} ({mission.source}) from this journal: "
            + "; ".join(differences),
            "journal-mismatch",
        )


RESUME_MARGIN = 60.0
"""How far (m) from where the nominal parking puts a checkpoint the journal may say it
was completed: the parking offsets a scenario may give (50 m, any heading) and room."""


def check_resume_pose(state: JournalState, mission: Mission, path: Path) -> None:
    """Refuse a journal whose last checkpoint pose (where the robot will start) cannot be
    that checkpoint's: farther from it than any parking of the aircraft could put it."""
    if state.pose_a is None or not state.progress.completed:
        return
    cp_id = state.progress.completed[-1]
    cp = next(c for c in mission.checkpoints if c.id == cp_id)
    nominal = mission.nominal_placement().pose_to_airport(cp.pose)
    x, y, _ = state.pose_a
    reach = RESUME_MARGIN + 2.0 * math.hypot(cp.pose.x, cp.pose.y)  # turned about the nose
    distance = math.hypot(x - nominal.x, y - nominal.y)
    if distance > reach:
        raise _problem(
            path,
            0,
            f"checkpoint '{cp_id}' is recorded completed at ({x:.1f}, {y:.1f}) in A, "
            f"{distance:.0f} m from where it can be (at most {reach:.0f} m)",
            "journal-pose",
        )
