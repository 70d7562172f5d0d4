"""The selection stage: the plan's stations from the coverage table, registrable if asked.

Takes the coverage table, the (C, 3) candidate positions and the fixed stations; gives a
:class:`Choice`: every method's full order, the chosen stations up to the goal (the plan's
method; with ``min_overlap_m2`` a network every station registers into) and, when they
were computed, the stations' overlap rows, which the survey reuses.

Array letters: C candidates, F faces, S stations.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from planner.progress import ProgressCallback, Stats, notify
from planner.selection.budget import FieldClock, best_in_budget, best_in_time, budget_report
from planner.selection.connected import connected_greedy, overlap_graph
from planner.selection.connectivity import Connectivity
from planner.selection.greedy import Selection
from planner.selection.optimal import SelectionOutcome, choose_stations
from planner.visibility.coverage import CoverageTable
from planner.visibility.overlap import OverlapRows, RowsFanout
from planner.visibility.qualify import Sight


@dataclass(frozen=True, eq=False)
class Choice:
    """What the selection stage decided.

    Attributes
    ----------
    outcome : every method's order, the optimal result and its curve, the report
    chosen : the plan: the chosen method up to the goal (registrable with
        ``min_overlap_m2``)
    station_overlap : (S, F) CSR of the chosen stations' overlap rows, when the selection
        computed them (``min_overlap_m2`` set), else None
    """

    outcome: SelectionOutcome
    chosen: Selection
    station_overlap: sp.csr_matrix | None


def choose(sight: Sight, table: CoverageTable, positions: np.ndarray, fixed: tuple[int, ...],
           stats: Stats, *, progress: ProgressCallback | None = None,
           threads: int | None = None, fanout: RowsFanout | None = None,
           overlap: Sight | None = None, clock: FieldClock | None = None) -> Choice:
    """The stations of the plan under ``sight.spec`` (method, goal, overlap, budget); the
    overlap rows are measured on the pieces of ``overlap`` (default: the coverage's,
    ``sight``) and computed by ``fanout`` when given (a cluster); ``clock``: the field time
    of a set of stations, for a budget of hours (``max_field_time_h``)."""
    spec = sight.spec
    pieces = sight if overlap is None else overlap
    started = time.perf_counter()
    rows = None
    connectivity = None
    min_overlap_m2 = spec.min_overlap_m2
    if min_overlap_m2 is not None:
        # the overlap rows (faces each candidate qualifies for at the overlap density) are
        # computed when a method first needs them: the connected greedy asks for a few
        rows = OverlapRows(pieces.scene, positions, pieces.limits, pieces.occlusion,
                           spec.overlap_density_pts_m2, threads=threads,
                           file_faces=pieces.file_faces, fanout=fanout)
        if spec.method == "optimal" and not fixed:
            # optimal keeps the overlap graph connected: a flow MILP from connected greedy,
            # on the graph of every candidate's row
            t_graph = time.perf_counter()
            top_goal = max((spec.coverage_goal, *(spec.curve_goals or ())))
            connectivity = Connectivity(
                overlap_graph(rows.matrix(range(len(rows))), rows.scene, min_overlap_m2),
                *(connected_greedy(table, rows, rows.scene, positions,
                                   min_overlap_m2, weighted=w, goal=top_goal)
                  for w in (False, True)))
            stats.seconds["overlap_graph"] = time.perf_counter() - t_graph - rows.seconds
    outcome = choose_stations(
        table, method=spec.method, goal=spec.coverage_goal,
        time_limit_s=spec.optimal_time_limit_s, centroids_of=sight.scene.centroids_of, fixed=fixed,
        curve_goals=spec.curve_goals,
        progress=lambda fraction: notify(progress, "selection", fraction),
        connectivity=connectivity)
    chosen = outcome.chosen
    budget = spec.max_stations
    hours = spec.max_field_time_h
    if hours is not None and clock is None:
        raise ValueError("a budget of hours needs the field clock (planner.pipeline)")
    budgeted = budget is not None or hours is not None
    order = outcome.selections.get(spec.method)
    station_overlap = None
    if rows is not None and min_overlap_m2 is not None and spec.method != "optimal":
        # registration constraint: every station after the first overlaps a chosen one
        order = connected_greedy(
            table, rows, rows.scene, positions, min_overlap_m2,
            weighted=spec.method == "weighted_greedy",
            goal=1.0 if budgeted else spec.coverage_goal)
        chosen = order.truncated(spec.coverage_goal)
    if budgeted and order is not None:
        # a budget: the most coverage in that many stations (or hours), the goal reached or
        # not; swaps would not keep a registrable plan connected
        spent = None
        if hours is not None and clock is not None:
            chosen, swaps, spent = best_in_time(table, order, budget, hours * 3600.0, clock,
                                                swaps=rows is None)
            budget = spent.at_most_stations  # what the bound is over
        else:
            assert budget is not None
            chosen, swaps = best_in_budget(table, order, budget, swaps=rows is None)
        report = outcome.report
        n, lower = len(chosen.stations), int(report["lower_bound"])
        others = tuple(s for s in outcome.selections.values() if s is not order)
        report["budget"] = {**budget_report(table, chosen, order, budget, others,
                                            tuple(swaps)),
                            "goal_needs_at_least": lower}
        if spent is not None:
            report["budget"]["field_time"] = spent.to_dict()
        report["stations"] = n
        report["gap"] = round(max(0.0, (n - lower) / n), 6) if n else 0.0
        report["proven_optimal"] = False
    if rows is not None and min_overlap_m2 is not None:
        station_overlap = rows.matrix(list(chosen.stations))
        stats.seconds["overlap"] = rows.seconds
        stats.overlap_rows = rows.n_computed
        rows = None  # its cached rows (and bundles) are not needed any more
    # selection without the overlap rows and the field-time budget's routes computed in it
    stats.seconds["selection"] = time.perf_counter() - started - stats.seconds.get(
        "overlap", 0.0) - stats.seconds.get("walk graph", 0.0)
    for step, seconds in outcome.seconds.items():
        stats.seconds[f"selection_{step}"] = seconds
    return Choice(outcome, chosen, station_overlap)
