"""Taught routes: key images (seed 002, Blanc et al. 2004, §2.3) and their repetition (§3).

A pure law module: no py_trees, no clock, no I/O.

Key images (§2.3)
-----------------
A route taught from A to B is the sequence of images recorded while the robot was driven
along it; a *key image* ``I_k`` is one of them, kept with the mosaic landmarks it shows.
The route ``Phi_AB = {I_k}`` must satisfy the paper's two rules between successive key
images:

1. they contain at least one common landmark of the mosaic (needed to servo from one to
   the next: the landmark's image poses in both give the state, §3.1);
2. the variation of a landmark's orientation between them is below a threshold: with
   large rotations several different paths join the two poses, and the repeated path
   would not fit the taught one.

The camera looks straight up at a horizontal ceiling, so a landmark's orientation in the
image turns by exactly the robot's change of heading (eq. 1: ``I_r = (C_r)^T M_r``):
rule 2 is a bound on the heading change. We bound the heading change over the whole
recorded stretch between two key images (the unwrapped heading's largest excursion from
the first key's), which implies the bound between the two key images themselves and also
refuses a stretch that turns and turns back.

The paper adds that key images are chosen so that the elementary trajectories between
them "fit relatively the learned trajectory", without a measure. The two rules alone do
not ensure it: the first image of a turn, already a few degrees round, passes both rules
with an image 8 m back on the straight, and its line (§3) runs 0.8 m beside that
straight. So a third condition makes the fit explicit: the recorded positions between
two key images stay within ``max_deviation`` (2 cm by default) of the line through the
second (:func:`line_deviation`); ``None`` leaves the paper's two rules only.

The first and the last recorded images are always key images. Between them the selection
is greedy: from a key image, the next one is the farthest recorded image that still
satisfies the rules with it, so key images are as few as the rules allow (long straight
stretches are one line of §3 each; a turn gets one key image per threshold of heading).
A recording in which two *consecutive* images already break a rule cannot be turned into
a route (the landmarks were lost, or the images are too far apart in heading): that is
reported with the index (:class:`SparseRecordingError`).

Repeating a route (§3)
----------------------
Between key images ``k-1`` and ``k`` the robot follows the straight line Gamma through
key ``k``'s pose with its heading (§3.1: "a straight line defined ... by the position and
the orientation to be achieved"), steering by eq. 12 (:mod:`behaviours.laws.vnhv`) with
the longitudinal speed V a parameter, positive (forwards) or negative (a route taught
backwards). Key ``k`` is *passed* when the robot crosses its normal: ``sign(V) s >= 0``;
the next line then takes over. The paper does not say how the switch is made; a bare
switch makes omega jump (the new line starts with ``theta`` the turn between the two key
images and a lateral offset), so :class:`RouteFollower` blends the commands of both lines
over the last ``blend`` metres before the key, ``omega = (1 - a) omega_k + a omega_k+1``
with ``a`` rising linearly from 0 to 1 in the distance still to go; at the switch ``a = 1``
and omega is the new line's own: the command is continuous, and the turn starts a little
before the key as the taught path did. V is then lowered by :func:`vnhv.limit_speed`
to keep omega within the platform's limit (the path y(d) does not change) and towards the
last key so as to stop there within the platform's deceleration.

Gains (1/m^2, 1/m) come from a settling distance (§3.2: "the performances of a path
tracking can be determined in terms of settling distance"): critically damped,
``Kd = 2 sqrt(Kp)``, with eq. 10's 5 % settling distance the one asked
(:func:`gains_for_settling_distance`).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from behaviours.laws.vnhv import (
    DEFAULT_THETA_MAX,
    VnhvGains,
    VnhvState,
    limit_speed,
    settling_distance,
    state_from_poses,
    vnhv_command,
)
from executive.core.frames import Pose2, wrap_angle

__all__ = [
    "DEFAULT_BLEND",
    "DEFAULT_MAX_DEVIATION",
    "DEFAULT_MAX_HEADING_CHANGE",
    "KeyImageRules",
    "RecordedImage",
    "RepeatStep",
    "RouteFollower",
    "SparseRecordingError",
    "common_landmarks",
    "gains_for_settling_distance",
    "heading_excursion",
    "line_deviation",
    "select_key_images",
]

DEFAULT_MAX_HEADING_CHANGE = math.radians(10.0)
"""Rule 2's threshold: the chord to the next key image then stays within
``R (1 - cos 10 deg) = 1.5 %`` of the turn's radius of the taught arc."""
DEFAULT_MAX_DEVIATION = 0.02
"""Metres the taught positions may stray from the line they will be repeated along."""
DEFAULT_BLEND = 0.3
"""Metres before a key image over which the next line's command is blended in."""


# -- key images (§2.3) --------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class RecordedImage:
    """One image of the teaching run: the robot pose in the mosaic frame M when it was
    taken and the ids of the mosaic landmarks seen in it."""

    pose_m: Pose2
    landmarks: frozenset[str]


@dataclass(frozen=True, slots=True)
class KeyImageRules:
    """§2.3's two rules: at least ``min_common`` landmarks shared by successive key
    images (rule 1) and a heading change below ``max_heading_change`` (rad) between them
    (rule 2)."""

    max_heading_change: float = DEFAULT_MAX_HEADING_CHANGE
    min_common: int = 1
    max_deviation: float | None = DEFAULT_MAX_DEVIATION
    """The fit (m): the recorded positions between two key images stay within this of the
    line through the second (None: the paper's two rules only)."""

    def __post_init__(self) -> None:
        if self.max_deviation is not None and not self.max_deviation > 0.0:
            raise ValueError("max_deviation must be > 0 (or None)")
        if not (math.isfinite(self.max_heading_change) and self.max_heading_change > 0.0):
            raise ValueError("max_heading_change must be finite and > 0")
        if self.max_heading_change >= math.pi / 2:
            raise ValueError("max_heading_change must be below 90 deg (eq. 12's domain)")
        if self.min_common < 1:
            raise ValueError("min_common must be >= 1: successive key images share a landmark")


class SparseRecordingError(ValueError):
    """Two consecutive recorded images already break a rule: no route can be made.

    ``index`` is the first of the two images (0-based), ``reason`` which rule broke."""

    def __init__(self, index: int, reason: str) -> None:
        super().__init__(f"recorded images {index} and {index + 1}: {reason}")
        self.index = index
        self.reason = reason


def common_landmarks(a: RecordedImage, b: RecordedImage) -> frozenset[str]:
    """Rule 1: the mosaic landmarks seen in both images."""
    return a.landmarks & b.landmarks


def _unwrapped_headings(recording: Sequence[RecordedImage]) -> list[float]:
    out = [recording[0].pose_m.theta]
    for prev, cur in itertools.pairwise(recording):
        out.append(out[-1] + wrap_angle(cur.pose_m.theta - prev.pose_m.theta))
    return out


def heading_excursion(recording: Sequence[RecordedImage], i: int, j: int) -> float:
    """Rule 2's measure: the largest ``|heading(m) - heading(i)|`` over ``i <= m <= j``,
    the heading unwrapped along the recording (rad)."""
    if not 0 <= i <= j < len(recording):
        raise IndexError(f"need 0 <= i <= j < {len(recording)}, got {i}, {j}")
    unwrapped = _unwrapped_headings(recording[i : j + 1])
    return max(abs(h - unwrapped[0]) for h in unwrapped)


def line_deviation(recording: Sequence[RecordedImage], i: int, j: int) -> float:
    """The fit of key ``j``'s line to the taught stretch ``i..j``: the largest distance
    (m) of the recorded positions ``i..j`` from the line through image ``j``'s pose with
    its heading (the line Gamma the stretch is repeated along, §3.1)."""
    if not 0 <= i <= j < len(recording):
        raise IndexError(f"need 0 <= i <= j < {len(recording)}, got {i}, {j}")
    key = recording[j].pose_m
    c, s = math.cos(key.theta), math.sin(key.theta)
    xy = np.array([(r.pose_m.x, r.pose_m.y) for r in recording[i : j + 1]])
    lateral = -s * (xy[:, 0] - key.x) + c * (xy[:, 1] - key.y)
    return float(np.max(np.abs(lateral)))


def _reason(a: RecordedImage, b: RecordedImage, turn: float, rules: KeyImageRules) -> str | None:
    shared = len(common_landmarks(a, b))
    if shared < rules.min_common:
        return (
            f"{shared} common landmark(s), rule 1 needs {rules.min_common} "
            "(landmarks lost, or images too far apart)"
        )
    if turn >= rules.max_heading_change:
        return (
            f"heading change {math.degrees(turn):.1f} deg, rule 2 needs less than "
            f"{math.degrees(rules.max_heading_change):.1f} deg (record images more often)"
        )
    return None


def select_key_images(
    recording: Sequence[RecordedImage], rules: KeyImageRules | None = None
) -> tuple[int, ...]:
    """The indices of the key images of a recording (§2.3): the first, the last, and in
    between greedily the farthest image satisfying both rules with the previous key.

    Raises :class:`SparseRecordingError` when two consecutive images break a rule, and
    ValueError for an empty recording."""
    rules = rules or KeyImageRules()
    n = len(recording)
    if n == 0:
        raise ValueError("an empty recording has no key images")
    unwrapped = _unwrapped_headings(recording)
    for k in range(n - 1):  # the recording itself must be dense enough
        why = _reason(recording[k], recording[k + 1], abs(unwrapped[k + 1] - unwrapped[k]), rules)
        if why is not None:
            raise SparseRecordingError(k, why)
    keys = [0]
    k = 0
    while k < n - 1:
        best = k + 1
        excursion = 0.0
        for j in range(k + 1, n):
            excursion = max(excursion, abs(unwrapped[j] - unwrapped[k]))
            if excursion >= rules.max_heading_change:
                break  # the excursion only grows with j
            if len(common_landmarks(recording[k], recording[j])) < rules.min_common:
                continue
            if rules.max_deviation is None or (
                line_deviation(recording, k, j) <= rules.max_deviation
            ):
                best = j
        keys.append(best)
        k = best
    return tuple(keys)


# -- gains --------------------------------------------------------------------------------
def gains_for_settling_distance(distance: float) -> VnhvGains:
    """Critically damped eq. 9 gains (``Kd = 2 sqrt Kp``) whose eq. 10 response from a
    parallel offset settles within 5 % in ``distance`` metres.

    Critically damped, y(d) depends on ``omega_n d`` only, so the settling distance is
    ``D1 / omega_n`` with ``D1`` the one for ``omega_n = 1``."""
    if not (math.isfinite(distance) and distance > 0.0):
        raise ValueError("the settling distance must be finite and > 0")
    unit = settling_distance(VnhvGains(1.0, 2.0))
    wn = unit / distance
    return VnhvGains(wn * wn, 2.0 * wn)


# -- repeating (§3) -----------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class RepeatStep:
    """One command of :class:`RouteFollower`: ``v`` (m/s, signed) and ``omega`` (rad/s);
    ``target`` the index of the key image whose line is followed, ``state`` against that
    line; ``switched`` True when this step passed key ``target - 1`` (its lateral error
    ``passed_error``, m, to the left of its line); ``done`` when the last key is passed."""

    v: float
    omega: float
    target: int
    state: VnhvState
    switched: bool = False
    passed_error: float = 0.0
    done: bool = False
    in_domain: bool = True
    passed: int = -1
    """The key image passed by this step (the last if several), or -1."""


class RouteFollower:
    """Follows the lines through successive key poses (module docstring, §3).

    ``keys`` are robot poses in one planar frame (the mosaic's, M); ``speed`` is V (m/s,
    negative for a route taught backwards); ``omega_max`` and ``deceleration`` the
    platform's limits. The first line is key 1's: the robot starts near key 0."""

    def __init__(
        self,
        keys: Sequence[Pose2],
        speed: float,
        gains: VnhvGains,
        omega_max: float,
        deceleration: float,
        blend: float = DEFAULT_BLEND,
        theta_max: float = DEFAULT_THETA_MAX,
        min_speed: float = 0.05,
    ) -> None:
        if len(keys) < 2:
            raise ValueError("a route needs at least two key poses")
        if not (math.isfinite(speed) and speed != 0.0):
            raise ValueError("V must be finite and non-zero (eq. 10 holds for V != 0)")
        if not (omega_max > 0.0 and deceleration > 0.0 and blend >= 0.0 and min_speed > 0.0):
            raise ValueError("omega_max, deceleration and min_speed must be > 0, blend >= 0")
        self.keys = tuple(keys)
        self.speed = speed
        self.gains = gains
        self.omega_max = omega_max
        self.deceleration = deceleration
        self.blend = blend
        self.theta_max = theta_max
        self.min_speed = min(min_speed, abs(speed))
        self.target = 1
        lengths = [a.distance_to(b) for a, b in zip(self.keys, self.keys[1:], strict=False)]
        self._after = [sum(lengths[k:]) for k in range(len(lengths))] + [0.0]
        """Path length along the key poses from key k to the last."""
        self._blend = [0.0] + [min(blend, 0.5 * d) for d in lengths]
        """The blend before key k: at most half the way from key k-1, so that it starts
        after the switch to key k's line (with a weight 0 then: no jump)."""

    def reset(self, target: int = 1) -> None:
        """Start again towards key ``target`` (1: the route's first line)."""
        self.target = max(1, min(target, len(self.keys) - 1))

    @property
    def done(self) -> bool:
        return self.target >= len(self.keys)

    def remaining(self, pose_m: Pose2) -> float:
        """Metres still to go: to the target key, then from key to key to the last."""
        if self.done:
            return 0.0
        return pose_m.distance_to(self.keys[self.target]) + self._after[self.target]

    def progress(self, pose_m: Pose2, index: int) -> float:
        """``sign(V) s`` against key ``index``'s line: negative before it, >= 0 passed."""
        return math.copysign(1.0, self.speed) * state_from_poses(pose_m, self.keys[index]).s

    def _omega(self, state: VnhvState, v: float) -> tuple[float, bool]:
        cmd = vnhv_command(state, v, self.gains, self.omega_max, self.theta_max)
        return cmd.omega, cmd.in_domain

    def step(self, pose_m: Pose2, speed_cap: float | None = None) -> RepeatStep:
        """The command at robot pose ``pose_m``; passes keys the robot has crossed.

        ``speed_cap`` (m/s) bounds |V| further (the mission's speed limit at the pose)."""
        last = len(self.keys) - 1
        switched, passed_error = False, 0.0
        passed = -1
        while self.target <= last and self.progress(pose_m, self.target) >= 0.0:
            passed_error = state_from_poses(pose_m, self.keys[self.target]).y
            passed = self.target
            self.target += 1
            switched = True
        if self.target > last:
            state = state_from_poses(pose_m, self.keys[last])
            return RepeatStep(
                0.0, 0.0, last, state, switched, passed_error, done=True, passed=passed
            )
        state = state_from_poses(pose_m, self.keys[self.target])
        magnitude = abs(self.speed) if speed_cap is None else min(abs(self.speed), speed_cap)
        if self.target == last:
            to_go = max(0.0, -self.progress(pose_m, last))
        else:
            to_go = self.remaining(pose_m)
        # stop at the last key within the platform's deceleration (y(d) does not depend on V)
        magnitude = min(magnitude, max(self.min_speed, math.sqrt(2.0 * self.deceleration * to_go)))
        v = math.copysign(magnitude, self.speed)
        blend_to = None
        blend = self._blend[self.target]
        if self.target < last and blend > 0.0:
            a = 1.0 + self.progress(pose_m, self.target) / blend
            if a > 0.0:
                blend_to = (state_from_poses(pose_m, self.keys[self.target + 1]), a)
        # V lowered so that omega stays within the limit on every line that contributes
        if abs(state.theta) < self.theta_max:
            v = limit_speed(v, state, self.gains, self.omega_max)
        if blend_to is not None and abs(blend_to[0].theta) < self.theta_max:
            v = limit_speed(v, blend_to[0], self.gains, self.omega_max)
        omega, in_domain = self._omega(state, v)
        if blend_to is not None:
            nxt, a = blend_to
            omega_next, next_in = self._omega(nxt, v)
            omega = (1.0 - a) * omega + a * omega_next
            in_domain = in_domain and next_in
        return RepeatStep(
            v, omega, self.target, state, switched, passed_error, False, in_domain, passed
        )
