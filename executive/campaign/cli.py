"""``walkaround campaign``: run a campaign file's episodes, export one episode's
scenario, or merge shards. Exit codes as everywhere: 0 every episode succeeded, 1 some
failed (or crashed), 2 bad input (invalid file or arguments), 130 interrupted."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from executive.core.problems import InvalidInputError, Problem

if TYPE_CHECKING:
    from executive.campaign.results import Row
    from executive.campaign.runner import Shard

EXIT_OK, EXIT_FAILED, EXIT_BAD_INPUT, EXIT_INTERRUPTED = 0, 1, 2, 130
SEED_MAX = 2**32 - 1


def _bad(message: str) -> int:
    print(f"walkaround campaign: {message}", file=sys.stderr)
    return EXIT_BAD_INPUT


def _report(problems: list[Problem]) -> int:
    for problem in problems:
        print(f"{problem.where}: error: {problem.message} [{problem.code}]", file=sys.stderr)
    return EXIT_BAD_INPUT


def parse_shard(text: str) -> Shard | None:
    """``i/k`` with 0 <= i < k, or None when malformed."""
    from executive.campaign.runner import Shard

    index, sep, count = text.partition("/")
    if not sep or not index.isdigit() or not count.isdigit():
        return None
    shard = Shard(int(index), int(count))
    return shard if 0 <= shard.index < shard.count else None


def add_campaign_command(sub: argparse._SubParsersAction) -> None:
    """The ``campaign`` subcommand of the ``walkaround`` parser."""
    campaign = sub.add_parser(
        "campaign",
        help="Monte Carlo dry-runs of a mission on randomised scenarios (a campaign file)",
        description="Run the episodes of a campaign file (schemas/campaign.xsd): episode k "
        "dry-runs a scenario drawn from the campaign's distributions as a pure function of "
        "(seed, k). Each episode's result is appended to OUT/results.jsonl as it ends; "
        "OUT/summary.json (success rate with its 95 % interval per mission and scenario, "
        "failures by cause, worst checkpoints) and OUT/report.html (with plots) at the end. "
        "'walkaround campaign merge OUT SHARD_DIR...' merges the folders of --shard runs. "
        "Exit 0 when every episode succeeded, 1 when some failed, 2 on bad input.",
        usage="walkaround campaign CAMPAIGN.xml --out DIR [--episodes N] [--seed S] "
        "[--jobs J] [--backend local|ray] [--ray-address ADDR] [--shard i/k] [--resume]\n"
        "       [--max-time S] [--quiet]\n"
        "       walkaround campaign CAMPAIGN.xml --episode N --export-scenario FILE [--seed S]\n"
        "       walkaround campaign merge OUT SHARD_DIR...\n"
        "       walkaround campaign report OUT",
    )
    campaign.add_argument(
        "campaign", metavar="CAMPAIGN.xml", help="campaign file (or 'merge' or 'report', see above)"
    )
    campaign.add_argument("paths", nargs="*", type=Path, help=argparse.SUPPRESS)
    campaign.add_argument(
        "--out", type=Path, default=None, help="results folder (no default: required to run)"
    )
    campaign.add_argument(
        "--episodes",
        type=int,
        default=None,
        help="episodes 0..N-1, N 0 or more (default: the file's)",
    )
    campaign.add_argument(
        "--seed",
        type=int,
        default=None,
        help=f"override the campaign seed, 0 to {SEED_MAX} (default: the file's)",
    )
    campaign.add_argument(
        "--jobs",
        type=int,
        default=1,
        help="worker processes, 1 or more (default 1); with --backend ray, the CPUs of the "
        "Ray instance started here (a running cluster uses all of its CPUs)",
    )
    campaign.add_argument(
        "--backend",
        default="local",
        help="local: worker processes on this machine (default); ray: Ray tasks, on the "
        "cluster at --ray-address or $RAY_ADDRESS, else on a Ray instance started here "
        "(needs pip install 'walkaround[cluster]'; on several machines the campaign's "
        "files must lie at the same path on every node)",
    )
    campaign.add_argument(
        "--ray-address",
        default=None,
        metavar="ADDR",
        help="with --backend ray: the address of a running Ray cluster (default $RAY_ADDRESS)",
    )
    campaign.add_argument(
        "--shard",
        default=None,
        metavar="i/k",
        help="run only the episodes with index %% k == i, 0 <= i < k (default: every episode)",
    )
    campaign.add_argument(
        "--resume", action="store_true", help="skip the episodes already in OUT/results.jsonl"
    )
    campaign.add_argument(
        "--max-time",
        type=float,
        default=None,
        metavar="S",
        help="end each episode after S simulated s, more than 0 (default: its duration)",
    )
    campaign.add_argument("--quiet", action="store_true", help="no progress bar")
    campaign.add_argument(
        "--episode",
        type=int,
        default=None,
        metavar="N",
        help="with --export-scenario: the episode, 0 or more (no default: required there)",
    )
    campaign.add_argument(
        "--export-scenario",
        type=Path,
        default=None,
        metavar="FILE",
        help="write episode N's scenario file instead of running (default: run; rerun it "
        "with 'walkaround dry-run MISSION --scenario FILE'); it must lie in the mission "
        "library, e.g. beside the mission's scenarios",
    )
    campaign.set_defaults(handler=cmd_campaign)


def cmd_campaign(args: argparse.Namespace) -> int:
    """Dispatch: merge, export or run."""
    try:
        if args.campaign == "merge":
            return _merge(args)
        if args.campaign == "report":
            return _report_folder(args)
        if args.paths:
            return _bad(f"unexpected arguments: {' '.join(map(str, args.paths))}")
        return _export(args) if args.export_scenario is not None else _run(args)
    except InvalidInputError as exc:
        return _report(list(exc.problems))
    except KeyboardInterrupt:
        print("walkaround campaign: interrupted; rows written so far are kept", file=sys.stderr)
        return EXIT_INTERRUPTED


def _load(args: argparse.Namespace) -> object:
    from executive.campaign.spec import check_campaign, load_campaign

    path = Path(args.campaign)
    problems = check_campaign(path)
    if problems:
        raise InvalidInputError(problems)
    campaign = load_campaign(path)
    if args.seed is not None:
        if not 0 <= args.seed <= SEED_MAX:
            raise ValueError(f"--seed {args.seed}: an integer from 0 to {SEED_MAX}")
        campaign = campaign.with_seed(args.seed)
    return campaign


def _export(args: argparse.Namespace) -> int:
    from executive.campaign.sampler import ExportError, SamplingError, draw_episode, export_scenario

    if args.episode is None or args.episode < 0:
        return _bad("--export-scenario needs --episode N (0 or more)")
    try:
        campaign = _load(args)
    except ValueError as exc:
        return _bad(str(exc))
    try:
        episode = draw_episode(campaign, args.episode)  # type: ignore[arg-type]
        path = export_scenario(episode.scenario, args.export_scenario)
    except (ExportError, SamplingError) as exc:
        return _bad(str(exc))
    mission = episode.scenario.mission.source
    print(f"wrote {path}; rerun it with: walkaround dry-run {mission} --scenario {path}")
    return EXIT_OK


def _check_run_arguments(args: argparse.Namespace) -> str | None:
    import math

    from executive.campaign.runner import BACKENDS

    if args.backend not in BACKENDS:
        return f"--backend {args.backend}: one of {', '.join(BACKENDS)}"
    if args.backend == "ray":
        from executive.campaign.ray_backend import INSTALL_HINT, ray_available

        if not ray_available():
            return f"--backend ray needs Ray, which is not installed: {INSTALL_HINT}"
    elif args.ray_address is not None:
        return "--ray-address goes with --backend ray"
    if args.out is None:
        return "--out DIR is required to run a campaign"
    if args.episodes is not None and args.episodes < 0:
        return f"--episodes {args.episodes}: 0 or more"
    if args.jobs < 1:
        return f"--jobs {args.jobs}: 1 or more"
    if args.shard is not None and parse_shard(args.shard) is None:
        return f"--shard {args.shard}: i/k with 0 <= i < k"
    if args.max_time is not None and not (math.isfinite(args.max_time) and args.max_time > 0):
        return f"--max-time {args.max_time}: simulated seconds, more than 0"
    if args.episode is not None:
        return "--episode goes with --export-scenario"
    return None


def _run(args: argparse.Namespace) -> int:
    from executive.campaign.runner import ResultsFolderError, run_campaign

    bad = _check_run_arguments(args)
    if bad:
        return _bad(bad)
    try:
        campaign = _load(args)
    except ValueError as exc:
        return _bad(str(exc))
    episodes = args.episodes if args.episodes is not None else campaign.episodes  # type: ignore[attr-defined]
    shard = parse_shard(args.shard) if args.shard else None
    progress = _Progress(quiet=args.quiet)
    try:
        rows = run_campaign(
            campaign,  # type: ignore[arg-type]
            args.out,
            episodes,
            jobs=args.jobs,
            shard=shard,
            resume=args.resume,
            max_time=args.max_time,
            on_row=progress.update,
            backend=args.backend,
            ray_address=args.ray_address,
        )
    except ResultsFolderError as exc:
        return _bad(str(exc))
    except ConnectionError as exc:  # --backend ray: no cluster at the address
        return _bad(f"--backend ray: cannot reach the Ray cluster: {exc}")
    finally:
        progress.close()
    from executive.campaign.report import report_from_folder

    page = report_from_folder(args.out)
    ok = sum(bool(r.get("succeeded")) for r in rows)
    print(
        f"{ok}/{len(rows)} episodes succeeded; results in {args.out / 'results.jsonl'}, "
        f"summary in {args.out / 'summary.json'}, report in {page}"
    )
    return EXIT_OK if ok == len(rows) else EXIT_FAILED


def _report_folder(args: argparse.Namespace) -> int:
    """``walkaround campaign report OUT``: (re)write OUT's HTML report from its results."""
    from executive.campaign.report import report_from_folder

    if len(args.paths) != 1:
        return _bad("report needs exactly one results folder: walkaround campaign report OUT")
    print(f"report in {report_from_folder(args.paths[0])}")
    return EXIT_OK


def _merge(args: argparse.Namespace) -> int:
    from executive.campaign.results import (
        CAMPAIGN_FILE,
        RESULTS_FILE,
        SUMMARY_FILE,
        MergeError,
        merge_rows,
        summarise,
        write_json,
    )
    from executive.core.files import write_atomic

    if len(args.paths) < 2:
        return _bad("merge needs OUT and at least one SHARD_DIR")
    out, shards = args.paths[0], args.paths[1:]
    if (out / RESULTS_FILE).exists():
        return _bad(f"{out} already holds results; merge into a new folder")
    try:
        identity, rows = merge_rows(shards)
    except MergeError as exc:
        return _bad(str(exc))
    import json

    out.mkdir(parents=True, exist_ok=True)
    text = "".join(json.dumps(r, sort_keys=True) + "\n" for r in rows)
    write_atomic(out / RESULTS_FILE, text.encode("utf-8"))
    write_json(out / CAMPAIGN_FILE, identity | {"shard": None, "merged": [str(s) for s in shards]})
    write_json(out / SUMMARY_FILE, summarise(identity, rows))
    from executive.campaign.report import report_from_folder

    page = report_from_folder(out)
    print(f"merged {len(rows)} episodes from {len(shards)} folders into {out}; report in {page}")
    return EXIT_OK


class _Progress:
    """A live progress bar with the running success rate (tqdm), or nothing."""

    def __init__(self, quiet: bool) -> None:
        self.quiet = quiet
        self.bar: object | None = None
        self.ok = 0
        self.seen = 0

    def update(self, row: Row, done: int, total: int) -> None:
        if self.quiet:
            return
        from tqdm import tqdm

        if self.bar is None:
            self.bar = tqdm(total=total, initial=done - 1, unit="ep", file=sys.stderr)
        self.seen += 1
        self.ok += bool(row.get("succeeded"))
        bar = self.bar
        assert isinstance(bar, tqdm)
        bar.set_postfix_str(f"success {100.0 * self.ok / self.seen:.1f} % of {self.seen}")
        bar.update(1)
        if not row.get("succeeded"):
            bar.write(f"episode {row['episode']}: {row.get('first_cause')}")

    def close(self) -> None:
        bar = self.bar
        if bar is not None:
            bar.close()  # type: ignore[attr-defined]
