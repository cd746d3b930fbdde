"""The run's summary tells the truth (issue 12 §5), end to end through the CLI.

A run whose cameras are frozen, or whose pose drifts without GPS, may still complete
its tree; it must not say so with exit status 0. Each case runs the real command on a
copy of a shipped mission library with one more scenario, and checks the exit status,
the one-line summary's first cause and metrics.json.
"""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import pytest

from executive.cli import main

MISSIONS = Path(__file__).resolve().parents[1] / "missions"

SCENARIO = """<?xml version="1.0" encoding="UTF-8"?>
<scenario xmlns="urn:walkaround:scenario:1" id="{id}" mission="../{mission}" seed="1">
  <description>{id}</description>
  <faults>
{faults}
  </faults>
</scenario>
"""


def _run(tmp_path, capsys, library: str, mission: str, faults: list[str]) -> tuple[int, str, dict]:
    root = tmp_path / "library"
    shutil.copytree(MISSIONS / library, root / library)
    scenario = root / library / "scenarios" / "fault.xml"
    scenario.write_text(
        SCENARIO.format(id=f"{library}-fault", mission=mission, faults="\n".join(faults))
    )
    out = tmp_path / "run"
    code = main(
        [
            *("dry-run", str(root / library / mission)),
            *("--scenario", str(scenario), "--out", str(out), "--quiet"),
        ]
    )
    captured = capsys.readouterr()
    assert "Traceback" not in captured.out + captured.err
    summary = captured.out.strip().splitlines()[-1]
    metrics = json.loads((out / "metrics.json").read_text())
    metrics["stderr"] = captured.err
    metrics["journal"] = [json.loads(line) for line in (out / "journal.jsonl").open()]
    return code, summary, metrics


CAMERAS = ("front-left", "front-right", "rear-left", "rear-right", "ptz")


@pytest.mark.parametrize(
    ("cameras", "at"), [(("ptz",), 25.0), (CAMERAS, 2.0)], ids=["ptz-frozen", "all-frozen"]
)
def test_frozen_cameras_fail_the_run_and_say_which(tmp_path, capsys, cameras, at):
    faults = [f'    <camera-freeze camera="{c}" at="{at}" duration="10000"/>' for c in cameras]
    code, summary, metrics = _run(tmp_path, capsys, "lab", "visual-servoing.xml", faults)
    assert code == 1, summary
    assert metrics["outcome"] == "completed" and not metrics["succeeded"]
    match = re.search(
        r"failed: camera ptz stale from ([\d.]+) s: (\d+) items not inspected", summary
    )
    assert match, summary
    assert abs(float(match.group(1)) - at) < 1.0
    stale_items = sum(c["items"] - c["detected"] for c in metrics["checkpoints"])
    assert int(match.group(2)) == stale_items > 0
    assert metrics["stale_sensors"]["camera:ptz"][0]["until"] is None
    assert metrics["first_cause"] in summary
    loss = metrics["feature_loss_s"]
    assert set(loss) == {"front", "rear", "ptz"}  # every camera unit, used or not
    if "front-left" in cameras:  # the checkpoints' camera, frozen while it is in use
        assert loss["front"] > 0.0


def test_a_drifting_pose_without_gps_is_flagged_and_fails(tmp_path, capsys):
    """The track has nothing to register against: without GPS the pose drifts; the
    checkpoint is reached far from its true pose and the estimate knew it was unsure."""
    faults = ['    <gps-loss at="0" duration="10000"/>']
    code, summary, metrics = _run(tmp_path, capsys, "track", "straight-run.xml", faults)
    assert code == 1, summary
    cp = metrics["checkpoints"][0]
    assert cp["reached"] and cp["position_error"] > 0.15
    assert cp["uncertain"] and cp["pose_sigma"] > 0.15
    # the executive itself knew, without ground truth: an event, a warning, the journal
    assert "warning: checkpoint CP1 completed with a pose uncertainty of" in metrics["stderr"]
    done = next(r for r in metrics["journal"] if r["event"] == "checkpoint-done")
    assert done["sigma_f"] > 0.15
    assert re.search(
        r"failed: checkpoint CP1 reached \d+ cm from its pose \(tolerance 15 cm\)"
        r", with a pose uncertainty of \d+ cm",
        summary,
    ), summary
