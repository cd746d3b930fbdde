"""Obstacle distances from laser returns, measured from the robot's footprint.

r_c, the closest-obstacle distance of the thesis's guard conditions (seed lines
1453-1542), is taken from the robot's rectangular footprint, not from its centre: a
return 0.5 m ahead of the front bumper is 0.5 m away whatever the robot's length.
"""

from __future__ import annotations

import math

import numpy as np

from executive.core.frames import FloatArray, Pose2
from executive.core.records import TrackedObstacle


def scan_to_robot(
    ranges: FloatArray, angle_min: float, increment: float, range_max: float, mount: Pose2
) -> FloatArray:
    """Returns shorter than ``range_max`` as (N, 2) points in the robot frame."""
    hit = ranges < range_max
    angles = angle_min + increment * hit.nonzero()[0]
    r = ranges[hit]
    c, s = math.cos(mount.theta), math.sin(mount.theta)
    lx, ly = r * np.cos(angles), r * np.sin(angles)
    return np.column_stack((mount.x + c * lx - s * ly, mount.y + s * lx + c * ly))


def footprint_distances(points: FloatArray, length: float, width: float) -> FloatArray:
    """Distance of each point (robot frame) to the length x width rectangle at the axle
    centre; 0 for a point on or inside it."""
    return footprint_distances_xy(points[:, 0], points[:, 1], length, width)


def footprint_distances_xy(x: FloatArray, y: FloatArray, length: float, width: float) -> FloatArray:
    """:func:`footprint_distances` of the points of coordinates ``x``, ``y`` (any
    shape)."""
    dx = np.maximum(np.abs(x) - length / 2.0, 0.0)
    dy = np.maximum(np.abs(y) - width / 2.0, 0.0)
    return np.hypot(dx, dy)


MOVER_SPEED = 0.1
"""A track faster than this (m/s) counts as moving (as far as the lasers vouch for its
speed: :func:`vouched_velocity`)..."""
MOVER_MAX_SIZE = 1.5
"""...unless it is bigger than this (enclosing radius, m): a vehicle or a structure,
whose centroid slides as the robot's view of it changes."""


def closest_obstacle(points: FloatArray, length: float, width: float) -> tuple[float, float]:
    """(r_c, bearing): the nearest point's distance to the footprint and its direction
    from the robot's centre; (inf, 0) when there are no points."""
    if len(points) == 0:
        return math.inf, 0.0
    d = footprint_distances(points, length, width)
    k = int(np.argmin(d))
    return float(d[k]), math.atan2(points[k, 1], points[k, 0])


def observable_velocity(
    velocity: tuple[float, float], shape: tuple[float, ...]
) -> tuple[float, float]:
    """The part of a track's velocity the lasers can vouch for: for a line (``shape`` =
    its end points ``(x0, y0, x1, y1)``, in the velocity's frame) only the motion across
    it — the motion along a line is unobservable (the aperture problem) and a partial
    view slides the centroid of a static wall along it; the whole velocity otherwise."""
    if len(shape) != 4:
        return velocity
    x0, y0, x1, y1 = shape
    length = math.hypot(x1 - x0, y1 - y0)
    if length < 1e-9:
        return velocity
    nx, ny = -(y1 - y0) / length, (x1 - x0) / length
    across = velocity[0] * nx + velocity[1] * ny
    return across * nx, across * ny


def vouched_velocity(track: TrackedObstacle) -> tuple[float, float]:
    """A track's velocity as far as the lasers vouch for it: the whole velocity, except
    for a line whose motion along itself was not measured lately (``motion_measured``
    false: only parts of it seen), whose velocity counts across its length only
    (:func:`observable_velocity`). A trolley rolling along its own side face, both ends in
    view, is a line whose along-line motion the tracker measures: it counts at its full
    speed (one doing 1.15 m/s counted at 0.17 m/s, its across-line part, and was left to
    the spiral: A320 busy-apron campaign episode 55)."""
    shape = track.shape if track.kind == "line" and not track.motion_measured else ()
    return observable_velocity(track.velocity, shape)


def is_mover(track: TrackedObstacle) -> bool:
    """Whether a track counts as moving: faster than :data:`MOVER_SPEED` as far as the
    lasers vouch for it, no bigger than :data:`MOVER_MAX_SIZE`, not a zone."""
    return (
        track.kind != "zone"
        and track.size <= MOVER_MAX_SIZE
        and math.hypot(*vouched_velocity(track)) >= MOVER_SPEED
    )


def mover_sweep(
    tracks: tuple[TrackedObstacle, ...],
    horizon: float,
    step: float = 0.5,
    spacing: float = 0.1,
) -> FloatArray:
    """Where the movers (:func:`is_mover`) will be over the next ``horizon`` seconds, as
    points (robot frame): each one's outline (a circle of its size, one point every
    ``spacing`` metres) at its position now and every ``step`` seconds along its vouched
    velocity (:func:`vouched_velocity`). For a planner whose map is a snapshot: a path
    round these keeps off a mover's way for as long as it keeps its course."""
    rings = []
    for track in tracks:
        if not is_mover(track):
            continue
        vx, vy = vouched_velocity(track)
        times = np.arange(0.0, horizon + 1e-9, step)
        centres = np.asarray(track.position) + np.outer(times, (vx, vy))  # (T, 2)
        n = max(8, math.ceil(2.0 * math.pi * track.size / spacing))
        angles = np.linspace(0.0, 2.0 * math.pi, n, endpoint=False)
        ring = track.size * np.column_stack((np.cos(angles), np.sin(angles)))  # (n, 2)
        rings.append((centres[:, None, :] + ring[None, :, :]).reshape(-1, 2))
    return np.vstack(rings) if rings else np.zeros((0, 2))
