"""Servo targets and dwell for the checkpoints of a draft mission (issue 18).

The hand-written missions name, on each checkpoint, the camera unit and the feature that
visual servoing (issue 13, :mod:`behaviours.controllers.servo`) reaches the checkpoint on,
and how long the robot stands still there. A draft does the same, so that its dry-run is
like for like with theirs.

A feature is a servo target of a checkpoint pose when a camera unit of the platform that
servoes (the stereo and mono units: :func:`behaviours.controllers.servo.servo_cameras`
leaves the PTZ out) can take it, exactly as the compiler's
:class:`~behaviours.controllers.servo.ServoSession` will judge it:

1. **drivable**: with the unit at the desired pan and tilt of
   :func:`~behaviours.controllers.servo.desired_aim` (within its limits), at least
   :data:`~behaviours.laws.augmented_image.MIN_REAL_POINTS` points of the feature fall in
   the image of one of its cameras (``ServoCamera.reachable``, so ``servo.drivable`` and no
   ``servo-bearing-only`` warning). A PBVS target whose points in view do not fix its
   pose (fewer than 4, or on one line) is servoed by IBVS on the augmented image, as the
   servo session does for the hand-written missions' three-point targets;
2. **seen** with the planner's visibility tests 1-4
   (:func:`executive.planning.candidates.feature_views`: in range with margin, facing the
   camera, within the unit's limits and in its image, not hidden by the footprint) and the
   validator's (:func:`executive.core.checks.why_not_visible`), both from the checkpoint
   and from the servo start :data:`executive.compiler.SERVO_START` behind it on its
   heading line, where servoing begins;
3. **a clear servo start**: the robot may stop there (:meth:`FreeSpace.can_stop`), drive
   straight to it from the stop before (the last via point, the previous checkpoint or P)
   and from it to the checkpoint (:meth:`FreeSpace.can_drive`).

Among the features that qualify, those of the checkpoint's own items come first (in the
order of the items), then the others by distance from the checkpoint; the unit is the one
whose cameras see most of the feature's points (the platform's order on ties). The method
is the feature's own (``servo`` in the aircraft file; the compiler resolves ``auto``).

Dwell (:func:`template_dwell`): a draft checkpoint stands still as long as the longest
dwell of the template's checkpoints that inspect any of its items (the same robot and
inspection procedure); a checkpoint whose items the template does not inspect (another
aircraft type) takes the template's median dwell.
"""

from __future__ import annotations

import math
import statistics
from dataclasses import dataclass

import numpy as np

from behaviours.controllers.servo import servo_cameras
from behaviours.laws.augmented_image import MIN_REAL_POINTS
from executive.core import checks
from executive.core.frames import Pose2
from executive.core.model import CameraKind, Feature, Mission, ServoMethod
from executive.planning.candidates import feature_views
from executive.planning.space import FreeSpace

SERVO_START = 1.0
"""Metres behind the checkpoint, on its heading line, where the compiler starts visual
servoing (:data:`executive.compiler.SERVO_START`; kept equal by a test)."""


@dataclass(frozen=True)
class ServoTarget:
    """The servo camera unit, target feature and method of one checkpoint, and why."""

    camera: str
    feature: str
    method: ServoMethod
    points: int
    """Points of the feature in the unit's image at the checkpoint (its best camera)."""
    why: str


def servo_start(pose: Pose2) -> Pose2:
    """Where servoing towards ``pose`` starts: :data:`SERVO_START` behind it."""
    h = pose.theta
    return Pose2(pose.x - SERVO_START * math.cos(h), pose.y - SERVO_START * math.sin(h), h)


def _unit_points(mission: Mission, feature: Feature, pose: Pose2) -> dict[str, int]:
    """For each servo unit that can drive to ``pose`` on ``feature``: the most points one of
    its cameras has in view there (0 units: none can)."""
    out: dict[str, int] = {}
    for cam in servo_cameras(mission.platform, feature, pose, mission.aircraft.origin_height):
        if not cam.reachable or len(cam.points) < MIN_REAL_POINTS:
            continue
        out[cam.unit.id] = max(out.get(cam.unit.id, 0), len(cam.points))
    return out


def _seen(space: FreeSpace, unit_id: str, feature: Feature, poses: list[Pose2]) -> bool:
    mission = space.mission
    unit = mission.platform.cameras[unit_id]
    h0 = mission.aircraft.origin_height
    arr = np.array([[p.x, p.y, p.theta] for p in poses])
    seen = feature_views(space, unit, feature, arr)[0]
    return bool(seen.all()) and all(
        checks.why_not_visible(unit, feature, p, h0) is None for p in poses
    )


def choose_servo_target(
    space: FreeSpace,
    pose: Pose2,
    items: list[str],
    unit_ids: tuple[str, ...] | None = None,
    came_from: tuple[float, float] | None = None,
) -> tuple[ServoTarget | None, str]:
    """The servo target of a checkpoint at ``pose`` inspecting ``items`` (module docstring),
    or None and why not. ``unit_ids``: the units it may name (None: every servo unit);
    ``came_from``: the stop (in F) the robot drives to the servo start from, whose leg must
    be clear too."""
    mission = space.mission
    aircraft = mission.aircraft
    servo_units = [
        uid
        for uid, spec in mission.platform.cameras.items()
        if spec.kind is not CameraKind.PTZ and (unit_ids is None or uid in unit_ids)
    ]
    if not servo_units:
        return None, "the platform has no stereo or mono camera to servo with"
    start = servo_start(pose)
    if not bool(space.can_stop(np.array([[start.x, start.y]]))[0]):
        return None, (
            f"the servo start {SERVO_START:g} m behind it, ({start.x:.1f}, {start.y:.1f}), "
            "is too close to the footprint or a zone"
        )
    if not bool(space.can_drive([[start.x, start.y]], [[pose.x, pose.y]])[0]):
        return None, f"the straight servo approach from {SERVO_START:g} m behind it is not clear"
    if came_from is not None and not bool(
        space.can_drive([list(came_from)], [[start.x, start.y]])[0]
    ):
        return None, (
            f"the leg from ({came_from[0]:.1f}, {came_from[1]:.1f}) to the servo start "
            f"{SERVO_START:g} m behind it is not clear"
        )
    own: list[str] = []
    for item in items:
        f = aircraft.items[item].feature
        if f not in own:
            own.append(f)
    others = sorted(
        (f for f in aircraft.features if f not in own),
        key=lambda f: math.dist(aircraft.features[f].centroid()[:2], (pose.x, pose.y)),
    )
    for rank, fid in enumerate([*own, *others]):
        feature = aircraft.features[fid]
        if len(feature.points) < MIN_REAL_POINTS:
            continue
        units = {u: n for u, n in _unit_points(mission, feature, pose).items() if u in servo_units}
        units = {u: n for u, n in units.items() if _seen(space, u, feature, [pose, start])}
        if not units:
            continue
        best = max(units.values())
        unit = next(u for u in servo_units if units.get(u) == best)
        away = math.dist(feature.centroid()[:2], (pose.x, pose.y))
        whose = (
            "the feature of its own item(s)"
            if rank < len(own)
            else f"the nearest feature it can servo on ({away:.1f} m; none of its own items' "
            f"features shows {MIN_REAL_POINTS} points to a servo camera from here)"
        )
        why = (
            f"servo target '{fid}' ({feature.servo.value}, as the aircraft file says) on "
            f"camera '{unit}': {whose}; {best} of its {len(feature.points)} points in the "
            f"image at the checkpoint, seen from the servo start {SERVO_START:g} m behind it"
        )
        return ServoTarget(unit, fid, feature.servo, best, why), why
    return None, (
        f"no feature shows {MIN_REAL_POINTS} points to a servo camera "
        f"({', '.join(servo_units)}) both from here and from {SERVO_START:g} m behind"
    )


def template_dwell(template: Mission, items: list[str]) -> float:
    """Seconds a draft checkpoint inspecting ``items`` stands still (module docstring)."""
    by_item = {i: cp.dwell for cp in template.checkpoints for i in cp.items}
    mine = [by_item[i] for i in items if i in by_item]
    if mine:
        return max(mine)
    dwells = [cp.dwell for cp in template.checkpoints]
    return float(statistics.median(dwells)) if dwells else 0.0
