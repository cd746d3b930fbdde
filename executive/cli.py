"""The ``walkaround`` command line.

Exit codes follow one rule for every subcommand: 0 success, 1 the mission ran and
failed, 2 bad input (invalid files, bad arguments).
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
from collections.abc import Sequence
from pathlib import Path

from executive import __version__
from executive.core.loader import check_file, load_aircraft, load_mission, root_name
from executive.core.problems import InvalidInputError, Problem
from executive.core.resources import missions_dir, shipped_mission_files
from sim2d.scenario import check_scenario, load_scenario

EXIT_OK = 0
EXIT_FAILED = 1
EXIT_BAD_INPUT = 2


def _source_line(problem: Problem) -> str | None:
    """The offending line with a caret under the column, when it is printable text."""
    if problem.where.line <= 0:
        return None
    try:
        with open(problem.where.file, "rb") as handle:
            raw = next(itertools.islice(handle, problem.where.line - 1, None), None)
        if raw is None:
            return None
        text = raw.decode("utf-8").rstrip("\r\n").expandtabs(1)
    except (OSError, UnicodeDecodeError):
        return None
    if not text.isprintable() or len(text) > 200:
        return None
    caret = ""
    if 0 < problem.where.column <= len(text) + 1:
        caret = "\n      " + " " * (problem.where.column - 1) + "^"
    return f"    | {text}{caret.replace(chr(10) + '      ', chr(10) + '    | ', 1)}"


def check_any(path: Path, library: Path | None = None) -> list[Problem]:
    """Every problem of an aircraft, mission or scenario file; never raises."""
    if root_name(path) == "scenario":
        return check_scenario(path, library)
    return check_file(path, library)


def _describe(path: Path) -> str:
    kind = root_name(path)
    if kind == "scenario":
        scenario = load_scenario(path)
        return (
            f"scenario '{scenario.id}' for mission '{scenario.mission.id}': "
            f"{len(scenario.obstacles)} obstacles, {len(scenario.faults)} faults, "
            f"seed {scenario.seed}"
        )
    if kind == "mission":
        mission = load_mission(path)
        return (
            f"mission '{mission.id}' for {mission.aircraft.type}: "
            f"{len(mission.checkpoints)} checkpoints, "
            f"{sum(len(c.items) for c in mission.checkpoints)} item inspections, "
            f"{len(mission.airport.zones)} forbidden zones"
        )
    aircraft = load_aircraft(path)
    return (
        f"aircraft {aircraft.type}: {len(aircraft.features)} features, "
        f"{len(aircraft.items)} items, {len(aircraft.footprint)} footprint shapes"
    )


def cmd_validate(args: argparse.Namespace) -> int:
    files: list[Path] = [Path(f) for f in args.files]
    if not files:
        files = shipped_mission_files()
        if not args.json:
            print(f"validating the shipped mission library in {missions_dir()}")
    results = []
    for path in files:
        problems = check_any(path, args.library)
        summary = _describe(path) if not problems else None
        results.append((path, problems, summary))

    all_valid = all(not problems for _, problems, _ in results)
    if args.json:
        report = {
            "valid": all_valid,
            "files": [
                {
                    "file": str(path),
                    "valid": not problems,
                    "summary": summary,
                    "problems": [p.as_dict() for p in problems],
                }
                for path, problems, summary in results
            ],
        }
        json.dump(report, sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        total = 0
        for path, problems, summary in results:
            if not problems:
                print(f"ok    {path}: {summary}")
                continue
            print(f"FAIL  {path}: {len(problems)} problem(s)")
            for problem in problems:
                total += 1
                print(f"  {problem.where}: error: {problem.message} [{problem.code}]")
                snippet = _source_line(problem)
                if snippet:
                    print(snippet)
        n_bad = sum(1 for _, p, _ in results if p)
        print(
            f"{len(results) - n_bad} valid, {n_bad} invalid"
            + (f" ({total} problems)" if total else "")
        )
    return EXIT_OK if all_valid else EXIT_BAD_INPUT


def cmd_sim_view(args: argparse.Namespace) -> int:
    from sim2d.robot import SimRobot
    from sim2d.view import render_world

    scenario = load_scenario(args.scenario)
    robot = SimRobot(scenario)
    if args.at > 0:
        robot.advance(args.at)
    out = render_world(robot, args.out)
    print(f"wrote {out}")
    return EXIT_OK


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="walkaround",
        description="Mission executive for aircraft pre-flight inspection robots.",
    )
    parser.add_argument("--version", action="version", version=f"walkaround {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    validate = sub.add_parser(
        "validate",
        help="check aircraft, mission and scenario files; exit 0 if all are valid, 2 otherwise",
        description="Check aircraft, mission and scenario XML files: well-formedness, schema and "
        "semantics (references, radii, clearances, camera visibility). Every problem is "
        "reported with file:line:column. Without FILE, checks the shipped mission library.",
    )
    validate.add_argument(
        "files", nargs="*", metavar="FILE", help="aircraft, mission or scenario XML"
    )
    validate.add_argument("--json", action="store_true", help="machine-readable report on stdout")
    validate.add_argument(
        "--library",
        type=Path,
        default=None,
        help="mission library root that aircraft paths may not leave "
        "(default: the mission file's grandparent directory)",
    )
    validate.set_defaults(handler=cmd_validate)

    view = sub.add_parser(
        "sim-view",
        help="draw a scenario's world (aircraft, zones, obstacles, robot, a scan, cameras)",
        description="Top view of a sim2d scenario at its start (or after --at seconds with "
        "the robot standing still): the aircraft at its true parking pose, forbidden zones, "
        "the route and checkpoints, obstacles and their paths, the robot, one scan of each "
        "laser and the cameras' fields of view.",
    )
    view.add_argument("scenario", type=Path, metavar="SCENARIO", help="scenario XML")
    view.add_argument("--out", type=Path, default=Path("world.png"), help="image (.png/.svg)")
    view.add_argument("--at", type=float, default=0.0, help="simulated seconds to wait first")
    view.set_defaults(handler=cmd_sim_view)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``walkaround`` console script."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.handler(args))
    except InvalidInputError as exc:  # a subcommand loading input it did not pre-check
        print(exc.summary(), file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
