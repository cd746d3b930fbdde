"""Every sensor is watched (issue 12 §5): the freshness law, the safety layer's policy per
sensor kind (motion sensors stop the robot, mission sensors are reported), the inspection
that only counts fresh images, and a dry-run with a frozen camera.

Properties (hypothesis): for any stamp sequence a sensor is stale iff the age of the data
in hand exceeds its limit; for any camera image sequence, a run of identical non-empty
images is stale from its first image; in the safety layer, for random per-sensor delays,
the robot is stopped iff a motion sensor is stale, and every sensor's health says stale
iff its delay exceeds its limit.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np
import py_trees
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from behaviours.controllers.inspection import InspectItems
from behaviours.keys import COMMAND, FEATURES, POSE, PROGRESS, SENSOR_FRAME, MissionProgress
from behaviours.laws.freshness import Freshness
from behaviours.sensing.features import SenseFeatures
from executive.core.frames import Pose2, aircraft_from_robot, pan_tilt_towards
from executive.core.loader import load_mission
from executive.core.model import Mission
from executive.core.records import (
    Bumpers,
    CameraFrame,
    Detection,
    GpsFix,
    ImuReading,
    LaserScan,
    Obstacles,
    PanTilt,
    PanTiltRate,
    PoseEstimate,
    SensorFrame,
    VelocityCommand,
    WheelSpeeds,
    camera_ids,
)
from executive.dryrun import dry_run
from executive.safety import (
    SENSOR_DEGRADED,
    SENSOR_FRESH,
    SENSOR_RECOVERED,
    STALE_SENSOR,
    SafetyLayer,
)
from tests.conftest import SHIPPED_MISSIONS
from tests.sim2d_helpers import make_scenario

PERIOD = 0.02


# -- the freshness law ----------------------------------------------------------------------------
def test_a_sensor_is_stale_once_its_last_new_reading_is_older_than_the_limit():
    f = Freshness(0.1)
    assert f.stale(0.0)  # never reported
    assert f.observe(1.0)
    assert not f.stale(1.09) and f.stale(1.1001)
    assert not f.observe(1.0)  # the same reading again is not new
    assert f.last_fresh == 1.0
    assert f.observe(1.05) and f.last_fresh == 1.05
    assert not f.observe(math.nan) and not f.observe(None)
    assert not f.observe(0.5)  # a reading older than the last: the data in hand is that old
    assert f.last_fresh == 0.5 and f.stale(1.0)


def test_a_camera_repeating_its_image_with_fresh_stamps_is_stale():
    image = (Detection("nose", 0, 100.25, 200.5),)
    f = Freshness(0.12, repeats_are_stale=True)
    assert f.observe(1.0, image)
    for k in range(1, 10):  # the same detections, new stamps: nothing new
        assert not f.observe(1.0 + 0.04 * k, (Detection("nose", 0, 100.25, 200.5),))
    assert f.last_fresh == 1.0 and f.last_stamp == pytest.approx(1.36)
    assert f.stale(1.36)
    assert f.observe(1.40, (Detection("nose", 0, 100.3, 200.5),))  # live again
    assert not f.stale(1.40)
    # nothing seen is not evidence of a frozen camera
    assert f.observe(1.44, None) and f.observe(1.48, None)


reading = st.one_of(st.none(), st.floats(-5.0, 5.0), st.just(math.nan))


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(reading, st.floats(0.0, 1.0)), max_size=40), st.floats(0.0, 1.0))
def test_property_stale_iff_the_data_in_hand_is_older_than_the_limit(readings, limit):
    """Reference model: the data in hand is the latest finite reading; its age is ``now``
    (which only goes forward) minus its stamp."""
    f = Freshness(limit)
    now, in_hand = -10.0, None
    for stamp, dt in readings:
        now += dt
        f.observe(stamp)
        if stamp is not None and math.isfinite(stamp):
            in_hand = stamp
        expected = in_hand is None or now - in_hand > limit
        assert f.stale(now) == expected


@settings(max_examples=200, deadline=None)
@given(st.lists(st.sampled_from([None, "a", "b"]), min_size=1, max_size=40))
def test_property_a_repeated_image_is_stale_from_its_first_showing(contents):
    """Frames every 0.04 s with contents drawn from a few images: the last fresh stamp is
    the first frame of the current run of identical non-empty images."""
    f = Freshness(0.12, repeats_are_stale=True)
    first = None
    previous = object()
    for k, content in enumerate(contents):
        stamp = 0.04 * k
        f.observe(stamp, content)
        if content is None or content != previous:
            first = stamp
        previous = content
        assert f.last_fresh == first
        assert f.stale(stamp) == (stamp - first > 0.12)


# -- the safety layer, per sensor -----------------------------------------------------------------
@functools.cache
def mission() -> Mission:
    return load_mission(SHIPPED_MISSIONS["a320"])


class Feed:
    """Drives a SafetyLayer with a full sensor frame each period, any sensor held back.

    ``held[key] = t0`` keeps sensor ``key`` at its reading of time t0 (its stamp frozen);
    ``repeat[camera] = t0`` keeps the camera's image of t0 with fresh stamps (a frozen
    pipeline); ``dropped`` sensors are absent from the frame.
    """

    def __init__(self, **kw: object) -> None:
        self.m = mission()
        self.layer = SafetyLayer(self.m, self.m.nominal_placement(), PERIOD, **kw)
        self.t = 0.0
        self.held: dict[str, float] = {}
        self.repeat: dict[str, float] = {}
        self.dropped: set[str] = set()
        self.sent: list[VelocityCommand] = []

    def stamp(self, key: str) -> float:
        return self.held.get(key, self.t)

    def image(self, camera: str) -> CameraFrame:
        t = self.stamp(f"camera:{camera}")
        shot = self.repeat.get(camera, t)
        # pixel noise: a live image never repeats its detections
        return CameraFrame(t, (Detection("radome", 0, 400.0 + 13.7 * shot % 1.0, 300.0),))

    def frame(self) -> SensorFrame:
        p = self.m.platform
        cams = [c for u in p.cameras for c in camera_ids(p, u)]
        on = [k for k in ("wheels", "imu", "gps") if k not in self.dropped]
        return SensorFrame(
            self.t,
            scans={
                lid: LaserScan(self.stamp(f"laser:{lid}"), -2.0, 0.01, 30.0, np.full(3, 30.0))
                for lid in p.lasers
                if f"laser:{lid}" not in self.dropped
            },
            cameras={c: self.image(c) for c in cams if f"camera:{c}" not in self.dropped},
            pan_tilt={
                u: PanTilt(self.stamp(f"ptu:{u}"), 0.1, 0.0)
                for u in p.cameras
                if f"ptu:{u}" not in self.dropped
            },
            wheels=WheelSpeeds(self.stamp("wheels"), 0.5, 0.5) if "wheels" in on else None,
            imu=ImuReading(self.stamp("imu"), 0.0) if "imu" in on else None,
            gps=GpsFix(self.stamp("gps"), -60.0, 10.0, 0.03) if "gps" in on else None,
            bumpers=Bumpers(self.t),
        )

    def step(self, command: VelocityCommand | None = None) -> VelocityCommand:
        p = Pose2(-60.0, 10.0, 0.0)
        pl = self.layer.placement
        pose = PoseEstimate(self.t, p, np.eye(3) * 1e-4, pl.pose_to_aircraft(p), 1.0)
        out = self.layer.filter(
            command or VelocityCommand(0.5, 0.0, {"ptz": PanTiltRate(0.2, 0.1)}),
            now=self.t,
            frame=self.frame(),
            pose=pose,
            obstacles=Obstacles(self.t, math.inf, 0.0, np.zeros((0, 2))),
        )
        self.sent.append(out)
        self.t = round(self.t + PERIOD, 9)
        return out

    def run(self, seconds: float) -> VelocityCommand:
        out = VelocityCommand()
        for _ in range(round(seconds / PERIOD)):
            out = self.step()
        return out

    def events(self) -> list[tuple[str, str]]:
        return [(e.kind, e.reason) for e in self.layer.events]


MOTION = ["laser:front", "laser:rear", "wheels", "imu"]
MISSION = ["camera:front-left", "camera:ptz", "ptu:ptz", "ptu:front", "gps"]


@pytest.mark.parametrize("key", MOTION)
def test_a_stale_motion_sensor_stops_the_robot_until_it_is_fresh(key):
    feed = Feed()
    assert feed.run(1.0).v > 0.0 and not feed.events()
    feed.held[key] = feed.t - PERIOD  # frozen at its last reading, 0.98 s
    limit = feed.layer.sensor_health[key].limit
    out = feed.run(limit + 3 * PERIOD)
    assert out.v == 0.0 and out.omega == 0.0 and feed.layer.status.forced_stop
    label = feed.layer.sensor_health[key].label
    [(kind, reason)] = feed.events()
    assert kind == STALE_SENSOR
    assert reason.startswith(f"{label} stale from 0.98 s") and "old >" in reason
    assert feed.layer.status.stopped_reason == "stale: " + feed.layer._stale[key]
    del feed.held[key]
    assert feed.run(0.5).v > 0.0
    assert [k for k, _ in feed.events()] == [STALE_SENSOR, SENSOR_FRESH]
    [interval] = feed.layer.stale_intervals()[key]
    assert interval.since == pytest.approx(0.98)
    assert interval.detected == pytest.approx(0.98 + limit, abs=PERIOD + 1e-9)
    assert interval.until is not None and interval.until > interval.detected
    assert all(not v for k, v in feed.layer.stale_intervals().items() if k != key)


@pytest.mark.parametrize("key", MISSION)
def test_a_stale_mission_sensor_is_reported_and_the_robot_keeps_going(key):
    feed = Feed()
    feed.run(1.0)
    feed.held[key] = feed.t - PERIOD
    limit = feed.layer.sensor_health[key].limit
    out = feed.run(limit + 3 * PERIOD)
    assert out.v > 0.0 and not feed.layer.status.forced_stop
    health = feed.layer.sensor_health[key]
    assert health.stale and not health.stops
    [(kind, reason)] = feed.events()
    assert kind == SENSOR_DEGRADED
    assert reason.startswith(f"{health.label} stale from 0.98 s")
    del feed.held[key]
    feed.run(0.2)
    assert [k for k, _ in feed.events()] == [SENSOR_DEGRADED, SENSOR_RECOVERED]
    assert "fresh again" in feed.events()[1][1] and "stale from 0.98 s" in feed.events()[1][1]
    [interval] = feed.layer.stale_intervals()[key]
    assert interval.since == pytest.approx(0.98) and interval.until is not None
    assert health.stale_seconds(end=99.0) == pytest.approx(interval.until - 0.98)


def test_a_camera_repeating_its_image_content_is_degraded_from_the_frozen_shot():
    feed = Feed()
    feed.run(2.0)
    feed.repeat["ptz"] = 1.98  # the pipeline repeats the image of 1.98 s, stamps go on
    feed.run(1.0)
    [(kind, reason)] = feed.events()
    assert kind == SENSOR_DEGRADED
    assert reason.startswith("camera 'ptz' stale from 1.98 s: it repeats that image")
    health = feed.layer.sensor_health["camera:ptz"]
    assert health.stale and health.intervals[0].since == pytest.approx(1.98)
    del feed.repeat["ptz"]
    feed.run(0.1)
    assert not health.stale
    assert health.stale_seconds(end=10.0) == pytest.approx(health.intervals[0].until - 1.98)


def test_a_camera_that_sees_nothing_is_not_taken_for_a_frozen_one():
    feed = Feed()
    feed.image = lambda camera: CameraFrame(feed.stamp(f"camera:{camera}"))  # type: ignore[method-assign]
    feed.run(2.0)
    assert not feed.events()


def test_a_camera_frozen_on_an_empty_image_is_caught_by_its_image_id():
    """Seeing nothing is no evidence by itself, but an image id that repeats is."""
    feed = Feed()
    shots: dict[str, int] = {}  # images captured per camera: their ids

    def image(camera: str) -> CameraFrame:
        if camera not in feed.repeat:
            shots[camera] = shots.get(camera, 0) + 1
        return CameraFrame(feed.stamp(f"camera:{camera}"), (), shots[camera])

    feed.image = image  # type: ignore[method-assign]
    feed.run(1.0)
    assert not feed.events()
    feed.repeat["ptz"] = 0.98
    feed.run(0.5)
    [(kind, reason)] = feed.events()
    assert kind == SENSOR_DEGRADED and reason.startswith("camera 'ptz' stale from 0.98 s")


def test_a_stale_pan_tilt_unit_is_not_driven_blind():
    feed = Feed()
    feed.run(0.5)
    assert feed.sent[-1].pan_tilt["ptz"] == PanTiltRate(0.2, 0.1)
    feed.held["ptu:ptz"] = feed.t - PERIOD
    out = feed.run(0.5)
    assert out.pan_tilt["ptz"] == PanTiltRate() and out.v > 0.0
    del feed.held["ptu:ptz"]
    assert feed.run(0.1).pan_tilt["ptz"] == PanTiltRate(0.2, 0.1)


@pytest.mark.parametrize("key", ["wheels", "imu", "laser:front"])
def test_a_motion_sensor_missing_from_the_frame_stops_at_once(key):
    feed = Feed()
    feed.run(0.5)
    feed.dropped.add(key)
    assert feed.step().v == 0.0
    [(kind, reason)] = feed.events()
    assert kind == STALE_SENSOR and "stale from 0.48 s" in reason


def test_gps_loss_is_degraded_after_its_limit_and_the_interval_is_kept_open():
    feed = Feed()
    feed.run(1.0)
    feed.dropped.add("gps")
    feed.run(2.9)
    assert not feed.events()  # a short gap is no event
    feed.run(0.2)
    [(kind, reason)] = feed.events()
    assert kind == SENSOR_DEGRADED and reason == "GPS stale from 0.98 s: no fix"
    [interval] = feed.layer.stale_intervals()["gps"]
    assert interval.until is None and interval.duration(end=10.0) == pytest.approx(9.02)


def test_stale_limits_can_be_set_per_sensor():
    feed = Feed(stale_limits={"gps": 0.5, "camera:ptz": 1.0})
    assert feed.layer.sensor_health["gps"].limit == 0.5
    assert feed.layer.sensor_health["camera:ptz"].limit == 1.0
    # the platform's cameras run at 25 Hz: three periods
    assert feed.layer.sensor_health["camera:front-left"].limit == pytest.approx(0.12)


ALL = MOTION + MISSION + ["camera:rear-right", "ptu:rear"]


@settings(max_examples=40, deadline=None)
@given(st.lists(st.tuples(st.sampled_from(ALL), st.floats(0.0, 0.4)), max_size=5))
def test_property_health_and_stop_follow_the_age_of_each_sensor(delays):
    """Sensors held back by random delays: a sensor's health is stale iff its data is
    older than its limit, and the robot is stopped iff a motion sensor is stale."""
    feed = Feed()
    feed.run(1.0)
    lag = dict(delays)
    for _ in range(20):
        for key, d in lag.items():
            feed.held[key] = round(feed.t - d, 9)
        out = feed.step()
        now = round(feed.t - PERIOD, 9)
        stopped = False
        for key, health in feed.layer.sensor_health.items():
            age = now - feed.held.get(key, now)
            if key in lag and age > health.limit + 1e-9:
                assert health.stale, (key, age)
                stopped |= health.stops
            elif key in lag and age < health.limit - 1e-9:
                assert not health.stale, (key, age)
            elif key not in lag:
                assert not health.stale, key
        assert (out.v == 0.0) == stopped or any(
            abs(now - feed.held[k] - feed.layer.sensor_health[k].limit) <= 1e-9 for k in lag
        )


# -- features from fresh images only ---------------------------------------------------------------
def test_features_leave_out_a_frozen_camera_and_name_it():
    py_trees.blackboard.Blackboard.clear()
    m = load_mission(SHIPPED_MISSIONS["lab"])
    node = SenseFeatures(m.platform)
    assert node.limits["front-left"] == pytest.approx(3.0 / m.platform.cameras["front"].rate_hz)
    bb = py_trees.blackboard.Client(name="test")
    bb.register_key(key=SENSOR_FRAME.name, access=py_trees.common.Access.WRITE)
    bb.register_key(key=FEATURES.name, access=py_trees.common.Access.READ)
    frozen = (Detection("target-1", 0, 10.0, 20.0),)
    seen = []
    for k in range(10):
        t = 0.04 * k
        live = (Detection("target-1", 0, 10.0 + 0.1 * k, 20.0),)
        images = {"ptz": CameraFrame(t, live), "front-left": CameraFrame(t, frozen)}
        frame = SensorFrame(t, cameras=images)
        bb.set(SENSOR_FRAME.name, frame, overwrite=True)
        node.tick_once()
        seen.append(bb.get(FEATURES.name))
    assert all(obs.by_camera["ptz"] for obs in seen)
    # fresh until its first image is older than three periods, then left out and named
    assert [("front-left" in obs.by_camera) for obs in seen] == [True] * 4 + [False] * 6
    assert all(obs.stale == ("front-left",) for obs in seen[4:])
    assert not seen[-1].visible("target-1", "front")


# -- the inspection counts fresh images only ------------------------------------------------------
LAB = {"mission_type": "lab", "mission": "visual-servoing.xml"}


class Inspection:
    """InspectItems of the lab's CP1 on a blackboard, fed synthetic frames."""

    def __init__(self) -> None:
        py_trees.blackboard.Blackboard.clear()
        m = load_mission(SHIPPED_MISSIONS["lab"])
        self.m = m
        cp = m.checkpoints[0]
        self.unit = m.platform.cameras["ptz"]
        self.item = cp.items[0]
        self.feature = m.aircraft.items[self.item].feature
        self.node = InspectItems(cp.id, cp.items, m.aircraft, self.unit, ("ptz",))
        self.bb = py_trees.blackboard.Client(name="test")
        for key in (SENSOR_FRAME, POSE, PROGRESS):
            self.bb.register_key(key=key.name, access=py_trees.common.Access.WRITE)
        self.bb.register_key(key=COMMAND.name, access=py_trees.common.Access.READ)
        pose_f = cp.pose  # standing on the checkpoint (F = A here is not needed)
        self.pose = PoseEstimate(0.0, pose_f, np.eye(3) * 1e-4, pose_f, 1.0)
        target = (
            aircraft_from_robot(pose_f, m.aircraft.origin_height)
            .inverse()
            .apply(m.aircraft.feature_of(self.item).centroid())
        )
        self.aim = pan_tilt_towards(self.unit.mount, self.unit.mount_yaw, target)
        self.bb.set(PROGRESS.name, MissionProgress(), overwrite=True)
        self.t = 0.0

    def tick(
        self, image: CameraFrame | None, angles_stamp: float | None = None, angles: bool = True
    ) -> None:
        """One tick at ``self.t`` with the unit on its aim; none once the node succeeded
        (the mission's sequence does not tick a finished child again)."""
        if self.node.status == py_trees.common.Status.SUCCESS:
            return
        pan, tilt = self.aim
        stamp = self.t if angles_stamp is None else angles_stamp
        frame = SensorFrame(
            self.t,
            cameras={"ptz": image} if image is not None else {},
            pan_tilt={"ptz": PanTilt(stamp, pan, tilt)} if angles else {},
        )
        self.bb.set(SENSOR_FRAME.name, frame, overwrite=True)
        self.bb.set(POSE.name, dataclasses.replace(self.pose, stamp=self.t), overwrite=True)
        self.node.tick_once()
        self.t = round(self.t + 0.04, 9)

    def seen(self, shot: float) -> tuple[Detection, ...]:
        return (Detection(self.feature, 0, 500.0 + (7.3 * shot) % 1.0, 400.0),)

    def results(self):
        return self.bb.get(PROGRESS.name).results


def test_a_frozen_camera_showing_the_item_from_before_the_checkpoint_does_not_count():
    """The image was taken before the node started (before the checkpoint was reached);
    the camera goes on publishing it with fresh stamps: never detected, recorded stale."""
    run = Inspection()
    old = run.seen(-5.0)
    for _ in range(round(run.node.item_timeout / 0.04) + 2):
        run.tick(CameraFrame(run.t, old))
    [result] = run.results()
    assert not result.detected and result.stale
    assert result.stamp == pytest.approx(run.node.item_timeout, abs=0.05)


def test_a_camera_frozen_on_an_image_without_the_item_is_recorded_stale():
    """A frozen image that shows nothing: its repeated image id gives it away, so the
    item is recorded stale (not merely not seen)."""
    run = Inspection()
    for _ in range(round(run.node.item_timeout / 0.04) + 2):
        run.tick(CameraFrame(run.t, (), 7))
    [result] = run.results()
    assert not result.detected and result.stale


def test_a_live_camera_showing_the_item_counts_at_once():
    run = Inspection()
    for _ in range(5):
        run.tick(CameraFrame(run.t, run.seen(run.t)))
    [result] = run.results()
    assert result.detected and not result.stale
    assert result.stamp < 0.2


def test_an_image_stamped_before_the_aim_does_not_count():
    run = Inspection()
    for _ in range(round(run.node.item_timeout / 0.04) + 2):
        run.tick(CameraFrame(-1.0, run.seen(-1.0)))  # a camera whose stamp is stuck
    [result] = run.results()
    assert not result.detected and result.stale


def test_a_short_freeze_delays_the_item_and_the_fresh_image_decides():
    run = Inspection()
    old = run.seen(-5.0)
    for _ in range(50):  # 2 s frozen
        run.tick(CameraFrame(run.t, old))
    assert not run.results()
    for _ in range(3):
        run.tick(CameraFrame(run.t, run.seen(run.t)))
    [result] = run.results()
    assert result.detected and not result.stale and 2.0 <= result.stamp < 2.2


def test_a_live_camera_not_seeing_the_item_is_not_stale():
    run = Inspection()
    for _ in range(40):
        run.tick(CameraFrame(run.t, (Detection("elsewhere", 0, 10.0 + run.t, 10.0),)))
    [result] = run.results()
    assert not result.detected and not result.stale
    assert result.stamp <= run.node.look_time + 0.1


@pytest.mark.parametrize("angles", ["stale", "missing"])
def test_stale_pan_tilt_angles_are_not_aimed_with(angles):
    run = Inspection()
    for _ in range(round(run.node.item_timeout / 0.04) + 2):
        run.tick(CameraFrame(run.t, run.seen(run.t)), angles_stamp=-1.0, angles=angles == "stale")
        assert run.bb.get(COMMAND.name).pan_tilt.get("ptz", PanTiltRate()) == PanTiltRate()
    [result] = run.results()
    assert not result.detected and result.stale


frame_kinds = st.sampled_from(["repeat", "live-item", "live-other", "stuck", "none"])


@settings(max_examples=100, deadline=None)
@given(st.lists(frame_kinds, min_size=1, max_size=40))
def test_property_an_item_is_detected_iff_a_fresh_image_after_the_aim_shows_it(kinds):
    """Any sequence of camera frames (a repeat of the previous image with a new stamp, a
    live image with or without the item, the same frame again, no frame), the first one
    possibly an image from before the node started: the item is detected exactly at the
    first image that is new (later stamp, other content than the previous image the node
    saw; the first image it sees is only a reference), stamped after the aim, and shows
    the item."""
    run = Inspection()
    previous: CameraFrame | None = CameraFrame(-0.04, run.seen(-5.0))  # before the node
    expected: float | None = None
    shown: CameraFrame | None = None
    first_stamp: float | None = None
    fresh = 0  # fresh images since the aim; the look ends look_time after it if any came
    judged = False
    for k, kind in enumerate(kinds):
        if judged:
            break
        t = run.t
        if kind == "repeat":
            image = CameraFrame(t, previous.detections if previous else ())
        elif kind == "live-item":
            image = CameraFrame(t, run.seen(t))
        elif kind == "live-other":
            image = CameraFrame(t, (Detection("elsewhere", 0, 5.0 + t, 5.0),))
        elif kind == "stuck":  # the same frame again, stamp and all
            image = previous
        else:
            image = None
        if image is not None:
            new = (
                shown is not None
                and image.stamp > shown.stamp
                and (not image.detections or image.detections != shown.detections)
            )
            if shown is None:
                first_stamp = image.stamp
            aimed = k > 0 or image.stamp > 0.0  # aimed at the first tick (t = 0)
            if new and aimed and image.stamp > 0.0:
                fresh += 1
                if kind == "live-item":
                    expected, judged = t, True
            shown = image
            previous = image
        if fresh and t >= run.node.look_time:
            judged = True  # looked long enough, on fresh images that did not show it
        run.tick(image)
    results = run.results()
    detected = [r for r in results if r.detected]
    if expected is None:
        assert not detected
    else:
        assert len(detected) == 1 and detected[0].stamp == pytest.approx(expected)
        assert not detected[0].stale
    assert first_stamp is None or all(r.stamp >= 0.0 for r in results)


# -- end to end -----------------------------------------------------------------------------------
@pytest.mark.slow
def test_dry_run_with_the_ptz_frozen_before_the_second_checkpoint(tmp_path):
    """The lab run (CP1 inspected at about 15 s, CP2 from about 28 s): the PTZ camera
    freezes at 20 s for good. CP1's item is detected; CP2's two items are not (each waits
    its timeout for a fresh image), and are recorded stale; the camera's staleness is one
    event naming it and the time of its last fresh image; the robot is never stopped for
    it."""
    fault = '<faults><camera-freeze camera="ptz" at="20" duration="200"/></faults>'
    run = dry_run(make_scenario(tmp_path, fault, **LAB), max_time=55.0)
    results = run.result.progress.results
    assert [r.checkpoint for r in results] == ["CP1", "CP2", "CP2"]
    assert results[0].detected and not results[0].stale
    later = results[1:]
    assert all(not r.detected and r.stale for r in later)
    safety = [e.detail for e in run.result.events if e.kind == "safety"]
    degraded = [d["reason"] for d in safety if d["kind"] == SENSOR_DEGRADED]
    # the last live image is the one of 19.96 s (25 Hz); the camera repeats it from 20.0 s
    stale_from = "camera 'ptz' stale from 19.96 s: it repeats that image"
    assert degraded == [f"{stale_from} (no new one for over 0.120 s)"]
    assert not [d for d in safety if d["kind"] == STALE_SENSOR]
    assert {c.id for c in run.checkpoints if c.reached} == {"CP1", "CP2"}


@pytest.mark.slow
@pytest.mark.parametrize(
    ("fault", "label"), [("wheel-freeze", "wheel encoders"), ("imu-freeze", "IMU")]
)
def test_dry_run_with_frozen_odometry_stops_the_robot_while_it_lasts(tmp_path, fault, label):
    """The lab run, the wheel encoders (or the IMU) frozen from 6 s to 9 s, while the robot
    drives to CP1: it is stopped within a few ticks of the limit, the reason names the
    sensor and its last fresh reading, and it drives on once the readings are fresh."""
    faults = f'<faults><{fault} at="6" duration="3"/></faults>'
    run = dry_run(make_scenario(tmp_path, faults, **LAB), max_time=12.0)
    assert any(s.v > 0.1 for s in run.samples if 5.0 <= s.t < 6.0)
    stopped = [s for s in run.samples if 6.3 <= s.t < 9.0]
    assert stopped and all(s.v == 0.0 and s.omega == 0.0 for s in stopped)
    assert any(s.v > 0.0 for s in run.samples if s.t > 9.5)
    safety = [(e.t, e.detail) for e in run.result.events if e.kind == "safety"]
    stale = [(t, d["reason"]) for t, d in safety if d["kind"] == STALE_SENSOR]
    assert len(stale) == 1
    t, reason = stale[0]
    assert reason.startswith(f"{label} stale from 6.00 s: reading") and 6.2 <= t <= 6.25
    fresh = [t for t, d in safety if d["kind"] == SENSOR_FRESH]
    assert len(fresh) == 1 and 9.0 <= fresh[0] < 9.1


@pytest.mark.slow
def test_dry_run_with_the_pan_tilt_angles_frozen_during_the_first_inspection(tmp_path):
    """The PTZ unit's angles stop being published at 12 s, before CP1 is reached (about
    14 s), until 42 s: CP1's item cannot be aimed at and is recorded stale, not detected;
    a degraded event names the unit; the robot is never stopped for it."""
    faults = '<faults><ptu-freeze camera="ptz" at="12" duration="30"/></faults>'
    run = dry_run(make_scenario(tmp_path, faults, **LAB), max_time=35.0)
    [first, *_] = run.result.progress.results
    assert first.checkpoint == "CP1" and first.stale and not first.detected
    safety = [e.detail for e in run.result.events if e.kind == "safety"]
    degraded = [d["reason"] for d in safety if d["kind"] == SENSOR_DEGRADED]
    assert degraded == ["pan-tilt unit 'ptz' stale from 12.00 s: reading 0.140 s old > 0.120 s"]
    assert not [d for d in safety if d["kind"] == STALE_SENSOR]
