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
  that keep the movers off the footprint longest, then out of r_ES longest (a crawl
  they would catch), with room to stop; under a threat never a motion that fares worse
  than standing still against any mover;
* into a *corridor* (:func:`corridor_clearance`: ahead of the axle in the direction of
  motion, within half the robot's width plus r_ES of its axis) that the lasers cover
  (:func:`covered_sides`) and that holds no return inside r_ES. Every return inside r_ES
  then lies behind the axle with respect to the motion or beside the body, so the
  motion never decreases its distance to the footprint (see the tests' property);
* never after a bumper or the operator's e-stop: those need an operator;
* when no straight crawl gains ground (a robot pinched between two obstacles at its
  diagonal corners, where either way along its axis closes on one of them) and the lasers
  see all round the footprint but for pockets beside it that the robot remembers
  (:mod:`behaviours.laws.blind_spots`), an *arc* at a crawl
  (:meth:`Retreat.motion`): one that no return gets closer along (or, outside r_ES,
  comes inside it) over the distance the robot needs to stop (:func:`closes_in`), of
  curvature at most the platform's angular over linear acceleration (so that the safety
  layer can ramp both speeds along the same arc), and only while no mover threatens.

The tree proposes the retreat (:class:`behaviours.controllers.motion.EStopHold`, with
:meth:`Retreat.motion`); the safety layer admits a straight one by the same rule
(:meth:`Retreat.open_sides`: the corridor's returns, and, while no mover threatens, the
movers about to enter it; under a threat the retreat must be :meth:`Retreat.no_worse`
than standing), and an arc only when :meth:`Retreat.arc_admitted` (executive/safety.py,
rule 2).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from behaviours.laws.blind_spots import pockets_only, seen_by
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

ARC_TURNS = (1.0, 0.5)
"""The arcs a pinched robot tries, as fractions of the largest curvature it may retreat
on (:attr:`Retreat.max_curvature`), turning either way, forwards and backwards."""

GAIN_RATIO = 0.1
"""A retreat must bring the nearest return further by this fraction of the distance it
travels (over its :meth:`Retreat.lookahead`) to count as gaining ground: less is
creeping alongside for nothing (a straight crawl away from what is ahead gains 1)."""

ARC_STEP = 0.01
"""Axle travel (m) between the poses a retreat is checked at along its path."""

FORWARD, BACKWARD = 1, -1
SIDES = (FORWARD, BACKWARD)

_SAMPLES = 9  # per metre along and across a corridor, for the coverage check
_DIGITS = 9  # predictions' times (s) and gaps (m) are compared to the nanosecond, nanometre


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
        if seen_by(specs, *np.meshgrid(along, across)).all():
            sides.add(side)
    return frozenset(sides)


def path_poses(v: float, omega: float, distance: float, step: float = ARC_STEP) -> FloatArray:
    """The poses ``(x, y, theta)`` (K, 3) of a robot leaving the origin at constant
    ``(v, omega)`` (a straight line when omega is 0, else an arc of curvature
    omega / v), every ``step`` m of axle travel up to ``distance``, the start included,
    and 0.1 mm and 1 mm from it (a return that the first millimetres approach and the
    next ones leave would pass between the samples); the unicycle integrated exactly."""
    n = max(1, math.ceil(distance / step))
    s = np.linspace(0.0, distance, n + 1)
    s = np.unique(np.concatenate((s, [min(1e-4, distance), min(1e-3, distance)])))
    s *= math.copysign(1.0, v)  # signed travel
    k = omega / v
    theta = k * s
    if abs(k) < 1e-12:
        return np.column_stack((s, np.zeros_like(s), theta))
    return np.column_stack((np.sin(theta) / k, (1.0 - np.cos(theta)) / k, theta))


def distances_along(
    points: FloatArray, poses: FloatArray, length: float, width: float
) -> FloatArray:
    """The footprint's distance to each point (robot frame at the first pose, (N, 2)) from
    each of ``poses`` (K, 3) in that frame: (K, N)."""
    x, y, theta = poses[:, 0:1], poses[:, 1:2], poses[:, 2:3]
    dx, dy = points[None, :, 0] - x, points[None, :, 1] - y
    c, s = np.cos(theta), np.sin(theta)
    return footprint_distances_xy(dx * c + dy * s, dy * c - dx * s, length, width)


def closes_in(distances: FloatArray, r_es: float, tol: float = 1e-9) -> bool:
    """Whether a motion whose footprint distances along its path are ``distances`` (K, N;
    row 0 the start, :func:`distances_along`) brings the footprint closer to a return
    already inside r_ES, or brings one from outside r_ES inside it: what no retreat may
    do."""
    floor = np.minimum(distances[0], r_es) - tol
    return bool((distances[1:] < floor[None, :]).any())


def movers(tracks: Iterable[TrackedObstacle]) -> list[TrackedObstacle]:
    """The tracks that count as moving (:func:`~behaviours.laws.obstacles.is_mover`)."""
    return [track for track in tracks if is_mover(track)]


@dataclass(frozen=True, slots=True)
class Prediction:
    """How one mover fares against a straight motion of the robot over the horizon:
    ``intrusion``, the first time (s) its gap falls below r_ES, ``contact`` the first
    time it reaches the footprint (inf: never), and ``gap``, the smallest gap (m). The
    larger, the better (:meth:`key`)."""

    intrusion: float
    contact: float
    gap: float

    @property
    def key(self) -> tuple[float, float, float]:
        """What the motions are compared by: (contact, intrusion, gap), the larger the
        better in that order. Being struck is what a retreat is for avoiding: a motion
        that keeps a mover off the footprint beats one that only lets it inside r_ES a
        few milliseconds later and is struck (an escape under the latch, where the robot
        is stopped already). A mover kept out of r_ES over the whole horizon is out of
        harm's way at any gap: all such count alike, (inf, inf, inf). Ranking them by gap
        let a walker 9 m off, whose gap an escape brought down to 5 m, veto the escape
        from a chaser about to strike (A320 busy-apron episode 72)."""
        if self.intrusion == math.inf:
            return (math.inf, math.inf, math.inf)
        return (self.contact, self.intrusion, self.gap)


def entry_time(
    x: float,
    y: float,
    ux: float,
    uy: float,
    length: float,
    width: float,
    reach: float,
    horizon: float,
) -> float:
    """The first time ``t`` in [0, ``horizon``] (s) at which the point ``(x, y) + (ux,
    uy) t`` (robot frame, m and m/s) is within ``reach`` (m, >= 0) of the length x width
    footprint at the axle centre (:func:`footprint_distances`); inf when it never is.
    Exact: the footprint grown by ``reach`` is the union of two rectangles (grown along
    each axis) and four discs at the corners; the point's ray enters each in closed form
    (slabs; a quadratic), so no sampling step can miss a corner or shift the time."""
    hl, hw = 0.5 * length, 0.5 * width
    first = math.inf
    for ax, ay in ((hl + reach, hw), (hl, hw + reach)):
        lo, hi = 0.0, horizon
        for p, u, a in ((x, ux, ax), (y, uy, ay)):
            if u == 0.0:
                if abs(p) > a:
                    lo, hi = math.inf, -math.inf
                continue
            t1, t2 = (-a - p) / u, (a - p) / u
            lo, hi = max(lo, min(t1, t2)), min(hi, max(t1, t2))
        if lo <= hi:
            first = min(first, lo)
    for cx in (-hl, hl):
        for cy in (-hw, hw):
            px, py = x - cx, y - cy
            c = px * px + py * py - reach * reach
            if c <= 0.0:
                return 0.0
            a = ux * ux + uy * uy
            b = px * ux + py * uy  # half the linear coefficient
            disc = b * b - a * c
            if a > 0.0 and b < 0.0 and disc >= 0.0:
                t = (-b - math.sqrt(disc)) / a
                if t <= horizon:
                    first = min(first, t)
    return first


def segment_gap(
    x: float, y: float, ux: float, uy: float, length: float, width: float, horizon: float
) -> float:
    """The smallest distance (m) of the point ``(x, y) + (ux, uy) t``, t in [0,
    ``horizon``], to the footprint (:func:`entry_time`'s frame and point): 0 when it
    reaches it, else attained at an end of the segment or at a corner of the footprint
    (the nearest points of two disjoint convex shapes: a vertex of one, an edge of the
    other)."""
    if entry_time(x, y, ux, uy, length, width, 0.0, horizon) < math.inf:
        return 0.0
    hl, hw = 0.5 * length, 0.5 * width
    ex, ey = x + ux * horizon, y + uy * horizon
    best = float(footprint_distances_xy(np.array([x, ex]), np.array([y, ey]), length, width).min())
    dx, dy = ex - x, ey - y
    span = dx * dx + dy * dy
    for cx in (-hl, hl):
        for cy in (-hw, hw):
            s = 0.0 if span == 0.0 else min(1.0, max(0.0, ((cx - x) * dx + (cy - y) * dy) / span))
            best = min(best, math.hypot(x + s * dx - cx, y + s * dy - cy))
    return best


def predictions(
    tracks: Iterable[TrackedObstacle],
    velocity: float,
    length: float,
    width: float,
    r_es: float,
    horizon: float = THREAT_HORIZON,
) -> list[Prediction]:
    """Per moving track (:func:`movers`, in order), its :class:`Prediction` against the
    footprint driving straight at ``velocity`` (robot frame, m/s), the track at its
    velocity: its gap is the tracked point's distance to the footprint less the track's
    size, its intrusion and contact the exact times that gap falls below r_ES and to 0
    (:func:`entry_time`; a time sampled on a grid that depends on the relative speed
    moved by a grid step from one velocity to the next, and a retreat that changed
    nothing for a mover beside the body counted as bringing its contact a few
    milliseconds sooner: A320 busy-apron episode 94). A position or velocity that is not
    a number counts as touching now with a gap of -inf (an unknown is a threat)."""
    out = []
    for track in movers(tracks):
        vx, vy = vouched_velocity(track)
        ux, uy = vx - velocity, vy
        x, y = track.position
        if not all(math.isfinite(c) for c in (x, y, ux, uy, track.size)):
            out.append(Prediction(0.0, 0.0, -math.inf))
            continue
        size = track.size
        intrusion = entry_time(x, y, ux, uy, length, width, r_es + size, horizon)
        contact = entry_time(x, y, ux, uy, length, width, size, horizon)
        gap = segment_gap(x, y, ux, uy, length, width, horizon) - size
        # one instant reached by two formulas (a slab, a corner's disc) differs in the
        # last bits: rounded, it compares equal
        out.append(Prediction(*(round(float(q), _DIGITS) for q in (intrusion, contact, gap))))
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


def enters_corridor(
    track: TrackedObstacle,
    v: float,
    half: float,
    horizon: float = THREAT_HORIZON,
    points: FloatArray | None = None,
) -> bool:
    """Whether a moving track ahead of a robot driving at ``v`` (m/s, robot frame) enters
    the corridor it drives into (``x v > 0``, ``|y| <= half``) within ``horizon``
    seconds, moving relative to the robot at its vouched velocity less the robot's own
    ``v`` (the motion term of speed-and-separation monitoring: a walker about to step in
    front of the robot counts before it gets there, not once it is there). A mover
    behind, chasing, never does: slowing for it would let it catch up.

    Where the track is, across the corridor: its disc (``size`` about its position), or,
    given the returns (``points``, robot frame), the returns within that disc: in the
    corridor, or the nearest to it of those on the side it moves away from (they cross
    first). A cluster merged with what it passes encloses far more than it holds
    (avoidance episode 142: a 1.14 m disc over a chaser and a cone, half of it across a
    corridor that none of its returns were in)."""
    if not is_mover(track):
        return False
    x, y = track.position
    vx, vy = vouched_velocity(track)
    if x * v <= 0.0:
        return False
    ys = np.array([y - track.size, y + track.size])  # the disc's extent across
    if points is not None and len(points):
        own = points[np.hypot(points[:, 0] - x, points[:, 1] - y) <= track.size + 1e-6]
        if len(own):
            ys = own[:, 1]
    if (np.abs(ys) <= half).any() or (ys.min() < -half and ys.max() > half):
        t0 = 0.0  # in the corridor, or across it
    elif abs(vy) < 1e-9:
        return False  # beside the corridor and not moving across
    else:
        towards = ys[ys * vy < 0.0]  # on the side it moves away from: closing on the axis
        if len(towards) == 0:
            return False  # all on the side it moves towards: moving away from the corridor
        t0 = (float(np.abs(towards).min()) - half) / abs(vy)
    # still ahead of the axle when it enters the corridor (x moves at vx - v)
    return t0 <= horizon and (x + (vx - v) * t0) * v > 0.0


def corridor_room(
    points: FloatArray,
    tracks: Iterable[TrackedObstacle],
    v: float,
    length: float,
    width: float,
    r_es: float,
    horizon: float = THREAT_HORIZON,
) -> float:
    """The room (m) ahead of a motion at ``v`` (its sign picks the side): the
    :func:`corridor_clearance` of the returns, or the clearance of a tracked mover that
    :func:`enters_corridor` within ``horizon``, whichever is smaller. The slowdown zone's
    r_d, and a straight retreat's room when no mover threatens."""
    side = 1 if v > 0.0 else -1
    room = corridor_clearance(points, side, length, width, r_es)
    half = 0.5 * width + r_es
    for track in tracks:
        if track.clearance < room and enters_corridor(track, v, half, horizon, points):
            room = track.clearance
    return room


def open_sides(
    points: FloatArray,
    sides: Iterable[int],
    length: float,
    width: float,
    r_es: float,
    tracks: Iterable[TrackedObstacle] = (),
    speed: float = RETREAT_SPEED,
) -> dict[int, float]:
    """The covered ``sides`` whose corridor holds no return inside r_ES and no mover of
    ``tracks`` about to enter it that close at ``speed`` (:func:`corridor_room`), each
    with its room (m)."""
    tracks = tuple(tracks)
    room = {
        side: corridor_room(points, tracks, side * speed, length, width, r_es) for side in sides
    }
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
    max_curvature: float = 0.0
    """1/m: the tightest arc a pinched robot may retreat on (:meth:`motion`); 0: straight
    retreats only (the lasers do not see all round the footprint)."""

    @staticmethod
    def of(mission: Mission) -> Retreat:
        """The retreat of the mission's platform: its footprint, r_ES, the sides its
        lasers cover out to r_OA-trigger beyond the footprint, and its limits. Arcs when
        the lasers see all round the footprint that far but for blind pockets it
        remembers (:func:`~behaviours.laws.blind_spots.pockets_only`), of
        curvature at most the angular over the linear acceleration (the safety layer
        then ramps the yaw rate with the speed, on the same arc, within both limits) and
        the angular speed over the crawl's."""
        platform, safety = mission.platform, mission.safety
        lasers = platform.lasers.values()
        sides = covered_sides(
            lasers, platform.length, platform.width, safety.r_es, safety.r_oa_trigger
        )
        around = pockets_only(lasers, platform.length, platform.width, safety.r_oa_trigger)
        curvature = min(
            platform.max_angular_acceleration / platform.max_acceleration,
            platform.max_angular_speed / RETREAT_SPEED,
        )
        return Retreat(
            platform.length,
            platform.width,
            safety.r_es,
            sides,
            max(RETREAT_SPEED, platform.max_speed),
            platform.max_acceleration,
            platform.max_jerk,
            curvature if around else 0.0,
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

    def open_sides(
        self,
        points: FloatArray,
        tracks: tuple[TrackedObstacle, ...],
        threat: bool,
        speed: float = RETREAT_SPEED,
    ) -> dict[int, float]:
        """The sides a straight retreat may take, each with its room (m): one rule for the
        tree that proposes and the safety layer that admits. Under a threat
        (:meth:`threatened`) the returns' corridors (:func:`open_sides`): the movers are
        judged by their :func:`predictions` against the retreat (:meth:`no_worse`), and
        a merged track's disc overlapping a corridor its returns leave open does not
        close it (avoidance episode 142). Otherwise a mover about to enter a corridor
        counts too, with its clearance (:func:`corridor_room`, at ``speed``)."""
        entering = () if threat else tracks
        return open_sides(points, self.sides, self.length, self.width, self.r_es, entering, speed)

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
        standing still against every mover (:attr:`Prediction.key`: none that standing
        keeps out of r_ES comes in, none touching sooner, none inside r_ES sooner among
        those that touch as soon, no smaller gap for one that comes in at the same
        time): under a threat, the condition of any retreat."""
        tracks = tuple(tracks)
        return _dominates(self.predict(tracks, velocity), self.predict(tracks, 0.0))

    @staticmethod
    def _score(found: list[Prediction]) -> tuple[float, float, float]:
        """The worst of the movers' :attr:`Prediction.key` (contact, intrusion, gap),
        each on its own: what a retreat's speed is chosen by."""
        keys = [p.key for p in found]
        return (
            min((k[0] for k in keys), default=math.inf),
            min((k[1] for k in keys), default=math.inf),
            min((k[2] for k in keys), default=math.inf),
        )

    def speed(
        self, points: FloatArray, closest: float, tracks: Iterable[TrackedObstacle] = ()
    ) -> float:
        """The speed to propose (m/s, signed; 0: stay).

        Under a threat (:meth:`threatened`): of the :data:`ESCAPE_SPEEDS` speeds up to
        :meth:`top_speed` on each of the :func:`open_sides` that leave room to stop
        (:meth:`room_for`) and are :meth:`no_worse` than standing, the slowest whose
        movers reach the footprint and come inside r_ES no sooner than the best's and
        whose smallest gap is within :data:`GAP_SLACK` of it (no smaller, once a mover is
        inside r_ES), when that best beats standing still.
        Otherwise a crawl at :data:`RETREAT_SPEED` towards the open side with the most
        room (:meth:`open_sides`: the movers about to enter count) until the
        nearest return (``closest``, r_c) is :data:`RETREAT_CLEARANCE` beyond r_ES, and
        under a threat only when it is :meth:`no_worse` than standing."""
        tracks = tuple(tracks)
        standing = self.predict(tracks, 0.0)
        threat = any(p.intrusion < math.inf for p in standing)  # :meth:`threatened`
        room = self.open_sides(points, tracks, threat)
        if not room:
            return 0.0
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
                slack = GAP_SLACK if best[1] > 0.0 else 0.0
                for v, (contact, intrusion, gap) in zip(candidates, scores, strict=True):
                    if (contact, intrusion) >= best[:2] and gap >= best[2] - slack:
                        return float(v)  # the slowest near the best
        if not closest < self.r_es + RETREAT_CLEARANCE:
            return 0.0
        crawl = _roomiest(room) * RETREAT_SPEED
        return crawl if not threat or _dominates(self.predict(tracks, crawl), standing) else 0.0

    def lookahead(self, speed: float) -> float:
        """How far along its path (m) a retreat at ``speed`` is checked: its
        :meth:`stopping` distance and one :data:`ARC_STEP`."""
        return self.stopping(speed) + ARC_STEP

    def gain(
        self, points: FloatArray, v: float, omega: float, hidden: FloatArray | None = None
    ) -> tuple[bool, float]:
        """(whether the motion ``(v, omega)`` (robot frame) keeps every return, and every
        ``hidden`` one remembered in a blind spot, out of the footprint's way over its
        :meth:`lookahead`, see :func:`closes_in`; how much further (m) the nearest return
        then is)."""
        if hidden is not None and len(hidden):
            points = np.vstack((points, hidden))
        poses = path_poses(v, omega, self.lookahead(v))
        d = distances_along(points, poses, self.length, self.width)
        if d.shape[1] == 0:
            return True, 0.0
        seen = d[:, : len(d[0]) - (0 if hidden is None else len(hidden))]
        gain = float(seen[-1].min() - seen[0].min()) if seen.shape[1] else 0.0
        return not closes_in(d, self.r_es), gain

    def arc_admitted(
        self, points: FloatArray, v: float, omega: float, hidden: FloatArray | None = None
    ) -> bool:
        """Whether ``(v, omega)``, omega not 0, is an arc this robot may retreat on now:
        a crawl at most :data:`RETREAT_SPEED`, within :attr:`max_curvature`, along which
        no return, seen or ``hidden``, closes in (:meth:`gain`); never without the returns
        themselves (an estimate of r_c alone cannot vouch for a sweep). Whether a mover
        threatens is the caller's to check (:meth:`threatened`)."""
        if not (0.0 < abs(v) <= RETREAT_SPEED and omega != 0.0) or len(points) == 0:
            return False  # NaN fails too
        if not abs(omega) <= self.max_curvature * abs(v) * (1.0 + 1e-9):
            return False
        return self.gain(points, v, omega, hidden)[0]

    def motion(
        self,
        points: FloatArray,
        closest: float,
        tracks: Iterable[TrackedObstacle] = (),
        previous: tuple[float, float] = (0.0, 0.0),
        hidden: FloatArray | None = None,
    ) -> tuple[float, float]:
        """The ``(v, omega)`` to propose (robot frame; (0, 0): stay).

        Under a threat, or once the nearest return is :data:`RETREAT_CLEARANCE` beyond
        r_ES, :meth:`speed`'s straight motion. Otherwise, of the crawls the robot may
        make, each with its :meth:`gain` (how much further the nearest return gets over
        the lookahead), those that gain ground (:data:`GAIN_RATIO`): the ``previous``
        motion while it does (the safety layer stops a robot before it reverses or changes
        its arc: no dithering between two that gain alike); else the straight crawl that
        gains most; else, when none does (pinched at two corners), the arc
        (:data:`ARC_TURNS`; only when :attr:`max_curvature` allows arcs) that gains most
        without closing in on anything, seen or ``hidden`` (returns remembered in the
        lasers' blind spots). When none gains: inside r_ES, :meth:`speed`'s crawl (a
        return abeam, which it leaves behind); beyond r_ES, stay (the latch runs out)."""
        tracks = tuple(tracks)
        straight = self.speed(points, closest, tracks)
        if not closest < self.r_es + RETREAT_CLEARANCE or self.threatened(tracks):
            return straight, 0.0
        room = self.open_sides(points, tracks, False)
        options = [(side * RETREAT_SPEED, 0.0) for side in room]
        if self.max_curvature > 0.0 and len(points):
            options += [
                (side * RETREAT_SPEED, turn * k * self.max_curvature * RETREAT_SPEED)
                for side in SIDES
                for k in ARC_TURNS
                for turn in (1.0, -1.0)
            ]
        spread = 1.0 + self.max_curvature * math.hypot(self.length, self.width) / 2
        near = self._near(points, closest, spread)
        least = GAIN_RATIO * self.lookahead(RETREAT_SPEED)
        gains: dict[tuple[float, float], float] = {}
        for v, omega in options:
            admitted, gain = self.gain(near, v, omega, hidden if omega else None)
            if (omega == 0.0 or admitted) and gain >= least:  # straight: by its corridor
                gains[(v, omega)] = gain
        if previous in gains:
            return previous
        for arcs in (False, True):
            found = {m: g for m, g in gains.items() if (m[1] != 0.0) == arcs}
            if found:
                return max(found, key=lambda m: found[m])
        return (straight, 0.0) if closest < self.r_es else (0.0, 0.0)

    def _near(self, points: FloatArray, closest: float, spread: float) -> FloatArray:
        """The returns that can matter to a crawl's :meth:`gain`: those within reach of
        r_ES or of the nearest one once a corner has swept ``spread`` x the lookahead."""
        if len(points) == 0:
            return points
        reach = max(closest, self.r_es) + 2.0 * spread * self.lookahead(RETREAT_SPEED) + 0.01
        return points[footprint_distances(points, self.length, self.width) <= reach]
