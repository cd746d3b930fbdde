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

Then the tracking metrics against sim2d's ground truth, as the dry-run judges them
(``executive.dryrun``: a track within ``TRACK_MATCH_RADIUS`` of a mover's true position is
that mover's; errors on tracks at least ``TRACK_SETTLED_AGE`` old): the movers' position
and velocity errors, and the speed of every other confirmed track (static structure:
the aircraft, parked vehicles, cones, walls), which should be zero.
"""

from __future__ import annotations

import argparse
import gc
import math
import statistics
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from bench_sim import CONTROL_HZ, RouteFollower

from behaviours.laws.blind_spots import BlindSpotMemory
from behaviours.laws.laser_clusters import KIND_NAMES, ScanClusterer
from behaviours.laws.obstacles import MOVER_SPEED, closest_obstacle, is_mover, scan_to_robot
from behaviours.laws.tracking import DangerParams, ObstacleTracker
from executive.core.frames import Pose2
from executive.core.records import LaserScan, TrackedObstacle
from executive.core.resources import missions_dir
from executive.dryrun import TRACK_MATCH_RADIUS
from executive.report import TRACK_SETTLED_AGE
from sim2d.robot import SimRobot
from sim2d.scenario import load_scenario

Mover = tuple[float, float, float, float]
"""A mover's true position and velocity in the airport frame: (x, y, vx, vy)."""
Pair = tuple[list[LaserScan], Pose2, tuple[float, float], list[Mover]]


def record(scenario: Path, warmup: float, seconds: float) -> tuple[SimRobot, list[Pair]]:
    """Every new pair of scans after ``warmup`` s, with the true pose, the command and the
    movers' true states."""
    robot = SimRobot(load_scenario(scenario))
    follower = RouteFollower(robot)
    physics = robot.scenario.physics_rate
    control = round(physics / CONTROL_HZ)
    pairs = []
    last = None
    command = follower.command(robot)
    for step in range(round((warmup + seconds) * physics)):
        if step % control == 0:
            command = follower.command(robot)
            robot.send(command)
        # one physics step at a time: the scans are taken at its end, so that the true
        # pose read now is the scans' (a pose even 10 ms off moves every obstacle)
        robot.advance(1.0 / physics)
        frame = robot.read()
        stamps = tuple(s.stamp for s in frame.scans.values())
        if robot.time > warmup and stamps != last:
            last = stamps
            movers = [(m.agent.x, m.agent.y, m.agent.vx, m.agent.vy) for m in robot.world.moving]
            pairs.append(
                (
                    list(frame.scans.values()),
                    robot.truth.robot,
                    (command.v, command.omega),
                    movers,
                )
            )
    return robot, pairs


def summary(values: list[float]) -> tuple[float, float, float]:
    ordered = sorted(values)
    return (
        statistics.fmean(values),
        statistics.median(values),
        ordered[min(len(ordered) - 1, int(0.99 * len(ordered)))],
    )


class TrackJudge:
    """Confirmed tracks against the ground truth (the tracker's world frame is the airport
    frame here: it is given the true pose)."""

    def __init__(self) -> None:
        self.position_error: list[float] = []
        self.velocity_error: list[float] = []
        self.static_speed: list[float] = []
        self.static_moving = 0
        """Samples of static structure that count as moving (:func:`is_mover`): what
        makes avoidance dodge a wall."""

    def judge(self, tracks: Sequence[TrackedObstacle], pose: Pose2, movers: list[Mover]) -> None:
        rot = pose.rotation()
        for track in tracks:
            x, y = pose.apply(np.array(track.position))
            vx, vy = rot @ np.array(track.velocity)
            d = [math.hypot(mx - x, my - y) for mx, my, _, _ in movers]
            k = int(np.argmin(d)) if d else -1
            if k >= 0 and d[k] <= TRACK_MATCH_RADIUS:
                if track.age >= TRACK_SETTLED_AGE:
                    _, _, mvx, mvy = movers[k]
                    self.position_error.append(d[k])
                    self.velocity_error.append(math.hypot(vx - mvx, vy - mvy))
            else:
                self.static_speed.append(math.hypot(vx, vy))
                self.static_moving += is_mover(track)

    def lines(self) -> list[str]:
        static = len(self.static_speed)
        share = self.static_moving / static if static else 0.0
        tail = [
            "",
            f"static structure counted as moving (vouched speed >= {MOVER_SPEED} m/s): "
            f"{self.static_moving} of {static} samples ({100 * share:.2f} %), fastest track "
            f"{max(self.static_speed, default=0.0):.3f} m/s",
        ]
        out = [f"| {'tracking':<44} | {'samples':>8} | {'mean':>8} | {'p50':>8} | {'p99':>8} |"]
        out.append(f"|{'-' * 46}|{'-' * 10}|{'-' * 10}|{'-' * 10}|{'-' * 10}|")
        for name, values, unit in (
            ("movers: position error", self.position_error, "m"),
            ("movers: velocity error", self.velocity_error, "m/s"),
            ("static structure: track speed", self.static_speed, "m/s"),
        ):
            if not values:
                out.append(f"| {name:<44} | {0:>8} | {'-':>8} | {'-':>8} | {'-':>8} |")
                continue
            mean, p50, p99 = summary(values)
            out.append(
                f"| {name + ' (' + unit + ')':<44} | {len(values):>8} | {mean:8.3f} | "
                f"{p50:8.3f} | {p99:8.3f} |"
            )
        return out + tail


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

    memory = BlindSpotMemory(platform.lasers.values(), platform.length, platform.width)
    t_detect, t_track, t_total, t_memory = [], [], [], []
    returns, clusters, tracks, hidden = [], [], [], 0
    kinds = np.zeros(len(KIND_NAMES))
    gc.disable()
    try:
        for scans, pose, velocity, _ in pairs:
            with_mounts = [(scan, mounts[lid]) for lid, scan in zip(ids, scans, strict=True)]
            t0 = time.perf_counter_ns()
            hints = tracker.hints(max(scan.stamp for scan in scans), pose)
            found = clusterer.detect(with_mounts, None, hints)
            t1 = time.perf_counter_ns()
            confirmed = tracker.update(found, pose, velocity)
            t2 = time.perf_counter_ns()
            points = np.vstack(
                [
                    scan_to_robot(s.ranges, s.angle_min, s.angle_increment, s.range_max, m)
                    for s, m in with_mounts
                ]
            )
            r_c, _ = closest_obstacle(points, platform.length, platform.width)
            t3 = time.perf_counter_ns()
            hidden += len(memory.update(points, pose, r_c)) > 0
            t_memory.append((time.perf_counter_ns() - t3) * 1e-6)
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
    print(f"returns hidden in a blind spot beside the body in {hidden} of {n} pairs")
    print()
    print(f"| {'part':<44} | {'mean':>8} | {'p50':>8} | {'p99':>8} |")
    print(f"|{'-' * 46}|{'-' * 10}|{'-' * 10}|{'-' * 10}|")
    for name, times in (
        ("detect: merge, clean, segment, split, fit", t_detect),
        ("track: predict, associate, update, danger", t_track),
        ("whole pipeline", t_total),
        ("blind spots: remember near returns", t_memory),
    ):
        mean, p50, p99 = summary(times)
        print(f"| {name:<44} | {mean:5.2f} ms | {p50:5.2f} ms | {p99:5.2f} ms |")

    # the tracking metrics, on a second pass (not timed)
    judge = TrackJudge()
    clusterer = ScanClusterer(platform.length, platform.width)
    tracker = ObstacleTracker(DangerParams(platform.length, platform.width))
    for scans, pose, velocity, movers in pairs:
        with_mounts = [(scan, mounts[lid]) for lid, scan in zip(ids, scans, strict=True)]
        hints = tracker.hints(max(scan.stamp for scan in scans), pose)
        found = clusterer.detect(with_mounts, None, hints)
        judge.judge(tracker.update(found, pose, velocity), pose, movers)
    print()
    print("\n".join(judge.lines()))


if __name__ == "__main__":
    main()
