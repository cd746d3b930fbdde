"""Backing out of an obstacle e-stop: our addition to the thesis's r_ES stop (seed lines
1536-1542).

The thesis stops the robot while an obstacle is inside r_ES and waits for the zone to
clear. An obstacle that stays there (a trolley parked at the end of its path, a walker
who stopped next to the robot, a chaser pressing it against a parked vehicle) then holds
the robot for good, and the mission fails with nobody in the wrong. The geofence already
lets the robot back out of a zone it overlaps; this module gives an *obstacle* latch the
same way out, under rules that never bring the robot closer to anything:

* only a straight crawl, forwards or backwards (omega = 0: turning in place swings the
  corners, which the lasers cannot vouch for), at most :data:`RETREAT_SPEED`;
* into a *corridor* (:func:`corridor_clearance`: ahead of the axle in the direction of
  motion, within half the robot's width plus r_ES of its axis) that the lasers cover
  (:func:`covered_sides`) and that holds no return inside r_ES. Every return inside r_ES
  then lies behind the axle with respect to the motion or beside the body, so the
  motion never decreases its distance to the footprint (see the tests' property);
* never after a bumper or the operator's e-stop: those need an operator.

The tree proposes the retreat (:class:`behaviours.controllers.motion.EStopHold`, with
:func:`retreat_side`); the safety layer admits it only when the same corridor rule holds
and no tracked mover is about to enter that corridor (executive/safety.py, rule 2).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from behaviours.laws.obstacles import footprint_distances
from executive.core.frames import FloatArray
from executive.core.model import LaserSpec, Mission

RETREAT_SPEED = 0.2
"""Top speed (m/s) of a retreat out of an obstacle e-stop: the slowdown floor's crawl
(0.2 x 1 m/s), far below any mover the robot would back away from."""

RETREAT_CLEARANCE = 0.2
"""The tree backs away until the nearest return is this far (m) beyond r_ES: enough for
the latch's hold to run out without the obstacle's jitter bringing it back in."""

FORWARD, BACKWARD = 1, -1
SIDES = (FORWARD, BACKWARD)

_SAMPLES = 9  # per metre along and across a corridor, for the coverage check


def corridor_clearance(
    points: FloatArray, side: int, length: float, width: float, r_es: float
) -> float:
    """The footprint's distance (m) to the nearest return (robot frame, (N, 2)) in the
    corridor of ``side``: ``x * side > 0`` and ``|y| <= width / 2 + r_es``; inf when that
    corridor holds none."""
    if len(points) == 0:
        return math.inf
    half = 0.5 * width + r_es
    ahead = points[(points[:, 0] * side > 0.0) & (np.abs(points[:, 1]) <= half)]
    if len(ahead) == 0:
        return math.inf
    return float(footprint_distances(ahead, length, width).min())


def covered_sides(
    lasers: Iterable[LaserSpec], length: float, width: float, r_es: float, reach: float
) -> frozenset[int]:
    """The sides whose corridor (see :func:`corridor_clearance`) the lasers see in full
    from the footprint's end out to ``reach`` beyond it: every sample point of it lies in
    some laser's field of view and range. A robot with only a front scanner cannot back
    out blind."""
    specs = list(lasers)
    half = 0.5 * width + r_es
    across = np.linspace(-half, half, max(3, math.ceil(2 * half * _SAMPLES) + 1))
    sides = set()
    for side in SIDES:
        along = side * np.linspace(
            0.5 * length + 0.01, 0.5 * length + reach, max(3, math.ceil(reach * _SAMPLES) + 1)
        )
        xs, ys = np.meshgrid(along, across)
        seen = np.zeros(xs.shape, dtype=bool)
        for spec in specs:
            dx, dy = xs - spec.mount[0], ys - spec.mount[1]
            bearing = np.arctan2(dy, dx) - spec.mount_yaw
            bearing = (bearing + np.pi) % (2 * np.pi) - np.pi
            seen |= (np.abs(bearing) <= 0.5 * spec.fov) & (np.hypot(dx, dy) <= spec.range)
        if seen.all():
            sides.add(side)
    return frozenset(sides)


def retreat_side(
    points: FloatArray,
    sides: Iterable[int],
    length: float,
    width: float,
    r_es: float,
) -> int:
    """The side to back out to (:data:`FORWARD` or :data:`BACKWARD`), 0 when neither may
    be used: of the covered ``sides`` whose corridor holds no return inside r_ES, the one
    with the most room (forwards on a tie)."""
    best, room = 0, -math.inf
    for side in SIDES:
        if side not in sides:
            continue
        clear = corridor_clearance(points, side, length, width, r_es)
        if clear >= r_es and clear > room:
            best, room = side, clear
    return best


@dataclass(frozen=True, slots=True)
class Retreat:
    """The retreat a robot of ``length`` x ``width`` with lasers covering ``sides`` may
    make out of an obstacle latch at ``r_es``."""

    length: float
    width: float
    r_es: float
    sides: frozenset[int]

    @staticmethod
    def of(mission: Mission) -> Retreat:
        """The retreat of the mission's platform: its footprint, r_ES, and the sides its
        lasers cover out to r_OA-trigger beyond the footprint."""
        platform, safety = mission.platform, mission.safety
        sides = covered_sides(
            platform.lasers.values(),
            platform.length,
            platform.width,
            safety.r_es,
            safety.r_oa_trigger,
        )
        return Retreat(platform.length, platform.width, safety.r_es, sides)

    def speed(self, points: FloatArray, closest: float) -> float:
        """The speed to propose (m/s, signed; 0: stay): :data:`RETREAT_SPEED` towards
        :func:`retreat_side` until the nearest return (``closest``, r_c) is
        :data:`RETREAT_CLEARANCE` beyond r_ES."""
        if not closest < self.r_es + RETREAT_CLEARANCE:
            return 0.0
        side = retreat_side(points, self.sides, self.length, self.width, self.r_es)
        return side * RETREAT_SPEED
