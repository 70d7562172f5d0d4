"""Is the candidate stage as fast as visibility on a 1 M-face interior?

Usage: python benchmarks/candidates_scale.py [--edge 0.05] [--repeat 3] [--one-group]

Remeshes shared/scenes/hall-full to ``--edge`` metres (0.05 m gives about 1 M faces), plans
it with the default grid and prints, best of ``--repeat``, the seconds of the candidate and
visibility stages and the process's peak RSS. ``--one-group`` drops the OBJ groups, as in a
scan mesh: the inside-object test then has one object of 1 M faces (the case that took
75 s and 14 GB before the winding numbers went through cells). Address space is capped at
6 GB so that a regression fails instead of swapping a shared machine.
"""

from __future__ import annotations

import argparse
import resource
import time
from pathlib import Path

from planner.io.readers import read_scene
from planner.parameters import PlanSpec
from planner.pipeline import plan
from planner.scene import build_scene

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
_ADDRESS_SPACE_BYTES = 6 * 1024**3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--edge", type=float, default=0.05, help="remesh edge, metres")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--one-group", action="store_true", help="drop the groups (scan)")
    args = parser.parse_args()
    resource.setrlimit(resource.RLIMIT_AS, (_ADDRESS_SPACE_BYTES, _ADDRESS_SPACE_BYTES))

    started = time.perf_counter()
    scene = read_scene(SHARED / "scenes" / "hall-full" / "hall.obj", max_edge_m=args.edge)
    if args.one_group:
        scene = build_scene(scene.vertices, scene.faces)
    print(f"faces {scene.n_faces:,}, read + remesh {time.perf_counter() - started:.1f} s")
    spec = PlanSpec(max_edge_m=args.edge)
    best: dict[str, float] = {}
    for run in range(args.repeat):
        result = plan(scene, spec)
        seconds = result.stats.seconds
        for stage in ("candidates", "visibility"):
            best[stage] = min(best.get(stage, float("inf")), seconds[stage])
        print(f"run {run + 1}: candidates {seconds['candidates']:.2f} s "
              f"({len(result.candidates)} of {result.candidates.considered} grid points), "
              f"visibility {seconds['visibility']:.2f} s")
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"best of {args.repeat}: candidates {best['candidates']:.2f} s, visibility "
          f"{best['visibility']:.2f} s; peak RSS {peak_mb:,.0f} MB "
          "(shared 2-core machine: timings are noisy)")


if __name__ == "__main__":
    main()
