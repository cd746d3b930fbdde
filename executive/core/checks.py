"""Semantic checks of missions that need geometry: pure functions returning messages.

The loader calls these after the XSD has passed and the model has been built; each
returns ``None``/an empty list when fine, otherwise plain sentences for the engineer.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Iterable, Iterator

import numpy as np
from shapely.geometry import LineString
from shapely.geometry import Polygon as ShapelyPolygon
from shapely.geometry.base import BaseGeometry

from executive.core.frames import AircraftPlacement, Pose2, aircraft_from_robot, pan_tilt_towards
from executive.core.geometry import distance_to_shape, polygon_problem, to_shapely
from executive.core.model import CameraSpec, Feature, Frame, Mission

Point2 = tuple[float, float]

__all__ = [
    "SLOWEST_TICK",
    "clearance_problems",
    "leg_problems",
    "polygon_problem",
    "stopping_distance",
    "stopping_problem",
    "suggest",
    "why_no_camera_sees",
    "why_not_visible",
]


SLOWEST_TICK = 0.1
"""Seconds between two decisions at the executive's slowest rate (10 Hz): a mission
does not state the rate it runs at, so r_ES must hold at the slowest one."""


def stopping_distance(speed: float, deceleration: float, tick: float = SLOWEST_TICK) -> float:
    """Metres driven from seeing an obstacle to standing still: one tick of reaction at
    ``speed``, then braking at ``deceleration`` (v * T + v^2 / (2 a))."""
    return speed * tick + speed * speed / (2.0 * deceleration)


def stopping_problem(
    r_es: float, speeds: dict[str, float], deceleration: float, tick: float = SLOWEST_TICK
) -> str | None:
    """Why r_ES is too small for the robot to stop in it at the mission's top speed.

    The thesis sets the executive's deadline from emergency braking at maximum speed
    (seed 000, lines 4593-4630): the robot must stop before reaching what it detected at
    r_ES. ``speeds`` names each speed the mission commands (cruise, inspection, waypoint
    speeds); the fastest decides. ``deceleration`` is the platform's max-acceleration.
    """
    if not speeds or not r_es > 0.0 or not deceleration > 0.0:
        return None
    name, speed = max(speeds.items(), key=lambda item: item[1])
    if not math.isfinite(speed) or speed <= 0.0:
        return None
    needed = stopping_distance(speed, deceleration, tick)
    if r_es >= needed - 1e-9:  # exactly enough is enough (0.1 s * 1 m/s + 0.5 m = 0.6 m)
        return None
    return (
        f"r-es {r_es:g} m is shorter than the {needed:.2f} m the robot needs to stop from "
        f"{name} {speed:g} m/s with max-acceleration {deceleration:g} m/s^2: one "
        f"{tick:g} s tick of reaction ({speed * tick:.2f} m, the executive's slowest rate) "
        f"plus braking v^2/(2a) ({speed * speed / (2.0 * deceleration):.2f} m); raise r-es, "
        "lower the speed or raise max-acceleration"
    )


def suggest(name: str, known: Iterable[str]) -> str:
    """``" (did you mean 'x'?)"`` when a known name is close to ``name``, else ``""``."""
    close = difflib.get_close_matches(name, list(known), n=1, cutoff=0.6)
    return f" (did you mean '{close[0]}'?)" if close else ""


def clearance_problems(
    mission: Mission, placement: AircraftPlacement, label: str, x: float, y: float, frame: Frame
) -> Iterator[str]:
    """Why the robot cannot stop at (x, y): too close to the aircraft or to a forbidden zone.

    At every stop the robot may turn on the spot (align-first navigation, a final turn to
    the checkpoint heading), sweeping a circle of half its diagonal. The lasers see the
    aircraft like any obstacle, so that circle must stay r_ES clear of the footprint or
    the e-stop latches; and the geofence margin clear of every forbidden zone (the safety
    layer refuses to bring the footprint closer than that). Shapes are compared in their
    own frame (the airport <-> aircraft map is rigid).
    """
    turn = mission.platform.turning_radius
    r_es = mission.safety.r_es
    margin = mission.safety.geofence_margin
    if frame is Frame.AIRCRAFT:
        xy_f = (x, y)
        xy_a = tuple(placement.to_airport_xy((x, y)))
    else:
        xy_a = (x, y)
        xy_f = tuple(placement.to_aircraft_xy((x, y)))
    for shape in mission.aircraft.footprint:
        d = distance_to_shape(xy_f[0], xy_f[1], shape)
        if d < turn + r_es:
            where = "inside" if d == 0.0 else f"{d:.2f} m from"
            yield (
                f"{label} is {where} the aircraft footprint '{shape.id}'; the robot needs "
                f"{turn + r_es:.2f} m to turn on the spot without an emergency stop (half its "
                f"diagonal {turn:.2f} m + r_ES {r_es:.2f} m)"
            )
    for zone in mission.airport.zones:
        px, py = xy_f if zone.frame is Frame.AIRCRAFT else xy_a
        d = distance_to_shape(px, py, zone.shape)
        if d < turn + margin:
            where = "inside" if d == 0.0 else f"{d:.2f} m from"
            yield (
                f"{label} is {where} forbidden zone '{zone.id}' ({zone.kind.value}); the robot "
                f"needs {turn + margin:.2f} m to turn on the spot (half its diagonal "
                f"{turn:.2f} m + geofence margin {margin:.2f} m)"
            )


def leg_problems(
    mission: Mission, placement: AircraftPlacement, label: str, a: Point2, b: Point2
) -> Iterator[str]:
    """Why the robot cannot drive straight from ``a`` to ``b`` (both in A).

    Driving, the footprint sweeps half its width either side of the leg: that plus r_ES
    is needed from the aircraft footprint (or the e-stop latches), and that plus the
    geofence margin from every forbidden zone (the ends are checked as stops).
    """
    line = LineString([a, b])
    if line.length < 1e-9:
        return
    half = mission.platform.half_width
    r_es = mission.safety.r_es
    margin = mission.safety.geofence_margin
    for shape in mission.aircraft.footprint:
        d = line.distance(_in_airport(to_shapely(shape), placement))
        if d < half + r_es:
            yield (
                f"{label} passes {d:.2f} m from the aircraft footprint '{shape.id}'; the robot "
                f"needs {half + r_es:.2f} m to pass without an emergency stop (half its width "
                f"{half:.2f} m + r_ES {r_es:.2f} m): move a stop or add a via point"
            )
    for zone in mission.airport.zones:
        geom = to_shapely(zone.shape)
        if zone.frame is Frame.AIRCRAFT:
            geom = _in_airport(geom, placement)
        d = line.distance(geom)
        if d < half + margin:
            yield (
                f"{label} passes {d:.2f} m from forbidden zone '{zone.id}' ({zone.kind.value}); "
                f"the robot needs {half + margin:.2f} m (half its width {half:.2f} m + geofence "
                f"margin {margin:.2f} m): move a stop or add a via point"
            )


def _in_airport(geom: BaseGeometry, placement: AircraftPlacement) -> ShapelyPolygon:
    return ShapelyPolygon(placement.to_airport_xy(np.asarray(geom.exterior.coords)))


def _deg_range(limits: tuple[float, float]) -> str:
    return f"{math.degrees(limits[0]):.0f}..{math.degrees(limits[1]):.0f}"


def _within(angle: float, lo: float, hi: float) -> bool:
    return any(lo <= a <= hi for a in (angle, angle - 2 * math.pi, angle + 2 * math.pi))


def why_not_visible(
    camera: CameraSpec, feature: Feature, pose_f: Pose2, origin_height: float
) -> str | None:
    """Why ``camera`` cannot see ``feature`` from a robot at ``pose_f``, or None if it can.

    The feature's centroid must be within its detection range of the camera, and the
    pan-tilt unit must be able to bring it into the field of view: the pan and tilt that
    centre it may exceed the unit's limits by at most half the field of view.
    """
    f_from_r = aircraft_from_robot(pose_f, origin_height)
    target_r = f_from_r.inverse().apply(feature.centroid())
    mount = np.array(camera.mount)
    distance = float(np.linalg.norm(target_r - mount))
    if distance > feature.detection_range:
        return (
            f"is {distance:.1f} m from camera '{camera.id}', beyond its detection range "
            f"of {feature.detection_range:g} m"
        )
    pan, tilt = pan_tilt_towards(mount, camera.mount_yaw, target_r)
    half_h, half_v = camera.horizontal_fov / 2, camera.vertical_fov / 2
    if not _within(pan, camera.pan_limits[0] - half_h, camera.pan_limits[1] + half_h):
        return (
            f"needs a pan of {math.degrees(pan):.0f} deg on camera '{camera.id}', outside its "
            f"limits {_deg_range(camera.pan_limits)} deg (field of view included)"
        )
    if not camera.tilt_limits[0] - half_v <= tilt <= camera.tilt_limits[1] + half_v:
        return (
            f"needs a tilt of {math.degrees(tilt):.0f} deg on camera '{camera.id}', outside its "
            f"limits {_deg_range(camera.tilt_limits)} deg (field of view included)"
        )
    return None


def why_no_camera_sees(
    cameras: Iterable[CameraSpec], feature: Feature, pose_f: Pose2, origin_height: float
) -> str | None:
    """None if some camera can see ``feature`` from ``pose_f``; else why the nearest can't."""
    f_from_r = aircraft_from_robot(pose_f, origin_height)
    target_r = f_from_r.inverse().apply(feature.centroid())
    reasons = []
    for camera in cameras:
        reason = why_not_visible(camera, feature, pose_f, origin_height)
        if reason is None:
            return None
        reasons.append((float(np.linalg.norm(target_r - np.array(camera.mount))), reason))
    return min(reasons)[1] if reasons else "has no camera to look at it"
