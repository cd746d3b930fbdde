"""sim2d speed: simulated seconds per wall-clock second for a whole world.

Usage:  OPENBLAS_NUM_THREADS=1 python benchmarks/bench_sim.py [SCENARIO] [--seconds 120]

Runs the scenario (default: the A320 busy apron: parked vehicles, crossing pedestrians,
a loitering group) with every sensor at its platform rate — both lasers at 40 Hz, five
cameras at 25 Hz, wheels 50 Hz, IMU 100 Hz, GPS 5 Hz — and physics at 100 Hz, driven at
50 Hz by a trivial controller that follows the mission's route point to point (no
executive). Prints the speed-up and where the time goes.
"""

from __future__ import annotations

import argparse
import cProfile
import math
import pstats
import time
from pathlib import Path

from executive.core.frames import wrap_angle
from executive.core.records import VelocityCommand
from executive.core.resources import missions_dir
from sim2d.robot import SimRobot
from sim2d.scenario import load_scenario
from sim2d.view import route_points

CONTROL_HZ = 50.0


class RouteFollower:
    """Turn towards the next route point, drive when roughly aligned."""

    def __init__(self, robot: SimRobot) -> None:
        self.points = [(x, y) for _, x, y in route_points(robot.scenario.mission)][1:]
        self.i = 0

    def command(self, robot: SimRobot) -> VelocityCommand:
        pose = robot.world.robot_pose  # a benchmark of the simulator, not of localisation
        if self.i >= len(self.points):
            return VelocityCommand()
        tx, ty = self.points[self.i]
        if math.hypot(tx - pose.x, ty - pose.y) < 0.3:
            self.i += 1
            return VelocityCommand()
        error = wrap_angle(math.atan2(ty - pose.y, tx - pose.x) - pose.theta)
        v = 1.0 if abs(error) < 0.3 else 0.0
        return VelocityCommand(v, max(-0.8, min(0.8, 1.5 * error)))


def run(scenario_path: Path, seconds: float) -> tuple[float, SimRobot]:
    robot = SimRobot(load_scenario(scenario_path))
    follower = RouteFollower(robot)
    steps = round(seconds * CONTROL_HZ)
    t0 = time.perf_counter()
    for _ in range(steps):
        robot.read()
        robot.send(follower.command(robot))
        robot.advance(1.0 / CONTROL_HZ)
    return time.perf_counter() - t0, robot


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    default = missions_dir() / "a320" / "scenarios" / "busy-apron.xml"
    parser.add_argument("scenario", nargs="?", type=Path, default=default)
    parser.add_argument("--seconds", type=float, default=120.0)
    parser.add_argument("--profile", action="store_true", help="print the top functions")
    args = parser.parse_args()

    wall, robot = run(args.scenario, args.seconds)
    counts = {lid: s.count for lid, (_, s) in robot.lasers.items()}
    cams = sum(s.count for _, s in robot.rigs)
    print(f"scenario: {args.scenario.name}, {args.seconds:.0f} s simulated in {wall:.2f} s")
    print(f"speed-up: {args.seconds / wall:.1f}x real time")
    print(f"per simulated second: {wall / args.seconds * 1e3:.2f} ms wall")
    scans = f"laser scans: {counts}, camera frames: {cams}"
    print(f"{scans}, collisions: {len(robot.truth.collisions)}")
    if args.profile:
        profiler = cProfile.Profile()
        profiler.enable()
        run(args.scenario, min(args.seconds, 30.0))
        profiler.disable()
        pstats.Stats(profiler).sort_stats("tottime").print_stats(15)


if __name__ == "__main__":
    main()
