"""Load + validate the shipped A320 mission: parse, XSD, model, semantic checks.

Usage:  OPENBLAS_NUM_THREADS=1 python benchmarks/bench_load.py [--repeat N] [MISSION]

Prints the first (cold: includes compiling both XSDs) and the warm figures: the warm
one is what `walkaround validate` costs per file in a session and what the executive
pays when it starts a mission.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

from executive.core import xmlsafe
from executive.core.loader import load_mission
from executive.core.resources import missions_dir


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "mission", nargs="?", type=Path, default=missions_dir() / "a320" / "preflight.xml"
    )
    parser.add_argument("--repeat", type=int, default=50)
    args = parser.parse_args()

    xmlsafe.load_schema.cache_clear()
    t0 = time.perf_counter()
    mission = load_mission(args.mission)
    cold = time.perf_counter() - t0

    times = []
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        load_mission(args.mission)
        times.append(time.perf_counter() - t0)
    times_ms = sorted(t * 1e3 for t in times)
    p95 = times_ms[int(0.95 * (len(times_ms) - 1))]
    print(
        f"mission: {args.mission} ({len(mission.checkpoints)} checkpoints, "
        f"{len(mission.aircraft.features)} features)"
    )
    print(f"cold load (compiles the XSDs): {cold * 1e3:.1f} ms")
    print(
        f"warm load x{args.repeat}: median {statistics.median(times_ms):.1f} ms, "
        f"mean {statistics.fmean(times_ms):.1f} ms, p95 {p95:.1f} ms, min {times_ms[0]:.1f} ms"
    )


if __name__ == "__main__":
    main()
