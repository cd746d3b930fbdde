"""sim2d's implementation of :class:`executive.core.robot.RobotInterface`.

:class:`SimRobot` owns a :class:`~sim2d.world.World` and samples every sensor at its own
rate on the simulated clock (lasers 40 Hz, cameras 25 Hz as the platform says; wheels
50 Hz, IMU 100 Hz, GPS as the scenario says), applies the scenario's faults, and keeps the
latest reading of each for :meth:`read`. A frozen sensor (laser dropout, wheel, IMU or
pan-tilt freeze) keeps its last reading with its old stamp, as a driver that stopped
publishing would; a frozen camera goes on publishing its last image (same image id, see
:class:`~executive.core.records.CameraFrame`) with fresh stamps.
The runtime calls :meth:`send` with a command and :meth:`advance` to let simulated time
pass.

What the robot would see is kept apart from ground truth: :attr:`truth` (poses, contacts)
is for reports and tests only, and both can be logged as JSONL that is identical, byte
for byte, for the same scenario and seed.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

import numpy as np
from numpy.typing import NDArray

from executive.core.frames import Pose2
from executive.core.records import (
    Bumpers,
    CameraFrame,
    CeilingImage,
    GpsFix,
    ImuReading,
    LaserScan,
    PanTilt,
    SensorFrame,
    VelocityCommand,
    WheelSpeeds,
)
from sim2d.cameras import CameraRig, FeatureCloud, PanTiltUnit, camera_rigs, detect
from sim2d.ceiling import CeilingTexture, UpwardCamera, render, upward_camera_for, walker
from sim2d.scenario import (
    Chaser,
    Fault,
    FaultKind,
    ObstacleKind,
    PathMover,
    Scenario,
    ScenarioCeiling,
    lamps_off_at,
)
from sim2d.sensors import (
    Gps,
    Imu,
    LaserSensor,
    WheelEncoders,
    scan_lasers,
    sight_lines_blocked,
)
from sim2d.world import Collision, World

WHEEL_RATE_HZ = 50.0
IMU_RATE_HZ = 100.0
TRUTH_RATE_HZ = 10.0


class _Schedule:
    """Fires every ``1/rate`` seconds of simulated time, counted in whole periods."""

    def __init__(self, rate_hz: float, name: str) -> None:
        self.period = 1.0 / rate_hz
        self.name = name
        self.count = 0

    def due(self, t: float) -> bool:
        if t + 1e-9 >= self.count * self.period:
            self.count += 1
            return True
        return False


@dataclass
class GroundTruth:
    """What really happened, for reports and tests (never for the robot's behaviours)."""

    robot: Pose2
    collisions: list[Collision] = field(default_factory=list)
    obstacles: list[tuple[str, float, float, float]] = field(default_factory=list)


def _fmt(x: float) -> float:
    return float(f"{x:.6f}")


class SimRobot:
    """A simulated robot in a scenario; implements ``RobotInterface``."""

    def __init__(
        self,
        scenario: Scenario,
        truth_log: Path | IO[str] | None = None,
        sensor_log: Path | IO[str] | None = None,
    ) -> None:
        self.scenario = scenario
        self._faults: dict[FaultKind, list[Fault]] = {}  # the scenario's faults by kind
        for fault in scenario.faults:
            self._faults.setdefault(fault.kind, []).append(fault)
        seeds = np.random.SeedSequence(scenario.seed).spawn(8)
        rngs = [np.random.default_rng(s) for s in seeds]
        self.world = World(scenario, rngs[0])
        mission = scenario.mission
        noise = scenario.noise
        self.lasers = {
            lid: (
                LaserSensor(spec, noise.laser_range, rngs[1].spawn(1)[0]),
                _Schedule(spec.rate_hz, lid),
            )
            for lid, spec in mission.platform.lasers.items()
        }
        self.units = {cid: PanTiltUnit(spec) for cid, spec in mission.platform.cameras.items()}
        self.rigs: list[tuple[CameraRig, _Schedule]] = [
            (rig, _Schedule(rig.spec.rate_hz, rig.id))
            for rig in camera_rigs(mission.platform.cameras)
        ]
        self.cloud = FeatureCloud.from_aircraft(mission.aircraft, self.world.placement)
        # how far (horizontally) a camera can be from the robot's origin, with a margin
        offsets = [math.hypot(*rig.spec.mount[:2]) + abs(rig.lateral) for rig, _ in self.rigs]
        self._camera_reach = max(offsets, default=0.0) + 0.01
        self.camera_rng = rngs[2]
        self.wheels = WheelEncoders(noise.wheel, rngs[3])
        self.imu = Imu(noise.imu_rate, noise.imu_bias, rngs[4])
        self.gps = Gps(
            scenario.gps, noise.gps, mission.aircraft.outline, self.world.placement, rngs[5]
        )
        self.wheel_schedule = _Schedule(WHEEL_RATE_HZ, "wheels")
        self.imu_schedule = _Schedule(IMU_RATE_HZ, "imu")
        self.gps_schedule = _Schedule(scenario.gps.rate_hz, "gps")
        self.truth_schedule = _Schedule(TRUTH_RATE_HZ, "truth")
        # the ceiling camera's images cost only when the platform has one and the scenario
        # a ceiling; its noise has a generator of its own (the others draw as before)
        self.ceiling = _CeilingView.of(self.world, rngs[6])
        self._ceiling: CeilingImage | None = None

        self._scans: dict[str, LaserScan] = {}
        self._cameras: dict[str, CameraFrame] = {}
        self._wheels: WheelSpeeds | None = None
        self._imu: ImuReading | None = None
        self._gps: GpsFix | None = None
        self._angles: dict[str, PanTilt] = {}  # the last published pan-tilt angles
        self._exposures: dict[str, int] = {}  # images captured per camera: their ids
        self._logged_collisions = 0
        self._opened: list[IO[str]] = []
        self._truth_out = self._open_log(truth_log)
        self._sensor_out = self._open_log(sensor_log)
        self._sample(0.0)

    # -- RobotInterface ---------------------------------------------------------------------------
    def read(self) -> SensorFrame:
        t = self.time
        front, rear = self.world.bumpers()
        hit = self._fault_targets(FaultKind.BUMPER_HIT, t)
        frozen = self._fault_targets(FaultKind.PTU_FREEZE, t)
        for uid, unit in self.units.items():
            if uid not in frozen or uid not in self._angles:
                self._angles[uid] = unit.reading(t)
        return SensorFrame(
            stamp=t,
            scans=dict(self._scans),
            cameras=dict(self._cameras),
            pan_tilt=dict(self._angles),
            wheels=self._wheels,
            imu=self._imu,
            gps=self._gps,
            bumpers=Bumpers(t, front or "front" in hit, rear or "rear" in hit),
            ceiling=self._ceiling,
        )

    def send(self, command: VelocityCommand) -> None:
        self.world.base.command(command.v, command.omega)
        for uid, unit in self.units.items():
            rate = command.pan_tilt.get(uid)
            unit.command(rate.pan if rate else 0.0, rate.tilt if rate else 0.0)

    # -- simulated time ----------------
    @property
    def time(self) -> float:
        return self.world.time

    def advance(self, duration: float) -> None:
        """Let ``duration`` seconds of simulated time pass (whole physics steps)."""
        end = self.world.time + duration - 1e-9
        while self.world.time < end:
            self._physics_step()

    def _physics_step(self) -> None:
        world = self.world
        t = world.time
        slip_factor = 1.0
        for fault in self._faults.get(FaultKind.SLIP_BURST, ()):
            if fault.active(t):
                slip_factor *= fault.factor
        bumper_fault = bool(self._fault_targets(FaultKind.BUMPER_HIT, t))
        world.step(slip_factor, bumper_fault)
        for unit in self.units.values():
            unit.step(world.dt)
        self._sample(world.time)

    def _fault_targets(self, kind: FaultKind, t: float) -> set[str | None]:
        faults = self._faults.get(kind)
        if not faults:  # the usual case: no fault of this kind in the scenario
            return set()
        return {f.target for f in faults if f.active(t)}

    # -- sensors ----------------
    def _sample(self, t: float) -> None:
        world = self.world
        pose = world.robot_pose
        lasers_due = [(sensor, s) for sensor, s in self.lasers.values() if s.due(t)]
        cameras_due = [rig for rig, s in self.rigs if s.due(t)]
        if lasers_due or cameras_due:
            world.refresh_scene()
        if lasers_due:
            self._sample_lasers([sensor for sensor, _ in lasers_due], pose, t)
        if cameras_due:
            self._sample_cameras(cameras_due, pose, t)
        if self.wheel_schedule.due(t) and not self._fault_targets(FaultKind.WHEEL_FREEZE, t):
            left, right = world.base.wheel_speeds()
            self._wheels = self.wheels.read(left, right, t)
            if self._sensor_out is not None:
                self._log_sensor(t, "wheels", [_fmt(self._wheels.left), _fmt(self._wheels.right)])
        if self.imu_schedule.due(t) and not self._fault_targets(FaultKind.IMU_FREEZE, t):
            self._imu = self.imu.read(float(world.robot_body.angular_velocity), t)
            if self._sensor_out is not None:
                self._log_sensor(t, "imu", _fmt(self._imu.yaw_rate))
        if self.gps_schedule.due(t):
            lost = self._fault_targets(FaultKind.GPS_LOSS, t)
            self._gps = None if lost else self.gps.read(pose, t)
            fix = self._gps
            if self._sensor_out is not None:
                logged = None if fix is None else [_fmt(fix.x), _fmt(fix.y), _fmt(fix.sigma)]
                self._log_sensor(t, "gps", logged)
        if self.ceiling is not None and self.ceiling.schedule.due(t):
            self._ceiling = CeilingImage(t, self.ceiling.render(pose, t))
            if self._sensor_out is not None:
                self._log_sensor(t, "ceiling", _digest(self._ceiling.image))
        if self.truth_schedule.due(t):
            self._log_truth(t)

    def _sample_lasers(self, lasers: list[LaserSensor], pose: Pose2, t: float) -> None:
        dropped = self._fault_targets(FaultKind.LASER_DROPOUT, t)
        scanning = [sensor for sensor in lasers if sensor.spec.id not in dropped]
        scans = scan_lasers(scanning, self.world.scene, pose, t)
        for sensor, scan in zip(scanning, scans, strict=True):
            self._scans[sensor.spec.id] = scan
            if self._sensor_out is not None:
                self._log_sensor(t, f"laser:{sensor.spec.id}", _digest(scan.ranges))

    def _sample_cameras(self, cameras_due: list[CameraRig], pose: Pose2, t: float) -> None:
        frozen = self._fault_targets(FaultKind.CAMERA_FREEZE, t)
        # Far from every feature no camera can detect anything: detect() would return no
        # detection without drawing from the camera generator, so it is not called.
        noise = self.scenario.noise
        blind = (
            noise.pixel >= 0.0
            and 0.0 <= noise.camera_dropout <= 1.0  # else detect() raises
            and self.cloud.out_of_range(pose.x, pose.y, self._camera_reach)
        )
        for rig in cameras_due:
            unit = self.units[rig.unit]
            if rig.id in frozen and rig.id in self._cameras:
                # A frozen camera keeps publishing its last image with fresh stamps.
                last = self._cameras[rig.id]
                frame = CameraFrame(t, last.detections, last.image)
            elif blind:
                self._exposures[rig.id] = self._exposures.get(rig.id, 0) + 1
                frame = CameraFrame(t, (), self._exposures[rig.id])
            else:
                self._exposures[rig.id] = self._exposures.get(rig.id, 0) + 1
                frame = detect(
                    rig,
                    unit.pan,
                    unit.tilt,
                    pose,
                    self.cloud,
                    rng=self.camera_rng,
                    pixel_noise=self.scenario.noise.pixel,
                    dropout=self.scenario.noise.camera_dropout,
                    occluded=self._occlusion_test(),
                    stamp=t,
                )
                frame = CameraFrame(frame.stamp, frame.detections, self._exposures[rig.id])
            self._cameras[rig.id] = frame
            if self._sensor_out is not None:
                seen = [
                    (d.feature, d.point, round(d.u, 3), round(d.v, 3)) for d in frame.detections
                ]
                self._log_sensor(t, f"camera:{rig.id}", seen)

    def _occlusion_test(self) -> Callable[[NDArray, NDArray], NDArray] | None:
        """The camera occlusion callback: obstacles (not the aircraft) taller than the line."""
        occluders = self.world.occluders
        if occluders.n_segments == 0 and occluders.n_circles == 0:
            return None
        heights = self.world.owner_height

        def occluded(origin: NDArray, targets: NDArray) -> NDArray:
            return sight_lines_blocked(occluders, heights, origin, targets)

        return occluded

    # -- ground truth and logs ----------------
    @property
    def truth(self) -> GroundTruth:
        return GroundTruth(
            self.world.robot_pose, list(self.world.collisions), self.world.obstacle_poses()
        )

    def _log_truth(self, t: float) -> None:
        out = self._truth_out
        if out is None:
            return
        pose = self.world.robot_pose
        record = {
            "t": _fmt(t),
            "robot": [_fmt(pose.x), _fmt(pose.y), _fmt(pose.theta)],
            "obstacles": {i: [_fmt(x), _fmt(y)] for i, x, y, _ in self.world.obstacle_poses()},
        }
        out.write(json.dumps(record, separators=(",", ":")) + "\n")
        for c in self.world.collisions[self._logged_collisions :]:
            event = {
                "t": _fmt(c.time),
                "event": "collision",
                "with": c.other,
                "at": [_fmt(c.x), _fmt(c.y)],
            }
            out.write(json.dumps(event, separators=(",", ":")) + "\n")
        self._logged_collisions = len(self.world.collisions)

    def _log_sensor(self, t: float, name: str, value: object) -> None:
        assert self._sensor_out is not None
        self._sensor_out.write(json.dumps([_fmt(t), name, value], separators=(",", ":")) + "\n")

    def _open_log(self, target: Path | IO[str] | None) -> IO[str] | None:
        if target is None or not isinstance(target, Path | str):
            return target
        handle = Path(target).open("w", encoding="utf-8")  # noqa: SIM115 (closed in close())
        self._opened.append(handle)
        return handle

    def close(self) -> None:
        """Flush the logs; close the ones this robot opened."""
        for out in (self._truth_out, self._sensor_out):
            if out is not None:
                out.flush()
        for handle in self._opened:
            handle.close()
        self._opened.clear()


class _CeilingView:
    """The platform's upward camera under the scenario's ceiling (issue 17): renders
    :func:`sim2d.ceiling.render` from the robot's true pose at the camera's rate, with the
    lamps of the scenario's timeline off and every person among the movers (paths and
    chasers of kind person, every member of a group) as a walker of their height."""

    def __init__(
        self, world: World, ceiling: ScenarioCeiling, camera: UpwardCamera, rng: np.random.Generator
    ) -> None:
        self.world = world
        self.settings = ceiling
        self.camera = camera
        self.texture = CeilingTexture(ceiling.spec)
        self.rng = rng
        self.schedule = _Schedule(camera.rate, "ceiling")
        self.timeline = ceiling.timeline(world.scenario.seed)
        person_ids = {
            ob.id
            for ob in world.scenario.obstacles
            if isinstance(ob, PathMover | Chaser) and ob.kind is ObstacleKind.PERSON
        }
        person_ids |= {w.agent.id for group in world.groups for w in group.walkers}
        self.persons = [m for m in world.moving if m.agent.id in person_ids]

    @classmethod
    def of(cls, world: World, rng: np.random.Generator) -> _CeilingView | None:
        spec = world.platform.ceiling_camera
        ceiling = world.scenario.ceiling
        if spec is None or ceiling is None:
            return None
        return cls(world, ceiling, upward_camera_for(spec), rng)

    def render(self, pose: Pose2, t: float) -> NDArray[np.uint8]:
        ceiling = self.settings
        occluders = [
            occluder
            for m in self.persons
            for occluder in walker(m.body.position.x, m.body.position.y, stature=m.height)
            if occluder.height > self.camera.mount_z + 0.01  # a child below the lens: unseen
        ]
        image = render(
            self.texture,
            self.camera,
            pose,
            lamps_off=lamps_off_at(self.timeline, t),
            exposure=ceiling.exposure,
            vignetting=ceiling.vignetting,
            blur_px=ceiling.blur_px,
            noise_sigma=ceiling.noise_grey,
            occluders=occluders,
            rng=self.rng,
        )
        image.flags.writeable = False
        return image


def _digest(values: np.ndarray) -> str:
    return hashlib.sha1(np.round(values, 6).tobytes()).hexdigest()[:16]
