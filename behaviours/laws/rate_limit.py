"""Rate limiter for (v, omega) avoidance commands (seed 000 lines 4302-4305, 4403-4405).

The thesis notes high variations of its avoidance velocities (figure 4.19) and names "rate
limiters on the acceleration" as the first future-work item. This pure law bounds the
linear and angular accelerations of a command stream and, optionally, the linear jerk.

``executive.safety.MotionLimits`` implements a jerk-limited profile for the safety layer,
but ``behaviours`` may only import ``executive.core`` (ARCHITECTURE.md §2), so this small
limiter lives here.

Linear speed with a jerk limit J: the acceleration moves by at most J dt per period and
towards the largest value from which the speed can still stop at the target without
overshoot. Ramping an acceleration ``a = n J dt`` down to zero in steps of J dt changes the
speed by ``dt J dt n (n + 1) / 2 = a^2 / (2 J) + a dt / 2``; solving that for a remaining
speed error e gives ``a_want = sign(e) (sqrt(h^2 + 2 J |e|) - h)`` with ``h = J dt / 2``,
clamped to +-A and to |e| / dt. Without a jerk limit the acceleration is simply
``clip(e / dt, -A, A)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

__all__ = ["RateLimiter", "RateLimits"]


@dataclass(frozen=True, slots=True)
class RateLimits:
    """Bounds of :class:`RateLimiter` (SI units); ``max_jerk`` None: no jerk limit."""

    max_acceleration: float = 0.5
    max_angular_acceleration: float = 1.0
    max_jerk: float | None = None
    max_speed: float | None = None
    max_angular_speed: float | None = None

    def __post_init__(self) -> None:
        if not (self.max_acceleration > 0.0 and self.max_angular_acceleration > 0.0):
            raise ValueError("acceleration limits must be > 0")
        for name in ("max_jerk", "max_speed", "max_angular_speed"):
            value = getattr(self, name)
            if value is not None and not value > 0.0:
                raise ValueError(f"RateLimits.{name} must be > 0 or None")


def _clip(x: float, lo: float, hi: float) -> float:
    return min(hi, max(lo, x))


@dataclass(slots=True)
class RateLimiter:
    """Stateful limiter: ``step(v, omega, dt)`` returns the limited command.

    State: the last output (v, omega) and the linear acceleration. :meth:`reset` sets it
    (e.g. to the command in force when the avoidance starts).
    """

    limits: RateLimits = field(default_factory=RateLimits)
    v: float = 0.0
    omega: float = 0.0
    acceleration: float = 0.0

    def reset(self, v: float = 0.0, omega: float = 0.0) -> None:
        self.v, self.omega, self.acceleration = v, omega, 0.0

    def step(self, v_cmd: float, omega_cmd: float, dt: float) -> tuple[float, float]:
        lim = self.limits
        if lim.max_speed is not None:
            v_cmd = _clip(v_cmd, -lim.max_speed, lim.max_speed)
        if lim.max_angular_speed is not None:
            omega_cmd = _clip(omega_cmd, -lim.max_angular_speed, lim.max_angular_speed)
        if dt <= 0.0:
            return self.v, self.omega
        big_a = lim.max_acceleration
        e = v_cmd - self.v
        if lim.max_jerk is None:
            a = _clip(e / dt, -big_a, big_a)
        else:
            da = lim.max_jerk * dt
            h = 0.5 * da
            want = math.copysign(math.sqrt(h * h + 2.0 * lim.max_jerk * abs(e)) - h, e)
            want = _clip(_clip(want, -big_a, big_a), -abs(e) / dt, abs(e) / dt)
            a = _clip(want, self.acceleration - da, self.acceleration + da)
        self.acceleration = a
        self.v += a * dt
        dw = lim.max_angular_acceleration * dt
        self.omega += _clip(omega_cmd - self.omega, -dw, dw)
        return self.v, self.omega
