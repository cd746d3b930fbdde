"""Laser obstacle perception: merge + clean + cluster + classify + track, per scan pair.

Usage:  OPENBLAS_NUM_THREADS=1 python benchmarks/bench_perception.py [SCENARIO]
            [--warmup 40] [--seconds 120]

Drives sim2d's robot along the mission's route in the scenario (default: the A320 busy
apron: the aircraft, parked vehicles, cones, crossing walkers and a loitering group) with
the simple route follower of ``bench_sim.py``, skips the first ``--warmup`` seconds (the
empty approach from the charging station), then records every pair of scans (front and
rear Hokuyo, 2 x 1081 beams, 40 Hz) for ``--seconds`` together with the robot's true pose.
The recorded pairs are then run, in order, through ``ScanClusterer.detect`` (thesis
Algorithm 2.1: merge both scans in the robot frame, remove isolated points, cluster with
the adaptive breakpoint detector, RANSAC lines and circles) and ``ObstacleTracker.update``
(constant-velocity Kalman filters, gated global nearest neighbour, danger levels), with
the garbage collector off. Prints the time per pair (mean, p50, p99) of each part and of
the whole, and what the scene holds (returns, clusters, confirmed tracks per pair).
"""

from __future__ import annotations

import argparse
import gc
import statistics
import time
from pathlib import Path

import numpy as np
from bench_sim import CONTROL_HZ, RouteFollower

from behaviours.laws.laser_clusters import KIND_NAMES, ScanClusterer
from behaviours.laws.tracking import DangerParams, ObstacleTracker
from executive.core.frames import Pose2
from executive.core.records import LaserScan
from executive.core.resources import missions_dir
from sim2d.robot import SimRobot
from sim2d.scenario import load_scenario


def record(
    scenario: Path, warmup: float, seconds: float
) -> tuple[SimRobot, list[tuple[list[LaserScan], Pose2, tuple[float, float]]]]:
    """Every new pair of scans after ``warmup`` s, with the true pose and the command."""
    robot = SimRobot(load_scenario(scenario))
    follower = RouteFollower(robot)
    pairs = []
    last = None
    for _ in range(round((warmup + seconds) * CONTROL_HZ)):
        command = follower.command(robot)
        robot.send(command)
        robot.advance(1.0 / CONTROL_HZ)
        frame = robot.read()
        stamps = tuple(s.stamp for s in frame.scans.values())
        if robot.time > warmup and stamps != last:
            last = stamps
            pairs.append(
                (list(frame.scans.values()), robot.truth.robot, (command.v, command.omega))
            )
    return robot, pairs


def summary(values: list[float]) -> tuple[float, float, float]:
    ordered = sorted(values)
    return (
        statistics.fmean(values),
        statistics.median(values),
        ordered[min(len(ordered) - 1, int(0.99 * len(ordered)))],
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    default = missions_dir() / "a320" / "scenarios" / "busy-apron.xml"
    parser.add_argument("scenario", nargs="?", type=Path, default=default)
    parser.add_argument("--warmup", type=float, default=40.0)
    parser.add_argument("--seconds", type=float, default=120.0)
    args = parser.parse_args()

    robot, pairs = record(args.scenario, args.warmup, args.seconds)
    platform = robot.scenario.mission.platform
    mounts = {
        lid: Pose2(spec.mount[0], spec.mount[1], spec.mount_yaw)
        for lid, spec in platform.lasers.items()
    }
    ids = list(robot.lasers)
    clusterer = ScanClusterer(platform.length, platform.width)
    tracker = ObstacleTracker(DangerParams(platform.length, platform.width))

    t_detect, t_track, t_total = [], [], []
    returns, clusters, tracks = [], [], []
    kinds = np.zeros(len(KIND_NAMES))
    gc.disable()
    try:
        for scans, pose, velocity in pairs:
            with_mounts = [(scan, mounts[lid]) for lid, scan in zip(ids, scans, strict=True)]
            t0 = time.perf_counter_ns()
            found = clusterer.detect(with_mounts)
            t1 = time.perf_counter_ns()
            confirmed = tracker.update(found, pose, velocity)
            t2 = time.perf_counter_ns()
            t_detect.append((t1 - t0) * 1e-6)
            t_track.append((t2 - t1) * 1e-6)
            t_total.append((t2 - t0) * 1e-6)
            returns.append(found.returns)
            clusters.append(len(found))
            tracks.append(len(confirmed))
            kinds += np.bincount(found.kind, minlength=len(KIND_NAMES))
    finally:
        gc.enable()

    n = len(pairs)
    beams = " + ".join(str(len(s.ranges)) for s in pairs[0][0])
    print(
        f"scenario: {args.scenario.name}; {n} scan pairs ({beams} beams) over "
        f"{args.seconds:g} s of driving after {args.warmup:g} s"
    )
    print(
        f"per pair: {statistics.fmean(returns):.0f} returns (max {max(returns)}), "
        f"{statistics.fmean(clusters):.1f} clusters (max {max(clusters)}: "
        + ", ".join(f"{k} {c / n:.1f}" for k, c in zip(KIND_NAMES, kinds, strict=True))
        + f"), {statistics.fmean(tracks):.1f} confirmed tracks (max {max(tracks)})"
    )
    print()
    print(f"| {'part':<44} | {'mean':>8} | {'p50':>8} | {'p99':>8} |")
    print(f"|{'-' * 46}|{'-' * 10}|{'-' * 10}|{'-' * 10}|")
    for name, times in (
        ("detect: merge, clean, cluster, classify", t_detect),
        ("track: predict, associate, update, danger", t_track),
        ("whole pipeline", t_total),
    ):
        mean, p50, p99 = summary(times)
        print(f"| {name:<44} | {mean:5.2f} ms | {p50:5.2f} ms | {p99:5.2f} ms |")


if __name__ == "__main__":
    main()
