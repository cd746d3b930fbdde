"""Executive speed: the tick at 50 Hz, and a whole dry-run against sim2d.

Usage:  OPENBLAS_NUM_THREADS=1 python benchmarks/bench_executive.py [--seconds 300]
            [--scenario clear-apron | --scenario PATH.xml] [--ticks-only]

(1) Tick: sensing + tree (obstacle avoidance included) + controllers + safety layer,
    without the simulator, over the first SECONDS (approach and inspection) of the A320
    pre-flight on SCENARIO (one of ``missions/a320/scenarios/``; default the clear apron):
    mean, p99, max. Measured twice: py_trees' logging at its default level (WARN), and at
    DEBUG with its output (py_trees prints it) captured in memory — py_trees formats its
    debug strings on every tick either way; the difference is what emitting them costs.
    The quiet run's ticks are also split by what drove: visual servoing (the controller
    events' "visual servoing (pbvs|ibvs)" intervals, issue 13) against everything else.
    Split again by the controller that drove (``by controller``). SCENARIO is the name of
    one of the A320's scenarios or the path of any scenario file (its mission runs).
(2) The whole A320 dry-run (executive + simulator + ground-truth judge): simulated
    seconds per wall-clock second.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import time
from pathlib import Path

import numpy as np
import py_trees

from executive.core.resources import missions_dir
from executive.dryrun import DryRun, dry_run
from sim2d.scenario import load_scenario


def scenario_path(name: str) -> Path:
    """One of the A320's shipped scenarios by name, or any scenario file by path."""
    if name.endswith(".xml"):
        return Path(name)
    return missions_dir() / "a320" / "scenarios" / f"{name}.xml"


def _summary(ms: np.ndarray) -> dict[str, float]:
    if ms.size == 0:
        return {"ticks": 0}
    return {
        "ticks": int(ms.size),
        "mean_ms": round(float(ms.mean()), 3),
        "p99_ms": round(float(np.percentile(ms, 99)), 3),
        "max_ms": round(float(ms.max()), 3),
    }


def controllers_per_tick(run: DryRun) -> np.ndarray:
    """The controller that drove the base at each of the run's ticks (its controller
    events' intervals; "none" before the first)."""
    stats = run.result.stats
    names = np.full(len(stats.durations), "none", dtype=object)
    for event in run.result.events:
        if event.kind == "controller":
            tick = min(names.size, round(event.t / stats.period))
            names[tick:] = str(event.detail.get("to", ""))
    return names


def servo_split(run: DryRun) -> dict[str, dict[str, float]]:
    """The run's tick durations while visual servoing drove the base, and otherwise."""
    ms = np.array(run.result.stats.durations) * 1e3
    names = controllers_per_tick(run)
    servoing = np.array([n.startswith("visual servoing") for n in names], dtype=bool)
    return {"servoing": _summary(ms[servoing]), "other": _summary(ms[~servoing])}


def controller_split(run: DryRun) -> dict[str, dict[str, float]]:
    """The run's tick durations by the controller that drove the base."""
    ms = np.array(run.result.stats.durations) * 1e3
    names = controllers_per_tick(run)
    return {str(name): _summary(ms[names == name]) for name in dict.fromkeys(names)}


def tick_figures(seconds: float, debug: bool, name: str) -> dict[str, object]:
    scenario = load_scenario(scenario_path(name))
    previous = py_trees.logging.level
    if debug:
        py_trees.logging.level = py_trees.logging.Level.DEBUG
    try:
        with contextlib.redirect_stdout(io.StringIO()):
            run = dry_run(scenario, max_time=seconds)
    finally:
        py_trees.logging.level = previous
    if debug:
        return run.result.stats.summary()
    split = {"by controller": controller_split(run)}
    return {**run.result.stats.summary(), **servo_split(run), **split}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=300.0)
    parser.add_argument(
        "--scenario", default="clear-apron", help="an A320 scenario's name, or a scenario file"
    )
    parser.add_argument(
        "--ticks-only", action="store_true", help="the tick figures only, not the whole dry-run"
    )
    args = parser.parse_args()
    quiet = tick_figures(args.seconds, debug=False, name=args.scenario)
    loud = tick_figures(args.seconds, debug=True, name=args.scenario)
    print(f"tick, py_trees logging quiet: {quiet}")
    print(f"tick, py_trees logging DEBUG: {loud}")
    if args.ticks_only:
        return
    scenario = load_scenario(scenario_path(args.scenario))
    t0 = time.perf_counter()
    run = dry_run(scenario)
    wall = time.perf_counter() - t0
    print(
        f"A320 dry-run: {run.result.outcome}, {run.robot.time:.0f} s simulated in {wall:.1f} s "
        f"= {run.robot.time / wall:.1f}x real time"
    )


if __name__ == "__main__":
    main()
