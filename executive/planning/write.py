"""Write a :class:`~executive.planning.plan.Plan` as a mission file (schemas/mission.xsd).

The robot (``<platform>``, ``<safety>``, ``<navigation>``) and the apron's forbidden zones
are copied verbatim from the template mission, so that the draft uses the same robot and
keeps its comments' sources; the station and parking pose, the approach, the checkpoints
and the return are the planner's, each with a comment saying why it is where it is.
Checkpoint poses and via points are in the aircraft frame F, the rest in the airport frame
A, as in the hand-written missions.
"""

from __future__ import annotations

import math
import os
import re
from pathlib import Path
from xml.sax.saxutils import escape, quoteattr

from lxml import etree

from executive.core.frames import Pose2
from executive.core.loader import MISSION_NS
from executive.core.problems import InvalidInputError, ProblemSink
from executive.core.xmlsafe import parse_xml
from executive.planning.plan import Plan

_NS_DECL = re.compile(r'\s+xmlns(:\w+)?="[^"]*"')


def _num(value: float) -> str:
    text = f"{value:.3f}".rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text


def _deg(angle: float) -> str:
    return _num(round(math.degrees(angle), 1))


def _comment(text: str, indent: str) -> str:
    """An XML comment (no '--' inside), wrapped at about 90 columns."""
    text = text.replace("--", "- -")
    words, lines, line = text.split(), [], ""
    for w in words:
        if line and len(indent) + len(line) + len(w) > 86:
            lines.append(line)
            line = w
        else:
            line = f"{line} {w}".strip()
    lines.append(line)
    body = f"\n{indent}     ".join(lines)
    return f"{indent}<!-- {body} -->\n"


def template_elements(template_path: Path) -> dict[str, str]:
    """The template's platform, safety and navigation elements and its zones, as text."""
    sink = ProblemSink(template_path)
    doc = parse_xml(template_path, sink)
    if doc is None:
        raise InvalidInputError(sink.problems)
    out: dict[str, str] = {"zones": ""}
    for child in doc.root:
        if not isinstance(child.tag, str):
            continue
        name = etree.QName(child).localname
        if name in ("platform", "safety", "navigation"):
            out[name] = _element_text(child)
        if name == "airport":
            zones = [
                _element_text(z)
                for z in child
                if isinstance(z.tag, str) and etree.QName(z).localname == "zone"
            ]
            out["zones"] = "".join(f"    {z}\n" for z in zones)
    return out


def _element_text(element: etree._Element) -> str:
    copy = etree.fromstring(etree.tostring(element))
    copy.tail = None
    return _NS_DECL.sub("", etree.tostring(copy, encoding="unicode"), count=1)


def _pose_attrs(pose: Pose2) -> str:
    return f'x="{_num(pose.x)}" y="{_num(pose.y)}" heading-deg="{_deg(pose.theta)}"'


def mission_xml(plan: Plan, template_path: Path, aircraft_ref: str) -> str:
    """The draft mission file's text."""
    m = plan.mission
    parts = template_elements(template_path)
    cps = plan.checkpoints
    n_items = len(m.aircraft.items)
    head = [
        '<?xml version="1.0" encoding="UTF-8"?>\n',
        "<!--\n",
        f"  DRAFT written by `walkaround plan` (issue 18) for the {m.aircraft.type}: "
        f"{len(cps)} checkpoints\n",
        f"  inspecting {len(plan.covered)} of {n_items} items; inspection tour "
        f"{plan.tour_length:.1f} m (P round the checkpoints back to P).\n",
        f"  Robot, safety radii, navigation and forbidden zones are copied from "
        f"{template_path.name}.\n",
        "  Checkpoint poses and via points are in the aircraft frame F (x to the tail, +y "
        "port,\n  heading 0 faces the tail); station, parking, handover and waypoints in "
        "the airport frame A.\n",
        "  Review before use: the planner knows the footprint, the zones and the features,"
        " not the apron.\n",
        "-->\n",
    ]
    body = [
        f'<mission xmlns="{MISSION_NS}" id={quoteattr(m.id)} aircraft={quoteattr(aircraft_ref)}'
        f"\n         aircraft-type={quoteattr(m.aircraft.type)}>\n",
        f"  <description>{escape(_description(plan))}</description>\n\n",
        f"  {parts['platform']}\n\n  {parts['safety']}\n\n  {parts['navigation']}\n\n",
        "  <airport>\n",
        f"    <station {_pose_attrs(m.airport.station)}/>\n",
        f"    <parking {_pose_attrs(m.airport.parking)}/>\n",
        parts["zones"],
        "  </airport>\n\n",
    ]
    if plan.uncovered:
        lines = [f"{item}: {reason}" for item, reason in plan.uncovered.items()]
        body.append(_comment("NOT COVERED: " + " | ".join(lines), "  "))
    body.append("  <approach>\n")
    for wp in m.approach:
        body.append(f'    <waypoint id="{wp.id}" x="{_num(wp.x)}" y="{_num(wp.y)}"/>\n')
    body.append(_comment(f"P: {plan.handover_why}", "    "))
    h = m.handover
    body.append(
        f'    <handover x="{_num(h.x)}" y="{_num(h.y)}" heading-deg="{_deg(h.heading or 0.0)}"/>\n'
    )
    body.append("  </approach>\n\n  <inspection>\n")
    for planned in cps:
        cp = planned.checkpoint
        body.append(_comment(f"{cp.id}: " + "; ".join(planned.why), "    "))
        attrs = f'id="{cp.id}" name={quoteattr(cp.name)} {_pose_attrs(cp.pose)}'
        if cp.camera:
            attrs += f' camera="{cp.camera}"'
        if cp.target:
            attrs += f' target="{cp.target}"'
        if cp.servo is not None:
            attrs += f' servo="{cp.servo.value}"'
        if cp.dwell > 0:
            attrs += f' dwell="{_num(cp.dwell)}"'
        body.append(f"    <checkpoint {attrs}>\n")
        for x, y in cp.via:
            body.append(f'      <via x="{_num(x)}" y="{_num(y)}"/>\n')
        for item in cp.items:
            body.append(f'      <inspect item="{item}"/>\n')
        body.append("    </checkpoint>\n")
    body.append("  </inspection>\n\n  <return>\n")
    for wp, why in zip(m.return_route, plan.return_why, strict=True):
        body.append(_comment(why, "    "))
        body.append(
            f'    <waypoint id="{wp.id}" x="{_num(wp.x)}" y="{_num(wp.y)}" '
            f'frame="{wp.frame.value}"/>\n'
        )
    body.append("  </return>\n</mission>\n")
    return "".join(head + body)


def _description(plan: Plan) -> str:
    m = plan.mission
    text = (
        f"Draft pre-flight walk-around of the {m.aircraft.type} by walkaround plan: "
        f"{len(plan.checkpoints)} checkpoints chosen by weighted set cover over "
        f"{plan.candidates} candidate poses, toured by nearest neighbour and 2-opt round the "
        "footprint and the forbidden zones; "
        f"{sum(1 for c in plan.checkpoints if c.checkpoint.target)} reached by visual "
        "servoing on a target a servo camera sees from them."
    )
    if plan.uncovered:
        text += f" {len(plan.uncovered)} item(s) could not be covered (see the comment)."
    return text


def aircraft_reference(out: Path, aircraft_path: Path) -> str:
    """The aircraft path as the draft refers to it: relative to the draft's folder."""
    rel = os.path.relpath(aircraft_path.resolve(), out.resolve().parent)
    return Path(rel).as_posix()


def write_mission(plan: Plan, template_path: Path, aircraft_path: Path, out: Path) -> None:
    """Write the draft to ``out`` (its folder must exist)."""
    text = mission_xml(plan, template_path, aircraft_reference(out, aircraft_path))
    out.write_text(text, encoding="utf-8")
