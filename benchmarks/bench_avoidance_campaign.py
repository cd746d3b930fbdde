"""Avoidance campaign (issue 6): seeded random obstacle layouts on one 13 m leg, the
executive's avoidance (spiral / velocity obstacles) against a dynamic-window baseline.

Usage:
    python benchmarks/bench_avoidance_campaign.py [--episodes 200] [--controller both]
        [--jobs 2] [--seed 0] [--out benchmarks/results/avoidance_campaign.json]
    python benchmarks/bench_avoidance_campaign.py --episodes 20 --layouts   # no runs

Mission: ``missions/track/avoidance-leg.xml``: the robot starts at (0, 0) facing east, the
leg runs to P at (13, 0); the checkpoint (1 s dwell) is 1 m further and the station
beside it, so an episode is one avoidance leg plus ~15 s at the far end. Each episode is a
scenario written into a private copy of ``missions/track/`` (as ``tests/sim2d_helpers``
does) and dry-run with ``dry_run(scenario, avoidance=True, avoider=...)``: ``None`` (the
executive's own avoidance, called "spiral" here: the policy picks the spiral, velocity
obstacles or its fallback planner) or :class:`dwa.DwaAvoidance` (benchmarks/dwa.py),
which the compiler then builds for both the spiral and the velocity-obstacle branches (the
policy's fallback planner stays the executive's; the time each avoidance controller ran
is recorded per episode, so a DWA run helped by it shows).

Episodes (:func:`make_layout`). Episode k draws from ``numpy.random.Generator(PCG64(
SeedSequence([seed, k])))``, so a layout depends only on (seed, k) and both controllers run
the very same scenarios (same simulator seed too). 1-3 obstacles, each one of:

* ``box`` (25 %): a parked vehicle (4-5 m x 1.6-2.0 m) or a cart / equipment
  (1-2.5 m x 0.8-1.5 m), any heading, centre within 2 m of the centre line;
* ``circle`` (20 %): a bin (r 0.3-0.6 m) or a cone (r 0.15-0.3 m), within 1.5 m of it;
* ``crossing`` (25 %): a person (r 0.3 m) or a trolley (1.2 x 0.8 m) walking a two-waypoint
  ``<path>`` straight across the track, from 3-5 m on one side to 3-5 m on the other, its
  ``trigger-radius`` set so that it reaches the centre line when the robot (at the cruise
  speed) would, +- 1.5 s;
* ``oncoming`` (15 %): a person or trolley walking down the track towards the start from
  x 8-11.5 m, 0-1.5 m off the centre line, triggered when the robot comes within 5-9 m;
* ``chaser`` (15 %): an adversarial ``<chaser>`` (person or trolley) waiting 2-4 m beside
  the track, triggered within 4-8 m, that gives up after a ``pursuit`` of 8-20 s (without
  it a chaser slower than the robot still reaches it while it stands at the checkpoint).

Mover speeds are uniform in [0.1, 0.6) m/s, 0.6 m/s being the robot's cruise speed on this
mission; a mover is faster (uniform in [0.6, 1.2] m/s) with probability ``FAST_FRACTION``
(10 %), and the results are split by that. Obstacles keep the first 3 m and the last
2.5 m before the checkpoint clear at the start (x in [3, 11.5] m). The mission has no
forbidden zones (no geofence), so the generator uses a 4 m half-width corridor as "the
track": a layout is rejected (and redrawn) unless the robot's start and P are connected
through the track with at least a 2.5 m gap everywhere (the free space eroded by 1.25 m);
movers must not start in or walk through a static obstacle.

Per episode (:func:`episode_record`): success (``DryRun.succeeded``: completed, no
collision, no geofence breach), outcome and reason, collisions (which obstacle, its
category and speed; the robot's sent speed and active controller at the last 10 Hz
sample before the contact: a mover walking into a robot held by the e-stop shows as
``robot_v`` 0 under the e-stop controller), the minimum true footprint
clearance (``metrics()['min_clearance']``), the true path length of the leg (until the
robot is within 0.35 m of P) and of the whole run, the leg and mission times (simulated),
the avoidance engagements (controller switches into an avoidance controller from another
controller; the avoidance controllers are read off the compiled tree: the controllers
under an ``AvoidanceTrigger`` guard), time per avoidance controller, e-stops. One
obstacle-free reference episode per controller gives the ratios "path length over the
obstacle-free path" (leg) and "time over the obstacle-free time" (mission).

Output: the JSON (``rows`` per episode, ``references``, ``summary`` per controller) and a
markdown table for BENCHMARKS.md on stdout. Progress: one line per finished episode.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy: one core per worker
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import json
import math
import multiprocessing
import shutil
import tempfile
import time
import traceback
from collections import Counter
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from dwa import DwaAvoidance  # benchmarks/dwa.py: the script's directory is on sys.path
from shapely.geometry import LineString, Point, box
from shapely.geometry import Polygon as ShapelyPolygon
from shapely.ops import unary_union

from behaviours.controllers.avoidance import AvoidanceTrigger
from executive.campaign.results import wilson
from executive.compiler import CompileOptions, GuardedBranch, compile_mission
from executive.dryrun import DryRun, dry_run
from executive.report import metrics
from sim2d.scenario import load_scenario

REPO = Path(__file__).resolve().parent.parent

MISSION_DIR = REPO / "missions" / "track"
MISSION_FILE = "avoidance-leg.xml"
START = (0.0, 0.0)
P = (13.0, 0.0)
CHECKPOINT = (14.0, 0.0)
CRUISE = 0.6
"""The mission's cruise speed (m/s): "slower than the robot" means slower than this."""
X_FREE_START, X_FREE_END = 3.0, 11.5
"""Obstacles start inside x in [3, 11.5] m: the first 3 m and the last 2.5 m are clear."""
TRACK_HALF_WIDTH = 4.0
"""Half-width of the corridor the gap check uses (the mission has no geofence)."""
GAP = 2.5
"""A layout must leave the robot a passage at least this wide (m)."""
FAST_FRACTION = 0.1
"""Probability that a mover is faster than the robot (0.6-1.2 m/s)."""
SLOW_SPEEDS = (0.1, CRUISE)
FAST_SPEEDS = (CRUISE, 1.2)
CATEGORIES = ("box", "circle", "crossing", "oncoming", "chaser")
WEIGHTS = (0.25, 0.20, 0.25, 0.15, 0.15)
DURATION = 150.0
"""Simulated time limit of an episode (s): about 4x the obstacle-free run (~40 s)."""
AT_P = 0.35
"""The leg ends when the true position first comes within this distance of P (m)."""
CONTROLLERS = ("spiral", "dwa")


# -- layouts ------------------------------------------------------------------------------------
@dataclass
class ObstacleSpec:
    """One obstacle of a layout: its scenario XML and what the report needs."""

    id: str
    category: str
    speed: float
    xml: str
    fast: bool = False
    static: bool = True


@dataclass
class Layout:
    episode: int
    seed: int
    obstacles: list[ObstacleSpec] = field(default_factory=list)
    redraws: int = 0

    @property
    def fast(self) -> bool:
        return any(o.fast for o in self.obstacles)


def _f(x: float) -> str:
    return f"{x:.3f}"


def _mover_body(rng: np.random.Generator) -> tuple[str, str, float]:
    """(kind, shape attributes, enclosing radius) of a person or a trolley."""
    if rng.random() < 0.5:
        return "person", 'radius="0.3" height="1.8"', 0.3
    return "trolley", 'length="1.2" width="0.8" height="1.0"', math.hypot(0.6, 0.4)


def _speed(rng: np.random.Generator) -> tuple[float, bool]:
    fast = bool(rng.random() < FAST_FRACTION)
    lo, hi = FAST_SPEEDS if fast else SLOW_SPEEDS
    return float(rng.uniform(lo, hi)), fast


def _box_geometry(x: float, y: float, heading: float, length: float, width: float):
    c, s = math.cos(heading), math.sin(heading)
    corners = [(length / 2, width / 2), (-length / 2, width / 2)]
    corners += [(-length / 2, -width / 2), (length / 2, -width / 2)]
    return ShapelyPolygon([(x + c * u - s * v, y + s * u + c * v) for u, v in corners])


def _static_box(rng: np.random.Generator, oid: str) -> tuple[ObstacleSpec, object]:
    if rng.random() < 0.5:
        kind, length, width, height = "vehicle", rng.uniform(4.0, 5.0), rng.uniform(1.6, 2.0), 1.5
    else:
        kind, length, width = "equipment", rng.uniform(1.0, 2.5), rng.uniform(0.8, 1.5)
        height = 1.0
    heading = float(rng.uniform(0.0, math.pi))
    half_x = 0.5 * (abs(math.cos(heading)) * length + abs(math.sin(heading)) * width)
    x = float(rng.uniform(X_FREE_START + half_x, max(X_FREE_START + half_x, X_FREE_END - half_x)))
    y = float(rng.uniform(-2.0, 2.0))
    xml = (
        f'<box id="{oid}" kind="{kind}" x="{_f(x)}" y="{_f(y)}" '
        f'heading-deg="{math.degrees(heading):.1f}" length="{_f(length)}" '
        f'width="{_f(width)}" height="{height}"/>'
    )
    return ObstacleSpec(oid, "box", 0.0, xml), _box_geometry(x, y, heading, length, width)


def _static_circle(rng: np.random.Generator, oid: str) -> tuple[ObstacleSpec, object]:
    if rng.random() < 0.5:
        kind, radius, height = "equipment", float(rng.uniform(0.3, 0.6)), 1.0
    else:
        kind, radius, height = "cone", float(rng.uniform(0.15, 0.3)), 0.7
    x = float(rng.uniform(X_FREE_START + radius, X_FREE_END - radius))
    y = float(rng.uniform(-1.5, 1.5))
    xml = (
        f'<circle id="{oid}" kind="{kind}" x="{_f(x)}" y="{_f(y)}" radius="{_f(radius)}" '
        f'height="{height}"/>'
    )
    return ObstacleSpec(oid, "circle", 0.0, xml), Point(x, y).buffer(radius)


def _crossing(rng: np.random.Generator, oid: str) -> tuple[ObstacleSpec, object, object]:
    kind, shape, radius = _mover_body(rng)
    speed, fast = _speed(rng)
    x = float(rng.uniform(4.5, 10.0))
    side = 1.0 if rng.random() < 0.5 else -1.0
    y0, y1 = side * float(rng.uniform(3.0, 5.0)), -side * float(rng.uniform(3.0, 5.0))
    # the robot (cruise speed) is at x when the mover reaches the centre line, +- 1.5 s
    start_at = x / CRUISE + float(rng.uniform(-1.5, 1.5)) - abs(y0) / speed
    robot_x = min(CRUISE * start_at, x)
    trigger = math.hypot(x - robot_x, y0) if start_at > 0.0 else math.hypot(x, y0) + 0.5
    xml = (
        f'<path id="{oid}" kind="{kind}" {shape} speed="{speed:.3f}" '
        f'trigger-radius="{_f(trigger)}" loop="false">'
        f'<waypoint x="{_f(x)}" y="{_f(y0)}"/><waypoint x="{_f(x)}" y="{_f(y1)}"/></path>'
    )
    spec = ObstacleSpec(oid, "crossing", speed, xml, fast, static=False)
    return spec, Point(x, y0).buffer(radius), LineString([(x, y0), (x, y1)]).buffer(radius)


def _oncoming(rng: np.random.Generator, oid: str) -> tuple[ObstacleSpec, object, object]:
    kind, shape, radius = _mover_body(rng)
    speed, fast = _speed(rng)
    x0 = float(rng.uniform(8.0, X_FREE_END - radius))
    y0 = float(rng.uniform(-1.5, 1.5))
    x1, y1 = -3.0, y0 + float(rng.uniform(-1.0, 1.0))
    trigger = float(rng.uniform(5.0, 9.0))
    xml = (
        f'<path id="{oid}" kind="{kind}" {shape} speed="{speed:.3f}" '
        f'trigger-radius="{_f(trigger)}" loop="false">'
        f'<waypoint x="{_f(x0)}" y="{_f(y0)}"/><waypoint x="{_f(x1)}" y="{_f(y1)}"/></path>'
    )
    spec = ObstacleSpec(oid, "oncoming", speed, xml, fast, static=False)
    return spec, Point(x0, y0).buffer(radius), LineString([(x0, y0), (x1, y1)]).buffer(radius)


def _chaser(rng: np.random.Generator, oid: str) -> tuple[ObstacleSpec, object, None]:
    kind, shape, radius = _mover_body(rng)
    speed, fast = _speed(rng)
    x = float(rng.uniform(5.0, 10.0))
    y = (1.0 if rng.random() < 0.5 else -1.0) * float(rng.uniform(2.0, 4.0))
    trigger, pursuit = float(rng.uniform(4.0, 8.0)), float(rng.uniform(8.0, 20.0))
    xml = (
        f'<chaser id="{oid}" kind="{kind}" x="{_f(x)}" y="{_f(y)}" {shape} '
        f'speed="{speed:.3f}" trigger-radius="{_f(trigger)}" pursuit="{_f(pursuit)}"/>'
    )
    spec = ObstacleSpec(oid, "chaser", speed, xml, fast, static=False)
    return spec, Point(x, y).buffer(radius), None


def passable(statics: list[object]) -> bool:
    """Whether start and P are connected through the track with a >= GAP passage."""
    corridor = box(START[0] - 3.0, -TRACK_HALF_WIDTH, CHECKPOINT[0] + 3.0, TRACK_HALF_WIDTH)
    free = corridor.difference(unary_union(statics)) if statics else corridor
    eroded = free.buffer(-GAP / 2.0)
    start, goal = Point(START), Point(P)
    parts = getattr(eroded, "geoms", [eroded])
    return any(part.covers(start) and part.covers(goal) for part in parts)


def make_layout(seed: int, episode: int) -> Layout:
    """The obstacles of one episode (module docstring), redrawn until valid."""
    rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([seed, episode])))
    layout = Layout(episode, seed)
    for attempt in range(1000):
        n = int(rng.integers(1, 4))
        specs: list[ObstacleSpec] = []
        statics: list[object] = []
        movers: list[tuple[object, object]] = []
        for i in range(n):
            category = str(rng.choice(CATEGORIES, p=WEIGHTS))
            oid = f"{category}-{i + 1}"
            if category == "box":
                spec, geom = _static_box(rng, oid)
                statics.append(geom)
            elif category == "circle":
                spec, geom = _static_circle(rng, oid)
                statics.append(geom)
            else:
                make = {"crossing": _crossing, "oncoming": _oncoming, "chaser": _chaser}
                spec, start_geom, sweep = make[category](rng, oid)
                movers.append((start_geom, sweep))
            specs.append(spec)
        blocked = unary_union(statics) if statics else None
        ok = passable(statics)
        if ok and blocked is not None:
            for start_geom, sweep in movers:
                if start_geom.buffer(0.3).intersects(blocked) or (
                    sweep is not None and sweep.intersects(blocked)
                ):
                    ok = False
        if ok:
            layout.obstacles, layout.redraws = specs, attempt
            return layout
    raise RuntimeError(f"no valid layout for episode {episode} after 1000 draws")


def scenario_xml(layout: Layout | None, sim_seed: int) -> str:
    """The episode's scenario file (``layout`` None: the obstacle-free reference)."""
    body = "".join(o.xml for o in layout.obstacles) if layout is not None else ""
    name = f"campaign episode {layout.episode}" if layout is not None else "reference"
    return (
        '<?xml version="1.0" encoding="UTF-8"?>\n'
        f'<scenario xmlns="urn:walkaround:scenario:1" id="avoidance-campaign" '
        f'mission="../{MISSION_FILE}" seed="{sim_seed}" duration="{DURATION:.0f}">\n'
        f"  <description>Avoidance campaign: {name}.</description>\n"
        f'  <start x="{START[0]}" y="{START[1]}" heading-deg="0"/>\n'
        + (f"  <obstacles>{body}</obstacles>\n" if body else "")
        + "</scenario>\n"
    )


# -- running -------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Task:
    controller: str
    episode: int
    """-1: the obstacle-free reference."""
    seed: int


def sim_seed(seed: int, episode: int) -> int:
    """The simulator's seed of an episode (the reference, -1, gets ``seed * 100000``)."""
    return seed * 100_000 + episode + 1


def _avoider(controller: str) -> type[DwaAvoidance] | None:
    return DwaAvoidance if controller == "dwa" else None


def avoidance_controllers(run: DryRun, controller: str) -> set[str]:
    """Names of the controllers under an avoidance guard in the compiled tree."""
    options = CompileOptions(avoidance=True, avoider=_avoider(controller))
    root = compile_mission(run.scenario.mission, options).root
    return {
        node.children[1].name
        for node in root.iterate()
        if isinstance(node, GuardedBranch) and isinstance(node.children[0], AvoidanceTrigger)
    }


def _path_length(points: np.ndarray) -> float:
    return float(np.hypot(*np.diff(points, axis=0).T).sum()) if len(points) > 1 else 0.0


def episode_record(run: DryRun, layout: Layout | None, controller: str) -> dict[str, object]:
    """The figures of one episode (module docstring)."""
    report = metrics(run)
    samples = run.samples
    xy = np.array([(s.true.x, s.true.y) for s in samples]) if samples else np.zeros((0, 2))
    at_p = np.flatnonzero(np.hypot(*(xy - P).T) <= AT_P) if len(xy) else np.array([])
    leg_end = int(at_p[0]) if len(at_p) else None
    names = avoidance_controllers(run, controller)
    entries = [
        e
        for e in run.result.events
        if e.kind == "controller" and e.detail["to"] in names and e.detail["from"] not in names
    ]
    period = samples[1].t - samples[0].t if len(samples) > 1 else 0.1
    time_in: Counter[str] = Counter()
    for s in samples:
        if s.controller in names:
            time_in[s.controller] += period
    specs = {o.id: o for o in layout.obstacles} if layout is not None else {}
    collisions = []
    for c in run.robot.truth.collisions:
        spec = specs.get(c.other)
        before = [s for s in samples if s.t <= c.time]  # the robot just before the hit
        near = before[-1] if before else None
        collisions.append(
            {
                "t": round(c.time, 2),
                "with": c.other,
                "category": spec.category if spec else "other",
                "speed": round(spec.speed, 3) if spec else 0.0,
                "fast": bool(spec.fast) if spec else False,
                "robot_v": round(near.v, 3) if near else None,
                "controller": near.controller if near else None,
            }
        )
    return {
        "controller": controller,
        "episode": layout.episode if layout is not None else -1,
        "sim_seed": run.scenario.seed,
        "obstacles": [
            {"id": o.id, "category": o.category, "speed": round(o.speed, 3), "fast": o.fast}
            for o in (layout.obstacles if layout is not None else [])
        ],
        "fast_mover": layout.fast if layout is not None else False,
        "success": run.succeeded,
        "outcome": run.result.outcome,
        "reason": run.result.reason,
        "collisions": collisions,
        "collided": sorted({c["with"] for c in collisions}),
        "min_clearance": report["min_clearance"],
        "leg_length": round(_path_length(xy[: leg_end + 1]), 3) if leg_end is not None else None,
        "leg_time": round(samples[leg_end].t, 2) if leg_end is not None else None,
        "path_length": round(_path_length(xy), 3),
        "mission_time": report["simulated_s"],
        "engagements": len(entries),
        "avoidance_time": {k: round(v, 1) for k, v in sorted(time_in.items())},
        "estops": report["estops"],
        "safety_stops": len(report["safety_stops"]),
        "geofence_breaches": len(report["geofence_breaches"]),
        "wall_s": round(run.wall_time, 2),
    }


def run_task(task: Task) -> dict[str, object]:
    """Run one episode in a private copy of the track missions; never raises."""
    layout = make_layout(task.seed, task.episode) if task.episode >= 0 else None
    wall0 = time.perf_counter()
    try:
        with tempfile.TemporaryDirectory(prefix="walkaround-campaign-") as tmp:
            lib = Path(tmp) / "lib"
            shutil.copytree(MISSION_DIR, lib / "track", ignore=shutil.ignore_patterns("scenarios"))
            (lib / "track" / "scenarios").mkdir()
            path = lib / "track" / "scenarios" / "episode.xml"
            path.write_text(
                scenario_xml(layout, sim_seed(task.seed, task.episode)), encoding="utf-8"
            )
            scenario = load_scenario(path)
            run = dry_run(scenario, avoidance=True, avoider=_avoider(task.controller))
            return episode_record(run, layout, task.controller)
    except Exception as exc:  # a crashed episode is a result, not the end of the campaign
        return {
            "controller": task.controller,
            "episode": task.episode,
            "success": False,
            "outcome": "error",
            "reason": repr(exc),
            "traceback": traceback.format_exc(),
            "collisions": [],
            "collided": [],
            "fast_mover": layout.fast if layout is not None else False,
            "wall_s": round(time.perf_counter() - wall0, 2),
        }


# -- summary -------------------------------------------------------------------------------------
def _pct(values: list[float], q: float) -> float | None:
    return round(float(np.percentile(values, q)), 3) if values else None


def _mean(values: list[float]) -> float | None:
    return round(float(np.mean(values)), 3) if values else None


def _wilson(k: int, n: int) -> tuple[float, float] | None:
    """95 % Wilson score interval of a success rate, in percent (the campaign report's)."""
    interval = wilson(k, n)
    return None if interval is None else (round(100 * interval[0], 1), round(100 * interval[1], 1))


def summarise(rows: list[dict], reference: dict | None, wall: float) -> dict[str, object]:
    """Aggregates of one controller's episodes."""
    n = len(rows)
    ok = [r for r in rows if r["success"]]
    slow_layouts = [r for r in rows if not r["fast_mover"]]
    fast_layouts = [r for r in rows if r["fast_mover"]]
    hits = [c for r in rows for c in r["collisions"]]
    by_obstacle = {(r["episode"], w) for r in rows for w in r["collided"]}
    first_hit: dict[tuple[int, str], dict] = {}
    for r in rows:
        for c in r["collisions"]:
            first_hit.setdefault((r["episode"], c["with"]), c)
    slow_hits = [c for c in first_hit.values() if not c["fast"]]
    fast_hits = [c for c in first_hit.values() if c["fast"]]
    clearances = [r["min_clearance"] for r in rows if r.get("min_clearance") is not None]
    ref_leg = reference.get("leg_length") if reference else None
    ref_time = reference.get("mission_time") if reference else None
    path_ratio = [r["leg_length"] / ref_leg for r in rows if r.get("leg_length") and ref_leg]
    time_ratio = [
        r["mission_time"] / ref_time
        for r in rows
        if r.get("outcome") == "completed" and ref_time and r.get("mission_time")
    ]
    reasons = Counter(
        f"{r['outcome']}: {r['reason']}" + (" + collision" if r["collisions"] else "")
        for r in rows
        if not r["success"]
    )
    return {
        "episodes": n,
        "successes": len(ok),
        "success_rate": round(100 * len(ok) / n, 1) if n else None,
        "success_ci95": _wilson(len(ok), n),
        "success_rate_slow_layouts": (
            round(100 * sum(r["success"] for r in slow_layouts) / len(slow_layouts), 1)
            if slow_layouts
            else None
        ),
        "episodes_slow_layouts": len(slow_layouts),
        "success_rate_fast_layouts": (
            round(100 * sum(r["success"] for r in fast_layouts) / len(fast_layouts), 1)
            if fast_layouts
            else None
        ),
        "episodes_fast_layouts": len(fast_layouts),
        "outcomes": dict(Counter(r["outcome"] for r in rows)),
        "failure_reasons": dict(reasons.most_common()),
        "episodes_with_collision": sum(bool(r["collisions"]) for r in rows),
        "collisions": len(by_obstacle),
        "collision_contacts": len(hits),
        "collisions_slower_than_robot": len(slow_hits),
        "collisions_faster_than_robot": len(fast_hits),
        "collisions_by_category": dict(Counter(c["category"] for c in first_hit.values())),
        "collisions_robot_stopped": sum(
            1 for c in first_hit.values() if c["robot_v"] is not None and abs(c["robot_v"]) < 0.05
        ),
        "min_clearance": {
            "min": round(min(clearances), 3) if clearances else None,
            "p5": _pct(clearances, 5),
            "median": _pct(clearances, 50),
        },
        "path_ratio": {
            "n": len(path_ratio),
            "mean": _mean(path_ratio),
            "p95": _pct(path_ratio, 95),
        },
        "time_ratio": {
            "n": len(time_ratio),
            "mean": _mean(time_ratio),
            "p95": _pct(time_ratio, 95),
        },
        "engagements_mean": _mean([r["engagements"] for r in rows if "engagements" in r]),
        "estops": sum(r.get("estops", 0) for r in rows),
        "episodes_with_estop": sum(bool(r.get("estops")) for r in rows),
        "wall_s": round(wall, 1),
        "wall_s_per_episode": _mean([r["wall_s"] for r in rows]),
    }


def _cell(value: object) -> str:
    return "-" if value is None else str(value)


def markdown(summary: dict[str, dict], references: dict[str, dict]) -> str:
    """A table for BENCHMARKS.md: one column per controller."""
    names = list(summary)
    rows: list[tuple[str, list[object]]] = []

    def add(label: str, fn: object) -> None:
        rows.append((label, [fn(summary[c]) for c in names]))  # type: ignore[operator]

    add("episodes", lambda s: s["episodes"])
    add(
        "success rate (95 % CI)",
        lambda s: (
            f"{s['success_rate']} % ({s['success_ci95'][0]}-{s['success_ci95'][1]})"
            if s["success_ci95"]
            else None
        ),
    )
    add(
        "success, movers slower than the robot only",
        lambda s: f"{_cell(s['success_rate_slow_layouts'])} % (n={s['episodes_slow_layouts']})",
    )
    add(
        "success, with a mover faster than the robot",
        lambda s: f"{_cell(s['success_rate_fast_layouts'])} % (n={s['episodes_fast_layouts']})",
    )
    add("episodes with a collision", lambda s: s["episodes_with_collision"])
    add("collisions, obstacle slower than the robot", lambda s: s["collisions_slower_than_robot"])
    add("collisions, obstacle faster than the robot", lambda s: s["collisions_faster_than_robot"])
    add("collisions with the robot stopped", lambda s: s["collisions_robot_stopped"])
    add(
        "min clearance (m): min / p5 / median",
        lambda s: " / ".join(_cell(s["min_clearance"][k]) for k in ("min", "p5", "median")),
    )
    add(
        "leg path / obstacle-free leg: mean / p95",
        lambda s: f"{_cell(s['path_ratio']['mean'])} / {_cell(s['path_ratio']['p95'])}",
    )
    add(
        "mission time / obstacle-free time: mean / p95",
        lambda s: f"{_cell(s['time_ratio']['mean'])} / {_cell(s['time_ratio']['p95'])}",
    )
    add("avoidance engagements per episode (mean)", lambda s: s["engagements_mean"])
    add("e-stops (episodes)", lambda s: f"{s['estops']} ({s['episodes_with_estop']})")
    add("wall time per episode (s)", lambda s: s["wall_s_per_episode"])
    lines = [
        "| | " + " | ".join(names) + " |",
        "|---|" + "---|" * len(names),
        *(f"| {label} | " + " | ".join(_cell(v) for v in values) + " |" for label, values in rows),
    ]
    refs = ", ".join(
        f"{c}: leg {r.get('leg_length')} m, mission {r.get('mission_time')} s"
        for c, r in references.items()
    )
    lines.append("")
    lines.append(f"Obstacle-free reference: {refs}.")
    for c in names:
        reasons = summary[c]["failure_reasons"]
        if reasons:
            lines.append("")
            lines.append(f"{c} failures:")
            lines += [f"- {count} x {reason}" for reason, count in reasons.items()]
    return "\n".join(lines)


# -- main ----------------------------------------------------------------------------------------
def _progress(done: int, total: int, row: dict, wall0: float) -> str:
    tag = "ok  " if row["success"] else "FAIL"
    ep = "ref" if row["episode"] == -1 else f"{row['episode']:3d}"
    clearance = row.get("min_clearance")
    hit = f" hit {','.join(row['collided'])}" if row.get("collided") else ""
    return (
        f"[{done:4d}/{total}] {row['controller']:<6} ep {ep} {tag} {row['outcome']:<9} "
        f"clearance {_cell(clearance):>6} m  leg {_cell(row.get('leg_length')):>6} m  "
        f"t {_cell(row.get('mission_time')):>6} s  wall {row['wall_s']:5.1f} s "
        f"(total {time.perf_counter() - wall0:6.0f} s){hit}"
        + ("" if row["success"] else f"  [{row['reason']}]")
    )


def _iterate(tasks: list[Task], jobs: int) -> Iterator[dict]:
    if jobs <= 1:
        yield from map(run_task, tasks)
        return
    with multiprocessing.get_context("fork").Pool(jobs, maxtasksperchild=20) as pool:
        yield from pool.imap_unordered(run_task, tasks, chunksize=1)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=200)
    parser.add_argument("--controller", choices=("spiral", "dwa", "both"), default="both")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--first", type=int, default=0, help="index of the first episode")
    parser.add_argument(
        "--out", type=Path, default=REPO / "benchmarks" / "results" / "avoidance_campaign.json"
    )
    parser.add_argument(
        "--layouts", action="store_true", help="print the generated layouts and exit (no runs)"
    )
    args = parser.parse_args(argv)
    episodes = range(args.first, args.first + args.episodes)
    if args.layouts:
        for k in episodes:
            layout = make_layout(args.seed, k)
            print(f"episode {k} (redraws {layout.redraws}):")
            for o in layout.obstacles:
                print(f"  {o.category:<9} {o.speed:4.2f} m/s{' FAST' if o.fast else ''}  {o.xml}")
        return 0
    controllers = list(CONTROLLERS) if args.controller == "both" else [args.controller]
    tasks = [Task(c, -1, args.seed) for c in controllers]
    tasks += [Task(c, k, args.seed) for k in episodes for c in controllers]
    print(
        f"avoidance campaign: {args.episodes} episodes x {len(controllers)} controller(s) "
        f"+ references, seed {args.seed}, {args.jobs} job(s)",
        flush=True,
    )
    wall0 = time.perf_counter()
    rows: list[dict] = []
    for done, row in enumerate(_iterate(tasks, args.jobs), start=1):
        rows.append(row)
        print(_progress(done, len(tasks), row, wall0), flush=True)
    wall = time.perf_counter() - wall0
    references = {r["controller"]: r for r in rows if r["episode"] == -1}
    episodes_rows = sorted(
        (r for r in rows if r["episode"] != -1), key=lambda r: (r["controller"], r["episode"])
    )
    summary = {
        c: summarise(
            [r for r in episodes_rows if r["controller"] == c],
            references.get(c),
            sum(r["wall_s"] for r in rows if r["controller"] == c),
        )
        for c in controllers
    }
    result = {
        "campaign": {
            "mission": f"missions/track/{MISSION_FILE}",
            "seed": args.seed,
            "episodes": list(episodes)[:1] + list(episodes)[-1:],
            "controllers": controllers,
            "jobs": args.jobs,
            "duration_limit_s": DURATION,
            "fast_fraction": FAST_FRACTION,
            "categories": dict(zip(CATEGORIES, WEIGHTS, strict=True)),
            "wall_s": round(wall, 1),
        },
        "summary": summary,
        "references": references,
        "rows": episodes_rows,
        "layouts": [asdict(make_layout(args.seed, k)) for k in episodes],
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1) + "\n", encoding="utf-8")
    print()
    print(markdown(summary, references))
    print()
    print(f"wrote {args.out} ({wall:.0f} s wall)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
