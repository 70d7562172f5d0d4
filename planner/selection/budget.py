"""A budget of stations: the plan with the most coverage in ``max_stations``.

Greedy maximum coverage: the first ``max_stations`` stations of the greedy (or weighted
greedy) order, whether or not they reach the coverage goal. Coverage is a monotone
submodular function of the stations, so greedy reaches at least 1 - 1/e of the best
``k`` stations' coverage (Nemhauser, Wolsey & Fisher, "An analysis of approximations for
maximizing submodular set functions", Math. Programming 14, 1978); the report gives the
sharper bound that the same submodularity gives from the plan itself: no ``k`` stations
cover more than the plan's area plus the ``k`` largest areas a single station would add to
it (ibid., and Minoux's accelerated greedy, 1978).

Array letters: C candidates, F faces.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from planner.selection.greedy import GAIN_QUANTUM_M2, Selection
from planner.visibility.coverage import CoverageTable


def first_stations(order: Selection, max_stations: int) -> Selection:
    """The first ``max_stations`` stations of ``order`` (all of them when it has fewer)."""
    n = min(max_stations, len(order.stations))
    return Selection(order.method, order.stations[:n], order.new_area_m2[:n],
                     order.covered_area_m2[:n], order.max_achievable_area_m2, order.fixed)


def budget_report(table: CoverageTable, order: Selection, max_stations: int
                  ) -> dict[str, Any]:
    """plan.json's ``selection.budget``: what the budget's plan covers, a bound on what any
    ``max_stations`` stations could, and what one station more would add."""
    plan = first_stations(order, max_stations)
    covered = plan.covered_area_m2[-1] if plan.stations else 0.0
    uncovered = ~table.covered_by(plan.stations)
    gains = table.sum_per_candidate(table.face_area_m2 * uncovered)  # (C,) beyond the plan
    top = np.sort(gains)[::-1][:max_stations]
    achievable = table.max_achievable_area_m2
    bound = min(achievable, covered + float(top.sum()))
    if order.method == "greedy" and not order.fixed and plan.stations:
        # greedy on area, from nothing: at least 1 - 1/e of the best k stations' area (its
        # gains are whole units of GAIN_QUANTUM_M2 a face: add their rounding, half a unit
        # a face, to stay a bound)
        rounding_m2 = 0.5 * GAIN_QUANTUM_M2 * table.n_faces
        bound = min(bound, (covered + rounding_m2) / (1.0 - 1.0 / math.e))
    n = len(plan.stations)
    return {
        "max_stations": max_stations,
        "stations": n,
        "covered_area_m2": round(covered, 3),
        "coverage_fraction": round(covered / achievable, 6) if achievable else 0.0,
        "upper_bound_area_m2": round(bound, 3),
        "upper_bound_fraction": round(bound / achievable, 6) if achievable else 0.0,
        "bound": "no max_stations stations cover more than the plan's area plus the "
                 "max_stations largest areas one station adds to it, nor (greedy from no "
                 "fixed station) more than its area / (1 - 1/e): coverage is submodular",
        "next_station_gain_m2": round(order.new_area_m2[n], 3) if n < len(order.stations)
        else 0.0,
    }
