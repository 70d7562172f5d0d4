"""What the placement tolerance report and robust planning cost, and whether more setups
change the report.

Usage: python benchmarks/tolerance_cost.py [--scene hall-full] [--robust]

On a shared hall (candidates.csv, mesh as given, greedy, goal 0.8) it prints

- the CPU seconds (process time, all threads: other jobs share the machine, so wall time
  is not a measure) of the default plan with ``placement_tolerance_m`` 0 (no report) and
  0.25 (the default), and of the tolerance stage alone;
- each station's worst loss with the documented setups (8 directions on the circle and
  the centre), with 16 directions, and with 16 directions plus an inner ring of 8 at half
  the radius (the report's stage run again with those setups);
- with ``--robust``: stations, covered and achievable area of ``robust: true``, and its CPU.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np

from planner.candidates.grid import read_candidates_csv
from planner.candidates.placement import displaced_positions, offsets_m
from planner.io.readers import read_scene
from planner.parameters import PlanSpec
from planner.pipeline import PlanResult, plan
from planner.rays import make_ray_caster
from planner.survey.tolerance import placement_tolerance
from planner.visibility.overlap import OverlapRows
from planner.visibility.qualify import Sight

SCENES = Path(__file__).resolve().parents[2] / "shared" / "scenes"


def run(name: str, **params: object) -> tuple[PlanResult, float]:
    folder = SCENES / name
    scene = read_scene(folder / "hall.obj", max_edge_m=None)
    candidates = read_candidates_csv(folder / "candidates.csv").tolist()
    spec = PlanSpec.from_mapping({"candidates": candidates, "max_edge_m": None, **params})
    cpu = time.process_time()
    result = plan(scene, spec, keep_table=True)
    return result, time.process_time() - cpu


def worst_losses(result: PlanResult, offsets: np.ndarray) -> list[float]:
    """Each station's worst loss with the given (K, 2) setups."""
    scene, spec, limits = result.scene, result.spec, result.limits
    stations = result.candidates.positions[list(result.chosen.stations)]
    caster = make_ray_caster(scene, limits.occludes)
    occlusion = caster  # the Embree caster is the occlusion test too
    overlap = OverlapRows(scene, stations, limits, occlusion,  # type: ignore[arg-type]
                          spec.overlap_density_pts_m2).matrix(range(len(stations)))
    report = placement_tolerance(
        scene, result.table, result.chosen.stations,
        displaced_positions(scene, stations, spec.placement_tolerance_m, spec.clearance_m,
                            caster, offsets),
        limits, Sight(scene, spec, limits, occlusion, "embree").qualifier(),
        tolerance_m=spec.placement_tolerance_m,
        covered_area_m2=result.chosen.covered_area_m2[-1],
        goal_area_m2=spec.coverage_goal * result.table.max_achievable_area_m2,
        station_overlap=overlap, min_overlap_m2=spec.min_overlap_m2,
        overlap_density_pts_m2=spec.overlap_density_pts_m2,
        occlusion=occlusion, file_faces=True)  # type: ignore[arg-type]
    return [round(s.worst_loss_m2, 3) for s in report.stations]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="hall-full")
    parser.add_argument("--robust", action="store_true")
    args = parser.parse_args()
    _, cpu_off = run(args.scene, placement_tolerance_m=0)
    result, cpu_on = run(args.scene)
    stage = result.stats.cpu_seconds["tolerance"]
    print(f"{args.scene}: default plan CPU {cpu_off:.2f} s without the report, {cpu_on:.2f} s "
          f"with it; tolerance stage {stage:.2f} s = {100 * stage / cpu_off:.1f} % of the "
          "plan without it", flush=True)
    assert result.tolerance is not None
    print("tolerance:", {k: v for k, v in result.tolerance.to_dict().items()
                         if k != "worst_case_components"})
    r = result.spec.placement_tolerance_m
    for label, offsets in (("8 + centre", offsets_m(r)),
                           ("16 + centre", offsets_m(r, 16)),
                           ("16 + 8 at r/2 + centre",
                            np.concatenate([offsets_m(r, 16), offsets_m(r, 8, (0.5,))[1:]]))):
        print(f"worst loss per station, {label}: {worst_losses(result, offsets)} m2",
              flush=True)
    if args.robust:
        robust, cpu = run(args.scene, robust=True)
        print(f"robust: {len(robust.chosen.stations)} stations (default "
              f"{len(result.chosen.stations)}), covered {robust.chosen.covered_area_m2[-1]:.2f}"
              f" of {robust.table.max_achievable_area_m2:.2f} m2 robustly achievable "
              f"(default {result.table.max_achievable_area_m2:.2f}), CPU {cpu:.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
