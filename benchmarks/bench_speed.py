"""Speed of this code against a baseline revision, side by side in one run (issue 16).

Usage:
    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_speed.py --baseline REV
        [--only dry-run,tick,sim,leg,a320] [--leg-episodes 10] [--a320-episodes 1]
        [--json benchmarks/results/speed.json]

The baseline is checked out with ``git worktree`` into a temporary folder and every
figure is measured there and in this working tree by the same code (this script, run in
a child process whose ``PYTHONPATH`` is the tree), alternating baseline and current for
each figure so that both see the same load on a shared machine. Each measurement is one
process on one core (``OPENBLAS_NUM_THREADS=1``); times are wall clock *and* the
process's CPU time, the steadier of the two on a noisy machine.

Figures:

* ``dry-run``: the whole A320 pre-flight on the clear apron, as the README's main job
  runs it (visual servoing, obstacle avoidance, registration, full sensing): simulated
  seconds per wall-clock second, and the outcome.
* ``tick``: the executive's tick with full sensing over the first 300 s of the A320 on
  the busy apron (``bench_executive``'s figure): mean, p99, max in ms.
* ``sim``: the simulator alone on the busy apron, 120 s, driven along the mission's route
  by ``bench_sim``'s route follower: times real time.
* ``leg`` / ``a320``: campaign throughput, episodes per hour per core: episodes 0..N-1 of
  the shipped avoidance-leg campaign and of the A320 busy-apron campaign, each run in the
  measuring process as a campaign worker runs it (:func:`episode_row`).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
FIGURES = ("dry-run", "tick", "sim", "leg", "a320")


# -- measurements (run in the child process, against whichever tree is on the path) ----
def _clock() -> tuple[float, float]:
    return time.perf_counter(), time.process_time()


def _since(start: tuple[float, float]) -> dict[str, float]:
    wall, cpu = _clock()
    return {"wall_s": round(wall - start[0], 2), "cpu_s": round(cpu - start[1], 2)}


def measure_dry_run() -> dict[str, object]:
    from executive.core.resources import missions_dir
    from executive.dryrun import dry_run
    from sim2d.scenario import load_scenario

    scenario = load_scenario(missions_dir() / "a320" / "scenarios" / "clear-apron.xml")
    start = _clock()
    run = dry_run(scenario)
    spent = _since(start)
    simulated = float(run.robot.time)
    return {
        "outcome": run.result.outcome,
        "simulated_s": round(simulated, 1),
        **spent,
        "x_real_time": round(simulated / spent["wall_s"], 2),
        "x_real_time_cpu": round(simulated / spent["cpu_s"], 2),
    }


def measure_tick(seconds: float = 300.0) -> dict[str, object]:
    import numpy as np

    from executive.core.resources import missions_dir
    from executive.dryrun import dry_run
    from sim2d.scenario import load_scenario

    scenario = load_scenario(missions_dir() / "a320" / "scenarios" / "busy-apron.xml")
    run = dry_run(scenario, max_time=seconds)
    ms = np.asarray(run.result.stats.durations) * 1e3
    return {
        "ticks": int(ms.size),
        "mean_ms": round(float(ms.mean()), 3),
        "p99_ms": round(float(np.percentile(ms, 99)), 3),
        "max_ms": round(float(ms.max()), 3),
    }


def measure_sim(seconds: float = 120.0) -> dict[str, object]:
    sys.path.insert(0, str(Path.cwd() / "benchmarks"))
    from bench_sim import run  # the tree's own route follower

    from executive.core.resources import missions_dir

    start = _clock()
    wall, robot = run(missions_dir() / "a320" / "scenarios" / "busy-apron.xml", seconds)
    spent = _since(start)
    return {
        "simulated_s": seconds,
        "wall_s": round(wall, 2),
        "cpu_s": spent["cpu_s"],
        "x_real_time": round(seconds / wall, 1),
        "collisions": len(robot.truth.collisions),
    }


def measure_campaign(name: str, episodes: int) -> dict[str, object]:
    from executive.campaign.runner import episode_row
    from executive.campaign.spec import load_campaign
    from executive.core.resources import missions_dir

    campaign = load_campaign(missions_dir() / "campaigns" / f"{name}.xml")
    start = _clock()
    rows = [episode_row(campaign, k) for k in range(episodes)]
    spent = _since(start)
    ok = sum(1 for row in rows if row.get("succeeded"))
    return {
        "episodes": episodes,
        "succeeded": ok,
        **spent,
        "episodes_per_hour_per_core": round(3600.0 * episodes / spent["wall_s"], 1),
        "episodes_per_cpu_hour": round(3600.0 * episodes / spent["cpu_s"], 1),
    }


def measure(figure: str, leg_episodes: int, a320_episodes: int) -> dict[str, object]:
    if figure == "dry-run":
        return measure_dry_run()
    if figure == "tick":
        return measure_tick()
    if figure == "sim":
        return measure_sim()
    if figure == "leg":
        return measure_campaign("avoidance-leg", leg_episodes)
    if figure == "a320":
        return measure_campaign("a320-busy-apron", a320_episodes)
    raise ValueError(figure)


# -- the driver -----------------------------------------------------------------------
def _in_tree(tree: Path, figure: str, args: argparse.Namespace) -> dict[str, object]:
    env = {**os.environ, "PYTHONPATH": str(tree), "OPENBLAS_NUM_THREADS": "1"}
    command = [
        sys.executable,
        str(Path(__file__).resolve()),
        "--measure",
        figure,
        "--leg-episodes",
        str(args.leg_episodes),
        "--a320-episodes",
        str(args.a320_episodes),
    ]
    done = subprocess.run(command, cwd=tree, env=env, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"{figure} in {tree} failed:\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def _ratio(before: dict[str, object], after: dict[str, object], key: str) -> float | None:
    a, b = before.get(key), after.get(key)
    if not isinstance(a, int | float) or not isinstance(b, int | float) or not b:
        return None
    return round(float(a) / float(b), 2)


def compare(args: argparse.Namespace) -> dict[str, object]:
    figures = [f for f in args.only.split(",") if f]
    unknown = sorted(set(figures) - set(FIGURES))
    if unknown:
        raise SystemExit(f"--only: unknown figure(s) {unknown}; known: {', '.join(FIGURES)}")
    revision = subprocess.run(
        ["git", "rev-parse", "--short", args.baseline],
        cwd=REPO,
        check=True,
        capture_output=True,
        text=True,
    ).stdout.strip()
    results: dict[str, object] = {"baseline": revision, "figures": {}}
    with tempfile.TemporaryDirectory(prefix="walkaround-baseline-") as tmp:
        tree = Path(tmp) / "tree"
        subprocess.run(
            ["git", "worktree", "add", "--detach", "-q", str(tree), revision],
            cwd=REPO,
            check=True,
        )
        try:
            for figure in figures:
                before = _in_tree(tree, figure, args)
                after = _in_tree(REPO, figure, args)
                speed = {
                    key: _ratio(before, after, key)
                    for key in ("wall_s", "cpu_s", "mean_ms", "p99_ms")
                    if key in before
                }
                row = {"baseline": before, "current": after, "faster_by": speed}
                results["figures"][figure] = row  # type: ignore[index]
                print(f"{figure}: {json.dumps(row)}", flush=True)
        finally:
            subprocess.run(
                ["git", "worktree", "remove", "--force", str(tree)], cwd=REPO, check=False
            )
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", default="HEAD", help="git revision to compare against")
    parser.add_argument("--only", default=",".join(FIGURES), help="comma-separated figures")
    parser.add_argument("--leg-episodes", type=int, default=10)
    parser.add_argument("--a320-episodes", type=int, default=1)
    parser.add_argument("--json", type=Path, help="also write the results here")
    parser.add_argument("--measure", choices=FIGURES, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.measure:
        print(json.dumps(measure(args.measure, args.leg_episodes, args.a320_episodes)))
        return
    results = compare(args)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(results, indent=2) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
