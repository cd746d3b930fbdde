"""Spiral obstacle avoidance (thesis §4.2, seed 000 lines 3808-4240; results 4240-4385).

A pure law: numpy and math only. The functions implement the equations one by one so that
the tests can check them against the thesis; :class:`SpiralAvoidance` strings them together
with the little state an avoidance needs (sense of motion, spiral anchor, PID integrators,
the xi filter).

Conventions (derived; the defining passage of the thesis was lost in extraction)
------------------------------------------------------------------------------------
Frame F_E (lines 3875-3917): origin at the spiral centre point (SCP), x_E towards the
current target, z_E skywards, y_E completing a right-handed frame. In F_E the robot's axle
centre M has polar coordinates (r_c, beta_c): ``r_c = |SCP M|`` and ``beta_c = (x_E, N)``
with ``N`` the vector SCP -> M, wrapped to [0, 2 pi). The target lies on x_E, so
``beta_target = 0`` and ``r_target = |SCP target|`` (eq. 4.2: the thesis extracts r_target
as the x coordinate of oMt; with x_E through the target its y coordinate is zero).

The sense of motion is ``SOM = +1`` (counter-clockwise about z_E, beta_c increasing) or
``-1`` (clockwise). The angle ``alpha_c`` is the angle from the robot heading to the line
of sight M -> SCP, counted in the sense of motion::

    alpha_c = wrap(SOM * (psi + pi - theta))

with psi the direction of N and theta the heading. With ``alpha_c = pi/2`` the robot moves
tangentially in the sense of motion. The unicycle kinematics in these coordinates are::

    dr_c/dt = -nu cos(alpha_c)            d(phi)/dt = nu sin(alpha_c) / r_c

where ``phi = SOM * (beta_c - beta_0)`` is the angle swept since the spiral was anchored.
A path with constant ``alpha_c = alpha_d`` therefore obeys ``dr/dphi = -r cot(alpha_d)``:
``r = r_0 exp(-cot(alpha_d) phi) = r_0 exp(cot(alpha_d) SOM (beta_0 - beta_c))``, which is
eq. 4.1 (the thesis writes the counter-clockwise case). It reproduces the thesis's three
cases (lines 3808-3830): alpha_d = pi/2 a circle, alpha_d > pi/2 an outward spiral,
alpha_d < pi/2 an inward one. beta_0 (and so phi) is kept as a swept angle, accumulated
tick by tick, so that a moving SCP or a rotating x_E does not corrupt the progress.

The spiral centre point
-----------------------
The passage defining the SCP was lost. The thesis puts it "on the obstacle", computed from
the laser cluster, and recomputes it when the robot is trapped (the wall-like second
obstacle of figure 4.18 needed two recomputations, C.2 and C.3). Our choice:

* compact obstacles (a fitted circle, or a blob described by its enclosing circle): the
  SCP is the centre. Circling it at r_0 keeps a constant clearance r_0 - R;
* line obstacles (walls): the point of the segment nearest to the robot when the spiral is
  anchored.

The SCP is stored relative to the obstacle's tracked position, so it moves with a moving
obstacle. It is recomputed (the spiral re-anchored at the current robot position, with the
original clearance) when the tracked obstacle changes identity or when the robot's distance
to the obstacle's surface is below ``recompute_fraction`` of the clearance the spiral was
first anchored with: the spiral does not fit the obstacle (a wall longer than r_0). A
recomputation needs the robot to have swept ``recompute_sweep`` about the current SCP, so
that it does not repeat every period while the re-anchored spiral pushes the robot back
out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from executive.core.frames import FloatArray, Pose2, wrap_angle

__all__ = [
    "CCW",
    "CW",
    "Pid",
    "SpiralAvoidance",
    "SpiralObstacle",
    "SpiralOutput",
    "SpiralParams",
    "alpha_d_dynamic",
    "alpha_d_target_reaching",
    "angular_velocity",
    "beta_passed",
    "frame_e_polar",
    "lambda_weight",
    "line_of_sight_rate",
    "linear_velocity",
    "normalised_xi",
    "path_blocked",
    "release_condition",
    "sense_of_motion",
    "should_engage",
    "spiral_angle",
    "spiral_centre_point",
    "spiral_radius",
    "target_side_som",
]

CCW = 1
"""Sense of motion: counter-clockwise about z_E (beta_c increasing)."""
CW = -1
"""Sense of motion: clockwise about z_E (beta_c decreasing)."""

TWO_PI = 2.0 * math.pi


# -- obstacle geometry ---------------------------------------------------------------------------
def _closest_on_segment(a: FloatArray, b: FloatArray, p: FloatArray) -> FloatArray:
    ab = b - a
    denom = float(ab @ ab)
    t = 0.0 if denom == 0.0 else min(1.0, max(0.0, float((p - a) @ ab) / denom))
    return a + t * ab


def _cross(u: FloatArray, v: FloatArray) -> float:
    return float(u[0] * v[1] - u[1] * v[0])


def _segments_intersect(a: FloatArray, b: FloatArray, c: FloatArray, d: FloatArray) -> bool:
    d1, d2 = _cross(b - a, c - a), _cross(b - a, d - a)
    d3, d4 = _cross(d - c, a - c), _cross(d - c, b - c)
    return d1 * d2 < 0.0 and d3 * d4 < 0.0


def _segment_distance(a: FloatArray, b: FloatArray, c: FloatArray, d: FloatArray) -> float:
    """Distance between segments ab and cd."""
    if _segments_intersect(a, b, c, d):
        return 0.0
    return min(
        float(np.linalg.norm(p - _closest_on_segment(s0, s1, p)))
        for p, s0, s1 in ((a, c, d), (b, c, d), (c, a, b), (d, a, b))
    )


@dataclass(frozen=True, slots=True)
class SpiralObstacle:
    """The obstacle being avoided, in the frame of the robot pose (SI units).

    ``position`` is the tracked point (circle centre or cluster centroid), ``velocity`` its
    ground velocity, ``size`` the radius of a circle enclosing it. ``shape`` optionally holds
    the fitted shape in the same frame: ``(cx, cy, r)`` for a circle, ``(x0, y0, x1, y1)``
    for a line segment, ``()`` for a blob (then the enclosing circle is used). ``ident`` is
    the tracker's id; a change of id re-anchors the spiral.
    """

    position: tuple[float, float]
    velocity: tuple[float, float] = (0.0, 0.0)
    size: float = 0.0
    shape: tuple[float, ...] = ()
    ident: int | None = None

    def __post_init__(self) -> None:
        if len(self.shape) not in (0, 3, 4):
            raise ValueError("shape is (cx, cy, r), (x0, y0, x1, y1) or ()")
        if not self.size >= 0.0:
            raise ValueError("size must be >= 0")

    @property
    def is_line(self) -> bool:
        return len(self.shape) == 4

    @property
    def speed(self) -> float:
        return math.hypot(*self.velocity)

    @property
    def centre(self) -> FloatArray:
        """Centre of the compact shape (circle centre, else the tracked position)."""
        if len(self.shape) == 3:
            return np.array(self.shape[:2], dtype=float)
        return np.array(self.position, dtype=float)

    @property
    def radius(self) -> float:
        """Radius of the compact shape (fitted circle, else the enclosing circle)."""
        return float(self.shape[2]) if len(self.shape) == 3 else float(self.size)

    def segment(self) -> tuple[FloatArray, FloatArray]:
        """End points of a line obstacle."""
        if not self.is_line:
            raise ValueError("not a line obstacle")
        return np.array(self.shape[:2], dtype=float), np.array(self.shape[2:], dtype=float)

    def surface_distance(self, point: FloatArray) -> float:
        """Distance from ``point`` to the obstacle's surface (negative inside a circle)."""
        p = np.asarray(point, dtype=float)
        if self.is_line:
            a, b = self.segment()
            return float(np.linalg.norm(p - _closest_on_segment(a, b, p)))
        return float(np.linalg.norm(p - self.centre)) - self.radius

    def path_distance(self, start: FloatArray, end: FloatArray) -> float:
        """Distance from the straight segment start -> end to the obstacle's surface."""
        s, e = np.asarray(start, dtype=float), np.asarray(end, dtype=float)
        if self.is_line:
            a, b = self.segment()
            return _segment_distance(s, e, a, b)
        c = self.centre
        return float(np.linalg.norm(c - _closest_on_segment(s, e, c))) - self.radius


def spiral_centre_point(obstacle: SpiralObstacle, robot_xy: FloatArray) -> tuple[FloatArray, float]:
    """The SCP for the robot at ``robot_xy`` and its depth below the obstacle's surface.

    Compact obstacle: the centre, depth R (the radius). Line: the nearest point of the
    segment, depth 0. See the module docstring for why (the thesis's definition was lost).
    """
    if obstacle.is_line:
        a, b = obstacle.segment()
        return _closest_on_segment(a, b, np.asarray(robot_xy, dtype=float)), 0.0
    return obstacle.centre, obstacle.radius


def frame_e_polar(
    point_xy: FloatArray, scp: FloatArray, target_xy: FloatArray
) -> tuple[float, float]:
    """Polar coordinates (r, beta) of a point in F_E (eq. 4.2, lines 3875-3917).

    x_E points from the SCP to the target, so the target itself is at
    ``(r_target, beta_target = 0)``. ``beta`` is wrapped to [0, 2 pi).
    """
    n = np.asarray(point_xy, dtype=float) - scp
    to_target = np.asarray(target_xy, dtype=float) - scp
    x_e = math.atan2(float(to_target[1]), float(to_target[0]))
    beta = (math.atan2(float(n[1]), float(n[0])) - x_e) % TWO_PI
    return float(np.linalg.norm(n)), beta


def spiral_angle(pose: Pose2, scp: FloatArray, som: int) -> float:
    """alpha_c, the angle from the heading to the line of sight to the SCP (eq. 4.10).

    ``alpha_c = wrap(SOM (psi + pi - theta))`` (module docstring): pi/2 when the robot moves
    tangentially in the sense of motion, above pi/2 when it moves away from the SCP.
    """
    psi = math.atan2(pose.y - float(scp[1]), pose.x - float(scp[0]))
    return wrap_angle(som * (psi + math.pi - pose.theta))


# -- eq. 4.1 and the choice of alpha_d ----------------------------------------------------------
def spiral_radius(r0: float, alpha_d: float, beta0: float, beta_c: float, som: int = CCW) -> float:
    """Eq. 4.1 (lines 3808-3830): ``r_d = r_0 exp(cot(alpha_d) SOM (beta_0 - beta_c))``.

    The thesis states the counter-clockwise case (SOM = +1); the SOM factor makes the same
    spiral run clockwise (derivation in the module docstring). ``alpha_d`` must lie in
    (0, pi): at 0 or pi the "spiral" is a radial line.
    """
    if not 0.0 < alpha_d < math.pi:
        raise ValueError("alpha_d must lie in (0, pi)")
    return r0 * math.exp(som * (beta0 - beta_c) / math.tan(alpha_d))


def alpha_d_target_reaching(
    r0: float, r_target: float, beta0: float, beta_target: float, som: int
) -> float:
    """Eq. 4.5 (lines 3925-3990): the alpha_d whose spiral passes through the target.

    Eq. 4.4 sets ``r_d = r_target`` at ``beta_c = beta_target`` in eq. 4.1::

        r_target = r_0 exp(cot(alpha_d) SOM (beta_0 - beta_target))
        cot(alpha_d) = ln(r_target / r_0) / (SOM (beta_0 - beta_target))

    The angle swept until the target is reached is ``phi_t = SOM (beta_target - beta_0)``
    taken in (0, 2 pi) (the robot moves forward along the spiral), so
    ``cot(alpha_d) = -ln(r_target / r_0) / phi_t``. The extracted eq. 4.5 writes
    ``alpha_d = atan(1 / cot)``, which lands in (-pi/2, pi/2) and is wrong for an outward
    spiral; the inverse cotangent with values in (0, pi) is
    ``alpha_d = pi/2 - atan(cot(alpha_d))``. Returns pi/2 (a circle) when the target lies on
    the anchoring ray (phi_t = 0 or 2 pi: no spiral through it).
    """
    phi_t = (som * (beta_target - beta0)) % TWO_PI
    if phi_t < 1e-9 or r0 <= 0.0 or r_target <= 0.0:
        return math.pi / 2.0
    cot = -math.log(r_target / r0) / phi_t
    return math.pi / 2.0 - math.atan(cot)


def normalised_xi(xi: float, xi_min: float, xi_max: float) -> float:
    """Eq. 4.8 (lines 3995-4035, reconstructed): xi normalised to [-1, 1].

    ``xi = d e_r / dt`` (m/s). Speeds below ``xi_min`` (obstacle considered static, about
    10 % of walking speed) give 0; ``xi_max`` (about 300 % of walking speed) and above
    give +-1; linear in between, with the sign of xi::

        xi~ = sign(xi) clip((|xi| - xi_min) / (xi_max - xi_min), 0, 1)
    """
    if not 0.0 <= xi_min < xi_max:
        raise ValueError("need 0 <= xi_min < xi_max")
    magnitude = min(1.0, max(0.0, (abs(xi) - xi_min) / (xi_max - xi_min)))
    return math.copysign(magnitude, xi) if magnitude > 0.0 else 0.0


def alpha_d_dynamic(
    xi_tilde: float,
    alpha_base: float = math.pi / 2.0,
    a: float = 4.0,
    b: float = 3.0,
    max_delta: float = math.pi / 2.0,
    margin: float = math.radians(5.0),
) -> float:
    """Eqs. 4.6-4.7 and Algorithm 4.1 (lines 3995-4050, reconstructed): alpha_d from xi~.

    ``Delta alpha_d = clip((a / pi) atan(b xi~), -max_delta, max_delta)`` (eq. 4.7) and
    ``alpha_d = alpha_base - Delta alpha_d`` (eq. 4.6). With the thesis's a = 4, b = 3,
    ``(4 / pi) atan(3) = 1.59 > pi/2``, so the extrema xi~ = -+1 reach alpha_d = pi and 0
    as stated; ``max_delta`` is line 4 of Algorithm 4.1 ("adjust Delta alpha_d according to
    your robot's limitations", e.g. a narrower field of view). The sign: xi~ < 0 (e_r
    falling, the obstacle closing in) increases alpha_d above 90 deg, an outward spiral
    (figure 4.9). The result is kept within [margin, pi - margin] so that eq. 4.1 stays
    finite.
    """
    delta = min(max_delta, max(-max_delta, (a / math.pi) * math.atan(b * xi_tilde)))
    return min(math.pi - margin, max(margin, alpha_base - delta))


# -- eq. 4.12-4.16 ---------------------------------------------------------------------------------
def linear_velocity(e_alpha: float, nu_max: float) -> float:
    """Eq. 4.12 (lines 4075-4100): ``nu_OA = nu_OAmax / exp|e_alpha|``."""
    return nu_max * math.exp(-abs(e_alpha))


def lambda_weight(e_alpha: float, lam_min: float, lam_max: float, width: float) -> float:
    """lambda of eq. 4.14 (figure 4.12 lost; lines 4136-4160): grows as |e_alpha| shrinks.

    The thesis only states that lambda is strictly positive and increases when |e_alpha|
    decreases, raising the weight of the distance task. We use
    ``lambda = lam_min + (lam_max - lam_min) exp(-|e_alpha| / width)``: lam_max at
    e_alpha = 0, decreasing towards lam_min > 0 for large errors.
    """
    return lam_min + (lam_max - lam_min) * math.exp(-abs(e_alpha) / width)


def angular_velocity(som: int, psi: float, upsilon: float, lam: float) -> float:
    """Eq. 4.14 (lines 4115-4136): ``omega_OA = SOM (Psi(e_alpha) + lambda Upsilon(e_r))``."""
    return som * (psi + lam * upsilon)


@dataclass(slots=True)
class Pid:
    """A PID on one error (eqs. 4.15, 4.16): ``Kp e + Ki int_t0^tc e dt + Kd de/dt``.

    The integral starts at the trigger instant t0 (:meth:`reset`) and is clamped to
    ``+- integral_limit`` (anti-windup). The derivative is the backward difference, zero on
    the first call after a reset.
    """

    kp: float
    ki: float
    kd: float
    integral_limit: float
    integral: float = 0.0
    previous: float | None = None

    def reset(self) -> None:
        self.integral = 0.0
        self.previous = None

    def step(self, error: float, dt: float) -> float:
        lim = self.integral_limit
        self.integral = min(lim, max(-lim, self.integral + error * dt))
        derivative = 0.0 if self.previous is None or dt <= 0.0 else (error - self.previous) / dt
        self.previous = error
        return self.kp * error + self.ki * self.integral + self.kd * derivative


# -- sense of motion (Algorithm 4.2) ---------------------------------------------------------------
def target_side_som(
    robot_xy: FloatArray, heading: float, obstacle_xy: FloatArray, target_xy: FloatArray
) -> int:
    """The static SOM choice of [Futterlieb et al., 2014] (figure 4.13 lost; lines 4150-4165).

    Pass the obstacle on the side where the target lies, which reduces the turn at the start
    of the avoidance: a target to the left of the line robot -> obstacle means passing on
    the obstacle's left, i.e. the obstacle on the robot's right: clockwise about z_E. A
    target on the line: the side the robot is already heading to; dead ahead: CCW.
    """
    r = np.asarray(robot_xy, dtype=float)
    to_obstacle = np.asarray(obstacle_xy, dtype=float) - r
    side = _cross(to_obstacle, np.asarray(target_xy, dtype=float) - r)
    if abs(side) < 1e-9 * max(1.0, float(to_obstacle @ to_obstacle)):
        side = _cross(to_obstacle, np.array([math.cos(heading), math.sin(heading)]))
    return CW if side > 0.0 else CCW


def line_of_sight_rate(robot_xy: FloatArray, obstacle: SpiralObstacle) -> float:
    """beta_c dot due to the obstacle's own motion (rad/s), Algorithm 4.2's input.

    ``cross(d, v_obstacle) / |d|^2`` with d = obstacle - robot: negative when the obstacle
    passes from the robot's left to its right (lines 4166-4170). Only the obstacle's
    velocity is used: Algorithm 4.2 reacts to "the sense of the obstacle movement", and the
    robot's own forward motion would otherwise make every static obstacle off the axis look
    like a moving one.
    """
    d = obstacle.centre - np.asarray(robot_xy, dtype=float)
    dd = float(d @ d)
    if dd == 0.0:
        return 0.0
    return _cross(d, np.asarray(obstacle.velocity, dtype=float)) / dd


def sense_of_motion(beta_c_dot: float, threshold: float, static_som: int) -> int:
    """Algorithm 4.2 (lines 4166-4180): the decision tree for the SOM.

    ``|beta_c dot| < threshold``: the static choice (:func:`target_side_som`); otherwise
    beta_c dot > 0 (obstacle moving right -> left): CCW, else CW.
    """
    if abs(beta_c_dot) < threshold:
        return static_som
    return CCW if beta_c_dot > 0.0 else CW


# -- guards (lines 4180-4225, figure 4.15) ---------------------------------------------------------
def path_blocked(
    robot_xy: FloatArray, target_xy: FloatArray, obstacle: SpiralObstacle, margin: float
) -> bool:
    """Whether the obstacle lies between the robot and the target.

    True when the straight segment robot -> target comes within ``margin`` (the robot's
    half-width plus a safety distance) of the obstacle's surface. This is the "check on the
    distance to the target" of lines 4214-4225: an obstacle beyond the target (farther than
    the target) or off to the side is not in the way, however close it is.
    """
    return obstacle.path_distance(robot_xy, target_xy) < margin


def should_engage(
    robot_xy: FloatArray,
    target_xy: FloatArray,
    obstacle: SpiralObstacle,
    r_trigger: float,
    margin: float,
) -> bool:
    """Engage guard: the obstacle is closer than r_OA-trigger AND it blocks the path.

    The thesis first engaged on the distance alone (lines 4190-4196) and found the re-trigger
    loop of figure 4.15; adding the path check makes engage and release exclusive (release
    requires a clear path), so a released robot is never re-captured by the same geometry.
    """
    clearance = obstacle.surface_distance(robot_xy)
    return clearance < r_trigger and path_blocked(robot_xy, target_xy, obstacle, margin)


def beta_passed(beta_c: float) -> bool:
    """beta_c past pi/2 (CW) or 3 pi/2 (CCW) (lines 1515-1520, 4197-4204).

    A robot starting behind the obstacle (beta_c near pi) reaches pi/2 first going CW and
    3 pi/2 first going CCW; both thresholds bound the same half plane, the robot being level
    with the SCP or nearer the target: ``cos(beta_c) >= 0``. (One passage reads 3/4 pi; the
    other two read 3/2 pi, the only value symmetric with pi/2.)
    """
    return math.cos(beta_c) >= -1e-12


def release_condition(
    beta_c: float,
    robot_xy: FloatArray,
    target_xy: FloatArray,
    obstacle: SpiralObstacle,
    margin: float,
) -> tuple[bool, str]:
    """Release guard (lines 4197-4225, figure 4.15): beta_c passed AND the path is clear.

    Returns (released, reason); the reason names what still holds the robot.
    """
    if not beta_passed(beta_c):
        return False, "beta_c not past the release angle"
    if path_blocked(robot_xy, target_xy, obstacle, margin):
        return False, "obstacle still between robot and target"
    return True, "beta_c past the release angle and path to target clear"


# -- the stateful law ------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class SpiralParams:
    """Tuning of :class:`SpiralAvoidance` (SI units).

    Thesis values: r_OA-trigger = 2.5 m (lines 4276, 4340), nu_OAmax about 0.4 m/s (the
    avoidance speed of figure 4.19), xi_min = 10 % and xi_max = 300 % of walking speed
    (1.4 m/s; lines 4000-4012), a = 4, b = 3 (line 4030), alpha_d static = pi/2 (eq. 4.3).
    The gains are ours (the thesis gives none); they place the linearised circle-following
    poles ``s^2 + kp_alpha s + nu lambda kp_r`` near critical damping at nu_max.
    """

    nu_max: float = 0.4
    """nu_OAmax of eq. 4.12 (m/s)."""
    omega_max: float = 1.0
    """Platform yaw-rate limit (rad/s); omega_OA is clamped to it."""
    r_trigger: float = 2.5
    """r_OA-trigger (m), distance to the obstacle's surface that engages the avoidance."""
    path_margin: float = 0.8
    """Half-width of the corridor robot -> target used by the engage and release guards."""
    min_clearance: float = 0.8
    """Floor on the desired distance to the obstacle's surface (r_d >= depth + this)."""
    recompute_fraction: float = 0.6
    """Re-anchor the spiral when the clearance is below this x the first one."""
    recompute_sweep: float = math.radians(30.0)
    """Angle to sweep about an SCP before it may be recomputed (rad)."""
    alpha_static: float = math.pi / 2.0
    """eq. 4.3."""
    target_reaching: bool = True
    """Use eq. 4.5 when the target is close (and the caller says the scene is sparse)."""
    target_reaching_distance: float = 6.0
    """Largest SCP-target distance for which eq. 4.5 is used (m)."""
    dynamic_alpha: bool = True
    """Deform the spiral from xi (eqs. 4.6-4.8)."""
    xi_min: float = 0.14
    xi_max: float = 4.2
    xi_time_constant: float = 0.3
    """Low-pass filter of xi (s)."""
    a: float = 4.0
    b: float = 3.0
    max_delta_alpha: float = math.pi / 2.0
    alpha_margin: float = math.radians(5.0)
    som_threshold: float = 0.05
    """|beta_c dot| (rad/s) below which Algorithm 4.2 uses the static SOM choice."""
    kp_alpha: float = 1.2
    ki_alpha: float = 0.05
    kd_alpha: float = 0.05
    kp_r: float = 0.5
    ki_r: float = 0.02
    kd_r: float = 0.2
    integral_limit: float = 2.0
    lambda_min: float = 0.2
    lambda_max: float = 2.0
    lambda_width: float = 0.3
    """Width (rad) of the lambda bell."""
    feedforward: bool = True
    """Add the line-of-sight rate SOM nu sin(alpha_c) / r_c to omega (see the class doc)."""

    def __post_init__(self) -> None:
        for name in ("nu_max", "omega_max", "r_trigger", "xi_time_constant", "lambda_width"):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"SpiralParams.{name} must be > 0")
        if not 0.0 < self.lambda_min <= self.lambda_max:
            raise ValueError("need 0 < lambda_min <= lambda_max")
        if not 0.0 < self.recompute_fraction < 1.0:
            raise ValueError("recompute_fraction must lie in (0, 1)")
        if not 0.0 < self.alpha_margin < self.alpha_static < math.pi - self.alpha_margin:
            raise ValueError("alpha_static must lie inside (alpha_margin, pi - alpha_margin)")


@dataclass(frozen=True, slots=True)
class SpiralOutput:
    """One command of :class:`SpiralAvoidance` and the quantities behind it."""

    v: float
    omega: float
    alpha_d: float
    xi: float
    beta_c: float
    e_alpha: float
    e_r: float
    released: bool
    reason: str
    som: int
    r_c: float
    r_d: float
    recomputed: bool


@dataclass(slots=True)
class _Anchor:
    scp_offset: FloatArray  # SCP - obstacle.position
    depth: float
    r0: float
    clearance: float
    ident: int | None
    guard: float  # recompute when the clearance is below this (after some sweep)
    psi_last: float
    phi: float = 0.0


@dataclass(slots=True)
class SpiralAvoidance:
    """The spiral avoidance controller (eqs. 4.1-4.16, Algorithms 4.1 and 4.2).

    Call :meth:`reset` when the avoidance is triggered (t0 of eqs. 4.15-4.16), then
    :meth:`command` every period. The first command anchors the spiral: SCP, SOM
    (Algorithm 4.2), ``r_0 = max(r_c, depth + min_clearance)`` and beta_0 = beta_c.

    Each period: alpha_d = alpha_static or eq. 4.5, deformed by xi (eqs. 4.6-4.8);
    r_d from eq. 4.1 (floored at depth + min_clearance); e_alpha, e_r (eqs. 4.10, 4.11);
    nu (eq. 4.12); omega (eq. 4.14) clamped to omega_max; the release guard.

    xi is ``d e_r / dt`` with r_d evaluated at the previous alpha_d at both ends of the
    period, then low-pass filtered: a change of alpha_d itself moves r_d, and counting that
    jump as obstacle motion would feed alpha_d back on itself.

    Feed-forward (derived): along the spiral ``d alpha_c / dt = SOM (d beta_c / dt) - omega``
    in the counter-clockwise case, with ``d beta_c / dt = SOM nu sin(alpha_c) / r_c`` the
    rotation of the line of sight. Eq. 4.14 leaves its compensation to the integral terms;
    with ``feedforward`` it is added explicitly, ``omega = SOM (nu sin(alpha_c) / r_c +
    Psi + lambda Upsilon)``, so that the PIDs only correct errors: linearised about the
    circle, ``e_r'' + kp_alpha e_r' + nu lambda kp_r e_r = 0``.
    """

    params: SpiralParams = field(default_factory=SpiralParams)
    _anchor: _Anchor | None = field(init=False, default=None)
    _som: int = field(init=False, default=CCW)
    _pid_alpha: Pid = field(init=False)
    _pid_r: Pid = field(init=False)
    _xi: float = field(init=False, default=0.0)
    _alpha_d_last: float | None = field(init=False, default=None)
    _e_r_last: float | None = field(init=False, default=None)
    _recomputations: int = field(init=False, default=0)

    def __post_init__(self) -> None:
        p = self.params
        self._pid_alpha = Pid(p.kp_alpha, p.ki_alpha, p.kd_alpha, p.integral_limit)
        self._pid_r = Pid(p.kp_r, p.ki_r, p.kd_r, p.integral_limit)

    @property
    def som(self) -> int:
        return self._som

    @property
    def recomputations(self) -> int:
        """How many times the SCP was recomputed since the last reset."""
        return self._recomputations

    @property
    def scp(self) -> FloatArray | None:
        """The SCP of the last command relative to the obstacle position, or None."""
        return None if self._anchor is None else self._anchor.scp_offset.copy()

    def reset(self) -> None:
        """Forget the spiral: the next command engages afresh (t0 of eq. 4.15)."""
        self._anchor = None
        self._pid_alpha.reset()
        self._pid_r.reset()
        self._xi = 0.0
        self._alpha_d_last = None
        self._e_r_last = None
        self._recomputations = 0

    def _anchor_at(
        self, robot: FloatArray, obstacle: SpiralObstacle, clearance: float | None
    ) -> _Anchor:
        scp, depth = spiral_centre_point(obstacle, robot)
        r_c = float(np.linalg.norm(robot - scp))
        # first anchoring: the distance at the trigger instant; a recomputation keeps the
        # clearance the avoidance started with
        r0 = max(r_c, depth + self.params.min_clearance) if clearance is None else depth + clearance
        psi = math.atan2(float(robot[1] - scp[1]), float(robot[0] - scp[0]))
        self._pid_alpha.reset()
        self._pid_r.reset()
        self._alpha_d_last = None
        self._e_r_last = None
        return _Anchor(
            scp - np.asarray(obstacle.position, dtype=float),
            depth,
            r0,
            r0 - depth,
            obstacle.ident,
            self.params.recompute_fraction * (r0 - depth),
            psi,
        )

    def command(
        self,
        robot_pose: Pose2,
        target: FloatArray,
        obstacle: SpiralObstacle,
        dt: float,
        sparse: bool = True,
    ) -> SpiralOutput:
        """One avoidance command for the robot at ``robot_pose`` (same frame as ``target``
        and ``obstacle``); ``sparse``: few obstacles around, eq. 4.5 allowed."""
        p = self.params
        robot = np.array([robot_pose.x, robot_pose.y])
        goal = np.asarray(target, dtype=float)
        recomputed = False
        clearance = obstacle.surface_distance(robot)
        if self._anchor is None:
            self._anchor = self._anchor_at(robot, obstacle, None)
            static = target_side_som(robot, robot_pose.theta, obstacle.centre, goal)
            self._som = sense_of_motion(
                line_of_sight_rate(robot, obstacle), p.som_threshold, static
            )
        elif obstacle.ident != self._anchor.ident or (
            clearance < self._anchor.guard and abs(self._anchor.phi) >= p.recompute_sweep
        ):
            self._anchor = self._anchor_at(robot, obstacle, self._anchor.clearance)
            self._recomputations += 1
            recomputed = True
        anchor = self._anchor
        som = self._som

        scp = np.asarray(obstacle.position, dtype=float) + anchor.scp_offset
        psi = math.atan2(float(robot[1] - scp[1]), float(robot[0] - scp[0]))
        anchor.phi += som * wrap_angle(psi - anchor.psi_last)
        anchor.psi_last = psi
        r_c, beta_c = frame_e_polar(robot, scp, goal)
        r_target, _ = frame_e_polar(goal, scp, goal)
        beta0 = beta_c - som * anchor.phi  # eq. 4.1's beta_0 in the current F_E

        alpha_base = p.alpha_static
        if p.target_reaching and sparse and r_target <= p.target_reaching_distance:
            alpha_base = alpha_d_target_reaching(anchor.r0, r_target, beta0, 0.0, som)
            alpha_base = min(math.pi - p.alpha_margin, max(p.alpha_margin, alpha_base))
        floor = anchor.depth + p.min_clearance

        def desired_radius(alpha: float) -> float:
            return max(floor, spiral_radius(anchor.r0, alpha, beta0, beta_c, som))

        # xi: d e_r / dt at a fixed alpha_d (the previous one), filtered (eq. 4.8's input)
        if self._alpha_d_last is not None and self._e_r_last is not None and dt > 0.0:
            raw = (r_c - desired_radius(self._alpha_d_last) - self._e_r_last) / dt
            self._xi += dt / (p.xi_time_constant + dt) * (raw - self._xi)
        alpha_d = alpha_base
        if p.dynamic_alpha:
            xi_tilde = normalised_xi(self._xi, p.xi_min, p.xi_max)
            alpha_d = alpha_d_dynamic(
                xi_tilde, alpha_base, p.a, p.b, p.max_delta_alpha, p.alpha_margin
            )
        r_d = desired_radius(alpha_d)

        alpha_c = spiral_angle(robot_pose, scp, som)
        e_alpha = wrap_angle(alpha_c - alpha_d)  # eq. 4.10
        e_r = r_c - r_d  # eq. 4.11
        self._alpha_d_last, self._e_r_last = alpha_d, e_r

        v = linear_velocity(e_alpha, p.nu_max)
        lam = lambda_weight(e_alpha, p.lambda_min, p.lambda_max, p.lambda_width)
        omega = angular_velocity(
            som, self._pid_alpha.step(e_alpha, dt), self._pid_r.step(e_r, dt), lam
        )
        if p.feedforward and r_c > 0.0:
            omega += som * v * math.sin(alpha_c) / r_c
        omega = min(p.omega_max, max(-p.omega_max, omega))

        released, reason = release_condition(beta_c, robot, goal, obstacle, p.path_margin)
        return SpiralOutput(
            v=v,
            omega=omega,
            alpha_d=alpha_d,
            xi=self._xi,
            beta_c=beta_c,
            e_alpha=e_alpha,
            e_r=e_r,
            released=released,
            reason=reason,
            som=som,
            r_c=r_c,
            r_d=r_d,
            recomputed=recomputed,
        )
