"""What plan.dxf and plan.pdf cost on top of the other outputs: CPU seconds and peak RSS.

Usage: python benchmarks/cad_outputs.py [hall-full|fzk|fzk-default ...]

Plans each scene (hall-full with its candidates.csv, the mesh as given; FZK-Haus with a
0.5 m remesh and 1 m grid, or at default parameters), then, each in a fresh child process
so that peaks do not mix: plan.dxf alone, plan.pdf alone, every output but those two, and
every output. CPU time (user + system of the process, all threads) rather than wall time:
on a shared machine wall time says more about the neighbours than about the code. Peak
RSS is the process's high-water mark (Linux VmHWM, reset after the plan was loaded, so
unpickling's own peak does not hide the outputs'), the plan included; the line says what
the loaded plan alone held.
"""

from __future__ import annotations

import multiprocessing
import pickle
import sys
import tempfile
import time
from pathlib import Path

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "scenes"
NEW = ("plan.dxf", "plan.pdf")


def make_plan(name: str) -> object:
    from planner.candidates.grid import read_candidates_csv
    from planner.io.readers import read_scene
    from planner.parameters import PlanSpec
    from planner.pipeline import plan

    if name == "hall-full":
        candidates = read_candidates_csv(SHARED / "hall-full" / "candidates.csv")
        spec = PlanSpec(candidates=tuple(map(tuple, candidates.tolist())), max_edge_m=None)
        return plan(read_scene(SHARED / "hall-full" / "hall.obj", max_edge_m=None), spec)
    spec = PlanSpec(max_edge_m=0.5, grid_spacing_m=1.0) if name == "fzk" else PlanSpec()
    scene = read_scene(SHARED / "AC20-FZK-Haus.ifc", max_edge_m=spec.max_edge_m,
                       split_faces="as_needed")
    return plan(scene, spec)


def _rss_mib(field: str) -> float:
    """VmRSS or VmHWM (peak) of this process, MiB."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) / 1024
    return float("nan")


def measure(saved: Path, what: str, queue: multiprocessing.Queue) -> None:  # type: ignore[type-arg]
    import planner.outputs.cad
    import planner.outputs.printset  # noqa: F401  (imported before the clock starts)
    from planner.outputs.report import OUTPUTS, write_outputs

    result = pickle.loads(saved.read_bytes())
    held = _rss_mib("VmRSS")
    Path("/proc/self/clear_refs").write_text("5")  # resets VmHWM to the current RSS
    started = time.process_time()
    if what in OUTPUTS:
        OUTPUTS[what](result)
    else:
        names = tuple(n for n in OUTPUTS if what == "all" or n not in NEW)
        write_outputs(result, tempfile.mkdtemp(prefix="scanplan-bench-"), names=names)
    cpu = time.process_time() - started
    peak = _rss_mib("VmHWM")
    queue.put(f"{what:>22}: {cpu:6.2f} CPU s, peak {peak:5.0f} MiB (the plan {held:.0f} MiB)")


def main() -> None:
    names = sys.argv[1:] or ["hall-full", "fzk"]
    context = multiprocessing.get_context("spawn")
    with tempfile.TemporaryDirectory() as folder:
        for name in names:
            saved = Path(folder) / f"{name}.pickle"
            result = make_plan(name)
            saved.write_bytes(pickle.dumps(result))
            print(f"{name}: {len(result.chosen.stations)} stations, "  # type: ignore[attr-defined]
                  f"{result.scene.n_faces:,} faces")  # type: ignore[attr-defined]
            del result
            for what in (*NEW, "all but dxf and pdf", "all"):
                queue = context.Queue()
                child = context.Process(target=measure, args=(saved, what, queue))
                child.start()
                print(queue.get())
                child.join()


if __name__ == "__main__":
    main()
