"""The robot's subcommands: ``run``, ``sim-robot`` and ``operator`` (issue 14).

``run`` is the executive on the robot (the wires of a robot file, the wall clock);
``sim-robot`` serves the same wires from sim2d in real time (hardware in the loop);
``operator`` sends a command to a running ``run``. Exit codes as everywhere: 0 success,
1 the mission ran and failed (or the command was refused), 2 bad input, 128+N a signal.
"""

from __future__ import annotations

import argparse
import math
import signal
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

from executive.core.problems import InvalidInputError, Problem

EXIT_OK, EXIT_FAILED, EXIT_BAD_INPUT = 0, 1, 2
SIGNALS = ("SIGINT", "SIGTERM", "SIGHUP")
JOURNAL_FILE = "journal.jsonl"
CAN_LOG = "can.blf"


@contextmanager
def safe_signals(on_signal: Callable[[int], None]) -> Iterator[None]:
    """Route SIGINT, SIGTERM and SIGHUP to ``on_signal`` (an ignored one stays ignored:
    nohup) for the body, then restore the previous handlers."""
    previous = {}

    def handler(signum: int, _frame: object) -> None:
        on_signal(signum)

    for name in SIGNALS:
        sig = getattr(signal, name, None)
        if sig is not None and signal.getsignal(sig) is not signal.SIG_IGN:
            previous[sig] = signal.signal(sig, handler)
    try:
        yield
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)


def _report(problems: list[Problem]) -> int:
    from executive.cli import _report as report

    return report(problems)


def _bad(message: str) -> int:
    print(f"walkaround: {message}", file=sys.stderr)
    return EXIT_BAD_INPUT


def _load_inputs(args: argparse.Namespace) -> tuple[object, object] | int:
    """The mission and robot file, checked against each other; an exit code if bad."""
    from executive.cli import check_any
    from executive.core.loader import load_mission
    from executive.robotlink.config import load_robot

    for path in (args.mission, args.robot):
        problems = check_any(path)
        if problems:
            return _report(problems)
    mission = load_mission(args.mission)
    robot = load_robot(args.robot)
    missing = robot.problems_with(mission.platform)
    if missing:
        return _bad(f"{args.robot}: " + "; ".join(missing))
    return mission, robot


# -- walkaround run ------------------------------------------------------------------------------
def cmd_run(args: argparse.Namespace) -> int:
    from executive.core.files import output_dir_problem, remove_if_present
    from executive.journal import check_resumable, read_journal
    from executive.operator import OperatorEndpoint, OperatorState
    from executive.robotlink.link import LinkError, RobotLink
    from executive.robotrun import REPORT_FILES, robot_run, write_robot_report
    from executive.runtime import StopRequest

    if not (math.isfinite(args.rate) and 10.0 <= args.rate <= 50.0):
        return _bad(f"--rate {args.rate:g}: the executive runs at 10 to 50 Hz")
    problem = output_dir_problem(args.out)
    if problem:
        return _bad(f"--out {problem}")
    loaded = _load_inputs(args)
    if isinstance(loaded, int):
        return loaded
    mission, robot = loaded
    out: Path = args.out
    journal = out / JOURNAL_FILE
    state = None
    if args.resume:
        try:
            state = read_journal(journal)
            check_resumable(state, mission, journal)  # type: ignore[arg-type]
        except InvalidInputError as exc:
            return _report(list(exc.problems))
        if state.ended == "completed":
            print(f"mission already completed (journal {journal}): the robot is not moved")
            return EXIT_OK
    out.mkdir(parents=True, exist_ok=True)
    for name in REPORT_FILES if args.resume else (*REPORT_FILES, JOURNAL_FILE):
        remove_if_present(out / name)

    stop = StopRequest()

    def on_signal(signum: int) -> None:
        if stop:
            raise SystemExit(128 + signum)
        stop.set(f"interrupted by {signal.Signals(signum).name}", signum)

    operator = OperatorState()
    with safe_signals(on_signal):
        try:
            link = RobotLink.open(robot, mission.platform, can_log=out / CAN_LOG)  # type: ignore[arg-type]
        except LinkError as exc:
            print(f"walkaround: cannot reach the robot: {exc}", file=sys.stderr)
            return EXIT_FAILED
        # the operator's reset releases the base's own bumper latch too
        operator.listeners.append(lambda c: link.request_reset() if c == "reset-estop" else None)
        endpoint = OperatorEndpoint(
            operator,
            out,
            status=lambda: {"stop": stop.reason, **link.status()},
            host=robot.operator.host,  # type: ignore[attr-defined]
            port=robot.operator.port,  # type: ignore[attr-defined]
        )
        print(f"operator endpoint on {endpoint.host}:{endpoint.port} (secret in {out})")
        try:
            run = robot_run(
                mission,  # type: ignore[arg-type]
                link,
                rate_hz=args.rate,
                journal_path=journal,
                resume=state,
                operator=operator,
                stop=stop,
                max_missed_deadlines=args.max_missed_deadlines or None,
                max_time=args.max_time,
                progress_out=None if args.quiet else sys.stderr,
                servo=args.servo,
            )
        except LinkError as exc:
            print(f"walkaround: cannot start: {exc}; the robot was not moved", file=sys.stderr)
            return EXIT_FAILED
        finally:
            endpoint.close()
            link.close()
    write_robot_report(run, out)
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


# -- walkaround sim-robot ------------------------------------------------------------------------
def cmd_sim_robot(args: argparse.Namespace) -> int:
    from executive.cli import check_any
    from executive.core.files import output_dir_problem
    from executive.robotlink.config import load_robot
    from executive.simrobot import serve
    from sim2d.scenario import load_scenario

    problem = output_dir_problem(args.out)
    if problem:
        return _bad(f"--out {problem}")
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

    with safe_signals(on_signal):
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
        "as a dry-run, on the wall clock. Writes metrics.json, events.jsonl, journal.jsonl "
        "and can.blf to --out; the operator endpoint's address and secret too, while it runs.",
    )
    run.add_argument("mission", type=Path, metavar="MISSION", help="mission XML")
    run.add_argument("--robot", type=Path, required=True, help="robot XML (the wires)")
    run.add_argument("--out", type=Path, default=Path("run"), help="report folder")
    run.add_argument("--rate", type=float, default=50.0, help="executive rate (Hz)")
    run.add_argument("--resume", action="store_true", help="continue OUT/journal.jsonl")
    run.add_argument("--quiet", action="store_true", help="no live progress line")
    run.add_argument("--max-time", type=float, default=None, metavar="S", help="stop after S s")
    run.add_argument("--max-missed-deadlines", type=int, default=10, metavar="N")
    run.add_argument(
        "--servo", action=argparse.BooleanOptionalAction, default=None, help="as in dry-run"
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
    sim.add_argument("--max-time", type=float, default=None, metavar="S")
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
