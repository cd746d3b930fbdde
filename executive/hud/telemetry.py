"""What the HUD shows, built from the runtime every tick (issue 15).

:class:`Telemetry` is a runtime tick hook (``on_tick``): every :attr:`Telemetry.every`
ticks (10-12.5 Hz at 50 Hz) it builds a JSON-able snapshot of the run: the robot's pose
and its scans in the airport frame A, the tracked obstacles with their velocities, the
checkpoints with their status, the progress and the time to go, the active controller
with the guard that chose it, the alerts (e-stop and why, stale sensors, deadline misses,
geofence), the inspection results with the inspection camera's view of the target's
points, and the operator's side (:meth:`executive.operator.OperatorState.snapshot`). The
scene (aircraft footprint and zones in A through the current placement estimate, the
checkpoints, the station) is a separate message, rebuilt when the placement moves.

The runtime's thread writes, the web server's event loop reads: the latest snapshot and
scene are swapped in under a lock with a sequence number; a reader sends what is newer
than what it sent last.
"""

from __future__ import annotations

import logging
import math
import threading
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING

import numpy as np

from behaviours.keys import (
    FEATURES,
    OBSTACLES,
    POSE,
    PROGRESS,
    QUESTION,
    MissionProgress,
    OperatorQuestion,
)
from executive.core.frames import AircraftPlacement, Pose2
from executive.core.model import Frame, Mission
from executive.core.records import (
    FeatureObservations,
    Obstacles,
    PoseEstimate,
    SensorFrame,
    VelocityCommand,
    camera_ids,
)

if TYPE_CHECKING:
    from executive.operator import OperatorState
    from executive.runtime import Runtime

log = logging.getLogger("walkaround.hud")

SCAN_STRIDE = 3
"""Every this-many laser return is sent (a 1081-beam scan is 360 points)."""
PLACEMENT_MOVE = (0.01, math.radians(0.1))
"""The scene is rebuilt when the placement estimate moves this much (m, rad)."""
QUESTION_AGE = 0.5
"""A question the tree has not written for this long (s) is no longer asked."""
RESULTS_KEPT = 12
"""Inspection results kept for the HUD (the latest)."""

_STOP_ALERTS = {
    "estop-latched": "e-stop",
    "fault-stop": "fault",
    "stale-sensor": "stale sensor",
    "geofence-stop": "geofence",
}
_CLEARS = {
    "estop-released": "e-stop",
    "estop-reset": "e-stop",
    "sensor-fresh": "stale sensor",
    "geofence-clear": "geofence",
}


def _xy(values: np.ndarray) -> list[list[float]]:
    return [[round(float(x), 3), round(float(y), 3)] for x, y in values]


class Telemetry:
    """Snapshots of a run for the HUD; ``on_tick`` is a runtime tick hook."""

    def __init__(
        self,
        mission: Mission,
        *,
        rate_hz: float = 50.0,
        hud_hz: float = 12.5,
        operator: Callable[[], Mapping[str, object]] | None = None,
        status: Callable[[], Mapping[str, object]] | None = None,
        ask: Callable[[str, tuple[str, ...]], object] | None = None,
        withdraw: Callable[[], None] | None = None,
    ) -> None:
        self.mission = mission
        self.ask = ask
        self.withdraw = withdraw
        self._asked: str | None = None
        self.error: str | None = None
        """Why the telemetry stopped (a bug), or None."""
        self.every = max(1, round(rate_hz / hud_hz))
        self.operator = operator
        self.status = status
        self._lock = threading.Lock()
        self._seq = 0
        self._snapshot: dict[str, object] | None = None
        self._scene: dict[str, object] | None = None
        self._scene_seq = 0
        self._placement: AircraftPlacement | None = None
        self._ticks = 0
        self._events_seen = 0
        self._alerts: dict[str, str] = {}
        self._results: list[dict[str, object]] = []
        self._results_seen = 0
        self._started: float | None = None
        self._completed_at: list[float] = []
        self._trail: list[list[float]] = []
        self.set_placement(mission.nominal_placement())

    @classmethod
    def of_operator(
        cls,
        mission: Mission,
        state: OperatorState,
        rate_hz: float = 50.0,
        status: Callable[[], Mapping[str, object]] | None = None,
    ) -> Telemetry:
        """The telemetry of a run with ``state`` as its operator: the HUD shows the
        operator's side and posts the tree's questions to them."""
        return cls(
            mission,
            rate_hz=rate_hz,
            operator=state.snapshot,
            status=status,
            ask=state.ask,
            withdraw=state.withdraw,
        )

    # -- readers (the web server) ------------------------------------------------------------
    def latest(self) -> tuple[int, dict[str, object] | None]:
        with self._lock:
            return self._seq, self._snapshot

    def scene(self) -> tuple[int, dict[str, object] | None]:
        with self._lock:
            return self._scene_seq, self._scene

    # -- the scene ---------------------------------------------------------------------------
    def set_placement(self, placement: AircraftPlacement) -> None:
        """Rebuild the scene in A for ``placement`` when it moved enough."""
        old = self._placement
        if old is not None:
            moved = math.hypot(old.x - placement.x, old.y - placement.y)
            turned = abs(math.remainder(old.heading - placement.heading, math.tau))
            if moved < PLACEMENT_MOVE[0] and turned < PLACEMENT_MOVE[1]:
                return
        self._placement = placement
        m = self.mission
        footprint = [_xy(placement.to_airport_xy(s.vertices(32))) for s in m.aircraft.footprint]
        outline = [_xy(placement.to_airport_xy(s.vertices(32))) for s in m.aircraft.outline]
        zones = []
        for zone in m.airport.zones:
            pts = zone.shape.vertices(32)
            if zone.frame is Frame.AIRCRAFT:
                pts = placement.to_airport_xy(pts)
            zones.append({"id": zone.id, "kind": str(zone.kind.value), "points": _xy(pts)})
        checkpoints = []
        for cp in m.checkpoints:
            pose = placement.pose_to_airport(cp.pose)
            checkpoints.append(
                {
                    "id": cp.id,
                    "name": cp.name,
                    "x": round(pose.x, 3),
                    "y": round(pose.y, 3),
                    "theta": round(pose.theta, 4),
                }
            )
        station = m.airport.station
        scene = {
            "type": "scene",
            "mission": m.id,
            "aircraft": m.aircraft.type,
            "outline": outline,
            "footprint": footprint,
            "zones": zones,
            "checkpoints": checkpoints,
            "station": {"x": station.x, "y": station.y, "theta": station.theta},
            "robot": {"length": m.platform.length, "width": m.platform.width},
        }
        with self._lock:
            self._scene = scene
            self._scene_seq += 1

    # -- the tick hook -----------------------------------------------------------------------
    def on_tick(self, now: float, frame: SensorFrame, sent: VelocityCommand, rt: Runtime) -> None:
        """Follow the events every tick; build a snapshot every :attr:`every` ticks. The
        HUD is not on the robot's safety path: an error here stops the HUD's updates (and
        says why in :attr:`error`), not the mission."""
        if self.error is not None:
            return
        try:
            self._on_tick(now, frame, sent, rt)
        except Exception as exc:  # a HUD bug must not end the mission
            self.error = f"{type(exc).__name__}: {exc}"
            log.exception("the HUD's telemetry stopped")

    def _on_tick(self, now: float, frame: SensorFrame, sent: VelocityCommand, rt: Runtime) -> None:
        if self._started is None:
            self._started = now
        self._follow_events(rt)
        self._follow_question(now, rt)
        progress = rt._get(PROGRESS.name)
        if isinstance(progress, MissionProgress):
            self._follow_progress(now, progress, rt)
        self._ticks += 1
        if (self._ticks - 1) % self.every:
            return
        pose = rt._get(POSE.name)
        if isinstance(pose, PoseEstimate) and pose.placement is not None:
            self.set_placement(pose.placement)
        self.publish(self._snapshot_of(now, frame, sent, rt, pose, progress))

    def publish(self, snapshot: dict[str, object]) -> None:
        """Make ``snapshot`` the latest (the readers send it once)."""
        with self._lock:
            self._snapshot = snapshot
            self._seq += 1

    def _follow_question(self, now: float, rt: Runtime) -> None:
        """Post the tree's question to the operator once; withdraw it when no longer
        asked (the robot got free by itself)."""
        question = rt._get(QUESTION.name)
        asked = isinstance(question, OperatorQuestion) and now - question.stamp <= QUESTION_AGE
        if asked and question.id != self._asked:
            self._asked = question.id
            if self.ask is not None:
                self.ask(question.text, question.choices)
        elif not asked and self._asked is not None:
            self._asked = None
            if self.withdraw is not None:
                self.withdraw()

    def _follow_events(self, rt: Runtime) -> None:
        for event in rt.events[self._events_seen :]:
            if event.kind != "safety":
                continue
            kind = str(event.detail.get("kind", ""))
            reason = str(event.detail.get("reason", ""))
            if kind in _STOP_ALERTS:
                self._alerts[_STOP_ALERTS[kind]] = reason
            elif kind in _CLEARS:
                self._alerts.pop(_CLEARS[kind], None)
        self._events_seen = len(rt.events)

    def _follow_progress(self, now: float, progress: MissionProgress, rt: Runtime) -> None:
        while len(self._completed_at) < len(progress.completed):
            self._completed_at.append(now)
        if len(progress.results) <= self._results_seen:
            return
        features = rt._get(FEATURES.name)
        for result in progress.results[self._results_seen :]:
            self._results.append(self._result_view(result, features))
        self._results_seen = len(progress.results)
        del self._results[:-RESULTS_KEPT]

    def _result_view(self, result: object, features: object) -> dict[str, object]:
        """An inspection result with what its camera saw of the item's feature."""
        m = self.mission
        item = m.aircraft.items.get(getattr(result, "item", ""))
        feature = item.feature if item is not None else None
        camera = str(getattr(result, "camera", ""))
        spec = m.platform.cameras.get(camera)
        points: list[list[float]] = []
        if isinstance(features, FeatureObservations) and spec is not None and feature:
            for cid in camera_ids(m.platform, camera):
                for d in features.by_camera.get(cid, ()):
                    if d.feature == feature:
                        points.append([round(d.u, 1), round(d.v, 1)])
                if points:
                    break
        size = [spec.image_width_px, spec.image_height_px] if spec is not None else [0, 0]
        return {
            "checkpoint": getattr(result, "checkpoint", ""),
            "item": getattr(result, "item", ""),
            "feature": feature,
            "detected": bool(getattr(result, "detected", False)),
            "stale": bool(getattr(result, "stale", False)),
            "camera": camera,
            "points": points,
            "image": size,
        }

    def _snapshot_of(
        self,
        now: float,
        frame: SensorFrame,
        sent: VelocityCommand,
        rt: Runtime,
        pose: object,
        progress: object,
    ) -> dict[str, object]:
        robot = pose.pose_a if isinstance(pose, PoseEstimate) else None
        scans: list[list[float]] = []
        tracks: list[dict[str, object]] = []
        obstacles = rt._get(OBSTACLES.name)
        if robot is not None:
            if (
                len(self._trail) == 0
                or math.hypot(robot.x - self._trail[-1][0], robot.y - self._trail[-1][1]) > 0.1
            ):
                self._trail.append([round(robot.x, 2), round(robot.y, 2)])
                del self._trail[:-600]
            if isinstance(obstacles, Obstacles):
                if obstacles.points.size:
                    scans = _xy(robot.apply(obstacles.points[::SCAN_STRIDE]))
                tracks = [_track(t, robot) for t in obstacles.tracks if t.kind != "zone"]
        done = progress.completed if isinstance(progress, MissionProgress) else ()
        current = progress.checkpoint if isinstance(progress, MissionProgress) else None
        phase = progress.phase if isinstance(progress, MissionProgress) else "approach"
        total = len(self.mission.checkpoints)
        alerts = [{"kind": k, "text": v} for k, v in sorted(self._alerts.items())]
        misses = rt._missed_in_a_row
        if misses:
            alerts.append({"kind": "deadline", "text": f"{misses} tick deadlines missed in a row"})
        return {
            "type": "tick",
            "t": round(now, 2),
            "pose": None
            if robot is None
            else {"x": round(robot.x, 3), "y": round(robot.y, 3), "theta": round(robot.theta, 4)},
            "confidence": round(float(getattr(pose, "confidence", 0.0)), 3),
            "trail": self._trail[-300:],
            "scans": scans,
            "tracks": tracks,
            "phase": phase,
            "checkpoint": current,
            "completed": list(done),
            "total": total,
            "time_to_go": self._time_to_go(now, len(done), total),
            "controller": rt.controller,
            "why": _active_reason(rt),
            "command": {"v": round(sent.v, 3), "omega": round(sent.omega, 3)},
            "alerts": alerts,
            "results": self._results[-RESULTS_KEPT:],
            "operator": dict(self.operator()) if self.operator is not None else {},
            "link": dict(self.status()) if self.status is not None else {},
        }

    def _time_to_go(self, now: float, done: int, total: int) -> float | None:
        """The remaining checkpoints at the mean pace so far (None before the first)."""
        if done == 0 or self._started is None or not self._completed_at:
            return None
        pace = (self._completed_at[-1] - self._started) / done
        return round(pace * (total - done) + max(0.0, pace - (now - self._completed_at[-1])), 1)


def _active_reason(rt: Runtime) -> str:
    """The reason of the last controller switch (the guard that chose the controller)."""
    for event in reversed(rt.events):
        if event.kind == "controller":
            return str(event.detail.get("reason", ""))
    return ""


def _track(track: object, robot: Pose2) -> dict[str, object]:
    x, y = track.position
    vx, vy = track.velocity
    c, s = math.cos(robot.theta), math.sin(robot.theta)
    pa = robot.apply(np.array([[x, y]]))[0]
    return {
        "id": track.id,
        "kind": track.kind,
        "x": round(float(pa[0]), 3),
        "y": round(float(pa[1]), 3),
        "vx": round(c * vx - s * vy, 3),
        "vy": round(s * vx + c * vy, 3),
        "r": round(float(track.size), 3),
    }
