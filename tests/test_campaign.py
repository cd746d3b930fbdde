"""Campaigns (issue 16): the campaign file, episodes as pure functions of (seed, index),
results that survive a kill, shards that merge into the unsharded run, and an exported
episode that `dry-run` reruns identically."""

import dataclasses
import json
import math
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from shapely.geometry import Point

from executive.campaign.results import RESULTS_FILE, read_rows, wilson
from executive.campaign.route import RouteMap, obstacle_geometry, passable, sweep_geometry
from executive.campaign.runner import episode_row, run_campaign
from executive.campaign.sampler import draw_episode, episode_scenario, export_scenario
from executive.campaign.spec import load_campaign
from executive.cli import check_any, main
from executive.core.problems import InvalidInputError
from sim2d.scenario import Chaser, PathMover, StaticObstacle, load_scenario
from tests.conftest import MISSIONS, REPO, wait_until

SHIPPED = MISSIONS / "campaigns"
TRACK_CAMPAIGN = """<?xml version="1.0" encoding="UTF-8"?>
<campaign xmlns="urn:walkaround:campaign:1" id="short" seed="7" episodes="4" duration="{duration}">
  <scenario file="../track/scenarios/avoidance-leg.xml"/>
  <movers count-min="0" count-max="2" speed-min="0.1" speed-max="0.6" clearance="3"
          half-length-min="3" half-length-max="5" min-leg="10">
    <mover kind="person" radius="0.3" height="1.8"/>
    <mover kind="trolley" length="1.2" width="0.8" height="1.0"/>
    <chasers share="0.3" offset-min="3" offset-max="4" trigger-min="4" trigger-max="8"
             pursuit-min="8" pursuit-max="20"/>
  </movers>
  <blockers count-min="0" count-max="2" lateral="2" end-margin="3" gap="2.5" corridor="4"
            min-leg="10">
    <circle kind="cone" radius-min="0.15" radius-max="0.3" height="0.7"/>
    <box kind="equipment" length-min="1" length-max="2" width-min="0.8" width-max="1.2"
         height="1"/>
  </blockers>
  <noise scale-min="0.5" scale-max="2"/>
  <faults>
    <laser-dropout laser="rear" probability="0.5" at-min="0.5" at-max="2" duration-min="0.2"
                   duration-max="1"/>
  </faults>
</campaign>
"""


@pytest.fixture
def library(tmp_path: Path) -> Path:
    """A private mission library with the test track and a short campaign (4 s episodes)."""
    lib = tmp_path / "lib"
    shutil.copytree(MISSIONS / "track", lib / "track")
    (lib / "campaigns").mkdir()
    (lib / "campaigns" / "short.xml").write_text(TRACK_CAMPAIGN.format(duration=3))
    return lib


def _same_but_wall(a: dict, b: dict) -> bool:
    """Two result rows equal apart from the wall time."""
    return {k: v for k, v in a.items() if k != "wall_s"} == {
        k: v for k, v in b.items() if k != "wall_s"
    }


def _write(lib: Path, text: str) -> Path:
    path = lib / "campaigns" / "bad.xml"
    path.write_text(text)
    return path


def _line_of(path: Path, needle: str) -> int:
    return next(i for i, line in enumerate(path.read_text().splitlines(), 1) if needle in line)


SPAWNS = pytest.mark.xdist_group("hil")
"""For the tests that start worker processes of their own: they join the real-time (HIL)
tests' xdist group, which one worker runs in turn, so that they never starve the HIL
rig's processes on a 2-core machine."""


# -- the file ------------------------------------------------------------------------------------
def test_shipped_campaigns_are_valid():
    for path in sorted(SHIPPED.glob("*.xml")):
        assert check_any(path) == [], path
        campaign = load_campaign(path)
        assert campaign.scenarios and campaign.digest


@pytest.mark.parametrize(
    ("old", "new", "code", "needle"),
    [
        (
            'speed-min="0.1" speed-max="0.6"',
            'speed-min="0.9" speed-max="0.6"',
            "min-above-max",
            "<movers",
        ),
        ('speed-min="0.1"', 'speed-min="-0.1"', "schema", "<movers"),
        (
            'count-min="0" count-max="2" lateral',
            'count-min="-1" count-max="2" lateral',
            "schema",
            "<blockers",
        ),
        ('half-length-min="3"', 'half-length-min="2"', "crossing-inside-clearance", "<movers"),
        ('offset-min="3"', 'offset-min="1"', "chaser-inside-clearance", "<chasers"),
        ('laser="rear"', 'laser="top"', "unknown-reference", "<laser-dropout"),
        ('probability="0.5"', 'probability="1.5"', "schema", "<laser-dropout"),
        ("avoidance-leg.xml", "missing.xml", "scenario-path", "<scenario"),
        (
            'radius-min="0.15" radius-max="0.3"',
            'radius-min="0.3" radius-max="0.15"',
            "min-above-max",
            "<circle",
        ),
    ],
)
def test_loader_refuses_with_file_and_line(library, old, new, code, needle):
    text = TRACK_CAMPAIGN.format(duration=3)
    assert old in text
    path = _write(library, text.replace(old, new, 1))
    with pytest.raises(InvalidInputError) as info:
        load_campaign(path)
    problems = [p for p in info.value.problems if p.code == code]
    assert problems, info.value.summary()
    assert problems[0].where.file.endswith("bad.xml")
    # schema errors are reported on the element's line; semantic ones at the element
    line = _line_of(path, needle)
    assert line <= problems[0].where.line <= line + 2, info.value.summary()
    assert main(["validate", str(path)]) == 2
    assert main(["campaign", str(path), "--out", str(library / "out")]) == 2
    assert not (library / "out").exists()


def test_scenario_outside_the_library_is_refused(library):
    path = _write(
        library,
        TRACK_CAMPAIGN.format(duration=3).replace(
            "../track/scenarios/avoidance-leg.xml", "../../../etc/passwd"
        ),
    )
    with pytest.raises(InvalidInputError, match="outside the mission library"):
        load_campaign(path)


# -- episodes ------------------------------------------------------------------------------------
def test_episode_is_a_pure_function_of_seed_and_index(library):
    campaign = load_campaign(library / "campaigns" / "short.xml")
    again = load_campaign(library / "campaigns" / "short.xml")
    for k in range(6):
        assert episode_scenario(campaign, k) == episode_scenario(again, k)
    scenarios = [episode_scenario(campaign, k) for k in range(6)]
    assert len({s.seed for s in scenarios}) == 6
    assert episode_scenario(campaign.with_seed(8), 0) != scenarios[0]
    a, b = episode_row(campaign, 1), episode_row(again, 1)
    assert a["outcome"] == "timeout" and a["simulated_s"] == pytest.approx(3.0, abs=0.1)
    assert _same_but_wall(a, b)


def test_a_crashing_episode_is_a_row(library, monkeypatch):
    campaign = load_campaign(library / "campaigns" / "short.xml")

    def boom(*args, **kwargs):
        raise RuntimeError("simulated crash")

    monkeypatch.setattr("executive.dryrun.dry_run", boom)
    row = episode_row(campaign, 0)
    assert row["outcome"] == "crashed" and not row["succeeded"]
    assert "simulated crash" in row["first_cause"] and "RuntimeError" in row["traceback"]


def _check_layout(scenario, base_ids: set[str], campaign) -> None:
    """The placement rules of executive.campaign.sampler, checked independently."""
    route = RouteMap(dataclasses.replace(scenario, obstacles=()))
    drawn = [o for o in scenario.obstacles if o.id not in base_ids]
    base = [o for o in scenario.obstacles if o.id in base_ids]
    base_geoms = [obstacle_geometry(o) for o in base]
    for ob in drawn:
        geom = sweep_geometry(ob) if isinstance(ob, PathMover) else obstacle_geometry(ob)
        assert not route.footprint.intersects(geom), ob.id
        assert route.zones is None or not route.zones.intersects(geom), ob.id
        assert not route.spots.intersects(geom), ob.id
        assert all(not g.intersects(geom) for g in base_geoms), ob.id
        if isinstance(ob, StaticObstacle) and ob.id.startswith("clutter"):
            assert route.route_distance(geom) >= campaign.clutter.clearance - 1e-6
        elif isinstance(ob, StaticObstacle):
            assert route.point_distance(geom) >= campaign.blockers.end_margin - 1e-6
        elif isinstance(ob, PathMover):
            ends = [Point(p) for p in ob.waypoints]
            assert min(route.route_distance(p) for p in ends) >= campaign.movers.clearance - 1e-3
            assert route.lines.intersects(sweep_geometry(ob))  # it crosses the route
        else:
            assert isinstance(ob, Chaser)
            assert route.route_distance(Point(ob.start)) >= campaign.movers.clearance - 1e-3
    blockers = [obstacle_geometry(o) for o in drawn if o.id.startswith("blocker")]
    if blockers:
        for leg in route.legs:
            assert passable(leg, blockers, campaign.blockers.corridor, campaign.blockers.gap - 1e-3)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(index=st.integers(0, 10**6), which=st.sampled_from(["avoidance-leg", "a320-busy-apron"]))
def test_layouts_keep_the_route_usable(index, which):
    campaign = load_campaign(SHIPPED / f"{which}.xml")
    episode = draw_episode(campaign, index)
    base = campaign.scenarios[0].scenario
    _check_layout(episode.scenario, {o.id for o in base.obstacles}, campaign)
    off = campaign.parking_offset
    if off is not None:
        p = episode.scenario.parking_offset
        assert off.dx.lo <= p.x <= off.dx.hi and off.dy.lo <= p.y <= off.dy.hi
        assert off.dheading_deg.lo - 1e-6 <= math.degrees(p.theta) <= off.dheading_deg.hi + 1e-6


def test_export_round_trips_and_dry_run_reruns_the_episode(library, tmp_path, capsys):
    campaign = load_campaign(library / "campaigns" / "short.xml")
    folder = library / "track" / "scenarios"
    for k in range(8):  # every element the sampler produces, across episodes
        scenario = episode_scenario(campaign, k)
        path = export_scenario(scenario, folder / f"episode-{k}.xml")
        assert dataclasses.replace(load_scenario(path), source="") == dataclasses.replace(
            scenario, source=""
        )
    shutil.copytree(MISSIONS / "a320", library / "a320")
    shutil.copy(SHIPPED / "a320-busy-apron.xml", library / "campaigns")
    busy = load_campaign(library / "campaigns" / "a320-busy-apron.xml")
    for k in (0, 2, 4, 6):  # chasers, crossings, clutter, the base's groups and boxes
        scenario = episode_scenario(busy, k)
        path = export_scenario(scenario, library / "a320" / "scenarios" / f"ep-{k}.xml")
        assert dataclasses.replace(load_scenario(path), source="") == dataclasses.replace(
            scenario, source=""
        )

    row = episode_row(campaign, 2)
    out = tmp_path / "ep"
    exported = tmp_path / "exported.xml"  # the shipped mission is outside its library
    assert (
        main(
            [
                "campaign",
                str(SHIPPED / "avoidance-leg.xml"),
                "--episode",
                "2",
                "--export-scenario",
                str(exported),
            ]
        )
        == 2
    )
    assert not exported.exists()
    target = folder / "episode-2-cli.xml"
    assert (
        main(
            [
                "campaign",
                str(library / "campaigns" / "short.xml"),
                "--episode",
                "2",
                "--export-scenario",
                str(target),
            ]
        )
        == 0
    )
    capsys.readouterr()
    status = main(
        [
            "dry-run",
            str(library / "track" / "avoidance-leg.xml"),
            "--scenario",
            str(target),
            "--out",
            str(out),
            "--quiet",
            "--no-record",
        ]
    )
    assert status == 1  # 3 s is not enough to finish: a timeout, as in the campaign
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["seed"] == row["sim_seed"]
    assert metrics["outcome"] == row["outcome"] and metrics["first_cause"] == row["first_cause"]
    assert metrics["min_clearance"] == row["min_clearance"]
    assert metrics["simulated_s"] == row["simulated_s"]
    assert metrics["checkpoints_reached"] == row["checkpoints_reached"]


# -- running -------------------------------------------------------------------------------------
@SPAWNS
def test_shards_merge_into_the_unsharded_run(library, tmp_path, capsys):
    campaign = library / "campaigns" / "short.xml"
    whole = run_campaign(load_campaign(campaign), tmp_path / "whole", 5)
    assert [r["episode"] for r in whole] == [0, 1, 2, 3, 4]
    for i in (0, 1):
        assert (
            main(
                [
                    "campaign",
                    str(campaign),
                    "--out",
                    str(tmp_path / f"s{i}"),
                    "--episodes",
                    "5",
                    "--shard",
                    f"{i}/2",
                    "--quiet",
                    "--jobs",
                    "2",
                ]
            )
            == 1
        )
    assert [r["episode"] for r in read_rows(tmp_path / "s1" / RESULTS_FILE)] in ([1, 3], [3, 1])
    assert (
        main(
            [
                "campaign",
                "merge",
                str(tmp_path / "m"),
                str(tmp_path / "s0"),
                str(tmp_path / "s1"),
                str(tmp_path / "s0"),
            ]
        )
        == 0
    )
    merged = read_rows(tmp_path / "m" / RESULTS_FILE)
    assert len(merged) == len(whole)
    assert all(_same_but_wall(a, b) for a, b in zip(merged, whole, strict=True))
    summary = json.loads((tmp_path / "m" / "summary.json").read_text())
    assert (
        summary["episodes"] == 5 and summary["by_scenario"][0]["scenario"] == "track-avoidance-leg"
    )
    # a shard of another seed is refused
    assert (
        main(
            [
                "campaign",
                str(campaign),
                "--out",
                str(tmp_path / "other"),
                "--episodes",
                "1",
                "--seed",
                "99",
                "--quiet",
            ]
        )
        == 1
    )
    assert (
        main(
            [
                "campaign",
                "merge",
                str(tmp_path / "m2"),
                str(tmp_path / "s0"),
                str(tmp_path / "other"),
            ]
        )
        == 2
    )
    assert "another campaign" in capsys.readouterr().err


@SPAWNS
def test_killed_campaign_resumes_without_loss_or_repeat(library, tmp_path):
    campaign = library / "campaigns" / "short.xml"
    out = tmp_path / "run"
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "PYTHONPATH": str(REPO)}
    command = [
        sys.executable,
        "-m",
        "executive.cli",
        "campaign",
        str(campaign),
        "--out",
        str(out),
        "--episodes",
        "6",
        "--quiet",
    ]
    proc = subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        results = out / RESULTS_FILE
        wait_until(
            lambda: results.exists() and results.read_text().count("\n") >= 2,
            120,
            "two finished episodes",
        )
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    before = read_rows(out / RESULTS_FILE)
    assert 2 <= len(before) < 6
    with (out / RESULTS_FILE).open("a") as handle:
        handle.write('{"episode": 5, "outcome": "tor')  # a write cut by the kill
    assert main(["campaign", str(campaign), "--out", str(out), "--episodes", "6"]) == 2
    assert (
        main(
            ["campaign", str(campaign), "--out", str(out), "--episodes", "6", "--resume", "--quiet"]
        )
        == 1
    )
    after = read_rows(out / RESULTS_FILE)
    assert sorted(r["episode"] for r in after) == [0, 1, 2, 3, 4, 5]
    assert after[: len(before)] == before  # the finished episodes were kept, not rerun
    reference = run_campaign(load_campaign(campaign), tmp_path / "ref", 6)
    by_episode = {r["episode"]: r for r in after}
    assert all(_same_but_wall(by_episode[r["episode"]], r) for r in reference)
    # another seed may not extend these results
    assert (
        main(
            [
                "campaign",
                str(campaign),
                "--out",
                str(out),
                "--episodes",
                "6",
                "--resume",
                "--seed",
                "3",
                "--quiet",
            ]
        )
        == 2
    )


def test_command_line_refusals(library, tmp_path, capsys):
    campaign = str(library / "campaigns" / "short.xml")
    out = str(tmp_path / "o")
    for bad in (["--shard", "2/2"], ["--shard", "x"], ["--jobs", "0"], ["--episodes", "-1"]):
        assert main(["campaign", campaign, "--out", out, *bad]) == 2
    assert main(["campaign", campaign]) == 2  # no --out
    shipped = str(SHIPPED / "avoidance-leg.xml")
    assert main(["campaign", shipped, "--episode", "1", "--export-scenario", out]) == 2
    assert main(["campaign", shipped, "--export-scenario", out]) == 2  # no --episode
    assert not Path(out).exists()


def test_wilson_interval():
    assert wilson(0, 0) is None
    low, high = wilson(99, 100)
    assert low == pytest.approx(0.9455, abs=1e-3) and high == pytest.approx(0.9982, abs=1e-3)
    assert wilson(10, 10)[1] == 1.0
