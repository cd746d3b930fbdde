"""Aircraft registration: the laser returns matched against the aircraft's footprint.

Relative localisation in the aircraft frame (seed 000, lines 1030-1147). Algorithm 2.2
(3D point-cloud matching) acquires a cloud, cleans it (sampling, clustering, segmentation),
runs a *modified RANSAC* until the global matching error is small enough, then ICP.
Algorithm 2.3 (the modified RANSAC): compute a characteristic of each point of the scan
and of the aircraft model, take three points of the model and compare characteristics
and geometry, apply the most likely transform, compute the global error. ICP is
Chen and Medioni (1991, point-to-plane) / Besl and McKay (1992). Here the cloud is the
planar scan of the two 270 deg scanners (no pan-tilt sweep) and the model is the
aircraft's footprint at laser height (``Aircraft.footprint``: gear legs, nacelles, a low
belly), which is what the lasers can hit; everything lives in the ground plane.

Frames. The aircraft frame F (x nose -> tail, y to port, z down) is *mirrored* seen from
above, so a robot pose ``Pose2(x_F, y_F, h)`` in F is not a rigid transform of the plane.
Internally the model lives in the proper frame G = (x_F, -y_F), where the robot pose is
the ordinary SE(2) transform ``G <- R = Pose2(x_F, -y_F, -h)`` (``frames.mirror_pose``, an
involution); the public API speaks F, and covariances convert with diag(1, -1, -1).

What was adapted to 2D, and why:

* *Cleaning and characteristics* (Alg. 2.2 step 4, Alg. 2.3 step 2). The scan is split
  into clusters at range jumps (beam order), each cluster either recognised as an arc of
  one of the model's circles (algebraic circle fit) or split into straight pieces
  (iterative end-point fit, the split step of split-and-merge) fitted by total least
  squares. A characteristic is a *line* (direction, offset, extent, and its outward
  side: the side the sensor sees) or a *circle* (centre, radius); the model's are its
  polygon edges (outward normal, length) and circles. A scan line is compatible with a
  model edge when its outward normal agrees with the prior heading within the gate and
  it is not longer than the edge; a scan arc with a model circle when the radii agree.
  A person (r ~0.3 m) is no gear leg, and a truck's 9 m side is no nacelle.
* *Minimal sets* (step 3). In 3D three point correspondences fix a pose; in the plane an
  oriented line correspondence already fixes the rotation, so *two* characteristics
  fix the transform: two non-parallel lines (rotation from both, translation from the
  intersection of their supporting lines, which need not be a corner of one element),
  a line and a circle, or two circles (the classical two-point case, checked by their
  distance). Each hypothesis is checked against the model's geometry (each transformed
  scan segment must lie within its edge's extent, the circle at its distance from the
  line) and gated by the prior. The third and further correspondences of the thesis
  enter through the global error, which every characteristic and return takes part in.
* *Global error* (steps 4-5). All compatible pairs are enumerated (tens to hundreds,
  not a time-limited random draw) and every surviving hypothesis is scored at once,
  vectorised, by a truncated quadratic cost (MSAC) of evenly spread returns against a
  precomputed distance field of the outline. Returns that no hypothesis explains
  (people, vehicles) cost every hypothesis the same, so they cannot pull one. The few
  best distinct hypotheses are refined by ICP and the best supported one wins (sum of
  its Cauchy weights: a sloppy fit with as many inliers loses to a tight one).
* *ICP* (Alg. 2.2 step 6): point-to-line (Chen-Medioni's point-to-plane in 2D) against
  outline samples with outward normals; correspondences from the distance field (the
  nearest sample of each cell); samples facing away from the robot rejected (a scanner
  cannot see the far side of a leg); a correspondence gate that shrinks over the
  iterations; Cauchy weights; damped Gauss-Newton steps.
* *Free space* (an addition; the thesis's 3D model gave each match far more context).
  The global error only rewards returns near the outline, so clutter shaped like part
  of the footprint (two vehicles the size and spacing of the nacelles) can pass for the
  aircraft. Given the scans' sight lines (:class:`SightLines`: each beam from its
  scanner to its return, or to full range), a candidate whose footprint the beams pass
  through is penalised, and refused when such contradictions are too many.

The covariance is the Gauss-Newton one, ``sigma^2 (J^T W J)^-1``, with sigma from the
weighted inlier residuals (floored at ``sigma_floor``) and inflated by ``n_inliers /
independent_points`` (at least 1): neighbouring returns share range bias and model error,
so a thousand inliers are not a thousand independent measurements. With sim2d's white
range noise, which has none of that, the reported standard deviations are therefore 2-3
times the observed ones: conservative by design. ``conditioning`` is the smallest eigenvalue of
``J^T W J`` (rotation in rad, i.e. displacement 1 m away): the number of effective
returns that constrain the weakest direction. A result is *well conditioned* when the
covariance's worst position axis and its heading are within ``max_sigma_xy`` and
``max_sigma_theta``.

Insufficient evidence: :func:`register` returns ``None``, never a guess, when no
hypothesis can be formed (a single line, parallel lines only, or one circular gear leg
alone, whose rotation about the leg is unobservable), when the best fit has too few
inliers or inliers on a single footprint element, leaves the prior's gate, is not well
conditioned, or is contradicted by the free space. :func:`refine` always returns its
result; its ``well_conditioned`` flag and its covariance (large along an unobservable
direction) say how far to trust it.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping
from dataclasses import dataclass
from enum import StrEnum

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from behaviours.laws.obstacles import scan_to_robot
from executive.core.frames import (
    AircraftPlacement,
    FloatArray,
    Pose2,
    mirror_covariance,
    mirror_pose,
    wrap_angle,
)
from executive.core.model import Aircraft, Circle, LaserSpec, Polygon
from executive.core.records import LaserScan

IntArray = NDArray[np.intp]
BoolArray = NDArray[np.bool_]


"""(x, y, heading) in F <-> in the proper ground frame G; its own inverse."""

MIN_CROSSING = 0.3
"""Two scan lines make a hypothesis when they meet at more than asin(0.3) ~ 17 deg."""

DISTINCT = (0.05, 0.05, 0.005)
"""Hypotheses closer than this in (x, y, theta) (m, m, rad) are one."""

SEPARATE = (0.3, 0.05)
"""Candidates refined by ICP differ by more than this in position (m) or heading (rad)."""

EIGEN_FLOOR = 1e-6
"""Information eigenvalues are clipped here before inversion: an unobservable direction
gets a variance of ``sigma^2 / EIGEN_FLOOR`` rather than infinity."""


def _wrap(a: FloatArray) -> FloatArray:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def _perp(v: FloatArray) -> FloatArray:
    """2D vectors (..., 2) turned by +90 deg."""
    return np.stack((-v[..., 1], v[..., 0]), axis=-1)


def _angle(v: FloatArray) -> FloatArray:
    return np.arctan2(v[..., 1], v[..., 0])


def _cross(a: FloatArray, b: FloatArray) -> FloatArray:
    """z of the cross product of 2D vectors (..., 2)."""
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def _rotations(theta: FloatArray) -> FloatArray:
    """(H,) angles -> (H, 2, 2) rotation matrices."""
    c, s = np.cos(theta), np.sin(theta)
    return np.stack((np.stack((c, -s), -1), np.stack((s, c), -1)), -2)


# -- model ---------------------------------------------------------------------------------------
class LandmarkKind(StrEnum):
    CIRCLE = "circle"
    POLYGON = "polygon"


@dataclass(frozen=True, slots=True)
class Landmark:
    """One footprint element as a whole, in F: ``centre`` (x_F, y_F) (the circle's, or the
    mean of the polygon's vertices), ``kind`` and ``size`` (radius; for a polygon the
    largest distance of a vertex from the centre)."""

    id: str
    kind: LandmarkKind
    centre: tuple[float, float]
    size: float


def _landmark(shape: Circle | Polygon) -> Landmark:
    if isinstance(shape, Circle):
        return Landmark(shape.id, LandmarkKind.CIRCLE, (shape.cx, shape.cy), shape.radius)
    pts = np.asarray(shape.points, dtype=float)
    centre = pts.mean(axis=0)
    size = float(np.max(np.hypot(*(pts - centre).T)))
    return Landmark(shape.id, LandmarkKind.POLYGON, (float(centre[0]), float(centre[1])), size)


@dataclass(frozen=True, slots=True, eq=False)
class FootprintModel:
    """The aircraft footprint in the proper frame G, ready for registration.

    ``samples``, ``normals``, ``sample_element``: outline points at most ``spacing``
    (:meth:`from_aircraft`) apart on every polygon edge and circle, their outward unit
    normals and the index of their footprint element in ``elements``. The model's
    characteristics (Alg. 2.3): ``edge_start``, ``edge_direction``, ``edge_normal``
    (outward), ``edge_length`` per polygon edge, and ``circles`` (cx, cy, r). The
    distance field covers the outline's bounding box plus ``margin``:
    ``field_distance[iy, ix]`` is the distance from the centre of cell (ix, iy), at
    ``field_origin + (ix + 0.5, iy + 0.5) * resolution``, to the nearest sample and
    ``field_nearest`` that sample's index (-1 beyond ``margin``).
    ``landmarks`` describes each element as a whole, in F, in footprint order.
    """

    elements: tuple[str, ...]
    landmarks: tuple[Landmark, ...]
    samples: FloatArray
    normals: FloatArray
    sample_element: IntArray
    edge_start: FloatArray
    edge_direction: FloatArray
    edge_normal: FloatArray
    edge_length: FloatArray
    circles: FloatArray
    resolution: float
    margin: float
    field_origin: FloatArray
    field_distance: NDArray[np.float32]
    field_nearest: NDArray[np.int32]

    @staticmethod
    def from_aircraft(
        aircraft: Aircraft, spacing: float = 0.05, resolution: float = 0.05, margin: float = 1.5
    ) -> FootprintModel:
        """Sample the footprint of ``aircraft`` and build its distance field with a KD-tree
        over the samples (once per aircraft type: ~0.1 s for the shipped ones).

        Polygons may be given in either orientation (the outward side comes from the
        signed area). ``margin`` bounds the field: no correspondence or score farther out.
        """
        if not aircraft.footprint:
            raise ValueError(f"aircraft {aircraft.type!r} has no footprint to register against")
        samples, normals, owner = [], [], []
        starts, directions, edge_normals, lengths, circles = [], [], [], [], []
        for k, shape in enumerate(aircraft.footprint):
            if isinstance(shape, Circle):
                cx, cy, r = shape.cx, -shape.cy, shape.radius
                n = max(8, math.ceil(2.0 * math.pi * r / spacing))
                t = 2.0 * math.pi * (np.arange(n) + 0.5) / n
                radial = np.column_stack((np.cos(t), np.sin(t)))
                samples.append(np.array([cx, cy]) + r * radial)
                normals.append(radial)
                owner.append(np.full(n, k))
                circles.append((cx, cy, r))
                continue
            ring = np.asarray(shape.points, dtype=float) * np.array([1.0, -1.0])
            nxt = np.roll(ring, -1, axis=0)
            area2 = float(np.sum(ring[:, 0] * nxt[:, 1] - nxt[:, 0] * ring[:, 1]))
            outward = -1.0 if area2 > 0.0 else 1.0  # counter-clockwise: outside on the right
            for a, b in zip(ring, nxt, strict=True):
                length = float(np.hypot(*(b - a)))
                if length == 0.0:
                    continue
                d = (b - a) / length
                m = math.ceil(length / spacing)
                u = (np.arange(m) + 0.5) / m * length
                samples.append(a + u[:, None] * d)
                normals.append(np.tile(outward * _perp(d), (m, 1)))
                owner.append(np.full(m, k))
                starts.append(a)
                directions.append(d)
                edge_normals.append(outward * _perp(d))
                lengths.append(length)
        pts = np.vstack(samples)
        lo = pts.min(axis=0) - margin
        nx, ny = np.ceil((pts.max(axis=0) + margin - lo) / resolution).astype(int)
        gx = lo[0] + (np.arange(nx) + 0.5) * resolution
        gy = lo[1] + (np.arange(ny) + 0.5) * resolution
        centres = np.stack(np.meshgrid(gx, gy), axis=-1).reshape(-1, 2)
        dist, idx = cKDTree(pts).query(centres, distance_upper_bound=margin)
        far = ~np.isfinite(dist)
        return FootprintModel(
            elements=tuple(s.id for s in aircraft.footprint),
            landmarks=tuple(_landmark(s) for s in aircraft.footprint),
            samples=pts,
            normals=np.vstack(normals),
            sample_element=np.concatenate(owner),
            edge_start=np.array(starts, dtype=float).reshape(-1, 2),
            edge_direction=np.array(directions, dtype=float).reshape(-1, 2),
            edge_normal=np.array(edge_normals, dtype=float).reshape(-1, 2),
            edge_length=np.array(lengths, dtype=float),
            circles=np.array(circles, dtype=float).reshape(-1, 3),
            resolution=resolution,
            margin=margin,
            field_origin=lo,
            field_distance=np.where(far, margin, dist).reshape(ny, nx).astype(np.float32),
            field_nearest=np.where(far, -1, idx).reshape(ny, nx).astype(np.int32),
        )

    def landmark_centres(self) -> FloatArray:
        """(K, 2) centres of the footprint elements in F, in footprint order."""
        return np.array([lm.centre for lm in self.landmarks], dtype=float).reshape(-1, 2)

    def lookup(self, points_g: FloatArray) -> tuple[FloatArray, IntArray]:
        """Distance to the outline and nearest sample index of points (..., 2) in G, read
        from the distance field; ``margin`` and -1 outside it."""
        cell = np.floor((points_g - self.field_origin) / self.resolution).astype(np.intp)
        ny, nx = self.field_distance.shape
        ix, iy = cell[..., 0], cell[..., 1]
        inside = (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)
        ix, iy = np.where(inside, ix, 0), np.where(inside, iy, 0)
        dist = np.where(inside, self.field_distance[iy, ix], self.margin)
        return dist, np.where(inside, self.field_nearest[iy, ix], -1)


# -- scan characteristics (Alg. 2.2 step 4, Alg. 2.3 step 2) ---------------------------------------
@dataclass(frozen=True, slots=True, eq=False)
class ScanFeatures:
    """Characteristics of a scan, in R.

    Lines: end points, centroid, unit normal on the side the sensor sees (the surface's
    outward normal), weight ``n_points * length^2`` (how well the direction is known).
    Circles: (cx, cy, r) of the arcs whose radius matches one of the model's circles.
    """

    line_start: FloatArray
    line_end: FloatArray
    line_centre: FloatArray
    line_normal: FloatArray
    line_weight: FloatArray
    circles: FloatArray

    @property
    def n_lines(self) -> int:
        return len(self.line_centre)


def _fit_circle(pts: FloatArray) -> tuple[FloatArray, float, float]:
    """Algebraic (Kasa) circle fit: centre, radius, rms of the radial residuals. Centred
    coordinates turn it into a 2x2 linear system."""
    mean = pts.mean(axis=0)
    x, y = (pts - mean).T
    zz = x * x + y * y
    m = np.array([[x @ x, x @ y], [x @ y, y @ y]])
    rhs = 0.5 * np.array([x @ zz, y @ zz])
    if abs(np.linalg.det(m)) < 1e-12:
        return mean, 0.0, math.inf
    cx, cy = np.linalg.solve(m, rhs)
    radius = math.sqrt(cx * cx + cy * cy + zz.mean())
    centre = mean + np.array([cx, cy])
    rms = float(np.sqrt(np.mean((np.hypot(x - cx, y - cy) - radius) ** 2)))
    return centre, radius, rms


def _line_pieces(
    cluster: FloatArray, split_distance: float, min_points: int, min_length: float
) -> list[FloatArray]:
    """Iterative end-point fit: split at the return farthest from the chord (from the
    first return when the chord is too short, e.g. a U) until each piece is straight."""
    pieces = []
    stack = [(0, len(cluster) - 1)]
    while stack:
        i, k = stack.pop()
        if k - i + 1 < min_points:
            continue
        rel = cluster[i : k + 1] - cluster[i]
        chord = cluster[k] - cluster[i]
        span = math.hypot(*chord)
        if span >= min_length:
            off = np.abs(rel[:, 1] * chord[0] - rel[:, 0] * chord[1]) / span
        else:
            off = np.hypot(*rel.T)
            off[-1] = 0.0  # split inside, or not at all: the piece is too short
        worst = int(np.argmax(off))
        if off[worst] > split_distance:
            stack += [(i, i + worst), (i + worst, k)]
        elif span >= min_length:
            pieces.append(cluster[i : k + 1])
    return pieces


def extract_features(
    model: FootprintModel,
    points_r: ArrayLike,
    *,
    jump: float = 0.15,
    jump_ratio: float = 0.03,
    split_distance: float = 0.05,
    min_points: int = 6,
    min_line_length: float = 0.3,
    max_fit_rms: float = 0.03,
    radius_tolerance: float = 0.1,
) -> ScanFeatures:
    """Lines and model-sized arcs of a scan: ``points_r`` (N, 2) in R in beam order,
    scanners concatenated (as :func:`points_from_scans` returns them).

    Clusters break where consecutive returns are farther apart than ``jump + jump_ratio
    * range``. A cluster of ``min_points`` or more that fits a circle (rms within
    ``max_fit_rms``) of a model circle's radius (within ``radius_tolerance``) and bulges
    towards the sensor is an arc; any other is cut into straight pieces (within
    ``split_distance`` of their chord), and the pieces of ``min_points`` returns,
    ``min_line_length`` long and fitting a line within ``max_fit_rms`` are lines.
    """
    pts = np.asarray(points_r, dtype=float).reshape(-1, 2)
    ranges = np.hypot(pts[:, 0], pts[:, 1])
    gaps = np.hypot(*np.diff(pts, axis=0).T)
    cuts = np.flatnonzero(gaps > jump + jump_ratio * ranges[:-1]) + 1
    radii = model.circles[:, 2]
    widest = 2.0 * (float(radii.max()) + radius_tolerance) if len(radii) else 0.0
    lines: list[tuple[FloatArray, FloatArray, FloatArray, FloatArray, float]] = []
    arcs: list[tuple[float, float, float]] = []
    for lo, hi in itertools.pairwise(np.concatenate(([0], cuts, [len(pts)]))):
        if hi - lo < min_points:
            continue
        cluster = pts[lo:hi]
        if math.dist(cluster[0], cluster[-1]) <= widest:
            centre, radius, rms = _fit_circle(cluster)
            if (
                rms <= max_fit_rms
                and np.min(np.abs(radii - radius)) <= radius_tolerance
                and math.hypot(*centre) > float(np.mean(ranges[lo:hi]))
            ):
                arcs.append((centre[0], centre[1], radius))
                continue
        for piece in _line_pieces(cluster, split_distance, min_points, min_line_length):
            centroid = piece.mean(axis=0)
            x, y = (piece - centroid).T
            sxx, syy, sxy = x @ x, y @ y, x @ y
            phi = 0.5 * math.atan2(2.0 * sxy, sxx - syy)  # total least squares direction
            d = np.array([math.cos(phi), math.sin(phi)])
            normal = np.array([-d[1], d[0]])
            u = x * d[0] + y * d[1]
            length = float(u.max() - u.min())
            rms = math.sqrt(
                max(normal @ np.array([[sxx, sxy], [sxy, syy]]) @ normal, 0.0) / len(piece)
            )
            if rms > max_fit_rms or length < min_line_length:
                continue
            if normal @ centroid > 0.0:  # make it face the robot
                normal = -normal
            start, end = centroid + u.min() * d, centroid + u.max() * d
            lines.append((start, end, centroid, normal, len(piece) * length * length))
    if lines:
        start, end, centre, normal, weight = (np.array(c) for c in zip(*lines, strict=True))
    else:
        start = end = centre = normal = np.zeros((0, 2))
        weight = np.zeros(0)
    return ScanFeatures(start, end, centre, normal, weight, np.array(arcs).reshape(-1, 3))


# -- hypotheses (Alg. 2.3 step 3) -------------------------------------------------------------
def _on_edges(
    model: FootprintModel,
    feats: ScanFeatures,
    theta: FloatArray,
    t: FloatArray,
    line: IntArray,
    edge: IntArray,
    tolerance: float,
) -> BoolArray:
    """Whether each transformed scan segment ``line`` lies within the extent of ``edge``."""
    rot = _rotations(theta)
    a, d, length = model.edge_start[edge], model.edge_direction[edge], model.edge_length[edge]
    ok = np.ones(len(theta), dtype=bool)
    for ends in (feats.line_start, feats.line_end):
        p = np.einsum("hij,hj->hi", rot, ends[line]) + t
        u = np.einsum("hi,hi->h", p - a, d)
        ok &= (u >= -tolerance) & (u <= length + tolerance)
    return ok


def _hypotheses(
    model: FootprintModel,
    feats: ScanFeatures,
    prior_g: Pose2,
    gate_xy: float,
    gate_theta: float,
    *,
    angle_tolerance: float,
    extent_tolerance: float,
    radius_tolerance: float,
) -> FloatArray:
    """Every transform (x, y, theta) of G <- R that a pair of compatible characteristics
    implies and the prior admits, duplicates removed."""
    out: list[FloatArray] = []
    # single line matches: the outward normals fix the rotation
    alpha = _angle(feats.line_normal)
    beta = _angle(model.edge_normal)
    th = _wrap(beta[None, :] - alpha[:, None])
    scan_len = np.hypot(*(feats.line_end - feats.line_start).T)
    ok = (np.abs(_wrap(th - prior_g.theta)) <= gate_theta + angle_tolerance) & (
        scan_len[:, None] <= model.edge_length[None, :] + 2.0 * extent_tolerance
    )
    li, le = np.nonzero(ok)
    lth = th[li, le]
    offset = np.einsum("ij,ij->i", model.edge_normal, model.edge_start)  # n . x = c
    # pairs of non-parallel lines: translation from the two supporting lines
    a, b = np.triu_indices(len(li), 1)
    keep = (
        (li[a] != li[b])
        & (le[a] != le[b])
        & (np.abs(_wrap(lth[a] - lth[b])) <= angle_tolerance)
        & (np.abs(_cross(feats.line_normal[li[a]], feats.line_normal[li[b]])) >= MIN_CROSSING)
    )
    a, b = a[keep], b[keep]
    wa, wb = feats.line_weight[li[a]], feats.line_weight[li[b]]
    theta = _wrap(lth[a] + _wrap(lth[b] - lth[a]) * wb / (wa + wb))
    rot = _rotations(theta)
    na, nb = model.edge_normal[le[a]], model.edge_normal[le[b]]
    ra = offset[le[a]] - np.einsum("hi,hij,hj->h", na, rot, feats.line_centre[li[a]])
    rb = offset[le[b]] - np.einsum("hi,hij,hj->h", nb, rot, feats.line_centre[li[b]])
    det = na[:, 0] * nb[:, 1] - na[:, 1] * nb[:, 0]
    t = np.column_stack((ra * nb[:, 1] - rb * na[:, 1], na[:, 0] * rb - nb[:, 0] * ra))
    t /= det[:, None]
    fits = _on_edges(model, feats, theta, t, li[a], le[a], extent_tolerance) & _on_edges(
        model, feats, theta, t, li[b], le[b], extent_tolerance
    )
    out.append(np.column_stack((t, theta))[fits])
    # arcs matched to model circles
    ck, cl = np.nonzero(
        np.abs(feats.circles[:, 2][:, None] - model.circles[:, 2][None, :]) <= radius_tolerance
    )
    if len(ck):
        # a line and a circle: rotation from the line, translation from the centre
        a, c = (g.ravel() for g in np.meshgrid(np.arange(len(li)), np.arange(len(ck))))
        theta = lth[a]
        rot = _rotations(theta)
        t = model.circles[cl[c], :2] - np.einsum("hij,hj->hi", rot, feats.circles[ck[c], :2])
        n = model.edge_normal[le[a]]
        moved = np.einsum("hij,hj->hi", rot, feats.line_centre[li[a]]) + t
        fits = np.abs(np.einsum("hi,hi->h", n, moved) - offset[le[a]]) <= extent_tolerance
        fits &= _on_edges(model, feats, theta, t, li[a], le[a], extent_tolerance)
        out.append(np.column_stack((t, theta))[fits])
        # two circles: the classical two-point case, checked by their distance
        a, b = np.triu_indices(len(ck), 1)
        keep = (ck[a] != ck[b]) & (cl[a] != cl[b])
        a, b = a[keep], b[keep]
        vs = feats.circles[ck[b], :2] - feats.circles[ck[a], :2]
        vm = model.circles[cl[b], :2] - model.circles[cl[a], :2]
        fits = np.abs(np.hypot(*vs.T) - np.hypot(*vm.T)) <= extent_tolerance
        theta = _wrap(_angle(vm) - _angle(vs))
        rot = _rotations(theta)
        mid_s = 0.5 * (feats.circles[ck[a], :2] + feats.circles[ck[b], :2])
        mid_m = 0.5 * (model.circles[cl[a], :2] + model.circles[cl[b], :2])
        t = mid_m - np.einsum("hij,hj->hi", rot, mid_s)
        out.append(np.column_stack((t, theta))[fits])
    hyp = np.vstack(out)
    near = (np.hypot(hyp[:, 0] - prior_g.x, hyp[:, 1] - prior_g.y) <= gate_xy) & (
        np.abs(_wrap(hyp[:, 2] - prior_g.theta)) <= gate_theta
    )
    hyp = hyp[near]
    keys = np.round(hyp / np.array(DISTINCT)).astype(np.int64)
    _, first = np.unique(keys, axis=0, return_index=True)
    return hyp[np.sort(first)]


def _scores(model: FootprintModel, points_r: FloatArray, hyp: FloatArray, eps: float) -> FloatArray:
    """MSAC score (Alg. 2.3 step 5, the global error turned into a gain): for each
    hypothesis, ``sum(1 - min(d, eps)^2 / eps^2)`` over the points, d from the field."""
    rot = _rotations(hyp[:, 2])
    moved = np.einsum("hij,nj->hni", rot, points_r) + hyp[:, None, :2]
    d, _ = model.lookup(moved)
    return np.sum(1.0 - np.minimum(d, eps) ** 2 / (eps * eps), axis=1)


# -- free space --------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True, eq=False)
class SightLines:
    """The beams of a scan as free space, in R: each from its scanner (``origins``) to
    its return, or to the end of its range when nothing returned (``ends``), (M, 2) each.
    Nothing of the aircraft can lie across them."""

    origins: FloatArray
    ends: FloatArray

    @staticmethod
    def from_scans(
        scans: Mapping[str, LaserScan], lasers: Mapping[str, LaserSpec], stride: int = 1
    ) -> SightLines:
        """Every ``stride``-th beam of the scans of known lasers."""
        origins, ends = [], []
        for lid, spec in lasers.items():
            if lid not in scans:
                continue
            scan = scans[lid]
            mount = Pose2(spec.mount[0], spec.mount[1], spec.mount_yaw)
            k = np.arange(0, len(scan.ranges), stride)
            angle = scan.angle_min + scan.angle_increment * k
            reach = np.minimum(scan.ranges[k], scan.range_max)
            local = reach[:, None] * np.column_stack((np.cos(angle), np.sin(angle)))
            ends.append(mount.apply(local))
            origins.append(np.tile(mount.position, (len(k), 1)))
        if not ends:
            return SightLines(np.zeros((0, 2)), np.zeros((0, 2)))
        return SightLines(np.vstack(origins), np.vstack(ends))


def _see_through(
    model: FootprintModel, lines: SightLines | None, pose_g: Pose2, tolerance: float
) -> int:
    """How many sight lines contradict ``pose_g``: shortened by ``tolerance`` at their
    end, they cross the footprint placed there (a beam cannot pass through a gear leg).
    Crossings at grazing incidence (within ~6 deg of an edge) do not count: there, the
    range noise alone moves a return across the edge."""
    if lines is None or not len(lines.ends):
        return 0
    inv = pose_g.inverse()
    v = lines.ends - lines.origins
    length = np.hypot(v[:, 0], v[:, 1])
    v *= (np.maximum(length - tolerance, 0.0) / np.maximum(length, 1e-12))[:, None]
    a = inv.apply(model.edge_start)[None] - lines.origins[:, None, :]
    e = ((model.edge_direction * model.edge_length[:, None]) @ inv.rotation().T)[None]
    den = _cross(v[:, None, :], e)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = _cross(a, e) / den
        u = _cross(a, v[:, None, :]) / den
    steep = np.abs(den) > 0.1 * length[:, None] * model.edge_length[None, :]
    hit = np.any(steep & (t >= 0.0) & (t <= 1.0) & (u >= 0.0) & (u <= 1.0), axis=1)
    if len(model.circles):
        c = inv.apply(model.circles[:, :2])[None] - lines.origins[:, None, :]
        vv = np.maximum(np.einsum("ij,ij->i", v, v), 1e-12)
        along = np.clip(np.einsum("mi,mci->mc", v, c) / vv[:, None], 0.0, 1.0)
        gap = np.linalg.norm(along[..., None] * v[:, None, :] - c, axis=2)
        hit |= np.any(gap < model.circles[None, :, 2], axis=1)
    return int(np.count_nonzero(hit))


# -- ICP (Alg. 2.2 step 6) ----------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class IcpSettings:
    """Point-to-line ICP and the quality figures of its result (module docstring).

    The correspondence gate starts at ``max_distance`` and shrinks by ``shrink`` per
    iteration down to ``min_distance``, which also bounds an inlier; Cauchy weights of
    scale ``robust_scale``; converged when a step at the smallest gate moves less than
    ``tolerance`` (m and rad), or after ``max_iterations``.
    """

    max_iterations: int = 30
    max_distance: float = 0.5
    min_distance: float = 0.1
    shrink: float = 0.6
    robust_scale: float = 0.05
    tolerance: float = 1e-5
    sigma_floor: float = 0.01
    independent_points: float = 100.0
    max_sigma_xy: float = 0.05
    max_sigma_theta: float = math.radians(0.5)
    min_element_inliers: int = 10


@dataclass(frozen=True, slots=True, eq=False)
class _Fit:
    pose_g: Pose2
    information: FloatArray
    support: float
    """Sum of the final Cauchy weights: inliers counted by how well they fit."""
    sigma2: float
    residuals: FloatArray
    inliers: BoolArray
    nearest: IntArray
    iterations: int


def _correspond(
    model: FootprintModel, points_r: FloatArray, pose_g: Pose2, gate: float, icp: IcpSettings
) -> tuple[FloatArray, FloatArray, FloatArray, IntArray, BoolArray]:
    """Point-to-line residuals, Jacobian rows in (x, y, theta) of G <- R, Cauchy weights
    (0 for rejected pairs), nearest samples and the accepted mask at ``pose_g``."""
    moved = pose_g.apply(points_r)
    _, nearest = model.lookup(moved)
    j = np.maximum(nearest, 0)
    q, n = model.samples[j], model.normals[j]
    offset = moved - q
    residual = np.einsum("ij,ij->i", n, offset)
    accepted = (
        (nearest >= 0)
        & (np.einsum("ij,ij->i", offset, offset) <= gate * gate)
        & (np.einsum("ij,ij->i", n, pose_g.position - q) > 0.0)  # the sample faces the robot
    )
    lever = moved - pose_g.position  # R(theta) p, so d(moved)/d(theta) = perp(lever)
    jac = np.column_stack((n, np.einsum("ij,ij->i", n, _perp(lever))))
    weight = np.where(accepted, 1.0 / (1.0 + (residual / icp.robust_scale) ** 2), 0.0)
    return residual, jac, weight, nearest, accepted


def _icp(model: FootprintModel, points_r: FloatArray, initial_g: Pose2, icp: IcpSettings) -> _Fit:
    """Point-to-line ICP with Cauchy weights and a shrinking correspondence gate, in G."""
    x = np.array([initial_g.x, initial_g.y, initial_g.theta])
    gate = icp.max_distance
    iterations = 0
    while iterations < icp.max_iterations:
        iterations += 1
        r, jac, w, _, accepted = _correspond(model, points_r, Pose2(*x), gate, icp)
        if np.count_nonzero(accepted) < 3:
            break
        h = jac.T @ (w[:, None] * jac)
        step = np.linalg.solve(h + 1e-9 * max(np.trace(h), 1.0) * np.eye(3), -jac.T @ (w * r))
        x += step
        x[2] = wrap_angle(x[2])
        small = math.hypot(step[0], step[1]) < icp.tolerance and abs(step[2]) < icp.tolerance
        if gate <= icp.min_distance and small:
            break
        gate = max(icp.min_distance, gate * icp.shrink)
    pose = Pose2(*x)
    r, jac, w, nearest, accepted = _correspond(model, points_r, pose, icp.min_distance, icp)
    sigma2 = float(np.sum(w * r * r)) / max(float(w.sum()) - 3.0, 1.0)
    information = jac.T @ (w[:, None] * jac)
    return _Fit(pose, information, float(w.sum()), sigma2, r, accepted, nearest, iterations)


# -- result -------------------------------------------------------------------------------------
class RegistrationMethod(StrEnum):
    GLOBAL = "global"
    """Hypotheses from pairs of characteristics, global error, then ICP."""
    ICP = "icp"
    """ICP from a given initial pose (tracking)."""


@dataclass(frozen=True, slots=True, eq=False)
class Registration:
    """A registered robot pose in the aircraft frame and how good the fit is.

    ``pose_f`` is the robot pose in F (``Pose2(x_F, y_F, h)``, h from +x_F towards +y_F,
    as ``AircraftPlacement.pose_to_aircraft`` gives it) and ``covariance`` its 3x3
    covariance in (x_F, y_F, h). ``rms`` (m) is the point-to-line residual of the inliers
    (returns within ``min_distance`` of a visible part of the outline);
    ``inlier_fraction = n_inliers / n_points``. ``conditioning`` and
    ``well_conditioned``: see the module docstring. ``elements`` names the footprint
    elements with inliers; ``hypotheses`` is how many transforms the global step scored
    (0 for ``icp``); ``contradictions`` how many sight lines pass through the registered
    footprint (free-space test; 0 when no sight lines were given).
    """

    pose_f: Pose2
    covariance: FloatArray
    rms: float
    inlier_fraction: float
    n_inliers: int
    n_points: int
    iterations: int
    method: RegistrationMethod
    conditioning: float
    well_conditioned: bool
    elements: tuple[str, ...] = ()
    hypotheses: int = 0
    contradictions: int = 0


def _registration(
    model: FootprintModel,
    fit: _Fit,
    n_points: int,
    method: RegistrationMethod,
    icp: IcpSettings,
    hypotheses: int = 0,
    contradictions: int = 0,
) -> Registration:
    inliers = fit.inliers
    n_in = int(np.count_nonzero(inliers))
    vals, vecs = np.linalg.eigh(fit.information)
    inflation = max(1.0, n_in / icp.independent_points)
    sigma2 = max(fit.sigma2, icp.sigma_floor**2) * inflation
    cov_g = sigma2 * (vecs / np.maximum(vals, EIGEN_FLOOR)) @ vecs.T
    cov_g = 0.5 * (cov_g + cov_g.T)
    counts = np.bincount(model.sample_element[fit.nearest[inliers]], minlength=len(model.elements))
    return Registration(
        pose_f=mirror_pose(fit.pose_g),
        covariance=mirror_covariance(cov_g),
        rms=float(np.sqrt(np.mean(fit.residuals[inliers] ** 2))) if n_in else math.inf,
        inlier_fraction=n_in / n_points if n_points else 0.0,
        n_inliers=n_in,
        n_points=n_points,
        iterations=fit.iterations,
        method=method,
        conditioning=float(vals[0]),
        well_conditioned=bool(
            np.linalg.eigvalsh(cov_g[:2, :2])[-1] <= icp.max_sigma_xy**2
            and cov_g[2, 2] <= icp.max_sigma_theta**2
        ),
        elements=tuple(
            e for e, c in zip(model.elements, counts, strict=True) if c >= icp.min_element_inliers
        ),
        hypotheses=hypotheses,
        contradictions=contradictions,
    )


def _points(points_r: ArrayLike) -> FloatArray:
    pts = np.asarray(points_r, dtype=float).reshape(-1, 2)
    return pts[np.all(np.isfinite(pts), axis=1)]


# -- public entry points ------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class GlobalSettings:
    """The global step (Alg. 2.3): matching tolerances and hypothesis scoring.

    ``gate`` multiplies the prior sigmas into the search window; ``score_distance`` is
    the MSAC truncation; at most ``max_score_points`` returns (evenly spread) score each
    of at most ``max_hypotheses`` hypotheses (those nearest the prior are kept: a bound
    on the time, as the thesis's time limit); the ``candidates`` best distinct
    hypotheses are refined by ICP; fewer than ``min_inliers`` inliers, or inliers on
    fewer than ``min_elements`` footprint elements (``IcpSettings.min_element_inliers``
    each), means no result: one rectangle alone is too easily a vehicle of its size.
    Free-space test (when the sight lines are given): a beam that passes through the
    footprint, ``see_through_tolerance`` short of its return, contradicts the pose;
    each contradiction cancels ``see_through_weight`` of a candidate's support, and more
    than ``max_see_through`` contradictions per inlier means no result.
    """

    gate: float = 3.0
    angle_tolerance: float = math.radians(4.0)
    extent_tolerance: float = 0.25
    radius_tolerance: float = 0.1
    score_distance: float = 0.2
    max_score_points: int = 400
    max_hypotheses: int = 3000
    candidates: int = 3
    min_inliers: int = 40
    min_elements: int = 2
    see_through_tolerance: float = 0.2
    see_through_weight: float = 2.0
    max_see_through: float = 0.1


DEFAULT_ICP = IcpSettings()
DEFAULT_GLOBAL = GlobalSettings()


def refine(
    model: FootprintModel,
    points_r: ArrayLike,
    initial_pose_f: Pose2,
    icp: IcpSettings = DEFAULT_ICP,
    *,
    sight_lines: SightLines | None = None,
    see_through_tolerance: float = DEFAULT_GLOBAL.see_through_tolerance,
) -> Registration:
    """ICP refinement (Alg. 2.2 step 6: Chen-Medioni point-to-line error, Besl-McKay
    iteration) of the robot pose in F from ``initial_pose_f``, for periodic tracking.

    ``points_r``: (N, 2) returns in R, any order. The initial pose must displace the
    returns by less than about ``icp.max_distance``. ``sight_lines``
    (:meth:`SightLines.from_scans`), when given, are counted in ``contradictions``.
    Always returns a result: check ``well_conditioned``, ``n_inliers``, ``rms`` (and
    ``contradictions``) before trusting it.
    """
    pts = _points(points_r)
    fit = _icp(model, pts, mirror_pose(initial_pose_f), icp)
    seen_through = _see_through(model, sight_lines, fit.pose_g, see_through_tolerance)
    return _registration(model, fit, len(pts), RegistrationMethod.ICP, icp, 0, seen_through)


def register(
    model: FootprintModel,
    points_r: ArrayLike,
    prior_pose_f: Pose2,
    *,
    prior_sigma_xy: float,
    prior_sigma_theta: float,
    sight_lines: SightLines | None = None,
    settings: GlobalSettings = DEFAULT_GLOBAL,
    icp: IcpSettings = DEFAULT_ICP,
) -> Registration | None:
    """Global registration: Alg. 2.2 with the modified RANSAC of Alg. 2.3, then ICP.

    ``points_r``: (N, 2) returns in R in beam order, scanners concatenated
    (:func:`points_from_scans`). ``prior_pose_f``: the robot pose in F as believed (e.g.
    through the nominal parking pose), searched within ``settings.gate`` times
    ``prior_sigma_xy`` (m) and ``prior_sigma_theta`` (rad) of it. A parking error
    (d, phi) about the nose moves a robot r metres from the nose by up to d + r phi in F.
    ``sight_lines`` (:meth:`SightLines.from_scans`), when given, enable the free-space
    test (:class:`GlobalSettings`), which keeps clutter of the footprint's shapes from
    passing for the aircraft. Returns ``None`` when the evidence is insufficient
    (module docstring), never a guess.
    """
    if not (prior_sigma_xy > 0.0 and prior_sigma_theta > 0.0):
        raise ValueError("the prior sigmas must be positive")
    s = settings
    pts = _points(points_r)
    if len(pts) < s.min_inliers:
        return None
    prior_g = mirror_pose(prior_pose_f)
    gate_xy, gate_theta = s.gate * prior_sigma_xy, s.gate * prior_sigma_theta
    hyp = _hypotheses(
        model,
        extract_features(model, pts, radius_tolerance=s.radius_tolerance),
        prior_g,
        gate_xy,
        gate_theta,
        angle_tolerance=s.angle_tolerance,
        extent_tolerance=s.extent_tolerance,
        radius_tolerance=s.radius_tolerance,
    )
    if not len(hyp):
        return None
    if len(hyp) > s.max_hypotheses:
        far = np.hypot(hyp[:, 0] - prior_g.x, hyp[:, 1] - prior_g.y) / gate_xy
        far += np.abs(_wrap(hyp[:, 2] - prior_g.theta)) / gate_theta
        hyp = hyp[np.argsort(far, kind="stable")[: s.max_hypotheses]]
    stride = max(1, math.ceil(len(pts) / s.max_score_points))
    scores = _scores(model, pts[::stride], hyp, s.score_distance)
    chosen: list[FloatArray] = []
    for h in hyp[np.argsort(-scores, kind="stable")]:
        if all(
            math.hypot(h[0] - c[0], h[1] - c[1]) > SEPARATE[0]
            or abs(wrap_angle(h[2] - c[2])) > SEPARATE[1]
            for c in chosen
        ):
            chosen.append(h)
            if len(chosen) == s.candidates:
                break
    fits = [_icp(model, pts, Pose2(*h), icp) for h in chosen]
    seen = [_see_through(model, sight_lines, f.pose_g, s.see_through_tolerance) for f in fits]
    merit = [f.support - s.see_through_weight * c for f, c in zip(fits, seen, strict=True)]
    k = int(np.argmax(merit))
    best = fits[k]
    result = _registration(model, best, len(pts), RegistrationMethod.GLOBAL, icp, len(hyp), seen[k])
    pose = best.pose_g
    if (
        result.n_inliers < s.min_inliers
        or len(result.elements) < s.min_elements
        or seen[k] > s.max_see_through * result.n_inliers
        or not result.well_conditioned
        or math.hypot(pose.x - prior_g.x, pose.y - prior_g.y) > gate_xy
        or abs(wrap_angle(pose.theta - prior_g.theta)) > gate_theta
    ):
        return None
    return result


def points_from_scans(
    scans: Mapping[str, LaserScan], lasers: Mapping[str, LaserSpec]
) -> FloatArray:
    """The returns of the scans of known lasers as (N, 2) points in R: beam order within a
    scan, scans in the platform's laser order (the order :func:`register` expects)."""
    parts = [
        scan_to_robot(
            scans[lid].ranges,
            scans[lid].angle_min,
            scans[lid].angle_increment,
            scans[lid].range_max,
            Pose2(spec.mount[0], spec.mount[1], spec.mount_yaw),
        )
        for lid, spec in lasers.items()
        if lid in scans
    ]
    return np.vstack(parts) if parts else np.zeros((0, 2))


# -- airport <- aircraft ------------------------------------------------------------------------
def placement_from_registration(
    pose_a: Pose2, registration: Registration, origin_height: float
) -> AircraftPlacement:
    """The aircraft placement (A <- F) implied by the robot's pose in A and its registered
    pose in F: the one whose ``pose_to_aircraft(pose_a)`` is ``registration.pose_f``.
    ``origin_height`` is the aircraft type's nose height (``Aircraft.origin_height``)."""
    pf = registration.pose_f
    phi = wrap_angle(pose_a.theta + pf.theta)  # heading of +x_F in A
    c, s = math.cos(phi), math.sin(phi)
    x = pose_a.x - (c * pf.x + s * pf.y)  # minus Rot(phi) (x_F, -y_F)
    y = pose_a.y - (s * pf.x - c * pf.y)
    return AircraftPlacement(x, y, wrap_angle(phi - math.pi), origin_height)


def placement_covariance(
    pose_a: Pose2, pose_a_covariance: ArrayLike, registration: Registration
) -> FloatArray:
    """3x3 covariance of (x, y, heading) of :func:`placement_from_registration`, to first
    order, from the robot pose's covariance in A and the registration's (independent)."""
    pf = registration.pose_f
    phi = pose_a.theta + pf.theta
    c, s = math.cos(phi), math.sin(phi)
    gx, gy = s * pf.x - c * pf.y, -c * pf.x - s * pf.y  # d(x, y) / d(phi)
    j_a = np.array([[1.0, 0.0, gx], [0.0, 1.0, gy], [0.0, 0.0, 1.0]])
    j_f = np.array([[-c, -s, gx], [-s, c, gy], [0.0, 0.0, 1.0]])
    cov = j_a @ np.asarray(pose_a_covariance, dtype=float) @ j_a.T
    cov += j_f @ registration.covariance @ j_f.T
    return 0.5 * (cov + cov.T)
