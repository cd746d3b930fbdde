"""Backing out of an obstacle e-stop: our addition to the thesis's r_ES stop (seed lines
1536-1542).

The thesis stops the robot while an obstacle is inside r_ES and waits for the zone to
clear. An obstacle that stays there (a trolley parked at the end of its path, a walker
who stopped next to the robot, a chaser pressing it against a parked vehicle) then holds
the robot for good, and the mission fails with nobody in the wrong. The geofence already
lets the robot back out of a zone it overlaps; this module gives an *obstacle* latch the
same way out, under rules that never bring the robot closer to anything:

* only a straight motion, forwards or backwards (omega = 0: turning in place swings the
  corners, which the lasers cannot vouch for): a crawl at :data:`RETREAT_SPEED`, or,
  when a tracked mover would come inside r_ES of the robot standing where it is within
  :data:`THREAT_HORIZON` (:func:`predicted_gap`: a walker or a trolley pressing on, one
  crossing into the robot's side), the side and speed up to twice the mover's speed
  that keep the largest predicted gap to the movers (a crawl they would catch); under
  a threat never a motion that leaves a smaller gap than standing still;
* into a *corridor* (:func:`corridor_clearance`: ahead of the axle in the direction of
  motion, within half the robot's width plus r_ES of its axis) that the lasers cover
  (:func:`covered_sides`) and that holds no return inside r_ES. Every return inside r_ES
  then lies behind the axle with respect to the motion or beside the body, so the
  motion never decreases its distance to the footprint (see the tests' property);
* never after a bumper or the operator's e-stop: those need an operator.

The tree proposes the retreat (:class:`behaviours.controllers.motion.EStopHold`, with
:meth:`Retreat.speed`); the safety layer admits it only when the same corridor rule
holds, no tracked mover is about to enter that corridor, and, under a threat, the
retreat is :meth:`Retreat.no_worse` than standing (executive/safety.py, rule 2).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from behaviours.laws.obstacles import (
    MOVER_MAX_SIZE,
    MOVER_SPEED,
    footprint_distances,
    observable_velocity,
)
from executive.core.frames import FloatArray
from executive.core.model import LaserSpec, Mission
from executive.core.records import TrackedObstacle

RETREAT_SPEED = 0.2
"""Top speed (m/s) of a retreat out of an obstacle e-stop: the slowdown floor's crawl
(0.2 x 1 m/s), far below any mover the robot would back away from."""

THREAT_HORIZON = 3.0
"""Seconds ahead over which the movers' tracked velocities are trusted to predict a
threat and to choose the retreat's speed (the slowdown's ``mover_horizon``)."""

ESCAPE_FACTOR = 2.0
"""A retreat from a threatening mover goes at most this many times its speed (the
velocity-obstacle dodge's escape factor)."""

ESCAPE_SPEEDS = 6
"""Speeds tried from :data:`RETREAT_SPEED` to the top speed when a mover threatens."""

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


def _vouched(track: TrackedObstacle) -> tuple[float, float]:
    """The velocity the lasers vouch for: across its length for a line."""
    shape = track.shape if track.kind == "line" else ()
    return observable_velocity(track.velocity, shape)


def movers(tracks: Iterable[TrackedObstacle]) -> list[TrackedObstacle]:
    """The tracks that move: faster than :data:`MOVER_SPEED` (what the lasers can vouch
    for, across a line) and no bigger than :data:`MOVER_MAX_SIZE`, zones excluded."""
    return [
        track
        for track in tracks
        if track.kind != "zone"
        and track.size <= MOVER_MAX_SIZE
        and math.hypot(*_vouched(track)) >= MOVER_SPEED
    ]


def predicted_gap(
    tracks: Iterable[TrackedObstacle],
    velocity: float,
    length: float,
    width: float,
    horizon: float = THREAT_HORIZON,
    samples: int = 16,
) -> float:
    """The smallest gap (m) between the footprint, driving straight at ``velocity``
    (robot frame, m/s), and any moving track (:func:`movers`; its tracked point's distance
    to the footprint less its size), over ``horizon`` s at the tracks' velocities; inf
    when no track moves."""
    moving = movers(tracks)
    if not moving:
        return math.inf
    t = np.linspace(0.0, horizon, samples)
    gaps = []
    for track in moving:
        vx, vy = _vouched(track)
        rel = np.column_stack((track.position[0] + (vx - velocity) * t, track.position[1] + vy * t))
        gaps.append(float(footprint_distances(rel, length, width).min()) - track.size)
    return min(gaps)


def open_sides(
    points: FloatArray, sides: Iterable[int], length: float, width: float, r_es: float
) -> dict[int, float]:
    """The covered ``sides`` whose corridor holds no return inside r_ES, each with its
    room (the corridor's clearance, m)."""
    room = {side: corridor_clearance(points, side, length, width, r_es) for side in sides}
    return {side: clear for side, clear in room.items() if clear >= r_es}


def retreat_side(
    points: FloatArray,
    sides: Iterable[int],
    length: float,
    width: float,
    r_es: float,
) -> int:
    """The side to back out to (:data:`FORWARD` or :data:`BACKWARD`), 0 when neither may
    be used: of the :func:`open_sides`, the one with the most room (forwards on a tie)."""
    room = open_sides(points, sides, length, width, r_es)
    return max(SIDES, key=lambda side: room.get(side, -math.inf)) if room else 0


@dataclass(frozen=True, slots=True)
class Retreat:
    """The retreat a robot of ``length`` x ``width`` with lasers covering ``sides`` may
    make out of an obstacle latch at ``r_es``, at most at ``max_speed``."""

    length: float
    width: float
    r_es: float
    sides: frozenset[int]
    max_speed: float = RETREAT_SPEED

    @staticmethod
    def of(mission: Mission) -> Retreat:
        """The retreat of the mission's platform: its footprint, r_ES, the sides its
        lasers cover out to r_OA-trigger beyond the footprint, and its top speed."""
        platform, safety = mission.platform, mission.safety
        sides = covered_sides(
            platform.lasers.values(),
            platform.length,
            platform.width,
            safety.r_es,
            safety.r_oa_trigger,
        )
        top = max(RETREAT_SPEED, platform.max_speed)
        return Retreat(platform.length, platform.width, safety.r_es, sides, top)

    def threatened(self, tracks: Iterable[TrackedObstacle]) -> bool:
        """Whether a mover would come inside r_ES of the robot standing where it is
        within :data:`THREAT_HORIZON` (:func:`predicted_gap`)."""
        return predicted_gap(tracks, 0.0, self.length, self.width) < self.r_es

    def top_speed(self, tracks: Iterable[TrackedObstacle]) -> float:
        """The fastest retreat (m/s): under a threat (:meth:`threatened`)
        :data:`ESCAPE_FACTOR` x the fastest mover's speed (at most the platform's top
        speed), else :data:`RETREAT_SPEED`."""
        if not self.threatened(tracks):
            return RETREAT_SPEED
        fastest = max(math.hypot(*_vouched(track)) for track in movers(tracks))
        return min(self.max_speed, max(RETREAT_SPEED, ESCAPE_FACTOR * fastest))

    def no_worse(self, tracks: Iterable[TrackedObstacle], velocity: float) -> bool:
        """Whether a retreat at ``velocity`` (robot frame, m/s) keeps at least the
        :func:`predicted_gap` to the movers that standing still keeps: under a threat,
        the condition of any retreat."""
        tracks = tuple(tracks)
        gap = predicted_gap(tracks, velocity, self.length, self.width)
        return gap >= predicted_gap(tracks, 0.0, self.length, self.width)

    def speed(
        self, points: FloatArray, closest: float, tracks: Iterable[TrackedObstacle] = ()
    ) -> float:
        """The speed to propose (m/s, signed; 0: stay).

        Under a threat (:meth:`threatened`): of the :data:`ESCAPE_SPEEDS` speeds up to
        :meth:`top_speed` on each of the :func:`open_sides`, the slowest whose
        :func:`predicted_gap` is within 5 cm of the best, when that best beats standing
        still. Otherwise a crawl at :data:`RETREAT_SPEED` towards :func:`retreat_side`
        until the nearest return (``closest``, r_c) is :data:`RETREAT_CLEARANCE` beyond
        r_ES, and under a threat only when it is :meth:`no_worse` than standing."""
        tracks = tuple(tracks)
        room = open_sides(points, self.sides, self.length, self.width, self.r_es)
        if not room:
            return 0.0
        threat = self.threatened(tracks)
        if threat:
            candidates = [
                side * v
                for v in np.linspace(RETREAT_SPEED, self.top_speed(tracks), ESCAPE_SPEEDS)
                for side in sorted(room, key=lambda side: -room[side])
            ]
            gaps = np.array([predicted_gap(tracks, v, self.length, self.width) for v in candidates])
            k = int(np.flatnonzero(gaps >= gaps.max() - 0.05)[0])
            if gaps.max() > predicted_gap(tracks, 0.0, self.length, self.width):
                return float(candidates[k])
        if not closest < self.r_es + RETREAT_CLEARANCE:
            return 0.0
        crawl = max(SIDES, key=lambda side: room.get(side, -math.inf)) * RETREAT_SPEED
        return crawl if not threat or self.no_worse(tracks, crawl) else 0.0
