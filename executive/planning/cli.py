"""``walkaround plan AIRCRAFT.xml --out MISSION.xml``: draft a mission (issue 18).

Exit codes as everywhere: 0 the draft is written, validates and covers every item; 1 the
draft is written and validates but some items could not be covered (each is listed with
the reason), or nothing could be covered (no file is written); 2 bad input (an invalid
aircraft or template file, a malformed option, a station the robot cannot stand at).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

from executive.core import checks
from executive.core.frames import Pose2
from executive.core.loader import load_aircraft, load_mission, root_name
from executive.core.model import Frame, Mission
from executive.core.problems import InvalidInputError
from executive.core.resources import missions_dir

EXIT_OK, EXIT_INCOMPLETE, EXIT_BAD_INPUT = 0, 1, 2


def _bad(message: str) -> int:
    print(f"walkaround plan: {message}", file=sys.stderr)
    return EXIT_BAD_INPUT


def parse_pose(text: str, need_heading: bool) -> Pose2 | None:
    """``X,Y`` or ``X,Y,HEADING_DEG`` (heading required when ``need_heading``); None if bad."""
    parts = text.split(",")
    if len(parts) not in ((3,) if need_heading else (2, 3)):
        return None
    try:
        values = [float(p) for p in parts]
    except ValueError:
        return None
    if not all(math.isfinite(v) for v in values):
        return None
    heading = math.radians(values[2]) if len(values) == 3 else 0.0
    return Pose2(values[0], values[1], heading)


def default_template(aircraft_path: Path) -> Path:
    """A mission of the aircraft's own folder that flies it (the first by name), else the
    shipped A320 pre-flight: the draft then uses the same robot."""
    folder = aircraft_path.resolve().parent
    for candidate in sorted(folder.glob("*.xml")):
        if candidate.resolve() == aircraft_path.resolve() or root_name(candidate) != "mission":
            continue
        return candidate
    return missions_dir() / "a320" / "preflight.xml"


def add_plan_command(sub: argparse._SubParsersAction) -> None:
    """The ``plan`` subcommand of the ``walkaround`` parser."""
    plan = sub.add_parser(
        "plan",
        help="draft a mission from an aircraft file: checkpoints, tour, approach and return",
        description="Draft a mission for an aircraft file (issue 18): candidate robot poses "
        "from which the inspection camera sees each item's feature (in range, facing it, "
        "within the pan-tilt limits, not hidden by the footprint), clear of the footprint "
        "and the forbidden zones; a small set of checkpoints seeing every item (weighted set "
        "cover); a short tour through them round the footprint and the zones (nearest "
        "neighbour + 2-opt on shortest clear paths, via points where a straight leg would "
        "not keep its clearance), in the direction that follows the aircraft file's item "
        "order; the handover point and the return; on each checkpoint, where one exists, the "
        "servo camera and target visual servoing reaches it on (a feature a stereo or mono "
        "unit sees with enough points from it), and the template's dwell. The robot, safety "
        "radii, navigation and forbidden zones come from a template mission (--like). The "
        "draft is validated "
        "before the command ends; comments in it say why each checkpoint is where it is. "
        "Exit 0 when every item is covered, 1 when some are not (listed with the reason), "
        "2 on bad input.",
    )
    plan.add_argument("aircraft", type=Path, metavar="AIRCRAFT.xml", help="aircraft file")
    plan.add_argument("--out", type=Path, required=True, help="the draft mission file to write")
    plan.add_argument(
        "--like",
        type=Path,
        default=None,
        metavar="MISSION.xml",
        help="template mission for the robot, safety, navigation, zones, station and parking "
        "(default: a mission in the aircraft file's folder, else the shipped A320 pre-flight)",
    )
    plan.add_argument(
        "--station",
        default=None,
        metavar="X,Y[,HEADING]",
        help="charging station in the airport frame (m, heading in deg; default: the template's)",
    )
    plan.add_argument(
        "--parking",
        default=None,
        metavar="X,Y,HEADING",
        help="nominal parking pose of the nose tip in the airport frame (m, deg; default: "
        "the template's)",
    )
    plan.add_argument("--id", default=None, help="mission id (default: <type>-draft)")
    plan.add_argument(
        "--dwell",
        type=float,
        default=None,
        metavar="S",
        help="seconds to stand still at each checkpoint after its items, 0 to 600 (default: "
        "the template's longest dwell at the checkpoint's items, else its median dwell)",
    )
    plan.set_defaults(handler=cmd_plan)


def _station_problems(base: Mission) -> list[str]:
    st = base.airport.station
    placement = base.nominal_placement()
    return list(
        checks.clearance_problems(
            base, placement, "the charging station", st.x, st.y, Frame.AIRPORT
        )
    )


def cmd_plan(args: argparse.Namespace) -> int:
    from executive.planning.plan import PlanningError, draft_base, plan_mission
    from executive.planning.write import write_mission

    station = parking = None
    if args.station is not None:
        station = parse_pose(args.station, need_heading=False)
        if station is None:
            return _bad(f"--station wants X,Y or X,Y,HEADING_DEG in metres, got '{args.station}'")
    if args.parking is not None:
        parking = parse_pose(args.parking, need_heading=True)
        if parking is None:
            return _bad(f"--parking wants X,Y,HEADING_DEG in metres, got '{args.parking}'")
    if args.dwell is not None and not (math.isfinite(args.dwell) and 0.0 <= args.dwell <= 600.0):
        return _bad(f"--dwell wants seconds in 0..600, got {args.dwell:g}")
    if not args.out.parent.resolve().is_dir():
        return _bad(f"--out: folder {args.out.parent} does not exist")
    template_path = args.like or default_template(args.aircraft)
    try:
        aircraft = load_aircraft(args.aircraft)
        template = load_mission(template_path)
    except InvalidInputError as exc:
        print(exc.summary(), file=sys.stderr)
        return EXIT_BAD_INPUT
    base = draft_base(template, aircraft, station, parking, args.id)
    problems = _station_problems(base)
    if problems:
        return _bad("; ".join(problems))

    t0 = time.perf_counter()
    try:
        plan = plan_mission(template, aircraft, station, parking, args.id, args.dwell)
    except PlanningError as exc:
        print(f"walkaround plan: internal error, no draft written: {exc}", file=sys.stderr)
        return EXIT_INCOMPLETE
    elapsed = time.perf_counter() - t0
    for item, reason in plan.uncovered.items():
        print(f"walkaround plan: item '{item}' is not coverable: {reason}", file=sys.stderr)
    if not plan.checkpoints:
        print("walkaround plan: no item can be covered; no draft written", file=sys.stderr)
        return EXIT_INCOMPLETE

    write_mission(plan, template_path, args.aircraft, args.out)
    root = Path(os.path.commonpath([args.out.resolve().parent, args.aircraft.resolve().parent]))
    try:
        draft = load_mission(args.out, root)
    except InvalidInputError as exc:
        print(exc.summary(), file=sys.stderr)
        print(f"walkaround plan: the draft {args.out} does not validate", file=sys.stderr)
        return EXIT_INCOMPLETE
    n_items = len(aircraft.items)
    print(
        f"{args.out}: {len(draft.checkpoints)} checkpoints inspecting "
        f"{len(plan.covered)} of {n_items} items, inspection tour {plan.tour_length:.1f} m, "
        f"{plan.candidates} candidate poses, planned in {elapsed:.2f} s (robot and zones "
        f"from {template_path})"
    )
    return EXIT_INCOMPLETE if plan.uncovered else EXIT_OK
