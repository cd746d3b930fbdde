"""Dry-run a mission in sim2d: the executive against a simulated robot, with a report.

The executive sees only what the simulated robot reports; the harness also watches the
simulator's ground truth (at 10 Hz) to judge the run: where each checkpoint was really
reached, the clearance to everything, collisions, and whether the robot's footprint ever
entered a forbidden zone.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TextIO

import numpy as np
import py_trees
import shapely
from shapely.geometry import Polygon as ShapelyPolygon

from behaviours.controllers.avoidance import (
    AvoidanceController,
    AvoidanceParams,
    AvoiderFactory,
    AvoidObstacle,
    obstacle_in_airport,
)
from behaviours.keys import OBSTACLES, POSE, PROGRESS, MissionProgress
from executive.compiler import CompileOptions, compile_mission
from executive.core.frames import AircraftPlacement, Pose2, wrap_angle
from executive.core.geometry import to_shapely
from executive.core.model import Frame
from executive.core.records import (
    Obstacles,
    OperatorRequests,
    PoseEstimate,
    RegistrationRecord,
    SensorFrame,
    VelocityCommand,
)
from executive.journal import Journal, read_journal
from executive.runtime import RunResult, Runtime
from executive.safety import SafetyLayer
from sim2d.robot import SimRobot
from sim2d.scenario import Scenario

TRUTH_RATE_HZ = 10.0


class SimClock:
    """Simulated time: waiting advances the simulator."""

    def __init__(self, robot: SimRobot) -> None:
        self.robot = robot

    def now(self) -> float:
        return self.robot.time

    def wait(self, until: float) -> None:
        if until > self.robot.time:
            self.robot.advance(until - self.robot.time)


@dataclass
class Sample:
    t: float
    true: Pose2
    estimate: Pose2 | None
    controller: str
    v: float
    omega: float
    r_c: float
    clearance: float


@dataclass
class RegistrationSample:
    """One registration attempt against the ground truth (robot pose in F)."""

    t: float
    method: str
    accepted: bool
    reason: str
    position_error: float | None
    heading_error_deg: float | None
    rms: float
    inlier_fraction: float


@dataclass
class LocalisationSample:
    """The estimate in F against the truth, at TRUTH_RATE_HZ."""

    t: float
    reference: str
    position_error: float
    heading_error_deg: float
    placement_error: float
    placement_heading_error_deg: float
    sigma_f: float


@dataclass
class TrackSample:
    """A tracked obstacle placed in A with the true robot pose, and the mover it matches
    (position and velocity errors against that mover's truth; None: no mover near)."""

    t: float
    id: int
    kind: str
    x: float
    y: float
    vx: float
    vy: float
    danger: int
    age: float
    mover: str | None = None
    position_error: float | None = None
    velocity_error: float | None = None


@dataclass
class AvoidanceSample:
    """One tick of an obstacle avoidance, at TRUTH_RATE_HZ: the law's quantities (NaN for
    velocity obstacles) and the true clearance."""

    t: float
    episode: int
    mode: str
    obstacle: int | None
    alpha_d: float
    xi: float
    beta_c: float
    e_alpha: float
    e_r: float
    v: float
    omega: float
    clearance: float


TRACK_MATCH_RADIUS = 1.0
"""A track within this distance (m) of a mover's true centre is taken to be that mover."""


@dataclass
class CheckpointOutcome:
    id: str
    reached: bool
    time: float | None = None
    position_error: float | None = None
    heading_error_deg: float | None = None
    items: int = 0
    detected: int = 0


@dataclass
class DryRun:
    """Everything a report needs."""

    scenario: Scenario
    result: RunResult
    samples: list[Sample]
    checkpoints: list[CheckpointOutcome]
    breaches: list[tuple[float, str]]
    robot: SimRobot
    warnings: list[str] = field(default_factory=list)
    wall_time: float = 0.0
    resumed_from: tuple[str, ...] = ()
    registrations: list[RegistrationSample] = field(default_factory=list)
    localisation: list[LocalisationSample] = field(default_factory=list)
    tracks: list[TrackSample] = field(default_factory=list)
    avoidance: list[AvoidanceSample] = field(default_factory=list)
    final_placement: AircraftPlacement | None = None

    @property
    def succeeded(self) -> bool:
        return (
            self.result.outcome == "completed"
            and not self.robot.truth.collisions
            and not self.breaches
        )


class _Watcher:
    """Ground-truth judge, called after every tick (samples at TRUTH_RATE_HZ)."""

    def __init__(
        self,
        robot: SimRobot,
        scenario: Scenario,
        avoiders: Sequence[AvoidanceController] = (),
    ) -> None:
        self.robot = robot
        self.avoiders = list(avoiders)
        self.avoidance: list[AvoidanceSample] = []
        self._episodes: dict[tuple[int, int], int] = {}
        self.scenario = scenario
        mission = scenario.mission
        self.true = scenario.true_placement()
        self.samples: list[Sample] = []
        self.breaches: list[tuple[float, str]] = []
        self._next = 0.0
        self._in_zone: set[str] = set()
        self.zones = []
        for zone in mission.airport.zones:
            geom = to_shapely(zone.shape)
            if zone.frame is Frame.AIRCRAFT:
                geom = ShapelyPolygon(self.true.to_airport_xy(geom.exterior.coords))
            shapely.prepare(geom)
            self.zones.append((zone.id, geom))
        self.half = (mission.platform.length / 2, mission.platform.width / 2)
        self.checkpoint_done_at: dict[str, float] = {}
        self.completed_seen: tuple[str, ...] = ()
        self.outcomes: dict[str, CheckpointOutcome] = {}
        self.registrations: list[RegistrationSample] = []
        self.localisation: list[LocalisationSample] = []
        self.tracks: list[TrackSample] = []
        self._registration: RegistrationRecord | None = None
        self.final_placement: AircraftPlacement | None = None

    def footprint(self, pose: Pose2) -> ShapelyPolygon:
        hl, hw = self.half
        return ShapelyPolygon(pose.apply([(hl, hw), (-hl, hw), (-hl, -hw), (hl, -hw)]))

    def clearance(self, foot: ShapelyPolygon) -> float:
        """True distance from the robot's footprint to the nearest shape of the world."""
        scene = self.robot.world.scene
        best = math.inf
        if scene.n_segments:
            lines = shapely.linestrings(scene.segments.reshape(-1, 2, 2))
            best = float(shapely.distance(foot, lines).min())
        if scene.n_circles:
            centres = shapely.points(scene.centers)
            best = min(best, float((shapely.distance(foot, centres) - scene.radii).min()))
        return max(best, 0.0)

    def __call__(self, t: float, frame: SensorFrame, sent: VelocityCommand, rt: Runtime) -> None:
        progress = rt._get(PROGRESS.name)
        if isinstance(progress, MissionProgress) and progress.completed != self.completed_seen:
            for cp_id in progress.completed[len(self.completed_seen) :]:
                self._judge_checkpoint(cp_id, t, progress)
            self.completed_seen = progress.completed
        pose = rt._get(POSE.name)
        world = self.robot.world
        true = world.robot_pose
        if isinstance(pose, PoseEstimate):
            self._judge_registration(t, pose, true)
            self.final_placement = pose.placement
        if t + 1e-9 < self._next:
            return
        self._next = t + 1.0 / TRUTH_RATE_HZ
        obstacles = rt._get(OBSTACLES.name)
        if isinstance(pose, PoseEstimate):
            self._judge_localisation(t, pose, true)
        if isinstance(obstacles, Obstacles):
            self._judge_tracks(t, obstacles, true)
        foot = self.footprint(true)
        inside = {zid for zid, geom in self.zones if geom.intersects(foot)}
        for zid in inside - self._in_zone:
            self.breaches.append((t, zid))
        self._in_zone = inside
        # Clearance: the true distance from the footprint to the nearest scene shape.
        scene = world.scene
        pts = (
            np.vstack((scene.segments[:, :2], scene.segments[:, 2:])) if scene.n_segments else None
        )
        clearance = math.inf
        if pts is not None and len(pts):
            clearance = float(
                shapely.distance(
                    foot, shapely.multilinestrings([scene.segments.reshape(-1, 2, 2)])
                ).min()
            )
        if scene.n_circles:
            d = np.hypot(*(scene.centers - (true.x, true.y)).T) - scene.radii
            body = math.hypot(*self.half)
            clearance = min(clearance, float(max(d.min() - body, 0.0)) if len(d) else clearance)
        self.samples.append(
            Sample(
                t,
                true,
                getattr(pose, "pose_a", None),
                rt.controller,
                sent.v,
                sent.omega,
                getattr(obstacles, "closest", math.inf),
                clearance,
            )
        )
        if self.avoiders:
            self._judge_avoidance(t, sent, clearance)

    def _judge_avoidance(self, t: float, sent: VelocityCommand, clearance: float) -> None:
        for node in self.avoiders:
            if node.status != py_trees.common.Status.RUNNING:
                continue
            session = node.session
            key = (id(session), session.count)
            episode = self._episodes.setdefault(key, len(self._episodes) + 1)
            out = node.last if isinstance(node, AvoidObstacle) else None
            nan = math.nan
            self.avoidance.append(
                AvoidanceSample(
                    round(t, 3),
                    episode,
                    session.mode,
                    session.obstacle_id,
                    out.alpha_d if out else nan,
                    out.xi if out else nan,
                    out.beta_c if out else nan,
                    out.e_alpha if out else nan,
                    out.e_r if out else nan,
                    sent.v,
                    sent.omega,
                    clearance,
                )
            )

    def _judge_registration(self, t: float, pose: PoseEstimate, true: Pose2) -> None:
        reg = pose.registration
        if reg is None or reg is self._registration:
            return
        self._registration = reg
        pos_err = head_err = None
        if reg.pose_f is not None:
            truth_f = self.true.pose_to_aircraft(true)
            pos_err = round(reg.pose_f.distance_to(truth_f), 4)
            head_err = round(math.degrees(abs(wrap_angle(reg.pose_f.theta - truth_f.theta))), 3)
        self.registrations.append(
            RegistrationSample(
                round(t, 3),
                reg.method,
                reg.accepted,
                reg.reason,
                pos_err,
                head_err,
                round(reg.rms, 4) if math.isfinite(reg.rms) else math.nan,
                round(reg.inlier_fraction, 3),
            )
        )

    def _judge_localisation(self, t: float, pose: PoseEstimate, true: Pose2) -> None:
        truth_f = self.true.pose_to_aircraft(true)
        est = pose.pose_f
        placement = pose.placement
        p_err = p_head = math.nan
        if placement is not None:
            p_err = math.hypot(placement.x - self.true.x, placement.y - self.true.y)
            p_head = math.degrees(abs(wrap_angle(placement.heading - self.true.heading)))
        cov = pose.covariance_f
        sigma = math.sqrt(max(float(cov[0, 0] + cov[1, 1]), 0.0)) if cov is not None else math.nan
        self.localisation.append(
            LocalisationSample(
                round(t, 3),
                str(pose.reference),
                round(est.distance_to(truth_f), 4),
                round(math.degrees(abs(wrap_angle(est.theta - truth_f.theta))), 3),
                round(p_err, 4),
                round(p_head, 3),
                round(sigma, 4),
            )
        )

    def _judge_tracks(self, t: float, obstacles: Obstacles, true: Pose2) -> None:
        movers = [
            (m.agent.id, m.agent.x, m.agent.y, m.agent.vx, m.agent.vy)
            for m in self.robot.world.moving
        ]
        for track in obstacles.tracks:
            if track.kind == "zone":
                continue
            in_a = obstacle_in_airport(track, true)  # placed with the true robot pose
            (x, y), (vx, vy) = in_a.position, in_a.velocity
            sample = TrackSample(
                round(t, 3),
                track.id,
                track.kind,
                float(x),
                float(y),
                vx,
                vy,
                int(track.danger),
                track.age,
            )
            if movers:
                d = [math.hypot(mx - x, my - y) for _, mx, my, _, _ in movers]
                k = int(np.argmin(d))
                if d[k] <= TRACK_MATCH_RADIUS:
                    mid, _, _, mvx, mvy = movers[k]
                    sample.mover = mid
                    sample.position_error = round(d[k], 4)
                    sample.velocity_error = round(math.hypot(vx - mvx, vy - mvy), 4)
            self.tracks.append(sample)

    def _judge_checkpoint(self, cp_id: str, t: float, progress: MissionProgress) -> None:
        mission = self.scenario.mission
        cp = next(c for c in mission.checkpoints if c.id == cp_id)
        goal = self.true.pose_to_airport(cp.pose)
        true = self.robot.world.robot_pose
        results = [r for r in progress.results if r.checkpoint == cp_id]
        self.outcomes[cp_id] = CheckpointOutcome(
            id=cp_id,
            reached=True,
            time=round(t, 2),
            position_error=round(math.hypot(goal.x - true.x, goal.y - true.y), 4),
            heading_error_deg=round(math.degrees(abs(wrap_angle(goal.theta - true.theta))), 3),
            items=len(results),
            detected=sum(r.detected for r in results),
        )


class _Progress:
    """A one-line live progress report (rewritten in place on a terminal)."""

    def __init__(self, out: TextIO | None, n_checkpoints: int) -> None:
        self.out = out
        self.n = n_checkpoints
        self.tty = bool(out is not None and out.isatty())
        self._next_wall = 0.0
        self._t0 = time.perf_counter()

    def __call__(self, t: float, rt: Runtime) -> None:
        if self.out is None:
            return
        wall = time.perf_counter() - self._t0
        if wall < self._next_wall:
            return
        self._next_wall = wall + (0.2 if self.tty else 5.0)
        progress = rt._get(PROGRESS.name)
        phase = getattr(progress, "phase", "-")
        done = len(getattr(progress, "completed", ()))
        line = (
            f"{phase:<10} checkpoint {done}/{self.n}  {rt.controller[:28]:<28} "
            f"t={t:7.1f} s  x{t / max(wall, 1e-6):5.1f}"
        )
        self.out.write(("\r" + line) if self.tty else (line + "\n"))
        self.out.flush()

    def close(self) -> None:
        if self.out is not None and self.tty:
            self.out.write("\n")


def dry_run(
    scenario: Scenario,
    *,
    rate_hz: float = 50.0,
    journal_path: Path | None = None,
    resume: bool = False,
    operator: Callable[[float], OperatorRequests] | None = None,
    progress_out: TextIO | None = None,
    max_time: float | None = None,
    robot: SimRobot | None = None,
    avoidance: bool = True,
    avoider: AvoiderFactory | None = None,
    avoidance_params: AvoidanceParams | None = None,
) -> DryRun:
    """Run the scenario's mission with the executive in sim2d and judge it."""
    mission = scenario.mission
    resumed = None
    start = None
    if resume and journal_path is not None:
        resumed, pose = read_journal(journal_path)
        if pose is not None:
            start = Pose2(*pose)
            scenario = _with_start(scenario, start)
    robot = robot or SimRobot(scenario)
    options = CompileOptions(
        rate_hz=rate_hz,
        start=start or scenario.start,
        resume=resumed,
        avoidance=avoidance,
        avoider=avoider,
        avoidance_params=avoidance_params,
    )
    compiled = compile_mission(mission, options)
    safety = SafetyLayer(
        mission,
        compiled.placement,
        1.0 / rate_hz,
        geofence_margin=mission.safety.geofence_margin,
    )
    journal = None
    if journal_path is not None:
        journal = Journal(journal_path, mission.id, append=resume)
        if resumed is not None:
            journal.resume_from(resumed)
    avoiders = [n for n in compiled.root.iterate() if isinstance(n, AvoidanceController)]
    watcher = _Watcher(robot, scenario, avoiders)
    show = _Progress(progress_out, len(mission.checkpoints))

    def on_tick(t: float, frame: SensorFrame, sent: VelocityCommand, rt: Runtime) -> None:
        watcher(t, frame, sent, rt)
        show(t, rt)

    runtime = Runtime(
        compiled,
        robot,
        SimClock(robot),
        safety,
        rate_hz=rate_hz,
        journal=journal,
        operator=operator,
        on_tick=on_tick,
    )
    wall0 = time.perf_counter()
    result = runtime.run(max_time if max_time is not None else scenario.duration)
    wall = time.perf_counter() - wall0
    show.close()
    if journal is not None:
        journal.write(
            {"t": round(robot.time, 3), "event": "mission-end", "outcome": result.outcome}
        )
        journal.close()
    done = set(resumed.completed) if resumed is not None else set()
    outcomes = [
        watcher.outcomes.get(cp.id, CheckpointOutcome(cp.id, reached=cp.id in done))
        for cp in mission.checkpoints
    ]
    return DryRun(
        scenario=scenario,
        result=result,
        samples=watcher.samples,
        checkpoints=outcomes,
        breaches=watcher.breaches,
        robot=robot,
        warnings=[str(w) for w in compiled.warnings],
        wall_time=wall,
        resumed_from=tuple(sorted(done)),
        registrations=watcher.registrations,
        localisation=watcher.localisation,
        tracks=watcher.tracks,
        avoidance=watcher.avoidance,
        final_placement=watcher.final_placement,
    )


def _with_start(scenario: Scenario, start: Pose2) -> Scenario:
    return dataclasses.replace(scenario, start=start)
