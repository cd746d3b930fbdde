"""When to register the aircraft from the laser returns, and how the result is used.

The maths (footprint model, RANSAC on footprint correspondences, ICP) is in
:mod:`behaviours.laws.registration`; this module is the policy around it, after the
thesis's point-cloud matching (seed lines 1053-1147, Algorithm 2.2):

* **global** registration (RANSAC then ICP) when the aircraft comes into view, whenever
  the estimate is not registered (never, or lost) and when the pose confidence in F
  drops below ``relocalise_confidence``; at most every ``global_period`` s, so a failed
  attempt does not eat every tick;
* **tracking**: while registered, a cheap ICP refinement from the current estimate every
  ``track_period`` s, so the pose in F never drifts with the odometry;
* a result is used only if its fit is good (inliers, rms, well conditioned) and the
  pose filter's Mahalanobis gate accepts it. A *global* result the gate refuses
  ``reset_after`` times in a row means the filter, not the matching, is wrong: the
  placement is re-initialised from it;
* **lost**: no accepted registration for ``lost_after`` s while the aircraft is in view
  (occluded by vehicles, or too far). The pose in F is then carried by odometry from the
  last checkpoint reached — the thesis's back-up frame (seed lines 1030-1040) — and the
  estimate says so (:class:`FrameReference`).

The thesis stopped the robot for every matching; the runtime cost here is a few
milliseconds for tracking (in the tick) and ~10-50 ms for a global step (in a worker
thread, applied a fixed ``global_latency`` after its scans), so the robot keeps moving,
and the estimate's ``confidence_f`` tells a guard when it must stop instead.

Latency: the scans are older than the filter (they arrive at 40 Hz, the filter runs on
the 100 Hz wheels). The prior is taken back to the scans' time and the result carried
forward to now along the filter's own motion (:func:`moved_in_aircraft`), so a robot at
1 m/s does not read a 2.5 cm lag as a registration error.
"""

from __future__ import annotations

import math
import weakref
from collections.abc import Mapping
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from behaviours.laws.localisation import CHI2_999, PoseFilter
from behaviours.laws.registration import (
    FootprintModel,
    Registration,
    SightLines,
    points_from_scans,
    refine,
    register,
)
from behaviours.sensing.pose_history import PoseHistory
from executive.core.frames import Pose2, moved_in_aircraft
from executive.core.model import Aircraft, LaserSpec
from executive.core.records import FrameReference, RegistrationRecord, SensorFrame


@dataclass(frozen=True, slots=True)
class RegistrationPolicy:
    """The knobs of :class:`AircraftRegistrar` (SI units)."""

    global_period: float = 1.0
    """Seconds between two global attempts while not registered."""
    track_period: float = 0.25
    """Seconds between two ICP refinements while registered."""
    view_range: float = 20.0
    """The aircraft is in view when a footprint element is this close to the robot (m)."""
    min_inliers: int = 30
    """Fewest scan points on the footprint for a usable result."""
    max_rms: float = 0.06
    """Largest rms distance of the inliers to the footprint (m)."""
    lost_after: float = 6.0
    """Seconds in view without an accepted registration before the estimate is lost."""
    relocalise_confidence: float = 0.5
    """Below this ``confidence_f`` a registered estimate asks for a global registration
    again (ICP tracking from a doubtful pose could lock onto the wrong face)."""
    gate: float = CHI2_999[3]
    """Mahalanobis gate of a registration in the pose filter."""
    reset_after: int = 3
    """Consecutive gate refusals of good *global* results before the placement is reset."""
    min_covariance: tuple[float, float] = (0.01, math.radians(0.2))
    """Floor of the registration's 1-sigma (m, rad): the footprint is a model, not truth."""
    history: float = 1.0
    """Seconds of filter poses kept to carry a result from the scans' time to now."""
    global_latency: float = 0.1
    """A global registration runs in a worker thread beside the tick loop (it takes ~10 ms,
    up to ~50 ms in clutter: too long for a 20 ms tick) and is applied this many seconds
    after its scans, waiting for it if needed; a fixed latency keeps dry-runs
    deterministic whatever the machine's speed."""


@dataclass(frozen=True, slots=True)
class _Job:
    """A global registration running in the worker."""

    future: Future[Registration | None]
    scan_stamp: float
    due: float


class AircraftRegistrar:
    """Registers the aircraft from both scans and feeds the pose filter."""

    def __init__(
        self,
        aircraft: Aircraft,
        lasers: Mapping[str, LaserSpec],
        policy: RegistrationPolicy | None = None,
    ) -> None:
        self.policy = policy or RegistrationPolicy()
        self.model = FootprintModel.from_aircraft(aircraft)
        self.lasers = dict(lasers)
        model = self.model
        self._elements = np.array(
            [
                model.samples[model.sample_element == k].mean(axis=0)
                for k in range(len(model.elements))
            ]
        )
        self._history = PoseHistory(self.policy.history)
        self._stamps: tuple[float, ...] = ()
        self._last_global = -math.inf
        self._last_track = -math.inf
        self._last_ok: float | None = None
        self._in_view_since: float | None = None
        self._refusals = 0
        self.registered = False
        self.ever_registered = False
        self.last: RegistrationRecord | None = None
        self.attempts = {"global": 0, "icp": 0}
        self.accepted = {"global": 0, "icp": 0}
        self._job: _Job | None = None
        self._pool: ThreadPoolExecutor | None = None

    def _submit(self, *args: object, **kwargs: object) -> Future[Registration | None]:
        if self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="registration")
            weakref.finalize(self, self._pool.shutdown, wait=False)
        return self._pool.submit(register, *args, **kwargs)  # type: ignore[arg-type]

    # -- bookkeeping ---------------------------------------------------------------------
    def record_pose(self, stamp: float, pose_a: Pose2) -> None:
        """Remember the filter's pose at ``stamp`` (call after every prediction)."""
        self._history.record(stamp, pose_a)

    def _pose_at(self, stamp: float, default: Pose2) -> Pose2:
        """The filter's pose at ``stamp`` (nearest kept sample; ``default`` if none)."""
        return self._history.at(stamp, default)

    def in_view(self, pose_f: Pose2) -> bool:
        d = np.hypot(self._elements[:, 0] - pose_f.x, self._elements[:, 1] - pose_f.y)
        return bool(np.min(d) <= self.policy.view_range)

    def reference(self) -> FrameReference:
        if self.registered:
            return FrameReference.AIRCRAFT
        return FrameReference.CHECKPOINT if self.ever_registered else FrameReference.NOMINAL

    # -- one tick ------------------------------------------------------------------------
    def step(self, frame: SensorFrame, pose_filter: PoseFilter) -> RegistrationRecord | None:
        """Register if the policy says so; returns the attempt's record (None: none made)."""
        now = frame.stamp
        policy = self.policy
        if self._job is not None:  # a global registration is running: apply it when due
            if now < self._job.due:
                return None
            job, self._job = self._job, None
            result = job.future.result()
            pose_now_a = pose_filter.pose
            delta = self._pose_at(job.scan_stamp, pose_now_a).inverse() @ pose_now_a
            record = self._use(now, job.scan_stamp, "global", result, delta, pose_filter)
            self.last = record
            return record
        pose_now_f = pose_filter.pose_f
        if not self.in_view(pose_now_f):
            self._in_view_since = None
            return None
        if self._in_view_since is None:
            self._in_view_since = now
        self._lose_if_stale(now)  # also when the lasers are silent
        if self.registered and pose_filter.confidence_f < policy.relocalise_confidence:
            self.registered = False  # the confidence dropped: match globally again
        scans = {lid: s for lid, s in frame.scans.items() if lid in self.lasers}
        stamps = tuple(s.stamp for s in scans.values())
        if not scans or stamps == self._stamps:
            return None
        method = "icp" if self.registered else "global"
        due = self._last_track if self.registered else self._last_global
        period = policy.track_period if self.registered else policy.global_period
        if now - due < period:
            return None
        self._stamps = stamps
        scan_stamp = max(stamps)
        # the filter's motion from the scans' time to now, in R at the scans' time
        pose_now_a = pose_filter.pose
        pose_scan_a = self._pose_at(scan_stamp, pose_now_a)
        delta = pose_scan_a.inverse() @ pose_now_a
        prior_f = moved_in_aircraft(pose_now_f, delta.inverse())
        points = points_from_scans(scans, self.lasers)
        self.attempts[method] += 1
        if method == "global":
            self._last_global = now
            cov_f = pose_filter.covariance_f
            future = self._submit(
                self.model,
                points,
                prior_f,
                prior_sigma_xy=max(0.2, math.sqrt(float(np.linalg.eigvalsh(cov_f[:2, :2])[-1]))),
                prior_sigma_theta=max(math.radians(1.0), math.sqrt(float(cov_f[2, 2]))),
                sight_lines=SightLines.from_scans(scans, self.lasers),
            )
            self._job = _Job(future, scan_stamp, scan_stamp + policy.global_latency)
            return None
        self._last_track = now
        result = refine(self.model, points, prior_f)
        record = self._use(now, scan_stamp, method, result, delta, pose_filter)
        self.last = record
        return record

    def _lose_if_stale(self, now: float) -> None:
        if not self.registered:
            return
        since = self._last_ok if self._last_ok is not None else -math.inf
        seen = self._in_view_since if self._in_view_since is not None else now
        if now - max(since, seen) > self.policy.lost_after:
            self.registered = False

    def _use(
        self,
        now: float,
        scan_stamp: float,
        method: str,
        result: Registration | None,
        delta: Pose2,
        pose_filter: PoseFilter,
    ) -> RegistrationRecord:
        policy = self.policy
        if result is None:
            return RegistrationRecord(
                now, scan_stamp, method, None, None, math.nan, 0.0, False, "no match"
            )
        pose_f = moved_in_aircraft(result.pose_f, delta)
        sx, sth = policy.min_covariance
        cov = np.asarray(result.covariance, dtype=float) + np.diag([sx * sx, sx * sx, sth * sth])

        def record(accepted: bool, reason: str) -> RegistrationRecord:
            return RegistrationRecord(
                now,
                scan_stamp,
                method,
                pose_f,
                cov,
                float(result.rms),
                float(result.inlier_fraction),
                accepted,
                reason,
            )

        if result.n_inliers < policy.min_inliers:
            return record(False, f"{result.n_inliers} inliers < {policy.min_inliers}")
        if not result.rms <= policy.max_rms:
            return record(False, f"rms {result.rms:.3f} m > {policy.max_rms:.3f} m")
        if not result.well_conditioned:
            return record(False, "ill-conditioned (too little of the footprint in view)")
        first = not self.ever_registered
        if pose_filter.update_registration(pose_f, cov, gate=None if first else policy.gate):
            self._accept(now, method)
            return record(True, "first registration" if first else "update")
        if method == "global":
            self._refusals += 1
            if self._refusals >= policy.reset_after:
                pose_filter.reset_placement(pose_f, cov)
                self._accept(now, method)
                return record(True, f"placement reset after {self._refusals} refusals")
        return record(False, "refused by the pose filter's gate")

    def _accept(self, now: float, method: str) -> None:
        self.accepted[method] += 1
        self._last_ok = now
        self._refusals = 0
        self.registered = True
        self.ever_registered = True
