"""Issue 18: pictures that read well.

sim-view and trajectory.png carry a legend beside the plot that names every kind of mark
drawn and only those (checked against what the scenario holds, with movers and zones and
without); the checkpoint labels of the A320 (23 of them) do not overlap one another in
the saved figure, measured with its renderer, and stay inside it; the label placer keeps
random crowds apart; avoidance.png is written only when there is something to draw, and
metrics.json names only the pictures that are in the folder.
"""

import dataclasses
import io
import itertools
import json
import math

import matplotlib.pyplot as plt
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import executive.report as report
from executive.dryrun import AvoidanceSample, DryRun, dry_run
from executive.report import controller_kind, trajectory_figure, write_report
from executive.runtime import Event
from sim2d.labels import Label, kinds_legend, mark_kinds, place_labels, tag_all, untagged_marks
from sim2d.robot import SimRobot
from sim2d.scenario import (
    Chaser,
    LoiteringGroup,
    PathMover,
    Scenario,
    StaticObstacle,
    load_scenario,
)
from sim2d.view import world_figure
from tests.conftest import MISSIONS

BUSY = MISSIONS / "a320" / "scenarios" / "busy-apron.xml"  # zones, static obstacles, movers
TRACK = MISSIONS / "track" / "scenarios" / "clear-apron.xml"  # no zone, no obstacle
CHASED = MISSIONS / "track" / "scenarios" / "straight-run-40m.xml"  # no zone; a chaser
A320 = MISSIONS / "a320" / "scenarios" / "clear-apron.xml"


def world_kinds(scenario: Scenario, *, views: bool) -> set[str]:
    """The kinds of marks the world of ``scenario`` must show, from what it holds (the
    laser scan aside: whether a beam hits anything depends on where the robot stands)."""
    mission = scenario.mission
    kinds = {"route (as planned)", "robot"}
    kinds |= {"aircraft outline"} if mission.aircraft.outline else set()
    kinds |= {"aircraft footprint"} if mission.aircraft.footprint else set()
    kinds |= {"checkpoint (as planned)"} if mission.checkpoints else set()
    kinds |= {f"forbidden zone: {z.kind.value}" for z in mission.airport.zones}
    obstacles = scenario.obstacles
    kinds |= {"static obstacle"} if any(isinstance(o, StaticObstacle) for o in obstacles) else set()
    kinds |= {"mover's path"} if any(isinstance(o, PathMover) for o in obstacles) else set()
    kinds |= {"loitering area"} if any(isinstance(o, LoiteringGroup) for o in obstacles) else set()
    if any(isinstance(o, Chaser) and o.trigger_radius for o in obstacles):
        kinds.add("chaser's trigger radius")
    if any(not isinstance(o, StaticObstacle) for o in obstacles):
        kinds.add("moving obstacle")
    if views:
        kinds.add("camera field of view")
    return kinds


def saved(fig: plt.Figure) -> plt.Figure:
    """``fig`` after saving it as a PNG (the layout and text extents then are final)."""
    fig.savefig(io.BytesIO(), format="png")
    return fig


def legend_texts(fig: plt.Figure) -> list[str]:
    (legend,) = fig.legends
    return [t.get_text() for t in legend.get_texts()]


def assert_legend_beside_the_plot(fig: plt.Figure) -> None:
    """The legend hides nothing of the plot; it, the axis labels, ticks and title are
    all inside the figure (nothing cut at its edge)."""
    renderer = fig.canvas.get_renderer()
    (legend,) = fig.legends
    box = legend.get_window_extent(renderer)
    assert not box.overlaps(fig.axes[0].bbox), "the legend hides part of the plot"
    decorations = fig.axes[0].get_tightbbox(renderer)
    for part in (box, decorations):
        assert fig.bbox.contains(part.x0, part.y0) and fig.bbox.contains(part.x1, part.y1)


def label_boxes(fig: plt.Figure) -> dict[str, object]:
    renderer = fig.canvas.get_renderer()
    return {t.get_text(): t.get_window_extent(renderer) for t in fig.axes[0].texts if t.get_text()}


def assert_no_overlap_inside(fig: plt.Figure, boxes: dict[str, object]) -> None:
    for (a, box_a), (b, box_b) in itertools.combinations(boxes.items(), 2):
        assert not box_a.overlaps(box_b), f"labels {a!r} and {b!r} overlap"
    frame = fig.axes[0].bbox
    for name, box in boxes.items():
        assert frame.x0 <= box.x0 and box.x1 <= frame.x1, name
        assert frame.y0 <= box.y0 and box.y1 <= frame.y1, name
        assert fig.bbox.contains(box.x0, box.y0) and fig.bbox.contains(box.x1, box.y1), name


@pytest.mark.parametrize("path", [BUSY, TRACK, CHASED], ids=["busy-apron", "track", "chaser"])
def test_sim_view_legend_names_every_kind_of_mark_drawn_and_only_those(path):
    scenario = load_scenario(path)
    fig = saved(world_figure(SimRobot(scenario)))
    ax = fig.axes[0]
    entries = legend_texts(fig)
    assert not untagged_marks(ax), "a mark that the legend cannot name"
    assert entries == mark_kinds(ax)  # each kind drawn once, nothing else
    assert set(entries) - {"laser scan"} == world_kinds(scenario, views=True)
    assert_legend_beside_the_plot(fig)
    plt.close(fig)


def test_movers_and_zones_appear_in_the_legend_only_when_the_scenario_has_them():
    with_them = saved(world_figure(SimRobot(load_scenario(BUSY))))
    without = saved(world_figure(SimRobot(load_scenario(TRACK))))
    busy, bare = set(legend_texts(with_them)), set(legend_texts(without))
    assert {"moving obstacle", "mover's path", "loitering area", "static obstacle"} <= busy
    assert {"forbidden zone: refuelling", "forbidden zone: engine-danger"} <= busy
    assert not {k for k in bare if "zone" in k or "obstacle" in k or "mover" in k}
    plt.close(with_them)
    plt.close(without)


def test_the_a320_checkpoint_labels_do_not_collide_in_sim_view():
    scenario = load_scenario(A320)
    fig = saved(world_figure(SimRobot(scenario)))
    boxes = label_boxes(fig)
    assert sorted(boxes) == sorted(cp.id for cp in scenario.mission.checkpoints)
    assert len(boxes) == 23
    assert_no_overlap_inside(fig, boxes)
    plt.close(fig)


@pytest.fixture(scope="module")
def short_runs() -> dict[str, DryRun]:
    """Two seconds of the A320 on the busy apron and on the clear one."""
    return {
        "busy": dry_run(load_scenario(BUSY), max_time=2.0),
        "clear": dry_run(load_scenario(A320), max_time=2.0),
    }


@pytest.mark.parametrize("name", ["busy", "clear"])
def test_trajectory_legend_and_labels(short_runs, name):
    run = short_runs[name]
    fig = saved(trajectory_figure(run))
    ax = fig.axes[0]
    entries = legend_texts(fig)
    assert not untagged_marks(ax)
    assert entries == mark_kinds(ax)
    controllers = {f"true path: {controller_kind(s.controller)}" for s in run.samples}
    expected = world_kinds(run.scenario, views=False) | controllers
    expected |= {"checkpoint (true pose)", "estimated path"}
    assert expected <= set(entries)
    extra = set(entries) - expected
    allowed = {
        "tracked obstacle's path",
        "tracked obstacle on the robot's path",
        "global registration (accepted)",
        "global registration (rejected)",
        "footprint as registered",
    }
    assert extra <= allowed, extra
    assert ("footprint as registered" in extra) == (run.final_placement is not None)
    assert "collision" not in entries and "e-stop" not in entries  # none happened
    assert_legend_beside_the_plot(fig)
    boxes = label_boxes(fig)  # "CP07 not reached": 23 long labels
    assert len(boxes) == len(run.checkpoints) == 23
    assert_no_overlap_inside(fig, boxes)
    plt.close(fig)


@settings(
    max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    st.lists(
        st.tuples(st.floats(-3.0, 3.0), st.floats(-3.0, 3.0)),
        min_size=2,
        max_size=14,
    ),
    st.floats(-60.0, 60.0),
)
def test_a_crowd_of_labels_is_kept_apart(anchors, where):
    """Up to 14 labels within a 6 m square somewhere in a 140 m wide view (as the
    checkpoints round a nose gear): no two overlap, all inside the axes, each beside its
    anchor (within the furthest distance tried)."""
    fig, ax = plt.subplots(figsize=(8, 6), dpi=100, layout="constrained")
    ax.set_xlim(-70, 70)
    ax.set_ylim(-50, 50)
    tag_all(ax.plot(*zip(*[(x + where, y) for x, y in anchors], strict=True), "o"), "point")
    kinds_legend(fig, ax)
    labels = [Label(f"CP{i:02d} 12 cm 0.4°", x + where, y) for i, (x, y) in enumerate(anchors)]
    texts = place_labels(fig, ax, labels)
    saved(fig)
    boxes = label_boxes(fig)
    assert len(boxes) == len(labels)
    assert_no_overlap_inside(fig, boxes)
    renderer = fig.canvas.get_renderer()
    for text, label in zip(texts, labels, strict=True):
        box = text.get_window_extent(renderer)
        ax_, ay_ = ax.transData.transform((label.x, label.y))
        near = (min(max(ax_, box.x0), box.x1), min(max(ay_, box.y0), box.y1))
        assert math.dist(near, (ax_, ay_)) <= 70 * fig.dpi / 72  # points to pixels
    plt.close(fig)


def test_safety_stops_and_breaches_are_marked_named_and_labelled(lab_run):
    """An e-stop, a stale-sensor stop and a geofence breach (put into a real run's
    record): each has its mark and legend entry, and the breach its label."""
    events = [
        *lab_run.result.events,
        Event(1.0, "safety", {"kind": "estop-latched", "reason": "obstacle at 0.5 m"}),
        Event(1.5, "safety", {"kind": "stale-sensor", "reason": "laser front stale"}),
    ]
    zone = lab_run.scenario.mission.airport.zones[0].id
    run = dataclasses.replace(
        lab_run,
        result=dataclasses.replace(lab_run.result, events=events),
        breaches=[(1.2, zone)],
    )
    fig = saved(trajectory_figure(run))
    entries = legend_texts(fig)
    assert entries == mark_kinds(fig.axes[0])
    assert {"e-stop", "safety stop: stale-sensor", "geofence breach"} <= set(entries)
    assert "collision" not in entries
    boxes = label_boxes(fig)
    assert f"breach {zone}" in boxes and len(boxes) == len(run.checkpoints) + 1
    assert_no_overlap_inside(fig, boxes)
    assert_legend_beside_the_plot(fig)
    plt.close(fig)
    plain = saved(trajectory_figure(lab_run))
    assert not {"e-stop", "geofence breach"} & set(legend_texts(plain))
    plt.close(plain)


def _avoiding(run: DryRun, value: float) -> DryRun:
    """``run`` with one avoidance episode of 20 samples whose plotted values are ``value``."""
    samples = [
        AvoidanceSample(
            t=1.0 + k / 10,
            episode=1,
            mode="spiral",
            obstacle=3,
            alpha_d=value,
            xi=value,
            beta_c=value,
            e_alpha=value,
            e_r=value,
            v=0.5,
            omega=0.0,
            clearance=value,
        )
        for k in range(20)
    ]
    return dataclasses.replace(run, avoidance=samples)


@pytest.fixture(scope="module")
def lab_run() -> DryRun:
    return dry_run(load_scenario(MISSIONS / "lab" / "scenarios" / "clear-apron.xml"), max_time=2)


def test_no_avoidance_no_avoidance_png_and_metrics_do_not_name_it(lab_run, tmp_path):
    assert not lab_run.avoidance  # its tracks (static things) are no avoidance
    out = write_report(lab_run, tmp_path / "plain")
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["figures"] == ["trajectory.png", "timeline.png"]
    assert not (out / "avoidance.png").exists()
    assert all((out / name).stat().st_size > 10_000 for name in metrics["figures"])
    # samples but nothing finite to plot: still no picture
    out = write_report(_avoiding(lab_run, math.nan), tmp_path / "nan")
    assert not (out / "avoidance.png").exists()
    assert "avoidance.png" not in json.loads((out / "metrics.json").read_text())["figures"]


def test_an_avoidance_episode_draws_avoidance_png_and_metrics_name_it(lab_run, tmp_path):
    out = write_report(_avoiding(lab_run, 1.5), tmp_path / "avoided")
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["figures"] == ["trajectory.png", "timeline.png", "avoidance.png"]
    assert (out / "avoidance.png").stat().st_size > 10_000


@pytest.mark.slow
def test_a_real_avoidance_draws_avoidance_png_and_shows_in_the_trajectory(tmp_path):
    """15 s of the 40 m run: the spiral has engaged round the parked car."""
    run = dry_run(load_scenario(CHASED), max_time=15.0)
    assert run.avoidance
    out = write_report(run, tmp_path / "report")
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["figures"] == ["trajectory.png", "timeline.png", "avoidance.png"]
    assert (out / "avoidance.png").stat().st_size > 10_000
    fig = saved(trajectory_figure(run))
    entries = legend_texts(fig)
    assert "true path: spiral avoidance" in entries and entries == mark_kinds(fig.axes[0])
    assert not untagged_marks(fig.axes[0])
    assert_legend_beside_the_plot(fig)
    plt.close(fig)


def test_a_picture_that_cannot_be_written_is_not_named(lab_run, tmp_path, monkeypatch):
    real = report.write_atomic

    def full(path, data):
        if path.name == "avoidance.png":
            raise OSError(28, "No space left on device", str(path))
        return real(path, data)

    monkeypatch.setattr(report, "write_atomic", full)
    out = tmp_path / "full"
    with pytest.raises(OSError, match="No space left"):
        write_report(_avoiding(lab_run, 1.5), out)
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["figures"] == ["trajectory.png", "timeline.png"]
    assert not (out / "avoidance.png").exists()
