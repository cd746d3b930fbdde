"""The robot's subcommands: ``run``, ``sim-robot`` and ``operator`` (issue 14).

``run`` is the executive on the robot (the wires of a robot file, the wall clock);
``sim-robot`` serves the same wires from sim2d in real time (hardware in the loop);
``operator`` sends a command to a running ``run``. Exit codes as everywhere: 0 success,
1 the mission ran and failed (or the command was refused), 2 bad input, 128+N a signal.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from executive.core.problems import InvalidInputError, Problem

if TYPE_CHECKING:
    from executive.core.model import Mission, Platform
    from executive.robotlink.config import RobotConfig
    from executive.runtime import StopRequest

EXIT_OK, EXIT_FAILED, EXIT_BAD_INPUT = 0, 1, 2
JOURNAL_FILE = "journal.jsonl"
CAN_LOG = "can.blf"


def _report(problems: list[Problem]) -> int:
    from executive.cli import _report as report

    return report(problems)


def _bad(message: str) -> int:
    print(f"walkaround: {message}", file=sys.stderr)
    return EXIT_BAD_INPUT


def _load_inputs(args: argparse.Namespace) -> tuple[Mission, RobotConfig] | int:
    """The mission and robot file, checked against each other; an exit code if bad."""
    from executive.cli import check_any
    from executive.core.loader import load_mission
    from executive.robotlink.config import load_robot

    for path in (args.mission, args.robot):
        problems = check_any(path)
        if problems:
            return _report(problems)
    return load_mission(args.mission), load_robot(args.robot)


# -- walkaround run ------------------------------------------------------------------------------
WATCHDOG_PERIODS = 3.0
"""The base's watchdog must span this many periods of the executive: a tick late by a
period or two must not brake the base."""


def _check_run_arguments(args: argparse.Namespace) -> str | None:
    from executive.core.files import output_dir_problem

    if not (math.isfinite(args.rate) and 10.0 <= args.rate <= 50.0):
        return f"--rate {args.rate:g}: the executive runs at 10 to 50 Hz"
    if args.max_time is not None and not (math.isfinite(args.max_time) and args.max_time > 0):
        return f"--max-time {args.max_time}: seconds, more than 0"
    if args.max_missed_deadlines < 0:
        return f"--max-missed-deadlines {args.max_missed_deadlines}: 0 (never) or more"
    problem = output_dir_problem(args.out)
    if problem:
        return f"--out {problem}"
    journal = args.out / JOURNAL_FILE
    if args.resume and (journal.is_symlink() or not journal.exists()):
        return f"--resume: the journal {journal} does not exist; nothing to resume"
    return None


def _robot_problems(robot: RobotConfig, platform: Platform, rate: float) -> list[str]:
    """What makes this robot file unfit for this mission at this rate: a platform sensor
    without its wire, a limit the DBC cannot carry, a watchdog shorter than the ticks."""
    from executive.robotlink.canbase import load_dbc

    problems = robot.problems_with(platform)
    db = load_dbc()
    for message, signal, limit, what in (
        ("MOTION_CMD", "V", platform.max_speed, "max-speed"),
        ("MOTION_CMD", "OMEGA", platform.max_angular_speed, "max-angular-speed"),
        *(
            ("PTU_CMD", "PAN_RATE", cam.pan_rate, f"camera '{cid}' pan rate")
            for cid, cam in platform.cameras.items()
        ),
        *(
            ("PTU_CMD", "TILT_RATE", cam.tilt_rate, f"camera '{cid}' tilt rate")
            for cid, cam in platform.cameras.items()
        ),
    ):
        high = db.get_message_by_name(message).get_signal_by_name(signal).maximum
        if high is not None and limit > high:
            problems.append(
                f"the platform's {what} {limit:g} is more than the CAN frame carries "
                f"({message}.{signal} at most {high:g})"
            )
    if robot.can.watchdog < WATCHDOG_PERIODS / rate:
        problems.append(
            f"the base's watchdog ({robot.can.watchdog * 1e3:g} ms) must span "
            f"{WATCHDOG_PERIODS:g} ticks at {rate:g} Hz ({WATCHDOG_PERIODS / rate * 1e3:g} ms): "
            "raise --rate or watchdog-ms"
        )
    return problems


def cmd_run(args: argparse.Namespace) -> int:
    from executive.compiler import CompileError
    from executive.journal import JournalWriteError
    from executive.runtime import StopRequest
    from executive.signals import stop_on_signals

    stop = StopRequest()
    try:
        with stop_on_signals(stop):
            return _run(args, stop)
    except (InvalidInputError, CompileError) as exc:
        return _report(list(exc.problems))
    except JournalWriteError as exc:
        print(f"walkaround: {exc.strerror or exc}; the robot was sent a stop", file=sys.stderr)
        return EXIT_FAILED


def _run(args: argparse.Namespace, stop: StopRequest) -> int:
    from executive.core.files import remove_if_present
    from executive.hud.server import HudServer
    from executive.hud.telemetry import Telemetry
    from executive.journal import check_resumable, check_resume_pose, read_journal
    from executive.operator import OperatorState
    from executive.recording import recording_path
    from executive.robotlink.link import LinkError, RobotLink
    from executive.robotrun import REPORT_FILES, NotStartedError, robot_run, write_robot_report
    from executive.runtime import WallClock

    bad = _check_run_arguments(args)
    if bad:
        return _bad(bad)
    loaded = _load_inputs(args)
    if isinstance(loaded, int):
        return loaded
    mission, robot = loaded
    problems = _robot_problems(robot, mission.platform, args.rate)
    if problems:
        return _bad(f"{args.robot}: " + "; ".join(problems))
    out: Path = args.out
    journal = out / JOURNAL_FILE
    state = None
    if args.resume:
        state = read_journal(journal)  # InvalidInputError: exit 2 at the journal's line
        check_resumable(state, mission, journal)
        if state.ended == "completed":
            print(f"mission already completed (journal {journal}): the robot is not moved")
            return EXIT_OK
        check_resume_pose(state, mission, journal)
    out.mkdir(parents=True, exist_ok=True)

    def clear_old_report() -> None:
        """Once the robot answered: a run that cannot start destroys nothing."""
        for name in REPORT_FILES if args.resume else (*REPORT_FILES, JOURNAL_FILE):
            remove_if_present(out / name)

    clock = WallClock()
    operator = OperatorState()
    try:
        link = RobotLink.open(robot, mission.platform, clock=clock.now, can_log=_can_log(out))
    except LinkError as exc:
        print(f"walkaround: cannot reach the robot: {exc}", file=sys.stderr)
        return EXIT_FAILED
    endpoint = None
    try:
        # the operator's reset releases the base's own bumper latch too
        operator.listeners.append(lambda c: link.request_reset() if c == "reset-estop" else None)
        # no link status in the snapshots: it summarises every wire's latencies (O(run)),
        # which stalled the tick late in a run; the HUD's /status answers it on request
        telemetry = Telemetry.of_operator(mission, operator, args.rate)
        endpoint = HudServer(
            operator,
            out,
            status=lambda: {"stop": stop.reason, **link.status()},
            host=robot.operator.host,
            port=robot.operator.port,
            telemetry=telemetry,
        )
        print(
            f"operator HUD on {endpoint.host}:{endpoint.port}: {endpoint.url}\n"
            f"(the secret is also in {out / 'operator.secret'})"
        )
        run = robot_run(
            mission,
            link,
            clock=clock,
            rate_hz=args.rate,
            journal_path=journal,
            resume=state,
            operator=operator,
            stop=stop,
            max_missed_deadlines=args.max_missed_deadlines or None,
            max_time=args.max_time,
            progress_out=None if args.quiet else sys.stderr,
            servo=args.servo,
            before_start=clear_old_report,
            record=recording_path(out) if args.record else None,  # never overwrites one
            observers=(telemetry.on_tick,),
        )
    except NotStartedError as exc:
        print(f"walkaround: {exc}", file=sys.stderr)
        return 128 + (stop.signal or 0)
    except (LinkError, OSError) as exc:
        print(f"walkaround: cannot start: {exc}; the robot was not moved", file=sys.stderr)
        return EXIT_FAILED
    finally:
        link.close()  # first: the base holds on its watchdog whatever comes next
        if endpoint is not None:
            endpoint.close()
    write_robot_report(run, out)
    if run.recording_error:
        print(f"warning: {run.recording_error}", file=sys.stderr)
    result = run.result
    stopped = "the robot was sent a stop" if result.stop_sent else "the stop was NOT confirmed"
    print(
        f"{result.outcome}: {result.reason}; {len(result.progress.completed)}/"
        f"{len(run.mission.checkpoints)} checkpoints; {stopped}; report in {out}"
    )
    if result.outcome == "interrupted" and stop.signal is not None:
        print(f"walkaround: continue with the same command and --resume (journal {journal})")
        return 128 + stop.signal
    return EXIT_OK if run.succeeded else EXIT_FAILED


def _can_log(out: Path) -> Path:
    """``can.blf``, or ``can-2.blf``, ... for a resumed run: no run's log is overwritten."""
    path, k = out / CAN_LOG, 1
    while path.exists() or path.is_symlink():
        k += 1
        path = out / f"can-{k}.blf"
    return path


# -- walkaround sim-robot ------------------------------------------------------------------------
def cmd_sim_robot(args: argparse.Namespace) -> int:
    from executive.cli import check_any
    from executive.core.files import output_dir_problem
    from executive.robotlink.config import load_robot
    from executive.signals import routed_signals
    from executive.simrobot import serve
    from sim2d.scenario import load_scenario

    problem = output_dir_problem(args.out)
    if problem:
        return _bad(f"--out {problem}")
    if args.max_time is not None and not (math.isfinite(args.max_time) and args.max_time > 0):
        return _bad(f"--max-time {args.max_time}: seconds, more than 0")
    for path in (args.scenario, args.robot):
        problems = check_any(path)
        if problems:
            return _report(problems)
    scenario = load_scenario(args.scenario)
    robot = load_robot(args.robot)
    missing = robot.problems_with(scenario.mission.platform)
    if missing:
        return _bad(f"{args.robot}: " + "; ".join(missing))
    stopping: list[int] = []

    def on_signal(signum: int) -> None:
        stopping.append(signum)

    with routed_signals(on_signal):
        summary = serve(
            scenario, robot, args.out, should_stop=lambda: bool(stopping), max_time=args.max_time
        )
    print(summary)
    return 128 + stopping[0] if stopping else EXIT_OK


# -- walkaround operator -------------------------------------------------------------------------
def cmd_operator(args: argparse.Namespace) -> int:
    from executive.operator import OperatorError, send_command

    try:
        print(send_command(args.run, args.command))
    except OperatorError as exc:
        print(f"walkaround: {exc}", file=sys.stderr)
        return EXIT_FAILED
    return EXIT_OK


def add_robot_commands(sub: argparse._SubParsersAction) -> None:
    """Add ``run``, ``sim-robot`` and ``operator`` to the ``walkaround`` parser."""
    from executive.operator import COMMANDS

    run = sub.add_parser(
        "run",
        help="run a mission on the robot (the wires of a robot file, the wall clock)",
        description="Compile the mission and run it on the robot the robot file wires: the "
        "drive base over CAN (DBC shipped with walkaround), lasers over SCIP 2.0, GPS over "
        "NMEA 0183, camera detections over ZeroMQ. The same tree, safety layer and journal "
        "as a dry-run, on the wall clock. Writes metrics.json, events.jsonl, journal.jsonl, "
        "can.blf and run.mcap (for Foxglove) to --out; the operator endpoint's address and "
        "secret too, while it runs.",
    )
    run.add_argument("mission", type=Path, metavar="MISSION", help="mission XML")
    run.add_argument("--robot", type=Path, required=True, help="robot XML (the wires)")
    run.add_argument("--out", type=Path, default=Path("run"), help="report folder")
    run.add_argument(
        "--rate", type=float, default=50.0, help="executive rate, Hz, 10 to 50 (default 50)"
    )
    run.add_argument("--resume", action="store_true", help="continue OUT/journal.jsonl")
    run.add_argument("--quiet", action="store_true", help="no live progress line")
    run.add_argument(
        "--no-record",
        dest="record",
        action="store_false",
        help="do not record the run for Foxglove (default: OUT/run.mcap, run-2.mcap, ...)",
    )
    run.add_argument(
        "--max-time",
        type=float,
        default=None,
        metavar="S",
        help="stop after S s, more than 0 (default: run until the mission ends)",
    )
    run.add_argument(
        "--max-missed-deadlines",
        type=int,
        default=10,
        metavar="N",
        help="stop the robot and fail the run after N consecutive missed tick deadlines, "
        "0 (never) or more (default 10)",
    )
    run.add_argument(
        "--servo",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="as in dry-run (default: on for the A320-200 and B737-800, off for other types)",
    )
    run.set_defaults(handler=cmd_run)

    sim = sub.add_parser(
        "sim-robot",
        help="hardware in the loop: sim2d in real time, serving the robot file's wires",
        description="Run a scenario in real time and serve exactly the robot's wires: CAN "
        "frames per the DBC (with the base's watchdog and bumper latch), SCIP servers for "
        "the lasers, an NMEA stream, camera detections. Writes truth.jsonl (ground truth "
        "with Unix times) to --out. Ends on SIGINT/SIGTERM or after --max-time.",
    )
    sim.add_argument("scenario", type=Path, metavar="SCENARIO", help="scenario XML")
    sim.add_argument("--robot", type=Path, required=True, help="robot XML (the wires)")
    sim.add_argument("--out", type=Path, default=Path("sim-robot"), help="truth folder")
    sim.add_argument(
        "--max-time",
        type=float,
        default=None,
        metavar="S",
        help="end after S s, more than 0 (default: run until SIGINT or SIGTERM)",
    )
    sim.set_defaults(handler=cmd_sim_robot)

    op = sub.add_parser(
        "operator",
        help="send a command to a running `walkaround run`",
        description="Send COMMAND to the run whose report folder is --run (its endpoint "
        "address and secret are there while it runs). status prints what it is doing.",
    )
    op.add_argument("command", choices=(*COMMANDS, "status"), metavar="COMMAND")
    op.add_argument("--run", type=Path, default=Path("run"), help="the run's --out folder")
    op.set_defaults(handler=cmd_operator)
