"""A budget of stations: the plan with the most coverage in ``max_stations``.

Greedy maximum coverage: the first ``max_stations`` stations of the greedy (or weighted
greedy) order, whether or not they reach the coverage goal, then swaps of one station for
another that covers more in its place (:func:`planner.selection.optimal.most_coverage`;
not for a plan that must stay registrable, whose order keeps it connected). Coverage is a
monotone submodular function of the stations, so greedy reaches at least 1 - 1/e of the
best ``k`` stations' coverage (Nemhauser, Wolsey & Fisher, "An analysis of approximations
for maximizing submodular set functions", Math. Programming 14, 1978); the same
submodularity bounds the best from the plan itself: no ``k`` stations cover more than the
plan's area plus the ``k`` largest areas a single station would add to it (ibid., and
Minoux's accelerated greedy, 1978). Both are loose where stations overlap much: the report
also gives the Lagrangian dual of the maximum-coverage LP
(:func:`planner.selection.lower_bound.coverage_upper_bound`), and the least of the three
is the bound. The Amersfoort sports hall, 20 stations: the plan covers 1,205 m², the
submodular bound says at most 1,616, the LP's 1,223.

Array letters: C candidates, F faces.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from planner.selection.greedy import GAIN_QUANTUM_M2, Selection, replay
from planner.selection.lower_bound import coverage_upper_bound
from planner.selection.optimal import Move, most_coverage
from planner.visibility.coverage import CoverageTable


def first_stations(order: Selection, max_stations: int) -> Selection:
    """The first ``max_stations`` stations of ``order`` (all of them when it has fewer)."""
    n = min(max_stations, len(order.stations))
    return Selection(order.method, order.stations[:n], order.new_area_m2[:n],
                     order.covered_area_m2[:n], order.max_achievable_area_m2, order.fixed)


def best_in_budget(table: CoverageTable, order: Selection, max_stations: int, *,
                   swaps: bool = True) -> tuple[Selection, list[Move]]:
    """The budget's plan: ``order``'s first ``max_stations`` stations, improved by swaps
    (``swaps``) when they cover more; the plan and the swaps made."""
    prefix = first_stations(order, max_stations)
    if not swaps or not prefix.stations:
        return prefix, []
    stations, moves = most_coverage(table, prefix.stations, prefix.fixed)
    if not moves:
        return prefix, []
    swapped = replay(table, stations, order.method, prefix.fixed)
    if swapped.covered_area_m2[-1] <= prefix.covered_area_m2[-1]:  # the classes' sums only
        return prefix, []
    return swapped, moves


def budget_report(table: CoverageTable, plan: Selection, order: Selection,
                  max_stations: int, others: tuple[Selection, ...] = (),
                  swaps: tuple[Move, ...] = ()) -> dict[str, Any]:
    """plan.json's ``selection.budget``: what the budget's ``plan`` (from ``order``, with
    ``swaps``) covers, a bound on what any ``max_stations`` stations could, and what one
    station more would add.

    ``others``: orders of other methods with the same fixed stations; the LP's bound starts
    from the most any known plan of ``max_stations`` covers (the closer to the best, the
    tighter: hall-small, 2 stations, 95.5 m² from greedy's 89.9 m², 100.1 from weighted
    greedy's).
    """
    covered = plan.covered_area_m2[-1] if plan.stations else 0.0
    uncovered = ~table.covered_by(plan.stations)
    gains = table.sum_per_candidate(table.face_area_m2 * uncovered)  # (C,) beyond the plan
    top = np.sort(gains)[::-1][:max_stations]
    achievable = table.max_achievable_area_m2
    submodular = min(achievable, covered + float(top.sum()))
    prefix = first_stations(order, max_stations)
    if order.method == "greedy" and not order.fixed and prefix.stations:
        # greedy on area, from nothing: at least 1 - 1/e of the best k stations' area (its
        # gains are whole units of GAIN_QUANTUM_M2 a face: add their rounding, half a unit
        # a face, to stay a bound)
        rounding_m2 = 0.5 * GAIN_QUANTUM_M2 * table.n_faces
        submodular = min(submodular, (prefix.covered_area_m2[-1] + rounding_m2)
                         / (1.0 - 1.0 / math.e))
    reached = max([covered, *(first_stations(other, max_stations).covered_area_m2[-1]
                              for other in others if other.stations)])
    lagrangian = coverage_upper_bound(table, max_stations, reached,
                                      fixed=plan.stations[:plan.fixed])
    bound = min(submodular, lagrangian.area_m2)
    n = len(plan.stations)
    return {
        "max_stations": max_stations,
        "stations": n,
        "covered_area_m2": round(covered, 3),
        "coverage_fraction": round(covered / achievable, 6) if achievable else 0.0,
        "upper_bound_area_m2": round(bound, 3),
        "upper_bound_fraction": round(bound / achievable, 6) if achievable else 0.0,
        "bound": "the least of: the plan's area plus the max_stations largest areas one "
                 "station adds to it, (greedy from no fixed station) its area / (1 - 1/e), "
                 "and the lagrangian dual of the maximum-coverage LP",
        "bounds": {"submodular_area_m2": round(submodular, 3),
                   "lagrangian": lagrangian.to_dict()},
        "swaps": [{"removed": list(m.removed), "added": list(m.added)} for m in swaps],
        "next_station_gain_m2": round(float(gains.max(initial=0.0)), 3),
    }
