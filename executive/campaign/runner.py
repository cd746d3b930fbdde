"""Running a campaign's episodes, in worker processes or on Ray, into its results folder.

Each episode is :func:`executive.dryrun.dry_run` on the scenario
:func:`executive.campaign.sampler.draw_episode` gives; its result row is appended to
``results.jsonl`` (flushed and synced) as soon as it ends, so a crash or a kill loses at
most the episodes then running, and a resumed run skips the finished ones. An exception
inside an episode is a row with outcome ``crashed`` and its traceback.
"""

from __future__ import annotations

import math
import multiprocessing
import os
import time
import traceback
from collections.abc import Callable, Generator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from contextlib import AbstractContextManager, closing, nullcontext
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

from executive.campaign.results import (
    CAMPAIGN_FILE,
    RESULTS_FILE,
    SUMMARY_FILE,
    Row,
    append_row,
    read_identity,
    read_rows,
    same_campaign,
    summarise,
    write_json,
)
from executive.campaign.sampler import Episode, draw_episode
from executive.campaign.spec import Campaign, load_campaign
from executive.core.problems import InvalidInputError, Problem, SourceLocation

WORKER_ENV = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
"""One core per worker: numpy's BLAS must not start threads of its own."""
RATE_HZ = 50.0
"""The executive's rate in every episode (the dry-run's default)."""


@dataclass(frozen=True)
class Shard:
    """Episodes whose index % count == index_."""

    index: int
    count: int

    def __str__(self) -> str:
        return f"{self.index}/{self.count}"

    def holds(self, episode: int) -> bool:
        return episode % self.count == self.index


def identity(campaign: Campaign) -> dict[str, object]:
    """What a results folder records of its campaign (``campaign.json``)."""
    return {
        "campaign": campaign.id,
        "file": campaign.source,
        "digest": campaign.digest,
        "seed": campaign.seed,
    }


# -- one episode -------------------------------------------------------------------------------
def _near_misses(clearances: list[float], threshold: float) -> int:
    """Excursions of the true clearance below ``threshold`` that end without contact."""
    count, low = 0, None
    for c in [*clearances, math.inf]:
        if c < threshold:
            low = c if low is None else min(low, c)
        elif low is not None:
            count += low > 0.0
            low = None
    return count


def _kind_of(episode: Episode, other: str) -> str:
    for ob in episode.scenario.obstacles:
        if ob.id == other:
            return str(getattr(ob, "kind", "person"))
    return "aircraft" if other.startswith("aircraft") else "other"


def _row_base(campaign: Campaign, episode: int) -> Row:
    return {
        "episode": episode,
        "campaign": campaign.id,
        "campaign_seed": campaign.seed,
    }


def episode_row(campaign: Campaign, index: int, max_time: float | None = None) -> Row:
    """Run episode ``index`` and describe it in one JSON-ready row; never raises."""
    from executive.dryrun import dry_run

    wall0 = time.perf_counter()
    row = _row_base(campaign, index)
    try:
        episode = draw_episode(campaign, index)
        scenario = episode.scenario
        row |= {
            "scenario": episode.base,
            "episode_scenario": scenario.id,
            "mission": scenario.mission.id,
            "sim_seed": scenario.seed,
            "drawn": episode.params,
        }
        run = dry_run(scenario, rate_hz=RATE_HZ, max_time=max_time)
    except Exception as exc:  # a crashed episode is a row, not the end of the campaign
        return row | {
            "outcome": "crashed",
            "succeeded": False,
            "first_cause": f"crashed: {type(exc).__name__}: {exc}",
            "causes": [],
            "traceback": traceback.format_exc(),
            "wall_s": round(time.perf_counter() - wall0, 2),
        }
    reached = [c for c in run.checkpoints if c.reached and c.position_error is not None]
    worst_p = max(reached, key=lambda c: c.position_error or 0.0, default=None)
    worst_h = max(reached, key=lambda c: c.heading_error_deg or 0.0, default=None)
    clearances = [s.clearance for s in run.samples if math.isfinite(s.clearance)]
    collisions = [
        {
            "t": round(c.time, 2),
            "with": c.other,
            "kind": _kind_of(episode, c.other),
            "robot_speed": round(c.robot_speed, 3),
            "robot_moving": c.robot_moving,
            "robot_closing": (
                round(c.robot_closing, 3) if math.isfinite(c.robot_closing) else None
            ),
        }
        for c in run.robot.truth.collisions
    ]
    return row | {
        "outcome": run.result.outcome,
        "succeeded": run.succeeded,
        "reason": run.result.reason,
        "first_cause": run.first_cause,
        "causes": [c.text for c in run.causes],
        "checkpoints_reached": sum(c.reached for c in run.checkpoints),
        "checkpoints_total": len(run.checkpoints),
        "worst_position_error": round(worst_p.position_error, 4) if worst_p else None,
        "worst_position_checkpoint": worst_p.id if worst_p else None,
        "worst_heading_error_deg": (
            round(worst_h.heading_error_deg, 3)
            if worst_h and worst_h.heading_error_deg is not None
            else None
        ),
        "worst_heading_checkpoint": worst_h.id if worst_h else None,
        "collisions": collisions,
        "min_clearance": round(min(clearances), 3) if clearances else None,
        "near_misses": _near_misses(clearances, campaign.near_miss),
        "simulated_s": round(run.robot.time, 2),
        "wall_s": round(time.perf_counter() - wall0, 2),
    }


@lru_cache(maxsize=4)
def _campaign(path: str, seed: int, digest: str | None = None) -> Campaign:
    """The campaign at ``path``, loaded once per worker process; ``digest`` (the driver's)
    is part of the key: a long-lived worker (Ray reuses them) whose cached copy is of
    other files loads the file again rather than trusting its cache."""
    return load_campaign(path).with_seed(seed)


def crashed_row(base: Row, cause: str, trace: str) -> Row:
    """``base`` as the row of an episode that crashed with ``cause`` (its first cause)."""
    return base | {
        "outcome": "crashed",
        "succeeded": False,
        "first_cause": f"crashed: {cause}",
        "causes": [],
        "traceback": trace,
    }


def worker_row(
    path: str, seed: int, index: int, max_time: float | None, digest: str | None = None
) -> Row:
    """:func:`episode_row` in a worker process: the campaign is loaded once per worker.
    With ``digest`` (the driver's :attr:`Campaign.digest`), a campaign whose files differ
    here from the driver's (edited since, or another copy on a cluster node) is not run:
    its episode is a crashed row."""
    base: Row = {"episode": index, "campaign_seed": seed}
    try:
        campaign = _campaign(path, seed, digest)
        if digest is not None and campaign.digest != digest:
            _campaign.cache_clear()  # the files may yet become the driver's
    except Exception as exc:
        return crashed_row(base, f"{type(exc).__name__}: {exc}", traceback.format_exc())
    if digest is not None and campaign.digest != digest:
        return crashed_row(
            _row_base(campaign, index),
            f"the campaign's files at {path} differ in this worker from the driver's "
            f"(digest {campaign.digest[:12]}, expected {digest[:12]})",
            "",
        )
    return episode_row(campaign, index, max_time)


def _set_worker_env() -> None:
    os.environ.update(WORKER_ENV)


# -- a campaign --------------------------------------------------------------------------------
class ResultsFolderError(ValueError):
    """The output folder holds results that this run may not extend or replace."""


def prepare_folder(campaign: Campaign, out: Path, resume: bool, shard: Shard | None) -> list[Row]:
    """Check ``out`` and return the rows already there (a resume); write campaign.json."""
    results = out / RESULTS_FILE
    ident = identity(campaign) | {"shard": str(shard) if shard else None}
    old = read_identity(out)
    if not resume:
        if results.exists() or old is not None:
            raise ResultsFolderError(
                f"{out} already holds campaign results: continue them with --resume, or "
                "choose another --out"
            )
    elif old is not None and not same_campaign(old, ident):
        what = ", ".join(f"{k} {old.get(k)!r}" for k in ("campaign", "seed", "digest"))
        raise ResultsFolderError(
            f"--resume: {out} holds results of another campaign run ({what}); the campaign "
            "file, a scenario file or the seed changed"
        )
    elif old is not None and old.get("shard") != ident["shard"]:
        raise ResultsFolderError(
            f"--resume: {out} holds shard {old.get('shard')}, not {ident['shard']}"
        )
    out.mkdir(parents=True, exist_ok=True)
    rows = read_rows(results, repair=True) if resume else []
    write_json(out / CAMPAIGN_FILE, ident)
    return rows


def _local_rows(
    campaign: Campaign,
    path: str,
    todo: list[int],
    jobs: int,
    max_time: float | None,
) -> Generator[Row, None, None]:
    """Rows of ``todo`` as their episodes end: in this process (``jobs`` 1) or in a
    pool of spawned worker processes."""
    if jobs <= 1:
        for index in todo:
            yield episode_row(campaign, index, max_time)
        return
    saved = {k: os.environ.get(k) for k in WORKER_ENV}
    _set_worker_env()  # inherited by the spawned workers before they import numpy
    try:
        context = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(jobs, mp_context=context, initializer=_set_worker_env) as pool:
            pending: dict[Future[Row], int] = {}
            queue = list(todo)
            while queue or pending:
                while queue and len(pending) < 2 * jobs:
                    index = queue.pop(0)
                    future = pool.submit(
                        worker_row, path, campaign.seed, index, max_time, campaign.digest
                    )
                    pending[future] = index
                done, _ = wait(pending, return_when=FIRST_COMPLETED)
                for future in done:
                    index = pending.pop(future)
                    yield _result_of(future, campaign, index)
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def _result_of(future: Future[Row], campaign: Campaign, index: int) -> Row:
    try:
        return future.result()
    except BrokenProcessPool as exc:  # a worker died (killed, out of memory)
        return crashed_row(
            _row_base(campaign, index),
            f"the worker process died ({exc})",
            "".join(traceback.format_exception(exc)),
        )


BACKENDS = ("local", "ray")
"""Where episodes run: worker processes on this machine, or tasks on a Ray cluster."""


def run_campaign(
    campaign: Campaign,
    out: Path,
    episodes: int,
    *,
    jobs: int = 1,
    shard: Shard | None = None,
    resume: bool = False,
    max_time: float | None = None,
    on_row: Callable[[Row, int, int], None] | None = None,
    backend: str = "local",
    ray_address: str | None = None,
) -> list[Row]:
    """Run episodes 0 .. ``episodes`` - 1 (those of ``shard``) not already in ``out``;
    write each row as it ends, then ``summary.json``. Returns every row of the folder,
    sorted by episode. ``on_row(row, done, total)`` follows progress.

    ``backend`` "local" runs the episodes in ``jobs`` worker processes (in this process
    when 1); "ray" runs them as Ray tasks (:mod:`executive.campaign.ray_backend`: the
    cluster at ``ray_address`` or ``RAY_ADDRESS``, else a local instance of ``jobs``
    CPUs). Both give the same rows apart from ``wall_s``."""
    if not campaign.source:
        raise ValueError("a campaign loaded from a file is needed (its workers reload it)")
    if backend not in BACKENDS:
        raise ValueError(f"backend {backend!r}: one of {', '.join(BACKENDS)}")
    session: AbstractContextManager[None] = nullcontext()
    if backend == "ray":
        from executive.campaign.ray_backend import ray_session

        session = ray_session(jobs, ray_address)  # connects before the folder is touched
    with session:
        rows = prepare_folder(campaign, out, resume, shard)
        finished = {int(r["episode"]) for r in rows}  # type: ignore[call-overload]
        wanted = [k for k in range(episodes) if shard is None or shard.holds(k)]
        todo = [k for k in wanted if k not in finished]
        total = len(wanted)
        done = total - len(todo)
        source: Generator[Row, None, None]
        if backend == "ray":
            from executive.campaign.ray_backend import ray_rows

            source = ray_rows(campaign, campaign.source, todo, jobs, max_time)
        else:
            source = _local_rows(campaign, campaign.source, todo, jobs, max_time)
        with (out / RESULTS_FILE).open("a", encoding="utf-8") as handle, closing(source):
            for row in source:
                append_row(handle, row)
                rows.append(row)
                done += 1
                if on_row is not None:
                    on_row(row, done, total)
    rows.sort(key=lambda r: int(r["episode"]))  # type: ignore[call-overload]
    write_json(out / SUMMARY_FILE, summarise(identity(campaign), rows))
    return rows


def check_results_folder(out: Path) -> list[Problem]:
    """Problems of an existing results folder's files (for the command line)."""
    try:
        read_identity(out)
        read_rows(out / RESULTS_FILE)
    except InvalidInputError as exc:
        return list(exc.problems)
    except OSError as exc:
        return [Problem(SourceLocation(str(out)), "unreadable", str(exc))]
    return []
