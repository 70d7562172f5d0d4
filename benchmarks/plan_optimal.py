"""Greedy, weighted greedy and optimal on the halls at goals 80, 90, 95 and 100 %.

Usage: python benchmarks/plan_optimal.py [--scenes hall-small hall-full]
       [--goals 0.8 0.9 0.95 1.0] [--time-limit 60]

Builds each hall's coverage table once (its candidates.csv, the mesh as given, the paper's
parameters), then runs the selection stage with ``method: optimal`` per goal and prints
stations per method, the proven lower bound, the gap, whether it is proven and the wall
seconds of the selection stage (the limit must hold: seconds <= limit + 5 %). Timings
depend on the machine and its load; take the best of a few runs.
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
from pathlib import Path

from planner.candidates.grid import read_candidates_csv
from planner.io.readers import read_scene
from planner.parameters import PlanSpec
from planner.pipeline import plan
from planner.selection.optimal import choose_stations

SHARED = Path(__file__).resolve().parents[1].parent / "shared"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="+", default=["hall-small", "hall-full"])
    parser.add_argument("--goals", nargs="+", type=float, default=[0.8, 0.9, 0.95, 1.0])
    parser.add_argument("--time-limit", type=float, default=60.0,
                        help="optimal_time_limit_s (default: the planner's default, 60)")
    args = parser.parse_args()
    # the coverage table of hall-full takes ~1 GB; stop rather than swap a shared machine
    resource.setrlimit(resource.RLIMIT_AS, (8 << 30, 8 << 30))
    print(f"{'scene':<11} {'goal':>5} {'greedy':>6} {'weighted':>8} {'optimal':>7} "
          f"{'bound':>5} {'gap':>6} {'proven':>6} {'seconds':>8}  status")
    for name in args.scenes:
        folder = SHARED / "scenes" / name
        scene = read_scene(folder / "hall.obj", max_edge_m=None)
        candidates = read_candidates_csv(folder / "candidates.csv")
        result = plan(scene, PlanSpec(candidates=tuple(map(tuple, candidates.tolist())),
                                      max_edge_m=None), keep_table=True)
        for goal in args.goals:
            started = time.perf_counter()
            outcome = choose_stations(result.table, method="optimal", goal=goal,
                                      time_limit_s=args.time_limit,
                                      centroids_of=scene.centroids_of)
            seconds = time.perf_counter() - started
            report = outcome.report
            print(f"{name:<11} {goal:>5.2f} {report['heuristics']['greedy']:>6} "
                  f"{report['heuristics']['weighted_greedy']:>8} {report['stations']:>7} "
                  f"{report['lower_bound']:>5} {report['gap']:>6.3f} "
                  f"{'yes' if report['proven_optimal'] else 'no':>6} {seconds:>8.2f}  "
                  f"{report['status']}",
                  flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
