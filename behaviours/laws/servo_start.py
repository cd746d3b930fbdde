"""Where a checkpoint's visual servoing starts: our addition to the thesis's sequence of
metric navigation, PBVS and IBVS towards a checkpoint (seed lines 3276-3285).

The compiler puts the servo start :data:`~executive.compiler.SERVO_START` behind the
checkpoint on its heading line, reached by metric go-to-goal with tight tolerances (the
camera's straight approach keeps the base's heading). The tolerances ask for a few turns in
place there. When the aircraft is parked off its mark, that start can land beside a
vehicle parked next to the aircraft (A320 busy apron, CP10 beside the fuel truck: 0.64 m
from its flank, 4 cm beyond r_ES): each turn swings a corner of the footprint into r_ES,
the e-stop latches, the robot is pushed off, and the navigation is trapped.

:func:`start_distance` slides such a start forwards along the heading line, towards the
checkpoint (a shorter servo run), to the first place from which the robot can turn in
place without any return coming within r_ES of its footprint: the disc its corners sweep,
of radius :attr:`~executive.core.model.Platform.turning_radius`, clears every return by r_ES and
:data:`SERVO_START_MARGIN`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from executive.core.frames import FloatArray

SERVO_START_MARGIN = 0.1
"""Metres beyond r_ES that a servo start's turning disc keeps from every return: the
laser's range noise and the pose estimate's jitter at the start (a few cm each), so that
settling on the start's heading never trips the e-stop."""

SLIDE_STEP = 0.05
"""Metres between the servo starts tried along the heading line."""

SHORTEST_RUN = 0.0
"""The shortest servo run (m) a start may slide to: none. The start is reached with the
checkpoint's own tolerances (2 cm, 0.5 deg), so a start slid onto the checkpoint is the
checkpoint reached by metric go-to-goal, which the servo then refines on the image alone
(the approach line's row, which fades out 0.25 m before the checkpoint, has nothing left
to steer). A shorter run loses the row's correction of a sideways offset; a start the
robot cannot turn at loses the checkpoint (A320 busy apron, episodes 36 and 73: CP10's
start still 1.36-1.44 m from the fuel truck's flank 0.4 m before the checkpoint, 1.56 m
needed)."""


def candidate_distances(longest: float, shortest: float = SHORTEST_RUN) -> FloatArray:
    """The servo-start distances before the checkpoint to try, longest first, every
    :data:`SLIDE_STEP` from ``longest`` down to ``shortest`` (``longest`` alone when it
    is the shorter)."""
    if longest <= shortest:
        return np.array([longest])
    n = math.floor((longest - shortest) / SLIDE_STEP + 1e-9)
    return longest - SLIDE_STEP * np.arange(n + 1)


def start_distance(
    returns: FloatArray,
    checkpoint: tuple[float, float, float],
    distances: Sequence[float] | FloatArray,
    need: float,
) -> tuple[float, float]:
    """(the servo start's distance before ``checkpoint`` (x, y, heading), of
    ``distances`` (longest first): the longest whose centre is at least ``need`` from
    every one of ``returns`` (N, 2, same frame); that centre's distance to the nearest
    return (inf: none)). When none is that far, the one furthest from the returns (the
    longest of equals), if that is :data:`SERVO_START_MARGIN` further than the longest
    (else the longest: a shorter run for a few centimetres is no gain).

    ``need`` is the platform's turning radius + r_ES + :data:`SERVO_START_MARGIN` for a start
    the robot must be able to turn in place at."""
    d = np.asarray(distances, dtype=float)
    x, y, h = checkpoint
    centres = np.column_stack((x - d * math.cos(h), y - d * math.sin(h)))
    if len(returns) == 0:
        return float(d[0]), math.inf
    gaps = np.hypot(
        returns[None, :, 0] - centres[:, None, 0], returns[None, :, 1] - centres[:, None, 1]
    ).min(axis=1)
    clear = np.flatnonzero(gaps >= need)
    if len(clear):
        k = int(clear[0])
    else:
        k = int(np.argmax(gaps))
        k = k if gaps[k] >= gaps[0] + SERVO_START_MARGIN else 0
    return float(d[k]), float(gaps[k])
