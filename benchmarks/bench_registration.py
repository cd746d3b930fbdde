"""Aircraft registration: global step (characteristic pairs + MSAC + ICP) and ICP alone.

Usage:  OPENBLAS_NUM_THREADS=1 python benchmarks/bench_registration.py [--repeat N] [--seed S]

The A320 clear-apron scenario, re-staged (``dataclasses.replace``) with each of four
parking offsets (up to 1.5 m and 10 deg, both signs) and each of eight robot spots
around the aircraft (by the nose gear, beside and between the main gear, between gear
and engine, ahead of and behind the engines), with four people (r 0.3 m) by the gear and
a 6 m x 2.4 m vehicle behind the left main gear. One frame of both lasers (default
sim2d noise: 1 cm range) per case.

* global: :func:`register` with the sight lines (free-space test), from the robot's
  true pose in A taken through the *nominal* parking pose (the prior is off by the
  parking offset), 1-sigma 0.6 m + 4 deg x the distance from the nose and 4 deg;
* ICP: :func:`refine` from the true pose in F moved by (10 cm, -5 cm, 1 deg), as a
  tracking step after a short odometry drift; alone, and with the contradiction count
  of the sight lines.

Each case is timed ``--repeat`` times (garbage collector off). Prints the time per
registration (mean, p50, max), the errors against sim2d's ground truth
(``scenario.true_placement().pose_to_aircraft(true pose)``) and the model build time.
"""

from __future__ import annotations

import argparse
import gc
import math
import statistics
import time
from dataclasses import replace

import numpy as np

from behaviours.laws.registration import (
    FootprintModel,
    SightLines,
    points_from_scans,
    refine,
    register,
)
from executive.core.frames import Pose2, wrap_angle
from executive.core.resources import missions_dir
from sim2d.robot import SimRobot
from sim2d.scenario import Body, ObstacleKind, Scenario, StaticObstacle, load_scenario

OFFSETS = [(1.5, 0.0, 10.0), (-1.0, -1.1, -10.0), (0.3, 1.45, -6.0), (-1.5, 0.3, 8.0)]
SPOTS = [  # robot in F: x, y (m), heading (deg)
    (3.2, -2.2, 20.0),  # by the nose gear
    (19.5, 7.5, 215.0),  # outside and behind the left main gear
    (16.0, 3.4, 300.0),  # between the left gear and engine
    (24.0, -2.0, 160.0),  # behind the main gear
    (17.7, -6.0, 90.0),  # outside the right main gear
    (9.0, 5.5, 10.0),  # ahead of the left engine
    (9.0, -3.0, -30.0),  # ahead of the right engine, inboard
    (13.0, 0.0, 180.0),  # under the fuselage, between the engines
]
PEOPLE = [(6.3, 1.2), (16.4, 5.3), (19.2, 2.6), (18.9, -5.2)]
VEHICLE = (22.0, 5.5, 15.0, 6.0, 2.4)  # x, y, heading (deg) in F, length, width
PRIOR_SIGMA = (0.6, math.radians(4.0))
TRACK_START = Pose2(0.10, -0.05, math.radians(1.0))


def staged(base: Scenario, offset: tuple, spot: tuple, seed: int) -> Scenario:
    """``base`` with the aircraft offset, the robot at ``spot`` (in the true F) and the
    obstacles by the gear (those within 1.5 m of the robot left out)."""
    dx, dy, dh = offset
    scenario = replace(base, parking_offset=Pose2(dx, dy, math.radians(dh)), seed=seed)
    placement = scenario.true_placement()
    x, y, h = spot
    obstacles = []
    for k, (px, py) in enumerate(PEOPLE):
        if math.hypot(px - x, py - y) > 1.5:
            ax, ay = placement.to_airport_xy((px, py))
            pose = Pose2(float(ax), float(ay), 0.0)
            obstacles.append(StaticObstacle(f"p{k}", ObstacleKind.PERSON, pose, Body(0.3), 1.8))
    vx, vy, vh, length, width = VEHICLE
    if math.hypot(vx - x, vy - y) > 4.5:
        ax, ay = placement.to_airport_xy((vx, vy))
        pose = Pose2(float(ax), float(ay), placement.x_axis_heading - math.radians(vh))
        body = Body(length=length, width=width)
        obstacles.append(StaticObstacle("truck", ObstacleKind.VEHICLE, pose, body, 2.5))
    start = placement.pose_to_airport(Pose2(x, y, math.radians(h)))
    return replace(scenario, start=start, obstacles=tuple(obstacles))


def timed(fn, repeat: int) -> tuple[list[float], object]:
    times, result = [], None
    gc.disable()
    try:
        for _ in range(repeat):
            t0 = time.perf_counter_ns()
            result = fn()
            times.append((time.perf_counter_ns() - t0) * 1e-6)
    finally:
        gc.enable()
    return times, result


def errors(pose: Pose2, truth: Pose2) -> tuple[float, float]:
    return pose.distance_to(truth), abs(wrap_angle(pose.theta - truth.theta))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=20)
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()

    base = load_scenario(missions_dir() / "a320" / "scenarios" / "clear-apron.xml")
    mission = base.mission
    t0 = time.perf_counter()
    model = FootprintModel.from_aircraft(mission.aircraft)
    build = time.perf_counter() - t0
    nominal = mission.nominal_placement()

    t_global: list[float] = []
    t_icp: list[float] = []
    t_icp_free: list[float] = []
    e_global: list[tuple[float, float]] = []
    e_icp: list[tuple[float, float]] = []
    hypotheses, points, failures = [], [], 0
    for i, (offset, spot) in enumerate((o, s) for o in OFFSETS for s in SPOTS):
        scenario = staged(base, offset, spot, args.seed + i)
        robot = SimRobot(scenario)
        scans = robot.read().scans
        pts = points_from_scans(scans, mission.platform.lasers)
        lines = SightLines.from_scans(scans, mission.platform.lasers)
        truth_a = robot.truth.robot
        truth_f = scenario.true_placement().pose_to_aircraft(truth_a)
        prior = nominal.pose_to_aircraft(truth_a)
        sigma_xy = PRIOR_SIGMA[0] + math.hypot(prior.x, prior.y) * PRIOR_SIGMA[1]

        def global_step(pts=pts, prior=prior, sigma_xy=sigma_xy, lines=lines):
            return register(
                model,
                pts,
                prior,
                prior_sigma_xy=sigma_xy,
                prior_sigma_theta=PRIOR_SIGMA[1],
                sight_lines=lines,
            )

        global_step()
        times, reg = timed(global_step, args.repeat)
        t_global += times
        points.append(len(pts))
        if reg is None:
            failures += 1
        else:
            e_global.append(errors(reg.pose_f, truth_f))
            hypotheses.append(reg.hypotheses)
        track_from = Pose2(
            truth_f.x + TRACK_START.x, truth_f.y + TRACK_START.y, truth_f.theta + TRACK_START.theta
        )
        times, tracked = timed(lambda pts=pts, s=track_from: refine(model, pts, s), args.repeat)
        t_icp += times
        e_icp.append(errors(tracked.pose_f, truth_f))
        times, _ = timed(
            lambda pts=pts, s=track_from, lines=lines: refine(model, pts, s, sight_lines=lines),
            args.repeat,
        )
        t_icp_free += times

    cases = len(OFFSETS) * len(SPOTS)
    print(
        f"A320, {cases} cases ({len(OFFSETS)} parking offsets x {len(SPOTS)} robot spots), "
        f"{args.repeat} timings each; {statistics.fmean(points):.0f} returns per frame "
        f"(both lasers); model built in {build * 1e3:.0f} ms "
        f"({len(model.samples)} outline samples, field {model.field_distance.shape})"
    )
    print()
    print(f"| {'step':<28} | {'mean':>8} | {'p50':>8} | {'max':>8} |")
    print(f"|{'-' * 30}|{'-' * 10}|{'-' * 10}|{'-' * 10}|")
    for name, times in (
        ("register (global + ICP)", t_global),
        ("refine (ICP only)", t_icp),
        ("refine + free-space count", t_icp_free),
    ):
        print(
            f"| {name:<28} | {statistics.fmean(times):5.2f} ms | "
            f"{statistics.median(times):5.2f} ms | {max(times):5.2f} ms |"
        )
    print()
    scored = f"mean {statistics.fmean(hypotheses):.1f}, max {max(hypotheses)}"
    print(f"global: {cases - failures}/{cases} registered; hypotheses scored: {scored}")
    for name, errs in (("global", e_global), ("ICP", e_icp)):
        e = np.array(errs)
        print(
            f"{name} error vs ground truth: position mean {e[:, 0].mean() * 100:.2f} cm, "
            f"max {e[:, 0].max() * 100:.2f} cm; heading mean {math.degrees(e[:, 1].mean()):.3f}"
            f" deg, max {math.degrees(e[:, 1].max()):.3f} deg"
        )


if __name__ == "__main__":
    main()
