"""Time of the IFC conversion and of the whole plan for FZK-Haus (default parameters).

Prints figures, never passes or fails on time::

    .venv/bin/python benchmarks/plan_ifc.py [model.ifc] [--max-edge-m 0.2] [--grid-spacing-m 0.5]
"""

from __future__ import annotations

import argparse
import resource
import tempfile
import time
from pathlib import Path

from planner.io.readers import read_scene
from planner.outputs.report import OUTPUTS, write_outputs
from planner.parameters import PlanSpec
from planner.pipeline import plan

DEFAULT_MODEL = Path(__file__).resolve().parents[2] / "shared/scenes/AC20-FZK-Haus.ifc"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("model", nargs="?", type=Path, default=DEFAULT_MODEL)
    parser.add_argument("--max-edge-m", type=float, default=PlanSpec.max_edge_m)
    parser.add_argument("--grid-spacing-m", type=float, default=PlanSpec.grid_spacing_m)
    args = parser.parse_args()

    from planner.io.ifc import read_ifc

    t0 = time.perf_counter()
    raw = read_ifc(args.model)
    t_convert = time.perf_counter() - t0
    t0 = time.perf_counter()
    scene = read_scene(args.model, max_edge_m=args.max_edge_m, split_faces="as_needed")
    t_read = time.perf_counter() - t0
    spec = PlanSpec(max_edge_m=args.max_edge_m, grid_spacing_m=args.grid_spacing_m)
    t0 = time.perf_counter()
    result = plan(scene, spec)
    t_plan = time.perf_counter() - t0
    t_elements = {}
    for name in ("elements.csv", "elements.json"):  # the first computes the rows and reasons
        t0 = time.perf_counter()
        OUTPUTS[name](result)
        t_elements[name] = time.perf_counter() - t0
    with tempfile.TemporaryDirectory() as out:
        t0 = time.perf_counter()
        written = write_outputs(result, out)
        t_write = time.perf_counter() - t0 + sum(t_elements.values())
    totals = result.table.max_achievable_area_m2
    print(f"model                   {args.model.name}")
    print(f"IFC conversion          {t_convert:8.2f} s  ({raw.n_faces} faces, "
          f"{len(raw.elements)} elements, {len(raw.metadata['spaces'])} rooms)")
    print(f"read_scene              {t_read:8.2f} s  ({scene.n_faces} file faces; split at "
          f"max_edge_m {args.max_edge_m} as needed: {result.scene.n_faces} faces)")
    for stage, seconds in result.stats.seconds.items():
        print(f"  plan: {stage:<16}{seconds:8.2f} s")
    print(f"plan (all stages)       {t_plan:8.2f} s  ({len(result.candidates)} candidates, "
          f"{result.stats.rays_cast} rays, {result.table.n_pairs} qualified pairs)")
    print(f"write outputs           {t_write:8.2f} s  ({', '.join(p.name for p in written)})")
    for name, seconds in t_elements.items():
        print(f"  of which {name:<13}{seconds:8.2f} s")
    print(f"total                   {t_read + t_plan + t_write:8.2f} s")
    print(f"stations                {len(result.chosen.stations)} "
          f"(max achievable {totals:.1f} m2)")
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"peak RSS                {peak_mb:.0f} MB")


if __name__ == "__main__":
    main()
