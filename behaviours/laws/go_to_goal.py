"""Go-to-goal control law (thesis §2.2.7: eqs. 2.4 and 2.5, Algorithm 2.4).

A pure law: no py_trees, no clock, no I/O. :class:`GoToGoal` keeps only the state that
hysteresis needs (current phase, driving direction, manoeuvre zone, last command) and
turns a pose, a goal and the current speed into a clamped ``(v, omega)`` command.

Phases (``GoToGoalOutput.phase``)
---------------------------------
``align``
    Turn in place towards the goal point (align-first). Coming from a drive, the robot
    first brakes to a halt in a straight line, then turns (thesis: "reduce the speed of
    the robot until complete halt and start turning it towards the target").
``manoeuvre-forward`` / ``manoeuvre-backward``
    Modified align-first (Algorithm 2.4): turn towards the goal while stepping forward or
    backward inside a turning zone instead of turning on the spot.
``drive`` / ``reverse``
    Move towards the goal point with a trapezoidal speed profile, steering with eq. 2.4;
    ``reverse`` drives backwards (eq. 2.5).
``final-turn``
    Inside the position tolerance: come to a halt, then turn in place to the goal heading.
``reached``
    Both tolerances hold (the goal heading only if one was given); the command is a stop.
    Leaving needs a margin: the approach restarts beyond ``reapproach_factor`` x the
    position tolerance, the final turn beyond ``reheading_factor`` x the heading
    tolerance. A new goal restarts the approach; a goal that only moved by less than half
    the tolerances (an aircraft-frame goal re-resolved through a placement estimate that
    the pose filter nudges on every GPS fix or registration) is the same goal.

Driving towards the goal point (rather than stopping at the edge of the tolerance disc)
and braking on the way leaves the whole tolerance as margin for slip and noise.

Eq. 2.4 — angular velocity
--------------------------
The extracted text reads ``omega = atan2(dy, dx)`` with ``dx = cos(dtheta)``,
``dy = sin(dtheta)``, ``dtheta = theta_d - theta_c`` (theta_d the direction of the target,
theta_c the robot heading, both in the airport frame). ``atan2(sin x, cos x)`` is ``x``
wrapped to (-pi, pi], so eq. 2.4 is a proportional law on the *wrapped* heading error with
unit gain; the thesis uses atan2 precisely "to keep the robot control angular values within
the interval [-pi, pi]". We add a gain and the platform limit:

    omega = clamp(k_omega * atan2(sin dtheta, cos dtheta), -omega_max, omega_max)

(``k_omega = 1`` and no clamp reproduces the thesis.) During the approach theta_d is the
bearing of the goal point, in the final turn it is the goal heading. Near dtheta = +-pi the
sign of the wrapped error is ill-conditioned; once a turn has started its direction is kept
while ``|dtheta| > pi - direction_hysteresis`` so that noise cannot make the robot
hesitate between left and right.

Eq. 2.5 — reverse driving
-------------------------
The garbled text gives ``theta <- (-1) * (pi - theta)`` when the target is behind, "that
is when [its direction relative to the robot] is greater than pi/2 or below -pi/2".
``-(pi - theta) = theta - pi = theta + pi (mod 2 pi)``: the substituted heading is that of
the robot's *rear*. The same law (eq. 2.4, the trapezoid) is then applied to the rear
heading and the linear velocity is negated. We reverse only when ``allow_reverse``, the goal
is behind (``|bearing error| > pi/2``) and within ``reverse_max_distance`` (further goals
are worth turning around for). With a goal heading the rotation still owed at the goal is
taken into account: reversing is chosen only if it does not increase the total rotation
(turn now + final turn). Once chosen, the direction only changes with a margin of
``direction_hysteresis`` and only while aligning (never in the middle of a drive).

Acceptance angle (Figure 2.14) and hysteresis
---------------------------------------------
The thesis: a heading error above an acceptable angle stops the robot and makes it turn;
"this acceptable angle is dependent on the distance towards the target. The closer the
target, the more narrow that range"; and once aligning "the acceptable range is
decreased ... much like in a hysteresis". Far from the goal a few degrees of heading error
are corrected by the steering long before arrival, so stopping for them wastes time; near
the goal there is no room left to correct, so the robot must already point at it. We
interpolate linearly in the distance d::

    alpha(d) = acceptance_near                                   d <= acceptance_near_distance
             = acceptance_far                                    d >= acceptance_far_distance
             = linear in between

Align -> drive when ``|e| <= alpha(d)``; drive -> align only when ``|e| > alpha(d) +
hysteresis`` *and* the straight line would miss the goal by more than
``lateral_fraction * position_tolerance`` (``|d sin e|``: close to the goal the bearing
error grows by itself as the robot passes the goal, which is no reason to stop). In the
words of Algorithm 2.4: threshold = alpha + hysteresis, safety = hysteresis. The
drive -> align condition must also hold for ``realign_delay`` seconds, so that a single
noisy pose (the bearing of a goal 0.3 m away moves by degrees with centimetres of
localisation noise) does not stop the robot.

Trapezoidal speed profile
-------------------------
The speed ceiling is ``min(max_speed, sqrt(2 b d_x))`` with ``b = braking_fraction *
max_acceleration`` and ``d_x = d cos e`` the distance still to go along the robot's
(effective) heading, so the robot stops at its closest approach to the goal point; the
command then moves towards the ceiling by at most ``max_acceleration * dt`` per call
(accelerate, cruise, decelerate). Within ``final_approach_distance`` the ceiling is also
``final_approach_speed``, joined by the same braking parabola. ``braking_fraction < 1``
leaves a margin so that braking never needs the full limit. In simultaneous mode the
ceiling is multiplied by ``max(0, cos e)``.

Orbit guard. With ``omega = k e`` the bearing error obeys ``de/dt = -omega + v sin(e) / d``;
when ``v / d`` is large (close to the goal) the robot would orbit the goal instead of
closing on it. Whenever the straight line would miss the goal by more than the lateral
allowance, the speed is limited to ``orbit_margin * |omega| * d / |sin e|`` (blended in
over the lateral band), which keeps ``|e|`` decreasing. The lateral miss ``d sin e`` itself
only shrinks under the steering (driving straight does not change it), so the goal is
reached without re-alignment chatter.

Algorithm 2.4 — modified align-first
------------------------------------
The thesis (a skid-steer platform wears its tyres and shakes when turning on the spot)
replaces the turn in place by K-turn-like manoeuvres: "a zone is created in which the
movement is still considered to be turn in place"; the robot keeps its reference point in
that zone; while the angle to the target gamma is above the threshold it turns towards the
target and moves forward if ``|gamma| <= 90 deg``, backward otherwise, "until boundary
reached OR |gamma| <= threshold - safety"; at the boundary the linear movement is
reversed, "up to three steps"; after that "the old align first behaviour" (turn in place)
takes over. Our reading, with the gaps filled:

* the zone is a disc of radius ``turning_zone_radius`` centred where the robot stood when
  the alignment started (after halting);
* gamma is the bearing error in the chosen driving direction (eq. 2.5 applies), the first
  step goes forward if ``|gamma| <= pi/2`` and backward otherwise (thesis) -- except when
  the goal lies inside the turning zone: then the first step is always backward (see
  below); each later step goes the other way; at most ``manoeuvre_steps`` steps, then the
  robot turns in place;
* the step speed follows a small trapezoid: ``manoeuvre_speed``, braking so as to stop on
  the boundary (the distance to the boundary is measured along the motion);
* robustness (not in the thesis): moving forward always makes ``|gamma|`` grow (the goal
  falls behind), moving backward always makes it shrink. Forward steps are therefore limited
  by the orbit guard (``|v| <= orbit_margin * |omega| * d / |sin gamma|``), so ``|gamma|``
  decreases monotonically during every step. Close to the goal even a guarded forward step
  is a poor choice: the turn must make up for what the translation undoes, so the robot
  turns up to twice as far and ends next to the goal with no straight leg left. A goal
  inside the turning zone (e.g. 0.1-0.5 m beside the robot) is therefore handled with a
  backward first step, which turns the goal towards the front faster than the rotation
  alone and lengthens the straight leg: a usable "turn + straight" geometry, never an
  orbit around the goal.
* if the robot, braking now, would stop inside the position tolerance, it does so.

Everything is deterministic; all outputs are clamped to the speed, acceleration and
angular limits.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from enum import StrEnum
from typing import Any

from executive.core.frames import Pose2, wrap_angle
from executive.core.model import Navigation, Platform, TurnMode

__all__ = [
    "ALIGNING",
    "DRIVING",
    "GoToGoal",
    "GoToGoalOutput",
    "GoToGoalParams",
    "Phase",
    "acceptance_angle",
    "eq_2_4_omega",
    "rear_heading",
]


class Phase(StrEnum):
    """What the law is doing (``GoToGoalOutput.phase``)."""

    ALIGN = "align"
    DRIVE = "drive"
    REVERSE = "reverse"
    FINAL_TURN = "final-turn"
    MANOEUVRE_FORWARD = "manoeuvre-forward"
    MANOEUVRE_BACKWARD = "manoeuvre-backward"
    REACHED = "reached"


ALIGNING = frozenset({Phase.ALIGN, Phase.MANOEUVRE_FORWARD, Phase.MANOEUVRE_BACKWARD})
"""Phases that turn the robot towards the goal point (align-first)."""
DRIVING = frozenset({Phase.DRIVE, Phase.REVERSE})
"""Phases that move the robot to the goal point."""


@dataclass(frozen=True)
class GoToGoalParams:
    """Tuning of :class:`GoToGoal`; SI units (m, s, rad).

    Defaults follow the shipped Air-Cobot missions (cruise 1.2 m/s, 1 rad/s, 1 m/s²,
    0.15 m / 5 deg tolerances, align-first); the rest are project choices documented in
    the module docstring. :meth:`from_model` takes the limits from a mission.
    """

    max_speed: float = 1.2
    """Linear speed limit (m/s), forward and backward."""
    max_angular_speed: float = 1.0
    """Angular speed limit (rad/s)."""
    max_acceleration: float = 1.0
    """Linear acceleration limit (m/s²) between consecutive commands."""
    max_angular_acceleration: float | None = None
    """Angular acceleration limit (rad/s²); None: no limit on omega's rate."""
    k_omega: float = 2.0
    """Gain of eq. 2.4 (1/s); the thesis' law is k = 1."""
    position_tolerance: float = 0.15
    heading_tolerance: float = math.radians(5.0)
    turn_mode: TurnMode = TurnMode.ALIGN_FIRST
    allow_reverse: bool = True
    """Eq. 2.5: drive backwards to goals behind the robot."""
    reverse_max_distance: float = 3.0
    """Only goals at most this far are approached in reverse."""
    acceptance_near: float = math.radians(10.0)
    acceptance_far: float = math.radians(30.0)
    acceptance_near_distance: float = 1.0
    acceptance_far_distance: float = 10.0
    hysteresis: float = math.radians(5.0)
    """Extra heading error tolerated while driving before stopping to re-align."""
    realign_delay: float = 0.1
    """Drive -> align only after the heading error stayed too large this long (s)."""
    direction_hysteresis: float = math.radians(10.0)
    """Margin before changing the driving direction or the turning direction near pi."""
    lateral_fraction: float = 0.5
    """Lateral miss allowed for the straight line, as a fraction of the position tolerance."""
    orbit_margin: float = 0.5
    """Orbit guard: translation may undo at most this fraction of the turn rate."""
    braking_fraction: float = 0.8
    """Braking profiles use this fraction of ``max_acceleration``."""
    final_approach_speed: float | None = 0.3
    """Speed cap near the goal (m/s); None: no cap besides the braking parabola."""
    final_approach_distance: float = 0.5
    manoeuvre: bool = True
    """Algorithm 2.4: align with forward/backward steps instead of turning on the spot."""
    turning_zone_radius: float = 0.5
    manoeuvre_speed: float = 0.15
    manoeuvre_steps: int = 3
    halt_speed: float = 0.02
    """|v| at or below which the robot counts as halted (m/s)."""
    stop_distance: float = 0.005
    """Along-track distance below which the approach counts as finished (m)."""
    reapproach_factor: float = 2.0
    """Position hysteresis: after arrival, approach again beyond this x tolerance."""
    reheading_factor: float = 2.0
    """Heading hysteresis: after arrival, turn again beyond this x heading tolerance."""

    def __post_init__(self) -> None:
        positive = (
            "max_speed",
            "max_angular_speed",
            "max_acceleration",
            "k_omega",
            "position_tolerance",
            "heading_tolerance",
            "acceptance_near",
            "acceptance_far",
            "turning_zone_radius",
            "manoeuvre_speed",
            "halt_speed",
        )
        for name in positive:
            if not getattr(self, name) > 0.0:
                raise ValueError(f"GoToGoalParams.{name} must be > 0")
        non_negative = (
            "reverse_max_distance",
            "acceptance_near_distance",
            "hysteresis",
            "realign_delay",
            "direction_hysteresis",
            "stop_distance",
            "final_approach_distance",
        )
        for name in non_negative:
            if not getattr(self, name) >= 0.0:
                raise ValueError(f"GoToGoalParams.{name} must be >= 0")
        if self.max_angular_acceleration is not None and not self.max_angular_acceleration > 0:
            raise ValueError("GoToGoalParams.max_angular_acceleration must be > 0 or None")
        if self.final_approach_speed is not None and not self.final_approach_speed > 0:
            raise ValueError("GoToGoalParams.final_approach_speed must be > 0 or None")
        if not self.acceptance_far_distance > self.acceptance_near_distance:
            raise ValueError("acceptance_far_distance must exceed acceptance_near_distance")
        if not self.acceptance_near + self.hysteresis < math.pi / 2:
            raise ValueError("acceptance_near + hysteresis must stay below 90 deg")
        if not self.acceptance_far + self.hysteresis < math.pi / 2:
            raise ValueError("acceptance_far + hysteresis must stay below 90 deg")
        for name in ("lateral_fraction", "orbit_margin", "braking_fraction"):
            if not 0.0 < getattr(self, name) <= 1.0:
                raise ValueError(f"GoToGoalParams.{name} must be in (0, 1]")
        if self.manoeuvre_steps < 1:
            raise ValueError("GoToGoalParams.manoeuvre_steps must be >= 1")
        if self.reapproach_factor < 1.0 or self.reheading_factor < 1.0:
            raise ValueError("re-approach and re-heading factors must be >= 1")
        object.__setattr__(self, "turn_mode", TurnMode(self.turn_mode))

    @classmethod
    def from_model(
        cls, platform: Platform, navigation: Navigation, **overrides: Any
    ) -> GoToGoalParams:
        """Limits from the platform, speed, tolerances and turn mode from the mission."""
        base = cls(
            max_speed=min(navigation.cruise_speed, platform.max_speed),
            max_angular_speed=platform.max_angular_speed,
            max_acceleration=platform.max_acceleration,
            max_angular_acceleration=platform.max_angular_acceleration,
            position_tolerance=navigation.position_tolerance,
            heading_tolerance=navigation.heading_tolerance,
            turn_mode=navigation.turn_mode,
        )
        known = {f.name for f in fields(cls)}
        unknown = set(overrides) - known
        if unknown:
            raise TypeError(f"unknown GoToGoalParams fields: {sorted(unknown)}")
        return replace(base, **overrides)


@dataclass(frozen=True)
class GoToGoalOutput:
    """One command: ``v`` (m/s, negative backwards), ``omega`` (rad/s, counter-clockwise).

    ``distance`` is the distance to the goal point; ``heading_error`` the error the
    current phase regulates (bearing of the goal relative to the driving direction while
    approaching, goal heading minus heading in the final turn, 0 without goal heading).
    """

    v: float
    omega: float
    phase: Phase
    reached: bool
    distance: float
    heading_error: float


# -- pure formulas ------------------------------------------------------------------------
def _clamp(x: float, lo: float, hi: float) -> float:
    return lo if x < lo else hi if x > hi else x


def eq_2_4_omega(delta: float, gain: float = 1.0, limit: float = math.inf) -> float:
    """Eq. 2.4: ``omega = gain * atan2(sin delta, cos delta)``, clamped to +-limit."""
    return _clamp(gain * math.atan2(math.sin(delta), math.cos(delta)), -limit, limit)


def rear_heading(theta: float) -> float:
    """Eq. 2.5: ``theta <- -(pi - theta)``, the heading of the robot's rear, wrapped."""
    return wrap_angle(-(math.pi - theta))


def acceptance_angle(params: GoToGoalParams, distance: float) -> float:
    """Acceptable bearing error at ``distance``: narrow near the goal, wide far from it."""
    p = params
    span = p.acceptance_far_distance - p.acceptance_near_distance
    t = _clamp((distance - p.acceptance_near_distance) / span, 0.0, 1.0)
    return p.acceptance_near + t * (p.acceptance_far - p.acceptance_near)


def _sign(x: float) -> int:
    return 1 if x > 0 else -1 if x < 0 else 0


# -- the law ------------------------------------------------------------------------------
_APPROACH = "approach"
_FINAL = "final"
_REACHED = "reached"

_ALIGN = "align"
_MANOEUVRE = "manoeuvre"
_DRIVE = "drive"


@dataclass
class _Manoeuvre:
    """Algorithm 2.4 state: zone centre, current step direction (+1 forward in the
    driving direction), number of steps started."""

    cx: float
    cy: float
    step: int
    steps: int


class GoToGoal:
    """Go-to-goal law with explicit state (hysteresis, direction, manoeuvre zone).

    Call :meth:`command` once per control period. A different goal (or goal-heading flag)
    restarts the approach but keeps the last command for the acceleration limits; call
    :meth:`reset` when the robot was driven by something else in between.
    """

    def __init__(self, params: GoToGoalParams | None = None) -> None:
        self.params = params if params is not None else GoToGoalParams()
        self.reset()

    # -- state --------------------------------------------------------------------------
    def reset(self) -> None:
        """Forget everything, including the last command (assumed to be a stop)."""
        self._v_last = 0.0
        self._omega_last = 0.0
        self._goal_key: tuple[float, float, float | None] | None = None
        self._restart()

    def new_goal(self) -> None:
        """Start a fresh approach at the next :meth:`command` whatever its goal, keeping
        the last command for the acceleration limits: a follower moving on to its next
        waypoint, however close to the last one (within half the position tolerance
        :meth:`command` takes a goal for the one it was already approaching, or had
        reached)."""
        self._goal_key = None

    def _restart(self) -> None:
        self._mode = _APPROACH
        self._stage = _ALIGN
        self._direction = 0  # 0 = not chosen yet, +1 forward, -1 reverse (eq. 2.5)
        self._turn_sign = 0
        self._manoeuvre: _Manoeuvre | None = None
        self._manoeuvre_spent = False
        self._off_course_time = 0.0

    @property
    def direction(self) -> int:
        """Chosen driving direction: +1 forward, -1 reverse, 0 not chosen yet."""
        return self._direction

    # -- main entry ---------------------------------------------------------------------
    def command(
        self,
        pose: Pose2,
        goal: Pose2,
        goal_heading: bool = True,
        v_now: float | None = None,
        dt: float = 0.02,
        omega_now: float | None = None,
    ) -> GoToGoalOutput:
        """The command for this period.

        ``pose`` and ``goal`` are in the same 2D frame; ``goal.theta`` is ignored unless
        ``goal_heading``. ``v_now`` / ``omega_now`` are the current (commanded or
        filtered measured) velocities the acceleration limits apply to; None uses the
        previous command of this law.
        """
        if not dt > 0.0:
            raise ValueError("dt must be > 0")
        p = self.params
        pose = Pose2(float(pose.x), float(pose.y), float(pose.theta))
        goal = Pose2(float(goal.x), float(goal.y), float(goal.theta))
        key = (goal.x, goal.y, goal.theta if goal_heading else None)
        if not self._same_goal(key):
            self._goal_key = key
            self._restart()
        v0 = self._v_last if v_now is None else float(v_now)
        w0 = self._omega_last if omega_now is None else float(omega_now)

        gx, gy = goal.x - pose.x, goal.y - pose.y
        d = math.hypot(gx, gy)
        bearing = math.atan2(gy, gx) if d > 0.0 else pose.theta
        e_fwd = wrap_angle(bearing - pose.theta)
        e_goal = wrap_angle(goal.theta - pose.theta) if goal_heading else 0.0
        halted = abs(v0) <= p.halt_speed

        # -- arrival hysteresis --------------------------------------------------------
        if self._mode != _APPROACH and d > p.reapproach_factor * p.position_tolerance:
            self._restart()
        if self._mode == _REACHED and abs(e_goal) > p.reheading_factor * p.heading_tolerance:
            self._mode = _FINAL
            self._turn_sign = 0

        if self._mode == _APPROACH:
            out = self._approach(pose, goal, goal_heading, d, bearing, e_fwd, v0, w0, dt)
            if out is not None:
                return out
            self._mode = _FINAL  # inside the position tolerance
            self._turn_sign = 0

        if self._mode == _FINAL and halted and abs(e_goal) <= p.heading_tolerance:
            self._mode = _REACHED
        if self._mode == _REACHED:
            return self._emit(0.0, 0.0, v0, w0, dt, Phase.REACHED, True, d, e_goal)
        omega = 0.0 if not halted else self._turn_omega(e_goal)
        return self._emit(0.0, omega, v0, w0, dt, Phase.FINAL_TURN, False, d, e_goal)

    def _same_goal(self, key: tuple[float, float, float | None]) -> bool:
        """Within half the tolerances of the goal the current approach was started for."""
        old = self._goal_key
        if old is None or (old[2] is None) != (key[2] is None):
            return False
        p = self.params
        if math.hypot(key[0] - old[0], key[1] - old[1]) > 0.5 * p.position_tolerance:
            return False
        if key[2] is None or old[2] is None:
            return True
        return abs(wrap_angle(key[2] - old[2])) <= 0.5 * p.heading_tolerance

    # -- approach -----------------------------------------------------------------------
    def _approach(
        self,
        pose: Pose2,
        goal: Pose2,
        goal_heading: bool,
        d: float,
        bearing: float,
        e_fwd: float,
        v0: float,
        w0: float,
        dt: float,
    ) -> GoToGoalOutput | None:
        """Align / manoeuvre / drive; None once the position tolerance is reached."""
        p = self.params
        halted = abs(v0) <= p.halt_speed
        simultaneous = p.turn_mode == TurnMode.SIMULTANEOUS
        lateral_ok = p.lateral_fraction * p.position_tolerance

        def effective_error() -> float:
            return e_fwd if self._direction >= 0 else wrap_angle(e_fwd - math.pi)

        if self._direction == 0 or (simultaneous and halted):
            self._choose_direction(goal, goal_heading, d, bearing, e_fwd)
        e = effective_error()

        if simultaneous:
            self._stage = _DRIVE
        else:
            alpha = acceptance_angle(p, d)
            off_course = abs(e) > math.pi / 2 or (
                abs(e) > alpha + p.hysteresis and abs(d * math.sin(e)) > lateral_ok
            )
            self._off_course_time = self._off_course_time + dt if off_course else 0.0
            if self._stage == _DRIVE and self._off_course_time >= p.realign_delay:
                self._stage = _ALIGN
                self._manoeuvre = None
                self._manoeuvre_spent = False
                self._turn_sign = 0
            if self._stage == _ALIGN:
                self._choose_direction(goal, goal_heading, d, bearing, e_fwd)
                e = effective_error()
            if self._stage != _DRIVE and abs(e) <= alpha:
                self._stage = _DRIVE
                self._manoeuvre = None

        # inside the position tolerance: a drive goes on to its closest approach, an
        # alignment stops as soon as braking now ends inside; the final phase brakes.
        if self._stage == _DRIVE:
            if d <= p.position_tolerance and d * math.cos(e) <= p.stop_distance:
                return None
            return self._drive(d, e, v0, w0, dt, simultaneous)
        if self._stop_point(pose, v0, dt).distance_to(goal) <= p.position_tolerance:
            return None

        # align-first, not yet aligned
        if self._stage == _ALIGN and not halted:  # brake to a halt in a line, then turn
            return self._emit(0.0, 0.0, v0, w0, dt, Phase.ALIGN, False, d, e)
        if p.manoeuvre and not self._manoeuvre_spent:
            if self._manoeuvre is None:
                near = d <= p.turning_zone_radius
                step = 1 if abs(e) <= math.pi / 2 and not near else -1
                self._manoeuvre = _Manoeuvre(pose.x, pose.y, step, 1)
                self._stage = _MANOEUVRE
            out = self._manoeuvre_step(pose, d, e, v0, w0, dt)
            if out is not None:
                return out
        return self._emit(0.0, self._turn_omega(e), v0, w0, dt, Phase.ALIGN, False, d, e)

    def _choose_direction(
        self, goal: Pose2, goal_heading: bool, d: float, bearing: float, e_fwd: float
    ) -> None:
        """Eq. 2.5: reverse to a goal behind (and close), with hysteresis."""
        p = self.params
        current = self._direction
        if not p.allow_reverse or d > p.reverse_max_distance:
            self._direction = 1
            return
        # rotation owed now + at the goal, forward vs reverse (reverse = 2 pi - forward)
        final = abs(wrap_angle(goal.theta - bearing)) if goal_heading else 0.0
        if goal_heading:
            cost_fwd = abs(e_fwd) + final
            cost_rev = (math.pi - abs(e_fwd)) + (math.pi - final)
        else:
            cost_fwd, cost_rev = abs(e_fwd), math.pi - abs(e_fwd)
        behind = abs(e_fwd) - math.pi / 2  # > 0: the goal is behind
        margin = 0.0 if current == 0 else p.direction_hysteresis
        if current < 0:  # reversing: keep unless clearly worse
            keep = behind > -margin and cost_rev <= cost_fwd + margin
            self._direction = -1 if keep else 1
        else:
            go_rev = behind > margin and cost_rev <= cost_fwd - margin
            self._direction = -1 if go_rev else 1
        if self._direction != current:
            self._turn_sign = 0

    def _drive(
        self, d: float, e: float, v0: float, w0: float, dt: float, simultaneous: bool
    ) -> GoToGoalOutput:
        p = self.params
        inside = d <= p.position_tolerance
        omega = 0.0 if inside else self._turn_omega(e, braking=False)
        speed = self.speed_ceiling(d * math.cos(e))
        if simultaneous:
            speed *= max(0.0, math.cos(e))
        # orbit guard, blended in over the lateral band [lateral_ok / 2, lateral_ok]
        lateral_ok = p.lateral_fraction * p.position_tolerance
        blend = _clamp((abs(d * math.sin(e)) - 0.5 * lateral_ok) / (0.5 * lateral_ok), 0.0, 1.0)
        if blend > 0.0 and not inside:
            speed = min(speed, p.orbit_margin * abs(omega) * d / (abs(math.sin(e)) * blend))
        v = self._direction * speed
        phase = Phase.DRIVE if self._direction > 0 else Phase.REVERSE
        return self._emit(v, omega, v0, w0, dt, phase, False, d, e)

    def speed_ceiling(self, along: float) -> float:
        """Trapezoid ceiling (m/s) with ``along`` metres left to the stopping point."""
        p = self.params
        b = p.braking_fraction * p.max_acceleration
        left = max(0.0, along)
        ceiling = min(p.max_speed, math.sqrt(2.0 * b * left))
        if p.final_approach_speed is not None:
            extra = max(0.0, left - p.final_approach_distance)
            ceiling = min(ceiling, math.sqrt(p.final_approach_speed**2 + 2.0 * b * extra))
        return ceiling

    def _manoeuvre_step(
        self, pose: Pose2, d: float, e: float, v0: float, w0: float, dt: float
    ) -> GoToGoalOutput | None:
        """Algorithm 2.4 (see the module docstring); None once the steps are spent."""
        p = self.params
        m = self._manoeuvre
        assert m is not None
        b = p.braking_fraction * p.max_acceleration
        eps = min(0.01, 0.1 * p.turning_zone_radius)

        def to_boundary(step: int) -> float:
            sign = self._direction * step
            ux, uy = sign * math.cos(pose.theta), sign * math.sin(pose.theta)
            rx, ry = pose.x - m.cx, pose.y - m.cy
            along = rx * ux + ry * uy
            disc = along * along - (rx * rx + ry * ry) + p.turning_zone_radius**2
            return -along + math.sqrt(max(0.0, disc))

        left = to_boundary(m.step)
        if left <= eps:
            if m.steps >= p.manoeuvre_steps:
                self._manoeuvre_spent = True
                self._manoeuvre = None
                self._stage = _ALIGN
                return None
            m.step, m.steps = -m.step, m.steps + 1
            left = to_boundary(m.step)
        omega = self._turn_omega(e)
        speed = min(p.manoeuvre_speed, math.sqrt(2.0 * b * max(0.0, left - eps)))
        if m.step > 0 and abs(math.sin(e)) > 1e-12:  # forward makes |gamma| grow: guard it
            speed = min(speed, p.orbit_margin * abs(omega) * d / abs(math.sin(e)))
        v = self._direction * m.step * speed
        phase = (
            Phase.MANOEUVRE_FORWARD if self._direction * m.step > 0 else Phase.MANOEUVRE_BACKWARD
        )
        return self._emit(v, omega, v0, w0, dt, phase, False, d, e)

    # -- helpers ------------------------------------------------------------------------
    def _stop_point(self, pose: Pose2, v0: float, dt: float) -> Pose2:
        """Where the robot ends if it brakes at the full limit from now on."""
        travel = v0 * abs(v0) / (2.0 * self.params.max_acceleration) + v0 * dt
        c, s = math.cos(pose.theta), math.sin(pose.theta)
        return Pose2(pose.x + travel * c, pose.y + travel * s, pose.theta)

    def _turn_omega(self, e: float, braking: bool = True) -> float:
        """Eq. 2.4 on ``e`` with a sticky turning direction near +-pi."""
        p = self.params
        if (
            self._turn_sign != 0
            and abs(e) > math.pi - p.direction_hysteresis
            and _sign(e) == -self._turn_sign
        ):
            e += 2.0 * math.pi * self._turn_sign  # keep turning the same way
            omega = _clamp(p.k_omega * e, -p.max_angular_speed, p.max_angular_speed)
        else:
            omega = eq_2_4_omega(e, p.k_omega, p.max_angular_speed)
        if _sign(e) != 0:
            self._turn_sign = _sign(e)
        if braking and p.max_angular_acceleration is not None:  # stop the turn on target
            cap = math.sqrt(2.0 * p.braking_fraction * p.max_angular_acceleration * abs(e))
            omega = _clamp(omega, -cap, cap)
        return omega

    def _emit(
        self,
        v: float,
        omega: float,
        v0: float,
        w0: float,
        dt: float,
        phase: Phase,
        reached: bool,
        distance: float,
        heading_error: float,
    ) -> GoToGoalOutput:
        """Clamp to the acceleration and speed limits and remember the command."""
        p = self.params
        dv = p.max_acceleration * dt
        v = _clamp(_clamp(v, v0 - dv, v0 + dv), -p.max_speed, p.max_speed)
        if p.max_angular_acceleration is not None:
            dw = p.max_angular_acceleration * dt
            omega = _clamp(omega, w0 - dw, w0 + dw)
        omega = _clamp(omega, -p.max_angular_speed, p.max_angular_speed)
        self._v_last, self._omega_last = v, omega
        return GoToGoalOutput(v, omega, phase, reached, distance, heading_error)
