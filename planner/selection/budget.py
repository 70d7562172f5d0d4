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

A budget of hours (``max_field_time_h``) is a budget of stations too: no plan in it has more
stations than the hours hold setups and scans (the walk only adds), so the bound is the one
of that many stations, and the plan is the longest prefix of the order whose field time,
walk included, fits (:func:`best_in_time`).

Array letters: C candidates, F faces.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from planner.errors import ParameterError
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


class FieldClock(Protocol):
    """The field time of a set of stations (:class:`planner.survey.fieldwork.FieldClock`)."""

    # the setup and scan of one station, what every station costs: above 0 (a scan takes
    # its points over the measurement rate, or a setting's duration, both positive)
    per_station_s: float

    def seconds(self, stations: list[int]) -> float:
        """Setup, scans and the walk between the candidates ``stations``, seconds."""
        ...


@dataclass(frozen=True)
class TimeBudget:
    """How a budget of hours was spent: the plan's field time, the most stations the
    hours could hold, and what one station more (the order's next) would take."""

    max_s: float  # the budget
    plan_s: float  # the plan's field time (every station at the plan's step)
    at_most_stations: int  # setups and scans alone fill the budget beyond this
    per_station_s: float
    next_station_s: float | None  # the order's next prefix; None: no station left

    def to_dict(self) -> dict[str, Any]:
        def h(seconds: float | None) -> float | None:
            return None if seconds is None else round(seconds / 3600.0, 4)

        return {
            "max_field_time_h": h(self.max_s),
            "plan_field_time_h": h(self.plan_s),
            "within": self.plan_s <= self.max_s,
            "station_setup_and_scan_s": round(self.per_station_s, 1),
            "at_most_stations": self.at_most_stations,
            "one_station_more_field_time_h": h(self.next_station_s),
            "counts": "each station's setup and its scan at the plan's step, and the route's "
                      "walk; a station whose faces allow a coarser setting scans faster, so "
                      "field_time.total_s is at most plan_field_time_h",
        }


def longest_prefix_in_time(order: Selection, cap: int, max_s: float,
                           seconds_of: Callable[[list[int]], float], per_station_s: float
                           ) -> tuple[int, float, float | None]:
    """How many of ``order``'s first stations (at most ``cap``, at least its fixed ones) fit
    in ``max_s`` seconds of field time (``seconds_of``; ``per_station_s`` > 0 of it each
    station's, the rest the walk): a binary search, the field time growing with the
    stations; the count, its seconds, and those of one station more (None when the order
    has none). The cap's set is asked about first; a smaller start walks no farther, so
    the stations its walk leaves room for fit too, and the search starts from them."""
    known: dict[int, float] = {}

    def fits(k: int) -> bool:
        if k not in known:
            known[k] = seconds_of(list(order.stations[:k]))
        return known[k] <= max_s

    high = min(cap, len(order.stations))
    low = min(order.fixed, high)
    if fits(high):
        low = high
    else:
        walk_s = known[high] - per_station_s * high  # the largest start's walk
        guess = int((max_s - walk_s) // per_station_s)
        if low < guess < high and fits(guess):
            low = guess
    if low < high and fits(low):  # fits(low), not fits(high)
        while high - low > 1:
            middle = (low + high) // 2
            if fits(middle):
                low = middle
            else:
                high = middle
    nxt = low + 1
    if nxt <= len(order.stations):
        fits(nxt)
    return low, known[low], known.get(nxt)


def best_in_time(table: CoverageTable, order: Selection, max_stations: int | None,
                 max_s: float, clock: FieldClock, *, swaps: bool = True
                 ) -> tuple[Selection, list[Move], TimeBudget]:
    """The plan with the most coverage in ``max_s`` seconds of field time (and at most
    ``max_stations``): the longest prefix of ``order`` that fits, improved by swaps
    (``swaps``) when the swapped stations still fit; the plan, the swaps made, and how the
    time was spent. The fixed stations are always kept (``within`` is false when they alone
    take longer); a budget whose first station's walk from the route's start does not fit
    raises :class:`~planner.errors.ParameterError`."""
    at_most = int(max_s // clock.per_station_s)
    cap = at_most if max_stations is None else min(max_stations, at_most)
    count, plan_s, next_s = longest_prefix_in_time(order, max(cap, order.fixed), max_s,
                                                   clock.seconds, clock.per_station_s)
    if count == 0 and next_s is not None:  # one setup and scan fit: the walk to it does not
        raise ParameterError(
            "max_field_time_h", f"{max_s / 3600:g} h holds no station: the first takes "
            f"{next_s / 3600:.3f} h with the walk to it from route_start; raise it or move "
            "route_start")
    chosen, moves = best_in_budget(table, order, count, swaps=swaps)
    if moves:
        swapped_s = clock.seconds(list(chosen.stations))
        if swapped_s <= max_s:
            plan_s = swapped_s
        else:  # the swapped stations are farther apart: the prefix's walk fits, theirs not
            chosen, moves = first_stations(order, count), []
    return chosen, moves, TimeBudget(max_s, plan_s, max(cap, order.fixed),
                                     clock.per_station_s, next_s)


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


def budget_line(selection: dict[str, Any]) -> str | None:
    """What the command line says of a budget's plan, from ``plan.json``'s ``selection``:
    the bound, and for a budget of hours the plan's field time and one station more's;
    None without a budget."""
    budget = selection.get("budget")
    if budget is None:
        return None
    most = f"{100 * budget['upper_bound_fraction']:.1f} %"
    spent = budget.get("field_time")
    if spent is None:
        return f"budget {budget['max_stations']} stations: no plan of as many covers more " \
               f"than {most}"
    more = spent["one_station_more_field_time_h"]
    return (f"budget {spent['max_field_time_h']:g} h: the plan takes "
            f"{spent['plan_field_time_h']:.2f} h in the field"
            + ("" if spent["within"] else " (its fixed stations alone take longer)")
            + ("" if more is None else f", one station more {more:.2f} h")
            + f"; no plan in {spent['max_field_time_h']:g} h covers more than {most}")
