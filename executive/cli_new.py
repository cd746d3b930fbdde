"""``walkaround new TYPE``: the folder of a new aircraft type, from a template (issue 18).

The files and their placeholders are :mod:`executive.scaffold`'s; this module is the
command line around it. Exit codes as everywhere: 0 written, 2 bad input (a bad type
name, an unknown template, a folder that exists: nothing is ever overwritten).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

EXIT_OK, EXIT_BAD_INPUT = 0, 2


def cmd_new(args: argparse.Namespace) -> int:
    from executive.scaffold import ScaffoldError, default_folder, relative, scaffold

    folder: Path = args.dir if args.dir is not None else default_folder(args.type, Path.cwd())
    try:
        written = scaffold(args.type, args.template, folder)
    except ScaffoldError as exc:
        print(f"walkaround new: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    where = relative(folder)
    print(f"wrote {where}/ from the {args.template} template:")
    for path in written:
        print(f"  {relative(path)}")
    mission = relative(folder / "preflight.xml")
    print(
        f"every figure is still the template's: replace the TODO sections of "
        f"{relative(folder / 'aircraft.xml')} and {mission} ({where}/README.md), then\n"
        f"  walkaround validate {where}/*.xml {where}/scenarios/*.xml\n"
        f"  walkaround dry-run {mission}"
    )
    return EXIT_OK


def add_new_command(sub: argparse._SubParsersAction) -> None:
    """The ``new`` subcommand of the ``walkaround`` parser."""
    from executive.scaffold import DEFAULT_TEMPLATE, TEMPLATES

    new = sub.add_parser(
        "new",
        help="start the mission library folder of a new aircraft type from a template",
        description="Write the folder of a new aircraft type: aircraft.xml (the template's "
        "footprint, features and items, marked TODO, to replace with the new type's), "
        "preflight.xml (the template's mission), scenarios/clear-apron.xml (the scenario "
        "'walkaround dry-run preflight.xml' runs by default) and README.md (the next "
        "steps). Everything written validates and dry-runs as it is. Never overwrites: "
        "exit 2 if the folder exists. docs/new-aircraft-type.md walks through it.",
    )
    new.add_argument(
        "type",
        metavar="TYPE",
        help="the type's designation, e.g. A330-300: the aircraft file's type, the mission's "
        "aircraft-type and the folder's name (a letter, then letters, digits, '-', '_', '.')",
    )
    new.add_argument(
        "--from",
        dest="template",
        choices=tuple(TEMPLATES),
        default=DEFAULT_TEMPLATE,
        help="the shipped type to start from: an airliner (a320, b737-800: 23 and 22 "
        "checkpoints) or the lab mock-up (lab: 3 checkpoints, a dry-run of about 90 "
        "simulated s) (default: %(default)s)",
    )
    new.add_argument(
        "--dir",
        type=Path,
        default=None,
        metavar="DIR",
        help="the folder to create (default: TYPE in the mission library of the current "
        "folder, e.g. ./missions/TYPE in a checkout, else ./TYPE); must not exist",
    )
    new.set_defaults(handler=cmd_new)
