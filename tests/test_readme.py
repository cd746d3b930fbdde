"""The README's main job, run as written: the shipped A320 pre-flight on the clear apron.

The README's first line sets up a fresh machine and runs ``walkaround dry-run
missions/a320/preflight.xml --out dry-run``. This test takes that command from the README
itself (so the README cannot drift from what is tested), runs it through the installed
``walkaround`` console script in its own process, and judges what a user gets: the exit
code, and the report against sim2d's ground truth (issue 4: the mission completes,
every checkpoint within tolerance and every item inspected, no collision or geofence
breach; issue 13: the checkpoints finished by visual servoing within 2 cm and 0.5 deg;
issue 15: the recording holds every topic for the whole run; the report's files).

CI (``.ci/run``) installs the project as the README's first line says and runs the test
command; this test is where the first line's dry-run is run and judged, in the test
pool rather than alone before it (a single-threaded run that left one core of two idle
for minutes).
"""

import json
import shlex
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

from executive.core.loader import load_mission
from tests.conftest import REPO
from tests.sim2d_helpers import assert_servoed
from tests.test_recording import assert_whole_run_recorded


def quick_start() -> list[str]:
    """The command lines of the README's first code block (its quick start)."""
    text = (REPO / "README.md").read_text()
    block = text.split("```bash\n", 1)[1].split("```", 1)[0]
    return [line.strip() for line in block.splitlines() if line.strip()]


def main_job() -> list[str]:
    """The ``walkaround`` command of the quick start's first line, as argv."""
    step = quick_start()[0].split("&&")[-1]
    argv = shlex.split(step)
    assert argv[:2] == ["walkaround", "dry-run"], quick_start()[0]
    return argv


def test_the_quick_start_is_two_lines_setup_and_main_job_then_the_tests():
    first, second = quick_start()
    assert "pip install ." in first and "walkaround dry-run missions/a320/preflight.xml" in first
    assert second.endswith("python -m pytest -q") and 'pip install ".[test]"' in second


@pytest.mark.slow
def test_the_readme_main_job_completes_the_a320_preflight(tmp_path: Path):
    argv = main_job()
    out = tmp_path / "dry-run"
    argv[argv.index("--out") + 1] = str(out)
    walkaround = Path(sys.executable).with_name("walkaround")
    done = subprocess.run(
        [str(walkaround), *argv[1:]],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=3600,
    )
    assert done.returncode == 0, (done.stdout[-2000:], done.stderr[-2000:])
    assert "succeeded" in done.stdout
    report = json.loads((out / "metrics.json").read_text())
    mission = load_mission(REPO / argv[2])
    assert report["succeeded"], (report["reason"], report["first_cause"])
    assert report["checkpoints_reached"] == report["checkpoints_total"] == len(mission.checkpoints)
    assert report["collisions"] == [] and report["geofence_breaches"] == []
    items = sum(len(cp.items) for cp in mission.checkpoints)
    assert report["items_inspected"] == report["items_detected"] == items
    outcomes = [SimpleNamespace(**cp) for cp in report["checkpoints"]]
    for cp, outcome in zip(mission.checkpoints, outcomes, strict=True):
        assert outcome.reached, cp.id
        assert outcome.position_error <= 0.15, (cp.id, outcome)
        assert outcome.heading_error_deg <= 5.0, (cp.id, outcome)
        assert outcome.items == outcome.detected == len(cp.items), cp.id
    events = [json.loads(line) for line in (out / "events.jsonl").read_text().splitlines()]
    switches = [e for e in events if e["event"] == "controller"]
    assert switches and all("reason" in e for e in switches)
    controllers = [e["to"] for e in switches]
    servoed = assert_servoed(mission.checkpoints, outcomes, report["warnings"], controllers)
    assert len(servoed) >= len(mission.checkpoints) - 2, servoed
    assert (out / "trajectory.png").stat().st_size > 10_000
    assert (out / "timeline.png").stat().st_size > 10_000
    assert (out / "journal.jsonl").stat().st_size > 0
    assert_whole_run_recorded(out / "run.mcap", report["simulated_s"])
