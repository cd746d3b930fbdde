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
  :data:`THREAT_HORIZON` (:func:`predictions`: a walker or a trolley pressing on, one
  crossing into the robot's side), the side and speed up to twice the mover's speed
  that keep the movers out of r_ES longest (a crawl they would catch), with room to
  stop; under a threat never a motion that fares worse than standing still against
  any mover;
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
    footprint_distances,
    footprint_distances_xy,
    is_mover,
    vouched_velocity,
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

REACTION = 0.1
"""Seconds before a stop takes hold (a tick of the executive and the base's cycle), as
the mission validator counts it for r_ES."""

ESCAPE_SPEEDS = 6
"""Speeds tried from :data:`RETREAT_SPEED` to the top speed when a mover threatens."""

RETREAT_CLEARANCE = 0.2
"""The tree backs away until the nearest return is this far (m) beyond r_ES: enough for
the latch's hold to run out without the obstacle's jitter bringing it back in."""

GAP_SLACK = 0.05
"""How much smaller (m) the smallest predicted gap of an escape may be than the best
escape's for a slower one to be taken instead, while no mover is inside r_ES yet. Once
one is, none: the retreat is chosen again every tick, and a slack given per horizon is
given again and again (a chaser at 0.32 m/s closed in on a robot backing at 0.29 m/s,
avoidance campaign episode 979)."""

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


SLOWDOWN_FLOOR = 0.2
"""The slowdown zone's lowest speed factor (:func:`slowdown_scale`): obstacle avoidance
can still creep round an obstacle just beyond r_ES."""


def slowdown_scale(
    clearance: FloatArray | float, r_es: float, r_oa: float, floor: float = SLOWDOWN_FLOOR
) -> FloatArray:
    """The slowdown zone's speed factor for the clearance ``r_c`` of the corridor a motion
    drives into (seed lines 1536-1542's zone between r_ES and r_OA-trigger, our linear
    ramp): 1 at and beyond r_OA-trigger, ``(r_c - r_ES) / (r_OA - r_ES)`` within it, never
    below ``floor``; ``floor`` for an unknown (NaN) clearance. Broadcasts."""
    r_c = np.asarray(clearance, dtype=float)
    ramp = np.clip((r_c - r_es) / (r_oa - r_es), floor, 1.0)
    return np.where(r_c >= r_oa, 1.0, np.where(np.isnan(r_c), floor, ramp))


def heading_clearances(
    points: FloatArray, headings: FloatArray, length: float, width: float, r_es: float
) -> FloatArray:
    """:func:`corridor_clearance` of the corridor ahead of a robot turned to each of
    ``headings`` (rad, in the robot frame of ``points``) (K,): where a motion along that
    heading, forwards or backwards (the footprint and the corridor are symmetric), drives
    into. inf where that corridor holds no return."""
    h = np.asarray(headings, dtype=float)[:, None]
    if len(points) == 0:
        return np.full(len(h), math.inf)
    c, s = np.cos(h), np.sin(h)
    x = points[:, 0] * c + points[:, 1] * s  # (K, N): the turned robot's frame
    y = points[:, 1] * c - points[:, 0] * s
    inside = (x > 0.0) & (np.abs(y) <= 0.5 * width + r_es)
    d = footprint_distances_xy(x, y, length, width)
    return np.where(inside, d, math.inf).min(axis=1)


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


def movers(tracks: Iterable[TrackedObstacle]) -> list[TrackedObstacle]:
    """The tracks that count as moving (:func:`~behaviours.laws.obstacles.is_mover`)."""
    return [track for track in tracks if is_mover(track)]


@dataclass(frozen=True, slots=True)
class Prediction:
    """How one mover fares against a straight motion of the robot over the horizon:
    ``intrusion``, the first time (s) its gap falls below r_ES, ``contact`` the first
    time it reaches the footprint (inf: never), and ``gap``, the smallest gap (m). The
    larger, the better, in that order (:meth:`key`)."""

    intrusion: float
    contact: float
    gap: float

    @property
    def key(self) -> tuple[float, float, float]:
        return (self.intrusion, self.contact, self.gap)


def predictions(
    tracks: Iterable[TrackedObstacle],
    velocity: float,
    length: float,
    width: float,
    r_es: float,
    horizon: float = THREAT_HORIZON,
    step: float = 0.02,
) -> list[Prediction]:
    """Per moving track (:func:`movers`, in order), its :class:`Prediction` against the
    footprint driving straight at ``velocity`` (robot frame, m/s), the track at its
    velocity; the gap is the tracked point's distance to the footprint less the track's
    size, sampled every ``step`` m of relative travel (so that a fast mover cannot pass a
    corner between two samples). A gap that is not a number counts as -inf (an unknown
    is a threat)."""
    out = []
    for track in movers(tracks):
        vx, vy = vouched_velocity(track)
        rel_v = (vx - velocity, vy)
        n = max(2, math.ceil(math.hypot(*rel_v) * horizon / step) + 1)
        t = np.linspace(0.0, horizon, n)
        rel = np.column_stack((track.position[0] + rel_v[0] * t, track.position[1] + rel_v[1] * t))
        gaps = footprint_distances(rel, length, width) - track.size
        gaps = np.where(np.isnan(gaps), -np.inf, gaps)
        inside, touching = np.flatnonzero(gaps < r_es), np.flatnonzero(gaps <= 0.0)
        intrusion = float(t[inside[0]]) if len(inside) else math.inf
        contact = float(t[touching[0]]) if len(touching) else math.inf
        out.append(Prediction(intrusion, contact, float(gaps.min())))
    return out


def predicted_gap(
    tracks: Iterable[TrackedObstacle],
    velocity: float,
    length: float,
    width: float,
    horizon: float = THREAT_HORIZON,
) -> float:
    """The smallest gap (m) of all :func:`predictions`; inf when no track moves."""
    found = predictions(tracks, velocity, length, width, 0.0, horizon)
    return min((p.gap for p in found), default=math.inf)


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
    return _roomiest(open_sides(points, sides, length, width, r_es))


def _dominates(moving: list[Prediction], standing: list[Prediction]) -> bool:
    """Whether every mover fares at least as well against a motion (``moving``) as
    against the robot standing still (:attr:`Prediction.key`)."""
    return all(m.key >= s.key for m, s in zip(moving, standing, strict=True))


def _roomiest(room: dict[int, float]) -> int:
    """The side with the most room (forwards on a tie), 0 when there is none."""
    return max(SIDES, key=lambda side: room.get(side, -math.inf)) if room else 0


@dataclass(frozen=True, slots=True)
class Retreat:
    """The retreat a robot of ``length`` x ``width`` with lasers covering ``sides`` may
    make out of an obstacle latch at ``r_es``: at most ``max_speed``, braking at
    ``max_acceleration`` under ``max_jerk`` (the platform's limits)."""

    length: float
    width: float
    r_es: float
    sides: frozenset[int]
    max_speed: float = RETREAT_SPEED
    max_acceleration: float = 1.0
    max_jerk: float = 0.0
    """m/s^3; 0: no jerk limit."""

    @staticmethod
    def of(mission: Mission) -> Retreat:
        """The retreat of the mission's platform: its footprint, r_ES, the sides its
        lasers cover out to r_OA-trigger beyond the footprint, and its limits."""
        platform, safety = mission.platform, mission.safety
        sides = covered_sides(
            platform.lasers.values(),
            platform.length,
            platform.width,
            safety.r_es,
            safety.r_oa_trigger,
        )
        return Retreat(
            platform.length,
            platform.width,
            safety.r_es,
            sides,
            max(RETREAT_SPEED, platform.max_speed),
            platform.max_acceleration,
            platform.max_jerk,
        )

    def predict(self, tracks: Iterable[TrackedObstacle], velocity: float) -> list[Prediction]:
        """The movers' :func:`predictions` against a retreat at ``velocity``."""
        return predictions(tracks, velocity, self.length, self.width, self.r_es)

    def threatened(self, tracks: Iterable[TrackedObstacle]) -> bool:
        """Whether a mover would come inside r_ES of the robot standing where it is
        within :data:`THREAT_HORIZON` (:func:`predictions`)."""
        return any(p.intrusion < math.inf for p in self.predict(tracks, 0.0))

    def top_speed(self, tracks: Iterable[TrackedObstacle]) -> float:
        """The fastest retreat (m/s): under a threat (:meth:`threatened`)
        :data:`ESCAPE_FACTOR` x the fastest mover's speed (at most :attr:`max_speed`),
        else :data:`RETREAT_SPEED`."""
        tracks = tuple(tracks)
        if not self.threatened(tracks):
            return RETREAT_SPEED
        fastest = max((math.hypot(*vouched_velocity(t)) for t in movers(tracks)), default=0.0)
        return min(self.max_speed, max(RETREAT_SPEED, ESCAPE_FACTOR * fastest))

    def stopping(self, speed: float) -> float:
        """How far (m) a retreat at ``speed`` may still travel once told to stop: one
        :data:`REACTION` period, the jerk-limited ramp into full braking, then braking at
        the platform's acceleration."""
        v = abs(speed)
        ramp = self.max_acceleration / self.max_jerk if self.max_jerk > 0.0 else 0.0
        return v * (REACTION + ramp) + v * v / (2.0 * self.max_acceleration)

    def room_for(self, speed: float) -> float:
        """The corridor clearance (m) a retreat at ``speed`` needs: r_ES, and beyond the
        crawl its :meth:`stopping` distance (a return at r_ES ahead of a fast retreat
        would be inside r_ES before the robot stops)."""
        return self.r_es + (self.stopping(speed) if abs(speed) > RETREAT_SPEED else 0.0)

    def no_worse(self, tracks: Iterable[TrackedObstacle], velocity: float) -> bool:
        """Whether a retreat at ``velocity`` (robot frame, m/s) fares no worse than
        standing still against every mover (:class:`Prediction`: no mover inside r_ES
        sooner, none that standing keeps out, none touching sooner, no smaller gap for
        one that comes in at the same time): under a threat, the condition of any
        retreat."""
        tracks = tuple(tracks)
        return _dominates(self.predict(tracks, velocity), self.predict(tracks, 0.0))

    @staticmethod
    def _score(found: list[Prediction]) -> tuple[float, float, float]:
        """The worst of the movers' (intrusion, contact, gap), each on its own: what a
        retreat's speed is chosen by."""
        return (
            min((p.intrusion for p in found), default=math.inf),
            min((p.contact for p in found), default=math.inf),
            min((p.gap for p in found), default=math.inf),
        )

    def speed(
        self, points: FloatArray, closest: float, tracks: Iterable[TrackedObstacle] = ()
    ) -> float:
        """The speed to propose (m/s, signed; 0: stay).

        Under a threat (:meth:`threatened`): of the :data:`ESCAPE_SPEEDS` speeds up to
        :meth:`top_speed` on each of the :func:`open_sides` that leave room to stop
        (:meth:`room_for`) and are :meth:`no_worse` than standing, the slowest whose
        movers come inside r_ES and reach the footprint no sooner than the best's and
        whose smallest gap is within :data:`GAP_SLACK` of it (no smaller, once a mover is
        inside r_ES), when that best beats standing still.
        Otherwise a crawl at :data:`RETREAT_SPEED` towards :func:`retreat_side` until the
        nearest return (``closest``, r_c) is :data:`RETREAT_CLEARANCE` beyond r_ES, and
        under a threat only when it is :meth:`no_worse` than standing."""
        tracks = tuple(tracks)
        room = open_sides(points, self.sides, self.length, self.width, self.r_es)
        if not room:
            return 0.0
        standing = self.predict(tracks, 0.0)
        threat = any(p.intrusion < math.inf for p in standing)  # :meth:`threatened`
        if threat:
            candidates, scores = [], []
            for v in np.linspace(RETREAT_SPEED, self.top_speed(tracks), ESCAPE_SPEEDS):
                for side in sorted(room, key=lambda side: -room[side]):
                    found = self.predict(tracks, side * v)
                    if room[side] >= self.room_for(v) and _dominates(found, standing):
                        candidates.append(side * v)
                        scores.append(self._score(found))
            best = max(scores, default=None)
            if best is not None and best > self._score(standing):
                # a mover already inside r_ES: no ground given (:data:`GAP_SLACK`)
                slack = GAP_SLACK if best[0] > 0.0 else 0.0
                for v, (intrusion, contact, gap) in zip(candidates, scores, strict=True):
                    if (intrusion, contact) >= best[:2] and gap >= best[2] - slack:
                        return float(v)  # the slowest near the best
        if not closest < self.r_es + RETREAT_CLEARANCE:
            return 0.0
        crawl = _roomiest(room) * RETREAT_SPEED
        return crawl if not threat or _dominates(self.predict(tracks, crawl), standing) else 0.0
