"""The fixed-rate executive loop: read -> tick -> safety layer -> send.

Each period the runtime reads a :class:`SensorFrame`, writes it (and the operator's
requests, and a zero command) on the blackboard, ticks the tree once, passes the command
the tree chose through the :class:`~executive.safety.SafetyLayer` — which has the last
word — and sends the result. A missed deadline is counted, and ``max_missed_deadlines``
consecutive ones stop the robot and fail the run; an exception inside a tick stops the
robot and fails the mission with the traceback; a journal that cannot be written (a full
disk) stops the robot and fails the run with the reason; a stop request
(:class:`StopRequest`, set by a signal handler) stops the robot and ends the run as
``interrupted``. Every switch of controller is an event with the guard's reason; mission
progress goes to the journal.
"""

from __future__ import annotations

import gc
import math
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
import py_trees

from behaviours.base import Controller
from behaviours.keys import (
    COMMAND,
    FEATURES,
    OBSTACLES,
    OPERATOR,
    POSE,
    PROGRESS,
    QUESTION,
    SENSOR_FRAME,
    SERVO,
    MissionProgress,
)
from executive.compiler import CompiledMission, GuardedBranch
from executive.core.records import (
    OperatorRequests,
    PoseEstimate,
    RegistrationRecord,
    SensorFrame,
    VelocityCommand,
)
from executive.core.robot import LinkHealth, RobotInterface
from executive.journal import Journal, JournalWriteError
from executive.safety import SafetyLayer

Status = py_trees.common.Status


class Clock(Protocol):
    """Time for the loop: simulated (advances the simulator) or the wall clock."""

    def now(self) -> float: ...

    def wait(self, until: float) -> None: ...

    def tick_timer(self) -> float:
        """A clock (s) that measures how long a tick took, against its deadline."""
        ...


class WallClock:
    """The robot's time: monotonic seconds since the run began."""

    tick_timer = staticmethod(time.perf_counter)
    """What a tick is charged: the elapsed time (see :meth:`Clock.tick_timer`)."""

    def __init__(self) -> None:
        self._t0 = time.monotonic()

    def now(self) -> float:
        return time.monotonic() - self._t0

    def wait(self, until: float) -> None:
        delay = until - self.now()
        if delay > 0:
            time.sleep(delay)


class StopRequest:
    """A request to end the run at the next tick, safely: set from a signal handler (it
    only stores the reason) and polled by the loop once per period."""

    def __init__(self) -> None:
        self.reason: str | None = None
        self.signal: int | None = None

    def set(self, reason: str, signal: int | None = None) -> None:
        if self.reason is None:  # the first request is the one the report names
            self.reason, self.signal = reason, signal

    def __bool__(self) -> bool:
        return self.reason is not None


DEFAULT_MAX_MISSED_DEADLINES = 10
"""Consecutive missed tick deadlines that stop the robot (ARCHITECTURE §8): at 50 Hz,
200 ms during which the robot drove on commands computed for an older world."""


@dataclass
class TickStats:
    """Compute time of each tick (sensing + tree + safety), against the period."""

    period: float
    durations: list[float] = field(default_factory=list)

    @property
    def misses(self) -> int:
        return sum(1 for d in self.durations if d > self.period)

    def summary(self) -> dict[str, float]:
        if not self.durations:
            return {"ticks": 0}
        ms = np.array(self.durations) * 1e3
        return {
            "ticks": len(ms),
            "mean_ms": round(float(ms.mean()), 4),
            "p99_ms": round(float(np.percentile(ms, 99)), 4),
            "max_ms": round(float(ms.max()), 4),
            "deadline_ms": round(self.period * 1e3, 3),
            "deadline_misses": self.misses,
        }


@dataclass
class Event:
    t: float
    kind: str
    detail: dict[str, object]

    def as_dict(self) -> dict[str, object]:
        return {"t": round(self.t, 3), "event": self.kind, **self.detail}


@dataclass
class RunResult:
    outcome: str  # completed | failed | timeout | aborted | interrupted
    reason: str
    progress: MissionProgress
    stats: TickStats
    events: list[Event]
    duration: float
    traceback: str | None = None
    stop_sent: bool = True
    """False when the robot link failed even for the stop (the base's own watchdog must
    then brake it: ARCHITECTURE §8)."""


TickHook = Callable[[float, SensorFrame, VelocityCommand, "Runtime"], None]


def _freeze_long_lived() -> None:
    """Move what exists after the first tick (mission, tree, maps, the simulator's scene)
    out of the garbage collector's reach for the run: a full collection otherwise walks
    all of it and stalls a tick for ~60 ms (one deadline miss in 300 s on the busy apron,
    BENCHMARKS.md). Garbage is collected first, so nothing unreachable is kept."""
    gc.collect()
    gc.freeze()


class Runtime:
    """Runs a compiled mission on a robot at a fixed rate."""

    def __init__(
        self,
        compiled: CompiledMission,
        robot: RobotInterface,
        clock: Clock,
        safety: SafetyLayer,
        *,
        rate_hz: float = 50.0,
        journal: Journal | None = None,
        operator: Callable[[float], OperatorRequests] | None = None,
        on_tick: TickHook | None = None,
        stop: StopRequest | None = None,
        max_missed_deadlines: int | None = DEFAULT_MAX_MISSED_DEADLINES,
    ) -> None:
        self.compiled = compiled
        self.robot = robot
        self.clock = clock
        self.safety = safety
        self.period = 1.0 / rate_hz
        self.journal = journal
        self.operator = operator or (lambda t: OperatorRequests())
        self.on_tick = on_tick
        self.stop = stop if stop is not None else StopRequest()
        self.stop_failures: list[str] = []
        self._completed: tuple[str, ...] = ()
        self._timer: Callable[[], float] = getattr(clock, "tick_timer", time.perf_counter)
        self.max_missed_deadlines = max_missed_deadlines
        self._missed_in_a_row = 0
        self.root = compiled.root
        # py_trees' blackboard is process-wide: a run starts from an empty one, not from
        # what the last run in this process left (a follow run read a lab run's values;
        # a campaign worker runs its episodes one after another). Values only, not
        # Blackboard.clear(): the compiled tree's clients are registered already
        py_trees.blackboard.Blackboard.storage.clear()
        self.bb = py_trees.blackboard.Client(name="runtime")
        for key in (SENSOR_FRAME, OPERATOR, COMMAND):
            self.bb.register_key(key=key.name, access=py_trees.common.Access.WRITE)
        for key in (POSE, OBSTACLES, PROGRESS, SERVO, FEATURES, QUESTION):
            self.bb.register_key(key=key.name, access=py_trees.common.Access.READ)
        # the blackboard is the process's: a question an earlier run asked is not this one's
        py_trees.blackboard.Blackboard.unset(QUESTION.name)
        self.stats = TickStats(self.period)
        self.events: list[Event] = []
        self.controller = "none"
        self.command = VelocityCommand.stop()
        self.sent = VelocityCommand.stop()
        self.reference: tuple[str, str] = ("", "")
        self._registration: RegistrationRecord | None = None
        self.aborted_at: float | None = None
        """When the operator asked to abort (the tree then holds the robot still)."""
        self._link = robot if isinstance(robot, LinkHealth) else None

    @property
    def completed(self) -> tuple[str, ...]:
        """The checkpoints completed so far, in order, as of the last tick recorded."""
        return self._completed

    def _get(self, key: str) -> object:
        try:
            return self.bb.get(key)
        except KeyError:
            return None

    def _active_controller(self) -> tuple[str, str]:
        tip = self.root.tip()
        node = tip
        while node is not None and not isinstance(node, Controller):
            node = node.parent
        if node is None:
            return "none", ""
        reason = ""
        if isinstance(node.parent, GuardedBranch):
            guard = node.parent.children[0]
            reason = f"{guard.name} {guard.feedback_message}".strip()
        elif node.parent is not None:
            guards = [c for c in node.parent.children if isinstance(c, GuardedBranch)]
            if guards:
                reason = "no guard holds: " + "; ".join(
                    f"{g.children[0].name} {g.children[0].feedback_message}" for g in guards
                )
        return node.name, reason

    def _failure_reason(self) -> str:
        """Follow the failure down from the root to the node that caused it."""
        node = self.root
        while node.children:
            failed = [c for c in node.children if c.status == Status.FAILURE]
            if not failed:
                break
            # A sequence fails at its first failing child; a selector only once all have.
            is_selector = isinstance(node, py_trees.composites.Selector)
            node = failed[-1] if is_selector else failed[0]
        detail = f": {node.feedback_message}" if node.feedback_message else ""
        return f"{node.name}{detail}"

    def step(self) -> Status:
        """One period: read, tick, filter, send. Returns the tree's status.

        The tick time measured is the executive's own work (sensing + tree + controllers
        + safety layer), from the frame read to the command ready, without the robot.
        """
        frame = self.robot.read()
        t0 = self._timer()
        now = frame.stamp
        operator = self.operator(now)
        if operator.abort and self.aborted_at is None:
            self.aborted_at = now
            self.events.append(
                Event(now, "abort-requested", {"reason": "the operator aborted the mission"})
            )
        self.bb.set(SENSOR_FRAME.name, frame, overwrite=True)
        self.bb.set(OPERATOR.name, operator, overwrite=True)
        self.bb.set(COMMAND.name, VelocityCommand.stop(), overwrite=True)
        # Tick the root directly: py_trees' BehaviourTree.tick also walks the whole tree
        # (~450 nodes for the A320) for visitors we do not use, which was 90 % of a tick.
        self.root.tick_once()
        command = self._get(COMMAND.name)
        self.command = command if isinstance(command, VelocityCommand) else VelocityCommand.stop()
        self.sent = self.safety.filter(
            self.command,
            now=now,
            frame=frame,
            pose=self._get(POSE.name),
            obstacles=self._get(OBSTACLES.name),
            reset_requested=operator.reset_estop,
            estop_requested=operator.estop,
        )
        pose = self._get(POSE.name)
        placement = getattr(pose, "placement", None)
        if placement is not None:
            self.safety.set_placement(placement)
        duration = self._timer() - t0
        self.stats.durations.append(duration)
        self._missed_in_a_row = self._missed_in_a_row + 1 if duration > self.period else 0
        self.robot.send(self.sent)
        self._record(now, frame.wheels.travel if frame.wheels is not None else None)
        if self.on_tick is not None:
            self.on_tick(now, frame, self.sent, self)
        return self.root.status

    def _record(self, now: float, travel: tuple[float, float] | None = None) -> None:
        name, reason = self._active_controller()
        if name != self.controller:
            self.events.append(
                Event(now, "controller", {"from": self.controller, "to": name, "reason": reason})
            )
            self.controller = name
        for ev in self.safety.drain_events():
            self.events.append(Event(ev.stamp, "safety", {"kind": ev.kind, "reason": ev.reason}))
        for session in self.compiled.route_sessions:  # taught routes: keys passed
            for rev in session.drain_events():
                self.events.append(Event(rev.stamp, rev.kind, rev.detail()))
        pose = self._get(POSE.name)
        if isinstance(pose, PoseEstimate):
            self._record_localisation(now, pose)
        progress = self._get(PROGRESS.name)
        if not isinstance(progress, MissionProgress):
            return
        sigma = pose.sigma_f if isinstance(pose, PoseEstimate) else None
        if progress.completed != self._completed:
            self._flag_uncertain(now, progress.completed[len(self._completed) :], sigma)
            self._completed = progress.completed
        if self.journal is not None:
            p = getattr(pose, "pose_a", None)
            self.journal.record(
                now,
                progress,
                None if p is None else (p.x, p.y, p.theta),
                sigma_f=sigma,
                travel=travel,
            )

    def _flag_uncertain(self, now: float, done: tuple[str, ...], sigma: float | None) -> None:
        """A checkpoint completed while the pose estimate's own position uncertainty (1
        sigma, in F) exceeds the checkpoint tolerance is an event: on the robot nothing
        else can tell that it may be far from where it should be (a GPS loss)."""
        tolerance = self.compiled.mission.navigation.position_tolerance
        if sigma is None or sigma <= tolerance:
            return
        for cp in done:
            self.events.append(
                Event(
                    now,
                    "checkpoint-uncertain",
                    {
                        "checkpoint": cp,
                        "sigma_m": round(sigma, 4),
                        "tolerance_m": tolerance,
                        "reason": f"checkpoint {cp} completed with a pose uncertainty of "
                        f"{sigma * 100:.0f} cm > its tolerance {tolerance * 100:.0f} cm",
                    },
                )
            )

    def _record_localisation(self, now: float, pose: PoseEstimate) -> None:
        """Events: what the pose in F is anchored to, and every global registration or
        refused one (the periodic ICP tracking updates are in the report's series)."""
        reference = (str(pose.reference), pose.anchor)
        if reference != self.reference:
            self.events.append(
                Event(
                    now,
                    "localisation",
                    {"reference": reference[0], "anchor": reference[1], "from": self.reference[0]},
                )
            )
            self.reference = reference
        reg = pose.registration
        if reg is None or reg is self._registration:
            return
        self._registration = reg
        if reg.method == "global" or not reg.accepted:
            detail: dict[str, object] = {
                "method": reg.method,
                "accepted": reg.accepted,
                "reason": reg.reason,
            }
            if reg.pose_f is not None:
                detail["rms"] = round(reg.rms, 4)
                detail["inliers"] = round(reg.inlier_fraction, 3)
            self.events.append(Event(now, "registration", detail))

    def run(self, max_time: float = math.inf) -> RunResult:
        """Tick until the mission succeeds, fails, or ``max_time`` (s) has passed.

        Whatever ends the run (an exception escaping the loop included), the robot is
        sent a stop and what the run froze (:func:`_freeze_long_lived`) is let go; a run
        started with objects already frozen by its caller freezes nothing.
        """
        start = self.clock.now()
        freeze = gc.get_freeze_count() == 0
        try:
            outcome, reason, trace = self._loop(start, max_time, freeze)
        finally:
            if freeze:
                gc.unfreeze()  # the next run in this process may collect this one's objects
            unsent = self._send_stop()
        if unsent is not None:
            self.stop_failures.append(unsent)
            self.events.append(Event(self.clock.now(), "link-lost", {"reason": unsent}))
        progress = self._get(PROGRESS.name)
        return RunResult(
            outcome=outcome,
            reason=reason,
            progress=progress if isinstance(progress, MissionProgress) else MissionProgress(),
            stats=self.stats,
            events=self.events,
            duration=self.clock.now() - start,
            traceback=trace,
            stop_sent=not self.stop_failures,
        )

    def _send_stop(self) -> str | None:
        """Send the robot a stop; why it could not be sent (a lost link), if it could not.
        Never raises: a stop is attempted whatever else failed."""
        try:
            self.robot.send(VelocityCommand.stop())
        except Exception as exc:  # the link itself is what failed
            return f"stop not confirmed: sending it raised {exc!r}"
        return None

    def _stop_safely(self, now: float, kind: str, reason: str) -> None:
        """Latch a fault stop in the safety layer, send the robot a stop, log the event."""
        self.safety.fault(now, reason)
        unsent = self._send_stop()
        if unsent is not None:
            self.stop_failures.append(unsent)
        self.events.append(Event(now, kind, {"reason": reason, "stop_sent": unsent is None}))

    def _loop(self, start: float, max_time: float, freeze: bool) -> tuple[str, str, str | None]:
        """The ticks of :meth:`run`: (outcome, reason, traceback of a crashed tick)."""
        outcome, reason, trace = "timeout", f"not finished after {max_time:.0f} s", None
        while True:
            now = self.clock.now()
            if now - start >= max_time:
                break
            if self.stop:
                outcome, reason = "interrupted", f"{self.stop.reason} at {now:.1f} s"
                self._stop_safely(now, "interrupted", reason)
                break
            try:
                faults = self._link.link_faults() if self._link is not None else ()
            except Exception as exc:  # judging the link failed: it cannot be trusted
                faults = (f"link health check raised {exc!r}",)
            if faults:
                outcome, reason = "failed", f"robot link lost at {now:.1f} s: {'; '.join(faults)}"
                self._stop_safely(now, "link-lost", reason)
                break
            try:
                status = self.step()
                if freeze:
                    _freeze_long_lived()
                    freeze = False
            except JournalWriteError as exc:  # the disk is full: nothing more can be kept
                outcome, reason = "failed", str(exc)
                self._stop_safely(now, "fault", reason)
                break
            except Exception as exc:  # a crashed behaviour: stop safely, say why
                trace = traceback.format_exc()
                outcome, reason = "failed", f"exception in tick: {exc!r}"
                self._stop_safely(now, "fault", reason)
                break
            limit = self.max_missed_deadlines
            if limit is not None and limit > 0 and self._missed_in_a_row >= limit:
                outcome = "failed"
                reason = (
                    f"{self._missed_in_a_row} consecutive tick deadlines missed "
                    f"(last tick {self.stats.durations[-1] * 1e3:.1f} ms > "
                    f"{self.period * 1e3:.1f} ms)"
                )
                self._stop_safely(now, "fault", reason)
                break
            if self.aborted_at is not None and status != Status.RUNNING:
                # the tree's abort branch took the robot back to the handover point P
                outcome = "aborted"
                reason = f"aborted by the operator at {self.aborted_at:.1f} s: " + (
                    "back at the handover point P"
                    if status == Status.SUCCESS
                    else f"could not return to the handover point P ({self._failure_reason()})"
                )
                self.events.append(Event(now, "aborted", {"reason": reason}))
                break
            if status == Status.SUCCESS:
                outcome, reason = "completed", "mission completed"
                break
            if status == Status.FAILURE:
                outcome, reason = "failed", self._failure_reason()
                self.events.append(Event(now, "mission-failed", {"reason": reason}))
                break
            self.clock.wait(now + self.period)
        return outcome, reason, trace
