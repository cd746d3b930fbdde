"""Latency of the robot runtime over its real wires (issue 14).

Usage:  python benchmarks/bench_hil.py [--mission lab] [--rate 50] [--out /tmp/bench-hil]

Runs ``walkaround sim-robot`` and ``walkaround run`` as two processes on this machine
(CAN over python-can's udp_multicast, SCIP and NMEA over loopback TCP, detections over
ZeroMQ) through the whole lab mission (or the 40 m track run) and prints, from the run's
metrics.json:

* command latency: from a tick's read of the sensors to its command frames handed to the
  bus (the executive's whole tick: sensing, tree, safety layer, encoding);
* laser-return-to-command: from the arrival of the newest laser scan a tick used to that
  tick's command (what the thesis's obstacle reaction waits for);
* the CAN receive latency (bus time stamp to decoded) of the base's frames;
* tick timing against the 20 ms deadline at 50 Hz, and missed deadlines;

next to the thesis's figures for the Air-Cobot executive (seed 000: lasers processed at
20 Hz, control loop at 25-30 Hz; the motion command sent at up to 50 Hz).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from tests.hil import robot_file  # noqa: E402  (the tests' free-port robot file)

MISSIONS = {
    "lab": ("lab/visual-servoing.xml", "lab/scenarios/clear-apron.xml"),
    "track": ("track/straight-run.xml", "track/scenarios/straight-run-40m.xml"),
}
THESIS = {
    "laser processing period": "50 ms (20 Hz)",
    "control period": "33-40 ms (25-30 Hz)",
    "command rate on the CAN bus": "at most 50 Hz",
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mission", choices=sorted(MISSIONS), default="lab")
    parser.add_argument("--rate", type=float, default=50.0)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix="bench-hil-"))
    out.mkdir(parents=True, exist_ok=True)
    mission, scenario = (REPO / "missions" / p for p in MISSIONS[args.mission])
    robot = robot_file(out)
    walkaround = [sys.executable, "-m", "executive.cli"]
    sim = subprocess.Popen(
        [*walkaround, "sim-robot", str(scenario), "--robot", str(robot), "--out",
         str(out / "sim"), "--max-time", "900"],
        cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    wall0 = time.perf_counter()
    try:
        run = subprocess.run(
            [*walkaround, "run", str(mission), "--robot", str(robot), "--out", str(out / "run"),
             "--rate", f"{args.rate:g}", "--quiet"],
            cwd=REPO, capture_output=True, text=True, timeout=1200, check=False,
        )  # fmt: skip
    finally:
        sim.send_signal(2)
        sim.wait(timeout=30)
    wall = time.perf_counter() - wall0
    metrics = json.loads((out / "run" / "metrics.json").read_text())
    link, ticks = metrics["link"], metrics["tick_timing"]
    summary = run.stdout.strip().splitlines()[-1]
    print(f"walkaround run {args.mission} at {args.rate:g} Hz against sim-robot: {summary}")
    print(f"outcome {metrics['outcome']}, {wall:.0f} s wall")
    print()
    print("| measure | p50 | p99 | max | samples |")
    print("|---|---|---|---|---|")
    rows = {
        "command latency: tick read -> frames on the bus (ms)": link["command_latency_ms"],
        "laser return -> command (ms)": link["scan_to_command_ms"],
        "CAN receive latency, base -> executive (ms)": link["can"]["receive_latency_ms"],
    }
    for name, row in rows.items():
        print(f"| {name} | {row['p50']} | {row['p99']} | {row['max']} | {row['count']} |")
    print(f"| tick (sensing + tree + safety) (ms) | mean {ticks['mean_ms']} | {ticks['p99_ms']} "
          f"| {ticks['max_ms']} | {ticks['ticks']} |")  # fmt: skip
    print()
    print(f"deadline {ticks['deadline_ms']} ms: {ticks['deadline_misses']} missed")
    lasers = link["lasers"]
    for lid, stats in lasers.items():
        print(f"laser {lid}: {stats['scans']} scans, period {stats['interval_mean'] * 1e3:.1f} ms "
              f"(jitter {stats['interval_jitter'] * 1e3:.1f} ms)")  # fmt: skip
    print()
    print("reference (seed 000, the Air-Cobot executive):")
    for name, value in THESIS.items():
        print(f"  {name}: {value}")


if __name__ == "__main__":
    main()
