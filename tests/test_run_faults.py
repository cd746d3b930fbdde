"""Bad arguments, signals, full disks and slow ticks (issue 12 §2, §3, §5).

* Every bad argument gives exit status 2 and one line, before any work, and leaves no
  output folder behind.
* SIGINT, SIGTERM and SIGHUP mid-run (a real process): the robot is sent a stop, the
  journal is closed with an ``interrupted`` record, a partial report is written, the
  message names the ``--resume`` command, the exit status is 128 + the signal.
* A full disk mid-run: the robot is stopped, the message says so, the journal holds
  whole lines only and a later ``--resume`` completes the mission.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from executive.cli import main
from executive.dryrun import dry_run
from executive.safety import SafetyLayer
from sim2d.scenario import Fault, FaultKind, load_scenario

MISSIONS = Path(__file__).resolve().parents[1] / "missions"
LAB = MISSIONS / "lab" / "visual-servoing.xml"
LAB_SCENARIO = MISSIONS / "lab" / "scenarios" / "clear-apron.xml"
REPO = Path(__file__).resolve().parents[1]


def _cli(capsys, *argv: str) -> tuple[int, str]:
    code = main(list(argv))
    captured = capsys.readouterr()
    text = captured.out + captured.err
    assert "Traceback" not in text
    return code, text


# -- §2: arguments ------------------------------------------------------------------------------
@pytest.fixture
def existing_file(tmp_path):
    path = tmp_path / "a-file"
    path.write_text("not a folder")
    return path


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["--out", "{file}"], "exists and is not a directory"),
        (["--out", "{file}/below"], "is not a directory"),
        (["--out", "/proc/walkaround-report"], "under /proc"),
        (["--out", "/sys/kernel/walkaround"], "under /sys"),
        (["--seed", "-1"], "--seed -1: a seed is an integer from 0"),
        (["--seed", str(2**40)], "--seed"),
        (["--rate", "nan"], "--rate nan"),
        (["--rate", "inf"], "--rate inf"),
        (["--rate", "5"], "10 to 50 Hz"),
        (["--max-time", "-3"], "--max-time -3"),
        (["--max-time", "nan"], "--max-time nan"),
        (["--max-missed-deadlines", "-1"], "--max-missed-deadlines -1"),
        (["--resume"], "nothing to resume"),
    ],
    ids=[
        "out-is-a-file",
        "out-below-a-file",
        "out-under-proc",
        "out-under-sys",
        "negative-seed",
        "huge-seed",
        "nan-rate",
        "inf-rate",
        "slow-rate",
        "negative-max-time",
        "nan-max-time",
        "negative-deadline-misses",
        "resume-without-journal",
    ],
)
def test_dry_run_refuses_bad_arguments_before_any_work(
    tmp_path, capsys, existing_file, argv, expected
):
    argv = [a.replace("{file}", str(existing_file)) for a in argv]
    out = tmp_path / "report"
    if "--out" not in argv:
        argv = [*argv, "--out", str(out)]
    before = sorted(tmp_path.rglob("*"))
    code, text = _cli(capsys, "dry-run", str(LAB), "--quiet", *argv)
    assert code == 2, text
    assert expected in text
    assert len(text.strip().splitlines()) == 1
    assert sorted(tmp_path.rglob("*")) == before  # no empty output folder left behind


def test_dry_run_refuses_an_unwritable_out(tmp_path, capsys):
    """A folder nobody may write into (root included: the immutable attribute)."""
    locked = tmp_path / "locked"
    locked.mkdir()
    subprocess.run(["chattr", "+i", str(locked)], check=True)
    try:
        code, text = _cli(capsys, "dry-run", str(LAB), "--out", str(locked / "run"))
        assert code == 2 and "is not writable" in text
        code, text = _cli(capsys, "dry-run", str(LAB), "--out", str(locked))
        assert code == 2 and "is not writable" in text
    finally:
        subprocess.run(["chattr", "-i", str(locked)], check=True)


SCENARIO_DURATION = load_scenario(LAB_SCENARIO).duration


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["--at", "-1"], "--at -1"),
        (["--at", "nan"], "--at nan"),
        (["--at", "inf"], "--at inf"),
        (["--at", str(SCENARIO_DURATION + 1)], "past the scenario's duration"),
        (["--out", "{tmp}/world.txt"], "must end in .png or .svg"),
        (["--out", "{tmp}"], "is a directory"),
        (["--out", "/proc/world.png"], "under /proc"),
    ],
    ids=["negative-at", "nan-at", "inf-at", "at-past-duration", "txt-out", "dir-out", "proc-out"],
)
def test_sim_view_refuses_bad_arguments(tmp_path, capsys, argv, expected):
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    if "--out" not in argv:
        argv = [*argv, "--out", str(tmp_path / "world.png")]
    code, text = _cli(capsys, "sim-view", str(LAB_SCENARIO), *argv)
    assert code == 2, text
    assert expected in text
    assert not (tmp_path / "world.png").exists()


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["--out", "{tmp}"], "is a directory"),
        (["--format", "png", "--out", "{tmp}/tree.svg"], "must end in .png"),
        (["--out", "{tmp}/missing/tree.txt"], None),
    ],
    ids=["dir-out", "png-as-svg", "missing-parent-is-created"],
)
def test_show_checks_its_output(tmp_path, capsys, argv, expected):
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    code, text = _cli(capsys, "show", str(LAB), *argv)
    if expected is None:
        assert code == 0 and (tmp_path / "missing" / "tree.txt").read_text().startswith("[=>]")
        return
    assert code == 2, text
    assert expected in text


def test_a_run_into_an_old_report_leaves_nothing_stale_and_writes_through_no_link(tmp_path, capsys):
    out = tmp_path / "run"
    out.mkdir()
    (out / "avoidance.png").write_bytes(b"stale picture of another run")
    victim = tmp_path / "victim.json"
    victim.write_text("precious")
    (out / "metrics.json").symlink_to(victim)
    code, text = _cli(capsys, "dry-run", str(LAB), "--out", str(out), "--quiet", "--max-time", "3")
    assert code == 1, text  # 3 s is not enough to finish: a timeout
    assert not (out / "avoidance.png").exists()  # this run avoided nothing
    assert victim.read_text() == "precious"
    assert not (out / "metrics.json").is_symlink()
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["outcome"] == "timeout"
    assert not [p for p in out.iterdir() if p.name.endswith(".tmp")]


# -- §3: signals, in a real process -----------------------------------------------------------
def _default_signals() -> None:
    """In the child: SIGINT, SIGTERM and SIGHUP as a terminal's session gives them. A
    run keeps a signal its parent ignores ignored (``nohup``), so under a test runner
    started with ``nohup`` SIGHUP would never reach it."""
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, signal.SIG_DFL)


def _start(out: Path, *extra: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "executive.cli", "dry-run", str(LAB), "--out", str(out), *extra],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=REPO,
        preexec_fn=_default_signals,
    )


def _wait_for(journal: Path, needle: str, process: subprocess.Popen, limit: float = 240) -> None:
    deadline = time.monotonic() + limit
    while time.monotonic() < deadline and process.poll() is None:
        with contextlib.suppress(OSError):
            if needle in journal.read_text():
                return
        time.sleep(0.02)
    raise AssertionError(f"{needle} never journaled (exit {process.poll()})")


def _process(*argv: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, *argv], capture_output=True, text=True, timeout=300, cwd=REPO, check=False
    )


def _resume(out: Path) -> subprocess.CompletedProcess:
    return _process(
        "-m", "executive.cli", "dry-run", str(LAB), "--out", str(out), "--quiet", "--resume"
    )


def _completed(journal: Path) -> list[str]:
    records = map(json.loads, journal.read_text().splitlines())
    return [r["checkpoint"] for r in records if r["event"] == "checkpoint-done"]


@pytest.mark.parametrize(("name", "status"), [("SIGTERM", 143), ("SIGINT", 130), ("SIGHUP", 129)])
def test_a_signal_mid_run_stops_the_robot_and_leaves_a_resumable_run(tmp_path, name, status):
    out = tmp_path / "run"
    run = _start(out, "--quiet")
    try:
        _wait_for(out / "journal.jsonl", '"checkpoint-done"', run)
        run.send_signal(getattr(signal, name))
        stdout, stderr = run.communicate(timeout=120)
    finally:
        if run.poll() is None:
            run.kill()
    assert run.returncode == status, stdout + stderr
    assert "Traceback" not in stderr
    assert f"interrupted by {name}" in stdout + stderr
    assert "the robot was sent a stop" in stderr
    assert "--resume" in stderr and "partial report" in stderr
    records = [json.loads(line) for line in (out / "journal.jsonl").read_text().splitlines()]
    assert records[-1]["event"] == "interrupted" and name in records[-1]["reason"]
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["outcome"] == "interrupted"
    last = metrics["last_commands"][-1]
    assert last["v"] == 0.0 and last["omega"] == 0.0  # the last thing the robot was told
    assert (out / "trajectory.png").exists()
    if name != "SIGTERM":
        return
    resumed = _resume(out)
    assert resumed.returncode == 0, resumed.stdout + resumed.stderr
    assert _completed(out / "journal.jsonl") == ["CP1", "CP2", "CP3"]
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["succeeded"] and metrics["resumed_after"]
    assert all(c["position_error"] is not None for c in metrics["checkpoints"])


FULL_DISK = """
import os, sys
import executive.journal as journal
capacity = [int(sys.argv[1])]
real = os.write
def disk(fd, data):
    if capacity[0] <= 0:
        raise OSError(28, "No space left on device")
    n = min(len(data), capacity[0])
    capacity[0] -= n
    return real(fd, bytes(data[:n]))
os.write = disk   # every file goes to a disk that fills up
from executive.cli import main
sys.exit(main(sys.argv[2:]))
"""


def test_a_full_disk_mid_run_stops_the_robot_and_resume_completes(tmp_path):
    out = tmp_path / "run"
    first = _process("-c", FULL_DISK, "1400", "dry-run", str(LAB), "--out", str(out), "--quiet")
    assert first.returncode == 1, first.stdout + first.stderr
    assert "Traceback" not in first.stderr
    assert "disk full while writing" in first.stdout + first.stderr
    assert "journal.jsonl" in first.stdout + first.stderr
    assert "the robot was sent a stop" in first.stderr and "--resume" in first.stderr
    journal = out / "journal.jsonl"
    data = journal.read_bytes()
    assert len(data) <= 1400 and data.endswith(b"\n")
    assert all(json.loads(line) for line in data.decode().splitlines())  # no torn line
    # The disk is full for the report too: no report file half-written, none left behind.
    assert not (out / "metrics.json").exists()
    assert not [p for p in out.iterdir() if p.name.endswith(".tmp")]
    second = _resume(out)
    assert second.returncode == 0, second.stdout + second.stderr
    assert _completed(journal) == ["CP1", "CP2", "CP3"]


def test_a_full_disk_for_the_report_is_said_and_nothing_is_half_written(
    tmp_path, monkeypatch, capsys
):
    import executive.core.files as files

    real = os.write

    def full(fd, data):
        if os.readlink(f"/proc/self/fd/{fd}").endswith(f".png.{os.getpid()}.tmp"):
            raise OSError(28, "No space left on device")
        return real(fd, data)

    monkeypatch.setattr(files.os, "write", full)
    out = tmp_path / "run"
    code, text = _cli(capsys, "dry-run", str(LAB), "--out", str(out), "--quiet", "--max-time", "2")
    assert code == 1
    assert "disk full while writing" in text and "trajectory.png" in text
    assert not (out / "trajectory.png").exists()
    assert not [p for p in out.iterdir() if p.name.endswith(".tmp")]
    json.loads((out / "metrics.json").read_text())  # whole


# -- §5: deadline overruns and the summary ---------------------------------------------------------
def _slow_ticks_after(monkeypatch, start: float, until: float = math.inf) -> None:
    """Every tick from ``start`` to ``until`` (simulated s) burns 30 ms of CPU at 50 Hz."""
    filter_ = SafetyLayer.filter

    def slow(self, command, *, now, **kw):
        if start < now < until:
            t0 = time.thread_time()
            while time.thread_time() - t0 < 0.03:
                pass
        return filter_(self, command, now=now, **kw)

    monkeypatch.setattr(SafetyLayer, "filter", slow)


def test_consecutive_deadline_misses_stop_the_robot(monkeypatch):
    """A tick that burns 30 ms of CPU at 50 Hz: after 3 in a row the run stops, says why."""
    _slow_ticks_after(monkeypatch, 2.0)
    run = dry_run(load_scenario(LAB_SCENARIO), max_time=10.0, max_missed_deadlines=3)
    assert run.result.outcome == "failed"
    assert "3 consecutive tick deadlines missed" in run.result.reason
    assert run.last_commands[-1][1].v == 0.0 and run.last_commands[-1][1].omega == 0.0
    assert 2.0 < run.robot.time < 2.2
    assert not run.succeeded and "deadlines missed" in run.first_cause


def test_a_dry_run_counts_missed_deadlines_but_its_outcome_does_not_depend_on_them(
    monkeypatch,
):
    """By default a dry-run does not stop on missed deadlines (a busy or virtual machine
    must not change a simulated outcome): the same run with and without a second of slow
    ticks drives the robot identically, and the misses are counted."""
    scenario = load_scenario(LAB_SCENARIO)
    fast = dry_run(scenario, max_time=6.0)
    _slow_ticks_after(monkeypatch, 2.0, 3.0)
    slow = dry_run(scenario, max_time=6.0)
    assert slow.result.outcome == fast.result.outcome == "timeout"
    assert slow.result.stats.misses >= 49 > fast.result.stats.misses
    assert slow.robot.world.robot_pose == fast.robot.world.robot_pose


def test_a_latched_bumper_is_the_first_cause(tmp_path):
    scenario = load_scenario(LAB_SCENARIO)
    scenario = dataclasses.replace(
        scenario, faults=(Fault(FaultKind.BUMPER_HIT, 4.0, 0.5, "front"),)
    )
    run = dry_run(scenario, max_time=12.0)
    assert run.result.outcome == "timeout"
    assert "bumper" in run.first_cause
    assert "waiting for an operator reset" in run.first_cause
    assert run.last_commands[-1][1].v == 0.0


def test_a_lost_link_ends_the_run_and_says_the_stop_was_not_confirmed():
    """The robot's send raises (bus-off) from 2 s on: no traceback escapes the run, which
    ends failed, and the report says the stop could not be confirmed."""
    from sim2d.robot import SimRobot

    class LostLink(SimRobot):
        def send(self, command):
            if self.time > 2.0:
                raise ConnectionError("bus-off")
            super().send(command)

    scenario = load_scenario(LAB_SCENARIO)
    run = dry_run(scenario, robot=LostLink(scenario), max_time=10.0)
    assert run.result.outcome == "failed" and "bus-off" in run.result.reason
    assert not run.result.stop_sent
    assert any("stop was not confirmed" in c.text for c in run.causes)
    assert any(e.kind == "link-lost" for e in run.result.events)


def test_a_signal_before_the_run_starts_changes_nothing(tmp_path, capsys, monkeypatch):
    import executive.dryrun as dryrun

    out = tmp_path / "run"
    out.mkdir()
    (out / "metrics.json").write_text('{"kept": true}')
    compile_mission = dryrun.compile_mission

    def compile_then_signal(*args, **kwargs):
        os.kill(os.getpid(), signal.SIGTERM)  # arrives while the mission compiles
        return compile_mission(*args, **kwargs)

    monkeypatch.setattr(dryrun, "compile_mission", compile_then_signal)
    code, text = _cli(capsys, "dry-run", str(LAB), "--out", str(out), "--quiet")
    assert code == 143
    assert "before the run started; nothing changed" in text
    assert (out / "metrics.json").read_text() == '{"kept": true}'
    assert not (out / "journal.jsonl").exists()


def test_a_successful_run_whose_report_cannot_be_written_exits_1(tmp_path, monkeypatch, capsys):
    import executive.dryrun as dryrun
    import executive.report as report

    monkeypatch.setattr(dryrun, "judge", lambda run: [])  # the run itself succeeds

    def full(run, out):
        raise OSError(28, "No space left on device", str(out / "metrics.json"))

    monkeypatch.setattr(report, "write_report", full)
    out = tmp_path / "run"
    code, text = _cli(capsys, "dry-run", str(LAB), "--out", str(out), "--quiet", "--max-time", "1")
    assert code == 1
    assert "succeeded" in text and "disk full while writing" in text


def test_the_scenarios_mission_is_compared_as_a_file_not_a_string(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(LAB_SCENARIO.parent)
    out = tmp_path / "run"
    code, text = _cli(
        capsys,
        "dry-run",
        "../visual-servoing.xml",
        "--scenario",
        LAB_SCENARIO.name,
        "--out",
        str(out),
        "--quiet",
        "--max-time",
        "1",
    )
    assert code == 1, text  # a 1 s run times out; it is not refused as another mission
    assert json.loads((out / "metrics.json").read_text())["outcome"] == "timeout"


def test_an_ignored_sighup_stays_ignored(tmp_path):
    """Started under nohup (SIGHUP ignored): a hang-up does not end the run; SIGTERM does."""
    out = tmp_path / "run"
    run = subprocess.Popen(
        [sys.executable, "-m", "executive.cli", "dry-run", str(LAB), "--out", str(out), "--quiet"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=REPO,
        preexec_fn=lambda: signal.signal(signal.SIGHUP, signal.SIG_IGN),
    )
    try:
        _wait_for(out / "journal.jsonl", '"checkpoint-start"', run)
        run.send_signal(signal.SIGHUP)
        _wait_for(out / "journal.jsonl", '"checkpoint-done"', run)  # it drives on
        run.send_signal(signal.SIGTERM)
        stdout, stderr = run.communicate(timeout=120)
    finally:
        if run.poll() is None:
            run.kill()
    assert run.returncode == 143, stdout + stderr
    assert "SIGHUP" not in stdout + stderr


@pytest.mark.parametrize(
    "argv",
    [
        ["sim-view", str(LAB_SCENARIO), "--out", "{out}"],
        ["show", str(LAB), "--format", "png", "--out", "{out}"],
        ["show", str(LAB), "--out", "{out}"],
    ],
    ids=["sim-view", "show-png", "show-ascii"],
)
def test_pictures_and_trees_are_written_whole_and_never_through_a_link(tmp_path, capsys, argv):
    victim = tmp_path / "victim.png"
    victim.write_bytes(b"precious")
    out = tmp_path / "picture.png"
    out.symlink_to(victim)
    code, _ = _cli(capsys, *(a.replace("{out}", str(out)) for a in argv))
    assert code == 0
    assert victim.read_bytes() == b"precious"
    assert not out.is_symlink() and out.stat().st_size > 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["picture.png", "victim.png"]
