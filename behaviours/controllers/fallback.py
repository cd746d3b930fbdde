"""The fallback of the spiral avoidance when trapped: plan on a costmap, follow with
go-to-goal (issue 6; the thesis leaves concave traps to future work, seed lines 4170-4240).

A thin adapter over :mod:`behaviours.laws.costmap` and :mod:`behaviours.laws.go_to_goal`.
When the avoidance policy declares the robot trapped (no progress towards the goal for a
while), :class:`FollowPlannedPath` builds a costmap around the robot and the goal from

* the laser returns of the last scans (both scanners, in A with the pose estimate),
* the virtual zone-wall points and every forbidden zone's outline,
* the aircraft's footprint placed with the current placement estimate,
* where every tracked mover will be over the next ``mover_horizon`` seconds at its
  tracked velocity (:func:`behaviours.laws.obstacles.mover_sweep`): a walker or a trolley
  slower than the avoidance's ``fast_speed`` is planned round, not dodged (faster ones
  take the robot from the planner, :class:`~behaviours.controllers.avoidance.AvoidancePolicy`),

inflates it by the robot's circumscribed radius plus r_ES, and runs A* in a worker thread (a plan
takes 0.05-0.3 s: far longer than a 20 ms tick). The result is applied a fixed
``plan_delay`` after the request, waiting for the worker if needed, so dry-runs stay
deterministic; the robot stands still meanwhile. It then drives the waypoints one after
the other with the go-to-goal law, and ends the avoidance (``session.released``) at the
last one or when no path exists.

The costmap is a snapshot: every tick, the returns of the current scans are checked
against the path still ahead (:func:`path_blocked_by`, up to ``lookahead`` m). One within
the robot's turning radius plus r_ES of it (a trolley that stopped on the path after the
plan) would trip the e-stop on the way: the robot stops and plans again from where it
stands (``replans`` counts them). Only returns the plan did not know count: those within
``known_tolerance`` of a return of its snapshot are obstacles it was planned round. The
path out of a trap starts closer to them than that (the costmap's escape region), and
counting them had the robot plan again at once, for ever (campaign episodes 652, 889).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable
from concurrent.futures import Future, ThreadPoolExecutor

import numpy as np
import py_trees
from scipy.spatial import cKDTree

from behaviours.controllers.avoidance import AvoidanceController, AvoidanceSession
from behaviours.goals import Goal
from behaviours.keys import OBSTACLES, POSE
from behaviours.laws.costmap import Costmap, PlannedPath
from behaviours.laws.go_to_goal import GoToGoal, GoToGoalParams
from behaviours.laws.obstacles import mover_sweep
from executive.core.frames import AircraftPlacement, FloatArray, Pose2
from executive.core.model import Frame, Mission
from executive.core.records import Obstacles, PoseEstimate

Status = py_trees.common.Status

_WORKER = ThreadPoolExecutor(max_workers=1, thread_name_prefix="walkaround-planner")


def known_polygons(mission: Mission, placement: AircraftPlacement) -> list[FloatArray]:
    """The aircraft footprint and the forbidden zones as outlines in A."""
    outlines: list[FloatArray] = [
        placement.to_airport_xy(shape.vertices(48)) for shape in mission.aircraft.footprint
    ]
    for zone in mission.airport.zones:
        pts = zone.shape.vertices(48)
        outlines.append(placement.to_airport_xy(pts) if zone.frame is Frame.AIRCRAFT else pts)
    return outlines


def path_blocked_by(points: FloatArray, path: FloatArray, radius: float) -> bool:
    """Whether any of ``points`` (N, 2) lies closer than ``radius`` to the polyline
    ``path`` (M, 2), M >= 1 (a single point: the distance to it)."""
    if len(points) == 0 or len(path) == 0:
        return False
    if len(path) == 1:
        return bool((np.hypot(*(points - path[0]).T) < radius).any())
    a, b = path[:-1], path[1:]  # (S, 2) segments
    ab = b - a
    length2 = np.maximum((ab * ab).sum(axis=1), 1e-12)
    rel = points[:, None, :] - a[None, :, :]  # (N, S, 2)
    t = np.clip((rel * ab[None]).sum(axis=2) / length2[None], 0.0, 1.0)
    gap = rel - t[..., None] * ab[None]
    return bool((np.hypot(gap[..., 0], gap[..., 1]) < radius).any())


def plan_path(
    start: tuple[float, float],
    goal: tuple[float, float],
    points: FloatArray,
    polygons: Iterable[FloatArray],
    robot_radius: float,
    clearance: float,
    goal_tolerance: float,
) -> PlannedPath | None:
    """One planning request (runs in the worker)."""
    costmap = Costmap.around(start, goal, margin=8.0, resolution=0.1)
    costmap.add_points(points)
    costmap.add_polygons(polygons)
    costmap.inflate(robot_radius, clearance)
    return costmap.plan(start, goal, goal_tolerance=goal_tolerance)


class FollowPlannedPath(AvoidanceController):
    """Plan around the trap on a costmap and follow the waypoints with go-to-goal."""

    def __init__(
        self,
        goal: Goal,
        session: AvoidanceSession,
        mission: Mission,
        period: float,
        params: GoToGoalParams,
        plan_delay: float = 0.5,
        waypoint_tolerance: float = 0.4,
        lookahead: float = 3.0,
        known_tolerance: float = 0.3,
        mover_horizon: float = 5.0,
        name: str = "fallback planner",
    ) -> None:
        super().__init__(goal, session, mission.platform, period, name)
        self.mission = mission
        platform = mission.platform
        # a path cell keeps the robot's circumscribed circle r_ES (+ a little) clear of
        # every obstacle, so following it never trips the e-stop
        self.radius = platform.turning_radius + mission.safety.r_es + 0.15
        # ...and a return that comes closer than this to the path ahead would trip it
        self.blocking = platform.turning_radius + mission.safety.r_es
        self.lookahead, self.known_tolerance = lookahead, known_tolerance
        self.mover_horizon = mover_horizon
        self.replans = 0
        self.params = dataclasses.replace(
            params, position_tolerance=waypoint_tolerance, allow_reverse=False
        )
        self.plan_delay, self.waypoint_tolerance = plan_delay, waypoint_tolerance
        self.path: PlannedPath | None = None
        self._future: Future[PlannedPath | None] | None = None
        self._cloud = np.zeros((0, 2))
        """The returns (in A) the plan being made or followed was made from."""
        self._known: cKDTree | None = None
        self._apply_at = 0.0
        self._next = 1
        self._law: GoToGoal | None = None
        self._law_waypoint = 0
        """The waypoint :attr:`_law` approaches."""

    def initialise(self) -> None:
        super().initialise()
        self._forget_plan()

    def _forget_plan(self) -> None:
        """Drop the plan (made, being made or followed): the next tick plans again."""
        self.path, self._future, self._next, self._law = None, None, 1, None
        self._known = None

    def update(self) -> Status:
        obstacles: Obstacles | None = self.read(OBSTACLES)
        pose: PoseEstimate | None = self.read(POSE)
        if obstacles is None or pose is None:
            return self.brake("no pose or obstacles")
        if self.path is None:
            return self._await_plan(obstacles, pose)
        waypoints = self.path.waypoints
        robot = pose.pose_a
        while self._next < len(waypoints) - 1 and (
            math.hypot(*(waypoints[self._next] - (robot.x, robot.y))) < self.waypoint_tolerance
        ):
            self._next += 1
        if self._blocked(obstacles, robot):
            self.replans += 1
            self._forget_plan()
            return self.brake(f"path blocked: planning again ({self.replans})")
        x, y = waypoints[self._next]
        if self._next == len(waypoints) - 1 and math.hypot(x - robot.x, y - robot.y) < (
            self.waypoint_tolerance
        ):
            self.session.released, self.session.reason = True, "end of the planned path"
            return self.brake("end of the planned path")
        heading = math.atan2(y - robot.y, x - robot.x)
        if self._law is None:
            self._law = GoToGoal(self.params)
        elif self._law_waypoint != self._next:  # a waypoint close to the last one is
            self._law.new_goal()  # another goal all the same (campaign episode 375)
        self._law_waypoint = self._next
        out = self._law.command(
            robot, Pose2(float(x), float(y), heading), goal_heading=False, dt=self.period
        )
        return self.drive(out.v, out.omega, f"waypoint {self._next}/{len(waypoints) - 1}")

    def _blocked(self, obstacles: Obstacles, robot: Pose2) -> bool:
        """Whether a current return, further than :attr:`blocking` from the robot, lies
        within it of the path ahead: from the robot through the next waypoints,
        ``lookahead`` m of it."""
        assert self.path is not None
        points = obstacles.points
        if len(points) == 0:
            return False
        # returns about the robot's own spot are the safety layer's (the robot was trapped
        # among them): only those further along the path count
        reach = np.hypot(points[:, 0], points[:, 1])
        near = points[(reach >= self.blocking) & (reach < self.lookahead + self.blocking)]
        if len(near) == 0:
            return False
        near = robot.apply(near)
        if self._known is not None:  # what the plan was made round does not block it
            distance, _ = self._known.query(near, distance_upper_bound=self.known_tolerance)
            near = near[np.isinf(distance)]
            if len(near) == 0:
                return False
        ahead = [np.array([robot.x, robot.y])]
        travelled = 0.0
        for waypoint in self.path.waypoints[self._next :]:
            travelled += float(np.hypot(*(waypoint - ahead[-1])))
            ahead.append(np.asarray(waypoint, dtype=float))
            if travelled >= self.lookahead:
                break
        return path_blocked_by(near, np.array(ahead), self.blocking)

    def _await_plan(self, obstacles: Obstacles, pose: PoseEstimate) -> Status:
        now = obstacles.stamp
        if self._future is None:
            robot = pose.pose_a
            target = self.goal.in_airport(pose)
            points = [robot.apply(obstacles.points)] if len(obstacles.points) else []
            if len(obstacles.virtual):
                points.append(robot.apply(obstacles.virtual))
            sweep = mover_sweep(obstacles.tracks, self.mover_horizon)
            if len(sweep):
                points.append(robot.apply(sweep))
            cloud = np.vstack(points) if points else np.zeros((0, 2))
            self._cloud = cloud
            placement = pose.placement or self.goal.nominal
            self._future = _WORKER.submit(
                plan_path,
                (robot.x, robot.y),
                (target.x, target.y),
                cloud,
                known_polygons(self.mission, placement),
                self.radius,
                0.5,
                0.3,
            )
            self._apply_at = now + self.plan_delay
            return self.brake("planning")
        if now < self._apply_at:
            return self.brake("planning")
        path = self._future.result()
        if path is None:
            self.session.released, self.session.reason = True, "no path on the costmap"
            return self.brake("no path on the costmap")
        self.path = path
        self._known = cKDTree(self._cloud) if len(self._cloud) else None
        return self.brake(f"planned {path.length:.1f} m, {len(path.waypoints) - 1} legs")
