"""Running a campaign's episodes as Ray tasks (``walkaround campaign --backend ray``).

Ray is the optional extra ``walkaround[cluster]`` (``pip install 'walkaround[cluster]'``).
Each episode is one task of one CPU running :func:`executive.campaign.runner.worker_row`
with one BLAS thread (``OPENBLAS_NUM_THREADS=1`` in the task's runtime environment); a
bounded number of tasks is in flight and their rows come back as they end, so the
results file, ``--resume``, ``--shard`` and the summary are those of the local backend.

Where: the Ray cluster at ``--ray-address`` or ``RAY_ADDRESS`` when one is given (the
address of a running cluster, ``auto`` on one of its nodes), else a Ray instance started
here with ``--jobs`` CPUs and shut down at the end. An instance already initialised in
this process (``ray.init`` by the caller) is used as it is.

The episodes' files: a task reloads the campaign, its scenarios and missions from the
campaign's absolute path, as the local worker processes do. On one machine that is all;
on a cluster of several machines that path must hold the same files on every node: a
shared file system, or the installed package's mission library (the same ``walkaround``
version installed on every node, the campaign run from
``<site-packages>/executive/_data/missions``). The files are not shipped with the tasks
(Ray's ``working_dir`` would upload the whole library on every run); instead each task
checks the campaign's digest, so an episode whose worker sees other files (or none)
becomes a ``crashed`` row saying so, and never a silently different result.

A task that raises, a worker that dies (killed, out of memory) or a lost node gives a
``crashed`` row like the local backend's; tasks are not retried.
"""

from __future__ import annotations

import contextlib
import logging
import os
import traceback
from collections import deque
from collections.abc import Generator, Iterator
from pathlib import Path
from types import ModuleType
from typing import Any

from executive.campaign.results import Row
from executive.campaign.runner import WORKER_ENV, _row_base, crashed_row, worker_row
from executive.campaign.spec import Campaign

INSTALL_HINT = "pip install 'walkaround[cluster]'"
IN_FLIGHT_PER_CPU = 2
"""Tasks submitted ahead per CPU of the cluster: enough to keep every CPU busy between
two rows, few enough that an interrupted campaign cancels little."""


class RayUnavailableError(RuntimeError):
    """Ray is not installed (the extra ``walkaround[cluster]``)."""


def ray_available() -> bool:
    """Whether ``import ray`` works here."""
    try:
        import ray  # noqa: F401
    except ImportError:
        return False
    return True


def require_ray() -> ModuleType:
    """The ``ray`` module, or :class:`RayUnavailableError` naming the extra to install."""
    try:
        import ray
    except ImportError as exc:
        raise RayUnavailableError(
            f"the Ray backend needs Ray, which is not installed: {INSTALL_HINT}"
        ) from exc
    return ray


@contextlib.contextmanager
def ray_session(jobs: int, address: str | None = None) -> Iterator[None]:
    """Ray initialised for this process while the block runs: the cluster at ``address``
    or ``RAY_ADDRESS``, else a local instance of ``jobs`` CPUs, shut down at the end; or
    the instance this process had already initialised, left running. Raises
    :class:`RayUnavailableError` without Ray; an unreachable cluster is ``ray.init``'s
    error (a ``ConnectionError``, after Ray's own connection timeout of minutes)."""
    ray = require_ray()
    if ray.is_initialized():
        yield
        return
    address = address or os.environ.get("RAY_ADDRESS") or None
    if address:
        ray.init(address=address, log_to_driver=False, logging_level=logging.WARNING)
    else:
        ray.init(
            num_cpus=max(1, jobs),
            include_dashboard=False,
            log_to_driver=False,
            logging_level=logging.WARNING,
        )
    try:
        yield
    finally:
        ray.shutdown()


def _episode_task(path: str, seed: int, index: int, max_time: float | None, digest: str) -> Row:
    """The body of one episode's task (in a Ray worker)."""
    return worker_row(path, seed, index, max_time, digest)


def ray_crashed_row(campaign: Campaign, index: int, exc: BaseException) -> Row:
    """The row of episode ``index`` whose task ended in ``exc`` instead of a row: the
    task raised (``RayTaskError``, whose ``cause`` is the exception), its worker died or
    its node was lost (any other error)."""
    cause = getattr(exc, "cause", None)
    if isinstance(cause, BaseException):
        text = f"{type(cause).__name__}: {cause}"
    else:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
        text = f"the Ray worker died or its task was lost ({type(exc).__name__}: {first})"
    return crashed_row(_row_base(campaign, index), text, "".join(traceback.format_exception(exc)))


def ray_rows(
    campaign: Campaign, path: str, todo: list[int], jobs: int, max_time: float | None
) -> Generator[Row, None, None]:
    """Rows of the episodes ``todo`` as their Ray tasks end (in no particular order);
    inside :func:`ray_session`. Closing the iterator early cancels the tasks in flight."""
    ray = require_ray()
    from ray.exceptions import RayError

    task = ray.remote(_episode_task).options(
        num_cpus=1, max_retries=0, runtime_env={"env_vars": dict(WORKER_ENV)}
    )
    where = str(Path(path).resolve())
    cpus = int(ray.cluster_resources().get("CPU", 0))
    limit = IN_FLIGHT_PER_CPU * max(1, jobs, cpus)
    queue = deque(todo)
    pending: dict[Any, int] = {}
    try:
        while queue or pending:
            while queue and len(pending) < limit:
                index = queue.popleft()
                pending[task.remote(where, campaign.seed, index, max_time, campaign.digest)] = index
            done, _ = ray.wait(list(pending), num_returns=1)
            for ref in done:
                index = pending.pop(ref)
                try:
                    row = ray.get(ref)
                except RayError as exc:
                    row = ray_crashed_row(campaign, index, exc)
                yield row
    finally:
        for ref in pending:  # interrupted: the running episodes' rows are lost anyway
            with contextlib.suppress(Exception):  # best effort: it may have just ended
                ray.cancel(ref, force=True)
