"""Planar geometry on model shapes, backed by shapely."""

from __future__ import annotations

import functools
import math
import re
from collections.abc import Iterable

import numpy as np
import shapely
from shapely.geometry import Point
from shapely.geometry import Polygon as ShapelyPolygon
from shapely.geometry.base import BaseGeometry
from shapely.validation import explain_validity

from executive.core.model import Circle, Shape


@functools.lru_cache(maxsize=4096)
def to_shapely(shape: Shape) -> BaseGeometry:
    """An exact shapely geometry for a polygon; a buffered point for a circle."""
    if isinstance(shape, Circle):
        return Point(shape.cx, shape.cy).buffer(shape.radius, quad_segs=32)
    return ShapelyPolygon(shape.points)


def polygon_problem(points: Iterable[tuple[float, float]]) -> str | None:
    """Why a ring of points is not a valid simple polygon, or None when it is."""
    pts = list(points)
    if len(pts) < 3:
        return f"a polygon needs at least 3 points, it has {len(pts)}"
    offsets = np.asarray(pts, dtype=float) - pts[0]
    if np.linalg.matrix_rank(offsets, tol=1e-9) < 2:
        return "the polygon has no area: its points are all on one line"
    poly = ShapelyPolygon(pts)
    if poly.is_valid:
        return None
    reason = explain_validity(poly)
    m = re.match(r"([^\[]+)\[(\S+) (\S+)\]", reason)
    if m:
        kind, x, y = m.groups()
        kind = {
            "Self-intersection": "its edges cross each other",
            "Ring Self-intersection": "its outline touches itself",
            "Too few points": "it has too few distinct points",
        }.get(kind, kind.lower())
        return f"not a valid simple polygon: {kind} at ({float(x):g}, {float(y):g})"
    return f"not a valid simple polygon: {reason}"


def distance_to_shape(x: float, y: float, shape: Shape) -> float:
    """Distance from (x, y) to a shape, 0 inside it; exact for circles and polygons."""
    if isinstance(shape, Circle):
        return max(0.0, math.hypot(x - shape.cx, y - shape.cy) - shape.radius)
    return float(shapely.distance(Point(x, y), to_shapely(shape)))
