"""The selection's heuristics and lower bound alone and beside other threads, on hall-full.

Usage: python benchmarks/selection_beside_threads.py [SCENE_DIR] [--repeat K]

``scanplan plan`` imports the renderers' modules on a background thread while the plan's
selection runs (``planner.__main__.PreloadAtSelection``), and a service may run other
Python threads beside a plan. A search that is a Python loop over compiled steps lets go
of the interpreter's lock at every step and waits for it at the next, up to the switch
interval (5 ms) whenever another thread holds it; a search that is one compiled call waits
once. This script plans hall-full (its candidates, the paper's parameters), then times, on
its coverage table, greedy and weighted greedy side by side (as the selection runs them)
and the lower bound beside the plan's greedy stations (``station_lower_bound``), each
alone and beside a thread that spins in Python (the worst such neighbour: it always wants
the lock). Prints seconds (the best of ``--repeat``) and what each found, so a change that
moves the stations or the bound shows; never passes or fails.
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from pathlib import Path

from planner.candidates.grid import read_candidates_csv
from planner.io.readers import read_scene
from planner.parameters import PlanSpec
from planner.pipeline import plan
from planner.selection.greedy import GOAL_SLACK_M2, greedy
from planner.selection.lower_bound import station_lower_bound
from planner.visibility.coverage import CoverageTable

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
GOAL = 0.8


@contextmanager
def nothing_beside() -> Iterator[None]:
    yield


@contextmanager
def spinning_beside() -> Iterator[None]:
    """A thread that counts in Python, holding the interpreter's lock for its turns."""
    running = [True]

    def spin() -> None:
        count = 0
        while running[0]:
            count += 1

    thread = threading.Thread(target=spin, daemon=True)
    thread.start()
    try:
        yield
    finally:
        running[0] = False
        thread.join()


def heuristics(table: CoverageTable) -> str:
    with ThreadPoolExecutor(max_workers=2) as pool:
        weighted = pool.submit(greedy, table, weighted=True)
        plain = greedy(table)
        return f"greedy {len(plain.stations)}, weighted {len(weighted.result().stations)}"


def bound(table: CoverageTable, stations: int) -> str:
    need = GOAL * table.max_achievable_area_m2 - GOAL_SLACK_M2
    found = station_lower_bound(table, need, stations)
    return f"bound {found.stations}, lp {found.lp_value:.12f}, {found.iterations} iterations"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene_dir", nargs="?", type=Path, default=SHARED / "scenes" / "hall-full")
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    scene = read_scene(args.scene_dir / "hall.obj", max_edge_m=None)
    candidates = read_candidates_csv(args.scene_dir / "candidates.csv")
    result = plan(scene, PlanSpec(candidates=tuple(map(tuple, candidates.tolist()))),
                  keep_table=True)
    table = result.table
    stations = len(result.chosen.stations)
    steps: list[tuple[str, Callable[[], str]]] = [
        ("greedy and weighted side by side", lambda: heuristics(table)),
        ("lower bound", lambda: bound(table, stations)),
    ]
    besides = [("alone", nothing_beside), ("beside a spinning thread", spinning_beside)]
    print(f"{'step':<34} {'beside':<26} {'best s':>7}  result")
    for name, step in steps:
        step()  # compiled kernels loaded before any timing
        for beside_name, beside in besides:
            best, said = float("inf"), ""
            for _ in range(args.repeat):
                with beside():
                    started = time.perf_counter()
                    said = step()
                    best = min(best, time.perf_counter() - started)
            print(f"{name:<34} {beside_name:<26} {best:>7.3f}  {said}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
