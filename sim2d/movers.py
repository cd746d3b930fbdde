"""Motions of moving obstacles: scripted paths, a loitering group, an adversarial chaser.

Each mover is asked, at every physics step, for the velocity of its kinematic body given
the time and the robot's true position; pymunk integrates it. Movers draw randomness only
from the generator they are given, so runs are reproducible.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from sim2d.scenario import Chaser, LoiteringGroup, PathMover


@dataclass
class Agent:
    """One moving body as the world sees it: id, shape, and where it is."""

    id: str
    x: float
    y: float
    heading: float = 0.0
    vx: float = 0.0
    vy: float = 0.0


class PathMotion:
    """Walks the waypoints at constant speed; waits for its start time or trigger."""

    def __init__(self, spec: PathMover) -> None:
        self.spec = spec
        self.agent = Agent(spec.id, *spec.waypoints[0])
        self.target = 1
        self.started = False
        self.finished = False

    def update(self, t: float, robot_xy: tuple[float, float]) -> None:
        a, spec = self.agent, self.spec
        if not self.started:
            first = spec.waypoints[0]
            near = spec.trigger_radius is not None and math.dist(robot_xy, first) <= (
                spec.trigger_radius
            )
            self.started = near if spec.trigger_radius is not None else t >= spec.start_time
        if not self.started or self.finished:
            a.vx = a.vy = 0.0
            return
        tx, ty = spec.waypoints[self.target]
        dx, dy = tx - a.x, ty - a.y
        dist = math.hypot(dx, dy)
        if dist < 0.05:
            self.target += 1
            if self.target >= len(spec.waypoints):
                if spec.loop:
                    self.target = 0
                else:
                    self.finished = True
                    a.vx = a.vy = 0.0
                    return
            tx, ty = spec.waypoints[self.target]
            dx, dy = tx - a.x, ty - a.y
            dist = math.hypot(dx, dy)
        a.heading = math.atan2(dy, dx)
        a.vx, a.vy = spec.speed * dx / max(dist, 1e-9), spec.speed * dy / max(dist, 1e-9)


@dataclass
class _Walker:
    agent: Agent
    goal: tuple[float, float]
    pause: float = 0.0


class GroupMotion:
    """People milling about inside a circle: walk to a random spot, pause, repeat."""

    def __init__(self, spec: LoiteringGroup, rng: np.random.Generator) -> None:
        self.spec = spec
        self.rng = rng
        self.walkers: list[_Walker] = []
        for i in range(spec.count):
            x, y = self._spot()
            self.walkers.append(_Walker(Agent(f"{spec.id}.{i}", x, y), self._spot()))

    def _spot(self) -> tuple[float, float]:
        r = self.spec.radius * math.sqrt(self.rng.uniform())
        a = self.rng.uniform(0.0, 2.0 * math.pi)
        return self.spec.center[0] + r * math.cos(a), self.spec.center[1] + r * math.sin(a)

    def update(self, dt: float) -> None:
        for w in self.walkers:
            a = w.agent
            if w.pause > 0.0:
                w.pause -= dt
                a.vx = a.vy = 0.0
                continue
            dx, dy = w.goal[0] - a.x, w.goal[1] - a.y
            dist = math.hypot(dx, dy)
            if dist < 0.1:
                w.goal = self._spot()
                w.pause = float(self.rng.uniform(1.0, 4.0))
                a.vx = a.vy = 0.0
                continue
            a.heading = math.atan2(dy, dx)
            a.vx, a.vy = self.spec.speed * dx / dist, self.spec.speed * dy / dist


@dataclass
class ChaserMotion:
    """Steers straight at the robot at a set speed once the robot is within range
    (the adversarial trolley of the thesis's stress test). With a ``pursuit`` time the
    pusher gives up after it, pushes the trolley back to where it waited and stays."""

    spec: Chaser
    agent: Agent = field(init=False)
    triggered_at: float | None = None
    gave_up: bool = False

    def __post_init__(self) -> None:
        self.agent = Agent(self.spec.id, *self.spec.start)

    def update(self, robot_xy: tuple[float, float], now: float) -> None:
        a, spec = self.agent, self.spec
        if self.triggered_at is None:
            reach = spec.trigger_radius
            if reach is None or math.hypot(robot_xy[0] - a.x, robot_xy[1] - a.y) <= reach:
                self.triggered_at = now
        if self.triggered_at is None:
            a.vx = a.vy = 0.0
            return
        if spec.pursuit is not None and now - self.triggered_at > spec.pursuit:
            self.gave_up = True
        goal = spec.start if self.gave_up else robot_xy
        dx, dy = goal[0] - a.x, goal[1] - a.y
        dist = math.hypot(dx, dy)
        if dist < (0.05 if self.gave_up else 1e-6):
            a.vx = a.vy = 0.0
            return
        a.heading = math.atan2(dy, dx)
        a.vx, a.vy = spec.speed * dx / dist, spec.speed * dy / dist
