"""Follow the operator: the follower controller of the collaborative mode (seed 000,
lines 1379-1452; Table 2.3 and the mode state machine of figure 2.21, lines 1543-1760).

The thesis (lines 1391-1397): "To determine the object to follow, the proposed method is
based on the laser range information. A search through the planar informations
determines the closest, most circular object available. This object will then be tracked
while the robot tries to keep a constant distance towards its center point." In the
thesis the operator stood in front of the robot before enabling the follower (lines
1608-1611); here the operator designates the person on the HUD: a point ``tap`` in the
airport frame A, and "closest" is closest to that point. The rest is not in the text (the
controller was AKKA's, on the ROS navigation stack) and is derived here:

* **Choosing the person** (:func:`choose_person`): among the laser tracks within
  ``pick_radius`` of the tap that can be a person (not a line nor a forbidden-zone wall,
  enclosing radius at most ``max_person_size``), the one minimising
  ``|p - tap| + circle_bonus (1 - roundness)``, roundness 1 for a RANSAC circle and 0 for
  a blob: the closest, most circular object.
* **Keeping its identity**: the tracker's id (:mod:`behaviours.laws.tracking`, whose
  prediction already carries a track through a crossing). When that id disappears (the
  tracker gave up on it, or split it), a new track is adopted if it lies within the
  re-association gate of the person's predicted position (:func:`reassociate`):
  ``|p - (p_last + v_last dt)| <= gate + max_person_speed dt``, ``dt`` the time since the
  person was last seen, the gate capped at ``max_gate``. A person unseen for ``lost_after``
  seconds is *lost*: the robot stops and the operator is asked to designate again.
* **The trail** (:class:`Trail`): breadcrumbs of the person's positions in A, one every
  ``crumb_spacing`` metres. The robot pursues the trail, not the person: a point
  ``lookahead`` metres down the trail from the robot's projection on it (pure pursuit,
  Coulter 1992). Where the person walked between parked vehicles, so does the robot; the
  straight line to the person would cut the corner into the vehicle.
* **The distance** kept is the *gap* from the robot's footprint (length x width at the
  axle centre M) to the person's edge, the quantity r_ES is measured on
  (:func:`footprint_gap`); the thesis's distance "towards its center point" is this gap
  plus the person's radius.
* **The speed** (:func:`follow_speed`): ``v = v_away + k (g - d)``, ``v_away`` the
  person's speed away from the robot (feed-forward, zero below ``min_person_speed``: the
  tracker's noise), ``g`` the regulated gap (:func:`regulated_gap`: the straight gap plus
  half the trail's detour, which matters round a corner only), clipped to
  ``[0, max_speed]`` (no reversing), then capped by the braking speed
  (:func:`braking_speed`) on the *straight* gap, so that braking at ``brake`` after one
  more period stops the robot outside ``r_es + margin`` even if the person stops dead:
  ``v dt + v^2 / (2 b) <= gap - r_es - margin``, the positive root
  ``v_b = -b dt + sqrt((b dt)^2 + 2 b s)``. A still person at ``g <= d`` gets ``v = 0``.
* **The turn** (:func:`pursuit_command`): pure pursuit of the trail point, the arc
  through it ``kappa = 2 sin(alpha) / l`` (``alpha`` its bearing in the robot frame, ``l``
  its distance), ``omega = v kappa``, the speed lowered where the arc would need more than
  ``max_omega``; beyond ``align_limit`` a skid-steer turns on the spot first.

Obstacle avoidance (Table 2.3 lists it beside the follower): static obstacles are the
trail's own (the robot goes where a person went); another person or vehicle crossing is
yielded to (:func:`yield_speed`: velocity obstacles along the trail, the robot slows or
waits rather than swerves off the path the operator took between parked vehicles); and
the safety layer is behind every command: e-stop at r_ES, slowdown within r_OA-trigger,
geofence, platform limits.

Frames: positions and velocities in A (x east, y north), the robot pose ``Pose2`` in A
(point M, heading). SI units.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from behaviours.laws.velocity_obstacles import MovingDisc, time_to_collision, velocity_vector
from executive.core.frames import FloatArray, Pose2, wrap_angle

SEARCHING = "searching"
FOLLOWING = "following"
UNSEEN = "unseen"
LOST = "lost"
IDLE = "idle"

PERSON_KINDS = ("circle", "blob")
"""Track kinds that can be a person (a line is a wall or a vehicle's side, a ``zone`` a
forbidden zone's edge)."""


@dataclass(frozen=True, slots=True)
class FollowParams:
    """Tuning of the follower (SI units). ``length``/``width``: the robot's footprint;
    ``r_es`` the mission's emergency-stop radius."""

    length: float = 1.4
    width: float = 1.0
    r_es: float = 0.6
    margin: float = 0.15
    """The robot stops at least this far outside r_es (m)."""
    max_speed: float = 1.5
    max_omega: float = 1.0
    brake: float = 0.5
    """Deceleration the braking cap assumes (m/s^2): half the platform's, so the safety
    layer's jerk-limited braking has room."""
    period: float = 0.02
    gain: float = 2.0
    """k: speed per metre of gap error (1/s)."""
    trail_weight: float = 0.5
    """Share of the trail's detour in the regulated gap (:func:`regulated_gap`)."""
    omega_gain: float = 2.0
    align_limit: float = math.radians(90.0)
    lookahead: float = 1.0
    crumb_spacing: float = 0.2
    max_crumbs: int = 600
    pick_radius: float = 1.5
    max_person_size: float = 0.6
    circle_bonus: float = 0.5
    """How much closer (m) a blob must be than a circle to be chosen instead."""
    gate: float = 0.8
    max_gate: float = 2.5
    max_person_speed: float = 2.5
    min_person_speed: float = 0.1
    lost_after: float = 1.0
    acquire_timeout: float = 2.0
    yield_horizon: float = 3.0
    """A crossing with another moving person or vehicle predicted within this time (s)
    slows the robot to the speed that lets it pass first (:func:`yield_speed`)."""
    yield_steps: int = 10

    def __post_init__(self) -> None:
        for name in ("length", "width", "max_speed", "max_omega", "brake", "period"):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"FollowParams.{name} must be > 0")
        if not (self.r_es >= 0.0 and self.margin >= 0.0):
            raise ValueError("FollowParams: r_es and margin must be >= 0")

    @property
    def min_distance(self) -> float:
        """The smallest gap the follower may be asked to keep (m): r_es + margin."""
        return self.r_es + self.margin


@dataclass(frozen=True, slots=True)
class PersonTrack:
    """A laser track that may be the person, in A: ``ident`` the tracker's id, ``kind``
    its shape (``circle``, ``blob``, ``line``, ``zone``), ``size`` its enclosing radius."""

    ident: int
    kind: str
    position: tuple[float, float]
    velocity: tuple[float, float] = (0.0, 0.0)
    size: float = 0.3


@dataclass(frozen=True, slots=True)
class FollowCommand:
    """One output of the follower: the command, the gap kept and why."""

    v: float
    omega: float
    gap: float
    state: str
    reason: str


# -- the person ---------------------------------------------------------------------------------
def could_be_person(track: PersonTrack, max_size: float) -> bool:
    """A circle or a blob no bigger than a person (enclosing radius ``max_size``)."""
    return track.kind in PERSON_KINDS and track.size <= max_size


def person_score(track: PersonTrack, tap: tuple[float, float], circle_bonus: float) -> float:
    """The thesis's "closest, most circular" as one number (smaller is better): distance
    to the designated point, plus ``circle_bonus`` for a shape that is not a circle."""
    roundness = 1.0 if track.kind == "circle" else 0.0
    return math.dist(track.position, tap) + circle_bonus * (1.0 - roundness)


def choose_person(
    tracks: Sequence[PersonTrack], tap: tuple[float, float], params: FollowParams
) -> PersonTrack | None:
    """The closest, most circular track within ``pick_radius`` of ``tap`` (seed lines
    1391-1395), or None."""
    best, best_score = None, math.inf
    for track in tracks:
        if not could_be_person(track, params.max_person_size):
            continue
        if math.dist(track.position, tap) > params.pick_radius:
            continue
        score = person_score(track, tap, params.circle_bonus)
        if score < best_score:
            best, best_score = track, score
    return best


def reassociation_gate(unseen: float, params: FollowParams) -> float:
    """Radius (m) around the predicted position within which a new track is taken to be
    the person, ``unseen`` s after they were last seen."""
    return min(params.max_gate, params.gate + params.max_person_speed * max(0.0, unseen))


def still_the_person(
    track: PersonTrack, last: PersonTrack, dt: float, params: FollowParams
) -> bool:
    """Whether the track that kept the person's id can still be them: person-like (not
    a line, no bigger than a person) and within :func:`reassociation_gate` of where they
    were heading. A tracker may hand an occluded person's id to the cluster next to them
    (a vehicle's side merged while someone crossed between): the id alone is not proof."""
    if not could_be_person(track, params.max_person_size):
        return False
    px = last.position[0] + last.velocity[0] * dt
    py = last.position[1] + last.velocity[1] * dt
    return math.dist(track.position, (px, py)) <= reassociation_gate(dt, params)


def reassociate(
    tracks: Sequence[PersonTrack],
    last: PersonTrack,
    unseen: float,
    params: FollowParams,
    exclude: frozenset[int] = frozenset(),
) -> PersonTrack | None:
    """The track that continues ``last`` (whose id has gone): the nearest person-like
    track to ``last``'s predicted position within :func:`reassociation_gate`; ids in
    ``exclude`` (tracks that already existed beside the person) never qualify."""
    dt = max(0.0, unseen)
    px = last.position[0] + last.velocity[0] * dt
    py = last.position[1] + last.velocity[1] * dt
    gate = reassociation_gate(unseen, params)
    best, best_d = None, math.inf
    for track in tracks:
        if track.ident in exclude or not could_be_person(track, params.max_person_size):
            continue
        d = math.dist(track.position, (px, py))
        if d <= gate and d < best_d:
            best, best_d = track, d
    return best


# -- the trail ----------------------------------------------------------------------------------
@dataclass
class Trail:
    """Breadcrumbs of the person's positions in A (one every ``spacing`` m), pruned behind
    the robot; :meth:`pursuit_point` is the point ``lookahead`` m down the trail."""

    spacing: float = 0.2
    max_crumbs: int = 600
    crumbs: list[tuple[float, float]] = field(default_factory=list)

    def clear(self) -> None:
        self.crumbs.clear()

    def add(self, p: tuple[float, float]) -> None:
        """Drop a crumb at ``p`` if the person moved ``spacing`` from the last one."""
        if not self.crumbs or math.dist(self.crumbs[-1], p) >= self.spacing:
            self.crumbs.append((float(p[0]), float(p[1])))
            if len(self.crumbs) > self.max_crumbs:
                del self.crumbs[0]

    def _polyline(self, person: tuple[float, float]) -> FloatArray:
        pts = [*self.crumbs]
        if not pts or math.dist(pts[-1], person) > 1e-6:
            pts.append((float(person[0]), float(person[1])))
        return np.asarray(pts, dtype=float)

    def project(
        self, robot: tuple[float, float], person: tuple[float, float], window: float
    ) -> tuple[int, FloatArray]:
        """The robot's projection on the trail (the nearest point of the segments that
        start within ``window`` m of trail length from its first crumb): (segment index,
        point). The window keeps a trail that comes back near itself (round a vehicle)
        from short-cutting to its later part."""
        pts = self._polyline(person)
        r = np.asarray(robot, dtype=float)
        if len(pts) == 1:
            return 0, pts[0]
        best_i, best_q, best_d, travelled = 0, pts[0], math.inf, 0.0
        for i in range(len(pts) - 1):
            a, b = pts[i], pts[i + 1]
            ab = b - a
            n2 = float(ab @ ab)
            s = 0.0 if n2 < 1e-12 else min(1.0, max(0.0, float((r - a) @ ab) / n2))
            q = a + s * ab
            d = float(np.hypot(*(r - q)))
            if d < best_d:
                best_i, best_q, best_d = i, q, d
            travelled += math.sqrt(n2)
            if travelled > window:
                break
        return best_i, best_q

    def prune(self, robot: tuple[float, float], person: tuple[float, float], window: float) -> None:
        """Forget the crumbs behind the robot's projection."""
        i, _ = self.project(robot, person, window)
        if i > 0:
            del self.crumbs[: min(i, len(self.crumbs))]

    def pursuit_point(
        self, robot: tuple[float, float], person: tuple[float, float], lookahead: float
    ) -> tuple[float, float]:
        """The point ``lookahead`` m down the trail from the robot's projection (the
        person's position when the trail is shorter)."""
        pts = self._polyline(person)
        i, q = self.project(robot, person, lookahead + 2.0)
        left = lookahead
        prev = q
        for b in pts[i + 1 :]:
            seg = float(np.hypot(*(b - prev)))
            if seg >= left:
                p = prev + (b - prev) * (left / seg)
                return float(p[0]), float(p[1])
            left -= seg
            prev = b
        return float(pts[-1][0]), float(pts[-1][1])

    def length(self, robot: tuple[float, float], person: tuple[float, float]) -> float:
        """Trail length (m) from the robot's projection to the person."""
        pts = self._polyline(person)
        i, q = self.project(robot, person, math.inf)
        rest = pts[i + 1 :]
        if not len(rest):
            return 0.0
        path = np.vstack((q, rest))
        return float(np.hypot(*np.diff(path, axis=0).T).sum())


# -- the command --------------------------------------------------------------------------------
def footprint_gap(
    robot: Pose2, person: tuple[float, float], radius: float, params: FollowParams
) -> float:
    """Distance (m) from the robot's footprint (length x width at M) to the person's edge,
    a circle of ``radius`` at ``person`` in A; negative when they overlap."""
    x, y = robot.inverse().apply(np.asarray(person, dtype=float))
    dx = max(abs(float(x)) - params.length / 2.0, 0.0)
    dy = max(abs(float(y)) - params.width / 2.0, 0.0)
    return math.hypot(dx, dy) - radius


def braking_speed(room: float, brake: float, period: float) -> float:
    """The largest v with ``v period + v^2 / (2 brake) <= room``: one more period at v,
    then braking at ``brake``, stops within ``room`` (m); 0 when there is no room."""
    if not room > 0.0:
        return 0.0
    bd = brake * period
    return -bd + math.sqrt(bd * bd + 2.0 * brake * room)


def regulated_gap(gap: float, detour: float, trail_weight: float) -> float:
    """The gap the speed law regulates: the straight gap plus ``trail_weight`` times the
    trail's detour (its length from the robot to the person less the straight distance,
    >= 0). Round a corner the straight gap shrinks while the gap along the trail does not;
    regulating the straight one alone stops the robot at the corner and it falls behind
    after it, regulating the trail alone drives it into the corner. Their mean
    (``trail_weight`` 0.5) splits the difference."""
    return gap + trail_weight * max(0.0, detour)


def follow_speed(
    gap: float, distance: float, v_away: float, params: FollowParams, detour: float = 0.0
) -> float:
    """``v = clip(v_away + k (g - distance), 0, max_speed)``, ``g`` the
    :func:`regulated_gap`, capped by the braking speed over the room the *straight* gap
    leaves before ``r_es + margin``."""
    g = regulated_gap(gap, detour, params.trail_weight)
    v = min(params.max_speed, max(0.0, v_away + params.gain * (g - distance)))
    cap = braking_speed(gap - params.min_distance, params.brake, params.period)
    return min(v, cap)


def speed_away(
    robot: Pose2, person: tuple[float, float], velocity: tuple[float, float], params: FollowParams
) -> float:
    """The person's speed away from the robot (m/s, >= 0; 0 below ``min_person_speed``)."""
    if math.hypot(*velocity) < params.min_person_speed:
        return 0.0
    dx, dy = person[0] - robot.x, person[1] - robot.y
    n = math.hypot(dx, dy)
    if n < 1e-9:
        return 0.0
    return max(0.0, (velocity[0] * dx + velocity[1] * dy) / n)


def pursuit_command(
    robot: Pose2, target: tuple[float, float], v: float, params: FollowParams
) -> tuple[float, float]:
    """Pure pursuit of ``target`` (Coulter 1992): the arc through it has curvature
    ``kappa = 2 sin(alpha) / l``, ``alpha`` its bearing and ``l`` its distance, and
    ``omega = v kappa``; when that exceeds ``max_omega`` the speed is lowered to keep the
    arc (``v = max_omega / |kappa|``). Beyond ``align_limit`` the robot turns on the spot
    (``omega = k_omega alpha``, clipped) before it drives."""
    dx, dy = target[0] - robot.x, target[1] - robot.y
    dist = math.hypot(dx, dy)
    if dist < 1e-6:
        return 0.0, 0.0
    alpha = wrap_angle(math.atan2(dy, dx) - robot.theta)
    if abs(alpha) > params.align_limit:
        omega = min(params.max_omega, max(-params.max_omega, params.omega_gain * alpha))
        return 0.0, omega
    kappa = 2.0 * math.sin(alpha) / dist
    if abs(v * kappa) > params.max_omega:
        v = params.max_omega / abs(kappa)
    return v, v * kappa


def yield_speed(
    robot: Pose2,
    v: float,
    omega: float,
    movers: Sequence[MovingDisc],
    params: FollowParams,
) -> tuple[float, float]:
    """Obstacle avoidance on the trail (Table 2.3): the largest speed, ``v`` scaled down
    in ``yield_steps`` steps with the arc kept (``omega`` scaled alike), whose velocity
    obstacles [Fiorini and Shiller 1998; :mod:`behaviours.laws.velocity_obstacles`]
    against the other movers are clear for ``yield_horizon`` s. The discs are the movers
    grown by the robot's circumscribed radius plus r_ES (the e-stop's distance), so a
    crossing the robot yields to stays outside r_ES. The robot stays on the trail (where
    the operator walked, between parked vehicles): it waits rather than swerves. When no
    speed is clear (a mover heading at the robot), the one with the latest contact,
    the slowest among equals."""
    if v <= 0.0 or not movers:
        return v, omega
    radius = 0.5 * math.hypot(params.length, params.width) + params.r_es
    xy = np.array([robot.x, robot.y])
    best, latest = (0.0, 0.0), -1.0
    for k in range(params.yield_steps, -1, -1):
        share = k / params.yield_steps
        vk, wk = v * share, omega * share
        u = velocity_vector(robot.theta, vk, wk, 0.5)
        ttc = min(time_to_collision(xy, u, m, radius) for m in movers)
        if ttc >= params.yield_horizon:
            return vk, wk
        if ttc >= latest:  # ties go to the slower one (k falls)
            best, latest = (vk, wk), ttc
    return best


# -- the follower -------------------------------------------------------------------------------
class OperatorFollower:
    """The follower: choose the person at the designated point, keep them, lay the trail,
    and command the robot along it at the set distance.

    :meth:`designate` starts (or restarts) on a request; :meth:`observe` takes the tracks
    of one scan (in A) with the robot's pose; :meth:`command` gives (v, omega). ``state``
    is ``idle``, ``searching`` (no person at the point yet), ``following``, ``unseen``
    (the person's track is gone for less than ``lost_after``: the robot goes on to where
    they were last seen) or ``lost`` (stopped until designated again). ``events`` keeps
    (t, kind, text) for every acquisition, re-association and loss.
    """

    def __init__(self, params: FollowParams | None = None) -> None:
        self.params = params or FollowParams()
        self.trail = Trail(self.params.crumb_spacing, self.params.max_crumbs)
        self.state = IDLE
        self.tap: tuple[float, float] | None = None
        self.distance = self.params.min_distance
        self.person: PersonTrack | None = None
        self.last_seen = 0.0
        self.since = 0.0
        self.now = 0.0
        self.reason = "no person designated"
        self.events: list[tuple[float, str, str]] = []
        self._others: dict[int, tuple[float, float]] = {}
        """The other tracks beside the person when last seen: id -> position (A)."""
        self.movers: tuple[MovingDisc, ...] = ()
        """The other moving tracks of the last scan (A): :func:`yield_speed`."""

    @property
    def track_id(self) -> int | None:
        return self.person.ident if self.person is not None else None

    def designate(self, t: float, tap: tuple[float, float], distance: float) -> None:
        """A new request: follow the person at ``tap`` (A) at a gap of ``distance`` m
        (raised to ``r_es + margin`` if smaller)."""
        self.tap = (float(tap[0]), float(tap[1]))
        self.distance = max(float(distance), self.params.min_distance)
        self.person = None
        self.trail.clear()
        self.state, self.since, self.now = SEARCHING, t, t
        self.reason = f"searching near ({tap[0]:.1f}, {tap[1]:.1f})"

    def cancel(self) -> None:
        """No request any more (hand-back)."""
        self.state, self.tap, self.person = IDLE, None, None
        self.trail.clear()
        self.reason = "no person designated"

    def _event(self, t: float, kind: str, text: str) -> None:
        self.events.append((t, kind, text))

    def _lose(self, t: float, why: str) -> None:
        self.state = LOST
        self.reason = f"operator lost: {why}: designate again"
        self._event(t, "lost", self.reason)

    def observe(self, t: float, robot: Pose2, tracks: Sequence[PersonTrack]) -> None:
        """Update the person from one set of tracks (in A) seen at ``t``."""
        p = self.params
        self.now = t
        if self.state in (IDLE, LOST) or self.tap is None:
            return
        if self.person is None:
            found = choose_person(tracks, self.tap, p)
            if found is None:
                if t - self.since > p.acquire_timeout:
                    self._lose(t, f"no person within {p.pick_radius:.1f} m of the point")
                return
            self._adopt(t, found, tracks, "acquired")
            return
        same = next((k for k in tracks if k.ident == self.person.ident), None)
        if same is not None and not still_the_person(same, self.person, t - self.last_seen, p):
            if self.state == FOLLOWING:  # once, not every scan
                self._event(t, "id taken", f"track {same.ident} is no longer person-like here")
            same = None
        if same is None:
            unseen = t - self.last_seen
            found = reassociate(tracks, self.person, unseen, p, self._neighbours(tracks, unseen))
            if found is not None:
                self._event(t, "re-associated", f"track {self.person.ident} -> {found.ident}")
                self._adopt(t, found, tracks, "re-associated")
                return
            if unseen > p.lost_after:
                self._lose(t, f"track {self.person.ident} not seen for {unseen:.1f} s")
            else:
                self.state = UNSEEN
                self.reason = f"track {self.person.ident} not seen for {unseen:.1f} s"
            return
        self._adopt(t, same, tracks, "")

    def _neighbours(self, tracks: Sequence[PersonTrack], unseen: float) -> frozenset[int]:
        """The ids that are still the neighbours they were beside the person: each within
        :func:`reassociation_gate` of where it was. An id that jumped farther is no longer
        that neighbour: the tracker swapped it (a person's id handed to a parked car's
        blob and the car's id to the person, as they passed each other in the scan), and
        it may be the person again."""
        gate = reassociation_gate(unseen, self.params)
        return frozenset(
            k.ident
            for k in tracks
            if k.ident in self._others and math.dist(k.position, self._others[k.ident]) <= gate
        )

    def _adopt(self, t: float, track: PersonTrack, tracks: Sequence[PersonTrack], why: str) -> None:
        if why == "acquired":
            off = math.dist(track.position, self.tap or track.position)
            self._event(t, why, f"track {track.ident}, {off:.2f} m from the designated point")
        self.person = track
        self.last_seen = t
        self.state = FOLLOWING
        self._others = {k.ident: k.position for k in tracks if k.ident != track.ident}
        self.movers = tuple(
            MovingDisc(k.position, k.velocity, k.size)
            for k in tracks
            if k.ident != track.ident and math.hypot(*k.velocity) >= self.params.min_person_speed
        )
        self.trail.add(track.position)
        self.reason = f"track {track.ident}"

    def command(self, robot: Pose2) -> FollowCommand:
        """(v, omega) along the trail at the set gap; zero unless following (or unseen)."""
        p = self.params
        person = self.person
        if self.state not in (FOLLOWING, UNSEEN) or person is None:
            return FollowCommand(0.0, 0.0, math.inf, self.state, self.reason)
        radius = min(max(person.size, 0.1), p.max_person_size)
        gap = footprint_gap(robot, person.position, radius, p)
        here = (robot.x, robot.y)
        self.trail.prune(here, person.position, p.lookahead + 2.0)
        target = self.trail.pursuit_point(here, person.position, p.lookahead)
        seen = self.state == FOLLOWING
        v_away = speed_away(robot, person.position, person.velocity, p) if seen else 0.0
        detour = self.trail.length(here, person.position) - math.dist(here, person.position)
        v = follow_speed(gap, self.distance, v_away, p, detour)
        v, omega = pursuit_command(robot, target, v, p)
        free = v
        v, omega = yield_speed(robot, v, omega, self.movers, p)
        why = f"{self.reason}: gap {gap:.2f} m (set {self.distance:.2f} m)"
        if v < free:
            why += f", yielding to a crossing ({v:.2f} of {free:.2f} m/s)"
        return FollowCommand(v, omega, gap, self.state, why)
