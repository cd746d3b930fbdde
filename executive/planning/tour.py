"""A short tour through the checkpoints that drives round the footprint and the zones.

Distances are shortest paths in a visibility graph (Lozano-Perez and Wesley 1979): its
nodes are the tour's stops and the corners of a polygon round the region where the robot
may not stop (:class:`executive.planning.space.FreeSpace`), its edges the straight legs
that keep the validator's leg clearance. Shortest paths by Dijkstra
(:func:`scipy.sparse.csgraph.shortest_path`); the corners a path turns at become the via
points of the checkpoint it leads to (or the return waypoints).

The order: nearest neighbour from the handover point P, then 2-opt on the closed tour
P -> ... -> P (Croes 1958) until no exchange of two legs shortens it. A closed tour is as
long one way round as the other; the planner drives it in the direction that best follows
the aircraft file's item order (the walk-around order of the flight crew operating manual
that the shipped aircraft files list their items in, seed 000 figure 2.4: the thesis'
inspection starts at the left forward fuselage and goes round the nose).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.sparse.csgraph import shortest_path

from executive.core.frames import FloatArray
from executive.planning.space import FreeSpace

TWO_OPT_ROUNDS = 200
"""Upper bound on improving 2-opt passes (each shortens the tour; it stops far sooner)."""


@dataclass(frozen=True)
class Roadmap:
    """Shortest paths between the terminals (the first ``n`` nodes) of a visibility graph."""

    nodes: FloatArray
    n: int
    dist: FloatArray
    pred: np.ndarray

    def length(self, a: int, b: int) -> float:
        return float(self.dist[a, b])

    def corners(self, a: int, b: int) -> list[tuple[float, float]]:
        """The intermediate nodes of the shortest path from terminal a to terminal b."""
        path = []
        k = int(self.pred[a, b])
        while k >= 0 and k != a:
            path.append((float(self.nodes[k, 0]), float(self.nodes[k, 1])))
            k = int(self.pred[a, k])
        return path[::-1]


def roadmap(space: FreeSpace, terminals: FloatArray) -> Roadmap:
    """The visibility graph over ``terminals`` (n, 2) and the space's corners, solved."""
    nodes = np.concatenate([np.asarray(terminals, dtype=float), space.corners])
    n_all = len(nodes)
    i, j = np.triu_indices(n_all, k=1)
    ok = space.can_drive(nodes[i], nodes[j]) if len(i) else np.zeros(0, dtype=bool)
    weights = np.zeros((n_all, n_all))
    lengths = np.hypot(*(nodes[j] - nodes[i]).T)
    weights[i[ok], j[ok]] = np.maximum(lengths[ok], 1e-9)
    weights[j[ok], i[ok]] = weights[i[ok], j[ok]]
    n = len(terminals)
    dist, pred = shortest_path(
        weights, method="D", directed=False, indices=np.arange(n), return_predecessors=True
    )
    return Roadmap(nodes, n, dist[:, :], pred)


def nearest_neighbour(dist: FloatArray) -> list[int]:
    """A tour from terminal 0 (P): always the nearest unvisited terminal next."""
    n = dist.shape[0]
    tour, left = [0], set(range(1, n))
    while left:
        here = tour[-1]
        nxt = min(left, key=lambda k: (dist[here, k], k))
        tour.append(nxt)
        left.remove(nxt)
    return tour


def tour_length(dist: FloatArray, tour: list[int]) -> float:
    """Length of the closed tour (back to its first terminal)."""
    return float(sum(dist[a, b] for a, b in zip(tour, [*tour[1:], tour[0]], strict=True)))


def two_opt(dist: FloatArray, tour: list[int]) -> list[int]:
    """Reverse tour segments while that shortens the closed tour; terminal 0 stays first."""
    best = list(tour)
    n = len(best)
    for _ in range(TWO_OPT_ROUNDS):
        improved = False
        for a in range(0, n - 1):
            for b in range(a + 2, n if a > 0 else n - 1):
                p, q = best[a], best[a + 1]
                r, s = best[b], best[(b + 1) % n]
                delta = dist[p, r] + dist[q, s] - dist[p, q] - dist[r, s]
                if delta < -1e-9:
                    best[a + 1 : b + 1] = best[a + 1 : b + 1][::-1]
                    improved = True
        if not improved:
            break
    return best


def order_agreement(tour: list[int], rank: dict[int, float]) -> float:
    """How well visiting the terminals in ``tour`` order follows ``rank`` (terminal ->
    its first item's position in the aircraft file): Spearman's rho, 0 when undefined."""
    visits = [k for k in tour if k in rank]
    if len(visits) < 2:
        return 0.0
    order = np.arange(len(visits), dtype=float)
    ranks = np.argsort(np.argsort([rank[k] for k in visits])).astype(float)
    if np.std(ranks) == 0.0:
        return 0.0
    return float(np.corrcoef(order, ranks)[0, 1])


def plan_tour(dist: FloatArray, rank: dict[int, float]) -> list[int]:
    """Nearest neighbour + 2-opt from terminal 0, in the direction that follows ``rank``."""
    if dist.shape[0] <= 2:
        return list(range(dist.shape[0]))
    tour = two_opt(dist, nearest_neighbour(dist))
    reverse = [tour[0], *tour[1:][::-1]]
    if order_agreement(reverse, rank) > order_agreement(tour, rank):
        return reverse
    return tour


def unreachable(dist: FloatArray) -> list[int]:
    """Terminals with no clear path from terminal 0."""
    return [k for k in range(dist.shape[0]) if not math.isfinite(dist[0, k])]
