"""The visual-servoing control law ``q_dot = -lambda (L J)^+ e`` (thesis eq. 3.10, 3.29).

Seed 000: IBVS control law (eq. 3.3-3.10, lines 2130-2175; eq. 3.7-3.10 were lost in
extraction, the text around them says "q_dot according to Equation (3.10)" is the
Moore-Penrose pseudo-inverse of ``L_I J`` times the error, lines 2397-2400), PBVS (eq.
3.26-3.29: "the control law is unchanged", lines 2630-2650), the stop criterion of
Algorithm 3.1 (lines 2990-3035), the advice to adapt the gain (lines 2960-2968).

With the choices of the best peer, ViSP's ``vpServo`` (read in its source, 3.x):

* the interaction matrix at the current features ``L(s)``, at the desired ones
  ``L(s*)`` (constant, with the desired depths), or their mean ``(L(s) + L(s*)) / 2``
  (:class:`InteractionAt`, ``vpServo::CURRENT | DESIRED | MEAN``);
* the adaptive gain ``lambda(x) = (l0 - linf) exp(-l'0 x / (l0 - linf)) + linf``
  (:class:`AdaptiveGain`, ``vpAdaptiveGain``) evaluated, as vpServo does, at
  ``x = ||e1||_inf`` with ``e1 = (L J)^+ e`` (the velocity direction, not the feature
  error);
* the pseudo-inverse keeps the singular values above ``threshold * sigma_max`` (vpServo:
  1e-6) and drops the others (:func:`pseudo_inverse`);
* continuous sequencing (Mansard & Chaumette 2007, eq. 17; ``vpServo::computeControlLaw(t,
  e_dot_init)``): after a task switch at ``t = 0``::

      q_dot(t) = -lambda e1(t) + (q_dot_prev + lambda e1(0)) exp(-mu t)

  so ``q_dot(0) = q_dot_prev``: the velocity the robot had when the task changed (zero
  when starting from rest, which is ViSP's ``computeControlLaw(t)``). The new task takes
  over smoothly with time constant ``1 / mu`` (vpServo's default ``mu = 4``).

:class:`VisualServo` strings them together with the only state the law needs (the task
switch's ``e1(0)`` and velocity, and the last command); it is cheap enough to call every
tick (one IBVS step for 4 points and 4 DoF, Jacobian included, costs ~0.08 ms; PBVS with
solvePnP ~0.25 ms: `python benchmarks/bench_servo.py --step-timing`). Features, interaction
matrices and Jacobians come from :mod:`behaviours.laws.interaction` and
:mod:`behaviours.laws.robot_jacobian`; a free-flying camera uses ``cJq = I6``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from enum import StrEnum

import numpy as np
from numpy.typing import ArrayLike

from behaviours.laws.interaction import (
    centroid_interaction_matrix,
    ibvs_error_eq_3_3,
    pbvs_error_eq_3_25,
    pbvs_interaction_matrix_eq_3_35,
    point_interaction_matrix_eq_3_17,
)
from executive.core.frames import FloatArray, Transform3

__all__ = [
    "DEFAULT_MU",
    "DEFAULT_PINV_THRESHOLD",
    "AdaptiveGain",
    "InteractionAt",
    "ServoStep",
    "VisualServo",
    "approach_depth_row",
    "approach_line_row",
    "control_law_eq_3_10",
    "pseudo_inverse",
    "stop_algorithm_3_1",
]

DEFAULT_PINV_THRESHOLD = 1e-6
"""Relative singular-value threshold of the pseudo-inverse (vpServo's)."""
DEFAULT_MU = 4.0
"""Continuous sequencing rate (1/s), vpServo's default."""


class InteractionAt(StrEnum):
    """Where the interaction matrix is evaluated (``vpServo::vpServoIteractionMatrixType``)."""

    CURRENT = "current"
    DESIRED = "desired"
    MEAN = "mean"


@dataclass(frozen=True, slots=True)
class AdaptiveGain:
    """``lambda(x) = (l0 - linf) exp(-l'0 x / (l0 - linf)) + linf``.

    ``lambda(0) = lambda_0``, ``lambda(inf) = lambda_inf``, slope ``-slope_0`` at 0 (the
    curve decreases from l0 to linf; vpAdaptiveGain calls ``slope_0`` "lambda'(0)" and
    means its magnitude). A constant gain is ``AdaptiveGain.constant(c)``.
    """

    lambda_0: float
    lambda_inf: float
    slope_0: float

    def __post_init__(self) -> None:
        if not (self.lambda_0 > 0.0 and self.lambda_inf > 0.0 and self.slope_0 >= 0.0):
            raise ValueError(
                "adaptive gain needs lambda_0 > 0, lambda_inf > 0 and slope_0 >= 0, got "
                f"({self.lambda_0}, {self.lambda_inf}, {self.slope_0})"
            )

    @classmethod
    def constant(cls, gain: float) -> AdaptiveGain:
        return cls(gain, gain, 0.0)

    @property
    def is_constant(self) -> bool:
        return self.lambda_0 == self.lambda_inf

    def __call__(self, x: float) -> float:
        a = self.lambda_0 - self.lambda_inf
        if abs(a) <= 1e-15:
            return self.lambda_inf
        return a * math.exp(-self.slope_0 * x / a) + self.lambda_inf


def pseudo_inverse(
    matrix: ArrayLike, threshold: float = DEFAULT_PINV_THRESHOLD
) -> tuple[FloatArray, int]:
    """Moore-Penrose pseudo-inverse and rank: singular values below ``threshold`` times the
    largest are dropped (treated as zero), as ``vpMatrix::pseudoInverse``."""
    m = np.asarray(matrix, dtype=float)
    u, s, vt = np.linalg.svd(m, full_matrices=False)
    if s.size == 0 or s[0] == 0.0:
        return np.zeros((m.shape[1], m.shape[0])), 0
    keep = s > threshold * s[0]
    rank = int(np.count_nonzero(keep))
    inv_s = np.where(keep, 1.0 / np.where(keep, s, 1.0), 0.0)
    return (vt.T * inv_s) @ u.T, rank


def control_law_eq_3_10(
    interaction: ArrayLike,
    jacobian: ArrayLike,
    error: ArrayLike,
    gain: float,
    threshold: float = DEFAULT_PINV_THRESHOLD,
) -> FloatArray:
    """Eq. 3.10 (and 3.29): ``q_dot = -lambda (L J)^+ e`` with a constant ``gain``."""
    task_jacobian = np.asarray(interaction, dtype=float) @ np.asarray(jacobian, dtype=float)
    pinv, _ = pseudo_inverse(task_jacobian, threshold)
    return -gain * (pinv @ np.asarray(error, dtype=float))


def stop_algorithm_3_1(
    q_dot: ArrayLike,
    iteration: int,
    min_iterations: int,
    thresholds: float | Sequence[float],
) -> bool:
    """Algorithm 3.1: stop (or raise the gain) once ``iteration >= min_iterations`` and
    every command ``|v|, |omega|, |omega_pan|, |omega_tilt|`` is at most its threshold.

    ``thresholds`` is one value for all (the thesis's "threshold") or one per component.
    The thesis uses it to end PBVS, whose error mixes metres and radians so that one
    threshold on ``e`` is hard to choose (lines 2980-2990).
    """
    if iteration < min_iterations:
        return False
    q = np.abs(np.asarray(q_dot, dtype=float))
    limit = np.broadcast_to(np.asarray(thresholds, dtype=float), q.shape)
    return bool(np.all(q <= limit))


def approach_line_row(
    x: float,
    y: float,
    theta: float,
    goal_x: float,
    goal_y: float,
    goal_theta: float,
    lookahead: float = math.inf,
) -> tuple[float, float, np.ndarray]:
    """A task row that steers a unicycle onto the goal's heading line (a secondary task
    stacked under the visual rows of eq. 3.10, for the robot Jacobian's q = (v, omega,
    omega_pan, omega_tilt)); poses in a right-handed planar frame, heading ``theta``.

    Four controls steer five configuration variables (base x, y, theta, pan, tilt). The
    offset of the base *across* the checkpoint's heading line is the one no instantaneous
    command reaches (no lateral velocity); in the image it is nearly the same as a
    rotation (a flat target a few metres away), so the least-squares law of eq. 3.10 ends
    wherever the start left it (Brockett: no smooth static feedback removes it). The row
    aims the base at the goal point while it still has distance to go (pure pursuit): with
    ``c`` the cross-track offset, ``d`` the along-track distance still to go (positive
    behind the goal) and ``dtheta = theta - theta*``,

        e = c + d sin(dtheta)       (where the heading ray crosses the goal's normal)
        de/dt = v sin(dtheta) (1 - cos(dtheta)) + d cos(dtheta) omega

    so the offset shrinks in proportion to the distance left. The row steers with
    ``omega`` only: its drift term is second order, and the speed is the visual rows' to
    choose. ``lookahead`` caps ``d`` (the aim point then runs ``lookahead`` ahead of the
    base's projection on the line, not at the goal): pursuing the goal point itself, the
    heading correction shrinks with the distance left and the offset falls only in
    proportion to it, so a start 1 m out ends with 40 % of its offset 0.4 m out; with the
    capped distance the offset decays exponentially over ``lookahead``. Returns
    ``(e, d, row)`` with ``d`` the uncapped distance to go and ``row`` the (4,) Jacobian
    of ``e`` in q; the caller drops the row near the goal, where what is left of ``c`` is
    the visual rows' (the row would otherwise hold a residual against them).
    """
    ch, sh = math.cos(goal_theta), math.sin(goal_theta)
    dx, dy = x - goal_x, y - goal_y
    cross = -sh * dx + ch * dy
    ahead = -(ch * dx + sh * dy)
    dth = math.atan2(math.sin(theta - goal_theta), math.cos(theta - goal_theta))
    d = min(max(ahead, 0.0), lookahead)
    return cross + d * math.sin(dth), ahead, np.array([0.0, d * math.cos(dth), 0.0, 0.0])


def approach_depth_row(
    x: float, y: float, theta: float, goal_x: float, goal_y: float, goal_theta: float
) -> tuple[float, np.ndarray]:
    """A task row for the distance still to go along the goal's heading line (poses as
    :func:`approach_line_row`): ``e = -d`` (zero at the goal, negative behind it), whose
    Jacobian in q = (v, omega, omega_pan, omega_tilt) is ``(cos(dtheta), 0, 0, 0)``
    (``d(-d)/dt = v cos(dtheta)``).

    Stacked with a small weight under the visual rows of eq. 3.10, it is the localisation's
    say on the camera's depth: where the image fixes the distance to the target well (a
    spread target seen face on) the visual rows outweigh it; where it does not (two points
    lying mostly along the line of sight: the image changes little with the distance) it
    sets where the least-squares law stops. Returns ``(e, row)``."""
    ch, sh = math.cos(goal_theta), math.sin(goal_theta)
    ahead = -(ch * (x - goal_x) + sh * (y - goal_y))
    dth = math.atan2(math.sin(theta - goal_theta), math.cos(theta - goal_theta))
    return -ahead, np.array([math.cos(dth), 0.0, 0.0, 0.0])


@dataclass(frozen=True, slots=True)
class ServoStep:
    """One evaluation of the law: the command, the error it regulates and why."""

    q_dot: FloatArray
    """The command (v, omega, omega_pan, omega_tilt), or the camera twist if free."""
    error: FloatArray
    """``e`` (IBVS: ``s - s*``, normalised; PBVS: eq. 3.25)."""
    e1: FloatArray
    """``(L J)^+ e``."""
    gain: float
    rank: int
    """Rank of ``L J`` after the threshold: below the DoF count, some motion is not
    controlled (e.g. fewer than 2 points, or a degenerate configuration)."""


class VisualServo:
    """``q_dot = -lambda (L J)^+ e`` with vpServo's options, one call per control period.

    ``gain``: a constant or an :class:`AdaptiveGain`. ``interaction``: where ``L`` is
    evaluated (IBVS; PBVS always uses the current one). ``mu``: continuous sequencing rate
    (None: plain law, the command may jump at a switch). Call :meth:`switch` when the task
    changes (start, PBVS <-> IBVS, new target): the time ``t`` given to the steps counts
    from there. The instance remembers the last command to carry it across a switch.
    """

    def __init__(
        self,
        gain: float | AdaptiveGain = 0.5,
        interaction: InteractionAt | str = InteractionAt.CURRENT,
        mu: float | None = None,
        pinv_threshold: float = DEFAULT_PINV_THRESHOLD,
    ) -> None:
        self.gain = gain if isinstance(gain, AdaptiveGain) else AdaptiveGain.constant(gain)
        self.interaction = InteractionAt(interaction)
        if mu is not None and not mu > 0.0:
            raise ValueError(f"mu must be > 0 (1/s), got {mu}")
        self.mu = mu
        self.pinv_threshold = float(pinv_threshold)
        self._e1_start: FloatArray | None = None
        self._q_dot_start: FloatArray | None = None
        self._switched = True
        self.last_q_dot: FloatArray | None = None

    def reset(self) -> None:
        """Forget everything: the next step starts a task from rest."""
        self._e1_start = None
        self._q_dot_start = None
        self._switched = True
        self.last_q_dot = None

    def switch(self, q_dot_now: ArrayLike | None = None) -> None:
        """The task changes: the next step is ``t = 0`` of the new one. Its command starts
        from ``q_dot_now`` (default: the last command this servo gave, or rest)."""
        self._switched = True
        if q_dot_now is not None:
            self.last_q_dot = np.asarray(q_dot_now, dtype=float).copy()

    def step(
        self, error: ArrayLike, interaction: ArrayLike, jacobian: ArrayLike, t: float = 0.0
    ) -> ServoStep:
        """The command for error ``e``, interaction matrix ``L`` (already the chosen one)
        and robot Jacobian ``cJq``; ``t`` (s) since the last :meth:`switch`."""
        e = np.asarray(error, dtype=float)
        task_jacobian = np.asarray(interaction, dtype=float) @ np.asarray(jacobian, dtype=float)
        pinv, rank = pseudo_inverse(task_jacobian, self.pinv_threshold)
        e1 = pinv @ e
        lam = self.gain(float(np.max(np.abs(e1))) if e1.size else 0.0)
        q_dot = -lam * e1
        if self.mu is not None:
            if self._switched or self._e1_start is None:
                self._e1_start = e1.copy()
                prev = self.last_q_dot
                self._q_dot_start = (
                    prev.copy() if prev is not None and prev.shape == e1.shape else 0.0 * e1
                )
            assert self._q_dot_start is not None
            q_dot = q_dot + (self._q_dot_start + lam * self._e1_start) * math.exp(-self.mu * t)
        self._switched = False
        self.last_q_dot = q_dot
        return ServoStep(q_dot, e, e1, lam, rank)

    # -- the two laws of the thesis ----------------------------------------------------
    def ibvs_step(
        self,
        xy: ArrayLike,
        depth: ArrayLike,
        xy_desired: ArrayLike,
        depth_desired: ArrayLike,
        jacobian: ArrayLike,
        t: float = 0.0,
    ) -> ServoStep:
        """IBVS (eq. 3.3, 3.17-3.18, 3.10): normalised points ``xy`` (N, 2) at depths Z
        (stereo or pose estimate) towards ``xy_desired`` at ``depth_desired``."""
        e = ibvs_error_eq_3_3(xy, xy_desired)
        if self.interaction is InteractionAt.CURRENT:
            lmat = point_interaction_matrix_eq_3_17(xy, depth)
        elif self.interaction is InteractionAt.DESIRED:
            lmat = point_interaction_matrix_eq_3_17(xy_desired, depth_desired)
        else:
            lmat = 0.5 * (
                point_interaction_matrix_eq_3_17(xy, depth)
                + point_interaction_matrix_eq_3_17(xy_desired, depth_desired)
            )
        return self.step(e, lmat, jacobian, t)

    def track_feature_step(
        self,
        xy: ArrayLike,
        depth: ArrayLike,
        jacobian: ArrayLike,
        t: float = 0.0,
        centroid_desired: ArrayLike = (0.0, 0.0),
    ) -> ServoStep:
        """The track-feature behaviour (lines 745-764): keep the centroid of the detected
        points at ``centroid_desired`` (the image centre by default) with the pan-tilt unit
        only. ``jacobian`` is the robot's 6x4 ``cJq``; the base's columns are dropped, so
        the command is ``(0, 0, omega_pan, omega_tilt)`` whatever the base does (its
        motion is not compensated: call it every tick)."""
        p = np.asarray(xy, dtype=float).reshape(-1, 2)
        e = p.mean(axis=0) - np.asarray(centroid_desired, dtype=float)
        lmat = centroid_interaction_matrix(p, depth)
        ptu = np.asarray(jacobian, dtype=float)[:, 2:4]
        step = self.step(e, lmat, ptu, t)
        q_dot = np.concatenate(([0.0, 0.0], step.q_dot))
        self.last_q_dot = q_dot
        return ServoStep(q_dot, step.error, step.e1, step.gain, step.rank)

    def pbvs_step(
        self,
        c_m_o: Transform3,
        cd_m_o: Transform3,
        jacobian: ArrayLike,
        t: float = 0.0,
        centroid_o: ArrayLike = (0.0, 0.0, 0.0),
    ) -> ServoStep:
        """PBVS (eq. 3.25, 3.35, 3.29): the target's pose ``cMo`` (e.g. from
        :func:`behaviours.laws.pose_estimation.camera_pose_from_points`) towards
        ``c*Mo``; ``centroid_o`` is the point O in the object frame."""
        e = pbvs_error_eq_3_25(c_m_o, cd_m_o, centroid_o)
        c_t_o = c_m_o.apply(np.asarray(centroid_o, dtype=float))
        lmat = pbvs_interaction_matrix_eq_3_35(c_t_o, e[3:])
        return self.step(e, lmat, jacobian, t)
