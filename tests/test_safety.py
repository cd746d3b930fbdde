"""The runtime safety layer (executive/safety.py): unit tests per rule, then properties.

Properties (hypothesis): every command sent is within the platform limits (and the rate
limits, except for a forced stop); while the e-stop is latched every command is zero or,
under an obstacle latch, a straight crawl away from the obstacle; in
randomised closed-loop runs with adversarial commands the footprint never enters a
forbidden zone, for airport- and aircraft-frame zones.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np
import pytest
import shapely
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from shapely.geometry import Point

from behaviours.laws.retreat import RETREAT_SPEED
from executive.core.frames import AircraftPlacement, Pose2
from executive.core.loader import load_mission
from executive.core.model import Circle, ForbiddenZone, Frame, Mission, ZoneKind
from executive.core.records import (
    Bumpers,
    CameraFrame,
    GpsFix,
    ImuReading,
    LaserScan,
    Obstacles,
    PanTilt,
    PanTiltRate,
    PoseEstimate,
    SensorFrame,
    TrackedObstacle,
    VelocityCommand,
    WheelSpeeds,
    camera_ids,
)
from executive.safety import MotionLimits, SafetyLayer
from tests.conftest import SHIPPED_MISSIONS

PERIOD = 0.05
TOL = 1e-9


@functools.cache
def mission() -> Mission:
    return load_mission(SHIPPED_MISSIONS["a320"])


def placement() -> AircraftPlacement:
    return mission().nominal_placement()


def with_circles(m: Mission) -> Mission:
    """The mission plus a circular zone in each frame."""
    extra = (
        ForbiddenZone("cone-a", ZoneKind.NO_GO, Frame.AIRPORT, Circle("cone-a", -30.0, -8.0, 2.0)),
        ForbiddenZone("cone-f", ZoneKind.NO_GO, Frame.AIRCRAFT, Circle("cone-f", 30.0, 14.0, 1.5)),
    )
    airport = dataclasses.replace(m.airport, zones=m.airport.zones + extra)
    return dataclasses.replace(m, airport=airport)


def zone_checker(m: Mission, pl: AircraftPlacement) -> list[tuple[str, object]]:
    """Exact zone geometry in A, independent of the layer: polygons, and circles as
    (centre, radius)."""
    out = []
    for z in m.airport.zones:
        shape = z.shape
        if isinstance(shape, Circle):
            c = np.array([shape.cx, shape.cy])
            if z.frame == Frame.AIRCRAFT:
                c = pl.to_airport_xy(c)
            out.append((z.id, (Point(float(c[0]), float(c[1])), shape.radius)))
        else:
            pts = np.array(shape.points)
            if z.frame == Frame.AIRCRAFT:
                pts = pl.to_airport_xy(pts)
            out.append((z.id, shapely.polygons(pts)))
    return out


def footprint(x: float, y: float, th: float, m: Mission) -> shapely.Polygon:
    hl, hw = m.platform.length / 2, m.platform.width / 2
    c, s = math.cos(th), math.sin(th)
    pts = [(x + c * px - s * py, y + s * px + c * py) for px, py in _corners(hl, hw)]
    return shapely.polygons(pts)


def _corners(hl: float, hw: float) -> list[tuple[float, float]]:
    return [(hl, hw), (-hl, hw), (-hl, -hw), (hl, -hw)]


def clearance(fp: shapely.Polygon, zones: list[tuple[str, object]]) -> float:
    """Footprint clearance to the exact zones (<= 0 when touching or inside)."""
    best = math.inf
    for _, g in zones:
        if isinstance(g, tuple):
            centre, r = g
            d = fp.distance(centre) - r
            if fp.contains(centre):
                d = -r
        else:
            d = -1.0 if fp.intersects(g) and fp.distance(g) == 0.0 else fp.distance(g)
        best = min(best, d)
    return best


class Bench:
    """A unicycle robot that integrates the filtered commands exactly, with a sensor feed."""

    def __init__(
        self,
        layer: SafetyLayer,
        x: float = -60.0,
        y: float = 10.0,
        th: float = 0.0,
        m: Mission | None = None,
    ) -> None:
        self.layer = layer
        self.m = m or mission()
        self.x, self.y, self.th = x, y, th
        self.t = 0.0
        self.sent: list[VelocityCommand] = []
        self.statuses = []
        self.wheel_speed = 0.0
        """What the wheels measure (m/s, both wheels alike)."""

    def frame(self, scan_age: float = 0.0, bumper: bool = False, lasers: bool = True):
        """Every sensor of the platform, fresh (the lasers ``scan_age`` old)."""
        t = self.t - scan_age
        scans = {}
        if lasers:
            scans = {
                lid: LaserScan(t, -2.0, 0.01, 30.0, np.full(3, 30.0))
                for lid in self.m.platform.lasers
            }
        platform = self.m.platform
        return SensorFrame(
            self.t,
            scans=scans,
            cameras={
                c: CameraFrame(self.t) for u in platform.cameras for c in camera_ids(platform, u)
            },
            pan_tilt={u: PanTilt(self.t, 0.0, 0.0) for u in platform.cameras},
            wheels=WheelSpeeds(self.t, self.wheel_speed, self.wheel_speed),
            imu=ImuReading(self.t, 0.0),
            gps=GpsFix(self.t, self.x, self.y, 0.03),
            bumpers=Bumpers(self.t, bumper, False),
        )

    def pose(self) -> PoseEstimate:
        p = Pose2(self.x, self.y, self.th)
        pl = self.layer.placement
        return PoseEstimate(self.t, p, np.eye(3) * 1e-4, pl.pose_to_aircraft(p), 1.0)

    def step(
        self,
        command: VelocityCommand,
        *,
        rc: float = math.inf,
        bumper: bool = False,
        reset: bool = False,
        scan_age: float = 0.0,
        pose: bool = True,
        obstacles: bool = True,
        move: bool = True,
        seen: Obstacles | None = None,
    ) -> VelocityCommand:
        """One period; the obstacle estimate is ``seen`` when given, else r_c = ``rc``
        straight ahead (no points)."""
        if seen is None and obstacles:
            seen = Obstacles(self.t, rc, 0.0, np.zeros((0, 2)))
        out = self.layer.filter(
            command,
            now=self.t,
            frame=self.frame(scan_age, bumper),
            pose=self.pose() if pose else None,
            obstacles=seen,
            reset_requested=reset,
        )
        self.sent.append(out)
        self.statuses.append(self.layer.status)
        if move:
            self.integrate(out.v, out.omega, PERIOD)
        self.t = round(self.t + PERIOD, 9)
        return out

    def integrate(self, v: float, w: float, dt: float) -> None:
        x, y, th = self.x, self.y, self.th
        if abs(w) < 1e-12:
            self.x, self.y = x + v * dt * math.cos(th), y + v * dt * math.sin(th)
        else:
            r = v / w
            self.x = x + r * (math.sin(th + w * dt) - math.sin(th))
            self.y = y - r * (math.cos(th + w * dt) - math.cos(th))
            self.th = th + w * dt


def layer(m: Mission | None = None, pl: AircraftPlacement | None = None, **kw) -> SafetyLayer:
    m = m or mission()
    return SafetyLayer(m, pl or m.nominal_placement(), PERIOD, **kw)


def kinds(lay: SafetyLayer, prefix: str = "") -> list[str]:
    return [e.kind for e in lay.events if e.kind.startswith(prefix)]


def estop_kinds(lay: SafetyLayer) -> list[str]:
    return [e.kind for e in lay.events if e.kind.startswith(("estop", "reset"))]


def cmd(v: float = 0.0, w: float = 0.0, **pt: tuple[float, float]) -> VelocityCommand:
    return VelocityCommand(v, w, {k: PanTiltRate(*r) for k, r in pt.items()})


def is_zero(c: VelocityCommand) -> bool:
    return (
        c.v == 0.0
        and c.omega == 0.0
        and all(r.pan == 0.0 and r.tilt == 0.0 for r in c.pan_tilt.values())
    )


def check_limits(bench: Bench) -> None:
    """Magnitudes always; acceleration and jerk except around a forced stop."""
    p = bench.m.platform
    lim = bench.layer.limits
    dt = PERIOD
    vs = [0.0, 0.0] + [c.v for c in bench.sent]
    ws = [0.0] + [c.omega for c in bench.sent]
    forced = [False, False] + [s.forced_stop for s in bench.statuses]
    for k, c in enumerate(bench.sent):
        assert math.isfinite(c.v) and math.isfinite(c.omega)
        assert abs(c.v) <= p.max_speed + TOL
        assert abs(c.omega) <= p.max_angular_speed + TOL
        assert set(c.pan_tilt) == set(p.cameras)
        for uid, r in c.pan_tilt.items():
            assert abs(r.pan) <= p.cameras[uid].pan_rate + TOL
            assert abs(r.tilt) <= p.cameras[uid].tilt_rate + TOL
        i = k + 2
        if forced[i]:
            assert is_zero(c)
            continue
        assert abs(vs[i] - vs[i - 1]) <= p.max_acceleration * dt + TOL, k
        assert abs(ws[k + 1] - ws[k]) <= p.max_angular_acceleration * dt + TOL, k
        if not forced[i - 1]:
            jerk = abs(vs[i] - 2 * vs[i - 1] + vs[i - 2]) / dt**2
            assert jerk <= lim.max_jerk * (1 + 1e-6) + 1e-6, (k, jerk)


# -- motion limits --------------------------------------------------------------------------------
def brake_by_steps(lim: MotionLimits, v: float, a: float) -> float:
    total = 0.0
    for _ in range(100000):
        if abs(v) < 1e-12 and abs(a) < 1e-12:
            break
        v, a = lim.step_v(v, a, 0.0)
        total += abs(v) * lim.dt
    return total


limit_sets = st.tuples(
    st.sampled_from([0.02, 0.025, 0.05, 0.1]),  # period
    st.floats(0.3, 3.0),  # max acceleration
    st.floats(0.5, 60.0),  # max jerk
    st.floats(0.5, 3.0),  # max speed
)


@settings(max_examples=60, deadline=None)
@given(limit_sets, st.floats(-1, 1), st.floats(-1, 1))
def test_linear_sweep_is_the_braking_sequence(params, fv, fa):
    dt, acc, jerk, vmax = params
    lim = MotionLimits(dt, vmax, acc, jerk, 1.0, 2.0)
    v, a = fv * vmax, fa * acc
    exact = brake_by_steps(lim, v, a)
    assert lim.linear_sweep(v, a) == pytest.approx(exact, abs=1e-9)
    # the table bound covers every acceleration
    assert lim.sweep_bound(v) >= exact - 1e-9
    # one braking step removes exactly the distance of that step
    v1, a1 = lim.step_v(v, a, 0.0)
    assert lim.linear_sweep(v, a) == pytest.approx(abs(v1) * dt + lim.linear_sweep(v1, a1))


@settings(max_examples=60, deadline=None)
@given(limit_sets, st.floats(-1, 1), st.floats(-3, 3))
def test_speed_profile_respects_limits_and_does_not_overshoot(params, start, target):
    dt, acc, jerk, vmax = params
    lim = MotionLimits(dt, vmax, acc, jerk, 1.0, 2.0)
    target = max(-vmax, min(vmax, target))
    v, a = start * vmax, 0.0
    lo, hi = min(v, target), max(v, target)
    for _ in range(2000):
        v1, a1 = lim.step_v(v, a, target)
        assert abs(a1) <= acc + TOL
        assert abs(a1 - a) <= lim.max_jerk * dt + TOL
        assert lo - TOL <= v1 <= hi + TOL  # from rest it never overshoots
        v, a = v1, a1
        if v == target and a == 0.0:
            break
    assert v == pytest.approx(target)


def test_angular_sweep_matches_steps():
    lim = MotionLimits(PERIOD, 2.0, 1.0, 5.0, 1.0, 2.0)
    for w in (0.0, 0.05, 0.1, 0.37, -0.9, 1.0):
        total, x = 0.0, w
        while x != 0.0:
            x = lim.step_w(x, 0.0)
            total += abs(x) * PERIOD
        assert lim.angular_sweep(w) == pytest.approx(total)


# -- limits ---------------------------------------------------------------------------------------
def test_free_command_ramps_to_the_request_within_the_limits():
    b = Bench(layer())
    for _ in range(80):
        out = b.step(cmd(1.2, 0.4))
    assert (out.v, out.omega) == pytest.approx((1.2, 0.4))
    check_limits(b)
    assert b.layer.events == []
    assert b.layer.status.stopped_reason is None


def test_speed_beyond_the_platform_is_clamped_and_logged_once():
    b = Bench(layer())
    for _ in range(100):
        out = b.step(cmd(10.0, -5.0))
    assert out.v == pytest.approx(2.0) and out.omega == pytest.approx(-1.0)
    assert kinds(b.layer) == ["limit"]
    assert "speed" in b.layer.events[0].reason
    for _ in range(20):
        b.step(cmd(1.0))
    assert kinds(b.layer) == ["limit", "limit-end"]
    check_limits(b)


def test_pan_tilt_rates_clamped_every_unit_named_unknown_dropped():
    p = mission().platform
    b = Bench(layer())
    out = b.step(cmd(0.0, 0.0, ptz=(5.0, -5.0), front=(0.1, 0.2), nosuch=(1.0, 1.0)))
    assert set(out.pan_tilt) == set(p.cameras)
    assert out.pan_tilt["ptz"] == PanTiltRate(
        p.cameras["ptz"].pan_rate, -p.cameras["ptz"].tilt_rate
    )
    assert out.pan_tilt["front"] == PanTiltRate(0.1, 0.2)
    assert out.pan_tilt["rear"] == PanTiltRate(0.0, 0.0)
    (event,) = b.layer.events
    assert "pan rate 'ptz'" in event.reason and "unknown pan-tilt unit 'nosuch'" in event.reason


def test_stopping_command_decelerates_within_the_limits():
    b = Bench(layer())
    for _ in range(80):
        b.step(cmd(2.0))
    for _ in range(60):
        out = b.step(cmd(0.0))
    assert out.v == 0.0
    check_limits(b)


# -- e-stop ---------------------------------------------------------------------------------------
def test_obstacle_estop_is_immediate_and_releases_after_the_hold():
    lay = layer()
    b = Bench(lay)
    for _ in range(60):
        b.step(cmd(2.0))
    r_es, hold = mission().safety.r_es, mission().safety.estop_hold
    out = b.step(cmd(2.0), rc=r_es - 0.1)
    assert is_zero(out) and set(out.pan_tilt) == set(mission().platform.cameras)
    assert lay.status.estop_latched and lay.status.estop_cause == "obstacle"
    assert lay.status.forced_stop
    (latch,) = [e for e in lay.events if e.kind == "estop-latched"]
    assert latch.value == pytest.approx(r_es - 0.1) and "r_ES" in latch.reason
    n_clear = round(hold / PERIOD)
    for _ in range(n_clear):  # clear, but not yet for the whole hold
        assert is_zero(b.step(cmd(2.0), rc=5.0))
    out = b.step(cmd(2.0), rc=5.0)
    assert not lay.status.estop_latched and out.v > 0.0
    assert estop_kinds(lay) == ["estop-latched", "estop-released"]
    check_limits(b)


def test_obstacle_coming_back_restarts_the_hold():
    lay = layer()
    b = Bench(lay)
    b.step(cmd(1.0), rc=0.1)
    for _ in range(10):
        b.step(cmd(1.0), rc=5.0)
    b.step(cmd(1.0), rc=0.2)
    for _ in range(15):
        assert is_zero(b.step(cmd(1.0), rc=5.0))
    assert lay.status.estop_latched


def test_nan_obstacle_distance_counts_as_inside():
    b = Bench(layer())
    assert is_zero(b.step(cmd(1.0), rc=math.nan))
    assert b.layer.status.estop_latched


def test_bumper_latch_needs_release_and_reset():
    lay = layer()
    b = Bench(lay)
    b.step(cmd(1.0))
    assert is_zero(b.step(cmd(1.0), bumper=True))
    assert lay.status.estop_cause == "bumper"
    for _ in range(60):  # released and clear for long: still latched
        assert is_zero(b.step(cmd(1.0)))
    assert is_zero(b.step(cmd(1.0), bumper=True, reset=True))  # pressed: refused
    assert kinds(lay) == ["estop-latched", "reset-refused"]
    assert is_zero(b.step(cmd(1.0), bumper=True, reset=True))  # held: refused once only
    assert kinds(lay) == ["estop-latched", "reset-refused"]
    out = b.step(cmd(1.0), reset=True)
    assert not lay.status.estop_latched and out.v > 0.0
    assert kinds(lay)[-1] == "estop-reset"


def test_bumper_reset_with_an_obstacle_inside_keeps_an_obstacle_latch():
    lay = layer()
    b = Bench(lay)
    b.step(cmd(1.0), bumper=True)
    assert is_zero(b.step(cmd(1.0), rc=0.3, reset=True))
    assert lay.status.estop_latched and lay.status.estop_cause == "obstacle"
    for _ in range(round(mission().safety.estop_hold / PERIOD) + 1):
        b.step(cmd(1.0), rc=3.0)
    assert not lay.status.estop_latched
    assert estop_kinds(lay) == ["estop-latched", "estop-reset", "estop-released"]


def test_obstacle_latch_reset_releases_at_once_when_clear():
    lay = layer()
    b = Bench(lay)
    b.step(cmd(1.0), rc=0.3)
    b.step(cmd(1.0), rc=3.0, reset=True)
    assert not lay.status.estop_latched
    assert estop_kinds(lay) == ["estop-latched", "estop-reset"]


def test_bumper_during_an_obstacle_latch_upgrades_it():
    lay = layer()
    b = Bench(lay)
    b.step(cmd(1.0), rc=0.3)
    b.step(cmd(1.0), rc=0.3, bumper=True)
    for _ in range(40):
        b.step(cmd(1.0), rc=3.0)
    assert lay.status.estop_latched and lay.status.estop_cause == "bumper"
    assert estop_kinds(lay) == ["estop-latched", "estop-latched"]
    assert lay.events[-1].kind == "slowdown-end"


# -- faults and stale data ------------------------------------------------------------------------
def test_default_stale_after_is_three_laser_periods():
    slowest = min(s.rate_hz for s in mission().platform.lasers.values())
    assert layer().stale_after == pytest.approx(3.0 / slowest)
    assert layer(stale_after=0.5).stale_after == 0.5


def test_stale_laser_stops_and_recovers_by_itself():
    lay = layer()
    b = Bench(lay)
    for _ in range(40):
        b.step(cmd(1.0))
    out = b.step(cmd(1.0), scan_age=lay.stale_after + 0.01)
    assert is_zero(out) and lay.status.forced_stop
    assert "stale" in lay.status.stopped_reason
    assert kinds(lay) == ["stale-sensor"]
    b.step(cmd(1.0), scan_age=lay.stale_after + 0.05)  # still stale: no new event
    assert kinds(lay) == ["stale-sensor"]
    out = b.step(cmd(1.0), scan_age=0.01)
    assert out.v > 0.0 and kinds(lay) == ["stale-sensor", "sensor-fresh"]
    check_limits(b)


@pytest.mark.parametrize(
    ("what", "expect"),
    [
        ("no-lasers", "has no scan"),
        ("no-pose", "no pose estimate"),
        ("no-obstacles", "no obstacle estimate"),
    ],
)
def test_missing_data_is_stale(what, expect):
    lay = layer()
    b = Bench(lay)
    b.step(cmd(1.0))
    if what == "no-lasers":
        out = lay.filter(
            cmd(1.0),
            now=b.t,
            frame=b.frame(lasers=False),
            pose=b.pose(),
            obstacles=Obstacles(b.t, math.inf, 0.0, np.zeros((0, 2))),
        )
    else:
        out = b.step(cmd(1.0), pose=what != "no-pose", obstacles=what != "no-obstacles")
    assert is_zero(out)
    assert expect in lay.status.stopped_reason
    assert expect in lay.events[-1].reason


def test_fault_latches_until_a_later_reset():
    lay = layer()
    b = Bench(lay)
    for _ in range(20):
        b.step(cmd(1.0))
    lay.fault(b.t, "exception in tick: ZeroDivisionError")
    assert is_zero(b.step(cmd(1.0), reset=True))  # a reset in the same tick does not count
    for _ in range(10):
        assert is_zero(b.step(cmd(1.0)))
    assert lay.status.stopped_reason.startswith("fault")
    out = b.step(cmd(1.0), reset=True)
    assert out.v > 0.0
    assert kinds(lay) == ["fault-stop", "estop-reset"]
    drained = lay.drain_events()
    assert [e.kind for e in drained] == ["fault-stop", "estop-reset"]
    assert lay.events == [] and drained[0].reason == "exception in tick: ZeroDivisionError"
    check_limits(b)


@pytest.mark.parametrize(
    "bad",
    [
        cmd(math.nan),
        cmd(1.0, math.inf),
        cmd(-math.inf),
        cmd(0.0, 0.0, ptz=(math.nan, 0.0)),
    ],
)
def test_non_finite_command_is_a_fault_stop(bad):
    lay = layer()
    b = Bench(lay)
    b.step(cmd(1.0))
    assert is_zero(b.step(bad))
    assert kinds(lay) == ["fault-stop"] and "non-finite" in lay.events[0].reason
    assert is_zero(b.step(cmd(1.0)))  # latched
    assert b.step(cmd(1.0), reset=True).v > 0.0


# -- slowdown zone --------------------------------------------------------------------------------
@pytest.mark.parametrize("rc", [0.7, 1.0, 1.55, 2.0, 2.49, 2.5, 10.0])
def test_slowdown_scales_the_speed(rc):
    s = mission().safety
    lay = layer()
    b = Bench(lay)
    for _ in range(100):
        out = b.step(cmd(1.5), rc=rc)
    expect = 1.0 if rc >= s.r_oa_trigger else max(0.2, (rc - s.r_es) / (s.r_oa_trigger - s.r_es))
    assert lay.status.speed_scale == pytest.approx(expect)
    assert out.v == pytest.approx(1.5 * expect)
    assert kinds(lay) == ([] if expect == 1.0 else ["slowdown"])


def test_slowdown_respects_the_deceleration_limit_and_logs_its_end():
    lay = layer()
    b = Bench(lay)
    for _ in range(60):
        b.step(cmd(2.0))
    for _ in range(40):
        b.step(cmd(2.0), rc=0.8)
    for _ in range(40):
        b.step(cmd(2.0))
    check_limits(b)
    assert kinds(lay) == ["slowdown", "slowdown-end"]
    assert lay.events[0].value == pytest.approx(0.8)


# -- geofence -------------------------------------------------------------------------------------
def drive_at_gse(lay: SafetyLayer, speed: float = 2.0, steps: int = 300) -> Bench:
    # gse-parking (airport frame): x 25..40, y 2..12; start west of it, facing east
    b = Bench(lay, x=15.0, y=7.0, th=0.0)
    for _ in range(steps):
        b.step(cmd(speed))
    return b


def test_geofence_stops_at_the_margin_when_driving_straight_at_a_zone():
    lay = layer()
    b = drive_at_gse(lay)
    gap = 25.0 - (b.x + mission().platform.length / 2)
    assert lay.margin - 1e-6 <= gap <= lay.margin + 0.05
    assert b.sent[-1].v == pytest.approx(0.0, abs=1e-3)
    assert lay.status.geofence_zone == "gse-parking"
    assert lay.status.geofence_distance == pytest.approx(gap)
    assert "geofence-slow" in kinds(lay)
    check_limits(b)
    assert not any(s.forced_stop for s in b.statuses)


def test_geofence_event_is_logged_once_per_approach():
    lay = layer()
    drive_at_gse(lay)
    assert kinds(lay).count("geofence-slow") == 1


def test_within_the_margin_approach_is_refused_but_backing_out_is_allowed():
    lay = layer()
    b = Bench(lay, x=25.0 - 0.7 - 0.15, y=7.0, th=0.0)  # 0.15 m from the zone
    for _ in range(20):
        out = b.step(cmd(1.0))
        assert out.v == 0.0
    assert lay.status.stopped_reason.startswith("geofence")
    assert "geofence-stop" in kinds(lay)
    for _ in range(40):
        out = b.step(cmd(-1.0))
    assert out.v < -0.5
    assert b.x < 25.0 - 0.7 - 1.0
    for _ in range(40):
        b.step(cmd(-1.0))
    assert kinds(lay)[-1] == "geofence-clear"
    check_limits(b)


def test_rotation_that_swings_a_corner_into_the_zone_is_refused():
    lay = layer()
    # facing north, the right side 0.1 m from the zone's west edge
    b = Bench(lay, x=25.0 - 0.5 - 0.1, y=7.0, th=math.pi / 2)
    for _ in range(40):
        b.step(cmd(0.0, -1.0))  # turning right swings the front-right corner east
    zones = zone_checker(mission(), placement())
    assert clearance(footprint(b.x, b.y, b.th, mission()), zones) >= lay.buffer - 1e-9
    # driving along the edge (not closer) is allowed
    b2 = Bench(layer(), x=25.0 - 0.5 - 0.1, y=0.0, th=math.pi / 2)
    for _ in range(40):
        out = b2.step(cmd(0.5))
    assert out.v == pytest.approx(0.5)


def test_inside_a_zone_the_robot_may_only_back_out_at_a_crawl():
    lay = layer()
    b = Bench(lay, x=25.5, y=7.0, th=0.0)  # overlapping gse-parking
    assert is_zero(b.step(cmd(1.0)))
    for _ in range(5):
        assert b.step(cmd(1.0)).v == 0.0
    assert lay.status.geofence_distance < 0.0
    xs = []
    for _ in range(80):
        out = b.step(cmd(-2.0))
        xs.append(b.x)
        assert abs(out.v) <= 0.5
    assert xs[-1] < 25.5 - 0.5
    check_limits(b)


def test_pose_jump_next_to_a_zone_is_an_emergency_stop():
    lay = layer()
    b = Bench(lay, x=-40.0, y=20.0, th=0.0)
    for _ in range(60):
        b.step(cmd(2.0))
    b.x, b.y, b.th = 25.0 - 0.7 - 0.2, 7.0, 0.0  # the estimate jumps
    out = b.step(cmd(2.0))
    assert is_zero(out)
    assert lay.status.forced_stop
    assert "emergency" in lay.status.stopped_reason
    assert kinds(lay)[-1] == "geofence-stop"


def test_aircraft_frame_zones_follow_the_placement():
    m = mission()
    lay = layer()
    nominal = m.nominal_placement()
    # a point 2 m in front of the eng1 inlet lip (x_F 8.3 - 2, y_F 5.75)
    p = nominal.to_airport_xy((6.3, 5.75))
    b = Bench(lay, x=float(p[0]), y=float(p[1]), th=0.0)
    b.step(cmd(0.0), move=False)
    d_nominal = lay.status.geofence_distance
    assert lay.status.geofence_zone == "eng1-inlet"
    moved = AircraftPlacement(nominal.x + 1.0, nominal.y, nominal.heading, nominal.origin_height)
    lay.set_placement(moved)
    b.step(cmd(0.0), move=False)
    assert lay.status.geofence_distance != pytest.approx(d_nominal)
    checker = zone_checker(m, moved)
    exact = clearance(footprint(b.x, b.y, b.th, m), checker)
    assert lay.status.geofence_distance == pytest.approx(exact, abs=1e-9)


def test_circle_zones_are_never_smaller_than_the_circle():
    m = with_circles(mission())
    lay = layer(m)
    b = Bench(lay, x=-30.0, y=-8.0 - 2.0 - 0.5 - 3.0, th=math.pi / 2, m=m)  # south of cone-a
    for _ in range(200):
        b.step(cmd(2.0))
    fp = footprint(b.x, b.y, b.th, m)
    assert fp.distance(Point(-30.0, -8.0)) - 2.0 >= lay.margin - 1e-6
    check_limits(b)


def test_far_from_every_zone_the_distance_is_a_lower_bound():
    lay = layer()
    b = Bench(lay)
    b.step(cmd(0.0), move=False)
    exact = clearance(footprint(b.x, b.y, b.th, mission()), zone_checker(mission(), placement()))
    assert 0.0 < lay.status.geofence_distance <= exact + 1e-9


# -- properties -----------------------------------------------------------------------------------
finite_or_not = st.one_of(
    st.floats(-3.0, 3.0),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, 1e9, -1e9, 2.0, -2.0]),
)
events = st.sampled_from(
    ["none"] * 6
    + ["obstacle", "slow", "bumper", "stale", "reset", "fault", "no-pose", "crawl", "crawl-near"]
)
NEAR = {"obstacle", "slow", "crawl-near"}  # an obstacle straight ahead, inside r_OA
tick = st.tuples(st.floats(-4.0, 4.0), st.floats(-3.0, 3.0), finite_or_not, events)
starts = st.sampled_from(
    [(-60.0, 10.0, 0.0), (20.0, 7.0, 0.0), (23.5, 4.0, 0.3), (6.0, -5.0, math.pi)]
)


def run_sequence(start, ticks) -> Bench:
    lay = layer()
    b = Bench(lay, *start)
    s = mission().safety
    for v, w, odd, event in ticks:
        if event == "fault":
            lay.fault(b.t, "test fault")
        command = cmd(v, w, ptz=(odd, -odd)) if event == "none" else cmd(odd, w)
        if event.startswith("crawl"):  # shaped as a retreat, either way
            command = cmd(math.copysign(0.5 * RETREAT_SPEED, v), 0.0)
        b.step(
            command,
            rc={"obstacle": s.r_es / 2, "slow": 1.2, "crawl-near": s.r_es / 2}.get(event, math.inf),
            bumper=event == "bumper",
            reset=event == "reset",
            scan_age=1.0 if event == "stale" else 0.0,
            pose=event != "no-pose",
        )
    return b


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(starts, st.lists(tick, min_size=1, max_size=80))
def test_property_every_output_within_the_platform_limits(start, ticks):
    b = run_sequence(start, ticks)
    check_limits(b)
    for status in b.statuses:
        if status.forced_stop:
            reason = status.stopped_reason
            assert reason.startswith(("e-stop", "fault", "stale")) or "emergency" in reason


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(starts, st.lists(tick, min_size=1, max_size=80))
def test_property_latched_means_zero_or_a_retreat(start, ticks):
    """While latched the output is zero, or (an obstacle latch only: never while a bumper
    latch waits for its reset) a straight crawl away from the obstacle
    (tests/test_retreat.py)."""
    b = run_sequence(start, ticks)
    for out, status, tick in zip(b.sent, b.statuses, ticks, strict=True):
        if status.estop_latched:
            assert set(out.pan_tilt) == set(mission().platform.cameras)
            if status.retreating:
                assert status.estop_cause == "obstacle"
                assert out.omega == 0.0 and abs(out.v) <= RETREAT_SPEED
                if tick[3] in NEAR:  # never towards an obstacle ahead
                    assert out.v <= 0.0
            else:
                assert is_zero(out)


def test_a_robot_still_turning_when_latched_stops_before_it_backs_out():
    """Found by the property above: latched while the base still turned (its angular
    speed ramping down under the rate limits), a retreat was let through at once and the
    output turned at 0.1 rad/s while "backing out straight". The layer stops first."""
    turn, crawl = (0.0, 1.0, 0.0, "none"), (-0.0, 0.0, 0.0, "crawl-near")
    b = run_sequence((-60.0, 10.0, 0.0), [turn, turn, crawl, crawl, crawl])
    assert b.sent[1].omega > 0.0  # turning when the latch came
    assert b.statuses[2].estop_latched and not b.statuses[2].retreating
    assert is_zero(b.sent[2])
    for out, status in zip(b.sent[3:], b.statuses[3:], strict=True):
        assert status.retreating and out.omega == 0.0 and out.v < 0.0


@pytest.mark.parametrize(("rolling", "from_the_wheels"), [(-0.7, True), (0.5, False)])
def test_after_a_stop_the_limits_start_from_the_speed_the_wheels_measure(rolling, from_the_wheels):
    """A robot backing away and turning is latched: the layer stops it (it still turns),
    and the base brakes on its own, its wheels still rolling at ``rolling``. The retreat
    that follows continues from that speed when the robot rolls its way, within one
    period's acceleration of it: from rest, the command braked a robot backing away from
    a chaser to a crawl, and the chaser reached it (A320 busy-apron episode 69). A robot
    rolling the other way is ramped from rest, as before."""
    lay = layer()
    b = Bench(lay)
    for _ in range(60):
        b.step(cmd(-0.8, -0.3))
    assert b.sent[-1].v == pytest.approx(-0.8) and b.sent[-1].omega < 0.0
    r_es = mission().safety.r_es
    retreat = cmd(-0.5 * RETREAT_SPEED, 0.0)
    b.wheel_speed = -0.75
    b.step(retreat, rc=r_es / 2)  # latched while turning: stopped first
    assert lay.status.forced_stop and is_zero(b.sent[-1])
    b.wheel_speed = rolling
    out = b.step(retreat, rc=r_es / 2)
    assert lay.status.estop_latched and lay.status.retreating
    step = mission().platform.max_acceleration * PERIOD + TOL
    start = rolling if from_the_wheels else 0.0
    assert abs(out.v - start) <= step and out.omega == 0.0
    for _ in range(60):  # then to the crawl within the limits, never past it
        b.wheel_speed = b.sent[-1].v
        previous, out = b.sent[-1].v, b.step(retreat, rc=r_es / 2)
        assert lay.status.retreating and abs(out.v - previous) <= step
        assert min(start, retreat.v) - TOL <= out.v <= 0.0
    assert out.v == pytest.approx(retreat.v)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(starts, st.lists(tick, max_size=60))
def test_property_bumper_latch_survives_anything_without_reset(start, ticks):
    ticks = [(v, w, odd, "none" if e == "reset" else e) for v, w, odd, e in ticks]
    b = run_sequence(start, [(1.0, 0.0, 0.0, "bumper"), *ticks])
    assert all(s.estop_latched and s.estop_cause == "bumper" for s in b.statuses)
    assert all(is_zero(out) for out in b.sent)


def adversary(rng: np.random.Generator, mode: str, bench: Bench, target: np.ndarray):
    """One command of an adversarial stream."""
    if mode == "charge":  # steer at the zone, full speed, some random omega
        want = math.atan2(target[1] - bench.y, target[0] - bench.x)
        err = (want - bench.th + math.pi) % (2 * math.pi) - math.pi
        return cmd(3.0, 2.0 * err + rng.normal(0.0, 0.5))
    if mode == "reverse-charge":  # back into it
        want = math.atan2(bench.y - target[1], bench.x - target[0])
        err = (want - bench.th + math.pi) % (2 * math.pi) - math.pi
        return cmd(-3.0, 2.0 * err + rng.normal(0.0, 0.5))
    if mode == "spin":
        return cmd(rng.uniform(-0.3, 0.3), rng.choice([-3.0, 3.0]))
    return cmd(rng.uniform(-4.0, 4.0), rng.uniform(-3.0, 3.0))  # "random"


def closed_loop(m: Mission, pl: AircraftPlacement, frame: Frame, seed: int, mode: str):
    rng = np.random.default_rng(seed)
    zones = [z for z in m.airport.zones if z.frame == frame]
    target_zone = zones[int(rng.integers(len(zones)))]
    checker = zone_checker(m, pl)
    geom = dict(checker)[target_zone.id]
    geom = geom[0].buffer(geom[1]) if isinstance(geom, tuple) else geom
    x0, y0, x1, y1 = geom.bounds
    while True:  # a start outside every zone, within a few metres of the target zone
        x = rng.uniform(x0 - 5.0, x1 + 5.0)
        y = rng.uniform(y0 - 5.0, y1 + 5.0)
        th = rng.uniform(-math.pi, math.pi)
        start_clearance = clearance(footprint(x, y, th, m), checker)
        if start_clearance > 0.0:
            break
    lay = SafetyLayer(m, pl, PERIOD)
    b = Bench(lay, x, y, th, m=m)
    centre = np.array(geom.centroid.coords[0])
    worst = math.inf
    switch = 0
    for k in range(160):
        if mode == "mixed" and k >= switch:
            current = rng.choice(["charge", "reverse-charge", "spin", "random"])
            switch = k + int(rng.integers(5, 40))
        b.step(adversary(rng, current if mode == "mixed" else mode, b, centre))
        d = clearance(footprint(b.x, b.y, b.th, m), checker)
        assert d > 0.0, (k, d, b.x, b.y, b.th)
        worst = min(worst, d)
    return b, start_clearance, worst


modes = st.sampled_from(["charge", "reverse-charge", "spin", "random", "mixed"])


def shifted_placement() -> AircraftPlacement:
    p = mission().nominal_placement()
    return AircraftPlacement(p.x + 0.8, p.y - 0.6, p.heading + 0.05, p.origin_height)


@pytest.mark.parametrize("frame", [Frame.AIRPORT, Frame.AIRCRAFT])
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1), mode=modes)
def test_property_closed_loop_never_enters_a_forbidden_zone(frame, seed, mode):
    m = with_circles(mission())
    b, start, worst = closed_loop(m, shifted_placement(), frame, seed, mode)
    lay = b.layer
    if start >= lay.buffer:
        # the braking invariant holds from the start: never closer than the buffer,
        # and never a forced stop, so every command respected the rate limits
        assert worst >= lay.buffer - 1e-6
        assert not any(s.forced_stop for s in b.statuses)
    check_limits(b)


@pytest.mark.parametrize("keep", ["none", "airport", "aircraft"])
def test_missions_with_fewer_zones(keep):
    m = mission()
    zones = tuple(z for z in m.airport.zones if z.frame.value == keep)
    m = dataclasses.replace(m, airport=dataclasses.replace(m.airport, zones=zones))
    lay = layer(m)
    b = Bench(lay, m=m)
    for _ in range(40):
        out = b.step(cmd(1.0))
    assert out.v == pytest.approx(1.0)
    assert (lay.status.geofence_zone is None) == (keep == "none")
    assert set(lay.zone_geometries) == {z.id for z in zones}


def test_slowdown_only_slows_motion_towards_the_obstacle():
    """An obstacle 1 m behind does not slow the robot driving forward (away from it), and
    does slow it backing up; a return ahead still slows it (speed-and-separation), one
    ahead but beside the corridor the robot sweeps (half its width + r_ES) does not."""
    s = mission().safety
    expect = max(0.2, (1.0 - s.r_es) / (s.r_oa_trigger - s.r_es))
    behind = np.array([[-0.7 - 1.0, 0.0]])  # 1 m behind the 1.4 m footprint's rear
    ahead = np.array([[0.7 + 1.0, 0.0]])
    aside = np.array([[0.7 + 1.0, 0.5 * mission().platform.width + s.r_es + 0.05]])
    cases = ((behind, 1.5, 1.0), (behind, -1.0, expect), (ahead, 1.5, expect), (aside, 1.5, 1.0))
    for points, v, scale in cases:
        lay = layer()
        b = Bench(lay)
        for _ in range(100):
            out = lay.filter(
                cmd(v),
                now=b.t,
                frame=b.frame(0.0, False),
                pose=b.pose(),
                obstacles=Obstacles(b.t, 1.0, math.atan2(points[0, 1], points[0, 0]), points),
            )
            b.t = round(b.t + PERIOD, 9)
        assert lay.status.speed_scale == pytest.approx(scale)
        assert out.v == pytest.approx(v * scale)


def _walker(x: float, y: float, vx: float, vy: float) -> TrackedObstacle:
    """A tracked person in the robot frame: circle of 0.3 m, footprint clearance from the
    1.4 m x 1.0 m footprint's front corner region (approximately, enough for the scale)."""
    clearance = math.hypot(max(0.0, abs(x) - 0.7), max(0.0, abs(y) - 0.5)) - 0.3
    return TrackedObstacle(1, "circle", (x, y), (vx, vy), np.eye(4), 0.3, clearance, 5.0)


def _near_side(x: float, y: float, radius: float = 0.3) -> np.ndarray:
    """The returns a laser at the robot's axle gets from a circle at (x, y): its half
    facing the robot."""
    facing = math.atan2(-y, -x)
    angles = facing + np.linspace(-0.5 * math.pi, 0.5 * math.pi, 9)
    return np.column_stack((x + radius * np.cos(angles), y + radius * np.sin(angles)))


@pytest.mark.parametrize(
    "walker, v, slowed",
    [
        # 1.8 m ahead, 2.2 m to the left, walking right across the way at 0.5 m/s: in the
        # corridor (half-width 0.5 + r_ES + 0.3 m) in under 3 s -> slowed before it is there
        ((1.8, 2.2, 0.0, -0.5), 1.0, True),
        # the same walker walking away from the way: not slowed
        ((1.8, 2.2, 0.0, 0.5), 1.0, False),
        # the same walker, but too slow to reach the corridor within the horizon
        ((1.8, 2.2, 0.0, -0.2), 1.0, False),
        # a chaser behind the robot, coming up the corridor: never slows the robot down
        ((-1.8, 0.3, 0.8, 0.0), 1.0, False),
        # a walker crossing ahead that the robot, at this speed, passes before it gets
        # there: it enters the corridor behind the axle
        ((0.9, 2.0, 0.0, -0.6), 1.5, False),
        # a walker behind the robot and beside its reversing corridor, walking into it:
        # slows the robot backing up (no return in that corridor yet)
        ((-1.8, 2.2, 0.0, -0.5), -0.5, True),
    ],
)
def test_slowdown_for_a_mover_about_to_enter_the_corridor(walker, v, slowed):
    """Speed-and-separation with the tracked motion: a mover ahead that will step into
    the corridor within ``mover_horizon`` (3 s), moving relative to the robot, slows it
    now; one walking away, too slow, chasing from behind, or passed first does not."""
    x, y, vx, vy = walker
    mover = _walker(x, y, vx, vy)
    lay = layer()
    b = Bench(lay)
    points = _near_side(x, y)
    for _ in range(60):
        lay.filter(
            cmd(v),
            now=b.t,
            frame=b.frame(0.0, False),
            pose=b.pose(),
            obstacles=Obstacles(b.t, mover.clearance, math.atan2(y, x), points, (mover,)),
        )
        b.t = round(b.t + PERIOD, 9)
    assert (lay.status.speed_scale < 1.0) == slowed


@pytest.mark.parametrize(
    "velocity, slowed",
    [
        # a partial view slides the centroid of a static wall along it: not a mover
        ((-0.5, 0.0), False),
        # the same segment (a trolley's long side) moving across itself into the way,
        # 1.5 m from the corridor's edge at 0.8 m/s: there in 1.9 s, still ahead of the
        # axle (at 0.5 m/s it would get there behind the robot, driving at 1 m/s)
        ((0.0, -0.8), True),
        ((0.0, -0.5), False),
    ],
)
def test_a_line_counts_as_a_mover_only_for_its_motion_across_itself(velocity, slowed):
    """A 2 m segment beside the corridor, parallel to the robot's axis (x 1.5-3.5 m, y
    2.6 m): its motion along itself is unobservable (the aperture problem), so only a
    motion across it can bring it into the corridor within the horizon."""
    clearance = math.hypot(1.5 - 0.7, 2.6 - 0.5)
    wall = TrackedObstacle(
        1, "line", (2.5, 2.6), velocity, np.eye(4), 1.0, clearance, 5.0, shape=(1.5, 2.6, 3.5, 2.6)
    )
    lay = layer()
    b = Bench(lay)
    points = np.array([[1.5, 2.6], [3.5, 2.6]])
    for _ in range(60):
        lay.filter(
            cmd(1.0),
            now=b.t,
            frame=b.frame(0.0, False),
            pose=b.pose(),
            obstacles=Obstacles(b.t, clearance, math.atan2(2.6, 1.5), points, (wall,)),
        )
        b.t = round(b.t + PERIOD, 9)
    assert (lay.status.speed_scale < 1.0) == slowed
