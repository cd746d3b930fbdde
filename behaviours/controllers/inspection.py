"""Inspection (NDT, seed lines 1420-1452) and the mission's bookkeeping nodes.

The base stands still while each item is inspected: the pan-tilt unit of the inspection
camera turns to the item's feature, then the camera's detections decide. In sim2d an item
counts as inspected when its feature is detected by that camera; on the robot the NDT
software takes that place. Every result goes into :class:`MissionProgress`, which the
runtime journals.
"""

from __future__ import annotations

import dataclasses
import math

import py_trees

from behaviours.base import Controller, Node
from behaviours.keys import COMMAND, POSE, PROGRESS, SENSOR_FRAME, ItemResult, MissionProgress
from behaviours.laws.freshness import Freshness
from executive.core.frames import aircraft_from_robot, pan_tilt_towards
from executive.core.model import Aircraft, CameraSpec
from executive.core.records import PanTiltRate, PoseEstimate, SensorFrame, VelocityCommand

Status = py_trees.common.Status


class InspectItems(Controller):
    """Point ``camera`` at each item's feature in turn and record whether it is seen.

    For each item: turn the unit (proportional rate, within its limits) until the pan and
    tilt errors are under ``aim_tolerance``; then watch the camera's frames for
    ``look_time`` s: seen in any of them -> detected. ``item_timeout`` bounds each item.

    Only fresh images count (:mod:`behaviours.laws.freshness`): an image must be stamped
    after the unit was aimed at the item (so after the checkpoint was reached: the node
    starts there) and be new data — a frozen camera that goes on publishing its last image
    with fresh stamps repeats the same detections, which no live camera does. While no
    fresh image has come since the aim, the look goes on until ``item_timeout`` (a short
    freeze delays the item instead of failing it). Stale pan-tilt angles are not aimed
    with: the unit is held and the item waits. An item judged without a fresh image or
    with stale angles is recorded ``stale`` and not detected.
    """

    reads = (POSE, SENSOR_FRAME, PROGRESS)
    writes = (COMMAND, PROGRESS)

    def __init__(
        self,
        checkpoint: str,
        items: tuple[str, ...],
        aircraft: Aircraft,
        unit: CameraSpec,
        camera_ids: tuple[str, ...],
        aim_tolerance: float = math.radians(1.0),
        look_time: float = 0.5,
        item_timeout: float = 10.0,
        gain: float = 2.0,
        name: str = "inspect",
    ) -> None:
        super().__init__(name)
        self.checkpoint = checkpoint
        self.items = items
        self.aircraft = aircraft
        self.unit = unit
        self.camera_ids = camera_ids
        self.aim_tolerance = aim_tolerance
        self.look_time = look_time
        self.item_timeout = item_timeout
        self.gain = gain
        # three camera periods, as the safety layer's default for the unit
        self.stale_limit = 3.0 / unit.rate_hz if unit.rate_hz > 0 else 0.5
        self._index = 0
        self._item_start: float | None = None
        self._aimed_at: float | None = None
        self._seen = False
        self._fresh_images = 0
        self._blind = False
        self._was_aimed = False
        self._images: dict[str, Freshness] = {}
        self._angles = Freshness(self.stale_limit)

    def initialise(self) -> None:
        # Re-entered after an operator's take-over: the items already recorded for this
        # checkpoint stay as they are (never inspected, nor recorded, twice).
        progress: MissionProgress = self.read(PROGRESS, MissionProgress())
        done = {r.item for r in progress.results if r.checkpoint == self.checkpoint}
        self._index = 0
        while self._index < len(self.items) and self.items[self._index] in done:
            self._index += 1
        self._item_start = self._aimed_at = None
        self._seen = False
        self._fresh_images = 0
        self._blind = self._was_aimed = False
        # what the cameras showed before the node started is not known: the first image
        # seen is only a reference for the next one
        self._images = {cid: Freshness(self.stale_limit, True) for cid in self.camera_ids}
        self._angles = Freshness(self.stale_limit)

    def _aim(self, pose: PoseEstimate, item: str) -> tuple[float, float]:
        feature = self.aircraft.feature_of(item)
        target_r = (
            aircraft_from_robot(pose.pose_f, self.aircraft.origin_height)
            .inverse()
            .apply(feature.centroid())
        )
        pan, tilt = pan_tilt_towards(self.unit.mount, self.unit.mount_yaw, target_r)
        lo, hi = self.unit.pan_limits
        if not lo <= pan <= hi:  # the other way round may be within the limits
            pan = pan - 2 * math.pi if pan > hi else pan + 2 * math.pi
        return min(max(pan, lo), hi), min(
            max(tilt, self.unit.tilt_limits[0]), self.unit.tilt_limits[1]
        )

    def update(self) -> Status:
        if self._index >= len(self.items):
            self.write(COMMAND, VelocityCommand.stop())
            return Status.SUCCESS
        pose: PoseEstimate | None = self.read(POSE)
        frame: SensorFrame = self.read(SENSOR_FRAME)
        now = frame.stamp
        item = self.items[self._index]
        if self._item_start is None:
            self._item_start, self._aimed_at, self._seen = now, None, False
            self._fresh_images, self._blind, self._was_aimed = 0, False, False
        # every camera's freshness is followed on every tick, aimed or not; the first
        # image a camera shows the node is only a reference: it may be a frozen one
        fresh_images = {}
        for cid, cam in frame.cameras.items():
            if cid in self._images:
                known = self._images[cid].last_stamp is not None
                new = self._images[cid].observe(cam.stamp, cam.content)
                fresh_images[cid] = known and new
        angles = frame.pan_tilt.get(self.unit.id)
        if angles is not None:
            self._angles.observe(angles.stamp)
        if angles is None or self._angles.stale(now):  # where the camera looks is unknown
            angles, self._blind, self._aimed_at = None, True, None
        rate = PanTiltRate()
        if pose is not None and angles is not None:
            pan_goal, tilt_goal = self._aim(pose, item)
            # the goal is within the unit's limits and so is its pan: the straight
            # difference is the way that stays inside them (the short way round could
            # push against a limit of a +-180 deg unit for ever)
            e_pan, e_tilt = pan_goal - angles.pan, tilt_goal - angles.tilt
            aimed = abs(e_pan) < self.aim_tolerance and abs(e_tilt) < self.aim_tolerance
            if aimed and self._aimed_at is None:
                self._aimed_at, self._was_aimed = now, True
            if not aimed:
                self._aimed_at = None
                rate = PanTiltRate(self.gain * e_pan, self.gain * e_tilt)
            if self._aimed_at is not None:
                self._look(frame, item, fresh_images)
        self.write(COMMAND, VelocityCommand(0.0, 0.0, {self.unit.id: rate}))
        looked = (
            self._aimed_at is not None
            and now - self._aimed_at >= self.look_time
            and self._fresh_images > 0
        )
        timed_out = now - self._item_start >= self.item_timeout
        if self._seen or looked or timed_out:
            # not judged on fresh data: aimed but no fresh image came, or blind angles
            stale = not self._seen and (
                self._blind or (self._was_aimed and self._fresh_images == 0)
            )
            self._record(item, now, pose, frame.pan_tilt.get(self.unit.id), stale)
            self._index += 1
            self._item_start = None
        self.feedback_message = f"item {self._index}/{len(self.items)}: {item}"
        return Status.RUNNING

    def _look(self, frame: SensorFrame, item: str, fresh_images: dict[str, bool]) -> None:
        """Judge the item on the images that are fresh and taken after the aim."""
        assert self._aimed_at is not None
        feature = self.aircraft.items[item].feature
        for cid in self.camera_ids:
            cam = frame.cameras.get(cid)
            if cam is None or not fresh_images.get(cid, False) or not cam.stamp > self._aimed_at:
                continue
            self._fresh_images += 1
            self._seen = self._seen or any(d.feature == feature for d in cam.detections)

    def _record(
        self, item: str, now: float, pose: PoseEstimate | None, angles: object, stale: bool
    ) -> None:
        progress: MissionProgress = self.read(PROGRESS, MissionProgress())
        pf = pose.pose_f if pose is not None else None
        result = ItemResult(
            checkpoint=self.checkpoint,
            item=item,
            stamp=now,
            detected=self._seen and not stale,
            camera=self.unit.id,
            pan=getattr(angles, "pan", math.nan),
            tilt=getattr(angles, "tilt", math.nan),
            pose_f=(pf.x, pf.y, pf.theta) if pf is not None else (math.nan,) * 3,
            stale=stale,
        )
        self.write(PROGRESS, dataclasses.replace(progress, results=(*progress.results, result)))


class SetProgress(Node):
    """Mark the start of a phase or a checkpoint in :class:`MissionProgress`."""

    reads = (PROGRESS,)
    writes = (PROGRESS,)

    def __init__(
        self,
        phase: str,
        checkpoint: str | None = None,
        goal: str | None = None,
        done: bool = False,
        name: str | None = None,
    ) -> None:
        label = name or (f"{'done' if done else 'start'} {checkpoint or phase}")
        super().__init__(label)
        self.phase = phase
        self.checkpoint = checkpoint
        self.goal = goal
        self.done = done

    def update(self) -> Status:
        progress: MissionProgress = self.read(PROGRESS, MissionProgress())
        completed = progress.completed
        if self.done and self.checkpoint is not None and self.checkpoint not in completed:
            completed = (*completed, self.checkpoint)
        self.write(
            PROGRESS,
            dataclasses.replace(
                progress,
                phase=self.phase,
                checkpoint=self.checkpoint or progress.checkpoint,
                goal=self.goal,
                completed=completed,
            ),
        )
        return Status.SUCCESS


class StartMission(Node):
    """First node of the mission: writes the initial progress (empty, or resumed)."""

    writes = (PROGRESS,)

    def __init__(self, resumed: MissionProgress | None = None, name: str = "start mission") -> None:
        super().__init__(name)
        self.resumed = resumed or MissionProgress()

    def update(self) -> Status:
        self.write(PROGRESS, self.resumed)
        return Status.SUCCESS
