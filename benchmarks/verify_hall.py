"""Plan the hall scenes with both coverage models and check each plan by a simulated scan.

Usage: python benchmarks/verify_hall.py [--scenes hall-small hall-full] [--models centroid
sampled] [--threads N] [--min-sampled-fraction F]

For every scene and model (candidates.csv, mesh as given, greedy, goal 0.8, the paper's
parameters) prints stations, promised and delivered area, false promises (promised but not
delivered), misses (delivered but not promised), holes, and the seconds of the plan and of
the verification. Timings are wall clock on whatever else the machine is doing.
"""

from __future__ import annotations

import argparse
import resource
import time
from pathlib import Path

import numpy as np

from planner.candidates.grid import read_candidates_csv
from planner.io.readers import read_scene
from planner.parameters import COVERAGE_MODELS, PlanSpec
from planner.pipeline import plan
from planner.truth.verification import verify

SHARED = Path(__file__).resolve().parents[1].parent / "shared"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="+", default=["hall-small", "hall-full"])
    parser.add_argument("--models", nargs="+", default=list(COVERAGE_MODELS),
                        choices=COVERAGE_MODELS)
    parser.add_argument("--threads", type=int, default=None)
    parser.add_argument("--min-sampled-fraction", type=float, default=1.0)
    args = parser.parse_args()
    header = (f"{'scene':<11} {'model':<9} {'stations':>8} {'promised':>10} {'delivered':>10} "
              f"{'false m2':>9} {'false %':>8} {'misses':>8} {'holes':>7} {'plan s':>7} "
              f"{'verify s':>8}")
    print(header)
    for name in args.scenes:
        scene_dir = SHARED / "scenes" / name
        scene = read_scene(scene_dir / "hall.obj", max_edge_m=None)
        candidates = read_candidates_csv(scene_dir / "candidates.csv")
        for model in args.models:
            spec = PlanSpec(candidates=tuple(map(tuple, candidates.tolist())),
                            max_edge_m=None, coverage_model=model,
                            min_sampled_fraction=args.min_sampled_fraction)
            t0 = time.perf_counter()
            result = plan(scene, spec, threads=args.threads)
            t1 = time.perf_counter()
            stations = result.candidates.positions[np.asarray(result.chosen.stations, int)]
            checked = verify(scene, spec, stations, result.faces["covered"].astype(bool),
                             threads=args.threads)
            t2 = time.perf_counter()
            totals = checked.totals()
            print(f"{name:<11} {model:<9} {len(stations):>8} "
                  f"{totals['promised_area_m2']:>10.2f} {totals['delivered_area_m2']:>10.2f} "
                  f"{totals['promised_not_delivered_area_m2']:>9.3f} "
                  f"{100 * totals['promised_not_delivered_fraction']:>8.3f} "
                  f"{totals['delivered_not_promised_area_m2']:>8.2f} "
                  f"{totals['hole_area_m2']:>7.3f} {t1 - t0:>7.1f} {t2 - t1:>8.1f}",
                  flush=True)
    peak_gb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6
    print(f"peak RSS {peak_gb:.2f} GB")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
