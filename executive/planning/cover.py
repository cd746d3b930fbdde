"""A small set of checkpoints that inspects every coverable item: weighted set cover.

The universe is the items some candidate sees (:mod:`executive.planning.candidates`); each
candidate pose is the set of items it sees. A checkpoint costs a stop
(:data:`STOP_COST`) plus a little per metre of viewing distance (:data:`DISTANCE_COST`:
closer views have more pixels on the feature and more margin to the detection range).

1. **Greedy** (Chvatal 1979, the ln(n)-approximation): repeatedly take the candidate with
   the most newly covered items per unit of cost.
2. **Local improvement**: drop any checkpoint whose items the others all see (costliest
   first), then replace any two checkpoints by one candidate that sees every item only
   they saw, while that is possible (each pass removes a stop, so it ends).
3. **Assignment**: each item goes to the chosen checkpoint that sees it from nearest.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from executive.planning.candidates import CandidateViews

STOP_COST = 1.0
"""Cost of one checkpoint (stopping, turning, aiming)."""

DISTANCE_COST = 0.02
"""Cost per metre of mean viewing distance of a checkpoint's items."""


@dataclass(frozen=True)
class Cover:
    """Chosen candidate rows and, for each, the item columns it inspects (in file order)."""

    chosen: tuple[int, ...]
    assigned: tuple[tuple[int, ...], ...]
    uncovered: tuple[int, ...]


def _cost(views: CandidateViews, row: int, cols: np.ndarray) -> float:
    if not cols.any():
        return STOP_COST
    return STOP_COST + DISTANCE_COST * float(views.distance[row, cols].mean())


def greedy_cover(views: CandidateViews) -> list[int]:
    """Rows of a greedy weighted cover of every item some candidate sees."""
    sees = views.sees
    todo = sees.any(axis=0)
    chosen: list[int] = []
    dist = np.where(sees, views.distance, 0.0)
    while todo.any():
        new = sees & todo
        gain = new.sum(axis=1)
        mean_dist = (dist * new).sum(axis=1) / np.maximum(gain, 1)
        ratio = gain / (STOP_COST + DISTANCE_COST * mean_dist)
        best = int(np.argmax(ratio))
        chosen.append(best)
        todo &= ~sees[best]
    return chosen


def drop_redundant(views: CandidateViews, chosen: list[int]) -> list[int]:
    """Remove checkpoints whose items the others see, costliest first."""
    kept = list(chosen)
    order = sorted(kept, key=lambda r: -_cost(views, r, views.sees[r]))
    for row in order:
        others = [r for r in kept if r != row]
        if not others:
            break
        if not (views.sees[row] & ~views.sees[others].any(axis=0)).any():
            kept = others
    return kept


def merge_pairs(views: CandidateViews, chosen: list[int]) -> list[int]:
    """Replace two checkpoints by one candidate seeing every item only they saw."""
    sees = views.sees
    kept = list(chosen)
    improved = True
    while improved and len(kept) > 1:
        improved = False
        for a, b in itertools.combinations(kept, 2):
            rest = [r for r in kept if r not in (a, b)]
            covered = sees[rest].any(axis=0) if rest else np.zeros(sees.shape[1], dtype=bool)
            need = (sees[a] | sees[b]) & ~covered
            able = sees[:, need].all(axis=1)
            if not able.any():
                continue
            rows = np.flatnonzero(able)
            costs = [_cost(views, int(r), need) for r in rows]
            kept = [*rest, int(rows[int(np.argmin(costs))])]
            improved = True
            break
    return kept


def assign(views: CandidateViews, chosen: list[int]) -> Cover:
    """Each coverable item to the chosen checkpoint that sees it from nearest."""
    m = views.sees.shape[1]
    assigned: dict[int, list[int]] = {r: [] for r in chosen}
    uncovered = []
    for col in range(m):
        rows = [r for r in chosen if views.sees[r, col]]
        if not rows:
            uncovered.append(col)
            continue
        best = min(rows, key=lambda r: views.distance[r, col])
        assigned[best].append(col)
    rows = [r for r in chosen if assigned[r]]
    return Cover(tuple(rows), tuple(tuple(assigned[r]) for r in rows), tuple(uncovered))


def set_cover(views: CandidateViews) -> Cover:
    """Greedy weighted set cover, then local improvement, then assignment."""
    chosen = greedy_cover(views)
    chosen = drop_redundant(views, chosen)
    chosen = merge_pairs(views, chosen)
    chosen = drop_redundant(views, chosen)
    return assign(views, chosen)
