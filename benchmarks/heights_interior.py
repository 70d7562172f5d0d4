"""Stations saved by several instrument heights on a furnished interior.

Usage: python benchmarks/heights_interior.py [--rooms 4] [--goal 0.8] [--method greedy]

Builds the deterministic furnished floor of ``benchmarks/plan_scale.py`` (rooms of 6 x 5 x
3 m with tables, 2 m cabinets, columns or bins and clutter), reads it as ``scanplan plan``
does (faces split to 0.2 m as needed) and plans it with grid candidates at
``scanner_heights_m`` [1.5] (the paper's single height) and [1.2, 1.5, 1.8]. Prints per run:
candidates, achievable area, stations at the goal, the stations' heights and CPU seconds
(process time, all threads: the machine is shared, wall time is not a measure).
"""

from __future__ import annotations

import argparse
import collections
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.plan_scale import build_interior
from planner.io.readers import read_scene
from planner.parameters import PlanSpec
from planner.pipeline import plan


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rooms", type=int, default=4)
    parser.add_argument("--goal", type=float, default=0.8)
    parser.add_argument("--method", default="greedy")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        model = Path(tmp) / "interior.obj"
        build_interior(args.rooms).write_obj(model)
        for heights in ([1.5], [1.2, 1.5, 1.8]):
            scene = read_scene(model, split_faces="as_needed")
            spec = PlanSpec.from_mapping({"scanner_heights_m": heights,
                                          "coverage_goal": args.goal, "method": args.method})
            cpu = time.process_time()
            result = plan(scene, spec)
            cpu = time.process_time() - cpu
            assert result.candidates.heights_m is not None
            used = collections.Counter(float(result.candidates.heights_m[c])
                                       for c in result.chosen.stations)
            print(f"heights {heights}: {len(result.candidates)} candidates, achievable "
                  f"{result.table.max_achievable_area_m2:.2f} m2, "
                  f"{len(result.chosen.stations)} stations at goal {args.goal} "
                  f"(heights used {dict(sorted(used.items()))}), covered "
                  f"{result.chosen.covered_area_m2[-1]:.2f} m2, CPU {cpu:.1f} s", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
