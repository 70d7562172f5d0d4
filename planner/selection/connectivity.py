"""Registration connectivity for ``optimal``: a single-commodity flow on the overlap graph.

With ``min_overlap_m2`` set, the chosen stations must form one connected registration
overlap graph (an edge where two candidates overlap: see
:mod:`planner.survey.registration`, whose test builds the graph). Following Dehbi et al.
(2021), the MILP gets, besides its coverage rows, a single-commodity flow over the
candidate overlap graph (K = the incumbent's station count, plans with more stations are
of no interest):

- ``r_c`` binary, ``sum_c r_c = 1``, ``r_c <= x_c``: one chosen station is the root;
- ``g_c`` in [0, K], ``g_c <= K r_c``: the root's supply;
- ``f_ab, f_ba`` in [0, K - 1] on every overlap edge, ``f <= (K - 1) x`` at both ends;
- at every candidate ``g_c + inflow_c - outflow_c = x_c``: each chosen station absorbs
  one unit, so the root sends ``sum x - 1`` and every unit travels along overlap edges
  between chosen stations only: the chosen stations are connected.

The incumbent (the connected greedy plan) becomes a full MIP start: root = its lowest
candidate, flows = subtree sizes of the breadth-first tree. Graphs with more than
MAX_FLOW_EDGES edges are not formulated (the program would outlast any time limit); the
plan is then the connected greedy one, improved by connectivity-keeping local search.

Array letters: C candidates, E overlap edges.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.sparse.csgraph import breadth_first_order, connected_components

from planner.selection.greedy import Selection
from planner.selection.program import ProgramBuilder

# above this many overlap edges (4 rows and 2 variables each) the MILP is not attempted
MAX_FLOW_EDGES = 50_000


@dataclass(frozen=True)
class OverlapGraph:
    """Which candidates overlap: ``edges`` (E, 2) int64, a < b, sorted, no duplicates."""

    n_candidates: int
    edges: NDArray[np.int64]

    @property
    def adjacency(self) -> sp.csr_matrix:
        """(C, C) CSR float64 of 1.0, symmetric."""
        a, b = self.edges[:, 0], self.edges[:, 1]
        n = self.n_candidates
        ones = np.ones(2 * len(a))
        return sp.csr_matrix((ones, (np.concatenate([a, b]), np.concatenate([b, a]))),
                             shape=(n, n))

    @property
    def too_big(self) -> bool:
        """More edges than MAX_FLOW_EDGES: no flow MILP."""
        return len(self.edges) > MAX_FLOW_EDGES

    def connected(self, stations: Sequence[int]) -> bool:
        """Whether ``stations`` (candidate indices) form one connected overlap graph."""
        chosen = np.unique(np.asarray(stations, np.int64))
        if len(chosen) <= 1:
            return True
        sub = self.adjacency[chosen][:, chosen]
        count, _ = connected_components(sub, directed=False)
        return bool(count == 1)


@dataclass(frozen=True)
class Connectivity:
    """The constraint for :func:`planner.selection.optimal.choose_stations`: the candidate
    overlap graph and the connected greedy plans (greedy, weighted greedy) to start from."""

    graph: OverlapGraph
    greedy: Selection
    weighted_greedy: Selection

    def report(self) -> dict[str, object]:
        """plan.json ``selection.connectivity`` (how optimal kept the plan connected)."""
        edges = len(self.graph.edges)
        if self.graph.too_big:
            return {"formulation": "connected_greedy", "overlap_edges": edges,
                    "note": f"{edges} overlap edges exceed {MAX_FLOW_EDGES}: no flow MILP, "
                            "the connected greedy plan after connectivity-keeping local search"}
        return {"formulation": "flow", "overlap_edges": edges, "note": None}


def flow_start(graph: OverlapGraph, chosen: NDArray[np.int64], capacity: int
               ) -> NDArray[np.float64] | None:
    """(2 C + 2 E,) values of (r, g, f) for the connected set ``chosen``, or None.

    Root: the lowest chosen candidate; arc flows: subtree sizes of the breadth-first tree
    over the chosen stations' overlap graph (deterministic: scipy visits in index order).
    """
    n, n_edges = graph.n_candidates, len(graph.edges)
    values = np.zeros(2 * n + 2 * n_edges)
    if len(chosen) == 0 or len(chosen) > capacity:
        return None
    sub = graph.adjacency[chosen][:, chosen]
    order, parent = breadth_first_order(sub, 0, directed=False, return_predecessors=True)
    if len(order) != len(chosen):
        return None  # not connected
    size = np.ones(len(chosen))
    arc = {(int(a), int(b)): e for e, (a, b) in enumerate(graph.edges)}
    for node in order[:0:-1]:  # leaves first; the root (order[0]) has no parent
        up = int(parent[node])
        size[up] += size[node]
        a, b = int(chosen[up]), int(chosen[node])
        e = arc[(min(a, b), max(a, b))]
        values[2 * n + 2 * e + (0 if a < b else 1)] = size[node]
    root = int(chosen[0])
    values[root] = 1.0
    values[n + root] = float(len(chosen))
    return values


def add_flow(builder: ProgramBuilder, graph: OverlapGraph, capacity: int) -> None:
    """Add the flow rows and variables (module docstring) to ``builder``.

    ``capacity`` K: the most stations a plan of interest has (the incumbent's count).
    Extends ``builder.start`` (x of the candidates) to the new variables when it is a
    connected plan.
    """
    n, edges = graph.n_candidates, graph.edges
    n_edges = len(edges)
    k = float(max(capacity, 1))
    x_start = builder.start
    r0 = builder.add_variables(np.zeros(n), integer=True, lower=0.0, upper=1.0)
    g0 = builder.add_variables(np.zeros(n), integer=False, lower=0.0, upper=k)
    # arcs: 2e = a -> b, 2e + 1 = b -> a
    f0 = builder.add_variables(np.zeros(2 * n_edges), integer=False, lower=0.0,
                               upper=max(k - 1.0, 0.0))
    width = builder.n_variables
    cand = np.arange(n)
    arcs = np.arange(2 * n_edges)
    tail = np.empty(2 * n_edges, np.int64)  # (2E,) where each arc starts
    head = np.empty(2 * n_edges, np.int64)
    tail[0::2], head[0::2] = edges[:, 0], edges[:, 1]
    tail[1::2], head[1::2] = edges[:, 1], edges[:, 0]

    def rows(r: NDArray[np.int64], c: NDArray[np.int64], v: NDArray[np.float64],
             n_rows: int) -> sp.csr_matrix:
        return sp.csr_matrix((v, (r, c)), shape=(n_rows, width))

    # sum r = 1
    builder.add_rows(rows(np.zeros(n, np.int64), r0 + cand, np.ones(n), 1), 1.0, 1.0)
    # r_c - x_c <= 0 and g_c - K r_c <= 0
    builder.add_rows(rows(np.repeat(cand, 2), np.stack([r0 + cand, cand], 1).reshape(-1),
                          np.tile([1.0, -1.0], n), n), -np.inf, 0.0)
    builder.add_rows(rows(np.repeat(cand, 2), np.stack([g0 + cand, r0 + cand], 1).reshape(-1),
                          np.tile([1.0, -k], n), n), -np.inf, 0.0)
    # g_c + inflow_c - outflow_c - x_c = 0
    node_rows = np.concatenate([cand, head, tail, cand])
    node_cols = np.concatenate([g0 + cand, f0 + arcs, f0 + arcs, cand])
    node_vals = np.concatenate([np.ones(n), np.ones(2 * n_edges), -np.ones(2 * n_edges),
                                -np.ones(n)])
    builder.add_rows(rows(node_rows, node_cols, node_vals, n), 0.0, 0.0)
    # f_arc - (K - 1) x_end <= 0 at both ends
    for end in (tail, head):
        builder.add_rows(rows(np.repeat(arcs, 2), np.stack([f0 + arcs, end], 1).reshape(-1),
                              np.tile([1.0, -(k - 1.0)], 2 * n_edges), 2 * n_edges),
                         -np.inf, 0.0)
    if x_start is not None and len(x_start) == r0:
        extra = flow_start(graph, np.flatnonzero(x_start[:n] > 0.5), int(k))
        builder.start = None if extra is None else np.concatenate([x_start, extra])
