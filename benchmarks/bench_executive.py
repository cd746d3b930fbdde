"""Executive speed: the tick at 50 Hz, and a whole dry-run against sim2d.

Usage:  OPENBLAS_NUM_THREADS=1 python benchmarks/bench_executive.py [--seconds 300]

(1) Tick: sensing + tree + controllers + safety layer, without the simulator, over the
    first SECONDS of the A320 pre-flight on the clear apron (approach and inspection):
    mean, p99, max. Measured twice: py_trees' logging at its default level (WARN), and at
    DEBUG with its output (py_trees prints it) captured in memory — py_trees formats its
    debug strings on every tick either way; the difference is what emitting them costs.
(2) The whole A320 dry-run (executive + simulator + ground-truth judge): simulated
    seconds per wall-clock second.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import time

import py_trees

from executive.core.resources import missions_dir
from executive.dryrun import dry_run
from sim2d.scenario import load_scenario


def tick_figures(seconds: float, debug: bool) -> dict[str, float]:
    scenario = load_scenario(missions_dir() / "a320" / "scenarios" / "clear-apron.xml")
    previous = py_trees.logging.level
    if debug:
        py_trees.logging.level = py_trees.logging.Level.DEBUG
    try:
        with contextlib.redirect_stdout(io.StringIO()):
            run = dry_run(scenario, max_time=seconds)
    finally:
        py_trees.logging.level = previous
    return run.result.stats.summary()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=300.0)
    args = parser.parse_args()
    quiet = tick_figures(args.seconds, debug=False)
    loud = tick_figures(args.seconds, debug=True)
    print(f"tick, py_trees logging quiet: {quiet}")
    print(f"tick, py_trees logging DEBUG: {loud}")
    scenario = load_scenario(missions_dir() / "a320" / "scenarios" / "clear-apron.xml")
    t0 = time.perf_counter()
    run = dry_run(scenario)
    wall = time.perf_counter() - t0
    print(
        f"A320 dry-run: {run.result.outcome}, {run.robot.time:.0f} s simulated in {wall:.1f} s "
        f"= {run.robot.time / wall:.1f}x real time"
    )


if __name__ == "__main__":
    main()
