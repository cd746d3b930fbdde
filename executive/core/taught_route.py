"""The taught-route file (``schemas/route.xsd``, namespace ``urn:walkaround:route:1``).

A route taught under a hangar ceiling (issue 17, seed 002 §2.3): the key images chosen
from a teaching run (:func:`behaviours.laws.routes.select_key_images`), each the robot
pose in the mosaic frame M (= A) with the ids of the mosaic landmarks it shows, repeated
at the longitudinal speed V by the VNHV law (§3). :func:`load_route` reads one with the
hardened front end every loader shares and reports every problem at ``file:line:column``
in one :class:`~executive.core.problems.InvalidInputError`; :func:`route_xml` writes one.

Semantic checks beyond the schema: unique key ids; V not zero; the mosaic file readable
(:func:`executive.core.mosaicfile.read_mosaic`) inside the mission library, taught under
the same ceiling height, knowing every landmark id a key names; the key images' files;
and the paper's two rules between successive key images (a common landmark; a heading
change below ``max-heading-change-deg``), each key ahead of the one before in the
direction of travel (the line through it is approached from behind, §3).
"""

from __future__ import annotations

import itertools
import math
from pathlib import Path
from xml.sax.saxutils import quoteattr

from lxml import etree

from executive.core.frames import Pose2, wrap_angle
from executive.core.model import KeyImage, TaughtRoute
from executive.core.mosaicfile import MosaicData, MosaicFormatError, read_mosaic
from executive.core.problems import InvalidInputError, Problem, ProblemSink, SourceLocation
from executive.core.xmlreader import (
    ElementReader,
    display_path,
    load_document,
    load_reference,
    problems_of,
)
from executive.core.xmlsafe import XmlDocument

__all__ = [
    "DEFAULT_MAX_HEADING_CHANGE_DEG",
    "DEFAULT_SETTLING_DISTANCE",
    "ROUTE_NS",
    "check_route",
    "load_route",
    "route_xml",
]

ROUTE_NS = "urn:walkaround:route:1"
DEFAULT_SETTLING_DISTANCE = 1.5
"""Metres (eq. 10, 5 %): about one robot length."""
DEFAULT_MAX_HEADING_CHANGE_DEG = 10.0
CEILING_HEIGHT_TOLERANCE = 0.05
"""Metres between the route's ceiling height and its mosaic's before they disagree."""
MIN_KEY_SPACING = 1e-3
"""Metres between successive key poses: closer, the line of §3 has no before and after."""


def load_route(path: Path | str, library_root: Path | str | None = None) -> TaughtRoute:
    """Load and check a taught route; raise InvalidInputError on any problem. Its files
    (mosaic, key images) must stay inside ``library_root`` (default: the route file's
    grandparent directory; a mission passes its own library root)."""
    return load_document(path, "route", ROUTE_NS, _build, library_root, 2)


def check_route(path: Path | str, library_root: Path | str | None = None) -> list[Problem]:
    """Every problem of a route file (empty when valid); never raises."""
    return problems_of(lambda: load_route(path, library_root))


def _checked_mosaic(path: Path) -> tuple[Path, MosaicData]:
    try:
        return path, read_mosaic(path)
    except MosaicFormatError as exc:
        where = SourceLocation(display_path(path))
        raise InvalidInputError([Problem(where, "mosaic-format", str(exc))]) from None


def _regular(path: Path) -> Path:
    return path


def _build(doc: XmlDocument, sink: ProblemSink, path: Path, root_dir: Path) -> TaughtRoute | None:
    r = ElementReader(doc, sink)
    root = doc.root
    loaded, problems = load_reference(r, "mosaic", path, root_dir, _checked_mosaic, "route")
    sink.extend(problems)
    height = r.num(root, "ceiling-height")
    speed = r.num(root, "speed")
    if speed == 0.0:
        r.problem(root, "route-speed", "speed V must not be 0 (eq. 10 holds for V != 0)", "speed")
    threshold = math.radians(r.num(root, "max-heading-change-deg", DEFAULT_MAX_HEADING_CHANGE_DEG))
    if loaded is not None and abs(loaded[1].ceiling_height - height) > CEILING_HEIGHT_TOLERANCE:
        r.problem(
            root,
            "route-ceiling",
            f"ceiling-height {height:g} m differs from the mosaic's "
            f"{loaded[1].ceiling_height:g} m: the landmarks would not match",
            "ceiling-height",
        )
    key_el = r.children(root, "key")
    r.unique(key_el, "key")
    known = set(loaded[1].ids) if loaded is not None else None
    keys = []
    for ke in key_el:
        landmarks = frozenset((ke.get("landmarks") or "").split())
        if known is not None:
            unknown = sorted(landmarks - known)
            if unknown:
                shown = ", ".join(unknown[:5]) + (" ..." if len(unknown) > 5 else "")
                r.problem(
                    ke,
                    "route-landmark",
                    f"key '{r.str_(ke, 'id')}' names {len(unknown)} landmark(s) the mosaic "
                    f"does not have: {shown}",
                    "landmarks",
                )
        image = None
        if ke.get("image") is not None:
            image, image_problems = load_reference(
                r, "image", path, root_dir, _regular, "route", ke, "key-image"
            )
            sink.extend(image_problems)
        keys.append(KeyImage(r.str_(ke, "id"), r.pose(ke), landmarks, image, r.where(ke)))
    _check_rules(r, key_el, keys, speed, threshold)
    if loaded is None or sink:
        return None
    return TaughtRoute(
        id=r.str_(root, "id"),
        mosaic=loaded[0],
        ceiling_height=height,
        speed=speed,
        settling_distance=r.num(root, "settling-distance", DEFAULT_SETTLING_DISTANCE),
        max_heading_change=threshold,
        keys=tuple(keys),
        source=sink.file,
        where=r.where(root),
    )


def _check_rules(
    r: ElementReader,
    key_el: list[etree._Element],
    keys: list[KeyImage],
    speed: float,
    threshold: float,
) -> None:
    """§2.3's rules between successive key images, and the direction of travel."""
    for (_, a), (el, b) in itertools.pairwise(zip(key_el, keys, strict=True)):
        pair = f"keys '{a.id}' and '{b.id}'"
        if not a.landmarks & b.landmarks:
            r.problem(
                el,
                "route-rule-1",
                f"{pair} share no landmark (seed 002 §2.3, rule 1): the robot could not "
                "servo from one to the next",
                "landmarks",
            )
        turn = abs(wrap_angle(b.pose_m.theta - a.pose_m.theta))
        if turn >= threshold:
            r.problem(
                el,
                "route-rule-2",
                f"{pair} differ by {math.degrees(turn):.1f} deg of heading, not below "
                f"max-heading-change-deg {math.degrees(threshold):g} (seed 002 §2.3, rule 2)",
                "heading-deg",
            )
        gap = math.hypot(b.pose_m.x - a.pose_m.x, b.pose_m.y - a.pose_m.y)
        if gap < MIN_KEY_SPACING:
            r.problem(el, "route-spacing", f"{pair} are at the same place", "x")
            continue
        rel = b.pose_m.inverse() @ a.pose_m  # key a in key b's line frame
        if speed != 0.0 and math.copysign(1.0, speed) * rel.x >= 0.0:
            way = "forwards" if speed > 0.0 else "backwards"
            r.problem(
                el,
                "route-direction",
                f"key '{b.id}' is not ahead of key '{a.id}' driving {way} (speed "
                f"{speed:g} m/s): the line through it would be approached from beyond",
                "heading-deg",
            )


def route_xml(route: TaughtRoute, mosaic: str, images: dict[str, str] | None = None) -> str:
    """A route file's text for ``route``; ``mosaic`` and ``images`` (by key id) are the
    paths as the file will name them (relative to it)."""
    images = images or {}
    lines = [
        '<?xml version="1.0" encoding="UTF-8"?>',
        f'<route xmlns="{ROUTE_NS}" id={quoteattr(route.id)} mosaic={quoteattr(mosaic)}',
        f'       ceiling-height="{route.ceiling_height:.4f}" speed="{route.speed:g}"',
        f'       settling-distance="{route.settling_distance:g}"'
        f' max-heading-change-deg="{math.degrees(route.max_heading_change):.6g}">',
    ]
    for key in route.keys:
        p: Pose2 = key.pose_m
        image = f" image={quoteattr(images[key.id])}" if key.id in images else ""
        ids = " ".join(sorted(key.landmarks))
        lines.append(
            f'  <key id={quoteattr(key.id)} x="{p.x:.5f}" y="{p.y:.5f}" '
            f'heading-deg="{math.degrees(p.theta):.5f}" landmarks={quoteattr(ids)}{image}/>'
        )
    lines.append("</route>")
    return "\n".join(lines) + "\n"
