"""The runtime safety layer: the last word on every command sent (ARCHITECTURE.md §3, §8).

The behaviour tree proposes one :class:`VelocityCommand` per tick; :meth:`SafetyLayer.filter`
turns it into the command that is actually sent. The layer is pure Python (numpy, shapely):
no py_trees, no simulator, so it can be tested on its own.

Order of the checks (each later rule only ever sees what the earlier ones let through, so
the e-stop, faults and the geofence always win over the tree):

0. **Operator reset** (``reset_requested``, a level: honoured on every call where it is
   set and the conditions allow). It clears a fault signalled on an *earlier* call, releases
   a bumper latch once the bumper is released, and releases an obstacle latch at once if
   the zone is clear (otherwise the obstacle latch stays, see 2.). A reset refused because
   a bumper is still pressed is logged once per request (on its rising edge).
1. **Non-finite command**: a NaN or infinite v, omega or pan/tilt rate is a controller bug;
   it is handled like :meth:`SafetyLayer.fault` (zero, ``fault-stop``, latched until reset).
2. **E-stop latch**: latched when ``obstacles.closest < r_es`` (a NaN distance counts as
   inside) or a bumper is pressed. A latch caused only by obstacles releases by itself
   once ``closest >= r_es`` has been observed for ``safety.estop_hold`` seconds. Once a
   bumper has been pressed the latch releases only by an operator reset, and only while
   the bumper is released; if an obstacle is still inside r_es at that moment the latch
   becomes an obstacle latch. While latched every command is exactly zero, with one
   exception: an *obstacle* latch (not a bumper, not the operator's e-stop) admits a
   command shaped as a straight retreat (:mod:`behaviours.laws.retreat`): omega exactly
   0, ``0 < |v| <=`` :data:`~behaviours.laws.retreat.RETREAT_SPEED` (a crawl), or up
   to twice the speed of a mover that closes in; under such a threat only a retreat
   that fares no worse than standing still against every mover
   (:meth:`~behaviours.laws.retreat.Retreat.no_worse`); from rest or continuing one (any
   other command is stopped as before; a robot still turning is stopped first, so that
   the output is straight from the retreat's first tick), into a corridor the lasers
   cover and that holds no return inside r_es (beyond the crawl: r_es plus the
   retreat's stopping distance) and, while no mover threatens, no tracked mover about
   to enter it within :data:`~behaviours.laws.retreat.THREAT_HORIZON` (under a threat
   the movers are judged by their predictions, as above), with no fault and no stale
   data: the rule the tree proposes by
   (:meth:`~behaviours.laws.retreat.Retreat.open_sides`), so that what the tree proposes
   the layer lets through. A robot pinched at two corners, where
   no straight crawl gains ground, may instead take an *arc* at a crawl
   (:meth:`~behaviours.laws.retreat.Retreat.arc_admitted`): ``|v| <=`` the crawl,
   curvature within the platform's retreat arcs, no return (seen, or remembered in the
   lasers' blind pockets beside the body, ``Obstacles.hidden``) closing in or coming
   inside r_es along it over its stopping distance, no mover threatening, from rest or
   on the same arc; its speed and yaw rate are then ramped together on that arc (rule
   4 scales both), and a geofence rule that would bend it stops the robot instead. The
   retreat never brings the footprint closer to anything inside r_es; it then goes
   through rules 4-7 like any command (``estop-retreat`` when one starts).
3. **Faults and stale data**: a :meth:`fault` (an exception in a tick, a lost bus, a
   non-finite command) stops the robot until an operator reset. Every sensor is watched
   (:mod:`behaviours.laws.freshness`: a sensor is stale when its last *new* reading is
   older than its limit; a camera that repeats its image content with fresh stamps
   delivers nothing new). What happens depends on what the sensor is for:

   * safe motion depends on it — each laser (no scan, or a scan older than
     ``stale_after``, default three periods of the slowest laser; every scan in the frame
     is checked too), the wheel encoders, the IMU, the obstacle estimate (missing or
     older than ``stale_after``) and the pose estimate (missing or non-finite): the robot
     is stopped while it lasts (``stale-sensor``, then ``sensor-fresh``), the reason
     naming each stale sensor and the time of its last fresh reading;
   * only the mission's quality depends on it — each camera, each pan-tilt unit's angles,
     the GPS: ``sensor-degraded`` / ``sensor-recovered``, one event per sensor, the robot
     keeps going (obstacles are seen by the lasers, the pose is carried by odometry). A
     unit whose angles are stale is not driven blind: its pan/tilt rates are zeroed.

   Every stale stretch of every sensor is kept in :attr:`SafetyLayer.sensor_health`
   (:meth:`SafetyLayer.stale_intervals`) for the report.
4. **Slowdown zone** (like Nav2's collision monitor, with the direction of travel of
   speed-and-separation monitoring): the requested speed is scaled by
   ``s = clamp((r_d - r_es) / (r_oa - r_es), floor, 1)`` where r_d is the distance from
   the footprint to the nearest laser return *in the corridor the robot drives into*: ahead
   of the axle for v > 0, behind it for v < 0, and within half the robot's width + r_es
   of its axis (r_c itself when only r_c and its bearing are known and the bearing lies
   that way). A tracked mover that will enter that corridor within ``mover_horizon``
   (placed across it by its returns, :func:`~behaviours.laws.retreat.enters_corridor`)
   (default 3 s) at its tracked velocity counts as in it, with its current clearance: a
   walker about to cross the robot's way slows it before stepping in front of it.
   Driving away from an obstacle, or sideways past a static one, is not slowed, so
   avoidance can outpace or sidestep an obstacle closing in.
   The floor (``slowdown_floor``, default 0.2) keeps obstacle avoidance able to creep round
   an obstacle; the e-stop takes over below r_es anyway. Only v is scaled; omega and the
   pan/tilt rates are not.
5. **Magnitude limits**: |v| <= max_speed, |omega| <= max_angular_speed, each pan/tilt rate
   within its camera's pan_rate / tilt_rate; a rate for an unknown unit is dropped. Every
   output names every platform unit (zero when the tree gave no rate).
6. **Rate limits**, with respect to the previously *sent* command (after a forced stop,
   the speed the wheels measure: see below) and the fixed ``period``:
   |dv/dt| <= max_acceleration, |d2v/dt2| <= max_jerk (v follows a jerk-limited profile
   that never overshoots its target when that can be avoided), |domega/dt| <=
   max_angular_acceleration. Pan/tilt rates have no rate limit.
7. **Geofence** (forbidden zones are never entered), from the estimated pose and the
   robot's footprint (length x width rectangle centred at the axle). Airport-frame zones
   are used as they are, aircraft-frame zones through the current placement
   (:meth:`set_placement`). For a candidate output o, S(o) is the distance any footprint
   point can travel during this period and during the full stop that follows it when the
   layer brakes at its own limits (jerk-limited v, acceleration-limited omega, corners at
   radius r_corner): ``S = (|v| + r_corner |omega|) dt + sweep_v(v, a) + r_corner sweep_w``.
   This is the discrete, jerk-aware form of ``v_allowed = sqrt(2 a max(0, d - margin))``
   (which it becomes as jerk -> inf and dt -> 0).

   * soft rule, per zone and directional: a candidate that brings the footprint closer to
     a zone (predicted over a short horizon for its v and omega) must keep
     ``S <= d_zone - geofence_margin``; otherwise it is blended towards the braking step.
     Inside the margin a motion that brings the footprint closer is refused: a variant
     without its rotation (or without its translation) is used if that one does not
     approach, else the robot brakes. Motions that increase or keep the distance are
     allowed, so the robot can always back out.
   * hard rule, isotropic: every output keeps ``S <= d_min - geofence_buffer``. This is an
     invariant: if it held on the previous period, braking at the limits keeps it. It can
     only be lost by a jump (pose estimate, placement, a start inside the buffer); then
     the robot may still back out at a crawl (``S <= escape_sweep``) or brake at its
     limits when that stops it before the zone, and otherwise it is stopped at once
     (``geofence-stop``, an emergency).

   The rules trust the pose estimate and assume the base follows the commands: the buffer
   (default 0.05 m) absorbs estimate jitter from one period to the next, the margin
   (default 0.3 m) the base's tracking lag and the estimate's bias. A footprint that
   overlaps a zone has a negative clearance, ``-sqrt(overlap area)``, so backing out is a
   motion that increases it. Zones further than a few metres (bounding boxes) cost
   nothing; shapely is called once per period near a zone, twice when a rule may bind.

**Stopping is always possible**: an e-stop, a fault, stale data or a geofence emergency
outputs zero at once, even when that exceeds the deceleration (and jerk) limits: the
platform brakes. Every other slowdown (slowdown zone, geofence slow/stop) respects the
limits. After a stop the limits apply again from the speed the wheels measure when the
robot still rolls the way the next command asks (the base brakes at its own limits; a
command ramped up from rest instead braked a robot backing away from a chaser to a crawl
and let the chaser reach it: A320 busy-apron campaign episode 69), from rest otherwise.

**Events** (:attr:`SafetyLayer.events`, append-only, drained by the runtime): one per change
of state, not one per tick: ``estop-latched`` / ``estop-released`` / ``estop-reset`` /
``reset-refused`` / ``estop-retreat``, ``fault-stop``, ``stale-sensor`` / ``sensor-fresh``,
``sensor-degraded`` / ``sensor-recovered``, ``slowdown`` /
``slowdown-end``, ``geofence-slow`` / ``geofence-stop`` / ``geofence-clear``, ``limit`` /
``limit-end`` (only the magnitude limits: the tree asked for more than the platform can
do; acceleration and jerk smoothing is normal and not logged). A state that eases off
(geofence, slowdown, limit) is reported only after it stayed eased for ``event_hold``
seconds, so riding a boundary does not flood the log.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Hashable, Iterable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np
import shapely
from shapely.geometry import Point
from shapely.geometry.base import BaseGeometry

from behaviours.laws import estop
from behaviours.laws.estop import OPERATOR as OPERATOR_ESTOP
from behaviours.laws.estop import EStopLatch
from behaviours.laws.freshness import Freshness
from behaviours.laws.localisation import wheel_odometry
from behaviours.laws.retreat import SLOWDOWN_FLOOR, Retreat, corridor_room, slowdown_scale
from executive.core.frames import AircraftPlacement, FloatArray
from executive.core.model import Circle, ForbiddenZone, Frame, Mission
from executive.core.records import (
    Obstacles,
    PanTiltRate,
    PoseEstimate,
    SensorFrame,
    VelocityCommand,
    camera_ids,
)

# event kinds
ESTOP_LATCHED = "estop-latched"
ESTOP_RELEASED = "estop-released"
ESTOP_RESET = "estop-reset"
RESET_REFUSED = "reset-refused"
ESTOP_RETREAT = "estop-retreat"
_LATCH_EVENTS = {
    estop.LATCHED: ESTOP_LATCHED,
    estop.RELEASED: ESTOP_RELEASED,
    estop.RESET: ESTOP_RESET,
    estop.RESET_REFUSED: RESET_REFUSED,
}
FAULT_STOP = "fault-stop"
STALE_SENSOR = "stale-sensor"
SENSOR_FRESH = "sensor-fresh"
SENSOR_DEGRADED = "sensor-degraded"
SENSOR_RECOVERED = "sensor-recovered"
SLOWDOWN = "slowdown"
SLOWDOWN_END = "slowdown-end"
GEOFENCE_SLOW = "geofence-slow"
GEOFENCE_STOP = "geofence-stop"
GEOFENCE_CLEAR = "geofence-clear"
LIMIT = "limit"
LIMIT_END = "limit-end"


_CIRCLE_SEGMENTS = 16  # per quarter circle; zone circles are circumscribed, never smaller
_TOL = 1e-9


@dataclass(frozen=True, slots=True)
class SafetyEvent:
    """A change of the safety layer's state at ``stamp``, with its reason and value."""

    stamp: float
    kind: str
    reason: str
    value: float | None = None


@dataclass(frozen=True, slots=True)
class SafetyStatus:
    """The layer's state after the last :meth:`SafetyLayer.filter`.

    ``stopped_reason`` says why the layer holds (or brings) the robot to a stop: e-stop,
    fault, stale data or the geofence; None while the tree's command goes through
    (possibly limited). ``speed_scale`` is the slowdown-zone factor (1 outside it).
    ``geofence_distance`` is the footprint's clearance to the nearest forbidden zone
    (negative: overlapping it; inf: no zone or no pose; beyond a few metres only a lower
    bound) and ``geofence_zone`` that zone. ``forced_stop`` is True when the output was
    forced to zero regardless of the deceleration limits (e-stop, fault, stale data,
    geofence emergency). ``retreating``: the e-stop is latched by an obstacle and the
    output is a retreat from it (rule 2), not a stop.
    """

    estop_latched: bool = False
    estop_cause: str | None = None
    stopped_reason: str | None = None
    speed_scale: float = 1.0
    geofence_distance: float = math.inf
    geofence_zone: str | None = None
    forced_stop: bool = False
    retreating: bool = False


DEFAULT_STALE_LIMITS: Mapping[str, float] = MappingProxyType(
    {"wheels": 0.2, "imu": 0.2, "gps": 3.0}
)
"""Stale limits (s) of the sensors whose rate the platform does not give: 10 periods of
50 Hz encoders and an IMU (20 cm of blind odometry at 1 m/s), 3 periods of a 1 Hz GPS.
Lasers use ``stale_after``; cameras and pan-tilt units three periods of their camera."""


@dataclass(frozen=True, slots=True)
class StaleInterval:
    """One stretch of time a sensor was stale.

    ``since`` is the stamp of its last fresh reading before the stretch (None: it had
    never delivered one): data newer than that was missing from then on; ``detected``
    when the layer declared it stale (``since`` + its limit, to one tick); ``until`` when
    fresh data came back (None: still stale at the end of the run). ``reason`` is the
    event's reason.
    """

    since: float | None
    detected: float
    until: float | None = None
    reason: str = ""

    def duration(self, end: float, start: float = 0.0) -> float:
        """Seconds without fresh data: from ``since`` (``start`` when None) to ``until``
        (``end`` while still stale)."""
        first = self.since if self.since is not None else start
        last = self.until if self.until is not None else end
        return max(0.0, last - first)


@dataclass(slots=True)
class SensorHealth:
    """What the layer knows of one sensor.

    ``sensor`` is its key (``laser:<id>``, ``camera:<camera>``, ``ptu:<unit>``,
    ``wheels``, ``imu``, ``gps``, ``pose``, ``obstacles``), ``label`` how messages name
    it, ``stops`` whether it being stale stops the robot, ``limit`` its stale limit (s),
    ``intervals`` its stale stretches in order (the last one open while stale).
    """

    sensor: str
    label: str
    stops: bool
    limit: float
    intervals: list[StaleInterval] = field(default_factory=list)

    @property
    def stale(self) -> bool:
        return bool(self.intervals) and self.intervals[-1].until is None

    def stale_seconds(self, end: float, start: float = 0.0) -> float:
        """Total time without fresh data up to ``end`` (see :meth:`StaleInterval.duration`)."""
        return sum(i.duration(end, start) for i in self.intervals)


# -- motion limits --------------------------------------------------------------------------------
class MotionLimits:
    """Jerk-limited forward speed and acceleration-limited yaw rate, one period at a time.

    ``step_v`` moves (v, a) towards a target speed: the acceleration changes by at most
    ``J dt`` per period and stays within ``+-A``, and it is chosen as large as possible
    while the speed can still reach the target without overshooting it (ramping the
    acceleration back to zero at the jerk limit). ``linear_sweep`` and ``angular_sweep``
    are the exact distances (angles) covered by the braking sequence that ``step_v`` /
    ``step_w`` produce with a zero target: the geofence relies on them.
    """

    def __init__(
        self,
        period: float,
        max_speed: float,
        max_acceleration: float,
        max_jerk: float,
        max_angular_speed: float,
        max_angular_acceleration: float,
    ) -> None:
        if not period > 0.0:
            raise ValueError(f"period must be positive, got {period}")
        self.dt = float(period)
        self.v_max = float(max_speed)
        self.a_max = float(max_acceleration)
        self.w_max = float(max_angular_speed)
        self.alpha_max = float(max_angular_acceleration)
        # change of acceleration per period; a jerk limit looser than 2A/dt never binds
        self.da = min(max_jerk * self.dt, 2.0 * self.a_max)
        if not (self.da > 0.0 and max_angular_acceleration > 0.0):
            raise ValueError("the acceleration and jerk limits must be positive")
        self.max_jerk = self.da / self.dt
        self.dw = self.alpha_max * self.dt
        self._v_land = self.reach(self.a_max)
        # sweep_bound: the sweep from full forward acceleration on a grid of speeds
        self._grid = max(self.v_max, 1e-3) / 200.0
        self._bound = [self.linear_sweep(k * self._grid, self.a_max) for k in range(203)]

    def reach(self, a: float) -> float:
        """Speed change while applying ``a >= 0`` now, then ramping it down to zero."""
        s = self.da
        n = max(0, math.ceil(a / s - 1e-12) - 1)
        return self.dt * ((n + 1) * a - s * n * (n + 1) / 2.0)

    def a_star(self, e: float) -> float:
        """The largest ``a >= 0`` with ``reach(a) <= e`` (e >= 0)."""
        if e <= 0.0:
            return 0.0
        s, dt = self.da, self.dt
        q = e / (dt * s)
        n = max(0, math.ceil(math.sqrt(2.0 * q + 0.25) - 1.5))
        while n > 0 and q <= n * (n + 1) / 2.0:
            n -= 1
        while q > (n + 1) * (n + 2) / 2.0:
            n += 1
        return (e / dt + s * n * (n + 1) / 2.0) / (n + 1)

    def step_v(self, v: float, a: float, target: float) -> tuple[float, float]:
        """One period of the jerk-limited speed profile: (v, a) -> (v', a')."""
        lo = max(-self.a_max, a - self.da)
        hi = min(self.a_max, a + self.da)
        e = target - v
        want = self.a_star(e) if e >= 0.0 else -self.a_star(-e)
        a_new = min(max(want, lo), hi)
        v_new = v + a_new * self.dt
        if abs(v_new - target) <= 1e-12:
            v_new = target
        return v_new, a_new

    def step_w(self, w: float, target: float) -> float:
        """One period of the acceleration-limited yaw rate."""
        return w + min(max(target - w, -self.dw), self.dw)

    def linear_sweep(self, v: float, a: float) -> float:
        """Distance travelled after this period while braking to rest with ``step_v``.

        The same sequence as repeated ``step_v(v, a, 0)``, with its regular stretches (the
        jerk ramp, the constant deceleration, the final landing) summed in closed form.
        """
        if v < 0.0 or (v == 0.0 and a < 0.0):
            v, a = -v, -a
        dt, big_a, s = self.dt, self.a_max, self.da
        v_land = self._v_land
        v_ramp = v_land + big_a * dt
        ceil, sqrt = math.ceil, math.sqrt
        total = 0.0
        for _ in range(100000):
            if v > v_ramp and a > -big_a:
                # ramp the acceleration down towards -A while the landing cannot bind
                m = ceil((a + big_a) / s - 1e-12) - 1
                if m >= 1:
                    v_end = v + dt * (m * a - s * m * (m + 1) / 2.0)
                    if v_end > v_ramp:
                        total += dt * (m * v + dt * (m * a * (m + 1) / 2.0 - s * _tri2(m)))
                        v, a = v_end, a - m * s
            if a == -big_a and v > v_land:
                k = math.floor((v - v_land) / (big_a * dt))
                if k >= 1:
                    total += dt * (k * v - big_a * dt * k * (k + 1) / 2.0)
                    v -= k * big_a * dt
            # one step of step_v(v, a, 0), or the whole landing when it is reachable
            lo = a - s if a - s > -big_a else -big_a
            hi = a + s if a + s < big_a else big_a
            e = v if v >= 0.0 else -v
            mag = 0.0
            n = 0
            if e > 0.0:  # a_star(e), inlined
                q = e / (dt * s)
                n = max(0, ceil(sqrt(2.0 * q + 0.25) - 1.5))
                while n > 0 and q <= n * (n + 1) / 2.0:
                    n -= 1
                while q > (n + 1) * (n + 2) / 2.0:
                    n += 1
                mag = (e / dt + s * n * (n + 1) / 2.0) / (n + 1)
            want = -mag if v > 0.0 else mag
            if lo <= want <= hi:
                # the landing: accelerations mag - k s while positive, speeds reach(...)
                for k in range(1, n + 1):
                    b = mag - k * s
                    nb = n - k
                    total += dt * dt * ((nb + 1) * b - s * nb * (nb + 1) / 2.0)
                break
            a = want if want > lo else lo
            if a > hi:
                a = hi
            v += a * dt
            total += (v if v >= 0.0 else -v) * dt
        return total

    def sweep_bound(self, v: float) -> float:
        """An upper bound of ``linear_sweep(v, a)`` for any ``|a| <= A``, from a table.

        The sweep grows with the speed and with the acceleration in the direction of
        motion (checked by the tests), so the entry at full acceleration and the next grid
        speed bounds it.
        """
        k = math.ceil(abs(v) / self._grid - 1e-12)
        if k < len(self._bound):
            return self._bound[k] + 1e-9
        return self.linear_sweep(abs(v), self.a_max) + 1e-9

    def angular_sweep(self, w: float) -> float:
        """Angle turned after this period while braking the yaw rate to rest."""
        w = abs(w)
        if w <= 0.0:
            return 0.0
        n = math.ceil(w / self.dw - 1e-12) - 1
        return self.dt * (n * w - self.dw * n * (n + 1) / 2.0)


def _tri2(m: int) -> float:
    """sum_{j=1..m} j (j + 1) / 2."""
    return m * (m + 1) * (m + 2) / 6.0


# -- geofence geometry ----------------------------------------------------------------------------
class _ZoneSet:
    """Forbidden zones in the airport frame as (prepared) shapely geometries."""

    def __init__(self, zones: Iterable[ForbiddenZone], placement: AircraftPlacement) -> None:
        self.ids: list[str] = []
        geoms: list[BaseGeometry] = []
        for zone in zones:
            geoms.append(_zone_geometry(zone, placement))
            self.ids.append(zone.id)
        self.geoms = np.array(geoms, dtype=object)
        shapely.prepare(self.geoms)
        self.bounds = shapely.bounds(self.geoms) if geoms else np.zeros((0, 4))

    def __len__(self) -> int:
        return len(self.ids)


def _zone_geometry(zone: ForbiddenZone, placement: AircraftPlacement) -> BaseGeometry:
    shape = zone.shape
    to_a = zone.frame == Frame.AIRCRAFT
    if isinstance(shape, Circle):
        cx, cy = shape.cx, shape.cy
        if to_a:
            cx, cy = (float(c) for c in placement.to_airport_xy((cx, cy)))
        # circumscribe the circle so the polygon contains it
        radius = shape.radius / math.cos(math.pi / (4 * _CIRCLE_SEGMENTS))
        return Point(cx, cy).buffer(radius, quad_segs=_CIRCLE_SEGMENTS)
    pts = np.asarray(shape.points, dtype=float)
    if to_a:
        pts = placement.to_airport_xy(pts)
    return shapely.polygons(pts)


def footprint_corners(length: float, width: float) -> FloatArray:
    """The closed ring of the footprint rectangle in the robot frame (5, 2)."""
    hl, hw = length / 2.0, width / 2.0
    return np.array([[hl, hw], [-hl, hw], [-hl, -hw], [hl, -hw], [hl, hw]])


def predict_pose(x: float, y: float, th: float, v: float, w: float, h: float) -> tuple:
    """The unicycle pose after ``h`` seconds at constant (v, w), integrated exactly."""
    if abs(w) < 1e-9:
        return x + v * h * math.cos(th), y + v * h * math.sin(th), th
    r = v / w
    th2 = th + w * h
    return x + r * (math.sin(th2) - math.sin(th)), y - r * (math.cos(th2) - math.cos(th)), th2


class _Candidate:
    """An output under consideration: forward speed and acceleration, yaw rate."""

    __slots__ = ("a", "sweep", "v", "w")

    def __init__(self, v: float, a: float, w: float) -> None:
        self.v, self.a, self.w = v, a, w
        self.sweep = math.nan

    def blend(self, other: _Candidate, lam: float, v0: float, dt: float) -> _Candidate:
        a = self.a + lam * (other.a - self.a)
        return _Candidate(v0 + a * dt, a, self.w + lam * (other.w - self.w))

    @property
    def is_zero(self) -> bool:
        return self.v == 0.0 and self.w == 0.0


class _Monitor:
    """Reports a level as events: rises at once, falls after ``hold`` seconds."""

    def __init__(self, hold: float) -> None:
        self.hold = hold
        self.level = 0
        self._low_since: float | None = None

    def update(self, now: float, level: int) -> int | None:
        """The newly reported level, or None when nothing is to be reported."""
        if level > self.level:
            self.level, self._low_since = level, None
            return level
        if level == self.level:
            self._low_since = None
            return None
        if self._low_since is None:
            self._low_since = now
        if now - self._low_since >= self.hold:
            self.level, self._low_since = level, None
            return level
        return None


_NONE, _SLOW, _STOP, _EMERGENCY = 0, 1, 2, 3

_LABELS = {
    "laser": "laser",
    "camera": "camera",
    "ptu": "pan-tilt unit",
    "wheels": "wheel encoders",
    "imu": "IMU",
    "gps": "GPS",
    "pose": "pose estimate",
    "obstacles": "obstacle estimate",
}
_MISSING = {
    "laser": "has no scan",
    "camera": "no image",
    "ptu": "no angles",
    "wheels": "no reading",
    "imu": "no reading",
    "gps": "no fix",
}
_STOPPING = frozenset({"laser", "wheels", "imu", "pose", "obstacles"})
"""The sensors safe motion depends on: stale -> stop. The others (cameras, pan-tilt
angles, GPS) only degrade the mission's results."""


# -- the layer ------------------------------------------------------------------------------------
class SafetyLayer:
    """Filters every command of the tree before it is sent; see the module docstring."""

    def __init__(
        self,
        mission: Mission,
        placement: AircraftPlacement,
        period: float,
        *,
        stale_after: float | None = None,
        geofence_margin: float = 0.3,
        geofence_buffer: float = 0.05,
        escape_sweep: float = 0.05,
        slowdown_floor: float = SLOWDOWN_FLOOR,
        mover_horizon: float = 3.0,
        horizon: float | None = None,
        event_hold: float = 0.5,
        stale_limits: Mapping[str, float] | None = None,
    ) -> None:
        platform = mission.platform
        self.mission = mission
        self.period = float(period)
        self.limits = MotionLimits(
            period,
            platform.max_speed,
            platform.max_acceleration,
            platform.max_jerk,
            platform.max_angular_speed,
            platform.max_angular_acceleration,
        )
        self.safety = mission.safety
        self.lasers = tuple(platform.lasers)
        if stale_after is None:
            rates = [spec.rate_hz for spec in platform.lasers.values() if spec.rate_hz > 0]
            stale_after = 3.0 / min(rates) if rates else 3.0 * self.period
        self.stale_after = float(stale_after)
        self.margin = float(geofence_margin)
        self.buffer = min(float(geofence_buffer), self.margin)
        self.escape_sweep = float(escape_sweep)
        self.slowdown_floor = float(slowdown_floor)
        self.mover_horizon = float(mover_horizon)
        self.horizon = float(horizon) if horizon is not None else max(2.0 * self.period, 0.1)
        self.rates = {
            cid: (spec.pan_rate, spec.tilt_rate) for cid, spec in platform.cameras.items()
        }
        self.corners = footprint_corners(platform.length, platform.width)
        self._ring = [(float(px), float(py)) for px, py in self.corners]
        self.r_corner = math.hypot(platform.length / 2.0, platform.width / 2.0)
        # beyond this clearance no output can be restricted by the geofence
        lim = self.limits
        worst = self._sweep(_Candidate(lim.v_max, lim.a_max, lim.w_max))
        self._far = 1.25 * worst + self.margin + 0.5
        self.relevance = self._far + self.horizon * (lim.v_max + self.r_corner * lim.w_max)

        self._airport_zones = [z for z in mission.airport.zones if z.frame != Frame.AIRCRAFT]
        self._aircraft_zones = [z for z in mission.airport.zones if z.frame == Frame.AIRCRAFT]
        self._static = _ZoneSet(self._airport_zones, placement)
        self._placement: AircraftPlacement | None = None
        self._moving = _ZoneSet((), placement)
        self.set_placement(placement)

        self.events: list[SafetyEvent] = []
        self.status = SafetyStatus()
        # last sent command
        self._v = 0.0
        self._a = 0.0
        self._w = 0.0
        self._rest_sweep = 0.0  # sweep after the last output's own period (NaN: unknown)
        self._stopped = False  # the last output was a forced stop
        self._binding = False  # a geofence rule could bind on the last period
        # e-stop latch
        self.latch = EStopLatch(mission.safety.r_es, mission.safety.estop_hold)
        self.retreat = Retreat.of(mission)
        """How an obstacle latch may be backed out of (rule 2)."""
        self._retreating = False
        # fault latch and stale data
        self._fault: str | None = None
        self._fault_stamp = -math.inf
        self._stale: dict[str, str] = {}
        self._limits = dict(DEFAULT_STALE_LIMITS)
        for cid, spec in platform.cameras.items():
            per_camera = 3.0 / spec.rate_hz if spec.rate_hz > 0 else 3.0 * self.period
            for camera in camera_ids(platform, cid):
                self._limits[f"camera:{camera}"] = per_camera
            self._limits[f"ptu:{cid}"] = per_camera
        self._limits.update(stale_limits or {})
        self.sensor_health: dict[str, SensorHealth] = {}
        """Every watched sensor by key, with its stale intervals (see :class:`SensorHealth`)."""
        self._fresh: dict[str, Freshness] = {}
        self._stale_ptus: set[str] = set()
        for lid in self.lasers:
            self._watch(f"laser:{lid}")
        for cid in platform.cameras:
            for camera in camera_ids(platform, cid):
                self._watch(f"camera:{camera}")
            self._watch(f"ptu:{cid}")
        for key in ("wheels", "imu", "gps", "pose", "obstacles"):
            self._watch(key)
        # reported states
        self._geo_monitor = _Monitor(event_hold)
        self._slow_monitor = _Monitor(event_hold)
        self._limit_monitor = _Monitor(event_hold)
        self._limits_reported: set[str] = set()

    # -- public API -------------------------------------------------------------------------------
    def set_placement(
        self,
        placement: AircraftPlacement,
        tolerance: tuple[float, float] = (0.01, math.radians(0.05)),
    ) -> None:
        """The executive's current estimate of where the aircraft stands.

        Changes smaller than ``tolerance`` (m, rad) are ignored: the pose filter nudges
        the placement on every GPS fix, and rebuilding the zones for a millimetre would
        cost every tick for nothing (the geofence margin is decimetres).
        """
        old = self._placement
        if old is not None and not placement.differs_from(old, *tolerance):
            return
        self._placement = placement
        self._moving = _ZoneSet(self._aircraft_zones, placement)
        geoms = np.concatenate([self._static.geoms, self._moving.geoms])
        self._zone_ids = self._static.ids + self._moving.ids
        self._zone_geoms = geoms
        bounds = np.concatenate([self._static.bounds, self._moving.bounds])
        self._bounds_list = [tuple(float(v) for v in row) for row in bounds]

    @property
    def placement(self) -> AircraftPlacement:
        """The aircraft placement the aircraft-frame zones are enforced with."""
        assert self._placement is not None
        return self._placement

    @property
    def zone_geometries(self) -> dict[str, BaseGeometry]:
        """The forbidden zones as enforced now (airport frame), by id."""
        return dict(zip(self._zone_ids, self._zone_geoms, strict=True))

    def fault(self, now: float, reason: str) -> None:
        """Latch a fault stop (an exception in a tick, a lost bus): zero until reset."""
        if self._fault is None or self._fault != reason:
            self._emit(now, FAULT_STOP, reason)
        self._fault_stamp = now
        self._fault = reason

    def stale_intervals(self) -> dict[str, tuple[StaleInterval, ...]]:
        """Each watched sensor's stale stretches so far, by sensor key (empty: never
        stale). The last stretch of a sensor still stale has ``until`` None."""
        return {key: tuple(h.intervals) for key, h in self.sensor_health.items()}

    def drain_events(self) -> list[SafetyEvent]:
        """The events since the last drain (and forget them)."""
        out = list(self.events)
        self.events.clear()
        return out

    def filter(
        self,
        command: VelocityCommand,
        *,
        now: float,
        frame: SensorFrame,
        pose: PoseEstimate | None,
        obstacles: Obstacles | None,
        reset_requested: bool = False,
        estop_requested: bool = False,
    ) -> VelocityCommand:
        """The command to send for the tree's ``command``; see the module docstring.
        ``estop_requested``: the operator's e-stop (the HUD), latched like a bumper until
        ``reset_requested``."""
        # 0. operator reset of a fault signalled before this call
        if reset_requested and self._fault is not None and self._fault_stamp < now:
            self._emit(now, ESTOP_RESET, f"operator reset: fault cleared ({self._fault})")
            self._fault = None
        # 1. a non-finite command is a fault
        bad = _non_finite(command)
        if bad is not None:
            self.fault(now, f"non-finite command: {bad}")
        # 2. e-stop latch
        self._update_estop(now, frame, obstacles, reset_requested, estop_requested)
        # 3. stale data
        self._update_stale(now, frame, pose, obstacles)
        if self._stopped:
            self._resume_from_the_wheels(frame, command.v)
        stop = self._stop_reason()
        retreating = stop is not None and self._retreat_admitted(command, obstacles)
        if retreating:
            stop = None
            if not self._retreating:
                v = command.v
                side = "forwards" if v > 0.0 else "backwards"
                if command.omega:
                    turn = "left" if command.omega > 0.0 else "right"
                    why = f" on an arc turning {turn}: pinched, no return closes in along it"
                else:
                    why = ": no return inside r_ES that way"
                self._emit(now, ESTOP_RETREAT, f"backing out of the e-stop {side}{why}", v)
        self._retreating = retreating
        # an arc retreat keeps its curvature through the slowdown and the rate limits
        arc = command.omega / command.v if retreating and command.omega else None
        scale = self._slowdown(now, obstacles, command.v)
        xy = _pose_tuple(pose)
        if stop is not None:
            self._v = self._a = self._w = 0.0
            self._rest_sweep = 0.0
            self._stopped = True
            d_min, zone = self._nearest(self._zone_clearance(xy))
            self._geofence_event(now, _NONE, zone, d_min, "")
            self._limit_events(now, set())
            self.status = SafetyStatus(
                self.latch.latched, self.latch.cause, stop, scale, d_min, zone, forced_stop=True
            )
            return self._zero()

        # 4.-5. slowdown and magnitude limits
        lim = self.limits
        clipped: set[str] = set()
        vt = command.v * scale
        if abs(vt) > lim.v_max:
            clipped.add("speed")
            vt = math.copysign(lim.v_max, vt)
        wt = command.omega if arc is None else arc * vt
        if abs(wt) > lim.w_max:
            clipped.add("angular speed")
            wt = math.copysign(lim.w_max, wt)
        pan_tilt = self._pan_tilt(command.pan_tilt, clipped)
        self._limit_events(now, clipped)

        # 6. rate limits: the tree's candidate and the braking step
        v0, a0, w0 = self._v, self._a, self._w
        vc, ac = lim.step_v(v0, a0, vt)
        vb, ab = lim.step_v(v0, a0, 0.0)
        # on an arc the yaw rate follows the speed: within its own limit, since the
        # retreat's curvature is at most the angular over the linear acceleration
        cand = _Candidate(vc, ac, lim.step_w(w0, wt) if arc is None else arc * vc)
        brake = _Candidate(vb, ab, lim.step_w(w0, 0.0))
        if not math.isnan(self._rest_sweep):
            # S(brake) = S(last output) - its own period: the exact recursion of the sweep
            brake.sweep = self._rest_sweep

        # 7. geofence
        out, level, why, d_min, zone = self._geofence(xy, cand, brake)
        self._geofence_event(now, level, zone, d_min, why)

        if arc is not None and out is not cand:
            level = _EMERGENCY  # the geofence would bend the arc: stop instead
            retreating = self._retreating = False
        self._stopped = level == _EMERGENCY
        if level == _EMERGENCY:
            self._v = self._a = self._w = 0.0
            self._rest_sweep = 0.0
            out_cmd = self._zero()
        else:
            self._v, self._a, self._w = out.v, out.a, out.w
            self._rest_sweep = out.sweep - (abs(out.v) + self.r_corner * abs(out.w)) * lim.dt
            out_cmd = VelocityCommand(out.v, out.w, pan_tilt)
        stopped = f"geofence: {why}" if level >= _STOP else None
        self.status = SafetyStatus(
            self.latch.latched,
            self.latch.cause,
            stopped,
            scale,
            d_min,
            zone,
            forced_stop=level == _EMERGENCY,
            retreating=retreating,
        )
        return out_cmd

    def _resume_from_the_wheels(self, frame: SensorFrame, v: float) -> None:
        """After a forced stop: the rate limits start from the speed the wheels measure
        when the robot still rolls the way ``v`` asks (module docstring), within the
        platform's speed; the yaw rate and the acceleration from zero, as the stop sent."""
        wheels = frame.wheels
        if wheels is None:
            return
        measured, _ = wheel_odometry(wheels, self.mission.platform.odometry_track)
        if not (math.isfinite(measured) and measured * v > 0.0):
            return
        self._v = math.copysign(min(abs(measured), self.limits.v_max), measured)
        self._a = self._w = 0.0
        self._rest_sweep = math.nan  # moving: the braking sweep is computed afresh

    def _retreat_admitted(self, command: VelocityCommand, obstacles: Obstacles | None) -> bool:
        """Whether ``command`` may back out of the current stop (rule 2's exception)."""
        latch = self.latch
        if not latch.latched or latch.cause != "obstacle":
            return False
        if self._fault is not None or self._stale or obstacles is None:
            return False
        v = command.v
        if command.omega != 0.0:
            return self._arc_admitted(command, obstacles)
        if not abs(v) > 0.0:
            return False  # not a retreat (NaN fails too)
        side = 1 if v > 0.0 else -1
        if side not in self.retreat.sides or self._v * side < 0.0 or self._w != 0.0:
            return False  # neither from rest nor continuing one: stop first
        tracks = obstacles.tracks
        if abs(v) > self.retreat.top_speed(tracks):
            return False
        threat = self.retreat.threatened(tracks)
        if threat and not self.retreat.no_worse(tracks, v):
            return False
        if len(obstacles.points) == 0:  # r_c and its bearing only
            return self._closing_clearance(obstacles, v) >= self.retreat.room_for(v)
        room = self.retreat.open_sides(obstacles.points, tracks, threat, abs(v))
        return room.get(side, -math.inf) >= self.retreat.room_for(v)

    def _arc_admitted(self, command: VelocityCommand, obstacles: Obstacles) -> bool:
        """Rule 2's arc: a crawl on an arc no return closes in along
        (:meth:`~behaviours.laws.retreat.Retreat.arc_admitted`), with no mover
        threatening, from rest or on the arc the robot is already on (else stop first:
        the rate limits would bend the path between two arcs)."""
        v, omega = command.v, command.omega
        if not (math.isfinite(v) and math.isfinite(omega)) or v == 0.0:
            return False
        moving = self._v != 0.0 or self._w != 0.0
        if moving and not (self._v * v > 0.0 and math.isclose(self._w / self._v, omega / v)):
            return False
        if self.retreat.threatened(obstacles.tracks):
            return False
        return self.retreat.arc_admitted(obstacles.points, v, omega, obstacles.hidden)

    # -- e-stop, faults, stale data ---------------------------------------------------------------
    def _update_estop(
        self,
        now: float,
        frame: SensorFrame,
        obstacles: Obstacles | None,
        reset: bool,
        operator: bool = False,
    ) -> None:
        """The shared latch law (behaviours.laws.estop); its transitions become events."""
        pressed = tuple(side for side in ("front", "rear") if getattr(frame.bumpers, side))
        if operator:
            pressed = (*pressed, OPERATOR_ESTOP)
        closest = obstacles.closest if obstacles is not None else None
        self.latch.update(now, closest, pressed, reset)
        for event in self.latch.events:
            self._emit(now, _LATCH_EVENTS[event.kind], event.reason, event.value)

    def _watch(self, key: str) -> Freshness:
        """The freshness of sensor ``key``, watched from now on."""
        fresh = self._fresh.get(key)
        if fresh is None:
            kind, _, name = key.partition(":")
            limit = self._limits.get(key)
            if limit is None:
                limit = self._limits.get(kind, self.stale_after)
            if kind in ("laser", "obstacles"):
                limit = self.stale_after
            fresh = Freshness(limit, repeats_are_stale=kind == "camera")
            self._fresh[key] = fresh
            label = f"{_LABELS.get(kind, kind)} '{name}'" if name else _LABELS.get(kind, kind)
            self.sensor_health[key] = SensorHealth(key, label, kind in _STOPPING, fresh.limit)
        return fresh

    def _update_stale(
        self,
        now: float,
        frame: SensorFrame,
        pose: PoseEstimate | None,
        obstacles: Obstacles | None,
    ) -> None:
        """Feed every sensor's reading to its :class:`Freshness`; stale motion sensors stop
        the robot, stale mission sensors are reported (see the module docstring, 3.)."""
        readings: dict[str, tuple[float | None, Hashable | None, str]] = {}
        for lid, scan in frame.scans.items():
            readings[f"laser:{lid}"] = (scan.stamp, None, "has no scan")
        for cam_id, image in frame.cameras.items():
            readings[f"camera:{cam_id}"] = (image.stamp, image.content, "no image")
        for uid, angles in frame.pan_tilt.items():
            readings[f"ptu:{uid}"] = (angles.stamp, None, "no angles")
        for key, reading in (("wheels", frame.wheels), ("imu", frame.imu), ("gps", frame.gps)):
            none = "no fix" if key == "gps" else "no reading"
            readings[key] = (None if reading is None else reading.stamp, None, none)
        pose_ok = pose is not None and all(
            math.isfinite(c) for c in (pose.pose_a.x, pose.pose_a.y, pose.pose_a.theta)
        )
        pose_why = "no pose estimate" if pose is None else "pose estimate not finite"
        readings["pose"] = (pose.stamp if pose_ok and pose is not None else None, None, pose_why)
        readings["obstacles"] = (
            None if obstacles is None else obstacles.stamp,
            None,
            "no obstacle estimate",
        )

        for key in self._fresh:  # a sensor seen once and now absent from the frame
            readings.setdefault(key, (None, None, _MISSING.get(key.partition(":")[0], "")))
        stale: dict[str, str] = {}
        for key, (stamp, content, missing) in readings.items():
            fresh = self._watch(key)
            fresh.observe(stamp, content)
            # a motion sensor with no reading in hand is stale at once, not after a limit
            gone = stamp is None and self.sensor_health[key].stops
            if gone or fresh.stale(now):
                why = self._stale_detail(now, key, fresh, stamp, missing, gone)
                self._mark_stale(now, key, why, stale)
            else:
                self._mark_fresh(now, key)
        if not self.lasers and not frame.scans:
            stale["laser"] = "no laser scan"
        self._stale_ptus = {
            key[4:] for key, h in self.sensor_health.items() if key.startswith("ptu:") and h.stale
        }
        if set(stale) != set(self._stale):
            if stale:
                self._emit(now, STALE_SENSOR, "; ".join(stale.values()))
            else:
                self._emit(now, SENSOR_FRESH, "sensor data fresh again")
        self._stale = stale

    def _stale_detail(
        self,
        now: float,
        key: str,
        fresh: Freshness,
        stamp: float | None,
        missing: str,
        gone: bool,
    ) -> str:
        """Why ``key`` is stale, starting with its label and the time of its last fresh
        reading ("camera 'ptz' stale from 59.96 s: ...")."""
        label = self.sensor_health[key].label
        since = fresh.last_fresh
        head = f"{label} stale from " + ("the start" if since is None else f"{since:.2f} s")
        if gone or stamp is None:
            return f"{head}: {missing}"
        if key.startswith("obstacles"):
            return f"{head}: obstacle estimate {now - stamp:.3f} s old > {fresh.limit:.3f} s"
        last = fresh.last_stamp
        if since is not None and last is not None and last > since and now - last <= fresh.limit:
            return f"{head}: it repeats that image (no new one for over {fresh.limit:.3f} s)"
        what = "scan" if key.startswith("laser:") else "reading"
        return f"{head}: {what} {now - stamp:.3f} s old > {fresh.limit:.3f} s"

    def _mark_stale(self, now: float, key: str, why: str, stopping: dict[str, str]) -> None:
        health = self.sensor_health[key]
        if not health.stale:
            since = self._fresh[key].last_fresh
            health.intervals.append(StaleInterval(since, now, None, why))
            if not health.stops:
                self._emit(now, SENSOR_DEGRADED, why, since)
        if health.stops:
            stopping[key] = why

    def _mark_fresh(self, now: float, key: str) -> None:
        health = self.sensor_health[key]
        if not health.stale:
            return
        last = health.intervals[-1]
        health.intervals[-1] = dataclasses.replace(last, until=now)
        if not health.stops:
            since = "the start" if last.since is None else f"{last.since:.2f} s"
            self._emit(
                now,
                SENSOR_RECOVERED,
                f"{health.label} fresh again at {now:.2f} s (stale from {since})",
                last.since,
            )

    def _stop_reason(self) -> str | None:
        if self.latch.latched:
            return f"e-stop ({self.latch.cause}): {self.latch.reason}"
        if self._fault is not None:
            return f"fault: {self._fault}"
        if self._stale:
            return "stale: " + "; ".join(self._stale.values())
        return None

    # -- slowdown and limits ---------------------------------------------------------------------
    def _slowdown(self, now: float, obstacles: Obstacles | None, v: float) -> float:
        r_es, r_oa = self.safety.r_es, self.safety.r_oa_trigger
        r_c = self._closing_clearance(obstacles, v) if obstacles is not None else math.inf
        scale = float(slowdown_scale(r_c, r_es, r_oa, self.slowdown_floor))
        inside = scale < 1.0
        reported = self._slow_monitor.update(now, int(inside))
        if reported == 1:
            self._emit(
                now,
                SLOWDOWN,
                f"obstacle at {r_c:.3f} m < r_OA-trigger {r_oa:.2f} m: speed x{scale:.3f}",
                r_c,
            )
        elif reported == 0:
            self._emit(now, SLOWDOWN_END, f"no obstacle within r_OA-trigger {r_oa:.2f} m", r_c)
        return scale

    def _closing_clearance(self, obstacles: Obstacles, v: float) -> float:
        """r_d: the footprint's distance to the nearest return in the corridor the motion
        ``v`` drives into, or to a tracked mover that will cross that corridor within
        ``mover_horizon`` (:func:`~behaviours.laws.retreat.corridor_room`; NaN, unknown,
        stays NaN)."""
        r_c = obstacles.closest
        if not r_c < self.safety.r_oa_trigger or v == 0.0:
            return r_c
        points = obstacles.points
        if len(points) == 0:
            return r_c if v * math.cos(obstacles.bearing) > 0.0 else math.inf
        platform = self.mission.platform
        return corridor_room(
            points,
            obstacles.tracks,
            v,
            platform.length,
            platform.width,
            self.safety.r_es,
            self.mover_horizon,
        )

    def _pan_tilt(
        self, requested: Mapping[str, PanTiltRate], clipped: set[str]
    ) -> dict[str, PanTiltRate]:
        out = {}
        for uid, (pan_max, tilt_max) in self.rates.items():
            rate = requested.get(uid)
            if rate is None or uid in self._stale_ptus:
                out[uid] = PanTiltRate()
                continue
            pan = min(max(rate.pan, -pan_max), pan_max)
            tilt = min(max(rate.tilt, -tilt_max), tilt_max)
            if pan != rate.pan:
                clipped.add(f"pan rate '{uid}'")
            if tilt != rate.tilt:
                clipped.add(f"tilt rate '{uid}'")
            out[uid] = PanTiltRate(pan, tilt)
        for uid in requested:
            if uid not in self.rates:
                clipped.add(f"unknown pan-tilt unit '{uid}'")
        return out

    def _limit_events(self, now: float, clipped: set[str]) -> None:
        reported = self._limit_monitor.update(now, int(bool(clipped)))
        new = clipped - self._limits_reported
        if new and self._limit_monitor.level == 1:
            self._emit(now, LIMIT, "command beyond the platform limits: " + ", ".join(sorted(new)))
            self._limits_reported |= new
        if reported == 0:
            self._emit(now, LIMIT_END, "command within the platform limits again")
            self._limits_reported = set()

    def _zero(self) -> VelocityCommand:
        return VelocityCommand(0.0, 0.0, {uid: PanTiltRate() for uid in self.rates})

    # -- geofence -------------------------------------------------------------------------------
    def _footprints(self, poses: list[tuple[float, float, float]]) -> np.ndarray:
        flat: list[tuple[float, float]] = []
        for x, y, th in poses:
            c, s = math.cos(th), math.sin(th)
            flat += [(x + c * px - s * py, y + s * px + c * py) for px, py in self._ring]
        k = len(poses)
        return shapely.from_ragged_array(
            shapely.GeometryType.POLYGON,
            np.array(flat),
            (np.arange(0, 5 * k + 1, 5), np.arange(k + 1)),
        )

    def _clearance(self, poses: list[tuple[float, float, float]], idx: np.ndarray) -> FloatArray:
        """Signed clearance (k, len(idx)) of the footprints at ``poses`` to zones ``idx``."""
        fps = self._footprints(poses)
        zones = self._zone_geoms if len(idx) == len(self._zone_geoms) else self._zone_geoms[idx]
        d = shapely.distance(fps[:, None], zones)
        if d.min() <= 0.0:
            hit = d <= 0.0
            ii, jj = np.nonzero(hit)
            inter = shapely.intersection(fps[ii], zones[jj])
            d[ii, jj] = -np.sqrt(shapely.area(inter))
        return d

    def _lower_bounds(self, pose: tuple[float, float, float]) -> FloatArray:
        """Distance from the footprint's bounding disc to each zone's bounding box."""
        x, y, _ = pose
        r = self.r_corner
        out = []
        for x0, y0, x1, y1 in self._bounds_list:
            dx = x0 - x if x < x0 else (x - x1 if x > x1 else 0.0)
            dy = y0 - y if y < y0 else (y - y1 if y > y1 else 0.0)
            out.append(math.hypot(dx, dy) - r)
        return np.array(out)

    def _zone_clearance(self, pose: tuple[float, float, float] | None) -> FloatArray:
        """Clearance to every zone: exact within ``relevance``, a lower bound beyond."""
        if pose is None or not len(self._zone_ids):
            return np.zeros(0)
        d = self._lower_bounds(pose)
        near = np.nonzero(d <= self.relevance)[0]
        if len(near):
            d[near] = self._clearance([pose], near)[0]
        return d

    def _nearest(self, d: FloatArray) -> tuple[float, str | None]:
        if not len(d):
            return math.inf, None
        k = int(np.argmin(d))
        return float(d[k]), self._zone_ids[k]

    def _sweep(self, c: _Candidate) -> float:
        if math.isnan(c.sweep):
            lim = self.limits
            rc = self.r_corner
            c.sweep = (
                (abs(c.v) + rc * abs(c.w)) * lim.dt
                + lim.linear_sweep(c.v, c.a)
                + rc * lim.angular_sweep(c.w)
            )
        return c.sweep

    def _blend(
        self, b: _Candidate, c: _Candidate, ok: Callable[[_Candidate], bool], iters: int = 5
    ) -> _Candidate:
        """The candidate closest to ``c`` on the segment b -> c that ``ok`` accepts (b is)."""
        lo, hi = 0.0, 1.0
        best = b
        v0, dt = self._v, self.limits.dt
        for _ in range(iters):
            mid = 0.5 * (lo + hi)
            m = b.blend(c, mid, v0, dt)
            if ok(m):
                lo, best = mid, m
            else:
                hi = mid
        return best

    def _geofence(
        self, pose: tuple[float, float, float] | None, c: _Candidate, b: _Candidate
    ) -> tuple[_Candidate, int, str, float, str | None]:
        """(output, level, reason, clearance, nearest zone) for candidate ``c``."""
        if pose is None or not len(self._zone_ids):
            self._binding = False
            return c, _NONE, "", math.inf, None
        lim, rc = self.limits, self.r_corner
        d = self._lower_bounds(pose)
        near = np.nonzero(d <= self.relevance)[0]
        dp: FloatArray | None = None
        if not len(near):
            self._binding = False
            return c, _NONE, "", *self._nearest(d)
        quick = (
            (abs(c.v) + rc * abs(c.w)) * lim.dt + lim.sweep_bound(c.v) + rc * lim.angular_sweep(c.w)
        )
        # the candidates whose approach is tested: c, c without its rotation, c without its
        # translation, and the braking step
        cv = _Candidate(c.v, c.a, lim.step_w(self._w, 0.0))
        cw = _Candidate(b.v, b.a, c.w)
        cands = (c, cv, cw, b)
        h = self.horizon
        x, y, th = pose
        if self._binding:
            # a rule could bind on the last period: predict now too (one shapely call)
            preds = [predict_pose(x, y, th, o.v, o.w, h) for o in cands]
            dd = self._clearance([pose, *preds], near)
            d[near], dp = dd[0], dd[1:]
        else:
            d[near] = self._clearance([pose], near)[0]
        d_min, zone = self._nearest(d)
        self._binding = quick > d_min - self.margin
        if not self._binding:
            return c, _NONE, "", d_min, zone  # neither rule can bind (margin >= buffer)
        if dp is None:
            dp = self._clearance([predict_pose(x, y, th, o.v, o.w, h) for o in cands], near)
        ids = [self._zone_ids[i] for i in near]
        out, level, why = self._decide(pose, near, ids, d[near], dp, cands, d_min)
        return out, level, why, d_min, zone

    def _decide(
        self,
        pose: tuple[float, float, float],
        near: np.ndarray,
        ids: list[str],
        d: FloatArray,
        dp: FloatArray,
        cands: tuple[_Candidate, _Candidate, _Candidate, _Candidate],
        d_min: float,
    ) -> tuple[_Candidate, int, str]:
        """The soft and hard geofence rules on the near zones (clearances ``d``, predicted
        clearances ``dp`` of the four candidates)."""
        margin, buffer = self.margin, self.buffer
        c, cv, cw, b = cands
        sc, sb = self._sweep(c), self._sweep(b)
        # zones where either rule could bind; approaching another zone does not matter
        rel = d - buffer < max(sc, sb) + margin
        approach = (dp < d[None, :] - 1e-9) & rel[None, :]

        def soft_budget(k: int) -> tuple[float, int]:
            if not approach[k].any():
                return math.inf, -1
            j = int(np.argmin(np.where(approach[k], d, np.inf)))
            return float(d[j]) - margin, j

        level, why = _NONE, ""
        out = c
        budget_c, jc = soft_budget(0)
        if sc > budget_c:
            hit, dz = ids[jc], float(d[jc])
            within = dz <= margin
            if sb <= budget_c:
                if budget_c - sb > 1e-4:  # else there is no room worth a search
                    out = self._blend(b, c, lambda o: self._sweep(o) <= budget_c)
                else:
                    out = b
                level = _SLOW
                why = f"approaching zone '{hit}' ({dz:.2f} m): speed limited"
            else:
                out = b
                for k, alt in ((1, cv), (2, cw)):
                    if self._sweep(alt) <= soft_budget(k)[0]:
                        out = alt
                        break
                level = _STOP if within else _SLOW
                why = (
                    f"within {margin:g} m of zone '{hit}' ({dz:.2f} m): approach refused"
                    if within
                    else f"approaching zone '{hit}' ({dz:.2f} m): braking"
                )

        # hard, isotropic rule
        budget = d_min - buffer
        if self._sweep(out) <= budget:
            return out, level, why
        hit = ids[int(np.argmin(d))]
        if sb <= budget + _TOL:
            if budget - sb > 1e-4:
                out = self._blend(b, out, lambda o: self._sweep(o) <= budget)
            else:
                out = b
            return out, max(level, _SLOW), why or f"near zone '{hit}' ({d_min:.2f} m)"
        # the invariant is lost (a jump): back out at a crawl, brake, or stop at once
        esc = self.escape_sweep

        def escapes(o: _Candidate) -> bool:
            for k, known in enumerate(cands):
                if o is known:
                    return not approach[k].any()
            x, y, th = pose
            p = predict_pose(x, y, th, o.v, o.w, self.horizon)
            return not ((self._clearance([p], near)[0] < d - 1e-9) & rel).any()

        why = f"backing out of zone '{hit}' ({d_min:.2f} m)"
        if self._sweep(out) <= esc and escapes(out):
            return out, _STOP, why
        if sb <= esc and escapes(b):
            if escapes(out):
                out = self._blend(b, out, lambda o: self._sweep(o) <= esc)
                return out, _STOP, why
            return b, _STOP, why
        if b.is_zero or sb <= d_min:
            return b, _STOP, f"too close to zone '{hit}' ({d_min:.2f} m): braking"
        return (
            b,
            _EMERGENCY,
            f"emergency stop: cannot stop before zone '{hit}' ({d_min:.2f} m) within the limits",
        )

    def _geofence_event(self, now: float, level: int, zone: str | None, d: float, why: str) -> None:
        reported = self._geo_monitor.update(now, level)
        if reported is None:
            return
        value = d if math.isfinite(d) else None
        if reported == _NONE:
            self._emit(now, GEOFENCE_CLEAR, "geofence no longer limits the command", value)
        elif reported == _SLOW:
            self._emit(now, GEOFENCE_SLOW, why or f"near zone '{zone}'", value)
        else:
            self._emit(now, GEOFENCE_STOP, why or f"near zone '{zone}'", value)

    def _emit(self, now: float, kind: str, reason: str, value: float | None = None) -> None:
        self.events.append(SafetyEvent(now, kind, reason, value))


def _pose_tuple(pose: PoseEstimate | None) -> tuple[float, float, float] | None:
    if pose is None:
        return None
    p = pose.pose_a
    if not (math.isfinite(p.x) and math.isfinite(p.y) and math.isfinite(p.theta)):
        return None
    return (p.x, p.y, p.theta)


def _non_finite(command: VelocityCommand) -> str | None:
    if not math.isfinite(command.v):
        return f"v={command.v}"
    if not math.isfinite(command.omega):
        return f"omega={command.omega}"
    for uid, rate in command.pan_tilt.items():
        if not (math.isfinite(rate.pan) and math.isfinite(rate.tilt)):
            return f"pan-tilt '{uid}'=({rate.pan}, {rate.tilt})"
    return None
