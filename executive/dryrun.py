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
from collections import deque
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
from behaviours.keys import FEATURES, OBSTACLES, POSE, PROGRESS, SERVO, MissionProgress, ServoStatus
from executive.compiler import CompileOptions, compile_mission
from executive.core.frames import AircraftPlacement, Pose2, wrap_angle
from executive.core.geometry import to_shapely
from executive.core.model import Frame
from executive.core.records import (
    FeatureObservations,
    Obstacles,
    OperatorRequests,
    PoseEstimate,
    RegistrationRecord,
    SensorFrame,
    VelocityCommand,
    camera_ids,
)
from executive.journal import (
    Journal,
    JournalState,
    JournalWriteError,
    MissionBinding,
    read_journal,
)
from executive.recording import Recorder, serve_live
from executive.runtime import (
    RunResult,
    Runtime,
    StopRequest,
    TickHook,
)
from executive.safety import (
    ESTOP_LATCHED,
    ESTOP_RELEASED,
    ESTOP_RESET,
    FAULT_STOP,
    GEOFENCE_CLEAR,
    GEOFENCE_STOP,
    SENSOR_FRESH,
    STALE_SENSOR,
    SafetyLayer,
    StaleInterval,
)
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

    @staticmethod
    def tick_timer() -> float:
        """What a tick is charged in simulated time: the CPU time of this thread. A
        machine busy with other work delays the simulation, not the robot; a slow
        executive still shows its misses in the tick statistics (on the robot, the wall
        clock decides). On a virtual machine the CPU time the hypervisor stole is charged
        too, which is why a dry-run stops on misses only when asked."""
        return time.thread_time()


class PacedSimClock(SimClock):
    """Simulated time kept at ``pace`` times the wall clock (a live dry-run an operator
    watches and drives); a simulation slower than that runs as fast as it can."""

    def __init__(self, robot: SimRobot, pace: float) -> None:
        super().__init__(robot)
        if not pace > 0.0:
            raise ValueError(f"pace must be > 0, got {pace}")
        self.pace = pace
        self._origin: tuple[float, float] | None = None

    def wait(self, until: float) -> None:
        super().wait(until)
        if self._origin is None:
            self._origin = (time.monotonic(), self.robot.time)
        wall0, sim0 = self._origin
        ahead = wall0 + (self.robot.time - sim0) / self.pace - time.monotonic()
        if ahead > 0.0:
            time.sleep(ahead)

    @staticmethod
    def tick_timer() -> float:
        """The wall clock: at real time the tick's deadline is the robot's."""
        return time.perf_counter()


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


CAMERA_CONTROLLERS = ("servo", "correct", "inspect")
"""Controllers (by name) during which a checkpoint's camera must see its features."""

TRACK_MATCH_RADIUS = 1.0
"""A track within this distance (m) of a mover's true centre is taken to be that mover."""


@dataclass
class CheckpointOutcome:
    """How a checkpoint was really reached (ground truth), and how sure the executive was:
    ``pose_sigma`` is the estimate's own position uncertainty (m, 1-sigma) then, and
    ``uncertain`` says it exceeded the checkpoint tolerance. ``resumed``: judged by the
    run that completed it, before a ``--resume``."""

    id: str
    reached: bool
    time: float | None = None
    position_error: float | None = None
    heading_error_deg: float | None = None
    items: int = 0
    detected: int = 0
    pose_sigma: float | None = None
    uncertain: bool = False
    resumed: bool = False


@dataclass(frozen=True)
class Cause:
    """Why a run did not succeed, at the time it happened, in one line."""

    t: float
    text: str


class _CommandLog:
    """The robot as the runtime sees it, keeping the last commands it was sent: what the
    report says the robot was told when the run ended (a stop, whatever ended it)."""

    def __init__(self, robot: SimRobot, keep: int = 5) -> None:
        self.robot = robot
        self.sent: deque[tuple[float, VelocityCommand]] = deque(maxlen=keep)

    def read(self) -> SensorFrame:
        return self.robot.read()

    def send(self, command: VelocityCommand) -> None:
        self.robot.send(command)
        self.sent.append((self.robot.time, command))

    def last(self) -> list[tuple[float, VelocityCommand]]:
        return list(self.sent)


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
    causes: list[Cause] = field(default_factory=list)
    feature_loss_s: dict[str, float] = field(default_factory=dict)
    last_commands: list[tuple[float, VelocityCommand]] = field(default_factory=list)
    journal_error: str | None = None
    stale_sensors: dict[str, tuple[StaleInterval, ...]] = field(default_factory=dict)
    servo: dict[str, dict[str, object]] = field(default_factory=dict)
    """Per servo checkpoint: its target, the time servoed by mode and the time on an
    augmented image with reconstructed points (issue 13), from the ServoStatus key."""
    recording: Path | None = None
    """The run's MCAP recording for Foxglove (issue 15), when one was asked for."""
    recording_error: str | None = None
    """Why the recording stopped early (the run went on), or None."""

    @property
    def succeeded(self) -> bool:
        """Completed, no collision, no geofence breach, every checkpoint reached within
        its tolerance and every item inspected with a fresh image: no :attr:`causes`."""
        return not self.causes

    @property
    def first_cause(self) -> str | None:
        return self.causes[0].text if self.causes else None


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
        self.journal: Journal | None = None
        self._last_pose: PoseEstimate | None = None
        self.feature_loss: dict[str, float] = dict.fromkeys(mission.platform.cameras, 0.0)
        self._checkpoints = {c.id: c for c in mission.checkpoints}
        self.servo: dict[str, dict[str, object]] = {}
        self._bb = py_trees.blackboard.Client(name="dry-run judge")
        self._bb.register_key(key=FEATURES.name, access=py_trees.common.Access.READ)
        self._rigs = {unit: camera_ids(mission.platform, unit) for unit in mission.platform.cameras}

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
        pose = rt._get(POSE.name)
        self._last_pose = pose if isinstance(pose, PoseEstimate) else None
        servo = rt._get(SERVO.name)
        if isinstance(servo, ServoStatus):
            self.servo[servo.checkpoint] = {
                "target": servo.target,
                "reconstructed_s": servo.reconstructed_s,
                **{f"{mode}_s": t for mode, t in servo.servo_s},
                "switches": [{"t": t, "reason": why} for t, why in servo.switches],
                "start_m": servo.start,
                **({"start_note": servo.start_note} if servo.start_note else {}),
            }
        if isinstance(progress, MissionProgress) and progress.completed != self.completed_seen:
            for cp_id in progress.completed[len(self.completed_seen) :]:
                self._judge_checkpoint(cp_id, t, progress)
            self.completed_seen = progress.completed
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
        if isinstance(progress, MissionProgress):
            self._judge_feature_loss(self._features(), progress, rt.controller)
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
        sigma = pose.sigma_f if pose.sigma_f is not None else math.nan
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

    def _features(self) -> FeatureObservations | None:
        """What the executive's feature sensing kept this tick (fresh images only)."""
        try:
            features = self._bb.get(FEATURES.name)
        except KeyError:
            return None
        return features if isinstance(features, FeatureObservations) else None

    def _judge_feature_loss(
        self, features: FeatureObservations | None, progress: MissionProgress, controller: str
    ) -> None:
        """While a checkpoint's camera is in use (visual servoing, correcting the camera
        angle, inspecting), count the time (at TRUTH_RATE_HZ) that camera had no fresh
        detection of the checkpoint's features: frozen, dropped out, occluded or out of
        view all count (ARCHITECTURE §9, feature-loss time). Fresh is what the
        executive's own feature sensing kept (:class:`FeatureObservations`)."""
        cp = self._checkpoints.get(progress.checkpoint or "")
        if cp is None or cp.camera is None or cp.id in progress.completed:
            return
        if not any(word in controller for word in CAMERA_CONTROLLERS):
            return
        aircraft = self.scenario.mission.aircraft
        wanted = {aircraft.items[i].feature for i in cp.items if i in aircraft.items}
        if cp.target is not None:
            wanted.add(cp.target)
        fresh = features.by_camera if features is not None else {}
        seen = any(d.feature in wanted for rig in self._rigs[cp.camera] for d in fresh.get(rig, ()))
        if not seen:
            self.feature_loss[cp.camera] += 1.0 / TRUTH_RATE_HZ

    def _judge_checkpoint(self, cp_id: str, t: float, progress: MissionProgress) -> None:
        mission = self.scenario.mission
        cp = self._checkpoints[cp_id]
        if cp_id in progress.skipped:  # the operator skipped it (trapped): not reached
            self.outcomes[cp_id] = CheckpointOutcome(id=cp_id, reached=False, time=round(t, 2))
            if self.journal is not None:
                self.journal.write(
                    {
                        "event": "checkpoint-truth",
                        "checkpoint": cp_id,
                        **dataclasses.asdict(self.outcomes[cp_id]),
                    }
                )
            return
        goal = self.true.pose_to_airport(cp.pose)
        true = self.robot.world.robot_pose
        results = [r for r in progress.results if r.checkpoint == cp_id]
        sigma = self._last_pose.sigma_f if self._last_pose is not None else None
        sigma = round(sigma, 4) if sigma is not None else None
        outcome = CheckpointOutcome(
            id=cp_id,
            reached=True,
            time=round(t, 2),
            position_error=round(math.hypot(goal.x - true.x, goal.y - true.y), 4),
            heading_error_deg=round(math.degrees(abs(wrap_angle(goal.theta - true.theta))), 3),
            items=len(results),
            detected=sum(r.detected for r in results),
            pose_sigma=sigma,
            uncertain=sigma is not None and sigma > mission.navigation.position_tolerance,
        )
        self.outcomes[cp_id] = outcome
        if self.journal is not None:  # kept for the report of a resumed run
            self.journal.write(
                {"event": "checkpoint-truth", "checkpoint": cp_id, **dataclasses.asdict(outcome)}
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
    resume: bool | JournalState = False,
    operator: Callable[[float], OperatorRequests] | None = None,
    progress_out: TextIO | None = None,
    max_time: float | None = None,
    robot: SimRobot | None = None,
    avoidance: bool = True,
    avoider: AvoiderFactory | None = None,
    avoidance_params: AvoidanceParams | None = None,
    stop: StopRequest | None = None,
    max_missed_deadlines: int | None = None,
    before_start: Callable[[], None] | None = None,
    servo: bool | None = None,
    ask_operator: bool = False,
    trapped_after: float | None = None,
    record: Path | None = None,
    observers: Sequence[TickHook] = (),
    pace: float | None = None,
    foxglove: tuple[str, int] | None = None,
) -> DryRun:
    """Run the scenario's mission with the executive in sim2d and judge it.

    ``resume`` continues the journal at ``journal_path``: True reads it, a
    :class:`JournalState` is one already read and checked (the CLI reads it before any
    work, to refuse a bad journal with exit status 2). The robot starts where the last
    completed checkpoint was reached; the checkpoints completed before keep the outcome
    judged when they were completed. ``before_start`` is called once the mission is
    compiled and the simulator built, before anything is written: the CLI clears the old
    report there, so a run that cannot start destroys nothing.
    ``servo`` reaches the checkpoints with a servo target by visual servoing (issue 13;
    None: the compiler's default, :data:`executive.compiler.SERVO_VERIFIED`).
    ``ask_operator``: an operator answers the run's questions (a trapped checkpoint:
    wait, take over or skip; :attr:`executive.compiler.CompileOptions.ask_operator`);
    ``trapped_after`` overrides the trap period (s).
    ``observers`` are called after every tick like the runtime's own hook (the live
    HUD's telemetry); ``pace`` runs the simulation at that multiple of real time (the
    live dry-run: 1) instead of as fast as it can; ``foxglove`` (host, port) also serves
    the recording live over the Foxglove WebSocket protocol (needs ``record``).
    ``max_missed_deadlines`` stops the run as the robot would after that many consecutive
    ticks over their deadline; None (the default) never: a simulation's outcome must not
    depend on how busy the machine is (the same seed gives the same run; a virtual
    machine's stolen CPU time is charged to the tick it interrupted), and the misses are
    reported in the tick statistics either way.
    ``record`` names an MCAP file to record the run to for Foxglove (issue 15,
    :mod:`executive.recording`; overwritten), opened with the journal.
    """
    mission = scenario.mission
    state: JournalState | None = None
    if isinstance(resume, JournalState):
        state = resume
    elif resume and journal_path is not None:
        state = read_journal(journal_path)
    resumed = state.progress if state is not None else None
    start = None
    if state is not None and state.pose_a is not None:
        start = Pose2(*state.pose_a)
        scenario = _with_start(scenario, start)
    sim = robot or SimRobot(scenario)
    options = CompileOptions(
        rate_hz=rate_hz,
        start=start or scenario.start,
        resume=resumed,
        avoidance=avoidance,
        avoider=avoider,
        avoidance_params=avoidance_params,
        servo=servo,
        ask_operator=ask_operator,
        **({} if trapped_after is None else {"trapped_after": trapped_after}),
    )
    compiled = compile_mission(mission, options)
    safety = SafetyLayer(
        mission,
        compiled.placement,
        1.0 / rate_hz,
        geofence_margin=mission.safety.geofence_margin,
    )
    if before_start is not None:
        before_start()
    journal = None
    if journal_path is not None:
        journal = Journal(
            journal_path,
            MissionBinding.of(mission),
            append=state is not None,
            keep_bytes=state.keep_bytes if state is not None else None,
        )
        if resumed is not None:
            journal.resume_from(resumed)
            journal.write({"event": "resume", "t": round(sim.time, 3)})
    avoiders = [n for n in compiled.root.iterate() if isinstance(n, AvoidanceController)]
    watcher = _Watcher(sim, scenario, avoiders)
    watcher.journal = journal
    if resumed is not None:
        watcher.completed_seen = resumed.completed
    show = _Progress(progress_out, len(mission.checkpoints))
    recorder, recording_error = None, None
    if record is not None:
        try:
            recorder = Recorder.open(
                record,
                mission,
                placement=compiled.placement,
                metadata={"scenario": scenario.id, "scenario_file": scenario.source},
            )
        except OSError as exc:  # no recording is no reason not to run
            recording_error = f"cannot record to {record}: {exc.strerror or exc}"
    if recorder is not None and foxglove is not None:
        try:
            server = serve_live(recorder, *foxglove)
            if progress_out is not None:
                print(f"Foxglove live view: ws://{foxglove[0]}:{server.port}", file=progress_out)
        except Exception as exc:  # the SDK's own error type; the run goes on without it
            recording_error = f"cannot serve Foxglove on {foxglove[0]}:{foxglove[1]}: {exc}"

    def on_tick(t: float, frame: SensorFrame, sent: VelocityCommand, rt: Runtime) -> None:
        watcher(t, frame, sent, rt)
        show(t, rt)
        if recorder is not None:
            recorder.on_tick(t, frame, sent, rt)
        for observer in observers:
            observer(t, frame, sent, rt)

    wire = _CommandLog(sim)
    runtime = Runtime(
        compiled,
        wire,
        SimClock(sim) if pace is None else PacedSimClock(sim, pace),
        safety,
        rate_hz=rate_hz,
        journal=journal,
        operator=operator,
        on_tick=on_tick,
        stop=stop,
        max_missed_deadlines=max_missed_deadlines,
    )
    wall0 = time.perf_counter()
    try:
        result = runtime.run(max_time if max_time is not None else scenario.duration)
        if recorder is not None:
            recorder.close(runtime, result)
    finally:
        show.close()
        if recorder is not None:
            recorder.close(runtime)  # when the run raised; else already closed
    wall = time.perf_counter() - wall0
    journal_error = None
    if journal is not None:
        t_end = round(sim.time, 3)
        end: dict[str, object] = (
            {"t": t_end, "event": "interrupted", "reason": result.reason}
            if result.outcome == "interrupted"
            else {"t": t_end, "event": "mission-end", "outcome": result.outcome}
        )
        try:
            journal.write(end)
        except JournalWriteError as exc:
            journal_error = str(exc)
        finally:
            journal.close()
    done = set(resumed.completed) if resumed is not None else set()
    before = state.truth if state is not None else {}
    outcomes = [
        watcher.outcomes.get(cp.id) or _resumed_outcome(cp.id, cp.id in done, before.get(cp.id))
        for cp in mission.checkpoints
    ]
    run = DryRun(
        scenario=scenario,
        result=result,
        samples=watcher.samples,
        checkpoints=outcomes,
        breaches=watcher.breaches,
        robot=sim,
        warnings=[str(w) for w in compiled.warnings],
        wall_time=wall,
        resumed_from=tuple(sorted(done)),
        registrations=watcher.registrations,
        localisation=watcher.localisation,
        tracks=watcher.tracks,
        avoidance=watcher.avoidance,
        final_placement=watcher.final_placement,
        feature_loss_s={k: round(v, 2) for k, v in sorted(watcher.feature_loss.items())},
        last_commands=wire.last(),
        journal_error=journal_error,
        stale_sensors=safety.stale_intervals(),
        servo=watcher.servo,
        recording=record if recorder is not None else None,
        recording_error=recorder.error if recorder is not None else recording_error,
    )
    run.causes = judge(run)
    return run


def _resumed_outcome(
    cp_id: str, reached: bool, truth: dict[str, object] | None
) -> CheckpointOutcome:
    """A checkpoint this run did not complete: as judged before the resume, if it was."""
    if not reached:
        return CheckpointOutcome(cp_id, reached=False)
    known = {f.name for f in dataclasses.fields(CheckpointOutcome)}
    fields = {k: v for k, v in (truth or {}).items() if k in known and k != "id"}
    fields.update(reached=True, resumed=True)
    return CheckpointOutcome(cp_id, **fields)  # type: ignore[arg-type]


STOP_EVENTS = {
    ESTOP_LATCHED: ESTOP_RELEASED,
    STALE_SENSOR: SENSOR_FRESH,
    GEOFENCE_STOP: GEOFENCE_CLEAR,
}
"""Safety stops and the events that end them (a fault stop never ends)."""


def _active_stop(run: DryRun) -> Cause | None:
    """The safety stop still holding the robot when the run ended, if any."""
    active: dict[str, Cause] = {}
    for event in run.result.events:
        if event.kind != "safety":
            continue
        kind = str(event.detail.get("kind"))
        reason = str(event.detail.get("reason", ""))
        if kind == ESTOP_LATCHED:
            wait = ", waiting for an operator reset" if "bumper" in reason else ""
            active[kind] = Cause(event.t, f"{reason}: e-stop latched at {event.t:.1f} s{wait}")
        elif kind in (STALE_SENSOR, GEOFENCE_STOP, FAULT_STOP):
            active[kind] = Cause(event.t, f"{reason} (robot stopped at {event.t:.1f} s)")
        elif kind == ESTOP_RESET:
            active.pop(ESTOP_LATCHED, None)
        for stop, end in STOP_EVENTS.items():
            if kind == end:
                active.pop(stop, None)
    return min(active.values(), key=lambda c: c.t) if active else None


def judge(run: DryRun) -> list[Cause]:
    """Every reason the run did not succeed, in time order; empty: it succeeded.

    Success means the mission completed, with no collision and no geofence breach,
    every checkpoint reached within its position and heading tolerances (ground truth),
    and every item inspected with a fresh image and detected.
    """
    causes: list[Cause] = []
    result = run.result
    end = run.robot.time
    if result.outcome != "completed":
        stop = _active_stop(run) if result.outcome == "timeout" else None
        if stop is not None:
            causes.append(stop)
        elif result.outcome == "timeout":
            causes.append(Cause(end, f"timeout: {result.reason}"))
        else:
            causes.append(Cause(end, result.reason))
    if not result.stop_sent:
        causes.append(Cause(end, "the robot link was lost: the final stop was not confirmed"))
    for c in run.robot.truth.collisions:
        causes.append(Cause(c.time, c.describe()))
    for t, zone in run.breaches:
        causes.append(Cause(t, f"geofence breach: the robot entered zone '{zone}' at {t:.1f} s"))
    nav = run.scenario.mission.navigation
    for cp in run.checkpoints:
        if not cp.reached or cp.position_error is None or cp.time is None:
            continue
        if cp.position_error > nav.position_tolerance:
            causes.append(
                Cause(
                    cp.time,
                    f"checkpoint {cp.id} reached {cp.position_error * 100:.0f} cm from its "
                    f"pose (tolerance {nav.position_tolerance * 100:.0f} cm)"
                    + (
                        f", with a pose uncertainty of {cp.pose_sigma * 100:.0f} cm"
                        if cp.uncertain and cp.pose_sigma is not None
                        else ""
                    ),
                )
            )
        heading_tol = math.degrees(nav.heading_tolerance)
        if cp.heading_error_deg is not None and cp.heading_error_deg > heading_tol:
            causes.append(
                Cause(
                    cp.time,
                    f"checkpoint {cp.id} reached {cp.heading_error_deg:.1f} deg off its "
                    f"heading (tolerance {heading_tol:.1f} deg)",
                )
            )
    causes.extend(_item_causes(run))
    causes.sort(key=lambda c: c.t)
    return causes


def _item_causes(run: DryRun) -> list[Cause]:
    """Items inspected with a stale image (one cause per camera) or not detected."""
    causes: list[Cause] = []
    stale: dict[str, list[object]] = {}
    for r in run.result.progress.results:
        if getattr(r, "stale", False):
            stale.setdefault(r.camera, []).append(r)
        elif not r.detected:
            causes.append(
                Cause(r.stamp, f"item {r.item} not detected at checkpoint {r.checkpoint}")
            )
    for camera, items in stale.items():
        since, what = _stale_source(run, camera, min(r.stamp for r in items))  # type: ignore[attr-defined]
        causes.append(
            Cause(since, f"{what} stale from {since:.1f} s: {len(items)} items not inspected")
        )
    return causes


def _stale_source(run: DryRun, camera: str, stamp: float) -> tuple[float, str]:
    """When and what went stale for an item inspected at ``stamp`` with ``camera``: the
    camera's images, else its pan-tilt unit's angles."""
    platform = run.scenario.mission.platform
    rigs = camera_ids(platform, camera) if camera in platform.cameras else (camera,)
    sources = [(f"camera:{rig}", f"camera {rig}") for rig in rigs]
    sources.append((f"ptu:{camera}", f"pan-tilt unit {camera} angles"))
    for key, what in sources:
        since = _stale_since(run.stale_sensors.get(key, ()), stamp)
        if since is not None:
            return since, what
    return stamp, f"camera {camera}"


def _stale_since(intervals: Sequence[StaleInterval], stamp: float) -> float | None:
    """When the stale stretch that covers ``stamp`` began (None: no stretch covers it)."""
    for interval in intervals:
        start = interval.since if interval.since is not None else interval.detected
        if start <= stamp and (interval.until is None or stamp <= interval.until):
            return start
    return None


def _with_start(scenario: Scenario, start: Pose2) -> Scenario:
    return dataclasses.replace(scenario, start=start)
