"""A campaign's results folder: ``campaign.json`` (which campaign, seed, shard),
``results.jsonl`` (one row per finished episode, appended and synced as each ends) and
``summary.json`` (success with its 95 % Wilson interval per mission and scenario,
failures grouped by cause, the worst checkpoints, collisions and near misses with the
episode that reproduces each).
"""

from __future__ import annotations

import json
import math
import os
import re
from collections import Counter, defaultdict
from collections.abc import Iterable
from pathlib import Path
from typing import IO

from executive.core.files import write_atomic
from executive.core.problems import InvalidInputError, Problem, SourceLocation

RESULTS_FILE = "results.jsonl"
SUMMARY_FILE = "summary.json"
CAMPAIGN_FILE = "campaign.json"
IDENTITY_KEYS = ("campaign", "digest", "seed")
"""What two result folders must share to hold rows of the same campaign."""
WORST_LISTED = 10
"""Checkpoints, collisions and near misses listed in the summary."""


Row = dict[str, object]


def append_row(handle: IO[str], row: Row) -> None:
    """Append one row and make it durable before the next episode is counted done."""
    handle.write(json.dumps(row, sort_keys=True) + "\n")
    handle.flush()
    os.fsync(handle.fileno())


def read_rows(path: Path, repair: bool = False) -> list[Row]:
    """The rows of a results file. A torn last line (a kill during a write) is dropped,
    and with ``repair`` cut off the file so that new rows follow the last whole one; any
    other unreadable line is an InvalidInputError at ``file:line``."""
    if not path.exists():
        return []
    data = path.read_bytes()
    rows: list[Row] = []
    lines = data.split(b"\n")
    good = 0
    for number, raw in enumerate(lines, start=1):
        last = number == len(lines)
        if not raw.strip():
            good += len(raw) + (0 if last else 1)
            continue
        try:
            row = json.loads(raw)
            if not isinstance(row, dict) or not isinstance(row.get("episode"), int):
                raise ValueError("not a result row")
        except ValueError as exc:
            if last or (number == len(lines) - 1 and not lines[-1]):
                break  # the torn last line of an interrupted write
            where = SourceLocation(str(path), number, 1)
            raise InvalidInputError([Problem(where, "bad-result-row", str(exc))]) from None
        rows.append(row)
        good += len(raw) + (0 if last else 1)
    if repair and good < len(data):
        with path.open("r+b") as handle:
            handle.truncate(good)
            handle.flush()
            os.fsync(handle.fileno())
    return rows


def write_json(path: Path, data: object) -> None:
    write_atomic(path, (json.dumps(data, indent=1, sort_keys=True) + "\n").encode("utf-8"))


def read_identity(folder: Path) -> dict[str, object] | None:
    """``campaign.json`` of a results folder, or None when there is none."""
    path = folder / CAMPAIGN_FILE
    if not path.exists():
        return None
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        where = SourceLocation(str(path), 1, 1)
        raise InvalidInputError([Problem(where, "bad-campaign-json", str(exc))]) from None
    if not isinstance(data, dict):
        where = SourceLocation(str(path), 1, 1)
        raise InvalidInputError([Problem(where, "bad-campaign-json", "not a JSON object")])
    return data


def same_campaign(a: dict[str, object], b: dict[str, object]) -> bool:
    return all(a.get(k) == b.get(k) for k in IDENTITY_KEYS)


class MergeError(ValueError):
    """Shards that cannot be merged (another campaign, seed or file version)."""


def merge_rows(shards: Iterable[Path]) -> tuple[dict[str, object], list[Row]]:
    """The identity and the rows of shard folders, one row per episode, sorted."""
    identity: dict[str, object] | None = None
    by_episode: dict[int, Row] = {}
    for folder in shards:
        ident = read_identity(folder)
        if ident is None:
            raise MergeError(f"{folder}: no {CAMPAIGN_FILE}: not a campaign results folder")
        if identity is None:
            identity = ident
        elif not same_campaign(identity, ident):
            what = ", ".join(
                f"{k} {ident.get(k)!r} (not {identity.get(k)!r})"
                for k in IDENTITY_KEYS
                if ident.get(k) != identity.get(k)
            )
            raise MergeError(f"{folder}: results of another campaign run: {what}")
        for row in read_rows(folder / RESULTS_FILE):
            by_episode.setdefault(int(row["episode"]), row)  # type: ignore[call-overload]
    if identity is None:
        raise MergeError("no shard folder given")
    merged = {k: v for k, v in identity.items() if k not in ("shard", "episodes")}
    return merged, [by_episode[k] for k in sorted(by_episode)]


# -- summary -----------------------------------------------------------------------------------
def wilson(successes: int, n: int, z: float = 1.96) -> tuple[float, float] | None:
    """The 95 % Wilson score interval of a success rate (fractions), None for n = 0."""
    if n == 0:
        return None
    p = successes / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return round(max(centre - half, 0.0), 4), round(min(centre + half, 1.0), 4)


_NUMBER = re.compile(r"(?<![\w.-])\d+(?:\.\d+)?")


def cause_group(cause: str) -> str:
    """A cause with its numbers (times, distances) replaced by '#', so that the same
    failure at another time groups with it; identifiers such as CP03 stay."""
    return _NUMBER.sub("#", cause)


def _rate(rows: list[Row]) -> dict[str, object]:
    n = len(rows)
    k = sum(bool(r.get("succeeded")) for r in rows)
    return {
        "episodes": n,
        "successes": k,
        "success_rate": round(k / n, 4) if n else None,
        "ci95": wilson(k, n),
    }


def summarise(identity: dict[str, object], rows: list[Row]) -> dict[str, object]:
    """The campaign's summary (module docstring)."""
    groups: dict[tuple[str, str], list[Row]] = defaultdict(list)
    for row in rows:
        groups[(str(row.get("mission")), str(row.get("scenario")))].append(row)
    causes: dict[str, list[int]] = defaultdict(list)
    examples: dict[str, str] = {}
    for row in rows:
        if row.get("succeeded"):
            continue
        text = str(row.get("first_cause") or row.get("outcome"))
        key = cause_group(text)
        causes[key].append(int(row["episode"]))  # type: ignore[call-overload]
        examples.setdefault(key, text)
    checkpoints = [
        {
            "episode": r["episode"],
            "scenario": r.get("scenario"),
            "checkpoint": r.get("worst_position_checkpoint"),
            "position_error": r.get("worst_position_error"),
            "heading_error_deg": r.get("worst_heading_error_deg"),
            "heading_checkpoint": r.get("worst_heading_checkpoint"),
        }
        for r in rows
        if r.get("worst_position_error") is not None
    ]
    checkpoints.sort(key=lambda c: -float(c["position_error"]))  # type: ignore[arg-type]
    collisions = [
        {"episode": r["episode"], **c}
        for r in rows
        for c in r.get("collisions", [])  # type: ignore[union-attr]
    ]
    near = [
        {
            "episode": r["episode"],
            "near_misses": r["near_misses"],
            "min_clearance": r.get("min_clearance"),
        }
        for r in rows
        if r.get("near_misses")
    ]
    return {
        **{k: identity.get(k) for k in ("campaign", "file", "seed", "digest")},
        **_rate(rows),
        "outcomes": dict(Counter(str(r.get("outcome")) for r in rows)),
        "by_scenario": [
            {"mission": m, "scenario": s, **_rate(group)}
            for (m, s), group in sorted(groups.items())
        ],
        "failures_by_cause": [
            {"cause": key, "example": examples[key], "count": len(eps), "episodes": eps}
            for key, eps in sorted(causes.items(), key=lambda kv: (-len(kv[1]), kv[0]))
        ],
        "worst_checkpoints": checkpoints[:WORST_LISTED],
        "collisions": collisions,
        "episodes_with_collision": sorted({int(c["episode"]) for c in collisions}),  # type: ignore[call-overload]
        "episodes_with_collision_robot_moving": sorted(
            {int(c["episode"]) for c in collisions if c.get("robot_moving", True)}  # type: ignore[call-overload]
        ),
        "near_misses": near,
        "crashed": [r["episode"] for r in rows if r.get("outcome") == "crashed"],
    }
