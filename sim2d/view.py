"""Top view of a sim2d world (``walkaround sim-view``): what is where, and what the robot sees.

Draws, in the airport frame: the aircraft's overhead outline and footprint at its true
parking pose, forbidden zones, the mission route and checkpoints (at the nominal pose,
where the mission believes they are), static and moving obstacles (with their paths),
the robot, one scan of each laser, and each camera's field of view. Every mark is tagged
with its kind (:mod:`sim2d.labels`): the legend beside the plot lists each kind drawn, and
only those; the checkpoint labels are placed where they collide with nothing.
"""

from __future__ import annotations

import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.patches import Polygon as PolygonPatch

from executive.core.frames import AircraftPlacement, Pose2
from executive.core.model import Circle, Frame, Mission, Shape
from sim2d.cameras import airport_from_camera
from sim2d.labels import Label, fit_height, kinds_legend, place_labels, tag, tag_all
from sim2d.robot import SimRobot
from sim2d.scenario import Chaser, LoiteringGroup, PathMover, StaticObstacle

ZONE_COLOURS = {
    "refuelling": "#e6550d",
    "engine-danger": "#de2d26",
    "apu-exhaust": "#fd8d3c",
    "vehicle-parking": "#9e9ac8",
    "equipment": "#9e9ac8",
    "no-go": "#636363",
}


def _ring(shape: Shape, placement: AircraftPlacement | None) -> np.ndarray:
    pts = shape.vertices(48) if isinstance(shape, Circle) else np.array(shape.points)
    return placement.to_airport_xy(pts) if placement is not None else pts


def _patch(ax: Axes, ring: np.ndarray, kind: str, **style: object) -> None:
    tag(ax.add_patch(PolygonPatch(ring, closed=True, **style)), kind)


def route_points(mission: Mission) -> list[tuple[str, float, float]]:
    """The whole route in A at the nominal pose: station, approach, checkpoints, return."""
    nominal = mission.nominal_placement()

    def in_a(x: float, y: float, frame: Frame) -> tuple[float, float]:
        if frame is Frame.AIRCRAFT:
            ax_, ay_ = nominal.to_airport_xy((x, y))
            return float(ax_), float(ay_)
        return x, y

    st = mission.airport.station
    pts = [("station", st.x, st.y)]
    pts += [(w.id, *in_a(w.x, w.y, w.frame)) for w in mission.approach]
    pts.append(("P", mission.handover.x, mission.handover.y))
    for c in mission.checkpoints:
        pts += [(f"{c.id} via", *in_a(vx, vy, Frame.AIRCRAFT)) for vx, vy in c.via]
        pts.append((c.id, *in_a(c.pose.x, c.pose.y, Frame.AIRCRAFT)))
    pts += [(w.id, *in_a(w.x, w.y, w.frame)) for w in mission.return_route]
    pts += [("P", mission.handover.x, mission.handover.y), ("station", st.x, st.y)]
    return pts


def draw_world(
    ax: Axes, robot: SimRobot, *, scans: bool = True, cameras: bool = True
) -> list[Label]:
    """Draw the world of ``robot`` on ``ax`` (airport frame, metres); returns the labels
    to place (:func:`sim2d.labels.place_labels`): the checkpoints' names at the nominal
    pose."""
    scenario = robot.scenario
    mission = scenario.mission
    true = robot.world.placement
    for poly in mission.aircraft.outline:
        _patch(
            ax,
            _ring(poly, true),
            "aircraft outline",
            facecolor="#d9d9d9",
            edgecolor="#969696",
            lw=0.6,
        )
    for shape in mission.aircraft.footprint:
        _patch(
            ax,
            _ring(shape, true),
            "aircraft footprint",
            facecolor="#252525",
            edgecolor="black",
            lw=0.6,
        )
    for zone in mission.airport.zones:
        ring = _ring(zone.shape, true if zone.frame is Frame.AIRCRAFT else None)
        colour = ZONE_COLOURS.get(zone.kind.value, "#de2d26")
        _patch(
            ax,
            ring,
            f"forbidden zone: {zone.kind.value}",
            facecolor=colour,
            alpha=0.25,
            edgecolor=colour,
            hatch="//",
            lw=0.8,
        )

    route = route_points(mission)
    xs, ys = [p[1] for p in route], [p[2] for p in route]
    tag_all(ax.plot(xs, ys, color="#3182bd", lw=0.8, ls="--", zorder=2), "route (as planned)")
    nominal = mission.nominal_placement()
    labels = []
    if mission.checkpoints:
        poses = [nominal.pose_to_airport(cp.pose) for cp in mission.checkpoints]
        tag_all(
            ax.plot(
                [p.x for p in poses], [p.y for p in poses], "o", color="#31a354", ms=4, zorder=3
            ),
            "checkpoint (as planned)",
        )
        labels = [Label(cp.id, p.x, p.y) for cp, p in zip(mission.checkpoints, poses, strict=True)]

    for ob in scenario.obstacles:
        if isinstance(ob, StaticObstacle):
            shape = (
                Circle(ob.id, ob.pose.x, ob.pose.y, ob.body.radius)
                if ob.body.radius is not None
                else ob.body.polygon(ob.pose)
            )
            _patch(
                ax,
                _ring(shape, None),
                "static obstacle",
                facecolor="#8c6d31",
                edgecolor="black",
                lw=0.5,
            )
        elif isinstance(ob, PathMover):
            wp = np.array(ob.waypoints)
            tag_all(ax.plot(wp[:, 0], wp[:, 1], ":", color="#756bb1", lw=1.0), "mover's path")
        elif isinstance(ob, LoiteringGroup):
            ring = Circle(ob.id, *ob.center, ob.radius).vertices(48)
            _patch(ax, ring, "loitering area", fill=False, edgecolor="#756bb1", ls=":", lw=1.0)
        elif isinstance(ob, Chaser) and ob.trigger_radius:
            ring = Circle(ob.id, *ob.start, ob.trigger_radius).vertices(64)
            _patch(
                ax, ring, "chaser's trigger radius", fill=False, edgecolor="#e7298a", ls=":", lw=0.6
            )
    for m, (name, x, y, heading) in zip(
        robot.world.moving, robot.world.obstacle_poses(), strict=True
    ):
        body = m.shape_body
        shape = (
            Circle(name, x, y, body.radius)
            if body.radius is not None
            else body.polygon(Pose2(x, y, heading))
        )
        _patch(
            ax,
            _ring(shape, None),
            "moving obstacle",
            facecolor="#756bb1",
            edgecolor="black",
            lw=0.5,
        )

    pose = robot.truth.robot
    frame = robot.read()
    if scans:
        for lid, scan in frame.scans.items():
            laser = robot.lasers[lid][0]
            pts = laser.pose_in_world(pose).apply(scan.points()) if len(scan.ranges) else None
            if pts is not None and len(pts):
                tag_all(
                    ax.plot(pts[:, 0], pts[:, 1], ".", ms=1.0, color="#e31a1c", zorder=4),
                    "laser scan",
                )
    if cameras:
        for rig, _ in robot.rigs:
            unit = robot.units[rig.unit]
            a_from_c = airport_from_camera(rig, unit.pan, unit.tilt, pose)
            origin = a_from_c.translation[:2]
            axis = a_from_c.rotation[:2, 2]
            heading = math.atan2(axis[1], axis[0])
            half = rig.spec.horizontal_fov / 2
            reach = 12.0
            wedge = [origin] + [
                origin + reach * np.array([math.cos(a), math.sin(a)])
                for a in np.linspace(heading - half, heading + half, 12)
            ]
            _patch(
                ax,
                np.array(wedge),
                "camera field of view",
                facecolor="#fee391",
                alpha=0.25,
                edgecolor="#fec44f",
                lw=0.4,
            )
    body = Pose2(pose.x, pose.y, pose.theta)
    hl, hw = mission.platform.length / 2, mission.platform.width / 2
    corners = body.apply([(hl, hw), (-hl, hw), (-hl, -hw), (hl, -hw)])
    _patch(ax, corners, "robot", facecolor="#08519c", edgecolor="black", lw=0.6, zorder=5)
    ax.annotate(
        "",
        xy=tuple(body.apply((hl + 1.0, 0.0))),
        xytext=(pose.x, pose.y),
        arrowprops={"arrowstyle": "->", "color": "#08519c"},
    )
    return labels


def world_figure(robot: SimRobot, *, title: str | None = None) -> Figure:
    """The top view of the robot's world: the world, its legend, the placed labels."""
    fig, ax = plt.subplots(figsize=(12, 10), dpi=120, layout="constrained")
    labels = draw_world(ax, robot)
    ax.set_aspect("equal")
    ax.autoscale_view()
    ax.set_xlabel("x east (m)")
    ax.set_ylabel("y north (m)")
    scenario = robot.scenario
    ax.set_title(title or f"{scenario.id} — {scenario.mission.id} at t = {robot.time:.1f} s")
    ax.grid(True, lw=0.3, alpha=0.5)
    fit_height(fig, ax)
    kinds_legend(fig, ax)
    place_labels(fig, ax, labels, avoid=[(robot.truth.robot.x, robot.truth.robot.y)])
    return fig


def render_world(robot: SimRobot, out: Path, *, title: str | None = None) -> Path:
    """Write a PNG (or SVG/PDF by suffix) top view of the robot's world."""
    fig = world_figure(robot, title=title)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out)
    plt.close(fig)
    return out
