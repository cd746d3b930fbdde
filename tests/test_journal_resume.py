"""The journal belongs to one mission and never poisons a resume (issue 12 §4).

Each hostile journal is refused by ``walkaround dry-run --resume`` with exit status 2, a
message naming the journal's line, no traceback, and nothing driven (no report written).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import shutil
from pathlib import Path

import pytest

from behaviours.keys import ItemResult, MissionProgress
from executive.cli import main
from executive.compiler import CompileOptions, compile_mission
from executive.core.frames import Pose2
from executive.core.loader import load_mission
from executive.dryrun import dry_run
from executive.journal import (
    Journal,
    JournalWriteError,
    MissionBinding,
    check_resumable,
    read_journal,
)
from sim2d.scenario import load_scenario

MISSIONS = Path(__file__).resolve().parents[1] / "missions"
LAB = MISSIONS / "lab" / "visual-servoing.xml"
LAB_SCENARIO = MISSIONS / "lab" / "scenarios" / "clear-apron.xml"


def _binding() -> MissionBinding:
    return MissionBinding.of(load_mission(LAB))


def _lines(binding: MissionBinding, *records: dict) -> str:
    out = [json.dumps(binding.as_record())]
    out += [json.dumps(r) for r in records]
    return "\n".join(out) + "\n"


CP1_DONE = (
    {"t": 1.0, "event": "checkpoint-start", "checkpoint": "CP1"},
    {"t": 18.0, "event": "checkpoint-done", "checkpoint": "CP1", "pose_a": [1.5, 3.5, -1.57]},
)


def _resume(out: Path, capsys, mission: Path = LAB) -> tuple[int, str]:
    code = main(["dry-run", str(mission), "--out", str(out), "--quiet", "--resume"])
    captured = capsys.readouterr()
    text = captured.out + captured.err
    assert "Traceback" not in text
    return code, text.replace(": error: ", ": ")


def _write_journal(out: Path, text: str | bytes) -> Path:
    out.mkdir(parents=True, exist_ok=True)
    path = out / "journal.jsonl"
    path.write_bytes(text.encode() if isinstance(text, str) else text)
    return path


@pytest.mark.parametrize(
    ("content", "expected"),
    [
        ("", "journal.jsonl:1: the journal is empty"),
        ('{"event":"mission-start","mission":"lab-visual-servoing"}\n', "'format'"),
        ("[1, 2, 3]\n", "journal.jsonl:1: a journal line is a JSON object, not list"),
        ('"just a string"\n', "not str"),
        ("BINDING\n{broken json\n" + json.dumps(CP1_DONE[1]) + "\n", "journal.jsonl:2: not a JSON"),
        (
            "BINDING\n" + '{"t": 1.0, "event": "teleport"}\n',
            "journal.jsonl:2: unknown journal event",
        ),
        ("BINDING\n" + '{"t": 1.0, "event": "checkpoint-done"}\n', "without its 'checkpoint'"),
        (
            "BINDING\n" + '{"t": "soon", "event": "checkpoint-done", "checkpoint": "CP1"}\n',
            "field 't' must be a number",
        ),
        ("BINDING\n" + '{"t": NaN, "event": "phase", "phase": "return"}\n', "must be a number"),
        ("BINDING\n" + '{"t": 1, "event": "phase", "phase": "dancing"}\n', "must be one of"),
        (
            "BINDING\n" + '{"t": 1, "event": "checkpoint-done", "checkpoint": "CP9"}\n',
            "checkpoint 'CP9' is not one of the journal's mission",
        ),
        (
            "BINDING\n" + json.dumps(CP1_DONE[1]) + "\n" + json.dumps(CP1_DONE[1]) + "\n",
            "journal.jsonl:3: checkpoint 'CP1' completed twice",
        ),
        (
            "BINDING\n"
            + '{"t": 1, "event": "checkpoint-done", "checkpoint": "CP1", "pose_a": [1, 2]}\n',
            "'pose_a' must be three numbers",
        ),
        ('{"t": 0, "event": "phase", "phase": "approach"}\n', "the first line binds the journal"),
        ("BINDING\nBINDING\n", "a second 'mission-start' record"),
        (
            "BINDING\n" + '{"t": 1, "event": "item", "checkpoint": "CP1", "item": "x"}\n',
            "without its 'stamp'",
        ),
    ],
    ids=[
        "empty",
        "binding-without-fields",
        "array-line",
        "string-line",
        "corrupt-middle-line",
        "unknown-event",
        "missing-field",
        "wrong-type",
        "nan-number",
        "unknown-phase",
        "unknown-checkpoint",
        "checkpoint-twice",
        "short-pose",
        "no-binding-line",
        "two-bindings",
        "item-missing-fields",
    ],
)
def test_hostile_journals_are_refused_at_their_line(tmp_path, capsys, content, expected):
    binding = json.dumps(_binding().as_record())
    journal = _write_journal(tmp_path / "out", content.replace("BINDING", binding))
    before = journal.read_bytes()
    code, text = _resume(tmp_path / "out", capsys)
    assert code == 2, text
    assert expected in text
    assert journal.read_bytes() == before  # nothing appended, nothing repaired
    assert not (tmp_path / "out" / "metrics.json").exists()  # nothing driven


def test_another_missions_journal_is_refused(tmp_path, capsys):
    other = MissionBinding.of(load_mission(MISSIONS / "track" / "straight-run.xml"))
    _write_journal(tmp_path / "out", _lines(other))
    code, text = _resume(tmp_path / "out", capsys)
    assert code == 2
    assert "belongs to mission 'track-straight-run'" in text or "belongs to mission" in text


def _copy_lab(tmp_path: Path) -> Path:
    library = tmp_path / "library"
    shutil.copytree(MISSIONS / "lab", library / "lab")
    return library / "lab" / "visual-servoing.xml"


def _edit(path: Path, old: str, new: str) -> None:
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new, 1))


@pytest.mark.parametrize(
    ("edit", "expected"),
    [
        (lambda m: _edit(m, 'id="CP2"', 'id="CP2b"'), "checkpoints added since: CP2b"),
        (lambda m: _edit(m, 'x="3.5"', 'x="3.6"'), "checkpoints moved since: CP2"),
        (lambda m: _edit(m, "<description>", "<description>edited "), "the mission file changed"),
        (
            lambda m: _edit(m.parent / "aircraft.xml", "</aircraft>", "<!-- x --></aircraft>"),
            "the aircraft file changed",
        ),
    ],
    ids=["checkpoint-renamed", "checkpoint-moved", "text-changed", "aircraft-changed"],
)
def test_a_changed_mission_refuses_the_old_journal(tmp_path, capsys, edit, expected):
    mission = _copy_lab(tmp_path)
    binding = MissionBinding.of(load_mission(mission))
    _write_journal(tmp_path / "out", _lines(binding, *CP1_DONE))
    edit(mission)
    code, text = _resume(tmp_path / "out", capsys, mission)
    assert code == 2, text
    assert expected in text


def test_differences_name_added_removed_and_reordered_checkpoints():
    a = MissionBinding("m", "h", "a", (("CP1", 0, 0, 0), ("CP2", 1, 0, 0), ("CP3", 2, 0, 0)))
    b = MissionBinding("m", "h2", "a", (("CP1", 0, 0, 0), ("CP3", 2, 0, 0), ("CP2", 1, 0, 0)))
    c = MissionBinding("m", "h2", "a", (("CP1", 0, 0, 0),))
    assert a.differences(a) == []
    assert a.differences(b) == ["checkpoints reordered since"]
    assert a.differences(c) == ["checkpoints removed since: CP2, CP3"]


@pytest.mark.parametrize("kind", ["directory", "fifo", "symlink", "missing"])
def test_a_journal_that_is_not_a_regular_file_is_refused(tmp_path, capsys, kind):
    out = tmp_path / "out"
    out.mkdir()
    journal = out / "journal.jsonl"
    if kind == "directory":
        journal.mkdir()
    elif kind == "fifo":
        os.mkfifo(journal)
    elif kind == "symlink":
        real = tmp_path / "elsewhere.jsonl"
        real.write_text(_lines(_binding()))
        journal.symlink_to(real)
    code, text = _resume(out, capsys)
    assert code == 2, text
    assert "journal" in text


def test_resuming_a_finished_mission_drives_nothing(tmp_path, capsys):
    journal = _write_journal(
        tmp_path / "out",
        _lines(_binding(), *CP1_DONE, {"t": 80.0, "event": "mission-end", "outcome": "completed"}),
    )
    before = journal.read_bytes()
    code, text = _resume(tmp_path / "out", capsys)
    assert code == 0
    assert "already completed at 80.0 s" in text and "nothing to resume" in text
    assert journal.read_bytes() == before
    assert not (tmp_path / "out" / "metrics.json").exists()


def test_a_torn_last_line_is_cut_before_appending(tmp_path):
    binding = _binding()
    torn = _lines(binding, *CP1_DONE) + '{"t": 20.0, "event": "checkpoint-st'
    path = _write_journal(tmp_path, torn)
    state = read_journal(path)
    assert state.progress.completed == ("CP1",)
    mission = load_mission(LAB)
    check_resumable(state, mission, path)
    run = dry_run(load_scenario(LAB_SCENARIO), journal_path=path, resume=state, max_time=3.0)
    assert run.result.outcome == "timeout"
    lines = path.read_text().splitlines()
    records = [json.loads(line) for line in lines]  # every line whole
    assert path.read_bytes().endswith(b"\n")
    assert [r["event"] for r in records][:4] == [
        "mission-start",
        "checkpoint-start",
        "checkpoint-done",
        "resume",
    ]
    assert records[-1]["event"] == "mission-end"


def test_an_unterminated_but_whole_last_line_is_kept(tmp_path):
    text = _lines(_binding(), *CP1_DONE).rstrip("\n")
    state = read_journal(_write_journal(tmp_path, text))
    assert state.progress.completed == ("CP1",)
    assert state.keep_bytes == len(text.encode())


def test_a_failed_write_leaves_whole_lines_only(tmp_path, monkeypatch):
    """A full disk mid-line: the journal is cut back to its last whole line."""
    path = tmp_path / "journal.jsonl"
    journal = Journal(path, _binding())
    real_write = os.write
    budget = [40]

    def disk(fd, data):
        if budget[0] <= 0:
            raise OSError(28, "No space left on device")
        n = min(len(data), budget[0])
        budget[0] -= n
        return real_write(fd, bytes(data[:n]))

    monkeypatch.setattr("executive.journal.os.write", disk)
    progress = MissionProgress("inspection", "CP1", "CP1", ("CP1",), ())
    with pytest.raises(JournalWriteError, match="disk full while writing"):
        journal.record(18.0, progress, (1.5, 3.5, -1.57))
    journal.close()
    state = read_journal(path)  # valid: the binding and whatever fitted whole
    assert path.read_bytes().endswith(b"\n")
    assert state.progress.completed in ((), ("CP1",))


def test_item_results_and_truth_survive_a_resume(tmp_path):
    """The report of a resumed run keeps what was judged before the stop."""
    binding = _binding()
    item = ItemResult("CP1", "target-1-marker", 17.0, True, "front", 0.0, 0.0, (1.5, 3.5, -1.57))
    fields = {k: getattr(item, k) for k in ItemResult.__dataclass_fields__}
    fields["pose_f"] = list(fields["pose_f"])
    truth = {
        "event": "checkpoint-truth",
        "id": "CP1",
        "checkpoint": "CP1",
        "time": 18.0,
        "position_error": 0.031,
        "heading_error_deg": 1.5,
        "reached": True,
    }
    path = _write_journal(
        tmp_path,
        _lines(binding, CP1_DONE[0], {"t": 17.0, "event": "item", **fields}, CP1_DONE[1], truth),
    )
    state = read_journal(path)
    assert state.progress.results == (item,)
    run = dry_run(load_scenario(LAB_SCENARIO), journal_path=path, resume=state, max_time=2.0)
    cp1 = run.checkpoints[0]
    assert cp1.resumed and cp1.reached
    assert math.isclose(cp1.position_error, 0.031) and cp1.time == 18.0


def test_an_unterminated_line_gets_its_newline_before_the_next_record(tmp_path):
    path = _write_journal(tmp_path, _lines(_binding(), *CP1_DONE).rstrip("\n"))
    state = read_journal(path)
    journal = Journal(path, _binding(), append=True, keep_bytes=state.keep_bytes)
    journal.write({"event": "resume", "t": 0.0})
    journal.close()
    again = read_journal(path)  # every line whole: the resume record did not glue on
    assert again.progress.completed == ("CP1",)
    assert path.read_text().splitlines()[-1] == '{"event":"resume","t":0.0}'


def _item(checkpoint: str, stamp: float, detected: bool, stale: bool) -> dict:
    item = ItemResult(checkpoint, "i", stamp, detected, "ptz", 0.0, 0.0, (1.0, 2.0, 0.0), stale)
    fields = {k: getattr(item, k) for k in ItemResult.__dataclass_fields__}
    return {"t": stamp, "event": "item", **fields, "pose_f": [1.0, 2.0, 0.0]}


def test_an_attempt_stopped_before_its_checkpoint_was_done_leaves_no_result(tmp_path):
    """CP2's item judged stale, the run stopped, resumed, CP2 inspected again and done:
    only the second attempt's result stands."""
    path = _write_journal(
        tmp_path,
        _lines(
            _binding(),
            *CP1_DONE,
            {"t": 20.0, "event": "checkpoint-start", "checkpoint": "CP2"},
            _item("CP2", 21.0, False, True),
            {"t": 22.0, "event": "interrupted", "reason": "interrupted by SIGTERM at 22.0 s"},
            {"t": 0.0, "event": "resume"},
            _item("CP2", 5.0, True, False),
            {"t": 6.0, "event": "checkpoint-done", "checkpoint": "CP2"},
        ),
    )
    results = read_journal(path).progress.results
    assert [(r.checkpoint, r.detected) for r in results] == [("CP2", True)]


@pytest.mark.parametrize(
    ("records", "expected"),
    [
        (
            [{"t": 1.0, "event": "checkpoint-done", "checkpoint": "CP2"}],
            "checkpoint 'CP2' completed before 'CP1'",
        ),
        ([{"t": 10**400, "event": "phase", "phase": "return"}], "field 't' must be a number"),
        ([{"t": 1e300, "event": "phase", "phase": "return"}], "field 't' must be a number"),
        (
            [
                {"t": 1.0, "event": "checkpoint-done", "checkpoint": "CP1", "pose_a": [1e5, 0, 0]},
            ],
            "checkpoint 'CP1' is recorded completed at (100000.0, 0.0)",
        ),
    ],
    ids=["out-of-order", "400-digit-integer", "huge-float", "pose-far-away"],
)
def test_impossible_journals_are_refused(tmp_path, capsys, records, expected):
    _write_journal(tmp_path / "out", _lines(_binding(), *records))
    code, text = _resume(tmp_path / "out", capsys)
    assert code == 2, text
    assert expected in text


def test_a_deeply_nested_line_is_refused(tmp_path, capsys):
    binding = json.dumps(_binding().as_record())
    _write_journal(tmp_path / "out", binding + "\n" + "[" * 100_000 + "]" * 100_000 + "\n")
    code, text = _resume(tmp_path / "out", capsys)
    assert code == 2 and "journal.jsonl:2:" in text


def test_a_robot_runs_journal_keeps_where_the_robot_stood(tmp_path):
    """A robot run (pose_period) records its pose estimate as it goes: a run killed
    mid-leg resumes from where the robot stood, not from its last checkpoint."""
    from behaviours.keys import MissionProgress
    from executive.journal import Journal, read_journal

    path = tmp_path / "journal.jsonl"
    journal = Journal(path, "m", pose_period=0.5)
    journal.record(0.0, MissionProgress(), (1.0, 2.0, 0.1))
    journal.record(0.2, MissionProgress(), (1.1, 2.0, 0.1))  # within the period: not kept
    journal.record(0.6, MissionProgress(), (1.5, 2.0, 0.2), travel=(12.5, 12.75))
    journal.record(0.7, MissionProgress(), (float("nan"), 2.0, 0.2))
    journal.close()
    state = read_journal(path)
    assert state.last_pose == (1.5, 2.0, 0.2)
    assert state.last_travel == (12.5, 12.75)  # the base's odometers with it
    assert state.pose_a is None  # the last checkpoint's pose is another thing
    plain = tmp_path / "plain.jsonl"
    journal = Journal(plain, "m")  # a dry-run's journal: no pose records
    journal.record(0.6, MissionProgress(), (1.5, 2.0, 0.2))
    journal.close()
    assert read_journal(plain).last_pose is None


def test_a_resumed_robot_run_starts_where_the_odometers_say_the_robot_went():
    """The robot drove on after the executive died: the resumed run adds what the base's
    odometers counted since the journal's last pose record (WHEEL_TRAVEL), as one arc."""
    from executive.core.records import SensorFrame, WheelSpeeds
    from executive.journal import JournalState, MissionBinding
    from executive.robotrun import _localiser, _moved_while_down

    mission = load_mission(LAB)
    state = JournalState(
        MissionBinding.of(mission),
        MissionProgress(),
        None,
        last_pose=(1.0, 2.0, 0.0),
        last_travel=(33554.4, 10.0),  # the left odometer wraps on the way
    )

    class Link:
        def read(self) -> SensorFrame:
            wheels = WheelSpeeds(5.0, 0.0, 0.0, travel=(-33554.164, 10.3))  # 33554.7 wrapped
            return SensorFrame(5.0, wheels=wheels)

    moved = _moved_while_down(state, Link())
    assert moved == pytest.approx((0.3, 0.3), abs=1e-6)
    compiled = compile_mission(mission, CompileOptions(start=Pose2(1.0, 2.0, 0.0)))
    localise = _localiser(compiled.root)
    localise.moved_before_start(*moved)
    pose = localise.filter.pose
    speed_scale = localise.filter.state[5]  # c, eq. 2.1's scale
    assert (pose.x, pose.y, pose.theta) == pytest.approx((1.0 + 0.3 * speed_scale, 2.0, 0.0))
    # without odometers on either side nothing is added (the recorded pose it is)
    assert _moved_while_down(dataclasses.replace(state, last_travel=None), Link()) is None
