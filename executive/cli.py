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
from executive.core.loader import check_file, detect_kind, load_aircraft, load_mission
from executive.core.problems import InvalidInputError, Problem
from executive.core.resources import missions_dir, shipped_mission_files

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


def _describe(path: Path, kind: str | None) -> str:
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
        problems = check_file(path, args.library)
        kind = detect_kind(path) if not problems else None
        summary = _describe(path, kind) if not problems else None
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


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="walkaround",
        description="Mission executive for aircraft pre-flight inspection robots.",
    )
    parser.add_argument("--version", action="version", version=f"walkaround {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    validate = sub.add_parser(
        "validate",
        help="check aircraft and mission files; exit 0 if all are valid, 2 otherwise",
        description="Check aircraft and mission XML files: well-formedness, schema and "
        "semantics (references, radii, clearances, camera visibility). Every problem is "
        "reported with file:line:column. Without FILE, checks the shipped mission library.",
    )
    validate.add_argument("files", nargs="*", metavar="FILE", help="aircraft or mission XML")
    validate.add_argument("--json", action="store_true", help="machine-readable report on stdout")
    validate.add_argument(
        "--library",
        type=Path,
        default=None,
        help="mission library root that aircraft paths may not leave "
        "(default: the mission file's grandparent directory)",
    )
    validate.set_defaults(handler=cmd_validate)
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
