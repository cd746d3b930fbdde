"""The pymunk world: robot, aircraft footprint, static and moving obstacles, contacts.

Physics runs at a fixed step (``scenario.physics_rate``, 100 Hz by default) independent of
the control rate. The robot is a dynamic body whose velocity is set every step from the
skid-steer model (:mod:`sim2d.base`); obstacles that move are kinematic bodies driven by
:mod:`sim2d.movers`; the aircraft footprint (at the scenario's *true* parking pose) and
static obstacles are static shapes. Any contact of the robot with anything is a collision
event; contacts ahead of the axle press the front bumper, behind it the rear one.

The world also keeps the ray-casting scene the sensors use: static geometry once, moving
bodies refreshed from their poses in pymunk whenever a sensor is due.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
import pymunk

from executive.core.frames import Pose2, wrap_angle
from executive.core.model import Circle
from sim2d.base import SkidSteerBase, body_to_world
from sim2d.movers import Agent, ChaserMotion, GroupMotion, PathMotion
from sim2d.raycast import Scene
from sim2d.scenario import Body, Chaser, LoiteringGroup, PathMover, Scenario, StaticObstacle

ROBOT, AIRCRAFT, OBSTACLE = 1, 2, 3
SEGMENT_RADIUS = 0.01  # static polygon edges are thin pymunk segments (any polygon works)
STILL_SPEED = 0.05
"""m/s: a robot slower than this at a collision was standing still (braking to rest from
the e-stop's r_ES leaves a few mm/s of creep at most)."""


@dataclass(frozen=True, slots=True)
class Collision:
    """The robot touched something: when, what, where on the robot (robot frame), and how
    fast the robot itself moved at the first contact (ground truth, m/s): a robot
    standing still was struck (a mover that does not avoid ran into it), a moving robot
    drove into it or did not get out of its way."""

    time: float
    other: str
    x: float
    y: float
    robot_speed: float = 0.0
    robot_closing: float = math.nan
    """The robot's own speed towards the other body along the contact normal (m/s;
    negative: moving away from it; NaN: unknown)."""

    @property
    def robot_moving(self) -> bool:
        """The robot was moving at the first contact (at least :data:`STILL_SPEED`)."""
        return self.robot_speed >= STILL_SPEED

    def describe(self) -> str:
        """'collision with <other> at <t> s (the robot standing still | moving at v m/s |
        moving away at v m/s: struck)'."""
        if not self.robot_moving:
            how = "standing still: struck"
        elif self.robot_closing < STILL_SPEED:  # NaN: unknown, said as moving
            how = f"moving away at {self.robot_speed:.2f} m/s: struck"
        else:
            how = f"moving at {self.robot_speed:.2f} m/s"
        return f"collision with {self.other} at {self.time:.1f} s (the robot {how})"


@dataclass
class _Moving:
    agent: Agent
    body: pymunk.Body
    shape_body: Body
    height: float
    owner: int
    velocity: tuple[float, float] = (0.0, 0.0)


def _box_points(length: float, width: float) -> list[tuple[float, float]]:
    hl, hw = length / 2.0, width / 2.0
    return [(hl, hw), (-hl, hw), (-hl, -hw), (hl, -hw)]


class World:
    """Everything physical in a scenario, stepped at the physics rate."""

    def __init__(self, scenario: Scenario, rng: np.random.Generator) -> None:
        self.scenario = scenario
        self.platform = scenario.mission.platform
        self.dt = 1.0 / scenario.physics_rate
        self.time = 0.0
        self.placement = scenario.true_placement()
        self.space = pymunk.Space()
        self.space.iterations = 10
        self.base = SkidSteerBase(self.platform, rng.spawn(1)[0])
        self.owner_names: list[str] = []  # owner id -> name, for ray hits and contacts
        self.owner_heights: list[float] = []
        self.collisions: list[Collision] = []
        self._touching: dict[pymunk.Shape, tuple[float, float]] = {}
        self._build_robot()
        static, obstacles = self._build_static()
        self.moving: list[_Moving] = []
        self.paths: list[PathMotion] = []
        self.groups: list[GroupMotion] = []
        self.chasers: list[ChaserMotion] = []
        self._build_moving(rng.spawn(1)[0])
        self.static_scene = static
        self.static_obstacles = obstacles  # static obstacles only: camera occluders
        self.owner_height = np.array(self.owner_heights)
        self._poses = np.zeros((len(self.moving), 3))  # x, y, angle of each moving body
        self._read_robot()
        self._read_poses()
        self._build_moving_slots()

        self.space.on_collision(
            ROBOT, None, begin=self._begin, pre_solve=self._pre_solve, separate=self._separate
        )

    # -- construction -------------------------------------------------------------------------
    def _owner(self, name: str, height: float) -> int:
        self.owner_names.append(name)
        self.owner_heights.append(height)
        return len(self.owner_names) - 1

    def _build_robot(self) -> None:
        p = self.platform
        mass = 230.0
        moment = pymunk.moment_for_box(mass, (p.length, p.width))
        self.robot_body = pymunk.Body(mass, moment)
        start = self.scenario.start
        self.robot_body.position = (start.x, start.y)
        self.robot_body.angle = start.theta
        shape = pymunk.Poly.create_box(self.robot_body, (p.length, p.width), radius=0.0)
        shape.collision_type = ROBOT
        shape.friction = 0.8
        self.space.add(self.robot_body, shape)

    def _static_polygon(self, name: str, points: np.ndarray, height: float, kind: int) -> int:
        owner = self._owner(name, height)
        ring = np.vstack((points, points[:1]))
        for a, b in itertools.pairwise(ring):
            seg = pymunk.Segment(self.space.static_body, tuple(a), tuple(b), SEGMENT_RADIUS)
            seg.collision_type = kind
            seg.friction = 0.8
            self.space.add(seg)
        return owner

    def _static_circle(self, name: str, cx: float, cy: float, r: float, h: float, kind: int) -> int:
        owner = self._owner(name, h)
        circle = pymunk.Circle(self.space.static_body, r, (cx, cy))
        circle.collision_type = kind
        circle.friction = 0.8
        self.space.add(circle)
        return owner

    def _build_static(self) -> tuple[Scene, Scene]:
        """The static ray-casting scene (aircraft + obstacles) and the obstacles alone.

        Polygons become one-sided edges (back faces are culled when casting).
        """
        aircraft: list[Scene] = []
        obstacles: list[Scene] = []
        for shape in self.scenario.mission.aircraft.footprint:
            name = f"aircraft:{shape.id}"
            if isinstance(shape, Circle):
                cx, cy = self.placement.to_airport_xy((shape.cx, shape.cy))
                owner = self._static_circle(name, cx, cy, shape.radius, 99.0, AIRCRAFT)
                aircraft.append(Scene(circles=[(cx, cy, shape.radius)], circle_owner=[owner]))
            else:
                pts = self.placement.to_airport_xy(np.array(shape.points))
                owner = self._static_polygon(name, pts, 99.0, AIRCRAFT)
                aircraft.append(Scene.from_polygon(pts).with_owner(owner))
        for ob in self.scenario.obstacles:
            if not isinstance(ob, StaticObstacle):
                continue
            if ob.body.radius is not None:
                x, y, r = ob.pose.x, ob.pose.y, ob.body.radius
                owner = self._static_circle(ob.id, x, y, r, ob.height, OBSTACLE)
                obstacles.append(Scene(circles=[(x, y, r)], circle_owner=[owner]))
            else:
                pts = np.array(ob.body.polygon(ob.pose).points)
                owner = self._static_polygon(ob.id, pts, ob.height, OBSTACLE)
                obstacles.append(Scene.from_polygon(pts).with_owner(owner))
        return Scene.concat(aircraft + obstacles), Scene.concat(obstacles)

    def _add_moving(self, agent: Agent, body_spec: Body, height: float) -> None:
        body = pymunk.Body(body_type=pymunk.Body.KINEMATIC)
        body.position = (agent.x, agent.y)
        body.angle = agent.heading
        if body_spec.radius is not None:
            shape: pymunk.Shape = pymunk.Circle(body, body_spec.radius)
        else:
            shape = pymunk.Poly(body, _box_points(body_spec.length, body_spec.width))
        shape.collision_type = OBSTACLE
        shape.friction = 0.8
        self.space.add(body, shape)
        owner = self._owner(agent.id, height)
        self.moving.append(_Moving(agent, body, body_spec, height, owner))

    def _build_moving(self, rng: np.random.Generator) -> None:
        for ob in self.scenario.obstacles:
            if isinstance(ob, PathMover):
                motion = PathMotion(ob)
                self.paths.append(motion)
                self._add_moving(motion.agent, ob.body, ob.height)
            elif isinstance(ob, LoiteringGroup):
                group = GroupMotion(ob, rng.spawn(1)[0])
                self.groups.append(group)
                for w in group.walkers:
                    self._add_moving(w.agent, Body(radius=ob.person_radius), ob.height)
            elif isinstance(ob, Chaser):
                chaser = ChaserMotion(ob)
                self.chasers.append(chaser)
                self._add_moving(chaser.agent, ob.body, ob.height)

    # -- contacts -----------------------------------------------------------------------------
    def _name_of(self, shape: pymunk.Shape) -> str:
        body = shape.body
        for m in self.moving:
            if m.body is body:
                return m.agent.id
        if shape.collision_type == AIRCRAFT:
            return "aircraft"
        for ob in self.scenario.obstacles:  # static obstacles: nearest by position
            if isinstance(ob, StaticObstacle):
                bb = shape.bb
                cx, cy = (bb.left + bb.right) / 2, (bb.bottom + bb.top) / 2
                if math.hypot(cx - ob.pose.x, cy - ob.pose.y) <= ob.body.bounding_radius + 0.1:
                    return ob.id
        return "obstacle"

    def _contact_in_robot(self, arbiter: pymunk.Arbiter) -> tuple[float, float]:
        points = arbiter.contact_point_set.points
        if not points:
            return 0.0, 0.0
        p = points[0].point_a
        local = self.robot_body.world_to_local(p)
        return float(local.x), float(local.y)

    def _other(self, arbiter: pymunk.Arbiter) -> pymunk.Shape:
        a, b = arbiter.shapes
        return b if a.collision_type == ROBOT else a

    def _begin(self, arbiter: pymunk.Arbiter, space: pymunk.Space, data: object) -> None:
        del space, data
        where = self._contact_in_robot(arbiter)
        other = self._other(arbiter)
        self._touching[other] = where
        velocity = self.robot_body.velocity
        normal = arbiter.contact_point_set.normal  # from the first shape to the second
        if arbiter.shapes[0] is other:
            normal = -normal
        closing = float(velocity.dot(normal))
        speed = float(velocity.length)
        self.collisions.append(Collision(self.time, self._name_of(other), *where, speed, closing))

    def _pre_solve(self, arbiter: pymunk.Arbiter, space: pymunk.Space, data: object) -> None:
        del space, data
        self._touching[self._other(arbiter)] = self._contact_in_robot(arbiter)

    def _separate(self, arbiter: pymunk.Arbiter, space: pymunk.Space, data: object) -> None:
        del space, data
        self._touching.pop(self._other(arbiter), None)

    def bumpers(self) -> tuple[bool, bool]:
        """(front, rear) pressed by a current contact."""
        if not self._touching:
            return False, False
        front = any(x >= 0.0 for x, _ in self._touching.values())
        rear = any(x < 0.0 for x, _ in self._touching.values())
        return front, rear

    # -- state ----------------------------------------------------------------------------------
    @property
    def robot_pose(self) -> Pose2:
        return self._robot_pose

    def _read_robot(self) -> None:
        b = self.robot_body
        position = b.position
        self._robot_pose = Pose2(position.x, position.y, wrap_angle(b.angle))

    def _build_moving_slots(self) -> None:
        """Scenes with a fixed slot per moving body, rewritten in place at each refresh.

        ``scene`` = static scene + movers (for the lasers); ``occluders`` = static
        obstacles + movers (camera occlusion: the aircraft does not hide its own
        features). :meth:`Scene.concat` puts all segments first, then all circles, so the
        movers' rows start after the static part's.
        """
        self._box_movers = [k for k, m in enumerate(self.moving) if m.shape_body.radius is None]
        self._disc_movers = [
            k for k, m in enumerate(self.moving) if m.shape_body.radius is not None
        ]
        boxes = [self.moving[k] for k in self._box_movers]
        discs = [self.moving[k] for k in self._disc_movers]
        half = np.array([(m.shape_body.length / 2, m.shape_body.width / 2) for m in boxes])
        # Corners counter-clockwise, as Scene.from_box makes them: (+l,+w)... per box, as
        # (k, 4) offsets along and across each box.
        local = np.array([(1, 1), (-1, 1), (-1, -1), (1, -1)], dtype=float)
        self._box_lx = local[None, :, 0] * half.reshape(-1, 2)[:, 0, None]
        self._box_ly = local[None, :, 1] * half.reshape(-1, 2)[:, 1, None]
        parts = [
            Scene.from_box(
                m.agent.x, m.agent.y, m.agent.heading, m.shape_body.length, m.shape_body.width
            ).with_owner(m.owner)
            for m in boxes
        ]
        if discs:
            parts.append(
                Scene(
                    circles=[(m.agent.x, m.agent.y, m.shape_body.radius) for m in discs],
                    circle_owner=[m.owner for m in discs],
                )
            )
        moving = Scene.concat(parts)
        self.scene = Scene.concat([self.static_scene, moving])
        self.occluders = Scene.concat([self.static_obstacles, moving])
        self._slots = [
            (self.scene, self.static_scene.n_segments, self.static_scene.n_circles),
            (self.occluders, self.static_obstacles.n_segments, self.static_obstacles.n_circles),
        ]
        # the discs' centre rows of both scenes (views: the scenes are rewritten in place)
        self._disc_index = np.array(self._disc_movers, dtype=np.intp)
        self._disc_centers = [
            scene.centers[circ0 : circ0 + len(discs)] for scene, _, circ0 in self._slots
        ]
        self.refresh_scene()

    def refresh_scene(self) -> None:
        """Move the movers' slots of the ray-casting scenes to their current poses
        (read from pymunk)."""
        if not self.moving:
            return
        self._read_poses()
        movers = self._poses
        if self._box_movers:
            x, y, heading = movers[self._box_movers].T
            c, s = np.cos(heading), np.sin(heading)
            lx, ly = self._box_lx, self._box_ly
            cx = x[:, None] + c[:, None] * lx - s[:, None] * ly
            cy = y[:, None] + s[:, None] * lx + c[:, None] * ly
            corners = np.stack((cx, cy), axis=2)  # (k, 4, 2)
            edges = np.concatenate((corners, np.roll(corners, -1, axis=1)), axis=2)
            for scene, seg0, _ in self._slots:
                scene.set_segments(edges.reshape(-1, 4), seg0)
        if self._disc_movers:
            xy = movers[self._disc_index, :2]
            for centers in self._disc_centers:
                centers[:] = xy

    def _read_poses(self) -> None:
        """Read every moving body's pose from pymunk; update the movers' agents.

        A handful of bodies: direct reads cost less than one ``pymunk.batch`` call.
        """
        rows = []
        for m in self.moving:
            p = m.body.position
            m.agent.x, m.agent.y = p.x, p.y
            rows.append((p.x, p.y, m.body.angle))
        if rows:
            self._poses = np.array(rows)

    def obstacle_poses(self) -> list[tuple[str, float, float, float]]:
        """Ground truth of every moving obstacle: (id, x, y, heading)."""
        self._read_poses()
        return [
            (m.agent.id, float(x), float(y), float(angle))
            for m, (x, y, angle) in zip(self.moving, self._poses, strict=True)
        ]

    # -- stepping -----------------------------------------------------------------------------
    def step(self, slip_factor: float = 1.0, bumper_fault: bool = False) -> None:
        """Advance physics by one step."""
        pose = self.robot_pose
        robot_xy = (pose.x, pose.y)
        for path in self.paths:
            path.update(self.time, robot_xy)
        for group in self.groups:
            group.update(self.dt)
        for chaser in self.chasers:
            chaser.update(robot_xy, self.time)
        for m in self.moving:
            a = m.agent
            if (a.vx, a.vy) != m.velocity:  # pymunk attribute writes are not free
                m.velocity = (a.vx, a.vy)
                m.body.velocity = m.velocity
                m.body.angle = a.heading
        front, rear = self.bumpers()
        if front or rear or bumper_fault:
            self.base.stop_now()  # the platform brakes on a bumper (thesis §2.2.1)
        slip = self.scenario.slip.scaled(slip_factor) if slip_factor != 1.0 else self.scenario.slip
        velocity = self.base.step(self.dt, slip)
        self.robot_body.velocity = body_to_world(pose.theta, velocity)
        self.robot_body.angular_velocity = velocity.yaw_rate
        self.space.step(self.dt)
        self.time += self.dt
        self._read_robot()
        for m in self.moving:  # kinematic bodies move exactly by v * dt: no read-back
            m.agent.x += m.velocity[0] * self.dt
            m.agent.y += m.velocity[1] * self.dt
