"""Vectorised 2D ray casting for the simulated laser scanners and camera occlusion tests.

Pure numpy, no pymunk queries. Occluders are line segments and circles in one 2D frame
(the world, SI units, angles in rad counter-clockwise from +x), collected in a
:class:`Scene`. :func:`cast_scan` produces the ranges of a planar scanner (a Hokuyo
UTM-30LX is ``angle_min=-3*pi/4``, ``angle_increment=pi/720``, 1081 beams, 30 m), in the
convention of :class:`executive.core.records.LaserScan` (:func:`cast_scans`: several
scanners of one model at once, as one scan of a scene repeated for each); :func:`cast_rays`
answers first-hit queries for arbitrary directions and says which obstacle was hit.

Which beams are computed, and why
---------------------------------
Brute force (every beam against every shape) wastes almost all of its work: seen from the
sensor, a shape covers a small angular interval, and a beam outside it cannot hit it. So,
vectorised across shapes, with a small fixed number of numpy calls per cast:

1. Every point (segment end points, circle centres; stored as complex numbers ``x + iy``)
   is moved into the frame of beam 0 by one subtraction and one complex product, and
   its bearing taken by one ``arctan2``.
2. Each shape becomes an angular interval ``[start, start + width]``, width < pi: a
   segment ``a -> b`` spans ``arg(conj(a) b)`` from ``a`` (the product gives ``a . b`` and
   ``a x b`` at once), a circle its centre bearing ``+- asin(r / d)``.
3. Shapes that cannot be hit select nothing: circles containing the sensor or whose near
   side is out of reach; segments out of reach, or whose supporting line passes through
   the sensor (:data:`EDGE_ON_TOL`); and *back faces*: a segment flagged one-sided (the
   edges that :meth:`Scene.from_polygon` makes, stored counter-clockwise) when the sensor
   is on its interior side. Back-face culling is safe for any simple closed polygon: a ray
   from outside enters it through a front face before it can reach a back face.
4. Each interval becomes a range of beam indices, ``ceil`` of its low end and ``floor`` of
   its high end in units of ``angle_increment``, widened by :data:`ANGLE_TOL` so that a
   beam pointing exactly at a segment end point or exactly tangent to a circle is kept.
   The wrap-around is handled by shifting: an interval that starts before beam 0 (its
   relative start is in ``[-2 pi, pi]``) is also tried 2 pi later, so a shape
   straddling the +-pi direction, or the blind sector behind a 270 deg scanner, selects
   beams at both ends of the scan. Beams outside the field of view do not exist.
5. The index ranges are expanded into (beam, shape) pairs with ``cumsum``/``repeat``, the
   exact distance is computed for these pairs only, and ``np.minimum.at`` reduces them
   into the ranges: the nearest shape wins.

The selection of step 4 *is* the intersection test: a ray from the sensor meets a segment
exactly when its direction lies in the segment's angular span, and a circle exactly when
it lies within ``asin(r / d)`` of the centre's bearing. The distances are the analytic
ones, in float64: along the unit direction ``u``, a segment at
``t = (a x e) / (u x e)`` with ``e = b - a`` (``a x e`` rather than the equal ``a x b``,
which loses digits to cancellation); a circle at ``t = p - sqrt(r^2 - q^2)`` with
``p = c . u``, ``q = c x u``, ``r^2 - q^2`` clamped at 0 so that a grazing beam returns the
distance of the tangent point.

Conventions
-----------
* A beam with no hit within ``range_max`` reads ``range_max`` (:func:`cast_scan`); a ray
  with no hit within ``max_dist`` reads ``inf`` with owner ``-1`` (:func:`cast_rays`).
* A sensor inside a circle or on its boundary ignores that circle. A sensor on a segment
  ignores it; precisely, a segment whose supporting line passes closer to the sensor
  than ``EDGE_ON_TOL * (|a| + |b|)`` is ignored, which also covers a segment seen
  edge-on (it has no angular width; the end point of a polygon edge is still seen
  through the adjacent edge). With back-face culling, a sensor inside or on the boundary
  of a convex polygon from :meth:`Scene.from_polygon` does not see that polygon at all;
  inside a non-convex one it sees the edges whose outside faces it.
* Accuracy: a few ulp of the distance, except where the answer is ill-conditioned in the
  beam angle: at grazing incidence on a segment (error ~ ``|dt/dangle| * 1e-15 rad``) and
  for a beam tangent to a circle (``sqrt(2 r d * 1e-16)``, ~1e-7 m at 10 m).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "ANGLE_TOL",
    "EDGE_ON_TOL",
    "Scene",
    "box_corners",
    "cast_rays",
    "cast_scan",
    "cast_scans",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
ComplexArray = NDArray[np.complex128]

TWO_PI = 2.0 * math.pi

#: Angular widening (rad) of each shape's interval when beams are selected. Rounding in
#: the bearings and beam angles is ~1e-15 rad; at 30 m this tolerance is 3e-11 m sideways.
ANGLE_TOL = 1e-12

#: A segment is ignored when its supporting line passes closer to the sensor than
#: ``EDGE_ON_TOL * (|a| + |b|)`` (a, b its end points relative to the sensor): the sensor
#: sits on it, or sees it (within ~1e-11 rad of) edge-on. This also keeps every beam that
#: ANGLE_TOL admits in front of the line, so distances are always positive.
EDGE_ON_TOL = 4e-12


def _as_rows(values: ArrayLike, width: int, name: str) -> FloatArray:
    arr = np.asarray(values, dtype=np.float64)
    if arr.size == 0:
        return np.zeros((0, width))
    if arr.ndim == 1 and arr.shape[0] == width:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != width:
        raise ValueError(f"{name} must have shape (n, {width}), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite")
    return arr


def _as_owner(owner: ArrayLike | None, n: int, name: str) -> IntArray:
    if owner is None:
        return np.full(n, -1, dtype=np.int64)
    arr = np.asarray(owner)
    if arr.ndim == 0:
        return np.full(n, int(arr), dtype=np.int64)
    if arr.shape != (n,):
        raise ValueError(f"{name} must have shape ({n},), got {arr.shape}")
    return arr.astype(np.int64)


def _ring(points: ArrayLike) -> FloatArray:
    """A closed ring as (n, 2) vertices, counter-clockwise, without a repeated last point."""
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2 or not np.all(np.isfinite(pts)):
        raise ValueError("a polygon is a sequence of finite (x, y) points")
    if len(pts) > 1 and np.array_equal(pts[0], pts[-1]):
        pts = pts[:-1]
    if len(pts) < 3:
        raise ValueError("a polygon needs at least 3 vertices")
    x, y = pts[:, 0], pts[:, 1]
    area2 = float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))
    if area2 == 0.0:
        raise ValueError("a polygon must have a non-zero area")
    if not _ring_is_simple(pts):
        raise ValueError("a polygon must not touch or intersect itself")
    return pts if area2 > 0.0 else pts[::-1].copy()


def _ring_is_simple(pts: FloatArray) -> bool:
    """True when no two non-adjacent edges of the closed ring touch or cross."""
    n = len(pts)
    if n == 3:
        return True
    i, j = np.triu_indices(n, k=2)
    keep = ~((i == 0) & (j == n - 1))  # the first and last edges are adjacent
    i, j = i[keep], j[keep]
    nxt = np.roll(pts, -1, axis=0)
    p1, p2, p3, p4 = pts[i], nxt[i], pts[j], nxt[j]

    def orient(p: FloatArray, q: FloatArray, r: FloatArray) -> FloatArray:
        u, v = q - p, r - p
        return np.sign(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0])

    def within(p: FloatArray, q: FloatArray, r: FloatArray) -> NDArray[np.bool_]:
        return np.all((r >= np.minimum(p, q)) & (r <= np.maximum(p, q)), axis=1)

    o1, o2 = orient(p1, p2, p3), orient(p1, p2, p4)
    o3, o4 = orient(p3, p4, p1), orient(p3, p4, p2)
    bad = (o1 * o2 < 0) & (o3 * o4 < 0)
    bad |= (o1 == 0) & within(p1, p2, p3)
    bad |= (o2 == 0) & within(p1, p2, p4)
    bad |= (o3 == 0) & within(p3, p4, p1)
    bad |= (o4 == 0) & within(p3, p4, p2)
    return not bool(np.any(bad))


def _ring_segments(ring: FloatArray) -> FloatArray:
    return np.hstack((ring, np.roll(ring, -1, axis=0)))


class Scene:
    """Occluders for ray casting: line segments and circles in one 2D frame (the world).

    ``segments`` is ``(N, 4)``: ``x1, y1, x2, y2``; ``circles`` is ``(M, 3)``: ``cx, cy, r``
    with ``r > 0``. ``segment_owner`` / ``circle_owner`` are ``(N,)`` / ``(M,)`` integer ids
    (default ``-1``; a scalar sets them all) so that a caller can map a hit back to an
    obstacle. Segments given here are two-sided; :meth:`from_polygon` (and
    :meth:`from_box`) make one-sided edges, which allow back-face culling.

    Moving obstacles
    ----------------
    The geometry lives in preallocated arrays that the caller may rewrite in place at
    every step: no reallocation, and no cache to invalidate (everything derived is
    recomputed by each cast, from these arrays only).

    * :attr:`segments` ``(N, 4)``, :attr:`centers` ``(M, 2)``, :attr:`radii` ``(M,)``,
      :attr:`segment_owner` and :attr:`circle_owner` are writable views;
    * :meth:`set_segments`, :meth:`set_circles` and :meth:`set_polygon` overwrite a block
      of rows starting at a given row.

    :meth:`concat` keeps the order of its parts, so the rows of part ``i`` start after the
    ``n_segments`` (``n_circles``) of the parts before it. Polygon edges must stay
    counter-clockwise: a rigid motion (rotate and translate the end points) keeps them
    so, a reflection would not; :meth:`set_polygon` reorients a ring for you.
    """

    __slots__ = ("_n_seg", "_one_sided", "_owners", "_points", "_radii", "_side_sign", "_z")

    def __init__(
        self,
        segments: ArrayLike = (),
        circles: ArrayLike = (),
        segment_owner: ArrayLike | None = None,
        circle_owner: ArrayLike | None = None,
    ) -> None:
        seg = _as_rows(segments, 4, "segments")
        circ = _as_rows(circles, 3, "circles")
        if np.any(circ[:, 2] <= 0.0):
            raise ValueError("circle radii must be > 0")
        n, m = len(seg), len(circ)
        # All points as complex numbers x + iy: segment end points (a, b interleaved), then
        # circle centres. One complex multiply moves them into the sensor frame, and
        # conj(a) * b gives a . b + i a x b at once. _points is the (x, y) view of it.
        self._z = np.empty(2 * n + m, dtype=np.complex128)
        self._points = self._z.view(np.float64).reshape(-1, 2)
        self._points[: 2 * n] = seg.reshape(2 * n, 2)
        self._points[2 * n :] = circ[:, :2]
        self._n_seg = n
        self._radii = circ[:, 2].copy()
        self._owners = np.concatenate(
            (
                _as_owner(segment_owner, n, "segment_owner"),
                _as_owner(circle_owner, m, "circle_owner"),
            )
        )
        self._set_one_sided(np.zeros(n, dtype=bool))

    def _set_one_sided(self, flags: NDArray[np.bool_]) -> None:
        self._one_sided = flags
        # side = max(cross * sign, -cross): |cross| when two-sided, -cross when one-sided.
        self._side_sign = np.where(flags, -1.0, 1.0)

    # -- construction -------------------------------------------------------------------
    @staticmethod
    def from_polygon(points: ArrayLike) -> Scene:
        """The edges of a closed ring of ``(x, y)`` vertices, any orientation.

        The ring must be simple, with a non-zero area; a repeated closing vertex is
        dropped. The edges are stored counter-clockwise (the interior on their left) and
        flagged one-sided, so that edges facing away from the sensor are culled. Owners
        are ``-1``: see :meth:`with_owner`.
        """
        scene = Scene(_ring_segments(_ring(points)))
        scene._set_one_sided(np.ones(scene._n_seg, dtype=bool))
        return scene

    @staticmethod
    def from_box(
        x: float, y: float, heading: float, length: float, width: float, owner: int = -1
    ) -> Scene:
        """A rectangle centred at ``(x, y)``, ``length`` along ``heading``, as a polygon."""
        if not (length > 0.0 and width > 0.0):
            raise ValueError("a box needs length > 0 and width > 0")
        return Scene.from_polygon(box_corners(x, y, heading, length, width)).with_owner(owner)

    @staticmethod
    def concat(scenes: Iterable[Scene]) -> Scene:
        """One scene with the segments, then the circles, of ``scenes`` in order."""
        parts = list(scenes)
        out = Scene()
        if not parts:
            return out
        out._n_seg = sum(p._n_seg for p in parts)
        out._z = np.concatenate(
            [p._z[: 2 * p._n_seg] for p in parts] + [p._z[2 * p._n_seg :] for p in parts]
        )
        out._points = out._z.view(np.float64).reshape(-1, 2)
        out._radii = np.concatenate([p._radii for p in parts])
        out._owners = np.concatenate(
            [p.segment_owner for p in parts] + [p.circle_owner for p in parts]
        )
        out._set_one_sided(np.concatenate([p._one_sided for p in parts]))
        return out

    def with_owner(self, owner: int) -> Scene:
        """A copy whose shapes all have the owner id ``owner``."""
        out = self.copy()
        out._owners[:] = owner
        return out

    def copy(self) -> Scene:
        """A deep copy (its arrays can be rewritten independently)."""
        return Scene.concat([self])

    # -- views and updates --------------------------------------------------------------
    @property
    def n_segments(self) -> int:
        return self._n_seg

    @property
    def n_circles(self) -> int:
        return len(self._radii)

    @property
    def segments(self) -> FloatArray:
        """``(N, 4)`` writable view: ``x1, y1, x2, y2`` per row."""
        return self._points[: 2 * self._n_seg].reshape(self._n_seg, 4)

    @property
    def centers(self) -> FloatArray:
        """``(M, 2)`` writable view of the circle centres."""
        return self._points[2 * self._n_seg :]

    @property
    def radii(self) -> FloatArray:
        """``(M,)`` writable view of the circle radii (keep them > 0)."""
        return self._radii

    @property
    def circles(self) -> FloatArray:
        """``(M, 3)`` copy: ``cx, cy, r`` per row."""
        return np.column_stack((self.centers, self._radii))

    @property
    def segment_owner(self) -> IntArray:
        """``(N,)`` writable view of the segment owner ids."""
        return self._owners[: self._n_seg]

    @property
    def circle_owner(self) -> IntArray:
        """``(M,)`` writable view of the circle owner ids."""
        return self._owners[self._n_seg :]

    @property
    def one_sided(self) -> NDArray[np.bool_]:
        """``(N,)`` read-only: True for a (counter-clockwise) polygon edge."""
        view = self._one_sided.view()
        view.flags.writeable = False
        return view

    def set_segments(self, segments: ArrayLike, start: int = 0) -> None:
        """Overwrite segment rows ``start, start + 1, ...`` in place (``(k, 4)`` rows)."""
        rows = np.asarray(segments, dtype=np.float64).reshape(-1, 4)
        if start < 0 or start + len(rows) > self._n_seg:
            raise IndexError("segment rows out of range")
        self._points[2 * start : 2 * (start + len(rows))] = rows.reshape(-1, 2)

    def set_circles(self, circles: ArrayLike, start: int = 0) -> None:
        """Overwrite circle rows ``start, start + 1, ...`` in place (``(k, 3)`` rows)."""
        rows = np.asarray(circles, dtype=np.float64).reshape(-1, 3)
        if start < 0 or start + len(rows) > len(self._radii):
            raise IndexError("circle rows out of range")
        if np.any(rows[:, 2] <= 0.0):
            raise ValueError("circle radii must be > 0")
        base = 2 * self._n_seg + start
        self._points[base : base + len(rows)] = rows[:, :2]
        self._radii[start : start + len(rows)] = rows[:, 2]

    def set_polygon(self, points: ArrayLike, start: int = 0) -> None:
        """Overwrite the polygon edges from row ``start`` with the ring ``points``.

        For a polygon that moved: ``points`` is its ring at the new pose (any
        orientation, as for :meth:`from_polygon`), with as many vertices as it has edges.
        """
        edges = _ring_segments(_ring(points))
        stop = start + len(edges)
        if start < 0 or stop > self._n_seg or not np.all(self._one_sided[start:stop]):
            raise IndexError("rows start..start+n are not the edges of a polygon")
        self.set_segments(edges, start)

    def __repr__(self) -> str:
        return f"Scene({self._n_seg} segments, {len(self._radii)} circles)"


def box_corners(x: float, y: float, heading: float, length: float, width: float) -> FloatArray:
    """The 4 corners (counter-clockwise) of a ``length`` x ``width`` box centred at (x, y)."""
    c, s = math.cos(heading), math.sin(heading)
    hl, hw = 0.5 * length, 0.5 * width
    local = np.array(((hl, -hw), (hl, hw), (-hl, hw), (-hl, -hw)))
    return local @ np.array(((c, s), (-s, c))) + (x, y)


# -- per-cast machinery ------------------------------------------------------------------
#: Width given to a culled shape: finite (it is cast to an integer index) and so negative
#: that the shape selects no beam.
_CULLED = -1.0e6


def _shapes(
    scene: Scene, origin: complex | ComplexArray, rot: complex | ComplexArray, reach: float
) -> tuple[FloatArray, FloatArray, ComplexArray, FloatArray]:
    """Angular interval and pair coefficient of every shape, seen from ``origin``.

    Bearings are measured from the reference direction ``conj(rot)`` (``rot`` is a unit
    complex number). Returns, per shape (segments, then circles): ``start``, the bearing
    of the clockwise end of the interval, in ``[-2 pi, pi]``; ``width`` in ``[0, pi)``
    (``_CULLED`` for a shape that cannot be hit), so ``start + width <= 2 pi``; and
    ``coef``: for a segment ``(b - a) / (a x b)``, so that the beam of unit direction ``u``
    meets it at ``1 / Im(conj(u) * coef)``; for a circle, its centre. Also the squared
    radii.

    ``origin`` and ``rot`` may also be arrays with one value per point of the scene (as
    for a :func:`_stacked` scene, each copy seen from its own viewpoint).
    """
    n = scene._n_seg
    k = n + len(scene._radii)
    w = scene._z - origin
    w *= rot
    bearing = np.arctan2(w.imag, w.real)
    dist = np.abs(w)
    start = np.empty(k)
    width = np.full(k, _CULLED)
    coef = np.empty(k, dtype=np.complex128)
    if n:
        # e from the world coordinates (exact for short segments): a x e is then free of
        # the cancellation of a x b, and equal to it.
        e = scene._z[1 : 2 * n : 2] - scene._z[0 : 2 * n : 2]
        e *= rot[0 : 2 * n : 2] if isinstance(rot, np.ndarray) else rot
        length = np.abs(e)
        a, dist_a = w[0 : 2 * n : 2], dist[0 : 2 * n : 2]
        ae = np.conjugate(a)
        ae *= e  # a . e + i a x e
        cross = ae.imag
        # the angle from a to b, counter-clockwise: arg(conj(a) b) = arg(|a|^2 + conj(a) e),
        # whose imaginary part is exactly cross
        signed_width = np.arctan2(cross, ae.real + dist_a * dist_a)
        # cross / length is the sensor's signed distance to the line (> 0: on the left,
        # the interior side of a polygon edge). Keep a segment whose line is clear of
        # the sensor, seen from the outside if one-sided, and that may come within reach
        # (its points are at least (|a| + |b| - length) / 2 away).
        side = np.maximum(cross * scene._side_sign, -cross)
        span = dist_a + dist[1 : 2 * n : 2]
        keep = side > (EDGE_ON_TOL * span + 1e-150) * length  # 1e-150: no overflow in coef
        keep &= span - length <= 2.0 * reach
        np.minimum(signed_width, 0.0, out=start[:n])
        start[:n] += bearing[0 : 2 * n : 2]  # bearing of a, or of b when cross < 0
        np.copyto(width[:n], np.abs(signed_width), where=keep)
        np.divide(e, np.where(keep, cross, 1.0), out=coef[:n])
    r = scene._radii
    if len(r):
        d = dist[2 * n :]
        half = np.arcsin(r / np.maximum(d, r))
        keep = d > r
        keep &= d <= r + reach
        np.subtract(bearing[2 * n :], half, out=start[n:])
        np.copyto(width[n:], half + half, where=keep)
        coef[n:] = w[2 * n :]
    return start, width, coef, r * r


def _distances(
    neg_first: IntArray,
    count: IntArray,
    conj_dirs: ComplexArray,
    coef: ComplexArray,
    rsq: FloatArray,
    n_seg: int,
) -> tuple[IntArray, FloatArray, IntArray]:
    """Expand index ranges into (beam, shape) pairs and compute their exact distances.

    ``neg_first`` (minus the first index) and ``count`` are ``(S, K)``: S ranges of beam
    indices per shape (for the wrap-around); ``conj_dirs[i]`` is the conjugate of beam i's
    unit direction. Returns the beam index and distance of every pair, grouped by shape
    (segment pairs first), and the pair count of every shape.
    """
    per_shape = count[0] + count[1] if len(count) == 2 else count.sum(axis=0)
    flat = count.ravel(order="F")  # shape-major: the pairs of one shape are contiguous
    ends = np.add.accumulate(flat)
    total = int(ends[-1])
    n_seg_pairs = int(ends[len(count) * n_seg - 1]) if n_seg else 0
    offset = neg_first.ravel(order="F")
    offset += ends
    offset -= flat
    beams = np.arange(total)
    beams -= offset.repeat(flat)
    z = coef.repeat(per_shape)
    z *= conj_dirs.take(beams)
    t = np.empty(total)
    np.reciprocal(z.imag[:n_seg_pairs], out=t[:n_seg_pairs])
    if total > n_seg_pairs:
        q = z.imag[n_seg_pairs:]
        disc = rsq.repeat(per_shape[n_seg:])
        disc -= q * q
        np.maximum(disc, 0.0, out=disc)
        np.sqrt(disc, out=disc)
        np.subtract(z.real[n_seg_pairs:], disc, out=t[n_seg_pairs:])
    return beams, t, per_shape


def _shifts(fov: float) -> FloatArray:
    """Multiples of 2 pi to add to intervals so that they cover ``[0, fov]``, as (S, 1).

    An interval starts in ``[-2 pi, pi]`` and ends by ``2 pi`` (a width of pi or more is
    culled), so no negative shift is needed; ``+2 pi`` reaches the beams that an interval
    starting below 0 covers at the other end of the field of view.
    """
    return (TWO_PI * np.arange(2 + int(fov // TWO_PI), dtype=np.float64))[:, None]


#: The shifts for rays sorted in [0, 2 pi).
_RAY_SHIFTS = _shifts(math.pi)
_RAY_SHIFTS.flags.writeable = False


def _conj_dirs(angles: FloatArray) -> ComplexArray:
    """``cos(angles) - i sin(angles)``: the conjugate unit directions."""
    out = np.empty(len(angles), dtype=np.complex128)
    neg = np.negative(angles)
    np.cos(neg, out=out.real)
    np.sin(neg, out=out.imag)
    return out


def _beam_ranges(
    start: FloatArray,
    width: FloatArray,
    angle_increment: float,
    neg_lo: FloatArray,
    hi: FloatArray,
    caps: FloatArray,
) -> tuple[IntArray, IntArray]:
    """Beam-index range of every (shift, shape) from its angular ``start`` and ``width``
    (radians; both scaled in place): ``[ceil(low end), floor(high end)]`` as ``-first``
    (ceil(x) = -floor(-x)) and the beam count (0 when empty)."""
    inv = 1.0 / angle_increment
    start *= inv
    width *= inv
    width += start
    bounds = np.empty((2, len(neg_lo), len(start)))
    np.subtract(neg_lo, start, out=bounds[0])
    np.add(hi, width, out=bounds[1])
    np.floor(bounds, out=bounds)
    np.minimum(bounds, caps, out=bounds)
    index = bounds.astype(np.int64)
    count = index[1] + index[0]
    np.maximum(count, 0, out=count)
    return index[0], count


@lru_cache(maxsize=64)
def _beam_table(
    angle_increment: float, n_beams: int
) -> tuple[ComplexArray, FloatArray, FloatArray, FloatArray]:
    """Per-scanner constants: conjugate beam directions relative to beam 0; the shifts
    in beam indices, widened by ANGLE_TOL, as ``-(shift - tol)`` for the low ends and
    ``shift + tol + 1`` for the high ends; the caps ``(0, n_beams)`` of both."""
    conj_dirs = _conj_dirs(angle_increment * np.arange(n_beams))
    inv = 1.0 / angle_increment
    shifts = _shifts(angle_increment * (n_beams - 1)) * inv
    tol = ANGLE_TOL * inv
    neg_lo = tol - shifts
    hi = shifts + (tol + 1.0)
    caps = np.array((0.0, float(n_beams))).reshape(2, 1, 1)
    for arr in (conj_dirs, neg_lo, hi, caps):
        arr.flags.writeable = False
    return conj_dirs, neg_lo, hi, caps


def cast_scan(
    scene: Scene,
    origin: tuple[float, float],
    heading: float,
    angle_min: float,
    angle_increment: float,
    n_beams: int,
    range_max: float,
    out: NDArray | None = None,
) -> NDArray[np.float64]:
    """Ranges (n_beams,) of a scan from `origin` whose beam k points along
    heading + angle_min + k*angle_increment (world frame). No hit within range_max -> range_max.

    Only the beams inside the angular interval of some shape that can be hit are
    computed (see the module docstring). ``out`` (float64, ``(n_beams,)``) receives the
    ranges if given. A negative ``angle_increment`` is allowed.
    """
    n_beams = int(n_beams)
    if out is None:
        out = np.empty(n_beams)
    elif out.shape != (n_beams,) or out.dtype != np.float64:
        raise ValueError(f"out must be a float64 array of shape ({n_beams},)")
    if not (angle_increment != 0.0 and math.isfinite(angle_increment)):
        raise ValueError("angle_increment must be finite and non-zero")
    out.fill(range_max)
    if n_beams == 0 or len(scene._owners) == 0:
        return out
    target = out
    if angle_increment < 0.0:  # the same beams, counter-clockwise, into a reversed view
        angle_min += angle_increment * (n_beams - 1)
        angle_increment = -angle_increment
        target = out[::-1]
    conj_dirs, neg_lo, hi, caps = _beam_table(float(angle_increment), n_beams)
    ref = heading + angle_min  # the direction of beam 0
    start, width, coef, rsq = _shapes(
        scene,
        complex(origin[0], origin[1]),
        complex(math.cos(ref), -math.sin(ref)),
        float(range_max),
    )
    neg_first, count = _beam_ranges(start, width, angle_increment, neg_lo, hi, caps)
    beams, t, _ = _distances(neg_first, count, conj_dirs, coef, rsq, scene._n_seg)
    np.minimum.at(target, beams, t)
    return out


def _stacked(scene: Scene, copies: int) -> Scene:
    """``copies`` copies of the shapes of ``scene`` as one scene: the segments of every
    copy, then the circles of every copy. Only what :func:`_shapes` reads is set."""
    n = scene._n_seg
    z = scene._z
    out = Scene.__new__(Scene)
    out._z = np.concatenate((*(z[: 2 * n],) * copies, *(z[2 * n :],) * copies))
    out._n_seg = copies * n
    out._radii = np.concatenate((scene._radii,) * copies)
    out._side_sign = np.concatenate((scene._side_sign,) * copies)
    return out


@lru_cache(maxsize=64)
def _stack_layout(n_seg: int, n_circ: int, copies: int, n_beams: int) -> tuple[IntArray, IntArray]:
    """For a :func:`_stacked` scene: how many points of each block (the segments of each
    copy, then the circles of each copy) share a viewpoint, and the first output index
    (``copy * n_beams``) of every shape."""
    reps = np.array((2 * n_seg,) * copies + (n_circ,) * copies, dtype=np.int64)
    lane = n_beams * np.arange(copies, dtype=np.int64)
    first = np.concatenate((lane.repeat(n_seg), lane.repeat(n_circ)))
    for arr in (reps, first):
        arr.flags.writeable = False
    return reps, first


@lru_cache(maxsize=64)
def _tiled_dirs(angle_increment: float, n_beams: int, copies: int) -> ComplexArray:
    """The conjugate beam directions of :func:`_beam_table`, once per scan."""
    dirs = np.tile(_beam_table(angle_increment, n_beams)[0], copies)
    dirs.flags.writeable = False
    return dirs


def cast_scans(
    scene: Scene,
    origins: Sequence[tuple[float, float]],
    headings: Sequence[float],
    angle_min: float,
    angle_increment: float,
    n_beams: int,
    range_max: float,
) -> NDArray[np.float64]:
    """Ranges ``(L, n_beams)`` of L scans of one scanner model: row ``l`` is exactly
    ``cast_scan(scene, origins[l], headings[l], angle_min, ...)``.

    The scans are cast together, as one scan of a :func:`_stacked` scene whose copy
    ``l`` is seen from viewpoint ``l``: casting costs mostly the fixed overhead of its
    numpy calls, so two scanners cost little more than one. Every number is computed
    by the same numpy kernels as in :func:`cast_scan`, which give each element the same
    result wherever it sits in an array, with one exception: a complex product of
    length 1 is rounded without a fused multiply-add. So a scene with a single segment
    or point, a negative ``angle_increment``, and a scan with a single (beam, shape) pair
    are cast one scan at a time.
    """
    n_beams = int(n_beams)
    copies = len(origins)
    if len(headings) != copies:
        raise ValueError("origins and headings must have the same length")
    out = np.empty((copies, n_beams))
    n, m = scene._n_seg, len(scene._radii)
    if copies < 2 or n == 1 or 2 * n + m < 2 or not angle_increment > 0.0:
        for row in range(copies):
            args = (angle_min, angle_increment, n_beams, range_max)
            cast_scan(scene, origins[row], headings[row], *args, out=out[row])
        return out
    if not math.isfinite(angle_increment):
        raise ValueError("angle_increment must be finite and non-zero")
    out.fill(range_max)
    if n_beams == 0:
        return out
    conj_dirs = _tiled_dirs(float(angle_increment), n_beams, copies)
    _, neg_lo, hi, caps = _beam_table(float(angle_increment), n_beams)
    reps, lane_start = _stack_layout(n, m, copies, n_beams)
    refs = [heading + angle_min for heading in headings]  # the directions of beam 0
    at = np.array([complex(x, y) for x, y in origins] * 2).repeat(reps)
    rot = np.array([complex(math.cos(ref), -math.sin(ref)) for ref in refs] * 2).repeat(reps)
    start, width, coef, rsq = _shapes(_stacked(scene, copies), at, rot, float(range_max))
    # as in cast_scan, with the beams of copy l at l * n_beams... in the flat output
    neg_first, count = _beam_ranges(start, width, angle_increment, neg_lo, hi, caps)
    neg_first -= lane_start
    beams, t, _ = _distances(neg_first, count, conj_dirs, coef, rsq, copies * n)
    np.minimum.at(out.reshape(-1), beams, t)
    if len(t) > 1:
        lone = np.bincount(beams // n_beams, minlength=copies) == 1
        for row in lone.nonzero()[0].tolist():
            args = (angle_min, angle_increment, n_beams, range_max)
            cast_scan(scene, origins[row], headings[row], *args, out=out[row])
    return out


def cast_rays(
    scene: Scene,
    origin: tuple[float, float],
    angles: ArrayLike,
    max_dist: ArrayLike | float,
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """For arbitrary ray directions (world angles): first hit distance (inf if none within
    max_dist) and the owner id of the hit shape (-1 if none). Used for camera occlusion
    tests (a few hundred rays).

    The rays are sorted by direction so that each shape's angular interval selects a
    contiguous run of them (``searchsorted``); the distances are then the same exact ones
    as in :func:`cast_scan`. ``max_dist`` is a scalar or one value per ray (a hit at
    exactly ``max_dist`` counts). When two shapes are hit at the same distance, either
    owner may be reported. The outputs have the shape of ``angles``.
    """
    ang = np.asarray(angles, dtype=np.float64)
    shape = ang.shape
    ang = ang.ravel()
    n = len(ang)
    limit = np.asarray(max_dist, dtype=np.float64)
    if limit.ndim:
        if limit.shape != shape:
            raise ValueError("max_dist must be a scalar or have the shape of angles")
        limit = limit.ravel()
    dist = np.full(n, np.inf)
    owner = np.full(n, -1, dtype=np.int64)
    reach = float(limit.max()) if n else -1.0
    if not reach >= 0.0 or len(scene._owners) == 0:
        return dist.reshape(shape), owner.reshape(shape)

    wrapped = ang % TWO_PI
    wrapped[wrapped >= TWO_PI] = 0.0  # a tiny negative angle % 2 pi rounds to 2 pi
    order = np.argsort(wrapped)
    sorted_dir = wrapped[order]
    conj_dirs = _conj_dirs(ang[order])

    start, width, coef, rsq = _shapes(
        scene, complex(origin[0], origin[1]), 1.0 + 0.0j, min(reach, 1e300)
    )
    first = np.searchsorted(sorted_dir, _RAY_SHIFTS + (start - ANGLE_TOL), side="left")
    count = np.searchsorted(sorted_dir, _RAY_SHIFTS + (start + width + ANGLE_TOL), side="right")
    count -= first
    np.maximum(count, 0, out=count)
    np.negative(first, out=first)
    rays, t, per_shape = _distances(first, count, conj_dirs, coef, rsq, scene._n_seg)
    best = np.full(n, np.inf)
    np.minimum.at(best, rays, t)
    best[best > (limit[order] if limit.ndim else limit)] = np.inf
    winner = t == best[rays]
    best_owner = np.full(n, -1, dtype=np.int64)
    best_owner[rays[winner]] = np.repeat(scene._owners, per_shape)[winner]
    dist[order] = best
    owner[order] = best_owner
    return dist.reshape(shape), owner.reshape(shape)
