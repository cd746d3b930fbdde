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

The measurement is the cluster's tracked point (circle centre, middle of a line, else
centroid) in W, ``H = [I 0]``, with ``R = sigma^2 I``: ``sigma^2 = sigma_0^2 =
position_sigma^2 + (angular_sigma * range)^2`` for a circle, and
``sigma_0^2 + (size_sigma * size)^2`` otherwise, since the
centroid of a big object seen partly slides as the view changes; a partial view
(occluded, or not the shape the track has) is down-weighted further (``partial_sigma``).

Lines are measured by the fitted line itself, not by a point of their visible part. A
wall longer than the view, or cut by something in front, shows a part that changes as
the robot moves: the middle of that part slides along the wall at up to the robot's
speed, and a constant-velocity filter fed with it reports the static wall as a mover
(the empty lab's fence at 0.19 m/s, enough to engage avoidance). What a partial view
does fix is the line's position *across* itself: its motion along itself is unobservable
(the aperture problem; :func:`behaviours.laws.obstacles.observable_velocity` is the same
fact on the avoidance side). So a line assigned to a line track (a track whose
assignments were mostly lines) updates the filter in two scalar steps in the basis of
the fitted line, normal ``n`` and direction ``t`` (independent noises: sequential scalar
updates are the joint update):

* across: ``z_n = n . m`` (``m`` the middle of the fitted segment), ``H = [n^T 0]``,
  variance ``sigma_0^2``: the line's offset is measured whatever part is seen;
* along: ``z_t = t . m``, ``H = [t^T 0]``, the centroid variance above, when both
  ends are the object's true ends (``Clusters.ends_visible``, judged on the beams beyond
  them) in this scan and in the track's previous line update, so that ``m`` is the
  middle of the object both times. Otherwise the along-line coordinate is *re-anchored*:
  the track's point slides along the line to ``m`` (a change of the reference point on
  a rigid line, not a motion: the velocity is left alone), its along-line position gets
  the centroid variance and loses its correlations, and an along-line velocity variance
  above the new-track prior ``initial_speed_sigma^2`` is scaled down to it (so that the
  first whole views after a long partial one cannot turn noise into speed).

Another shape assigned to a line track (the wall seen together with something against
it: a centroid off the line by an unknown amount; a cone's arc after its face) except a
blob seen whole after a blob (the object itself: a track's kind is a vote over its whole
life, and a trolley that stood face-on, a line for seconds, then turned and rolled
corner-on, a blob in every scan, was re-anchored scan after scan at 0 m/s into the
robot, campaign episode 203), a blob bigger than ``max_blob_size``
(a part of a large structure, the aircraft's, whose visible part changes with the view),
a cluster of such a size of another kind than the track's last one (the middle of a
face, then the centroid of an L: other points of the object), a blob's centroid after
its fitted box's centre or the other way round, and a blob or circle grown or shrunk by
more than ``radius_tolerance`` since the last view (merged with a neighbour or split
from one: two people side by side, one circle in a scan, both one blob in the next)
only re-anchor the track, on both axes: they say where it is, not how it moves. A
circle track seen, cut by something in front, as another shape or with another
radius (a gear leg's arc cut short and flattened into a line, its middle on the robot's
side of the centre) is not measured at all: it is kept alive and its filter only
predicts. So does the next view after such an anchor (for a line, across it): its
difference from the anchor is the difference between two views, not a motion (a track
alternating between a wall and a blob of the wall with a wheel against it).

A static wall thus keeps the zero along-line velocity it was born with, and a mover
seen as a line keeps the velocity it had when its ends were seen: a box coming at the
robot face first is measured across its face; one passing sideways along its face, when
its ends are seen.

Data association: global nearest neighbour (a line and a line track are paired with the
covariance of the line model below: ``sigma_0^2`` across the line, along it the
centroid's, or the partial view's when an end is cut). Track-cluster pairs are gated by the squared
Mahalanobis distance of the innovation (``d^2 = y^T S^-1 y <= gate``, chi-square with 2
degrees of freedom) and assigned by minimising the sum of ``d^2 + ln det S`` (the
negative log-likelihood) with the Hungarian method (``scipy.optimize.
linear_sum_assignment``; Kuhn 1955). Because the prediction carries each track through
a crossing, two walkers who cross keep their identities. However inflated a partial
view's variance, a cluster is paired with a track only if it lies within both their
sizes plus the track's own position uncertainty (the gate's radius along the major axis
of the predicted position's covariance, at most ``max_offset``): a chaser's well-known
track took a post seen again, cut by the chaser, 1.2 m away, and the post got no track
of its own (avoidance campaign episode 979).

Track-aided segmentation: :meth:`ObstacleTracker.hints` gives the clusterer the
confirmed tracks of small objects predicted to the next scan, so that a segment of two
of them touching (a trolley sliding past a post) is cut back into the two
(:func:`behaviours.laws.laser_clusters.split_by_tracks`) instead of feeding both tracks
a merged view that is neither. A track stays hinted while it is seen small, whole or in
part (a chaser seen only partly, past the edge of what hides it, was hinted for the
first second only). A mover's hint also cuts its own points out of a segment of
something the hints do not cover (a parked box too big to be hinted): that part comes
back marked with the track's id (:attr:`~behaviours.laws.laser_clusters.Clusters.
carved_by`) and is paired with that track outside the assignment. It is a partial view,
the points within the track's own disc: its size is not the object's, and its
centroid measures the position like any view of that size (never an anchor: a
merge is what it was cut out of), so the track keeps measuring its motion while it
passes along the structure (avoidance campaign episode 558).

Track management: an unassigned cluster starts a tentative track (zero velocity, velocity
standard deviation ``initial_speed_sigma``); ``confirm_hits`` assignments confirm it; a
tentative track not seen for ``tentative_timeout`` or a confirmed one not seen for
``coast_time`` is deleted. Only confirmed tracks are reported, as
:class:`executive.core.records.TrackedObstacle` in the robot frame R at the robot's pose
of the scan: position in R, ground velocity in R's axes, covariance rotated into R. A
track's shape follows its state: a circle is centred on the tracked position, and a line
(its ends from the last whole view) is moved by :func:`line_through` to pass through it.
A track says whether its motion was measured on both axes within ``unseen_motion_time``
(``motion_measured``: a point update, or a line's along-line update): a line followed
only in part was not, and its velocity along itself is then not vouched for
(:func:`behaviours.laws.obstacles.vouched_velocity`).
A segment left where it was last seen whole describes a ghost: a track last seen whole
as a line, then followed as a blob to a walker standing 3.5 m away, kept its old segment
behind the robot; avoidance found the ghost off the path and drove into the walker, and
the e-stop held the robot there (avoidance campaign episode 254, issue 16).

Danger level (:func:`danger_level`): NONE, NEAR (within r_OA-trigger of the footprint),
ON_PATH (the obstacle's constant-velocity prediction comes within ``width / 2 + margin +
size`` of the robot's predicted path, a straight line or an arc of constant
``(v, omega)``, within the horizon; or it is predicted to touch the robot), IMMINENT (on
the path, and predicted to touch the robot within ``imminent_time``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment

from behaviours.laws.laser_clusters import BLOB, CIRCLE, KIND_NAMES, LINE, Clusters, TrackHints
from behaviours.laws.obstacles import MOVER_SPEED, footprint_distances, footprint_distances_xy
from executive.core.frames import FloatArray, Pose2
from executive.core.records import Danger, TrackedObstacle

IntArray = NDArray[np.intp]

_TWO_PI = 2.0 * math.pi
#: cost of a gated-out pair in the assignment (never chosen over a gated-in one)
_FORBIDDEN = 1e9
_NEAR, _ON_PATH, _IMMINENT = int(Danger.NEAR), int(Danger.ON_PATH), int(Danger.IMMINENT)
#: the :class:`Danger` of each code
_DANGERS = {int(level): level for level in Danger}


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


@lru_cache(maxsize=8)
def _instants(samples: int, horizon: float) -> FloatArray:
    """The ``samples`` instants from 0 to ``horizon`` of the danger predictions."""
    t = np.arange(samples) * (horizon / (samples - 1))
    t.flags.writeable = False
    return t


@lru_cache(maxsize=8)
def _robot_motion(
    v: float, omega: float, samples: int, horizon: float
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """The robot's pose at each instant of :func:`_instants` on the exact arc of
    constant ``(v, omega)``: position ``(rx, ry)`` and heading's cosine and sine."""
    t = _instants(samples, horizon)
    heading = omega * t
    c, s = np.cos(heading), np.sin(heading)
    if abs(omega) > 1e-12:
        rx, ry = v * s / omega, v * (1.0 - c) / omega
    else:
        rx, ry = v * t, np.zeros(samples)
    for a in (rx, ry, c, s):
        a.flags.writeable = False
    return rx, ry, c, s


def line_through(ends: FloatArray, points: FloatArray) -> FloatArray:
    """Each segment of ``ends`` (n x 4: x0, y0, x1, y1) translated so that its point
    closest to ``points[i]`` (n x 2) is that point: a line track's last whole view moved
    with the track. A segment through its point is unchanged; one of zero length (never
    seen whole) becomes the point itself."""
    a, b = ends[:, :2], ends[:, 2:]
    d = b - a
    length2 = np.einsum("ij,ij->i", d, d)
    along = np.einsum("ij,ij->i", points - a, d) / np.where(length2 > 0.0, length2, 1.0)
    closest = a + np.clip(along, 0.0, 1.0)[:, None] * d
    shift = points - closest
    return np.hstack((a + shift, b + shift))


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
    t = _instants(params.samples, params.horizon)
    q = position[:, None, :] + velocity[:, None, :] * t[:, None]  # (T, K, 2)
    reach = size[:, None] + params.margin
    rx, ry, c, s = _robot_motion(v, omega, params.samples, params.horizon)
    dx, dy = q[..., 0] - rx, q[..., 1] - ry
    gap = footprint_distances_xy(c * dx + s * dy, c * dy - s * dx, params.length, params.width)
    contact = gap <= reach
    first = np.where(contact.any(axis=1), t[contact.argmax(axis=1)], np.inf)
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
    well above their white noise), to which ``angular_sigma`` (rad, one beam of the
    UTM-30LX) times the range adds the fits' growing error on fewer, sparser returns far
    away; ``size_sigma``: the extra measurement noise of a
    line's or blob's centroid, per metre of its size.
    ``partial_sigma``: a partial view of a track's object is biased by up to the object's
    size, so its measurement noise grows by ``partial_sigma`` times that size: it keeps
    the track alive without dragging it. Partial views: an occluded cluster; assigned to
    a circle track, a line, a blob, or a circle whose radius differs from the track's by
    more than ``radius_tolerance`` times it. On any other track, a blob or circle whose
    size differs from the last view's by more than ``radius_tolerance`` times the larger
    only re-anchors it (module docstring).
    ``initial_speed_sigma`` (m/s): velocity standard deviation of a new track.
    ``max_blob_size`` (m): a blob (neither line nor circle) bigger than this (enclosing
    radius about its tracked point: for a box, the centre of its fitted rectangle) is a
    part of a large structure whose visible part changes with the view, so
    its centroid only re-anchors the track: it carries no velocity (a walker, a trolley
    or a small group stays below it).
    ``unseen_motion_time`` (s): a velocity component no view measures (an anchor: see the
    module docstring) is forgotten with this time constant.
    ``gate``: chi-square gate on the squared Mahalanobis distance (13.8: 99.9 % for 2
    degrees of freedom); ``max_offset`` (m): and a cluster is never farther from a
    track's predicted point than both their sizes plus the gate's radius along the
    major axis of the predicted position's covariance, at most this (a partial view's
    inflated variance let a structure's track take a cluster 19 m away, and a chaser's
    well-known track a post seen again 1.2 m away). ``confirm_hits``:
    assignments that confirm a track (M).
    ``tentative_timeout``, ``coast_time`` (s): a tentative, resp. confirmed, track not
    assigned for longer is deleted (1 s: a walker hidden by another while they cross).
    """

    accel_noise: float = 1.0
    position_sigma: float = 0.05
    angular_sigma: float = math.radians(0.25)
    size_sigma: float = 0.25
    initial_speed_sigma: float = 1.5
    partial_sigma: float = 5.0
    radius_tolerance: float = 0.25
    max_blob_size: float = 1.0
    unseen_motion_time: float = 0.5
    max_offset: float = 1.0
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
        #: the last update measured the track as a line whose two ends were true ends
        self.whole_line = np.zeros(0, dtype=bool)
        #: the last update only re-anchored the track (a view that shows no motion)
        self.anchored = np.zeros(0, dtype=bool)
        #: stamp of the last update that measured the motion on both axes (a point
        #: update, or a line's along-line update): -inf, never
        self.motion_seen = np.zeros(0)
        self.last_kind = np.zeros(0, dtype=np.int8)  # the kind of the last assigned cluster
        self.last_boxed = np.zeros(0, dtype=bool)  # ... and whether it was a fitted box
        #: the enclosing radius of the last whole view no bigger than ``max_blob_size``
        #: (0: none yet), and its stamp: the object's own size while it is seen merged
        self.small_size = np.zeros(0)
        self.small_seen = np.zeros(0)
        #: a whole view bigger than ``max_blob_size`` was ever assigned to the track
        self.seen_big = np.zeros(0, dtype=bool)

    def __len__(self) -> int:
        return len(self.ids)

    def hints(self, stamp: float, pose: Pose2) -> TrackHints:
        """The confirmed tracks of small objects (seen no bigger than ``max_blob_size``
        within ``coast_time``; the size of the last whole view) predicted to ``stamp``, in
        R at ``pose`` (W <- R), and which of them move (the filter's speed at least
        :data:`~behaviours.laws.obstacles.MOVER_SPEED`, on a track at least
        ``coast_time`` old never seen whole bigger than ``max_blob_size``): where the next
        scan's clusterer
        may cut a segment of two of them touching, or a mover out of a segment it touches
        (:func:`behaviours.laws.laser_clusters.split_by_tracks`)."""
        p = self.params
        recent = (self.small_size > 0.0) & (stamp - self.small_seen <= p.coast_time)
        small = ((self.hits >= p.confirm_hits) & recent).nonzero()[0]
        dt = 0.0 if self.stamp is None else max(stamp - self.stamp, 0.0)
        velocity = self.state[small, 2:]
        ahead = self.state[small, :2] + dt * velocity
        position = pose.inverse().apply(ahead) if len(small) else np.zeros((0, 2))
        # a mover: as fast as MOVER_SPEED, followed for coast_time at least (a walker's
        # track 0.4 s old, its speed still a first guess, cut the end of a wall for itself
        # and sped off at 1.5 m/s), never seen whole bigger than max_blob_size (a parked
        # box's track, its view shrunk to a fragment that slid, cut the box's face for
        # itself and sped along it at 0.9 m/s: avoidance campaign episode 323)
        speed = np.hypot(velocity[:, 0], velocity[:, 1])
        moving = (speed >= MOVER_SPEED) & (stamp - self.born[small] >= p.coast_time)
        moving &= ~self.seen_big[small]
        return TrackHints(position, self.small_size[small], moving, self.ids[small])

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
        # the fits' errors grow with the range: fewer, sparser returns (one beam's spacing)
        floor = p.position_sigma**2 + (p.angular_sigma * np.hypot(*clusters.position.T)) ** 2
        r = np.where(is_circle, floor, floor + (p.size_sigma * clusters.size) ** 2)
        # a partial view (the cluster is occluded, or a circle track is seen as a line or
        # a blob, whose centroid is not the centre) is biased by up to the object's size
        circle_track = (2 * self.votes[:, CIRCLE] > self.hits)[:, None]
        off_radius = (
            np.abs(clusters.size - self.radius[:, None]) > p.radius_tolerance * self.radius[:, None]
        )
        partial = circle_track & (~is_circle | off_radius)
        partial |= clusters.occluded
        r_pair = r + partial * (p.partial_sigma * self.size[:, None]) ** 2
        # a line measures a line track across itself to within sigma_0: gate it so
        ends = clusters.line[:, 2:] - clusters.line[:, :2]
        is_line = (clusters.kind == LINE) & (np.hypot(ends[:, 0], ends[:, 1]) > 1e-9)
        direction = np.where(is_line[:, None], ends, 1.0) @ pose.rotation().T
        direction /= np.hypot(direction[:, 0], direction[:, 1])[:, None]
        normal = direction[:, ::-1] * np.array((-1.0, 1.0))
        line_track = 2 * self.votes[:, LINE] > self.hits
        pair_line = line_track[:, None] & is_line[None, :]
        # ... and along itself to within the centroid's variance when seen whole (the
        # inflated partial variance would let it take a collinear line: an engine's inlet
        # for the other's)
        whole = is_line & clusters.ends_visible.all(axis=1)
        across = np.where(pair_line, floor[None, :], r_pair)
        seen_whole = ~circle_track & whole[None, :]  # any track but a walker's
        along = np.where(seen_whole, r[None, :], r_pair)
        r_xx = across * normal[:, 0] ** 2 + along * direction[:, 0] ** 2
        r_xy = (across - along) * normal[:, 0] * normal[:, 1]
        r_yy = across * normal[:, 1] ** 2 + along * direction[:, 1] ** 2
        # however inflated a partial view's variance, two views of one object lie within
        # their sizes of each other (the prediction carries the motion)
        reach = self.size[:, None] + clusters.size[None, :] + self._motion_reach()[:, None]
        # a mover's own part of a segment, cut out for it by its hint (split_by_tracks), is
        # its view: paired with it outside the assignment
        rows_c, cols_c = self._carved(clusters)
        reach[rows_c, :] = -1.0
        reach[:, cols_c] = -1.0
        rows, cols = self._associate(z, r_xx, r_xy, r_yy, reach)
        carved = np.concatenate((np.zeros(len(rows), dtype=bool), np.ones(len(rows_c), bool)))
        rows, cols = np.concatenate((rows, rows_c)), np.concatenate((cols, cols_c))
        # no measurement of motion, only a new anchor: a view of a big object of another
        # kind than the last one (the middle of a face, then the centroid of an L or the
        # centre of a fitted arc: other points of it), a box seen as a line after a blob
        # or the other way round (the middle of one face, then the centre of the box:
        # half its other side apart, a trolley turning from its face to its corner), a
        # line track seen as another shape (below), or a big blob (part of a large
        # structure, its visible part changing)
        kind = clusters.kind[cols]
        not_circle = ~circle_track[rows, 0]
        big = clusters.size[cols] > p.max_blob_size
        changed = kind != self.last_kind[rows]
        faces = changed & (kind != CIRCLE) & (self.last_kind[rows] != CIRCLE)
        # a blob's centroid, then its box's centre (or the other way round): other points
        boxed = (kind == BLOB) & ~changed & (clusters.boxed[cols] != self.last_boxed[rows])
        # a blob or circle grown or shrunk beyond the size tolerance since the last view:
        # merged with a neighbour or split from one (two people standing side by side, one
        # circle in a scan, one blob of both in the next): its tracked point is the middle
        # of other points, 0.2 m away; read as motion, it made a standing pair a 0.5 m/s
        # mover
        size, last_size = clusters.size[cols], self.size[rows]
        resized = np.abs(size - last_size) > p.radius_tolerance * np.maximum(size, last_size)
        resized &= (kind != LINE) & (self.last_kind[rows] != LINE)
        other_points = (changed & (big | faces)) | boxed | resized
        # a line track seen as another shape: the wall with something against it, a cone's
        # arc; a blob seen whole after a blob is the object itself (a trolley that stood
        # face-on turned corner-on; its kind is a vote over its whole life)
        blob_again = (kind == BLOB) & (self.last_kind[rows] == BLOB) & ~clusters.occluded[cols]
        anchor = (not_circle & other_points) | (line_track[rows] & ~is_line[cols] & ~blob_again)
        anchor |= (kind == BLOB) & big
        # a mover's carved part: its points within its disc, a partial view whose shape
        # and size are the cut's, its middle a measure of where it is
        anchor &= ~carved
        # lines on any track but a circle's are measured across the line, and along it only
        # when seen whole
        by_line = not_circle & is_line[cols] & (line_track[rows] | ~changed) & ~anchor & ~carved
        # the view after an anchor is another view of the object: its difference from
        # the anchor is no motion either (a track alternating between a wall and a blob)
        again = self.anchored[rows] & ~anchor & ~carved
        anchor |= again & ~by_line
        by_line_again = again & by_line
        self.anchored[rows] = anchor & ~again
        # a circle track seen, cut by something in front, as another shape or with another
        # radius (a gear leg's arc cut short, flattened into a line): its centroid is off
        # the centre by up to the radius, always on the robot's side: however weighted, it
        # would drag the track towards the robot. The track is seen (kept alive), its
        # filter only predicts.
        shape_off = (
            circle_track[rows, 0]
            & (~is_circle[cols] | off_radius[rows, cols])
            & clusters.occluded[cols]
            & ~carved
        )
        point = ~by_line & ~anchor & ~shape_off
        r_point = np.where(carved, r[cols], r_pair[rows, cols])
        self._correct(rows[point], z[cols[point]], r_point[point])
        self.motion_seen[rows[point]] = t
        if anchor.any():
            rows_a, z_a, r_a = rows[anchor], z[cols[anchor]], r[cols[anchor]]
            for k in range(2):  # along x, then along y
                axis = np.zeros((len(rows_a), 2))
                axis[:, k] = 1.0
                self._reanchor(rows_a, axis, z_a, r_a)
        rows_l, cols_l = rows[by_line], cols[by_line]
        if len(rows_l):
            direction, normal = direction[cols_l], normal[cols_l]
            z_l = z[cols_l]
            measure = ~by_line_again[by_line]
            self._correct_scalar(
                rows_l[measure],
                normal[measure],
                (normal[measure] * z_l[measure]).sum(axis=1),
                floor[cols_l[measure]],
            )
            self._reanchor(
                rows_l[~measure], normal[~measure], z_l[~measure], floor[cols_l[~measure]]
            )
            along = whole[cols_l] & self.whole_line[rows_l] & measure
            self._correct_scalar(
                rows_l[along],
                direction[along],
                (direction[along] * z_l[along]).sum(axis=1),
                r[cols_l[along]],
            )
            self.motion_seen[rows_l[along]] = t
            slide = ~along
            self._reanchor(rows_l[slide], direction[slide], z_l[slide], r[cols_l[slide]])
        self.whole_line[rows] = whole[cols]
        self.last_kind[rows] = clusters.kind[cols]
        self.last_boxed[rows] = clusters.boxed[cols]
        self._describe(rows, cols, clusters, pose, t, ~partial[rows, cols])
        fresh = np.ones(len(clusters), dtype=bool)
        fresh[cols] = False
        new = fresh.nonzero()[0]
        self._spawn(z[new], r[new], t, whole[new], clusters.kind[new], clusters.boxed[new])
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

    def _motion_reach(self) -> FloatArray:
        """Per track, how far its object may be from its predicted point: the gate's
        radius along the major axis of the predicted position's covariance
        (``sqrt(gate * lambda_max)``), at most ``max_offset``."""
        p = self.covariance
        a, b, c = p[:, 0, 0], p[:, 0, 1], p[:, 1, 1]
        lam = 0.5 * (a + c) + np.sqrt(0.25 * (a - c) ** 2 + b * b)
        return np.minimum(np.sqrt(self.params.gate * lam), self.params.max_offset)

    def _carved(self, clusters: Clusters) -> tuple[IntArray, IntArray]:
        """(track rows, cluster columns) of the clusters cut out for a tracked mover
        (:attr:`Clusters.carved_by`), one per track (``ids`` ascend: a new track is
        appended with the next id, and pruning keeps the order)."""
        ids = clusters.carved_by
        cols = (ids >= 0).nonzero()[0]
        if len(cols) == 0 or len(self) == 0:
            return np.zeros(0, dtype=np.intp), np.zeros(0, dtype=np.intp)
        rows = np.minimum(np.searchsorted(self.ids, ids[cols]), len(self) - 1)
        known = self.ids[rows] == ids[cols]
        rows, cols = rows[known], cols[known]
        rows, first = np.unique(rows, return_index=True)
        return rows, cols[first]

    def _associate(
        self,
        z: FloatArray,
        r_xx: FloatArray,
        r_xy: FloatArray,
        r_yy: FloatArray,
        reach: FloatArray,
    ) -> tuple[IntArray, IntArray]:
        """Global nearest neighbour between the tracks and the measurements ``z`` (C, 2)
        of covariance ``[[r_xx, r_xy], [r_xy, r_yy]]`` (each (T, C)), no pair farther
        apart than ``reach`` (T, C; negative: never paired): (track rows, cluster
        columns) of the gated pairs."""
        if len(self) == 0 or len(z) == 0:
            return np.zeros(0, dtype=np.intp), np.zeros(0, dtype=np.intp)
        p = self.covariance
        a = p[:, 0, 0, None] + r_xx
        b = p[:, 0, 1, None] + r_xy
        c = p[:, 1, 1, None] + r_yy
        dx = z[:, 0] - self.state[:, 0, None]
        dy = z[:, 1] - self.state[:, 1, None]
        det = a * c - b * b
        d2 = (c * dx * dx - 2.0 * b * dx * dy + a * dy * dy) / det
        inside = (d2 <= self.params.gate) & (dx * dx + dy * dy <= reach * reach) & (reach >= 0)
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

    def _correct_scalar(self, rows: IntArray, u: FloatArray, z: FloatArray, r: FloatArray) -> None:
        """Kalman update of tracks ``rows`` with the scalar measurements ``z = u . p``
        (``u`` (m, 2) unit directions, ``H = [u^T 0]``) of variance ``r``:
        ``K = P H^T / S``, ``S = H P H^T + r``, ``P <- P - K (P H^T)^T``."""
        if len(rows) == 0:
            return
        p = self.covariance[rows]
        ph = (p[:, :, :2] @ u[:, :, None])[:, :, 0]  # P H^T (m, 4)
        s = (ph[:, :2] * u).sum(axis=1) + r
        gain = ph / s[:, None]
        y = z - (self.state[rows, :2] * u).sum(axis=1)
        self.state[rows] += gain * y[:, None]
        p = p - gain[:, :, None] * ph[:, None, :]
        self.covariance[rows] = 0.5 * (p + p.transpose(0, 2, 1))

    def _reanchor(self, rows: IntArray, t: FloatArray, z: FloatArray, r: FloatArray) -> None:
        """Slide the point of line tracks ``rows`` along their lines (directions ``t``
        (m, 2) in W) to the measured middles ``z`` (m, 2): a new reference point on the
        line, not a motion. In the basis (p_n, p_t, v_n, v_t) the along-line position gets
        variance ``r`` and no correlation (a fresh, independent anchor), and the along-line
        velocity is scaled down to at most the new-track prior (a congruence by
        ``diag(1, 1, 1, alpha)``, ``alpha <= 1``: the covariance stays positive
        semi-definite).

        The velocity along ``t`` is not measured by an anchor: it is forgotten with the
        time constant ``unseen_motion_time`` (a first-order Markov velocity, Singer 1970),
        so that a motion no view confirms (a new track's first noisy guess, the last
        speed of a walker now merged into a wall) fades instead of lasting for ever."""
        if len(rows) == 0:
            return
        x = self.state[rows]
        shift = ((z - x[:, :2]) * t).sum(axis=1)
        x[:, :2] += shift[:, None] * t
        now = self.stamp if self.stamp is not None else 0.0
        fade = 1.0 - np.exp(
            -np.maximum(now - self.seen[rows], 0.0) / self.params.unseen_motion_time
        )
        x[:, 2:] -= (fade * (x[:, 2:] * t).sum(axis=1))[:, None] * t
        self.state[rows] = x
        m = len(rows)
        basis = np.zeros((m, 4, 4))  # rows: n, t for the position, then for the velocity
        normal = t[:, ::-1] * np.array((-1.0, 1.0))
        basis[:, 0, :2] = basis[:, 2, 2:] = normal
        basis[:, 1, :2] = basis[:, 3, 2:] = t
        p = basis @ self.covariance[rows] @ basis.transpose(0, 2, 1)
        p[:, 1, :] = 0.0
        p[:, :, 1] = 0.0
        p[:, 1, 1] = r
        prior = self.params.initial_speed_sigma**2
        alpha = np.sqrt(np.minimum(prior / np.maximum(p[:, 3, 3], 1e-300), 1.0))
        p[:, 3, :] *= alpha[:, None]
        p[:, :, 3] *= alpha[:, None]
        p = basis.transpose(0, 2, 1) @ p @ basis
        self.covariance[rows] = 0.5 * (p + p.transpose(0, 2, 1))

    # -- track management -------------------------------------------------------------------------
    def _spawn(
        self,
        z: FloatArray,
        r: FloatArray,
        t: float,
        whole_line: NDArray[np.bool_],
        kind: NDArray[np.int8],
        boxed: NDArray[np.bool_],
    ) -> None:
        """New tentative tracks at ``z``, at rest with a broad velocity prior;
        ``whole_line``: those born of a line seen whole (:attr:`whole_line`); ``kind``:
        their clusters' kinds."""
        n = len(z)
        if n == 0:
            return
        p = np.zeros((n, 4, 4))
        p[:, 0, 0] = p[:, 1, 1] = r
        p[:, 2, 2] = p[:, 3, 3] = self.params.initial_speed_sigma**2
        state = np.zeros((n, 4))
        state[:, :2] = z
        self.state = np.concatenate((self.state, state))
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
        self.whole_line = np.concatenate((self.whole_line, whole_line))
        self.anchored = np.concatenate((self.anchored, np.zeros(n, dtype=bool)))
        self.motion_seen = np.concatenate((self.motion_seen, np.full(n, -np.inf)))
        self.last_kind = np.concatenate((self.last_kind, kind.astype(np.int8)))
        self.last_boxed = np.concatenate((self.last_boxed, boxed))
        self.small_size = np.concatenate((self.small_size, np.zeros(n)))
        self.small_seen = np.concatenate((self.small_seen, np.full(n, -np.inf)))
        self.seen_big = np.concatenate((self.seen_big, np.zeros(n, dtype=bool)))

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
        # a part seen alone no bigger than max_blob_size (occluded, or seen as another
        # shape) says the object is still there and still small: the size stays the last
        # whole view's, the time is refreshed (a chaser seen only partly, past the edge of
        # what hides it, lost its hint a second after it was first seen and was merged into
        # that obstacle's track: avoidance campaign episode 558)
        part = ~whole & (clusters.size[cols] <= self.params.max_blob_size)
        part &= self.small_size[rows] > 0.0
        self.small_seen[rows[part]] = t
        rows, cols = rows[whole], cols[whole]
        self.size[rows] = clusters.size[cols]
        small = clusters.size[cols] <= self.params.max_blob_size
        self.small_size[rows[small]] = clusters.size[cols[small]]
        self.small_seen[rows[small]] = t
        self.seen_big[rows[~small]] = True
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
            "whole_line",
            "anchored",
            "motion_seen",
            "last_kind",
            "last_boxed",
            "small_size",
            "small_seen",
            "seen_big",
        ):
            setattr(self, name, getattr(self, name)[keep])

    # -- output -----------------------------------------------------------------------------------
    def _report(
        self, pose: Pose2, velocity: tuple[float, float], t: float
    ) -> tuple[TrackedObstacle, ...]:
        out = (self.hits >= self.params.confirm_hits).nonzero()[0]
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
        kind = self.votes[out].argmax(axis=1)
        measured = t - self.motion_seen[out] <= self.params.unseen_motion_time
        moved = line_through(self.line[out], self.state[out, :2])
        ends = inv.apply(moved.reshape(-1, 2)).reshape(-1, 4)
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
                danger=_DANGERS[d],
                shape=sh,
                motion_measured=m,
            )
            for i, k, (x, y), (vx, vy), cov, sz, cl, b, d, sh, m in zip(
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
                measured.tolist(),
                strict=True,
            )
        )
