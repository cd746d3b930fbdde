"""Skid-steer drive base: velocity tracking with limits, and slip.

The motor controllers track the commanded (v, omega) within the platform's acceleration
limits; that is what the wheels do and what the encoders see. The body moves less than
the wheels say, most in turns: a skid-steer base must drag its wheels sideways to turn,
so part of the wheels' yaw rate is lost (the instantaneous-centre-of-rotation expansion
of skid-steer kinematics) and the body slips outwards. Wheel odometry (thesis eq. 2.1,
2.2) therefore drifts, much more in tight turns than straight ahead.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from executive.core.model import Platform
from sim2d.scenario import SlipLevels


def _towards(current: float, target: float, max_step: float) -> float:
    return current + max(-max_step, min(max_step, target - current))


@dataclass
class BodyVelocity:
    """Velocity of the body in its own frame: forward, lateral (left) and yaw rate."""

    forward: float
    lateral: float
    yaw_rate: float


class SkidSteerBase:
    """Tracks commands within limits; returns wheel speeds and the body's true velocity."""

    def __init__(self, platform: Platform, rng: np.random.Generator) -> None:
        self.platform = platform
        self.rng = rng
        self.v_cmd = 0.0
        self.omega_cmd = 0.0
        self.v_wheels = 0.0  # what the motor controllers achieve (m/s, rad/s)
        self.omega_wheels = 0.0

    def command(self, v: float, omega: float) -> None:
        """New set-point, clamped to the platform's speed limits."""
        p = self.platform
        self.v_cmd = max(-p.max_speed, min(p.max_speed, v))
        self.omega_cmd = max(-p.max_angular_speed, min(p.max_angular_speed, omega))

    def stop_now(self) -> None:
        """Brakes engaged (bumper): the wheels stop at once."""
        self.v_cmd = self.omega_cmd = self.v_wheels = self.omega_wheels = 0.0

    def step(self, dt: float, slip: SlipLevels) -> BodyVelocity:
        """Advance the motor controllers by ``dt``; the body's true velocity with slip."""
        p = self.platform
        self.v_wheels = _towards(self.v_wheels, self.v_cmd, p.max_acceleration * dt)
        self.omega_wheels = _towards(
            self.omega_wheels, self.omega_cmd, p.max_angular_acceleration * dt
        )
        jitter = self.rng.standard_normal(2)
        long_slip = slip.longitudinal * (1.0 + 0.5 * jitter[0])
        # Turning slip grows with the share of the motion that is rotation: pure rotation
        # on the spot loses the most, a gentle curve at speed little.
        half_track = p.track / 2.0
        turn_share = (
            abs(self.omega_wheels)
            * half_track
            / (abs(self.v_wheels) + abs(self.omega_wheels) * half_track + 1e-9)
        )
        turn_slip = slip.turn * turn_share * (1.0 + 0.25 * jitter[1])
        forward = self.v_wheels * (1.0 - long_slip)
        yaw_rate = self.omega_wheels * (1.0 - turn_slip)
        lateral = -slip.lateral * forward * yaw_rate  # outwards in a turn
        return BodyVelocity(forward, lateral, yaw_rate)

    def wheel_speeds(self) -> tuple[float, float]:
        """Ground speed of the left and right wheels as the encoders measure it (eq. 2.1/2.2
        inverted: v_l = v - omega * track / 2, v_r = v + omega * track / 2)."""
        half_track = self.platform.track / 2.0
        return (
            self.v_wheels - self.omega_wheels * half_track,
            self.v_wheels + self.omega_wheels * half_track,
        )


def body_to_world(heading: float, body: BodyVelocity) -> tuple[float, float]:
    """World-frame linear velocity of a body with ``heading``."""
    c, s = math.cos(heading), math.sin(heading)
    return c * body.forward - s * body.lateral, s * body.forward + c * body.lateral
