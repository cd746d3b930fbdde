"""The typed blackboard keys: the only way behaviours share data (ARCHITECTURE.md §3).

Each key has one record type. Behaviours declare which keys they read and write
(:class:`behaviours.base.Node`); py_trees enforces the access at run time and the
compiler checks at compile time that every key read has a writer that runs before it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from executive.core.records import (
    FeatureObservations,
    Obstacles,
    OperatorRequests,
    PoseEstimate,
    SensorFrame,
    VelocityCommand,
)


@dataclass(frozen=True, slots=True)
class Key:
    """A blackboard key and the type of the record stored under it."""

    name: str
    type: type

    def __str__(self) -> str:
        return self.name


@dataclass(frozen=True, slots=True)
class MissionProgress:
    """Where the mission stands; written by the mission behaviours, journaled by the runtime.

    ``phase`` is approach / inspection / return / done; ``checkpoint`` the id being worked
    on (or the last one); ``completed`` the ids of the checkpoints finished so far, in
    order; ``results`` one :class:`ItemResult` per inspected item, in order.
    """

    phase: str = "approach"
    checkpoint: str | None = None
    goal: str | None = None
    completed: tuple[str, ...] = ()
    results: tuple[ItemResult, ...] = ()
    skipped: tuple[str, ...] = ()
    """Completed checkpoints the operator chose to skip (trapped): not inspected."""


@dataclass(frozen=True, slots=True)
class ItemResult:
    """One inspected item: when, from where, with which camera pose, detected or not.

    ``stale`` is True when the item could not be judged on fresh data: no image of the
    inspection camera newer than the moment it was aimed at the item was fresh (a frozen
    camera repeating an old image), or the pan-tilt angles were stale. Such an item is
    never ``detected``.
    """

    checkpoint: str
    item: str
    stamp: float
    detected: bool
    camera: str
    pan: float
    tilt: float
    pose_f: tuple[float, float, float]
    stale: bool = False


@dataclass(frozen=True, slots=True)
class ServoStatus:
    """The visual servoing of the current navigation (issue 13), written every tick its
    guard runs: ``mode`` is ``pbvs``, ``ibvs`` or ``lost`` (no camera sees enough real
    points: metric go-to-goal); ``camera`` the camera that drives the base (its unit
    ``unit``) with ``real`` detected and ``reconstructed`` points of ``target`` in the
    augmented image; ``reliability`` per camera; ``reconstructed_s`` the time this target
    has been servoed on an image with reconstructed points, ``servo_s`` by mode."""

    stamp: float
    checkpoint: str
    target: str
    mode: str
    unit: str | None = None
    camera: str | None = None
    real: int = 0
    reconstructed: int = 0
    reliability: tuple[tuple[str, float], ...] = ()
    reconstructed_s: float = 0.0
    servo_s: tuple[tuple[str, float], ...] = ()
    switches: tuple[tuple[float, str], ...] = ()
    """Every task switch of this servo (mode or driving camera) with its time and reason."""
    start: float = math.nan
    """Where this servo started, in metres before the checkpoint on its heading line."""
    start_note: str = ""
    """Why the servo start was moved from where the compiler put it ("" when it was not:
    :class:`behaviours.controllers.servo.SlideServoStart`)."""


@dataclass(frozen=True, slots=True)
class OperatorQuestion:
    """A question the mission asks the operator (the thesis's "operator asked for help",
    issue 15): ``id`` changes with each new question; the answer comes back as
    :attr:`executive.core.records.OperatorRequests.answer`, one of ``choices``."""

    stamp: float
    id: str
    text: str
    choices: tuple[str, ...]


SENSOR_FRAME = Key("/sensors/frame", SensorFrame)
POSE = Key("/state/pose", PoseEstimate)
OBSTACLES = Key("/state/obstacles", Obstacles)
FEATURES = Key("/state/features", FeatureObservations)
COMMAND = Key("/command", VelocityCommand)
PROGRESS = Key("/mission/progress", MissionProgress)
OPERATOR = Key("/operator", OperatorRequests)
SERVO = Key("/state/servo", ServoStatus)
QUESTION = Key("/operator/question", OperatorQuestion)

ALL_KEYS = (
    SENSOR_FRAME,
    POSE,
    OBSTACLES,
    FEATURES,
    COMMAND,
    PROGRESS,
    OPERATOR,
    SERVO,
    QUESTION,
)
EXTERNAL_KEYS = (SENSOR_FRAME, OPERATOR)
"""Written by the runtime before each tick, not by a behaviour."""
