"""Mission model -> behaviour tree (ARCHITECTURE.md §5), checked before it runs.

The tree::

    Parallel "walkaround"
    |-- Sequence "sensing"              localise, obstacles, features (always SUCCESS)
    `-- Selector "mode"
        |-- GuardedBranch "collaborative"  [operator takes over?] -> GuardSelector "operator":
        |                                    (the joystick's branch goes here)
        |                                    [operator lost?] -> hold: operator lost (asks)
        |                                    [follow requested?] -> follow operator
        |                                    operator control (hold still, default)
        `-- Sequence "mission" (memory)
            |-- start mission
            |-- Sequence "approach"      navigate(waypoint)... [or repeat(taught route)]
            |                            navigate(P)
            |-- Sequence "inspection"    per checkpoint: navigate(cp) -> correct camera
            |                            angle -> inspect items -> dwell -> done
            `-- Sequence "return"        navigate(waypoint)... navigate(P) -> navigate(station)

    navigate(goal) = Sequence [not trapped?, GuardSelector:
                                  [e-stop?] -> emergency stop
                                  [reached?] -> stop
                                  go to goal (default)]
    repeat(route) = Sequence [route progressing?, GuardSelector:
                                  [e-stop?] -> emergency stop
                                  avoidance (towards the current key image)
                                  follow taught route (default; seed 002 §3)]

The operator's take-over pauses the mission; the hand-back resumes it where it was
(ARCHITECTURE §5). While they have the robot it is in the thesis's collaborative mode
(seed 000 Table 2.3, figure 2.21; docs/collaborative-mode.md): it follows the person they
designate (:mod:`behaviours.controllers.follow`), stops and asks when that person is lost,
and otherwise holds still. The mission's memory sequences are :class:`ResumableSequence`: py_trees
restarts a memory sequence that a higher-priority branch has stopped, which would start
the mission again from ``start mission`` (empty progress, every checkpoint driven again).
A resumable one remembers the child that was running and resumes there; a checkpoint
resumes at its own navigation (the robot may have been moved), and the inspection skips
the items the progress already records. An operator's abort ends the mission: the robot
drives back to the handover point P (avoidance, e-stop and geofence as on any leg; a
take-over still pre-empts it) and the runtime ends the run as ``aborted``.

After building, :func:`check_tree` proves the wiring: every blackboard key a behaviour
reads has a writer that runs before it (or is written by the runtime), and every
controller of a guard selector sits behind its guard (or is the selector's default).
Neither py_trees nor BehaviorTree.CPP checks this; here a wiring mistake fails at compile
time. Options the executive cannot honour are reported with their file and line.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Iterator
from dataclasses import dataclass, field

import py_trees
import shapely
from shapely.geometry import Point
from shapely.geometry import Polygon as ShapelyPolygon
from shapely.ops import unary_union

from behaviours.base import Controller, Guard, Node, unobserved
from behaviours.controllers.avoidance import (
    DODGE,
    REPLAN,
    SPIRAL,
    AvoidanceParams,
    AvoidancePolicy,
    AvoidanceTrigger,
    AvoiderFactory,
    AvoidObstacle,
    DodgeObstacle,
)
from behaviours.controllers.fallback import FollowPlannedPath
from behaviours.controllers.follow import (
    AskOperator,
    FollowOperator,
    FollowRequested,
    FollowSession,
    OperatorLost,
)
from behaviours.controllers.inspection import InspectItems, SetProgress, StartMission
from behaviours.controllers.joystick import JoystickActive, JoystickControl
from behaviours.controllers.motion import (
    CorrectCameraAngle,
    Dwell,
    EStopHold,
    GoToGoalController,
    HoldStill,
    Rejoined,
)
from behaviours.controllers.repeat import (
    FollowTaughtRoute,
    RouteGoal,
    RouteProgressing,
    RouteSession,
)
from behaviours.controllers.servo import (
    IBVS,
    PBVS,
    AimedGoToGoal,
    FeaturesLostRecently,
    FeaturesVisible,
    ServoParams,
    ServoSession,
    ServoStartGoal,
    SlideServoStart,
    TrackFeature,
    VisualServoing,
)
from behaviours.goals import Goal
from behaviours.guards.conditions import (
    EmergencyStop,
    NotTrapped,
    OperatorAborted,
    OperatorTakeOver,
    PoseNotGoodEnough,
    Reached,
    RejoinAfterHandBack,
)
from behaviours.guards.operator_help import AskWhenTrapped, SkipCheckpoint, SkipRequests
from behaviours.keys import COMMAND, EXTERNAL_KEYS, MissionProgress
from behaviours.laws.augmented_image import MIN_REAL_POINTS
from behaviours.laws.go_to_goal import GoToGoalParams
from behaviours.laws.mosaic import localiser_from
from behaviours.laws.retreat import Retreat
from behaviours.sensing.ceiling import CeilingFixer, camera_mismatch
from behaviours.sensing.features import SenseFeatures
from behaviours.sensing.localisation import Localise
from behaviours.sensing.obstacles import SenseObstacles
from behaviours.sensing.registration import AircraftRegistrar
from executive.core.frames import AircraftPlacement, Pose2
from executive.core.geometry import to_shapely
from executive.core.model import CameraKind, Checkpoint, Frame, Mission, TaughtRoute, Waypoint
from executive.core.mosaicfile import MosaicFormatError, read_mosaic
from executive.core.problems import InvalidInputError, Problem, SourceLocation
from executive.core.records import VelocityCommand, camera_ids

Status = py_trees.common.Status

AVOIDANCE_PATH_MARGIN = 0.3
"""An obstacle within half the robot's width plus r_ES plus this (m) of the straight way
to the goal is on the way: passing it closer would trip the e-stop."""

NEAR_AIRFRAME = 3.0
"""Within this distance (m) of the aircraft the inspection speed applies."""

SERVO_START = 1.0
"""Visual servoing starts this far (m) behind the checkpoint on its heading line, reached
by metric go-to-goal: the camera's straight approach then keeps the base's heading (four
controls, five configuration variables: behaviours/controllers/servo.py). A start the
lasers show too close to something to turn in place at slides towards the checkpoint
(:class:`~behaviours.controllers.servo.SlideServoStart`)."""

SERVO_START_TOLERANCE = (0.02, math.radians(0.5))
"""Position (m) and heading (rad) tolerances of the servo start: a flat target seen
face-on hardly tells a sideways offset of the camera from a turn, so the lateral offset
the servo starts with is, to first order, the one it ends with."""

SERVO_LOST_GRACE = 4.0
"""Seconds a servo navigation holds still for lost features before metric go-to-goal."""

VICINITY_MARGIN = 3.0
"""Metres beyond P's own distance from the airframe within which a robot handed back by
the operator is "in P's close vicinity" (fig. 2.21) and resumes its phase; farther out it
goes back to P first. Three metres: about two robot lengths, the approach's last leg."""

SERVO_SPEED = 0.3
"""Top speed (m/s) of visual servoing (also capped by the mission's inspection speed). The
approach-line row turns the base back onto the checkpoint's heading line over its 0.4 m
look-ahead; at 0.5 m/s its heading loop lagged that (and the gain (4, 0.5, 10) with it):
A320 CP15 of a busy-apron campaign episode ended 2.1 cm across the line, 0.46 cm at
0.3 m/s."""

CAMERA_ANGLE_THRESHOLD = math.radians(0.25)
"""Correct camera angle acts when the measured pan is this far from the pan the
checkpoint's pose needs (it settles to a fifth of it)."""

JOYSTICK_SPEED = 0.5
JOYSTICK_OMEGA = 0.6
"""The operator's joystick drives at most this fast (m/s, rad/s): walking pace beside the
robot; the safety layer's slowdown and e-stop apply as to every command."""

SERVO_VERIFIED: frozenset[str] = frozenset({"A320-200", "B737-800"})
"""Aircraft types whose servo checkpoints are reached by visual servoing by default
(``CompileOptions.servo`` None): those where the sim2d end-to-end runs meet 2 cm and
0.5 deg at every servo checkpoint, clear and offset aprons (tests/test_executive_e2e.py),
*and* every other shipped test holds. Not the lab mock-up, whose servoing meets the bar
(tests/test_servo_e2e.py, with ``servo=True``) but which leaves checkpoint 3 after the
perpendicular servo approach with the fence a 3.5 m blob "on the way" of the obstacle
tracker: avoidance engages, which the empty-lab test of issue 12 forbids. There, and on
any other type, checkpoints keep metric go-to-goal with a ``servo-metric`` warning that
says so (``--servo`` forces servoing on)."""


class _LeanStop:
    """A composite's stop without py_trees' debug string nobody reads
    (:func:`behaviours.base.unobserved`): the tree stops composites thousands of times a
    second. Sequences and selectors stop as :class:`~py_trees.composites.Composite` does."""

    def stop(self, new_status: Status = Status.INVALID) -> None:
        if unobserved():
            py_trees.composites.Composite.stop(self, new_status)  # type: ignore[arg-type]
        else:
            super().stop(new_status)  # type: ignore[misc]


class Sequence(_LeanStop, py_trees.composites.Sequence):
    """py_trees' sequence, with a lean stop (:class:`_LeanStop`)."""


class Selector(_LeanStop, py_trees.composites.Selector):
    """py_trees' selector, with a lean stop (:class:`_LeanStop`)."""


class Parallel(py_trees.composites.Parallel):
    """py_trees' parallel, with a lean stop too (running children are stopped first, as
    py_trees' own does)."""

    def stop(self, new_status: Status = Status.INVALID) -> None:
        if not unobserved():
            super().stop(new_status)
            return
        for child in self.children:
            if child.status == Status.RUNNING:
                child.stop(Status.INVALID)
        py_trees.composites.Composite.stop(self, new_status)


class GuardSelector(Selector):
    """A priority selector of guarded controllers, re-evaluated every tick."""

    def __init__(self, name: str, children: list[py_trees.behaviour.Behaviour]) -> None:
        super().__init__(name, memory=False, children=children)


class GuardedBranch(Sequence):
    """[guard] -> controller: the controller runs only while its guard holds. The
    controller may be a :class:`GuardSelector` of guarded controllers (the collaborative
    mode's)."""

    def __init__(self, name: str, guard: Guard, controller: Controller | GuardSelector) -> None:
        super().__init__(name, memory=False, children=[guard, controller])


class ResumableSequence(Sequence):
    """A memory sequence that a pre-emption pauses instead of resetting (ARCHITECTURE §5).

    py_trees' memory sequence starts again from its first child whenever it is ticked
    after a stop to INVALID, and that is what a selector does to a running lower-priority
    branch when a higher one engages (the operator's take-over): the mission would start
    over. This one records the child that was running when it is stopped while RUNNING and
    resumes there on its next tick: the children before it (done) are not run again, the
    one that was running starts afresh (``initialise`` again: a navigation re-plans from
    where the robot now is). Nested resumable sequences each keep their own place.

    ``rewind_to``: a pause at or after that child resumes at it instead. A checkpoint
    resumes at its own navigation, since what follows it (aim the camera, inspect, dwell)
    needs the robot at the checkpoint and the operator may have moved it.

    A sequence that ends (SUCCESS or FAILURE) starts from its first child next time, as
    py_trees' own does; a fresh start forgets the pauses recorded below it, so a stale
    place never leaks into a new pass. BehaviorTree.CPP v4's ``SequenceWithMemory`` keeps
    its index through a halt in the same way (:attr:`btcpp_tag`, used by the export).
    """

    btcpp_tag = "SequenceWithMemory"

    def __init__(
        self,
        name: str,
        children: list[py_trees.behaviour.Behaviour],
        rewind_to: int | None = None,
    ) -> None:
        super().__init__(name, memory=True, children=children)
        if rewind_to is not None and not 0 <= rewind_to < len(children):
            raise ValueError(f"'{name}': rewind_to {rewind_to} is not a child index")
        self.rewind_to = rewind_to
        self.paused_at: int | None = None
        """Index of the child to resume at, while paused (None: start from the first)."""

    def stop(self, new_status: Status = Status.INVALID) -> None:
        if new_status == Status.INVALID:
            if self.status == Status.RUNNING and self.current_child is not None:
                index = self.children.index(self.current_child)
                if self.rewind_to is not None:
                    index = min(index, self.rewind_to)
                self.paused_at = index
        else:
            self.paused_at = None
        super().stop(new_status)

    def tick(self) -> Iterator[py_trees.behaviour.Behaviour]:
        if self.status != Status.RUNNING:
            if self.paused_at is not None:
                # py_trees' memory sequence carries on at current_child while RUNNING
                self.current_child = self.children[self.paused_at]
                self.paused_at = None
                self.status = Status.RUNNING
                self.feedback_message = f"resumed at '{self.current_child.name}'"
            else:
                self.feedback_message = ""
                for node in self.iterate():
                    if node is not self and isinstance(node, ResumableSequence):
                        node.paused_at = None
        yield from super().tick()


class Stop(Controller):
    """Zero command and SUCCESS: ends a navigation that has reached its goal."""

    writes = (COMMAND,)

    def __init__(self, name: str = "stop") -> None:
        super().__init__(name)

    def update(self) -> Status:
        self.write(COMMAND, VelocityCommand.stop())
        return Status.SUCCESS


class CompileError(InvalidInputError):
    """The mission cannot be compiled as written; every reason with its file and line."""


@dataclass
class CompileOptions:
    rate_hz: float = 50.0
    trapped_after: float = 120.0
    """Seconds without progress towards a goal before the mission fails as trapped."""
    placement: AircraftPlacement | None = None
    """The executive's idea of where the aircraft stands (default: nominal parking)."""
    start: Pose2 | None = None
    """Initial pose estimate in A (default: the charging station)."""
    resume: MissionProgress | None = None
    """Progress journaled by an earlier run: completed checkpoints are not visited again."""
    avoidance: bool = True
    """Avoid obstacles on the way (ARCHITECTURE §5, issue #6): the policy's spiral,
    velocity obstacles and fallback planner under the e-stop guard. False: no avoidance
    branches; the robot waits behind an obstacle (the e-stop and the safety layer's
    slowdown handle it)."""
    avoidance_params: AvoidanceParams | None = None
    """Tuning of the avoidance policy (r_OA and the corridor come from the mission)."""
    avoider: AvoiderFactory | None = None
    """Builds the avoidance controller (default :class:`AvoidObstacle`, the spiral)."""
    register_aircraft: bool = True
    """Register the aircraft from the laser returns (False: trust the nominal placement)."""
    ask_operator: bool = False
    """An operator is at hand (the HUD of a live dry-run or of the robot, issue 15): a
    checkpoint's trapped navigation asks them (wait, take over, skip) instead of failing
    the mission (:mod:`behaviours.guards.operator_help`)."""
    servo: bool | None = None
    """Reach checkpoints with a servo target by visual servoing (issue 13). None: on the
    aircraft types of :data:`SERVO_VERIFIED`; True: everywhere; False: never (metric)."""
    servo_params: ServoParams | None = None
    """The servo's tuning (None: the mission's speeds); its ``line_from`` is always the
    servo start, :data:`SERVO_START` (the compiler checks the approach from there)."""


@dataclass
class CompiledMission:
    mission: Mission
    root: py_trees.behaviour.Behaviour
    placement: AircraftPlacement
    warnings: list[Problem] = field(default_factory=list)
    goto_nodes: list[GoToGoalController] = field(default_factory=list)
    avoidance_policies: list[AvoidancePolicy] = field(default_factory=list)
    servo_sessions: list[ServoSession] = field(default_factory=list)
    route_sessions: list[RouteSession] = field(default_factory=list)
    """The taught routes' repetitions (issue 17): their key-passed events and records."""


def _warn(where: SourceLocation, code: str, message: str) -> Problem:
    return Problem(where, code, message)


class _Builder:
    def __init__(self, mission: Mission, options: CompileOptions) -> None:
        self.mission = mission
        self.options = options
        self.placement = options.placement or mission.nominal_placement()
        self.period = 1.0 / options.rate_hz
        self.errors: list[Problem] = []
        self.warnings: list[Problem] = []
        self.goto_nodes: list[GoToGoalController] = []
        self.avoidance_policies: list[AvoidancePolicy] = []
        self.servo_sessions: list[ServoSession] = []
        self.route_sessions: list[RouteSession] = []
        self.skips = SkipRequests()
        self.take_over = OperatorTakeOver()
        """The collaborative mode's guard; its hand-backs drive fig. 2.21's rejoin."""
        nav = mission.navigation
        platform = mission.platform
        self.checkpoint_tolerance = (
            min(0.05, nav.position_tolerance / 3.0),
            min(math.radians(2.0), nav.heading_tolerance / 2.5),
        )
        self.params = dataclasses.replace(
            GoToGoalParams.from_model(platform, nav),
            position_tolerance=self.checkpoint_tolerance[0],
            heading_tolerance=self.checkpoint_tolerance[1],
        )
        airframe = [to_shapely(s) for s in (*mission.aircraft.outline, *mission.aircraft.footprint)]
        shapes = [ShapelyPolygon(self.placement.to_airport_xy(g.exterior.coords)) for g in airframe]
        self.airframe = unary_union(shapes)
        shapely.prepare(self.airframe)
        m = mission
        self.registers = bool(
            options.register_aircraft and m.aircraft.footprint and m.platform.lasers
        )
        self.inspection_unit = next(
            (c for c in platform.cameras.values() if c.kind is CameraKind.PTZ), None
        )

    # -- helpers ----------------------------------------------------------------------------
    def speed_limit(self, pose: Pose2) -> float:
        nav = self.mission.navigation
        near = self.airframe.distance(Point(pose.x, pose.y)) < NEAR_AIRFRAME
        return nav.inspection_speed if near else nav.cruise_speed

    def waypoint_goal(self, wp: Waypoint) -> Goal:
        heading = wp.heading if wp.heading is not None else 0.0
        return Goal(Pose2(wp.x, wp.y, heading), wp.frame, self.placement)

    def checkpoint_goal(self, cp: Checkpoint) -> Goal:
        return Goal(cp.pose, Frame.AIRCRAFT, self.placement)

    def navigate(
        self,
        label: str,
        goal: Goal,
        use_heading: bool,
        tolerance: tuple[float, float | None],
        servo: ServoSession | None = None,
        aim: ServoSession | None = None,
        checkpoint: str | None = None,
        prepare: py_trees.behaviour.Behaviour | None = None,
    ) -> py_trees.behaviour.Behaviour:
        """One navigation: its guards, then metric go-to-goal. ``servo``: the checkpoint's
        visual-servoing branches; ``aim`` (or ``servo``): go-to-goal keeps the servo units
        aimed at that session's target (:class:`AimedGoToGoal`). ``checkpoint``: the
        navigation leads to that checkpoint, whose trap asks the operator when one is at
        hand (:attr:`CompileOptions.ask_operator`). ``prepare``: a behaviour ticked first
        every tick, that always succeeds (:class:`SlideServoStart` moves the goal)."""
        params = dataclasses.replace(
            self.params,
            position_tolerance=tolerance[0],
            heading_tolerance=tolerance[1] if tolerance[1] is not None else math.pi,
        )
        aim = aim or servo
        if aim is not None:
            goto: GoToGoalController = AimedGoToGoal(
                aim, goal, params, use_heading, self.period, self.speed_limit, f"go to {label}"
            )
        else:
            goto = GoToGoalController(
                goal, params, use_heading, self.period, self.speed_limit, name=f"go to {label}"
            )
        self.goto_nodes.append(goto)
        guards = GuardSelector(
            f"guards {label}",
            [
                self.estop_branch(label),
                *(
                    [
                        GuardedBranch(
                            f"relocalise {label}",
                            PoseNotGoodEnough(),
                            HoldStill("hold: relocalise"),
                        )
                    ]
                    if goal.frame is Frame.AIRCRAFT and self.registers
                    else []
                ),
                *self.avoidance(label, goal),
                *(self.servo_branches(label, servo) if servo is not None else []),
                GuardedBranch(
                    f"reached {label}",
                    Reached(goal, tolerance[0], tolerance[1] if use_heading else None),
                    Stop(),
                ),
                goto,
            ],
        )
        first = [prepare] if prepare is not None else []
        return Sequence(
            f"navigate {label}",
            memory=False,
            children=[*first, self.trap(label, goal, tolerance[0], checkpoint), guards],
        )

    def trap(
        self, label: str, goal: Goal, tolerance: float, checkpoint: str | None
    ) -> py_trees.behaviour.Behaviour:
        """The navigation's trap guard (within ``tolerance`` m of the goal the robot is
        there); with an operator at hand, on the way to a checkpoint, a trap asks them
        rather than failing."""
        trap = NotTrapped(goal, self.options.trapped_after, at_goal=tolerance, towards=label)
        if checkpoint is None or not self.options.ask_operator:
            return trap
        ask = AskWhenTrapped(trap, checkpoint, self.skips, name=f"ask operator {label}")
        return Selector(f"trapped {label}?", memory=False, children=[trap, ask])

    @functools.cached_property
    def retreat(self) -> Retreat:
        """How this platform may back out of an obstacle e-stop (behaviours.laws.retreat)."""
        return Retreat.of(self.mission)

    def estop_branch(self, label: str) -> GuardedBranch:
        """[e-stop?] -> emergency stop, which backs out of an obstacle latch where the
        lasers show the way clear (:attr:`retreat`)."""
        m = self.mission
        guard = EmergencyStop(m.safety.r_es, m.safety.estop_hold, name="e-stop?")
        return GuardedBranch(f"e-stop {label}", guard, EStopHold(guard.latch, self.retreat))

    def avoidance(self, label: str, goal: Goal) -> list[py_trees.behaviour.Behaviour]:
        """The obstacle-avoidance branches of a navigation (ARCHITECTURE §5), if enabled:
        velocity obstacles for fast obstacles, then the spiral; one policy decides."""
        m = self.mission
        if not (self.options.avoidance and m.platform.lasers):
            return []
        margin = 0.5 * m.platform.width + m.safety.r_es + AVOIDANCE_PATH_MARGIN
        params = dataclasses.replace(
            self.options.avoidance_params or AvoidanceParams(),
            r_oa=m.safety.r_oa_trigger,
            margin=margin,
            cruise=m.navigation.cruise_speed,
            too_close=m.safety.r_es + 0.3,
        )
        policy = AvoidancePolicy(goal, params)
        self.avoidance_policies.append(policy)
        session, make = policy.session, self.options.avoider
        if make is None:  # velocity obstacles never slower than the navigation's cruise
            dodge = DodgeObstacle(
                goal,
                session,
                m.platform,
                self.period,
                nu_min=m.navigation.cruise_speed,
                slowdown=(m.safety.r_es, m.safety.r_oa_trigger),
            )
        else:
            dodge = make(goal, session, m.platform, self.period)
        spiral = (make or AvoidObstacle)(goal, session, m.platform, self.period)
        replan = FollowPlannedPath(goal, session, m, self.period, self.params)
        return [
            GuardedBranch(f"dodge {label}", AvoidanceTrigger(policy, DODGE), dodge),
            GuardedBranch(f"replan {label}", AvoidanceTrigger(policy, REPLAN), replan),
            GuardedBranch(f"avoid {label}", AvoidanceTrigger(policy, SPIRAL), spiral),
        ]

    def servo_branches(self, label: str, session: ServoSession) -> list[GuardedBranch]:
        """[features visible (measured or reconstructed)?] -> visual servoing, IBVS above
        PBVS (one session decides which holds, ARCHITECTURE §5)."""
        modes = (IBVS, PBVS) if session.method == PBVS else (IBVS,)
        branches = [
            GuardedBranch(
                f"{mode} {label}", FeaturesVisible(session, mode), VisualServoing(session, mode)
            )
            for mode in modes
        ]
        branches.append(
            GuardedBranch(
                f"wait for features {label}",
                FeaturesLostRecently(session, SERVO_LOST_GRACE),
                HoldStill(f"hold: {session.target.id} lost"),
            )
        )
        return branches

    def servo_enabled(self) -> bool:
        if self.options.servo is not None:
            return self.options.servo
        return self.mission.aircraft.type in SERVO_VERIFIED

    def registrar(self) -> AircraftRegistrar | None:
        """The laser registration of the aircraft, when asked for and possible."""
        if not self.registers:
            return None
        return AircraftRegistrar(self.mission.aircraft, dict(self.mission.platform.lasers))

    def ceiling_fixer(self) -> CeilingFixer | None:
        """Ceiling fixes for the pose filter (issue 17): only with both the platform's
        ceiling camera and the mission's mosaic, learnt with a camera like it."""
        m = self.mission
        spec = m.platform.ceiling_camera
        if spec is None or m.ceiling_mosaic is None:
            return None
        try:
            data = read_mosaic(m.ceiling_mosaic)
            localiser = localiser_from(data, m.ceiling_mosaic)
        except MosaicFormatError as exc:
            self.errors.append(Problem(SourceLocation(m.source), "ceiling-mosaic", str(exc)))
            return None
        mismatch = camera_mismatch(spec, localiser, data.ceiling_height)
        if mismatch is not None:
            self.errors.append(
                Problem(spec.where, "ceiling-camera", f"ceiling-camera and mosaic: {mismatch}")
            )
            return None
        return CeilingFixer(localiser)

    # -- phases -------------------------------------------------------------------------------
    def approach(self) -> py_trees.behaviour.Behaviour:
        m = self.mission
        loose = (0.3, None)
        children: list[py_trees.behaviour.Behaviour] = [SetProgress("approach", goal="P")]
        for wp in m.approach:
            children.append(
                self.navigate(wp.id, self.waypoint_goal(wp), wp.heading is not None, loose)
            )
        if m.taught_route is not None:
            children.append(self.repeat_route(m.taught_route))
        children.append(self.navigate("P", self.waypoint_goal(m.handover), False, (0.2, None)))
        return ResumableSequence("approach", children)

    def repeat_route(self, route: TaughtRoute) -> py_trees.behaviour.Behaviour:
        """A taught route repeated (issue 17, seed 002 §3) with the guards of any
        navigation: [route progressing?, GuardSelector: [e-stop?] -> emergency stop,
        avoidance towards the current key image, follow taught route (default)]."""
        session = RouteSession(route, self.mission.platform)
        self.route_sessions.append(session)
        label = f"route {route.id}"
        goal = RouteGoal(route.end, Frame.AIRPORT, None, session)
        guards = GuardSelector(
            f"guards {label}",
            [
                self.estop_branch(label),
                *self.avoidance(label, goal),
                FollowTaughtRoute(session, self.speed_limit, name=f"follow {label}"),
            ],
        )
        trap = RouteProgressing(session, self.options.trapped_after, name=f"{label} progressing?")
        return Sequence(f"navigate {label}", memory=False, children=[trap, guards])

    def checkpoint(self, cp: Checkpoint) -> py_trees.behaviour.Behaviour:
        m = self.mission
        children: list[py_trees.behaviour.Behaviour] = [
            SetProgress("inspection", checkpoint=cp.id, goal=cp.id)
        ]
        for k, (vx, vy) in enumerate(cp.via, start=1):
            via = Goal(Pose2(vx, vy, 0.0), Frame.AIRCRAFT, self.placement)
            children.append(
                self.navigate(f"{cp.id} via {k}", via, False, (0.3, None), checkpoint=cp.id)
            )
        servo: ServoSession | None = None
        if cp.camera is not None and cp.target is not None:
            method = (cp.servo or m.aircraft.features[cp.target].servo).value
            if self.servo_enabled():
                servo = ServoSession(
                    cp.id,
                    m.aircraft.features[cp.target],
                    cp.pose,
                    m.platform,
                    m.aircraft.origin_height,
                    method,
                    dataclasses.replace(self.options.servo_params, line_from=SERVO_START)
                    if self.options.servo_params is not None
                    else ServoParams(
                        max_speed=min(m.navigation.inspection_speed, SERVO_SPEED),
                        max_omega=m.platform.max_angular_speed / 2,
                        line_from=SERVO_START,
                    ),
                )
                self.servo_sessions.append(servo)
                if servo.drivable:
                    label = f"{cp.id} servo start"
                    slide = SlideServoStart(
                        servo,
                        Goal(cp.pose, Frame.AIRCRAFT, self.placement),
                        m.platform,
                        m.safety.r_es,
                        name=f"slide {label}",
                    )
                    children.append(
                        self.navigate(
                            label,
                            ServoStartGoal(servo.start_f(), Frame.AIRCRAFT, self.placement, servo),
                            True,
                            SERVO_START_TOLERANCE,
                            aim=servo,
                            checkpoint=cp.id,
                            prepare=slide,
                        )
                    )
                else:
                    self.warnings.append(
                        _warn(
                            cp.where,
                            "servo-bearing-only",
                            f"checkpoint '{cp.id}': no camera sees {MIN_REAL_POINTS} points of "
                            f"'{cp.target}' from the checkpoint ({len(servo.points_f)} in the "
                            "model): its image fixes a bearing, not a pose, so metric "
                            "go-to-goal reaches the checkpoint with a unit tracking the "
                            "target, and correct camera angle sets the heading from it",
                        )
                    )
            else:
                self.warnings.append(
                    _warn(
                        cp.where,
                        "servo-metric",
                        f"checkpoint '{cp.id}': visual servoing ({method}) on '{cp.target}' is "
                        + (
                            "turned off (--no-servo)"
                            if self.options.servo is False
                            else f"not enabled by default on {m.aircraft.type} (not yet "
                            "shown to meet 2 cm and 0.5 deg at every servo checkpoint with "
                            "every shipped scenario green)"
                        )
                        + "; the checkpoint is reached by metric go-to-goal "
                        "(walkaround dry-run --servo to servo)",
                    )
                )
        reach = len(children)  # a pause from here on resumes by reaching the checkpoint
        drives = servo if servo is not None and servo.drivable else None
        children.append(
            self.navigate(
                cp.id,
                self.checkpoint_goal(cp),
                True,
                self.checkpoint_tolerance,
                servo=drives,
                aim=servo,
                checkpoint=cp.id,
            )
        )
        if servo is not None and not servo.drivable:
            children.append(TrackFeature(servo, name=f"track {cp.target}"))
        if cp.camera is not None and cp.target is not None:
            camera = m.platform.cameras[cp.camera]
            children.append(
                CorrectCameraAngle(
                    camera,
                    camera_ids(m.platform, cp.camera),
                    m.aircraft.features[cp.target],
                    cp.pose,
                    m.aircraft.origin_height,
                    threshold=CAMERA_ANGLE_THRESHOLD,
                    max_omega=m.platform.max_angular_speed / 2,
                    servoed=servo is not None,
                    servo_unit=servo.servoed_unit if servo is not None else None,
                    track=servo.track_rates if servo is not None else None,
                    name=f"correct {cp.camera} angle",
                )
            )
        if cp.items:
            unit = self.inspection_unit or (
                m.platform.cameras[cp.camera] if cp.camera is not None else None
            )
            if unit is None:
                self.errors.append(
                    Problem(
                        cp.where,
                        "no-inspection-camera",
                        f"checkpoint '{cp.id}' inspects items but the platform has no PTZ "
                        "camera and the checkpoint names no camera",
                    )
                )
            else:
                ids = camera_ids(m.platform, unit.id)
                children.append(
                    InspectItems(cp.id, cp.items, m.aircraft, unit, ids, name=f"inspect {cp.id}")
                )
        if cp.dwell > 0:
            children.append(Dwell(cp.dwell, name=f"dwell {cp.id}"))
        children.append(SetProgress("inspection", checkpoint=cp.id, done=True))
        visit = ResumableSequence(f"checkpoint {cp.id}", children, rewind_to=reach)
        if not self.options.ask_operator:
            return visit
        return Selector(
            f"checkpoint {cp.id} or skip",
            memory=False,
            children=[visit, SkipCheckpoint(cp.id, self.skips)],
        )

    def inspection(self) -> py_trees.behaviour.Behaviour:
        done = set(self.options.resume.completed) if self.options.resume else set()
        todo = [cp for cp in self.mission.checkpoints if cp.id not in done]
        return ResumableSequence("inspection", [self.checkpoint(cp) for cp in todo])

    def return_home(self) -> py_trees.behaviour.Behaviour:
        m = self.mission
        loose = (0.3, None)
        children: list[py_trees.behaviour.Behaviour] = [SetProgress("return", goal="station")]
        for wp in m.return_route:
            children.append(
                self.navigate(wp.id, self.waypoint_goal(wp), wp.heading is not None, loose)
            )
        children.append(self.navigate("P (return)", self.waypoint_goal(m.handover), False, loose))
        station = m.airport.station
        children.append(
            self.navigate(
                "station",
                Goal(station),
                True,
                (m.navigation.position_tolerance, m.navigation.heading_tolerance),
            )
        )
        return ResumableSequence("return", children)

    def collaborative(self) -> GuardedBranch:
        """The collaborative mode (seed 000 Table 2.3, figure 2.21): while the operator has
        the robot, drive it with their joystick while its stream keeps coming (issue 15;
        within :data:`JOYSTICK_SPEED` and :data:`JOYSTICK_OMEGA`), else follow the person
        they designate (laser tracks; the trail keeps the robot where the person walked,
        the safety layer filters every command), stop and ask when that person is lost,
        else hold still. A take-over pre-empts the return to P after an abort too. No
        e-stop branch: the safety
        layer's e-stop latch (r_ES, bumpers, the operator's e-stop) stops every command,
        and the follower's braking cap keeps its own commands outside r_ES."""
        m = self.mission
        session = FollowSession(m.platform, m.safety.r_es, self.period)
        control = GuardSelector(
            "operator",
            [
                # a stick in the hand wins over the follower; its stream stale: stop
                GuardedBranch(
                    "joystick",
                    JoystickActive(),
                    JoystickControl(
                        min(JOYSTICK_SPEED, m.platform.max_speed),
                        min(JOYSTICK_OMEGA, m.platform.max_angular_speed),
                    ),
                ),
                GuardedBranch("operator lost", OperatorLost(session), AskOperator(session)),
                GuardedBranch("follow", FollowRequested(session), FollowOperator(session)),
                HoldStill("operator control"),
            ],
        )
        return GuardedBranch("collaborative", self.take_over, control)

    def abort(self) -> py_trees.behaviour.Behaviour:
        """After the operator's abort: back to the handover point P, then the run ends
        (:class:`behaviours.guards.conditions.OperatorAborted`). The progress is left as
        it was, so a later ``--resume`` goes on with the checkpoint the abort cut short."""
        back = self.navigate(
            "P (abort)", self.waypoint_goal(self.mission.handover), False, (0.3, None)
        )
        return Sequence("abort: back to P", memory=False, children=[OperatorAborted(), back])

    def rejoin(self) -> py_trees.behaviour.Behaviour:
        """Fig. 2.21's surrender transitions (:class:`RejoinAfterHandBack`): handed back
        out of P's vicinity after the approach, the robot goes back to P first."""
        m = self.mission
        nominal = m.nominal_placement()
        airframe = unary_union(
            [to_shapely(s) for s in (*m.aircraft.outline, *m.aircraft.footprint)]
        )
        p = self.waypoint_goal(m.handover)
        p_f = p.pose if p.frame is Frame.AIRCRAFT else nominal.pose_to_aircraft(p.pose)
        reach = float(airframe.distance(Point(p_f.x, p_f.y))) + VICINITY_MARGIN
        guard = RejoinAfterHandBack(self.take_over, airframe, reach, nominal)
        back = self.navigate("P (rejoin)", p, False, (0.3, None))
        return Sequence("rejoin: back to P", memory=False, children=[guard, back, Rejoined(guard)])

    def build(self) -> py_trees.behaviour.Behaviour:
        m = self.mission
        start = self.options.start or m.airport.station
        sensing = Sequence(
            "sensing",
            memory=False,
            children=[
                Localise(
                    start,
                    m.platform.track,
                    self.placement,
                    self.registrar(),
                    ceiling=self.ceiling_fixer(),
                ),
                SenseObstacles(m.platform, m.airport.zones, m.safety.r_oa_trigger),
                SenseFeatures(m.platform),
            ],
        )
        resume = self.options.resume
        phases: list[py_trees.behaviour.Behaviour] = [StartMission(resume)]
        if resume is None or (not resume.completed and resume.phase == "approach"):
            phases.append(self.approach())
        phases.append(self.inspection())
        phases.append(self.return_home())
        phases.append(SetProgress("done", name="mission done"))
        mission = ResumableSequence("mission", phases)
        mode = Selector(
            "mode",
            memory=False,
            children=[self.collaborative(), self.abort(), self.rejoin(), mission],
        )
        policy = py_trees.common.ParallelPolicy.SuccessOnSelected([mode], synchronise=False)
        return Parallel("walkaround", policy, children=[sensing, mode])


def compile_mission(mission: Mission, options: CompileOptions | None = None) -> CompiledMission:
    """Build and check the tree; raise :class:`CompileError` with every reason otherwise."""
    builder = _Builder(mission, options or CompileOptions())
    root = builder.build()
    errors = builder.errors + [
        Problem(SourceLocation(mission.source), "tree", message) for message in check_tree(root)
    ]
    if errors:
        raise CompileError(errors)
    return CompiledMission(
        mission,
        root,
        builder.placement,
        builder.warnings,
        builder.goto_nodes,
        builder.avoidance_policies,
        builder.servo_sessions,
        builder.route_sessions,
    )


# -- the tree's own checks --------------------------------------------------------------------
def _preorder(node: py_trees.behaviour.Behaviour) -> Iterator[py_trees.behaviour.Behaviour]:
    yield node
    for child in node.children:
        yield from _preorder(child)


def check_tree(root: py_trees.behaviour.Behaviour) -> list[str]:
    """Wiring mistakes of a compiled tree (empty when sound)."""
    problems: list[str] = []
    written = {k.name for k in EXTERNAL_KEYS}
    feedback: list[tuple[str, str]] = []
    for node in _preorder(root):
        if isinstance(node, Node):
            feedback.extend((node.name, k.name) for k in node.reads_previous)
            for key in node.reads:
                if key.name not in written:
                    problems.append(
                        f"'{node.name}' reads {key.name} but nothing writes it before it runs"
                    )
            written.update(k.name for k in node.writes)
        if isinstance(node, GuardSelector):
            *branches, default = node.children
            if not isinstance(default, Controller):
                problems.append(f"'{node.name}' must end with a default controller")
            for branch in branches:
                if not isinstance(branch, GuardedBranch):
                    problems.append(f"'{node.name}': '{branch.name}' is not a guarded branch")
        if isinstance(node, GuardedBranch):
            kids = node.children
            if (
                len(kids) != 2
                or not isinstance(kids[0], Guard)
                or not isinstance(kids[1], Controller | GuardSelector)
            ):
                problems.append(f"'{node.name}' must be [guard] -> controller")
        parent = node.parent
        if (
            isinstance(node, Controller)
            and isinstance(parent, GuardSelector)
            and node is not parent.children[-1]
        ):
            problems.append(
                f"controller '{node.name}' in '{parent.name}' has no guard "
                "(only the last child may be unguarded)"
            )
    for name, key in feedback:
        if key not in written:
            problems.append(f"'{name}' reads {key} from the previous tick but nothing writes it")
    return problems
