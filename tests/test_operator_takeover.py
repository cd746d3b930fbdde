"""The operator's take-over pauses the mission and the hand-back resumes it (issue 12 §6).

ARCHITECTURE §5: "A take-over pauses the mission sequence; the hand-back resumes it where it
was (the progress is never reset)." py_trees restarts a memory sequence that a
higher-priority branch has stopped; :class:`ResumableSequence` keeps its place instead.
Shown at three levels: the composite itself (a hypothesis property over any pattern of
take-overs), the compiled mission tree, and real dry-runs of the lab mission (3
checkpoints) with take-overs in the approach, mid-leg, mid-inspection and repeated, and
an operator's abort.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Callable
from pathlib import Path

import py_trees
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from behaviours.base import Controller, Guard, Node
from behaviours.controllers.inspection import InspectItems
from behaviours.guards.conditions import OperatorAborted, OperatorTakeOver, RejoinAfterHandBack
from behaviours.keys import COMMAND, OPERATOR, PROGRESS, SENSOR_FRAME, ItemResult, MissionProgress
from executive.compiler import GuardedBranch, ResumableSequence, compile_mission
from executive.core.frames import Pose2, wrap_angle
from executive.core.loader import load_mission
from executive.core.model import Frame
from executive.core.records import (
    JoystickCommand,
    OperatorRequests,
    SensorFrame,
    VelocityCommand,
)
from executive.dryrun import DryRun, dry_run
from executive.report import write_report
from sim2d.robot import SimRobot
from sim2d.scenario import Scenario, load_scenario
from tests.conftest import MISSIONS, blackboard_writer

Status = py_trees.common.Status

LAB = MISSIONS / "lab" / "visual-servoing.xml"
LAB_SCENARIO = MISSIONS / "lab" / "scenarios" / "clear-apron.xml"
CHECKPOINTS = ("CP1", "CP2", "CP3")
ITEMS = {
    "CP1": ("target-1-present",),
    "CP2": ("target-2-present", "duct-static-port-clear"),
    "CP3": ("target-3-present", "tyre-engine-inlet"),
}


pytestmark = pytest.mark.usefixtures("fresh_blackboard")


# -- the composite ------------------------------------------------------------------------------
class Step(Node):
    """Takes ``ticks`` ticks (RUNNING before), then SUCCESS; counts its starts and ends."""

    def __init__(self, name: str, ticks: int, log: list[tuple[str, str]]) -> None:
        super().__init__(name)
        self.ticks = ticks
        self.log = log
        self._left = ticks

    def initialise(self) -> None:
        self._left = self.ticks
        self.log.append(("start", self.name))

    def update(self) -> Status:
        self._left -= 1
        if self._left > 0:
            return Status.RUNNING
        self.log.append(("done", self.name))
        return Status.SUCCESS


class Flag(Guard):
    """SUCCESS while the test's flag is up (the operator has the robot)."""

    def __init__(self, flag: list[bool]) -> None:
        super().__init__("operator?")
        self.flag = flag

    def update(self) -> Status:
        return Status.SUCCESS if self.flag[0] else Status.FAILURE


class Hold(Controller):
    def __init__(self) -> None:
        super().__init__("hold")

    def update(self) -> Status:
        return Status.RUNNING


def _mode(flag: list[bool], mission: py_trees.behaviour.Behaviour) -> py_trees.composites.Selector:
    """The compiled root's "mode" selector in miniature: [operator?] -> hold, mission."""
    return py_trees.composites.Selector(
        "mode", memory=False, children=[GuardedBranch("collaborative", Flag(flag), Hold()), mission]
    )


def _mission(spec: list[list[int]], log: list[tuple[str, str]]) -> ResumableSequence:
    """phases of steps, each step taking the given number of ticks."""
    phases = [
        ResumableSequence(
            f"phase {i}", [Step(f"step {i}.{j}", n, log) for j, n in enumerate(steps)]
        )
        for i, steps in enumerate(spec)
    ]
    return ResumableSequence("mission", phases)


def _run(root: py_trees.behaviour.Behaviour, flag: list[bool], pattern: list[bool]) -> int:
    """Tick ``root`` with the operator's flag following ``pattern`` (then handed back)
    until it succeeds; the number of ticks."""
    for tick in range(10_000):
        flag[0] = pattern[tick] if tick < len(pattern) else False
        root.tick_once()
        if root.status == Status.SUCCESS:
            return tick
        assert root.status == Status.RUNNING
    raise AssertionError("never finished")


def test_plain_py_trees_sequence_restarts_after_a_take_over():
    """The defect, at its root: py_trees' memory sequence starts over when pre-empted."""
    log: list[tuple[str, str]] = []
    flag = [False]
    mission = py_trees.composites.Sequence(
        "mission", memory=True, children=[Step("a", 1, log), Step("b", 3, log)]
    )
    _run(_mode(flag, mission), flag, [False, False, True, False])
    assert log.count(("done", "a")) == 2


def test_a_take_over_pauses_and_the_hand_back_resumes_at_the_running_child():
    log: list[tuple[str, str]] = []
    flag = [False]
    mission = _mission([[1, 3], [2, 4, 1]], log)
    root = _mode(flag, mission)
    # ticks: a0.0 done(1) | a0.1 running(2) | taken over for 5 ticks | ...
    _run(root, flag, [False, False, True, True, True, True, True])
    done = [name for what, name in log if what == "done"]
    assert done == ["step 0.0", "step 0.1", "step 1.0", "step 1.1", "step 1.2"]
    # the interrupted step started twice (afresh after the hand-back), no other did
    starts = [name for what, name in log if what == "start"]
    assert starts.count("step 0.1") == 2
    assert all(starts.count(n) == 1 for n in set(starts) - {"step 0.1"})
    assert mission.status == Status.SUCCESS and mission.paused_at is None


@settings(max_examples=150, deadline=None)
@given(
    spec=st.lists(st.lists(st.integers(1, 5), min_size=1, max_size=4), min_size=1, max_size=4),
    pattern=st.lists(st.booleans(), max_size=80),
)
def test_any_pattern_of_take_overs_finishes_every_step_exactly_once_in_order(spec, pattern):
    log: list[tuple[str, str]] = []
    flag = [False]
    root = _mode(flag, _mission(spec, log))
    ticks = _run(root, flag, pattern) + 1
    done = [name for what, name in log if what == "done"]
    expected = [f"step {i}.{j}" for i, steps in enumerate(spec) for j in range(len(steps))]
    assert done == expected
    # Without a take-over the mission takes sum(n) - (steps - 1) ticks (a step that ends
    # hands over to the next within the tick). Each held tick adds one; each take-over
    # loses at most what the interrupted step had done: never the finished steps.
    alone = sum(map(sum, spec)) - (len(expected) - 1)
    seen = pattern[:ticks]
    held = sum(seen)
    interruptions = sum(1 for k, up in enumerate(seen) if up and (k == 0 or not seen[k - 1]))
    worst = max(n for steps in spec for n in steps) - 1
    assert alone + held <= ticks <= alone + held + interruptions * worst


def test_rewind_to_resumes_a_pause_at_or_after_it_at_that_child():
    def starts(pattern: list[bool]) -> list[str]:
        log: list[tuple[str, str]] = []
        flag = [False]
        steps = [Step("mark", 1, log), Step("via", 2, log), Step("reach", 2, log)]
        checkpoint = ResumableSequence("checkpoint", [*steps, Step("inspect", 3, log)], 2)
        _run(_mode(flag, checkpoint), flag, pattern)
        return [name for what, name in log if what == "start"]

    # ticks: mark and via | via, reach | reach, inspect | inspect | inspect (done)
    # paused while inspecting (4th tick): the checkpoint is reached again, then inspected
    assert starts([False, False, False, True]) == [
        "mark",
        "via",
        "reach",
        "inspect",
        "reach",
        "inspect",
    ]
    # paused before it (on the via point): resumes there
    assert starts([False, True]) == ["mark", "via", "via", "reach", "inspect"]


def test_rewind_to_must_name_a_child():
    with pytest.raises(ValueError, match="rewind_to 2"):
        ResumableSequence("s", [Hold(), Hold()], rewind_to=2)


def test_a_finished_or_failed_sequence_starts_over_and_forgets_stale_pauses():
    log: list[tuple[str, str]] = []
    inner = ResumableSequence("inner", [Step("i0", 1, log), Step("i1", 3, log)])
    outer = ResumableSequence("outer", [inner, Step("o1", 1, log)])
    outer.tick_once()
    outer.tick_once()  # inner at i1, running
    outer.stop(Status.INVALID)  # paused: both remember
    assert outer.paused_at == 0 and inner.paused_at == 1
    outer.paused_at = None  # as if the outer sequence had finished: it starts afresh
    log.clear()
    outer.tick_once()
    assert log[0] == ("start", "i0")  # the inner pause was forgotten with the fresh start
    outer.stop(Status.FAILURE)
    assert outer.paused_at is None


# -- the compiled tree ----------------------------------------------------------------------------
@pytest.fixture(scope="module")
def lab_tree():
    return compile_mission(load_mission(LAB)).root


def test_every_memory_sequence_of_the_mission_is_resumable(lab_tree):
    memory = [
        n for n in lab_tree.iterate() if isinstance(n, py_trees.composites.Sequence) and n.memory
    ]
    assert memory and all(isinstance(n, ResumableSequence) for n in memory)
    names = {n.name for n in memory}
    assert {"mission", "approach", "inspection", "return"} <= names
    assert {f"checkpoint {cp}" for cp in CHECKPOINTS} <= names


def test_a_checkpoint_rewinds_to_its_own_navigation(lab_tree):
    for cp in CHECKPOINTS:
        node = next(n for n in lab_tree.iterate() if n.name == f"checkpoint {cp}")
        assert node.rewind_to is not None
        assert node.children[node.rewind_to].name == f"navigate {cp}"
        # everything after it needs the robot at the checkpoint
        after = [c.name for c in node.children[node.rewind_to + 1 :]]
        assert f"inspect {cp}" in after and after[-1] == f"done {cp}"


def test_the_mode_selector_keeps_the_architecture_shape(lab_tree):
    mode = next(n for n in lab_tree.iterate() if n.name == "mode")
    collaborative, abort, rejoin, mission = mode.children
    assert isinstance(collaborative, GuardedBranch)
    assert isinstance(collaborative.children[0], OperatorTakeOver)
    assert isinstance(abort.children[0], OperatorAborted)  # then back to P
    assert isinstance(rejoin.children[0], RejoinAfterHandBack)  # fig. 2.21
    assert mission.name == "mission" and isinstance(mission, ResumableSequence)


def _operator_guard(requests: OperatorRequests, guard: OperatorTakeOver) -> Status:
    blackboard_writer(OPERATOR).set(OPERATOR.name, requests, overwrite=True)
    guard.tick_once()
    return guard.status


def test_the_operator_guards_follow_a_take_over_and_latch_an_abort():
    guard = OperatorTakeOver()
    assert _operator_guard(OperatorRequests(), guard) == Status.FAILURE
    assert _operator_guard(OperatorRequests(take_over=True), guard) == Status.SUCCESS
    assert guard.feedback_message == "operator request"
    assert _operator_guard(OperatorRequests(), guard) == Status.FAILURE  # handed back
    aborted = OperatorAborted()
    assert _operator_guard(OperatorRequests(take_over=True), aborted) == Status.FAILURE
    assert _operator_guard(OperatorRequests(abort=True), aborted) == Status.SUCCESS
    for _ in range(3):  # one request is enough: the mission never resumes
        assert _operator_guard(OperatorRequests(), aborted) == Status.SUCCESS
        assert aborted.feedback_message == "operator abort"


def test_inspection_re_entered_skips_the_items_already_recorded():
    mission = load_mission(LAB)
    unit = mission.platform.cameras["ptz"]
    node = InspectItems("CP2", ITEMS["CP2"], mission.aircraft, unit, ("ptz",))
    node.setup()
    first = ItemResult("CP2", ITEMS["CP2"][0], 1.0, True, "ptz", 0.0, 0.0, (0.0, 0.0, 0.0))
    other = dataclasses.replace(first, checkpoint="CP3", item=ITEMS["CP2"][1])
    bb = blackboard_writer(PROGRESS, SENSOR_FRAME, COMMAND)
    bb.set(PROGRESS.name, MissionProgress(results=(first, other)), overwrite=True)
    bb.set(SENSOR_FRAME.name, SensorFrame(2.0), overwrite=True)
    node.tick_once()
    assert node.feedback_message.endswith(ITEMS["CP2"][1])  # goes on with the second item
    # all recorded: nothing to do, and nothing recorded again
    both = (first, dataclasses.replace(first, item=ITEMS["CP2"][1]))
    bb.set(PROGRESS.name, MissionProgress(results=both), overwrite=True)
    node.stop(Status.INVALID)
    node.tick_once()
    assert node.status == Status.SUCCESS
    assert bb.get(PROGRESS.name).results == both


# -- real dry-runs ------------------------------------------------------------------------------
def _progress() -> MissionProgress:
    """The mission's progress as the last tick left it (the operator is asked before the
    tick, so it sees what the previous one wrote)."""
    value = py_trees.blackboard.Blackboard.storage.get(PROGRESS.name)
    return value if isinstance(value, MissionProgress) else MissionProgress()


class Operator:
    """A stateful operator: from ``after`` s on, takes over ``delay`` s after
    ``when(progress)`` first holds, for ``hold`` s, ``times`` times (waiting ``gap`` s
    between), or aborts instead (one request). Records the windows it held the robot and
    when it aborted."""

    def __init__(
        self,
        when: Callable[[MissionProgress], bool],
        hold: float = 6.0,
        times: int = 1,
        gap: float = 0.0,
        abort: bool = False,
        after: float = 0.0,
        delay: float = 0.0,
    ) -> None:
        self.when = when
        self.hold, self.times, self.gap, self.abort = hold, times, gap, abort
        self.after, self.delay = after, delay
        self._since: float | None = None
        self.windows: list[tuple[float, float]] = []
        self.phases: list[str] = []  # the mission's phase at each take-over
        self.aborted_at: float | None = None

    def __call__(self, t: float) -> OperatorRequests:
        if self.aborted_at is not None:
            return OperatorRequests()  # the request was made once
        if self.windows and t < self.windows[-1][1]:
            return OperatorRequests(take_over=True)
        ready = t >= self.after and (not self.windows or t >= self.windows[-1][1] + self.gap)
        if self._since is None and self.when(_progress()):
            self._since = t
        if len(self.windows) < self.times and ready and self._due(t):
            if self.abort:
                self.aborted_at = t
                return OperatorRequests(abort=True)
            self.windows.append((t, t + self.hold))
            self.phases.append(_progress().phase)
            self._since = None
            return OperatorRequests(take_over=True)
        return OperatorRequests()

    def _due(self, t: float) -> bool:
        return self._since is not None and t >= self._since + self.delay


class RecordingRobot(SimRobot):
    """The simulated robot, keeping every command it received with its time."""

    def __init__(self, scenario: Scenario) -> None:
        super().__init__(scenario)
        self.received: list[tuple[float, VelocityCommand]] = []

    def send(self, command: VelocityCommand) -> None:
        self.received.append((self.time, command))
        super().send(command)


@pytest.fixture(scope="module")
def scenario() -> Scenario:
    return load_scenario(LAB_SCENARIO)


def _dry_run(scenario: Scenario, operator: Operator, tmp_path: Path, **kw) -> DryRun:
    robot = kw.pop("robot", None) or RecordingRobot(scenario)
    return dry_run(
        scenario,
        operator=operator,
        journal_path=tmp_path / "journal.jsonl",
        robot=robot,
        max_time=kw.pop("max_time", 200.0),
        **kw,
    )


def _journal(tmp_path: Path) -> list[dict]:
    return [json.loads(line) for line in (tmp_path / "journal.jsonl").read_text().splitlines()]


def _controllers(run: DryRun, after: float) -> list[str]:
    return [e.detail["to"] for e in run.result.events if e.kind == "controller" and e.t >= after]


def _moved(run: DryRun, start: float, end: float) -> float:
    """How far the robot really went (ground truth) between two times."""
    inside = [s.true for s in run.samples if start <= s.t <= end]
    assert len(inside) >= 2
    return max(math.hypot(p.x - inside[0].x, p.y - inside[0].y) for p in inside)


def _assert_resumed_mission(run: DryRun, tmp_path: Path) -> None:
    """Completed, each checkpoint once, each item once, nothing started twice."""
    result = run.result
    assert result.outcome == "completed", result.reason
    progress = result.progress
    assert progress.completed == CHECKPOINTS
    recorded = [(r.checkpoint, r.item) for r in progress.results]
    assert recorded == [(cp, item) for cp in CHECKPOINTS for item in ITEMS[cp]]
    records = _journal(tmp_path)
    for kind in ("checkpoint-start", "checkpoint-done"):
        started = [r["checkpoint"] for r in records if r.get("event") == kind]
        assert started == list(CHECKPOINTS), kind
    items = [(r["checkpoint"], r["item"]) for r in records if r.get("event") == "item"]
    assert items == recorded
    phases = [r["phase"] for r in records if r.get("event") == "phase"]
    assert len(phases) == len(set(phases)), phases  # no phase entered twice
    assert all(c.reached for c in run.checkpoints)
    # within tolerance, every item detected with a fresh image: the run succeeds (exit 0)
    assert run.succeeded, run.first_cause


def _assert_held_still(run: DryRun, windows: list[tuple[float, float]]) -> None:
    """From one second after the take-over (braking) to the hand-back, the robot really
    stood still."""
    for start, end in windows:
        assert _moved(run, start + 1.0, end) < 0.01, (start, end)


@pytest.mark.slow
def test_take_over_mid_leg_after_a_checkpoint_resumes_with_the_next(scenario, tmp_path):
    # take over 3 s after CP1 is done, on the way to CP2
    operator = Operator(lambda p: p.completed == ("CP1",), hold=8.0, delay=3.0)
    run = _dry_run(scenario, operator, tmp_path)
    ((start, _),) = operator.windows
    _assert_resumed_mission(run, tmp_path)
    _assert_held_still(run, operator.windows)
    after = _controllers(run, start)
    assert after[:2] == ["operator control", "go to CP2"]  # the leg is driven on
    assert not {"go to P", "go to CP1", "inspect CP1"} & set(after)
    speeds = [s.v for s in run.samples if start - 1.0 <= s.t < start]
    assert max(speeds) > 0.1  # it was really moving when taken over
    # the report says so: completed, succeeded, each checkpoint and item once
    metrics = json.loads((write_report(run, tmp_path / "report") / "metrics.json").read_text())
    assert metrics["outcome"] == "completed" and metrics["succeeded"]
    assert [c["id"] for c in metrics["checkpoints"]] == list(CHECKPOINTS)
    assert metrics["checkpoints_reached"] == 3 and metrics["items_inspected"] == 5


@pytest.mark.slow
def test_take_over_during_the_approach_resumes_the_approach(scenario, tmp_path):
    operator = Operator(lambda p: p.phase == "approach", hold=5.0, after=3.0)  # on the way to P
    run = _dry_run(scenario, operator, tmp_path)
    _assert_resumed_mission(run, tmp_path)
    _assert_held_still(run, operator.windows)
    after = _controllers(run, operator.windows[0][0])
    assert after[:2] == ["operator control", "go to P"]


@pytest.mark.slow
def test_take_over_mid_inspection_re_reaches_the_checkpoint_and_inspects_the_rest(
    scenario, tmp_path
):
    def first_cp2_item_recorded(p: MissionProgress) -> bool:
        return [r.item for r in p.results if r.checkpoint == "CP2"] == [ITEMS["CP2"][0]]

    operator = Operator(first_cp2_item_recorded, hold=4.0)
    run = _dry_run(scenario, operator, tmp_path)
    _assert_resumed_mission(run, tmp_path)
    _assert_held_still(run, operator.windows)
    start = operator.windows[0][0]
    after = _controllers(run, start)
    assert after[:3] == ["operator control", "go to CP2", "inspect CP2"]
    # the second item was inspected after the hand-back, the first one before only
    stamps = {r.item: r.stamp for r in run.result.progress.results}
    assert stamps[ITEMS["CP2"][0]] < start < operator.windows[0][1] <= stamps[ITEMS["CP2"][1]]
    cp2 = next(c for c in run.checkpoints if c.id == "CP2")
    assert cp2.items == 2


class JoystickRobot(RecordingRobot):
    """The operator drives the robot while it has it: during ``windows`` the robot gets
    ``drive`` instead of what the executive sent (manual control at the robot's seam)."""

    def __init__(self, scenario: Scenario, operator: Operator, drive: VelocityCommand) -> None:
        super().__init__(scenario)
        self.operator = operator
        self.drive = drive

    def send(self, command: VelocityCommand) -> None:
        manual = any(a <= self.time < b for a, b in self.operator.windows)
        super().send(self.drive if manual else command)


@pytest.mark.slow
def test_a_checkpoint_left_during_a_take_over_is_reached_again(scenario, tmp_path):
    """The operator drives the robot away mid-inspection: after the hand-back the robot
    goes back to the checkpoint before it inspects the remaining item."""

    def first_cp2_item_recorded(p: MissionProgress) -> bool:
        return [r.item for r in p.results if r.checkpoint == "CP2"] == [ITEMS["CP2"][0]]

    operator = Operator(first_cp2_item_recorded, hold=4.0)
    # reverse, turning: away from the fence (the checkpoint faces it)
    robot = JoystickRobot(scenario, operator, VelocityCommand(-0.3, 0.2))
    run = dry_run(
        scenario,
        operator=operator,
        journal_path=tmp_path / "journal.jsonl",
        robot=robot,
        max_time=200.0,
    )
    _assert_resumed_mission(run, tmp_path)
    ((start, end),) = operator.windows
    assert _moved(run, start, end) > 0.6  # really driven away
    assert _controllers(run, start)[:3] == ["operator control", "go to CP2", "inspect CP2"]
    cp = next(c for c in run.scenario.mission.checkpoints if c.id == "CP2")
    second = next(r for r in run.result.progress.results if r.item == ITEMS["CP2"][1])
    assert math.hypot(second.pose_f[0] - cp.pose.x, second.pose_f[1] - cp.pose.y) < 0.15
    outcome = next(c for c in run.checkpoints if c.id == "CP2")
    assert outcome.time is not None and outcome.time > end  # judged when really done


@pytest.mark.slow
def test_repeated_take_overs_never_repeat_a_checkpoint(scenario, tmp_path):
    operator = Operator(lambda p: True, hold=2.0, times=8, gap=9.0)
    run = _dry_run(scenario, operator, tmp_path)
    assert len(operator.windows) == 8
    assert {"approach", "inspection", "return"} <= set(operator.phases)  # in every phase
    _assert_resumed_mission(run, tmp_path)
    _assert_held_still(run, operator.windows)
    taken = [e for e in run.result.events if e.kind == "controller"]
    assert sum(e.detail["to"] == "operator control" for e in taken) == 8


def _handover_a(run: DryRun) -> tuple[float, float]:
    """Where the handover point P truly is, in A."""
    wp = run.scenario.mission.handover
    if wp.frame is Frame.AIRPORT:
        return wp.x, wp.y
    p = run.scenario.true_placement().pose_to_airport(Pose2(wp.x, wp.y, 0.0))
    return p.x, p.y


def _assert_aborted(run: DryRun, operator: Operator, tmp_path: Path) -> float:
    """The abort ended the mission and the robot drove back to the handover point P on its
    own (avoidance and the safety layer as on any leg), where the run ended ``aborted``."""
    t = operator.aborted_at
    assert t is not None
    result = run.result
    assert result.outcome == "aborted"
    assert result.reason == f"aborted by the operator at {t:.1f} s: back at the handover point P"
    kinds = [(e.kind, e.t) for e in result.events if e.kind in ("abort-requested", "aborted")]
    assert [k for k, _ in kinds] == ["abort-requested", "aborted"] and kinds[0][1] == t
    assert "go to P (abort)" in _controllers(run, t)
    # ground truth: at P (the leg's 0.3 m tolerance and the localisation's error), no
    # collision, no geofence breach, and the last command a stop
    x, y = _handover_a(run)
    end = run.robot.world.robot_pose
    assert math.hypot(end.x - x, end.y - y) < 0.4, (end, (x, y))
    assert not run.robot.world.collisions and not run.breaches
    assert run.robot.received[-1][1].is_stop
    # the journal ends with the outcome, the report is written
    assert _journal(tmp_path)[-1]["outcome"] == "aborted"
    out = write_report(run, tmp_path / "report")
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["outcome"] == "aborted"
    assert not run.succeeded and run.first_cause == result.reason  # the one-line summary
    return t


class LeadAway:
    """Takes the robot over 1 s after CP1 and leads it away from the fence with the
    joystick, as an operator watching it would: turn to face -y (away from the fence),
    drive ``drive`` s at 0.5 m/s, then hand back."""

    def __init__(self, robot: SimRobot, drive: float) -> None:
        self.robot, self.drive = robot, drive
        self.window: tuple[float, float] | None = None
        self.driving_since: float | None = None

    def __call__(self, t: float) -> OperatorRequests:
        if self.window is None and _progress().completed == ("CP1",):
            self.window = (t + 1.0, math.inf)
        if self.window is None or not self.window[0] <= t < self.window[1]:
            return OperatorRequests()
        error = wrap_angle(-math.pi / 2 - self.robot.world.robot_pose.theta)
        if self.driving_since is None and abs(error) < 0.05:
            self.driving_since = t
        v = 0.5 if self.driving_since is not None else 0.0
        if self.driving_since is not None and t >= self.driving_since + self.drive:
            self.window = (self.window[0], t)  # hand back
            return OperatorRequests()
        omega = max(-0.6, min(0.6, 2.0 * error))
        return OperatorRequests(take_over=True, joystick=JoystickCommand(t, v, omega))


@pytest.mark.slow
@pytest.mark.parametrize("drive", [4.0, 14.0])
def test_the_surrender_transitions_of_fig_2_21(scenario, tmp_path, drive):
    """Handed back in P's close vicinity (the band round the mock-up that P lies in: 6 m
    from the fence + 3 m) the robot goes on with its checkpoint; led out of it, it goes
    back to P first, then on: the mission completes either way, each checkpoint once,
    within tolerance."""
    robot = RecordingRobot(scenario)
    operator = LeadAway(robot, drive)
    run = _dry_run(scenario, operator, tmp_path, robot=robot)
    assert operator.window is not None and operator.window[1] < math.inf
    _assert_resumed_mission(run, tmp_path)
    after = _controllers(run, operator.window[1])
    switches = [e for e in run.result.events if e.kind == "controller"]
    rejoin = [e for e in switches if e.detail["to"] == "go to P (rejoin)"]
    if drive < 10.0:  # ~3 m + 2 m from the fence: within 9 m
        assert after[:1] == ["go to CP2"] and not rejoin
    else:  # ~3 m + 7 m: out of it
        assert after[:3] == ["go to P (rejoin)", "rejoined at P", "go to CP2"], after
        # it really went back to P (ground truth) before going on to CP2
        x, y = _handover_a(run)
        t_cp2 = next(
            e.t for e in switches if e.detail["to"] == "go to CP2" and e.t > operator.window[1]
        )
        at = min(math.hypot(s.true.x - x, s.true.y - y) for s in run.samples if s.t <= t_cp2)
        assert at < 0.4


@pytest.mark.slow
def test_abort_mid_leg_returns_to_the_handover_point_and_reports_aborted(scenario, tmp_path):
    operator = Operator(lambda p: p.completed == ("CP1",), abort=True, delay=3.0)
    run = _dry_run(scenario, operator, tmp_path)
    _assert_aborted(run, operator, tmp_path)
    assert run.result.progress.completed == ("CP1",)  # what was done is kept and reported
    assert [r.checkpoint for r in run.result.progress.results] == ["CP1"]


@pytest.mark.slow
def test_a_take_over_pre_empts_the_return_after_an_abort(scenario, tmp_path):
    class AbortThenTakeOver(Operator):
        """Aborts 3 s after CP1, takes the robot over 2 s later for 6 s (it holds still),
        then hands it back: the return to P goes on."""

        def __call__(self, t: float) -> OperatorRequests:
            if self.aborted_at is None:
                requests = super().__call__(t)
                if requests.abort:
                    self.windows = [(t + 2.0, t + 8.0)]
                return requests
            start, end = self.windows[0]
            return OperatorRequests(take_over=start <= t < end)

    operator = AbortThenTakeOver(lambda p: p.completed == ("CP1",), abort=True, delay=3.0)
    run = _dry_run(scenario, operator, tmp_path)
    t = _assert_aborted(run, operator, tmp_path)
    assert _controllers(run, t)[:3] == ["go to P (abort)", "operator control", "go to P (abort)"]
    start, end = operator.windows[0]
    assert _moved(run, start + 1.0, end) < 0.02  # held still while the operator had it
