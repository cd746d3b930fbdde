"""The virtual nonholonomic vehicle (VNHV) line-following law (seed 002, Blanc et al. 2004, §3).

A pure law module: no py_trees, no clock, no I/O. The robot (camera optical axis on the
axle midpoint, §3) is a cart that follows the straight line Gamma through the desired pose
(the next key image's pose), driven at a longitudinal speed V that is a free parameter
(forwards or backwards), steering with eq. 12.

State (§3.1, eq. 5)
-------------------
``VnhvState(s, y, theta)``: ``s`` the curvilinear abscissa along Gamma of the foot of the
cart on Gamma (``s = 0`` at the desired pose, ``s < 0`` before it), ``y`` the signed
lateral deviation (positive to the **left** of Gamma's direction), ``theta`` the cart
heading minus Gamma's heading. With these signs the kinematics are exactly eq. 5::

    s' = V cos theta,   y' = V sin theta,   theta' = omega           (eq. 5)

with ``omega`` the ordinary counter-clockwise yaw rate. (The paper writes
``theta = theta_Gamma - theta_v``, the mirror convention with y to the right and omega
the rate of that theta; eq. 5 and eq. 12 are invariant under the mirror
``(y, theta, omega) -> (-y, -theta, -omega)``, so the law is the same.) The state is
``desired^-1 @ current`` (:func:`state_from_poses`), or from one landmark's image poses
in the current and desired images (§3.1, ``R = r r*^T``, ``t = p - R p*``;
:func:`image_transform_s31`, :func:`state_from_image_poses`).

Chained form (eq. 6-11), c(s) = 0 for a straight line
------------------------------------------------------
``a1 = s``, ``a2 = y``, ``a3 = tan theta``; ``m1 = V cos theta`` (eq. 6) and
``m2 = a3' = omega / cos^2 theta`` (eq. 8 with c(s) = 0). In the distance ``a1`` the system
is linear (eq. 7) and the law ``m3 = m2 / m1 = -Kd a3 - Kp a2`` (eq. 9) gives
``a2'' + Kd a2' + Kp a2 = 0`` (eq. 10). For either sign of V, eq. 9 is implemented as
``m2 = -|m1| Kd a3 - m1 Kp a2`` (eq. 11) and eq. 8 solved for omega,
``omega = cos^2 theta m2``, gives::

    omega = -V cos^3(theta) Kp y - |V cos^3(theta)| Kd tan(theta)       (eq. 12)

**Erratum in eq. 8.** The paper prints ``m2 = cos^2 theta (omega - V c(s) cos theta)``:
the factor is on the wrong side. From ``a3 = tan theta``, ``a3' = theta' / cos^2 theta``,
and only ``omega = cos^2 theta m2`` turns eq. 11 into eq. 12 (with the printed form one
gets ``-V Kp y / cos theta - ...``; e.g. theta = 1, y = 0, V = Kd = 1: -2.88 rad/s instead
of eq. 12's -0.246). Eq. 12 is the one that is right: closed-loop runs reproduce eq. 10
exactly (tests/test_vnhv_law.py). The curvature term is dropped: with ``a3 = tan theta``
(rather than Thuilot et al.'s ``(1 - c y) tan theta``) the chained form of eq. 6 only holds
for c(s) = 0, the straight line the paper uses.

Eq. 10 then holds in the *distance travelled along Gamma* ``d = |s - s0|`` whatever V
(the sign of V included): ``y(d)`` does not depend on V, only the initial slope
``dy/dd(0) = sign(V cos theta0) tan theta0`` does (:func:`initial_slope`). Gains are in
1/m^2 (Kp) and 1/m (Kd) when the state is metric, in pixels otherwise (uncalibrated).

The line is stabilised, not a direction: ``a3 = tan theta -> 0`` means theta -> 0 *mod pi*.
We command eq. 12 only in the domain ``|theta| < theta_max < pi/2`` (default 80 deg), where
the robot faces along Gamma: with V > 0 it advances to ``s = 0`` from ``s < 0``; with
V < 0 it reverses to ``s = 0`` from ``s > 0`` (a route taught backwards).

The singularity theta = pi/2 [pi]
---------------------------------
There ``m1 = 0``: the chained form is undefined (``a3 = tan theta`` is infinite), and
eq. 12, written without the tangent as ``-V Kp y c^3 - |V| Kd |c| c sin theta``
(``c = cos theta``), tends to **0**: the cart would drive straight across the line for
ever (theta = +-pi/2 is an equilibrium of theta' = omega), and near it the effective gains
vanish like cos^2 theta. :func:`omega_eq12` is that tangent-free form, finite for every
input (0 on the singularity). :func:`vnhv_command` is what a behaviour should call: outside
the domain ``|theta| < theta_max`` (which includes the singularity and the backward-facing
half) it returns ``in_domain = False`` and a saturated turn ``omega = -sign(theta)
omega_max`` that rotates the heading back towards Gamma's direction (|theta| decreasing);
inside, eq. 12 clamped to ``+-omega_max`` (``saturated`` says so). The paper's remedy for
saturation is to lower V, which keeps the path y(d) unchanged: :func:`limit_speed`.
The chained-form helpers (:func:`to_chained`, :func:`m2_from_omega_eq8`) raise
``ValueError`` at the singularity instead of dividing by zero.

Eq. 10 theory and settling distance
-----------------------------------
``zeta = Kd / (2 sqrt Kp)``, ``omega_n = sqrt Kp`` (rad per metre). The settling distance
(:func:`settling_distance`) is **the smallest d such that |y(d')| <= 5 % of max |y| for all
d' >= d** (max |y| = |y0| when starting parallel to the line), computed on the exact
solution of eq. 10 (under-, critically or over-damped): a fine grid up to a horizon beyond
which the exponential envelope is below the band, then bisection on the last exit from the
band. :func:`settling_distance_envelope` is the textbook ``-ln(0.05) / sigma ~ 3 / (zeta
omega_n)`` (sigma the slowest decay rate), an approximation only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum

import numpy as np
from numpy.typing import ArrayLike

from behaviours.laws.ceiling import CeilingCamera, robot_pose_from_landmark_eq2
from executive.core.frames import FloatArray, Pose2, wrap_angle

__all__ = [
    "DEFAULT_THETA_MAX",
    "SETTLING_FRACTION",
    "ChainedState",
    "Damping",
    "Eq10Theory",
    "VnhvCommand",
    "VnhvGains",
    "VnhvState",
    "damping_ratio",
    "eq10_response",
    "image_transform_s31",
    "initial_slope",
    "kinematics_eq5",
    "limit_speed",
    "m1_eq6",
    "m2_eq11",
    "m2_from_omega_eq8",
    "m3_eq9",
    "natural_frequency",
    "omega_eq12",
    "omega_from_m2_eq8",
    "second_order_theory",
    "settling_distance",
    "settling_distance_envelope",
    "state_from_image_poses",
    "state_from_poses",
    "to_chained",
    "vnhv_command",
]

DEFAULT_THETA_MAX = math.radians(80.0)
"""Edge of the domain where eq. 12 is commanded (|theta| below it; cos = 0.17 there)."""
SETTLING_FRACTION = 0.05
"""The 5 % band of the settling distance."""
_MIN_COS = 1e-9
"""|cos theta| below this is the singularity for the chained-form helpers."""
_CRITICAL_TOL = 1e-6
"""|zeta - 1| below this is treated as critically damped."""


@dataclass(frozen=True, slots=True)
class VnhvGains:
    """Eq. 9 gains ``(Kp, Kd)``, both > 0 (1/m^2 and 1/m for a metric state)."""

    kp: float
    kd: float

    def __post_init__(self) -> None:
        if not (self.kp > 0.0 and self.kd > 0.0) or not (
            math.isfinite(self.kp) and math.isfinite(self.kd)
        ):
            raise ValueError("Kp and Kd must be finite and > 0 for eq. 10 to converge")


@dataclass(frozen=True, slots=True)
class VnhvState:
    """The VNHV state ``X_v = (s, y, theta)`` relative to the line Gamma (§3.1, eq. 5)."""

    s: float
    y: float
    theta: float


@dataclass(frozen=True, slots=True)
class ChainedState:
    """Chained-form coordinates ``(a1, a2, a3) = (s, y, tan theta)`` (eq. 6-7)."""

    a1: float
    a2: float
    a3: float


@dataclass(frozen=True, slots=True)
class VnhvCommand:
    """The steering command: ``omega`` (rad/s), whether eq. 12 was used (``in_domain``)
    and whether it was clamped to ``omega_max`` (``saturated``)."""

    omega: float
    in_domain: bool
    saturated: bool


class Damping(StrEnum):
    UNDER = "under"
    CRITICAL = "critical"
    OVER = "over"


@dataclass(frozen=True, slots=True)
class Eq10Theory:
    """Eq. 10 summary: damping ratio, natural frequency per metre, regime, settling
    distance (5 % band, from y0 = 1 parallel to the line)."""

    zeta: float
    omega_n: float
    damping: Damping
    settling_distance: float


# -- state --------------------------------------------------------------------------------
def state_from_poses(current: Pose2, desired: Pose2) -> VnhvState:
    """The line-following state of a robot at ``current`` for the line Gamma through the
    ``desired`` pose (both in the same planar frame, e.g. the mosaic M or the world):
    ``desired^-1 @ current`` read as ``(s, y, theta)``."""
    rel = desired.inverse() @ current
    return VnhvState(rel.x, rel.y, rel.theta)


def image_transform_s31(current_image: Pose2, desired_image: Pose2) -> Pose2:
    """§3.1: ``R = r r*^T``, ``t = p - R p*`` from one landmark's image poses ``(u, v, phi)``
    in the current and desired images, i.e. ``O_T_O* = I_L (I_L*)^-1`` (pixels)."""
    dphi = current_image.theta - desired_image.theta
    c, s = math.cos(dphi), math.sin(dphi)
    tx = current_image.x - (c * desired_image.x - s * desired_image.y)
    ty = current_image.y - (s * desired_image.x + c * desired_image.y)
    return Pose2(tx, ty, wrap_angle(dphi))


def state_from_image_poses(
    current_image: Pose2, desired_image: Pose2, camera: CeilingCamera
) -> VnhvState:
    """The state from one landmark seen in the current and the desired (key) image.

    Both robot poses are expressed in the landmark's frame by eq. 1-2, so the state is
    metric (``camera.scale = Z/f``) and accounts for the camera mount."""
    origin = Pose2(0.0, 0.0, 0.0)
    current = robot_pose_from_landmark_eq2(origin, current_image, camera)
    desired = robot_pose_from_landmark_eq2(origin, desired_image, camera)
    return state_from_poses(current, desired)


def kinematics_eq5(state: VnhvState, v: float, omega: float) -> tuple[float, float, float]:
    """Eq. 5: ``(s', y', theta') = (V cos theta, V sin theta, omega)``."""
    return v * math.cos(state.theta), v * math.sin(state.theta), omega


# -- chained form -------------------------------------------------------------------------
def _checked_cos(theta: float) -> float:
    c = math.cos(theta)
    if abs(c) < _MIN_COS:
        raise ValueError("chained form undefined at theta = pi/2 [pi] (a3 = tan theta)")
    return c


def to_chained(state: VnhvState) -> ChainedState:
    """Eq. 6-7 coordinates ``(s, y, tan theta)``; ValueError at theta = pi/2 [pi]."""
    c = _checked_cos(state.theta)
    return ChainedState(state.s, state.y, math.sin(state.theta) / c)


def m1_eq6(v: float, theta: float) -> float:
    """Eq. 6: ``m1 = a1' = s' = V cos theta``."""
    return v * math.cos(theta)


def m2_from_omega_eq8(omega: float, theta: float) -> float:
    """Eq. 8 for the straight line (c(s) = 0), corrected: ``m2 = a3' = omega / cos^2 theta``
    (the paper prints ``cos^2 theta omega``; see the module docstring). ValueError at the
    singularity."""
    c = _checked_cos(theta)
    return omega / (c * c)


def omega_from_m2_eq8(m2: float, theta: float) -> float:
    """Eq. 8 solved for omega (c(s) = 0): ``omega = cos^2 theta m2``; finite everywhere."""
    c = math.cos(theta)
    return c * c * m2


def m3_eq9(chained: ChainedState, gains: VnhvGains) -> float:
    """Eq. 9: ``m3 = -Kd a3 - Kp a2``."""
    return -gains.kd * chained.a3 - gains.kp * chained.a2


def m2_eq11(chained: ChainedState, m1: float, gains: VnhvGains) -> float:
    """Eq. 11: ``m2 = -|m1| Kd a3 - m1 Kp a2`` (eq. 9 for either sign of V)."""
    return -abs(m1) * gains.kd * chained.a3 - m1 * gains.kp * chained.a2


def omega_eq12(state: VnhvState, v: float, gains: VnhvGains) -> float:
    """Eq. 12: ``omega = -V cos^3 theta Kp y - |V cos^3 theta| Kd tan theta``.

    Evaluated without the tangent (``|c^3| tan theta = |c| c sin theta``), so it is finite
    everywhere and 0 at theta = pi/2 [pi] (see the module docstring)."""
    c = math.cos(state.theta)
    return -v * c * c * c * gains.kp * state.y - abs(v) * gains.kd * abs(c) * c * math.sin(
        state.theta
    )


def vnhv_command(
    state: VnhvState,
    v: float,
    gains: VnhvGains,
    omega_max: float,
    theta_max: float = DEFAULT_THETA_MAX,
) -> VnhvCommand:
    """Eq. 12 in its domain ``|theta| < theta_max``, clamped to ``+-omega_max``; outside,
    the saturated turn ``-sign(theta) omega_max`` back towards Gamma's direction."""
    if not omega_max > 0.0:
        raise ValueError("omega_max must be > 0")
    if not 0.0 < theta_max < math.pi / 2:
        raise ValueError("theta_max must lie in (0, pi/2)")
    theta = state.theta if -math.pi <= state.theta < math.pi else wrap_angle(state.theta)
    if abs(theta) >= theta_max:
        return VnhvCommand(-math.copysign(omega_max, theta), in_domain=False, saturated=True)
    omega = omega_eq12(VnhvState(state.s, state.y, theta), v, gains)
    if abs(omega) > omega_max:
        return VnhvCommand(math.copysign(omega_max, omega), in_domain=True, saturated=True)
    return VnhvCommand(omega, in_domain=True, saturated=False)


def limit_speed(v: float, state: VnhvState, gains: VnhvGains, omega_max: float) -> float:
    """The paper's remedy for saturation (§3.2): scale V so that |eq. 12| <= omega_max.

    Eq. 12 is positively homogeneous of degree 1 in V (``omega(k V) = k omega(V)``, k > 0),
    so ``V omega_max / |omega|`` meets the limit exactly, keeps V's sign, and leaves the
    path y(d) of eq. 10 unchanged."""
    if not omega_max > 0.0:
        raise ValueError("omega_max must be > 0")
    omega = abs(omega_eq12(state, v, gains))
    return v if omega <= omega_max else v * (omega_max / omega)


# -- eq. 10 theory ------------------------------------------------------------------------
def damping_ratio(gains: VnhvGains) -> float:
    """Eq. 10: ``zeta = Kd / (2 sqrt Kp)``."""
    return gains.kd / (2.0 * math.sqrt(gains.kp))


def natural_frequency(gains: VnhvGains) -> float:
    """Eq. 10: ``omega_n = sqrt Kp`` (rad per metre travelled along Gamma)."""
    return math.sqrt(gains.kp)


def _damping(zeta: float) -> Damping:
    if abs(zeta - 1.0) < _CRITICAL_TOL:
        return Damping.CRITICAL
    return Damping.UNDER if zeta < 1.0 else Damping.OVER


def initial_slope(state: VnhvState, v: float) -> float:
    """``dy/dd`` at the start, d the distance along Gamma: ``sign(V cos theta) tan theta``
    (``|theta| < pi/2``; ValueError at the singularity)."""
    chained = to_chained(state)
    return math.copysign(1.0, m1_eq6(v, state.theta)) * chained.a3


def eq10_response(gains: VnhvGains, y0: float, slope0: float, distance: ArrayLike) -> FloatArray:
    """The exact solution ``y(d)`` of eq. 10 with ``y(0) = y0``, ``y'(0) = slope0``."""
    d = np.asarray(distance, dtype=float)
    zeta, wn = damping_ratio(gains), natural_frequency(gains)
    sigma = zeta * wn
    kind = _damping(zeta)
    if kind is Damping.CRITICAL:
        return np.exp(-wn * d) * (y0 + (slope0 + wn * y0) * d)
    if kind is Damping.UNDER:
        wd = wn * math.sqrt(1.0 - zeta * zeta)
        b = (slope0 + sigma * y0) / wd
        return np.exp(-sigma * d) * (y0 * np.cos(wd * d) + b * np.sin(wd * d))
    root = wn * math.sqrt(zeta * zeta - 1.0)
    r1, r2 = -sigma + root, -sigma - root
    a = (slope0 - r2 * y0) / (r1 - r2)
    return a * np.exp(r1 * d) + (y0 - a) * np.exp(r2 * d)


def _envelope(gains: VnhvGains, y0: float, slope0: float, d: float) -> float:
    """An upper bound of |y(d')| for d' >= d (d beyond a few time constants)."""
    zeta, wn = damping_ratio(gains), natural_frequency(gains)
    sigma = zeta * wn
    kind = _damping(zeta)
    if kind is Damping.CRITICAL:
        return (abs(y0) + abs(slope0 + wn * y0) * d) * math.exp(-wn * d)
    if kind is Damping.UNDER:
        wd = wn * math.sqrt(1.0 - zeta * zeta)
        return math.hypot(y0, (slope0 + sigma * y0) / wd) * math.exp(-sigma * d)
    root = wn * math.sqrt(zeta * zeta - 1.0)
    r1, r2 = -sigma + root, -sigma - root
    a = (slope0 - r2 * y0) / (r1 - r2)
    return (abs(a) + abs(y0 - a)) * math.exp(r1 * d)


def _slowest_rate(gains: VnhvGains) -> float:
    zeta, wn = damping_ratio(gains), natural_frequency(gains)
    if zeta <= 1.0:
        return zeta * wn
    return wn * (zeta - math.sqrt(zeta * zeta - 1.0))


def _peak(gains: VnhvGains, y0: float, slope0: float, grid: FloatArray, y: FloatArray) -> float:
    """max |y| over the grid, refined by ternary search around the best sample."""
    k = int(np.argmax(y))
    lo, hi = float(grid[max(k - 1, 0)]), float(grid[min(k + 1, grid.size - 1)])
    for _ in range(100):
        m1, m2 = lo + (hi - lo) / 3.0, hi - (hi - lo) / 3.0
        f1 = abs(float(eq10_response(gains, y0, slope0, m1)))
        f2 = abs(float(eq10_response(gains, y0, slope0, m2)))
        lo, hi = (m1, hi) if f1 < f2 else (lo, m2)
    return max(abs(y0), float(y[k]), abs(float(eq10_response(gains, y0, slope0, lo))))


def settling_distance(
    gains: VnhvGains,
    y0: float = 1.0,
    slope0: float = 0.0,
    fraction: float = SETTLING_FRACTION,
    samples: int = 200_001,
) -> float:
    """The settling distance of eq. 10: the smallest d with ``|y(d')| <= fraction *
    max|y|`` for all ``d' >= d``, from the exact solution (grid, then bisection)."""
    if not 0.0 < fraction < 1.0:
        raise ValueError("fraction must lie in (0, 1)")
    if y0 == 0.0 and slope0 == 0.0:
        return 0.0
    horizon = 8.0 / _slowest_rate(gains)
    while True:
        grid = np.linspace(0.0, horizon, samples)
        y = np.abs(eq10_response(gains, y0, slope0, grid))
        band = fraction * _peak(gains, y0, slope0, grid, y)
        if _envelope(gains, y0, slope0, horizon) < 1e-3 * band:
            break
        horizon *= 2.0
    outside = np.nonzero(y > band)[0]
    if outside.size == 0:
        return 0.0
    lo, hi = float(grid[outside[-1]]), float(grid[outside[-1] + 1])
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        if abs(float(eq10_response(gains, y0, slope0, mid))) > band:
            lo = mid
        else:
            hi = mid
    return hi


def settling_distance_envelope(gains: VnhvGains, fraction: float = SETTLING_FRACTION) -> float:
    """Approximation ``-ln(fraction) / sigma`` (sigma the slowest decay rate; ~3 / (zeta
    omega_n) for the 5 % band when under-damped). Prefer :func:`settling_distance`."""
    return -math.log(fraction) / _slowest_rate(gains)


def second_order_theory(gains: VnhvGains, fraction: float = SETTLING_FRACTION) -> Eq10Theory:
    """Eq. 10 summary for ``(Kp, Kd)``, settling from y0 = 1 parallel to the line."""
    zeta = damping_ratio(gains)
    return Eq10Theory(
        zeta=zeta,
        omega_n=natural_frequency(gains),
        damping=_damping(zeta),
        settling_distance=settling_distance(gains, 1.0, 0.0, fraction),
    )
