"""The ``walkaround`` command line.

Exit codes follow one rule for every subcommand: 0 success, 1 the mission ran and
failed, 2 bad input (invalid files, bad arguments).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from executive import __version__
from executive.core.loader import check_file, load_aircraft, load_mission, root_name
from executive.core.problems import (
    InvalidInputError,
    Problem,
    SourceLocation,
    internal_error,
    source_line,
)
from executive.core.resources import missions_dir, shipped_mission_files
from executive.robotlink.config import check_robot, load_robot
from executive.robotlink.config import describe as describe_robot
from sim2d.scenario import check_scenario, load_scenario

if TYPE_CHECKING:
    from executive.dryrun import DryRun
    from executive.journal import JournalState
    from executive.runtime import StopRequest
    from sim2d.scenario import Scenario

EXIT_OK = 0
EXIT_FAILED = 1
EXIT_BAD_INPUT = 2


def check_any(path: Path, library: Path | None = None) -> list[Problem]:
    """Every problem of an aircraft, mission, scenario or robot file; never raises.

    An unexpected exception of a checker becomes an ``internal-error`` problem of this
    file, so a batch goes on with the next file.
    """
    try:
        kind = root_name(path)
        if kind == "scenario":
            return check_scenario(path, library)
        if kind == "campaign":
            from executive.campaign.spec import check_campaign

            return check_campaign(path, library)
        if kind == "robot":
            return check_robot(path)
        if kind == "route":
            from executive.core.taught_route import check_route

            return check_route(path, library)
        return check_file(path, library)
    except Exception as exc:  # reported as a problem of this file
        return [internal_error(path, exc)]


def _describe(path: Path) -> str:
    kind = root_name(path)
    if kind == "robot":
        return describe_robot(load_robot(path))
    if kind == "campaign":
        from executive.campaign.spec import load_campaign

        campaign = load_campaign(path)
        return (
            f"campaign '{campaign.id}': {len(campaign.scenarios)} base scenario(s), "
            f"{campaign.episodes} episodes, seed {campaign.seed}"
        )
    if kind == "route":
        from executive.core.taught_route import load_route

        route = load_route(path)
        return (
            f"taught route '{route.id}': {len(route.keys)} key images, "
            f"{route.length:.1f} m at {route.speed:g} m/s"
        )
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
    library = None
    if not files:
        files, library = _library_to_validate()
        if not args.json:
            print(library["said"])
    results = []
    for path in files:
        problems = check_any(path, args.library)
        summary = None
        if not problems:
            try:
                summary = _describe(path)
            except InvalidInputError as exc:  # changed between the check and the summary
                problems = list(exc.problems)
            except Exception as exc:  # one file never hides the others
                problems = [internal_error(path, exc)]
        results.append((path, problems, summary))

    all_valid = all(not problems for _, problems, _ in results)
    if args.json:
        report = {
            "valid": all_valid,
            **({"library": library} if library is not None else {}),  # no FILE: which one
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
                snippet = source_line(problem)
                if snippet:
                    print(snippet)
        n_bad = sum(1 for _, p, _ in results if p)
        print(
            f"{len(results) - n_bad} valid, {n_bad} invalid"
            + (f" ({total} problems)" if total else "")
        )
    return EXIT_OK if all_valid else EXIT_BAD_INPUT


def _library_to_validate() -> tuple[list[Path], dict[str, str]]:
    """``validate`` without FILE: the current folder's mission library, else the shipped one.

    The rule is :func:`executive.scaffold.find_library`'s; the dict says which one it is
    (``path``, ``source``: current-folder or installed, ``said``: the line printed).
    """
    from executive.scaffold import find_library, library_xml_files

    found = find_library(Path.cwd())
    if found is not None:
        files = library_xml_files(found)
        said = f"validating the mission library of the current folder, {found}"
        return files, {"path": str(found), "source": "current-folder", "said": said}
    said = (
        f"validating the shipped mission library in {missions_dir()} (the current folder "
        "is in no mission library: no */aircraft.xml here nor in a missions/ folder above)"
    )
    installed = {"path": str(missions_dir()), "source": "installed", "said": said}
    return shipped_mission_files(), installed


def _bad_argument(message: str) -> int:
    """One line on stderr, the bad-input exit status; nothing was done."""
    print(f"walkaround: {message}", file=sys.stderr)
    return EXIT_BAD_INPUT


def _output_file_problem(out: Path, suffixes: tuple[str, ...]) -> str | None:
    """Why ``out`` cannot take an output file of one of ``suffixes`` (None: it can)."""
    from executive.core.files import output_dir_problem

    if out.is_dir():
        return f"--out {out}: is a directory; name the file to write"
    if suffixes and out.suffix.lower() not in suffixes:
        return f"--out {out}: the file must end in {' or '.join(suffixes)}"
    problem = output_dir_problem(out.parent if str(out.parent) else Path("."))
    return f"--out {out}: {problem}" if problem else None


def cmd_sim_view(args: argparse.Namespace) -> int:
    import math

    from executive.core.files import produce_atomic
    from sim2d.robot import SimRobot
    from sim2d.view import render_world

    at: float = args.at
    if not math.isfinite(at) or at < 0:
        return _bad_argument(f"--at {args.at}: a time in seconds, 0 or more")
    problem = _output_file_problem(args.out, (".png", ".svg"))
    if problem:
        return _bad_argument(problem)
    problems = check_any(args.scenario)
    if problems:
        return _report(problems)
    scenario = load_scenario(args.scenario)
    if at > scenario.duration:
        return _bad_argument(f"--at {at:g}: past the scenario's duration ({scenario.duration:g} s)")
    robot = SimRobot(scenario)
    if at > 0:
        robot.advance(at)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    produce_atomic(args.out, lambda tmp: render_world(robot, tmp))
    print(f"wrote {args.out}")
    return EXIT_OK


def _report(problems: list[Problem]) -> int:
    """Print problems on stderr, compiler-style; the bad-input exit code."""
    for problem in problems:
        print(f"{problem.where}: error: {problem.message} [{problem.code}]", file=sys.stderr)
    return EXIT_BAD_INPUT


def _check_mission_file(path: Path) -> list[Problem]:
    """Every problem of ``path`` as a mission file (a valid non-mission is one too)."""
    problems = check_any(path)
    if not problems and root_name(path) != "mission":
        problems = [Problem(SourceLocation(str(path), 1, 1), "not-a-mission", "not a mission file")]
    return problems


def _default_scenario(mission: Path) -> Path:
    """The scenario dry-run stages ``mission`` in without --scenario: the mission's own,
    scenarios/<mission's stem>.xml beside it, when that file exists (missions/a320/
    hangar.xml runs in scenarios/hangar.xml), else the type's scenarios/clear-apron.xml."""
    folder = mission.resolve().parent / "scenarios"
    own = folder / f"{mission.stem}.xml"
    return own if own.is_file() else folder / "clear-apron.xml"


def _no_default_scenario(mission: Path) -> str:
    """Why a dry-run without --scenario has nothing to run, and the three ways out."""
    import shlex

    wanted = mission.parent / "scenarios" / "clear-apron.xml"
    return (
        f"{mission}: no scenario to run it in. Without --scenario, dry-run runs the "
        f"mission's own scenarios/{mission.stem}.xml or else the clear-apron scenario, "
        f"{wanted} (scenarios/clear-apron.xml beside the mission file), and there is "
        "neither. Either:\n"
        f"  - name a scenario: walkaround dry-run {shlex.quote(str(mission))} --scenario FILE\n"
        f"  - or create {wanted}: a scenario whose mission attribute is "
        f'"../{mission.name}" (copy a shipped type\'s scenarios/clear-apron.xml and change '
        "its mission and id; docs/scenario-format.md)\n"
        "  - or start a new aircraft type with `walkaround new TYPE`: it writes the "
        "aircraft file, a mission and this scenario together (docs/new-aircraft-type.md)"
    )


SEED_RANGE = (0, 2**32 - 1)
REPORT_FILES = ("metrics.json", "events.jsonl", "trajectory.png", "timeline.png", "avoidance.png")
"""What a dry-run writes in its folder besides the journal; removed before a new run."""
JOURNAL_FILE = "journal.jsonl"
DEFAULT_MISSED_DEADLINES = 0
"""A dry-run never stops on missed deadlines unless asked: same seed, same run, however
busy the machine (:func:`executive.dryrun.dry_run`); metrics.json counts them."""


def _resume_command(args: argparse.Namespace, scenario: Path) -> str:
    import shlex

    words = ["walkaround", "dry-run", str(args.mission), "--scenario", str(scenario)]
    words += ["--out", str(args.out), "--rate", f"{args.rate:g}"]
    if args.seed is not None:
        words += ["--seed", str(args.seed)]
    if not args.avoidance:
        words.append("--no-avoidance")
    if args.max_time is not None:
        words += ["--max-time", f"{args.max_time:g}"]
    if args.max_missed_deadlines != DEFAULT_MISSED_DEADLINES:
        words += ["--max-missed-deadlines", str(args.max_missed_deadlines)]
    if args.servo is not None:
        words.append("--servo" if args.servo else "--no-servo")
    if args.quiet:
        words.append("--quiet")
    if not args.record:
        words.append("--no-record")
    return shlex.join([*words, "--resume"])


def _check_dry_run_arguments(args: argparse.Namespace) -> str | None:
    """The first bad argument of a dry-run, before anything is read or written."""
    import math

    from executive.core.files import output_dir_problem

    if not (math.isfinite(args.rate) and 10.0 <= args.rate <= 50.0):
        return f"--rate {args.rate:g}: the executive runs at 10 to 50 Hz"
    if args.seed is not None and not SEED_RANGE[0] <= args.seed <= SEED_RANGE[1]:
        return f"--seed {args.seed}: a seed is an integer from {SEED_RANGE[0]} to {SEED_RANGE[1]}"
    if args.max_time is not None and not (math.isfinite(args.max_time) and args.max_time > 0):
        return f"--max-time {args.max_time}: simulated seconds, more than 0"
    if args.max_missed_deadlines < 0:
        return f"--max-missed-deadlines {args.max_missed_deadlines}: 0 (never) or more"
    if not (math.isfinite(args.pace) and 0.0 < args.pace <= 100.0):
        return f"--pace {args.pace:g}: simulated seconds per second, more than 0, at most 100"
    if args.live is not None:
        _, _, port = str(args.live).rpartition(":")
        if not (port.isdigit() and 0 <= int(port) <= 65535):
            return f"--live {args.live}: [HOST:]PORT with a port from 0 to 65535"
    problem = output_dir_problem(args.out)
    if problem:
        return f"--out {problem}"
    journal = args.out / JOURNAL_FILE
    if args.resume and (journal.is_symlink() or not journal.exists()):
        what = "is a symbolic link" if journal.is_symlink() else "does not exist"
        return f"--resume: the journal {journal} {what}; nothing to resume"
    return None


def cmd_dry_run(args: argparse.Namespace) -> int:
    from executive.compiler import CompileError
    from executive.journal import JournalWriteError
    from executive.runtime import StopRequest
    from executive.signals import stop_on_signals

    stop = StopRequest()
    try:
        with stop_on_signals(stop):
            return _dry_run(args, stop)
    except InvalidInputError as exc:
        return _report(list(exc.problems))
    except CompileError as exc:
        return _report(list(exc.problems))
    except JournalWriteError as exc:
        print(f"walkaround: {exc.strerror or exc}", file=sys.stderr)
        return EXIT_FAILED


def _dry_run(args: argparse.Namespace, stop: StopRequest) -> int:
    """The body of :func:`cmd_dry_run`, with the signal handlers in place."""
    import dataclasses

    from executive.core.files import UnusableFileError, describe_os_error, remove_if_present
    from executive.dryrun import dry_run
    from executive.journal import check_resumable, check_resume_pose, read_journal
    from executive.recording import RECORDING_FILE, recording_path, recordings_in
    from executive.report import write_report

    bad = _check_dry_run_arguments(args)
    if bad:
        return _bad_argument(bad)
    mission_path: Path = args.mission
    problems = _check_mission_file(mission_path)
    if problems:
        return _report(problems)
    scenario_path = args.scenario or _default_scenario(mission_path)
    if args.scenario is None and not (scenario_path.exists() or scenario_path.is_symlink()):
        return _bad_argument(_no_default_scenario(mission_path))
    problems = check_any(scenario_path)
    if problems:
        return _report(problems)
    scenario = load_scenario(scenario_path)
    mission = load_mission(mission_path)
    if not _same_file(scenario.mission.source, mission.source):
        print(
            f"{scenario_path}: this scenario stages mission '{scenario.mission.id}' "
            f"({scenario.mission.source}), not {mission_path}",
            file=sys.stderr,
        )
        return EXIT_BAD_INPUT
    if args.seed is not None:
        scenario = dataclasses.replace(scenario, seed=args.seed)
    out: Path = args.out
    journal = out / JOURNAL_FILE
    state = None
    if args.resume:
        state = read_journal(journal)  # InvalidInputError: exit 2 at the journal's line
        check_resumable(state, scenario.mission, journal)
        if state.ended == "completed":
            print(
                f"mission '{mission.id}' already completed at {state.end_t:.1f} s "
                f"(journal {journal}): nothing to resume, the robot is not moved"
            )
            return EXIT_OK
        check_resume_pose(state, mission, journal)
    # a resumed run adds run-2.mcap, ...; a new one replaces them all with run.mcap
    record = None
    if args.record:
        record = recording_path(out) if args.resume else out / RECORDING_FILE

    def clear_old_report() -> None:
        """Once the run can start (compiled, simulator built): before, nothing is lost."""
        if stop:
            raise _InterruptedBeforeStartError
        try:
            out.mkdir(parents=True, exist_ok=True)
            for name in REPORT_FILES if args.resume else (*REPORT_FILES, JOURNAL_FILE):
                remove_if_present(out / name)
            for old in () if args.resume else recordings_in(out):
                remove_if_present(old)
        except UnusableFileError as exc:
            raise _OutputError(str(exc)) from None
        except OSError as exc:
            raise _OutputError(f"--out {describe_os_error(exc, out, 'preparing')}") from None

    try:
        run = _run(dry_run, scenario, args, journal, state, stop, clear_old_report, record)
    except _InterruptedBeforeStartError:
        print(f"walkaround: {stop.reason} before the run started; nothing changed", file=sys.stderr)
        return 128 + (stop.signal or 0)
    except _OutputError as exc:
        return _bad_argument(str(exc))
    report_error = None
    try:
        write_report(run, out)
    except OSError as exc:
        report_error = describe_os_error(exc, getattr(exc, "filename", None) or out)
    for warning in run.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    if run.recording_error:
        print(f"warning: {run.recording_error}", file=sys.stderr)
    for event in run.result.events:
        if event.kind == "checkpoint-uncertain":
            print(f"warning: {event.detail['reason']}", file=sys.stderr)
    reached = sum(c.reached for c in run.checkpoints)
    worst = max((c.position_error or 0.0 for c in run.checkpoints), default=0.0)
    verdict = "succeeded" if run.succeeded else f"failed: {run.first_cause}"
    print(
        f"{verdict}; {reached}/{len(run.checkpoints)} checkpoints "
        f"(worst {worst * 100:.1f} cm), {len(run.robot.truth.collisions)} collisions, "
        f"{len(run.breaches)} geofence breaches; {run.robot.time:.0f} s simulated in "
        f"{run.wall_time:.1f} s; "
        + (f"report in {out}" if report_error is None else "no complete report")
    )
    stopped = (
        "the robot was sent a stop"
        if run.result.stop_sent
        else "the robot's stop was NOT confirmed: its link is lost"
    )
    for problem in (run.journal_error, report_error):
        if problem:
            print(f"walkaround: {problem}; {stopped}", file=sys.stderr)
    if run.result.outcome == "interrupted" or run.journal_error or report_error:
        print(
            f"walkaround: run ended ({run.result.reason}); {stopped}; journal {journal}"
            + (f"; partial report in {out}" if report_error is None else "")
            + f"; continue with: {_resume_command(args, scenario_path)}",
            file=sys.stderr,
        )
    if run.result.outcome == "interrupted" and stop.signal is not None:
        return 128 + stop.signal
    ok = run.succeeded and report_error is None and run.journal_error is None
    return EXIT_OK if ok else EXIT_FAILED


class _InterruptedBeforeStartError(Exception):
    """A signal came before the run started."""


class _OutputError(Exception):
    """The report folder could not be prepared."""


def _run(
    dry_run: Callable[..., DryRun],
    scenario: Scenario,
    args: argparse.Namespace,
    journal: Path,
    state: JournalState | None,
    stop: StopRequest,
    before_start: Callable[[], None],
    record: Path | None = None,
) -> DryRun:
    live: dict[str, object] = {}
    server = None
    if args.live is not None:
        server, live = _serve_live(scenario, args, journal.parent)
    try:
        return dry_run(
            scenario,
            rate_hz=args.rate,
            journal_path=journal,
            resume=state if state is not None else False,
            progress_out=sys.stderr if not args.quiet else None,
            avoidance=args.avoidance,
            stop=stop,
            max_missed_deadlines=args.max_missed_deadlines or None,
            max_time=args.max_time,
            before_start=before_start,
            servo=args.servo,
            record=record,
            **live,
        )
    finally:
        if server is not None:
            server.close()


FOXGLOVE_PORT = 8765
"""Foxglove's own default: where ``--live`` serves the recording to a Foxglove app."""


def _serve_live(
    scenario: Scenario, args: argparse.Namespace, out: Path
) -> tuple[object, dict[str, object]]:
    """The HUD of a live dry-run (issue 15): real time, an operator at hand."""
    from executive.hud.server import HudServer
    from executive.hud.telemetry import Telemetry
    from executive.operator import OperatorState

    host, _, port = str(args.live).rpartition(":")
    state = OperatorState()
    telemetry = Telemetry.of_operator(scenario.mission, state, args.rate)
    try:
        server = HudServer(
            state, out, status=dict, host=host or "127.0.0.1", port=int(port), telemetry=telemetry
        )
    except OSError as exc:
        raise _OutputError(f"--live {args.live}: cannot serve the HUD there ({exc})") from None
    print(f"operator HUD: {server.url}\n(the secret is also in {out / 'operator.secret'})")
    if sys.stdout.isatty():
        print(server.qr())
    options = {
        "operator": state,
        "observers": (telemetry.on_tick,),
        "pace": args.pace,
        "ask_operator": True,
        # a HUD on any free port (0, tests) puts Foxglove on any free port too
        "foxglove": (host or "127.0.0.1", FOXGLOVE_PORT if int(port) else 0)
        if args.record
        else None,
    }
    return server, options


def _same_file(a: str | Path, b: str | Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return Path(a).resolve() == Path(b).resolve()


def cmd_show(args: argparse.Namespace) -> int:
    from executive import export
    from executive.compiler import CompileError, compile_mission

    suffixes = {"png": (".png",), "svg": (".svg",), "html": (".html", ".htm")}.get(args.format, ())
    if args.out is not None:
        problem = _output_file_problem(args.out, suffixes)
        if problem:
            return _bad_argument(problem)
    problems = _check_mission_file(args.mission)
    if problems:
        return _report(problems)
    try:
        compiled = compile_mission(load_mission(args.mission))
    except CompileError as exc:
        return _report(list(exc.problems))
    root = compiled.root
    fmt = args.format
    # drawings: the overview (navigations and checkpoints folded) unless --full
    view = export.overview(root)
    folded = () if args.full else view.folded
    notes = {} if args.full else view.notes()
    if fmt in ("png", "svg", "html"):
        out = args.out or Path(f"{args.mission.stem}.{fmt}")
        if out.suffix.lower() not in suffixes:
            out = out.with_suffix(f".{fmt}")
        from executive.core.files import produce_atomic, write_atomic

        out.parent.mkdir(parents=True, exist_ok=True)
        if fmt == "html":
            from executive.treeview import to_html

            write_atomic(out, to_html(root, title=f"mission {compiled.mission.id}").encode())
        else:
            produce_atomic(out, lambda tmp: export.render(root, tmp, folded=folded, notes=notes))
        print(f"wrote {out}")
        return EXIT_OK
    if fmt == "ascii":
        text = export.to_ascii(root, unicode=args.unicode)
    elif fmt == "dot":
        text = export.to_dot(root, folded=folded, rankdir="LR")
    else:
        text = export.to_btcpp(root, keep_running_unselected=args.bt_runnable)
    if args.out is not None:
        from executive.core.files import write_atomic

        args.out.parent.mkdir(parents=True, exist_ok=True)
        write_atomic(args.out, (text + ("" if text.endswith("\n") else "\n")).encode())
        print(f"wrote {args.out}")
    else:
        sys.stdout.write(text + ("" if text.endswith("\n") else "\n"))
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
        "reported with file:line:column. Without FILE, checks the mission library of the current "
        "folder (the folder itself when it holds */aircraft.xml, its parent when it holds "
        "aircraft.xml, else the nearest missions/ folder holding */aircraft.xml, walking up), "
        "else the shipped one, and says which (also in --json: library).",
    )
    validate.add_argument(
        "files",
        nargs="*",
        metavar="FILE",
        help="aircraft, mission, scenario, robot or campaign XML (default: every XML file of "
        "the current folder's mission library, else of the shipped one)",
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
        "laser and the cameras' fields of view; a legend beside the plot names every kind "
        "of mark drawn, and the checkpoint labels are placed so that none overlaps another.",
    )
    view.add_argument("scenario", type=Path, metavar="SCENARIO", help="scenario XML")
    view.add_argument("--out", type=Path, default=Path("world.png"), help="image (.png/.svg)")
    view.add_argument(
        "--at",
        type=float,
        default=0.0,
        help="simulated seconds to wait first, 0 to the scenario's duration (default 0)",
    )
    view.set_defaults(handler=cmd_sim_view)

    dry = sub.add_parser(
        "dry-run",
        help="run a mission with the executive in the simulator and write a report",
        description="Compile the mission, run it at a fixed rate against sim2d (the "
        "mission's own scenarios/<stem>.xml, else its clear-apron scenario, unless "
        "--scenario is given) and write the report "
        "folder: trajectory.png, timeline.png, avoidance.png (when it avoided something), "
        "metrics.json, events.jsonl, journal.jsonl, "
        "run.mcap (a recording for Foxglove; docs/recording.md). "
        "Exit 0 when the mission succeeded (completed, no collision, no geofence breach, "
        "every checkpoint within tolerance, every item inspected with a fresh image), "
        "1 when it failed, 2 on bad input, 128+N when ended by signal N (SIGINT 130, "
        "SIGTERM 143, SIGHUP 129: the robot is sent a stop, a partial report is written).",
    )
    dry.add_argument("mission", type=Path, metavar="MISSION", help="mission XML")
    dry.add_argument(
        "--scenario",
        type=Path,
        default=None,
        help="scenario XML (default: scenarios/<MISSION's stem>.xml beside MISSION if it "
        "exists, else scenarios/clear-apron.xml)",
    )
    dry.add_argument("--out", type=Path, default=Path("dry-run"), help="report folder")
    dry.add_argument(
        "--rate", type=float, default=50.0, help="executive rate, Hz, 10 to 50 (default 50)"
    )
    dry.add_argument(
        "--seed",
        type=int,
        default=None,
        help=f"override the scenario's seed, {SEED_RANGE[0]} to {SEED_RANGE[1]} "
        "(default: the scenario's)",
    )
    dry.add_argument(
        "--resume",
        action="store_true",
        help="continue after the last checkpoint completed in OUT/journal.jsonl",
    )
    dry.add_argument("--quiet", action="store_true", help="no live progress line")
    dry.add_argument(
        "--no-record",
        dest="record",
        action="store_false",
        help="do not record the run for Foxglove (default: OUT/run.mcap)",
    )
    dry.add_argument(
        "--servo",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="visual servoing at the checkpoints that name a servo target (default: on for "
        "the aircraft types whose end-to-end runs meet 2 cm and 0.5 deg, the A320-200 and "
        "B737-800; --servo forces it on, --no-servo off)",
    )
    dry.add_argument(
        "--live",
        metavar="[HOST:]PORT",
        nargs="?",
        const="127.0.0.1:8080",
        default=None,
        help="serve the operator's HUD (default: off; given alone, 127.0.0.1:8080; a port "
        "from 0 to 65535) and run at real time: "
        "watch and drive the run from a browser (docs/hud.md); the recording is also "
        "served to Foxglove on the same host, port 8765 (docs/recording.md)",
    )
    dry.add_argument(
        "--pace",
        type=float,
        default=1.0,
        help="with --live: simulated seconds per wall-clock second, more than 0, at most 100 "
        "(default 1)",
    )
    dry.add_argument(
        "--max-time",
        type=float,
        default=None,
        metavar="S",
        help="end the run after S simulated seconds, more than 0 (default: the scenario's "
        "duration)",
    )
    dry.add_argument(
        "--max-missed-deadlines",
        type=int,
        default=DEFAULT_MISSED_DEADLINES,
        metavar="N",
        help="stop the robot and fail the run after N (0 or more) consecutive missed tick "
        "deadlines, as "
        "'walkaround run' does (default 0: never; a simulation's outcome does not depend on "
        "how busy the machine is; metrics.json counts the misses)",
    )
    dry.add_argument(
        "--avoidance",
        action=argparse.BooleanOptionalAction,
        default=True,
        help=(
            "obstacle avoidance in the tree: spiral, velocity obstacles, fallback planner; "
            "--no-avoidance leaves the e-stop and the slowdown only: the robot waits "
            "behind an obstacle"
        ),
    )
    dry.set_defaults(handler=cmd_dry_run)

    show = sub.add_parser(
        "show",
        help="print or draw the behaviour tree a mission compiles into",
        description="Compile the mission and show its tree: ascii (default), Graphviz dot, "
        "a png/svg drawing, an interactive html page whose branches fold, or "
        "BehaviorTree.CPP v4 XML (btcpp, one SubTree per navigation and checkpoint) that "
        "Groot2 can open. dot, png and svg draw an overview (each navigation and checkpoint "
        "folded into one box, one navigation in full as an example) unless --full.",
    )
    show.add_argument("mission", type=Path, metavar="MISSION", help="mission XML")
    show.add_argument(
        "--format",
        choices=("ascii", "dot", "png", "svg", "html", "btcpp"),
        default="ascii",
        help="ascii: text; dot: Graphviz; png, svg: a drawing; html: a page whose branches "
        "fold; btcpp: BehaviorTree.CPP v4 XML",
    )
    show.add_argument(
        "--out", type=Path, default=None, help="file (default: stdout / MISSION.png|svg|html)"
    )
    show.add_argument(
        "--full",
        action="store_true",
        help="dot, png, svg: draw every behaviour instead of the overview",
    )
    show.add_argument("--unicode", action="store_true", help="ascii: box-drawing characters")
    show.add_argument(
        "--bt-runnable",
        action="store_true",
        help="btcpp: keep sensing running under BT.CPP's Parallel semantics (one extra "
        "KeepRunningUntilFailure node per non-selected child)",
    )
    show.set_defaults(handler=cmd_show)

    from executive.cli_robot import add_robot_commands

    add_robot_commands(sub)

    from executive.campaign.cli import add_campaign_command

    add_campaign_command(sub)

    from executive.planning.cli import add_plan_command

    add_plan_command(sub)

    from executive.cli_new import add_new_command

    add_new_command(sub)

    from executive.teach import add_teach_command

    add_teach_command(sub)

    from executive.cli_help import show_defaults

    show_defaults(parser)  # last: every subcommand's --help names its defaults
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
    except KeyboardInterrupt:  # outside a run (a run handles its signals itself)
        return 130


if __name__ == "__main__":
    sys.exit(main())
