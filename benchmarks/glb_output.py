"""``coverage.glb`` alone, timed on a saved plan result.

Planning a large model takes minutes, writing its ``coverage.glb`` seconds; to time the
output (and compare two versions of it) the plan is made once and pickled::

    .venv/bin/python benchmarks/glb_output.py plan MODEL RESULT.pickle [--params JSON]
    .venv/bin/python benchmarks/glb_output.py time RESULT.pickle [--out FILE] [--repeat N]

``plan`` reads the model as ``scanplan plan`` does (faces split as needed) and pickles the
:class:`planner.pipeline.PlanResult`. ``time`` loads it and writes ``coverage.glb``
(:func:`planner.outputs.glb.coverage_glb`) ``--repeat`` times, printing per run the CPU
seconds of the process (user + sys, ``getrusage``: on a shared machine wall time stretches
with other work, CPU time much less), the bytes, and the peak resident memory while
writing (``VmHWM``, reset before each run: the loaded result included; numba's compiler is
started beforehand, as in a planning process); first the features and triangles drawn.
"""

from __future__ import annotations

import argparse
import json
import pickle
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.plan_stages import MIB, cpu_seconds, maxrss_mib, reset_peak, status_kib


def plan_model(model: Path, result_path: Path, params: dict[str, object]) -> None:
    from planner.io.readers import read_scene
    from planner.parameters import PlanSpec
    from planner.pipeline import plan

    spec = PlanSpec.from_mapping(params)
    scene = read_scene(model, max_edge_m=spec.max_edge_m, unit_scale=spec.unit_scale,
                       up_axis=spec.up_axis, split_faces="as_needed")
    start = cpu_seconds()
    result = plan(scene, spec)
    print(f"planned {model.name}: {result.scene.n_faces:,} faces, "
          f"{len(result.chosen.stations)} stations, {cpu_seconds() - start:.1f} s CPU", flush=True)
    with result_path.open("wb") as out:
        pickle.dump(result, out, protocol=pickle.HIGHEST_PROTOCOL)


def _hwm_mib() -> float | None:
    """The process's resident high-water mark (``VmHWM``), None where unknown."""
    hwm = status_kib("VmHWM")
    return None if hwm is None else hwm / MIB


def time_glb(result_path: Path, out: Path | None, repeat: int) -> None:
    import numba

    from planner.memory import release_freed_memory
    from planner.outputs import glb
    from planner.outputs.drawing import face_classes

    # numba's compiler started (about 30 MiB), as in a planning process, which has run its
    # kernels by the time it writes the outputs: not the output's memory
    numba.njit(lambda x: x + 1)(1)
    with result_path.open("rb") as f:
        result = pickle.load(f)
    loaded_mib = maxrss_mib()
    classes = face_classes(result.faces, result.limits.target)
    cpu = cpu_seconds()
    features = glb._features(result, classes)  # warm-up (imports, numba's cache)
    print(f"{result_path.name}: {result.scene.n_faces:,} faces, {features.count:,} features, "
          f"{len(features.corners):,} triangles; loaded: peak {loaded_mib:.0f} MiB; "
          f"features (first call): {cpu_seconds() - cpu:.2f} s CPU")
    del features, classes
    for _ in range(repeat):
        release_freed_memory()
        before = _hwm_mib() if reset_peak() else None
        cpu, wall = cpu_seconds(), time.perf_counter()
        data = glb.coverage_glb(result)
        cpu, wall = cpu_seconds() - cpu, time.perf_counter() - wall
        during = _hwm_mib() if before is not None else None
        stage = "" if during is None or before is None else (
            f", output peak {during:.0f} MiB (+{during - before:.0f} over {before:.0f})")
        print(f"  coverage_glb: {cpu:.2f} s CPU ({wall:.2f} s wall), {len(data) / 1e6:.2f} MB"
              f"{stage}", flush=True)
        if out is not None:
            out.write_bytes(data)
        del data


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("plan")
    p.add_argument("model", type=Path)
    p.add_argument("result", type=Path)
    p.add_argument("--params", default="{}", help="PlanSpec parameters as JSON")
    t = sub.add_parser("time")
    t.add_argument("result", type=Path)
    t.add_argument("--out", type=Path)
    t.add_argument("--repeat", type=int, default=1)
    args = parser.parse_args()
    if args.command == "plan":
        plan_model(args.model, args.result, json.loads(args.params))
    else:
        time_glb(args.result, args.out, args.repeat)
    sys.stdout.flush()


if __name__ == "__main__":
    main()
