"""Laser scan ray casting: sim2d.raycast against pymunk queries and a plain broadcast.

Usage:  OPENBLAS_NUM_THREADS=1 python benchmarks/bench_raycast.py [--scans N] [--seed S]

One Hokuyo UTM-30LX scan (270 deg in 0.25 deg steps = 1081 beams, 30 m) in a scene of
30 shapes (20 boxes + 10 circles, seeded, centres 2-25 m around the sensor), from N
random sensor poses (within 1 m of the scene centre, any heading), three ways:

* ``cast_scan``: sim2d.raycast, only the beams that some shape covers are computed;
* pymunk: the same scene as static ``pymunk.Poly`` boxes and ``pymunk.Circle`` circles
  (radius 0), one ``space.segment_query_first`` per beam;
* broadcast: every beam against every edge and circle in plain numpy.

Prints the time per scan (mean, p50, p99), the ratios, and the largest difference between
the ranges of the three methods over all scans. The garbage collector is off while timing.
"""

from __future__ import annotations

import argparse
import gc
import math
import statistics
import time

import numpy as np
import pymunk

from sim2d.raycast import Scene, box_corners, cast_scan

AMIN, INC, N_BEAMS, RMAX = -3 * math.pi / 4, math.pi / 720, 1081, 30.0


def make_obstacles(rng: np.random.Generator) -> tuple[list[tuple], list[tuple]]:
    """20 boxes (x, y, heading, length, width) and 10 circles (x, y, r), 2-25 m away,
    none closer than 1.5 m to the scene centre (so never around the sensor)."""
    boxes: list[tuple] = []
    while len(boxes) < 20:
        d, bearing = rng.uniform(2.0, 25.0), rng.uniform(-math.pi, math.pi)
        length, width = rng.uniform(0.5, 5.0), rng.uniform(0.5, 2.5)
        if d - 0.5 * math.hypot(length, width) >= 1.5:
            x, y = d * math.cos(bearing), d * math.sin(bearing)
            boxes.append((x, y, rng.uniform(-math.pi, math.pi), length, width))
    circles = []
    for _ in range(10):
        d, bearing = rng.uniform(2.0, 25.0), rng.uniform(-math.pi, math.pi)
        circles.append((d * math.cos(bearing), d * math.sin(bearing), rng.uniform(0.15, 0.8)))
    return boxes, circles


def make_scene(boxes: list[tuple], circles: list[tuple]) -> Scene:
    parts = [Scene.from_box(*b, owner=i) for i, b in enumerate(boxes)]
    parts.append(Scene(circles=circles, circle_owner=100 + np.arange(len(circles))))
    return Scene.concat(parts)


def make_space(boxes: list[tuple], circles: list[tuple]) -> pymunk.Space:
    space = pymunk.Space()
    body = space.static_body
    for b in boxes:
        space.add(pymunk.Poly(body, [tuple(p) for p in box_corners(*b)], radius=0.0))
    for x, y, r in circles:
        space.add(pymunk.Circle(body, r, (x, y)))
    return space


def pymunk_scan(space: pymunk.Space, origin: tuple[float, float], heading: float) -> np.ndarray:
    ox, oy = origin
    angles = heading + AMIN + INC * np.arange(N_BEAMS)
    ends_x = (ox + RMAX * np.cos(angles)).tolist()
    ends_y = (oy + RMAX * np.sin(angles)).tolist()
    every = pymunk.ShapeFilter()
    query = space.segment_query_first
    ranges = np.full(N_BEAMS, RMAX)
    for k in range(N_BEAMS):
        info = query(origin, (ends_x[k], ends_y[k]), 0.0, every)
        if info is not None:
            px, py = info.point
            ranges[k] = math.hypot(px - ox, py - oy)
    return ranges


def broadcast_scan(
    edges: np.ndarray, circles: np.ndarray, origin: tuple[float, float], heading: float
) -> tuple[np.ndarray, int]:
    """Every beam against every shape. Returns the ranges and the number of (beam, shape)
    hits before occlusion: the pairs that cast_scan computes."""
    ox, oy = origin
    angles = heading + AMIN + INC * np.arange(N_BEAMS)
    c, s = np.cos(angles)[:, None], np.sin(angles)[:, None]
    ax, ay = edges[:, 0] - ox, edges[:, 1] - oy
    ex, ey = edges[:, 2] - edges[:, 0], edges[:, 3] - edges[:, 1]
    cross = ax * ey - ay * ex
    with np.errstate(divide="ignore", invalid="ignore"):
        den = c * ey - s * ex
        t = cross / den
        u = (ax * s - ay * c) / den
    # front faces only (counter-clockwise boxes: the sensor on the right of the edge)
    hit = (cross < 0) & (t > 0) & (u >= 0) & (u <= 1)
    cx, cy, r = circles[:, 0] - ox, circles[:, 1] - oy, circles[:, 2]
    p = c * cx + s * cy
    q = c * cy - s * cx
    disc = r * r - q * q
    hit_c = (disc >= 0) & (p > 0)
    tc = p - np.sqrt(np.maximum(disc, 0.0))
    best = np.minimum(np.where(hit, t, np.inf).min(axis=1), np.where(hit_c, tc, np.inf).min(axis=1))
    return np.minimum(best, RMAX), int(hit.sum() + hit_c.sum())


def timed(fn, poses: list[tuple]) -> tuple[list[float], list]:
    results, times = [], []
    gc.disable()
    try:
        for origin, heading in poses:
            t0 = time.perf_counter_ns()
            res = fn(origin, heading)
            times.append((time.perf_counter_ns() - t0) * 1e-3)
            results.append(res)
    finally:
        gc.enable()
    return times, results


def summary(times: list[float]) -> tuple[float, float, float]:
    ordered = sorted(times)
    p99 = ordered[min(len(ordered) - 1, int(0.99 * len(ordered)))]
    return statistics.fmean(times), statistics.median(times), p99


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scans", type=int, default=2000)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    rng = np.random.default_rng(args.seed)
    boxes, circles = make_obstacles(rng)
    scene = make_scene(boxes, circles)
    space = make_space(boxes, circles)
    edges, circ = scene.segments.copy(), scene.circles
    poses = []
    for _ in range(args.scans):
        rho, phi = math.sqrt(rng.uniform()), rng.uniform(-math.pi, math.pi)
        poses.append(((rho * math.cos(phi), rho * math.sin(phi)), rng.uniform(-math.pi, math.pi)))

    out = np.empty(N_BEAMS)

    def ours(origin: tuple[float, float], heading: float) -> np.ndarray:
        return cast_scan(scene, origin, heading, AMIN, INC, N_BEAMS, RMAX, out).copy()

    def ours_timed_only(origin: tuple[float, float], heading: float) -> None:
        cast_scan(scene, origin, heading, AMIN, INC, N_BEAMS, RMAX, out)

    for origin, heading in poses[:50]:  # warm up (caches, lazy imports)
        ours_timed_only(origin, heading)
        broadcast_scan(edges, circ, origin, heading)
    t_ours, _ = timed(ours_timed_only, poses)
    _, r_ours = timed(ours, poses)
    t_pm, r_pm = timed(lambda o, h: pymunk_scan(space, o, h), poses)
    t_bc, r_bc = timed(lambda o, h: broadcast_scan(edges, circ, o, h), poses)

    ours_ranges, pm_ranges = np.array(r_ours), np.array(r_pm)
    bc_ranges = np.array([r for r, _ in r_bc])
    pairs = statistics.fmean(n for _, n in r_bc)
    hits = float(np.mean(ours_ranges < RMAX)) * N_BEAMS

    print(
        f"scene: {len(boxes)} boxes ({scene.n_segments} edges) + {len(circles)} circles, "
        f"seed {args.seed}; {args.scans} scans of {N_BEAMS} beams, {RMAX:g} m"
    )
    print(
        f"per scan: {hits:.0f} beams hit something; {pairs:.0f} (beam, shape) pairs "
        f"computed by cast_scan, out of {N_BEAMS * (scene.n_segments + len(circles))}"
    )
    print()
    base = summary(t_ours)[0]
    print(f"| {'method':<38} | {'mean':>9} | {'p50':>9} | {'p99':>9} | {'x cast_scan':>11} |")
    print(f"|{'-' * 40}|{'-' * 11}|{'-' * 11}|{'-' * 11}|{'-' * 13}|")
    for name, times in (
        ("sim2d.raycast.cast_scan", t_ours),
        ("pymunk segment_query_first per beam", t_pm),
        ("numpy broadcast, all beams x shapes", t_bc),
    ):
        mean, p50, p99 = summary(times)
        print(
            f"| {name:<38} | {mean:6.1f} us | {p50:6.1f} us | {p99:6.1f} us | "
            f"{mean / base:10.1f}x |"
        )
    print()
    print(f"max |cast_scan - pymunk|    = {np.abs(ours_ranges - pm_ranges).max():.3g} m")
    print(f"max |cast_scan - broadcast| = {np.abs(ours_ranges - bc_ranges).max():.3g} m")


if __name__ == "__main__":
    main()
