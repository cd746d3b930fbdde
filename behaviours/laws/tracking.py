"""Multi-target tracking of laser clusters, and the danger level of each track.

The last step of the thesis's obstacle pipeline (seed 000, lines 780-830, Fig. 2.3 and
Algorithm 2.1): "achieve a tracking of the most relevant objects in the scene which in
turn allows object movement prediction, even if its only valid for a very short time
period". The clusters come from :mod:`behaviours.laws.laser_clusters`.

Filter (Bar-Shalom, Li & Kirubarajan 2001, *Estimation with Applications to Tracking and
Navigation*, §6.2): one constant-velocity Kalman filter per track, state
``s = (x, y, vx, vy)`` in a world-fixed frame W (the caller gives the robot's pose in W
with every scan; odometry or the localisation filter will do, as long as it is
continuous). Continuous white-noise acceleration of spectral density ``q = a^2``::

    F = [[I, dt I], [0, I]]      Q = q [[dt^3/3 I, dt^2/2 I], [dt^2/2 I, dt I]]

The measurement is the cluster's tracked point (circle centre, else centroid) in W,
``H = [I 0]``, with ``R = sigma^2 I``: ``sigma = position_sigma`` for a circle, and
``sqrt(position_sigma^2 + (size_sigma * size)^2)`` otherwise, since the centroid of a big
object seen partly slides as the view changes; a partial view (occluded, or not the
shape the track has) is down-weighted further (``partial_sigma``).

Data association: global nearest neighbour. Track-cluster pairs are gated by the squared
Mahalanobis distance of the innovation (``d^2 = y^T S^-1 y <= gate``, chi-square with 2
degrees of freedom) and assigned by minimising the sum of ``d^2 + ln det S`` (the
negative log-likelihood) with the Hungarian method (``scipy.optimize.
linear_sum_assignment``; Kuhn 1955). Because the prediction carries each track through
a crossing, two walkers who cross keep their identities.

Track management: an unassigned cluster starts a tentative track (zero velocity, velocity
standard deviation ``initial_speed_sigma``); ``confirm_hits`` assignments confirm it; a
tentative track not seen for ``tentative_timeout`` or a confirmed one not seen for
``coast_time`` is deleted. Only confirmed tracks are reported, as
:class:`executive.core.records.TrackedObstacle` in the robot frame R at the robot's pose
of the scan: position in R, ground velocity in R's axes, covariance rotated into R.

Danger level (:func:`danger_level`): NONE, NEAR (within r_OA-trigger of the footprint),
ON_PATH (the obstacle's constant-velocity prediction comes within ``width / 2 + margin +
size`` of the robot's predicted path, a straight line or an arc of constant
``(v, omega)``, within the horizon; or it is predicted to touch the robot), IMMINENT (on
the path, and predicted to touch the robot within ``imminent_time``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment

from behaviours.laws.laser_clusters import CIRCLE, KIND_NAMES, LINE, Clusters
from behaviours.laws.obstacles import footprint_distances
from executive.core.frames import FloatArray, Pose2
from executive.core.records import Danger, TrackedObstacle

IntArray = NDArray[np.intp]

_TWO_PI = 2.0 * math.pi
#: cost of a gated-out pair in the assignment (never chosen over a gated-in one)
_FORBIDDEN = 1e9
_NEAR, _ON_PATH, _IMMINENT = int(Danger.NEAR), int(Danger.ON_PATH), int(Danger.IMMINENT)


# -- danger ---------------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class DangerParams:
    """The robot and the thresholds of :func:`danger_level`.

    ``length``, ``width`` (m): the footprint, centred at the axle centre; ``margin`` (m)
    added to the half width (and to an obstacle's size) for the corridor and the contact
    test; ``r_oa_trigger`` (m): the avoidance trigger distance (NEAR); ``horizon`` (s) of
    the constant-velocity predictions, sampled at ``samples`` instants;
    ``imminent_time`` (s): a predicted contact sooner than this is IMMINENT.
    """

    length: float
    width: float
    margin: float = 0.2
    r_oa_trigger: float = 2.5
    horizon: float = 3.0
    imminent_time: float = 1.0
    samples: int = 16

    def __post_init__(self) -> None:
        if self.samples < 2 or not self.horizon > 0.0:
            raise ValueError("need samples >= 2 and horizon > 0")


def path_distance(points: FloatArray, v: float, omega: float, length: float) -> FloatArray:
    """Distance from ``points`` (..., 2) in R to the path of the axle centre driving
    ``length`` metres at constant ``(v, omega)`` from the origin (forwards when
    ``v > 0``): a segment along x, or an arc about the instantaneous centre of rotation
    ``(0, v / omega)``. A robot that does not drive (``v == 0``) has the origin as path.
    """
    px, py = points[..., 0], points[..., 1]
    if v == 0.0 or length <= 0.0:
        return np.hypot(px, py)
    direction = math.copysign(1.0, v)
    kappa = omega / v
    if abs(kappa) * length < 1e-9:  # straight
        s = np.minimum(np.maximum(direction * px, 0.0), length)
        return np.hypot(px - direction * s, py)
    rho = v / omega  # signed radius: the centre of rotation is (0, rho)
    sweep = min(abs(kappa) * length, _TWO_PI)
    start = -math.copysign(math.pi / 2.0, rho)  # angle of the origin seen from the centre
    end = start + math.copysign(sweep, omega)
    rel_y = py - rho
    along = ((np.arctan2(rel_y, px) - start) * math.copysign(1.0, omega)) % _TWO_PI
    to_arc = np.abs(np.hypot(px, rel_y) - abs(rho))
    ex, ey = abs(rho) * math.cos(end), rho + abs(rho) * math.sin(end)
    to_ends = np.minimum(np.hypot(px, py), np.hypot(px - ex, py - ey))
    return np.where(along <= sweep, to_arc, to_ends)


def danger_level(
    position: FloatArray,
    velocity: FloatArray,
    size: FloatArray,
    clearance: FloatArray,
    v: float,
    omega: float,
    params: DangerParams,
) -> NDArray[np.int8]:
    """:class:`Danger` codes (T,) of T obstacles in R: ``position`` (T, 2), ground
    ``velocity`` (T, 2) in R's axes, enclosing radius ``size`` (T,), ``clearance`` (T,)
    from the footprint, for a robot moving at ``(v, omega)``.

    Each obstacle moves at constant velocity and the robot at constant ``(v, omega)``
    over the horizon, sampled at ``params.samples`` instants. ON_PATH: a predicted
    obstacle position within ``width / 2 + margin + size`` of the path the axle centre
    sweeps within the horizon, extended by ``length / 2`` (the front of the robot at the
    horizon), or a predicted contact; contact: the predicted position within
    ``margin + size`` of the footprint at the same instant (in the robot's predicted
    frame); IMMINENT: on the path with the first contact within ``imminent_time``;
    NEAR: ``clearance <= r_oa_trigger``.
    """
    t = np.arange(params.samples) * (params.horizon / (params.samples - 1))
    q = position[:, None, :] + velocity[:, None, :] * t[:, None]  # (T, K, 2)
    reach = size[:, None] + params.margin
    # the robot's pose at each instant: exact arc of constant (v, omega)
    heading = omega * t
    if abs(omega) > 1e-12:
        rx, ry = v * np.sin(heading) / omega, v * (1.0 - np.cos(heading)) / omega
    else:
        rx, ry = v * t, np.zeros_like(t)
    dx, dy = q[..., 0] - rx, q[..., 1] - ry
    c, s = np.cos(heading), np.sin(heading)
    local = np.empty_like(q)
    local[..., 0] = c * dx + s * dy
    local[..., 1] = c * dy - s * dx
    gap = footprint_distances(local.reshape(-1, 2), params.length, params.width)
    contact = gap.reshape(q.shape[:2]) <= reach
    first = np.where(contact.any(axis=1), t[np.argmax(contact, axis=1)], np.inf)
    corridor = path_distance(q, v, omega, abs(v) * params.horizon + params.length / 2.0)
    on_path = (corridor <= reach + params.width / 2.0).any(axis=1) | np.isfinite(first)
    level = (clearance <= params.r_oa_trigger).astype(np.int8) * _NEAR
    level[on_path] = _ON_PATH
    level[on_path & (first <= params.imminent_time)] = _IMMINENT
    return level


# -- tracker --------------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class TrackerParams:
    """Parameters of :class:`ObstacleTracker` (SI units).

    ``accel_noise`` (m/s^2 per sqrt(Hz)): a, the white-noise acceleration (q = a^2);
    1 lets a walker start, stop and turn. ``position_sigma`` (m): measurement noise of a
    circle's centre or a small cluster's centroid (a floor for the biases of the fits,
    well above their white noise); ``size_sigma``: the extra measurement noise of a
    line's or blob's centroid, per metre of its size.
    ``partial_sigma``: a partial view of a track's object is biased by up to the object's
    size, so its measurement noise grows by ``partial_sigma`` times that size: it keeps
    the track alive without dragging it. Partial views: an occluded cluster; assigned to
    a circle track, a line, a blob, or a circle whose radius differs from the track's by
    more than ``radius_tolerance`` times it.
    ``initial_speed_sigma`` (m/s): velocity standard deviation of a new track.
    ``gate``: chi-square gate on the squared Mahalanobis distance (13.8: 99.9 % for 2
    degrees of freedom). ``confirm_hits``: assignments that confirm a track (M).
    ``tentative_timeout``, ``coast_time`` (s): a tentative, resp. confirmed, track not
    assigned for longer is deleted (1 s: a walker hidden by another while they cross).
    """

    accel_noise: float = 1.0
    position_sigma: float = 0.05
    size_sigma: float = 0.25
    initial_speed_sigma: float = 1.5
    partial_sigma: float = 5.0
    radius_tolerance: float = 0.25
    gate: float = 13.8
    confirm_hits: int = 3
    tentative_timeout: float = 0.1
    coast_time: float = 1.0


class ObstacleTracker:
    """Tracks the clusters of successive scans in a world-fixed frame W (module docstring).

    Call :meth:`update` with every :class:`Clusters` result, in time order, with the
    robot's pose in W at the scans' stamp and its velocity ``(v, omega)`` (command or
    measurement) for the danger levels.
    """

    def __init__(self, danger: DangerParams, params: TrackerParams | None = None) -> None:
        self.danger = danger
        self.params = params or TrackerParams()
        self.stamp: float | None = None
        self._next_id = 1
        self.state = np.zeros((0, 4))
        self.covariance = np.zeros((0, 4, 4))
        self.ids = np.zeros(0, dtype=np.intp)
        self.born = np.zeros(0)
        self.seen = np.zeros(0)  # stamp of the last assignment
        self.hits = np.zeros(0, dtype=np.intp)
        self.votes = np.zeros((0, len(KIND_NAMES)), dtype=np.intp)  # assignments per kind
        self.size = np.zeros(0)
        self.radius = np.zeros(0)
        self.line = np.zeros((0, 4))  # last line end points, in W
        self.clearance = np.zeros(0)

    def __len__(self) -> int:
        return len(self.ids)

    def update(
        self, clusters: Clusters, pose: Pose2, velocity: tuple[float, float] = (0.0, 0.0)
    ) -> tuple[TrackedObstacle, ...]:
        """Predict every track to ``clusters.stamp``, assign and update, manage tracks;
        return the confirmed tracks in R at ``pose`` (W <- R), with danger levels for the
        robot velocity ``(v, omega)``."""
        t = clusters.stamp
        dt = 0.0 if self.stamp is None else max(t - self.stamp, 0.0)
        self.stamp = t if self.stamp is None else max(self.stamp, t)
        self._predict(dt)
        p = self.params
        z = pose.apply(clusters.position) if len(clusters) else np.zeros((0, 2))
        is_circle = clusters.kind == CIRCLE
        r = np.where(
            is_circle,
            p.position_sigma**2,
            p.position_sigma**2 + (p.size_sigma * clusters.size) ** 2,
        )
        # a partial view (the cluster is occluded, or a circle track is seen as a line or
        # a blob, whose centroid is not the centre) is biased by up to the object's size
        circle_track = (2 * self.votes[:, CIRCLE] > self.hits)[:, None]
        off_radius = (
            np.abs(clusters.size - self.radius[:, None]) > p.radius_tolerance * self.radius[:, None]
        )
        partial = circle_track & (~is_circle | off_radius)
        partial |= clusters.occluded
        r_pair = r + partial * (p.partial_sigma * self.size[:, None]) ** 2
        rows, cols = self._associate(z, r_pair)
        self._correct(rows, z[cols], r_pair[rows, cols])
        self._describe(rows, cols, clusters, pose, t, ~partial[rows, cols])
        fresh = np.ones(len(clusters), dtype=bool)
        fresh[cols] = False
        new = np.flatnonzero(fresh)
        self._spawn(z[new], r[new], t)
        rows = np.arange(len(self) - len(new), len(self))
        self._describe(rows, new, clusters, pose, t, np.ones(len(new), dtype=bool))
        self._prune(t)
        return self._report(pose, velocity, t)

    # -- filter -----------------------------------------------------------------------------------
    def _predict(self, dt: float) -> None:
        if dt == 0.0 or len(self) == 0:
            return
        q = self.params.accel_noise**2
        q11, q12, q22 = q * dt**3 / 3.0, q * dt**2 / 2.0, q * dt
        self.state[:, :2] += dt * self.state[:, 2:]
        p = self.covariance  # F P F^T in place: rows, then columns
        p[:, :2, :] += dt * p[:, 2:, :]
        p[:, :, :2] += dt * p[:, :, 2:]
        p += np.array([[q11, 0, q12, 0], [0, q11, 0, q12], [q12, 0, q22, 0], [0, q12, 0, q22]])

    def _associate(self, z: FloatArray, r: FloatArray) -> tuple[IntArray, IntArray]:
        """Global nearest neighbour between the tracks and the measurements ``z`` (C, 2)
        of variance ``r`` (T, C): (track rows, cluster columns) of the gated pairs."""
        if len(self) == 0 or len(z) == 0:
            return np.zeros(0, dtype=np.intp), np.zeros(0, dtype=np.intp)
        p = self.covariance
        a = p[:, 0, 0, None] + r
        b = p[:, 0, 1, None]
        c = p[:, 1, 1, None] + r
        dx = z[:, 0] - self.state[:, 0, None]
        dy = z[:, 1] - self.state[:, 1, None]
        det = a * c - b * b
        d2 = (c * dx * dx - 2.0 * b * dx * dy + a * dy * dy) / det
        inside = d2 <= self.params.gate
        cost = np.where(inside, d2 + np.log(det), _FORBIDDEN)
        rows, cols = linear_sum_assignment(cost)
        keep = inside[rows, cols]
        return rows[keep], cols[keep]

    def _correct(self, rows: IntArray, z: FloatArray, r: FloatArray) -> None:
        """Kalman update of tracks ``rows`` with positions ``z`` of variance ``r``:
        ``K = P H^T S^-1``, ``P <- P - K S K^T = P - (P H^T) K^T`` (symmetrised)."""
        if len(rows) == 0:
            return
        p = self.covariance[rows]
        ph = p[:, :, :2]  # P H^T
        a, b, c = ph[:, 0, 0] + r, ph[:, 0, 1], ph[:, 1, 1] + r
        det = a * c - b * b
        s_inv = np.empty((len(rows), 2, 2))
        s_inv[:, 0, 0], s_inv[:, 1, 1] = c / det, a / det
        s_inv[:, 0, 1] = s_inv[:, 1, 0] = -b / det
        gain = ph @ s_inv  # (m, 4, 2)
        y = z - self.state[rows, :2]
        self.state[rows] += (gain @ y[:, :, None])[:, :, 0]
        p = p - ph @ gain.transpose(0, 2, 1)
        self.covariance[rows] = 0.5 * (p + p.transpose(0, 2, 1))

    # -- track management -------------------------------------------------------------------------
    def _spawn(self, z: FloatArray, r: FloatArray, t: float) -> None:
        """New tentative tracks at ``z``, at rest with a broad velocity prior."""
        n = len(z)
        if n == 0:
            return
        p = np.zeros((n, 4, 4))
        p[:, 0, 0] = p[:, 1, 1] = r
        p[:, 2, 2] = p[:, 3, 3] = self.params.initial_speed_sigma**2
        self.state = np.concatenate((self.state, np.column_stack((z, np.zeros((n, 2))))))
        self.covariance = np.concatenate((self.covariance, p))
        self.ids = np.concatenate((self.ids, self._next_id + np.arange(n)))
        self._next_id += n
        self.born = np.concatenate((self.born, np.full(n, t)))
        self.seen = np.concatenate((self.seen, np.full(n, t)))
        self.hits = np.concatenate((self.hits, np.zeros(n, dtype=np.intp)))
        self.votes = np.concatenate((self.votes, np.zeros((n, len(KIND_NAMES)), dtype=np.intp)))
        self.size = np.concatenate((self.size, np.zeros(n)))
        self.radius = np.concatenate((self.radius, np.zeros(n)))
        self.line = np.concatenate((self.line, np.zeros((n, 4))))
        self.clearance = np.concatenate((self.clearance, np.zeros(n)))

    def _describe(
        self,
        rows: IntArray,
        cols: IntArray,
        clusters: Clusters,
        pose: Pose2,
        t: float,
        whole: NDArray[np.bool_],
    ) -> None:
        """Record the assignment of clusters ``cols`` to tracks ``rows``: a vote for the
        cluster's kind and its clearance; its size and shape only where it is seen
        ``whole`` (not a partial view)."""
        if len(rows) == 0:
            return
        self.seen[rows] = t
        self.hits[rows] += 1
        self.votes[rows, clusters.kind[cols]] += 1
        self.clearance[rows] = clusters.clearance[cols]
        rows, cols = rows[whole], cols[whole]
        self.size[rows] = clusters.size[cols]
        circle = clusters.kind[cols] == CIRCLE
        self.radius[rows[circle]] = clusters.circle[cols[circle], 2]
        line = clusters.kind[cols] == LINE
        ends = clusters.line[cols[line]].reshape(-1, 2)
        self.line[rows[line]] = pose.apply(ends).reshape(-1, 4)

    def _prune(self, t: float) -> None:
        confirmed = self.hits >= self.params.confirm_hits
        limit = np.where(confirmed, self.params.coast_time, self.params.tentative_timeout)
        keep = t - self.seen <= limit
        if keep.all():
            return
        for name in (
            "state",
            "covariance",
            "ids",
            "born",
            "seen",
            "hits",
            "votes",
            "size",
            "radius",
            "line",
            "clearance",
        ):
            setattr(self, name, getattr(self, name)[keep])

    # -- output -----------------------------------------------------------------------------------
    def _report(
        self, pose: Pose2, velocity: tuple[float, float], t: float
    ) -> tuple[TrackedObstacle, ...]:
        out = np.flatnonzero(self.hits >= self.params.confirm_hits)
        if len(out) == 0:
            return ()
        inv = pose.inverse()
        rot = inv.rotation()
        position = inv.apply(self.state[out, :2])
        speed = self.state[out, 2:] @ rot.T
        block = np.zeros((4, 4))
        block[:2, :2] = block[2:, 2:] = rot
        covariance = block @ self.covariance[out] @ block.T
        # a circle track's fitted radius, else (never fitted whole) its enclosing radius;
        # the size is at least the fitted radius (a partial arc's enclosing circle is not)
        radius = np.where(self.radius[out] > 0.0, self.radius[out], self.size[out])
        size = np.maximum(self.size[out], self.radius[out])
        stale = self.seen[out] < t
        clearance = np.where(
            stale,
            np.maximum(
                footprint_distances(position, self.danger.length, self.danger.width) - size, 0.0
            ),
            self.clearance[out],
        )
        danger = danger_level(position, speed, size, clearance, *velocity, self.danger)
        kind = np.argmax(self.votes[out], axis=1)
        ends = inv.apply(self.line[out].reshape(-1, 2)).reshape(-1, 4)
        shapes = [
            (x, y, r) if k == CIRCLE else tuple(e) if k == LINE else ()
            for k, (x, y), r, e in zip(
                kind.tolist(),
                position.tolist(),
                radius.tolist(),
                ends.tolist(),
                strict=True,
            )
        ]
        return tuple(
            TrackedObstacle(
                id=i,
                kind=KIND_NAMES[k],
                position=(x, y),
                velocity=(vx, vy),
                covariance=cov,
                size=sz,
                clearance=cl,
                age=t - b,
                danger=Danger(d),
                shape=sh,
            )
            for i, k, (x, y), (vx, vy), cov, sz, cl, b, d, sh in zip(
                self.ids[out].tolist(),
                kind.tolist(),
                position.tolist(),
                speed.tolist(),
                covariance,
                size.tolist(),
                clearance.tolist(),
                self.born[out].tolist(),
                danger.tolist(),
                shapes,
                strict=True,
            )
        )
