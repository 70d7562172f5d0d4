"""One plan on 1, 2 and 4 local Dask workers against the same plan on one machine: wall
time, each worker's peak memory and the byte comparison of every output.

Builds a tall generated office (:mod:`benchmarks.ifc_office`, 8 storeys by default) or
plans the model given, once in a child process on its own (the single-machine peak), then
on a ``distributed.LocalCluster`` of N worker processes of one thread each. Each worker's
peak is its process's VmHWM (``/proc/self/status``, read with ``client.run``), the client's
(the process that calls ``plan``) is printed beside it. On a machine of 2 cores the wall
time cannot show the gain; the tasks' times show what more cores would give.

Measured on 2 shared cores, the office of 8 storeys, 12 x 19 m (3.37 M faces split, 873
candidates at ``grid_spacing_m`` 1.0, no placement tolerance), while each task still
carried the file's mesh: one machine 105.5 s, peak 1,120 MiB; 1 worker 228 s, worker peak
1,122 MiB; 2 workers 352 s, 1,240 and 1,422 MiB; 4 workers 389 s, 1,224 to 1,798 MiB; every
file byte-identical each time. On so narrow and tall a building a tile is most of it.

Measured on 2 cores shared with other jobs (wall times meaningless), the office of 8
storeys, 60 x 19 m, ``--params '{"grid_spacing_m": 3.0, "max_edge_m": 0.8}'`` (3.17 M
faces split from 83,408 file faces, 424 candidates), ``--workers 2``: one machine peak
1,414 MiB; 2 workers 1,215 and 1,398 MiB with the file's mesh in every task, 1,256 and
1,160 MiB with it sent once per worker (CPU of the whole run 521 s and 524 s); every file
byte-identical. The file's mesh is 2.1 MiB and its BVH 5 to 8 MiB there: a worker's peak
was the libraries (197 MiB), the tile it ran and the next one queued (the overlap rows'
tiles 92 to 321 MiB, 0.9 to 3.1 M of the 3.17 M faces: everything within 25 m of
candidates up to 25 m apart; the coverage tiles 46 to 66 MiB) and the running tile's
scratch (up to about 1.5 times the tile).

With one task out per worker thread (no queued tile) and the overlap rows' candidates
grouped within 8 m cubes (a tile spans about 58 m), same parameters, ``--workers 2``,
``--width-m`` 40, 80 and 120 (1.32, 5.14 and 13.1 M faces split: the split's faces grow
about with the square of the width): one machine 903, 1,628 and 2,946 MiB; 2 workers 610
and 594, 1,023 and 1,011, 1,703 and 1,373 MiB (before, 774 and 758 at 40 m, 1,668 and
1,473 at 80 m); every file byte-identical each time. At 80 m the workers' CPU was 131 and 69 s
(before 201 and 122 s), the client's 335 s (before 446 s), its peak 2,354 MiB (before
3,817 MiB).

The client (which here hosts the ``LocalCluster``'s scheduler too, and the scheduler keeps
each task's arguments, its tile, until the task ends) then spent most of its extra CPU
cutting the tiles, profiled with py-spy at 40 m: the part's scene derived its faces'
centroids, normals and areas only to have them replaced by the model's, its vertices were
renumbered by ``np.unique`` (a sort), every target in the box around the candidates was
looked up in a k-d tree; and a tile carried the centroids, normals and areas (56 of about
125 bytes a face) the worker can derive again to the same bits. With those gone (the
bounds sort the targets out in one compiled pass, the tree is asked only about those in
doubt; a tile travels without its faces' values and the worker derives them, some 0.34 s
of CPU a million faces), same parameters, ``--workers 2``, each figure beside the same
session's run of the code before (2 cores shared with other jobs, so the CPU times carry
some noise):

- 40 m: one machine 954 MiB, CPU 69 s (1,055 MiB, 75 s in the run before); workers 625
  and 646 MiB (CPU 50 and 50 s; before 635 and 632 MiB, 48 and 38 s); client 990 MiB,
  CPU 71 s (before 1,549 MiB, 96 s);
- 80 m: one machine 1,644 MiB, CPU 226 s (1,732 MiB, 244 s in the run before); workers
  1,034 and 1,026 MiB (CPU 198 and 199 s; before 1,051 and 1,040 MiB, 148 and 203 s);
  client 1,693 MiB, CPU 234 s (before 2,805 MiB, 458 s);

every file byte-identical each time. The client's peak is now about the single machine's
(within the single machine's own spread from run to run) and its CPU about the same: it
runs every stage but the fanned ones, and besides holds Dask's libraries and the started
scheduler (some 25 MiB) and, while tasks run, the scheduler's copies of their tiles.

A worker's peak still grew with the building (625 and 646 MiB at 40 m, 1,034 and 1,026 at
80 m). Measured inside the tasks (a worker plugin reading VmRSS and VmHWM, the latter
reset, as each task starts and ends): a worker's process is 62 MiB, 209 MiB with
planner's libraries, and some 55 MiB more once the compiled kernels are loaded; the rest
was the task's tile. An overlap tile (the candidates of one 8 m cube and every piece within
25 m of them) held 0.6 to 1.3 M of the 1.3 M faces at 40 m, 1.1 to 3.9 M of the 5.1 M at
80 m (30 to 181 MiB of arrays, and the task's scratch 2 to 4.5 times that on top); a
coverage tile (the plan's candidates in 8 blocks: 38 candidates at 40 m, 70 at 80 m) 0.2
to 0.3 M and 0.7 to 0.9 M. The file's mesh and its BVHs (two, the overlap rows' with the
doors open) are 6 MiB each at 40 m, 10 at 80 m. With a tile's targets sent in parts of
about 250,000 faces (whole file faces, in the file's order; the client merges the parts'
pairs and rows), each task trimming the heap as it ends, same parameters, ``--workers 2``,
beside the same session's run of the code before (2 cores shared with other jobs, load
about 10: CPU times carry noise, wall times are meaningless):

- 40 m: one machine 939 MiB, CPU 41 s; workers 391 and 376 MiB, CPU 36 and 37 s (before
  610 and 614 MiB, 36 and 34 s); client 1,023 MiB, CPU 41 s (before 1,018 MiB, 42 s);
  some 100 tasks a worker, the largest 252,865 target faces (before 23 and 27 tasks, up
  to 1.30 M);
- 80 m: one machine 1,640 MiB, CPU 141 s; workers 416 and 441 MiB, CPU 136 and 133 s
  (before 1,003 and 965 MiB, 116 and 119 s); client 1,709 MiB, CPU 147 s (before 1,688
  MiB, 128 s); some 430 tasks a worker, the largest 257,737 target faces (before 41 and
  49, up to 3.94 M);

every file byte-identical each time. A worker's peak now grows by some 10 % when the
building's faces grow four times (the file's mesh and its BVHs, and the floor the worker's
heap keeps between tasks), the single machine's by 75 %. At 80 m the CPU rose by some 15 %
on the workers and the client: ten times the tasks, each paying once for what does not
shrink with it (its bundles take the planes of every face of the file's mesh, 7.5 % of a
worker's samples in py-spy). An earlier run at 80 m, whose client renumbered each part's
vertices among the model's (now among its tile's), gave workers 444 and 422 MiB, CPU 153
and 156 s, client 1,721 MiB, 171 s.

    PYTHONPATH=. .venv/bin/python benchmarks/plan_distributed.py [MODEL.ifc]
        [--storeys 8] [--width-m 12] [--depth-m 19] [--workers 1 2 4]
        [--params '{"grid_spacing_m": 1.0}'] [--out /tmp/plan-distributed]
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import resource
import shutil
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))


def peak_mib() -> float:
    """This process's peak resident memory (VmHWM), MiB."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def cpu_s() -> float:
    """This process's CPU time so far (user and system), seconds."""
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


# the plan's stages (result.stats.seconds) whose work runs as tasks on the cluster
FANNED_STAGES = ("visibility", "overlap")
CORES_REASONED = (16,)


def task_seconds(records: list[dict[str, Any]]) -> dict[str, tuple[int, float, float]]:
    """Per kind of task (its name in the key, ``scanplan-<name>-<token>-<n>``): how many
    ran, their compute seconds in all and the longest's, from a task stream's records
    (``startstops``)."""
    kinds: dict[str, list[float]] = {}
    for record in records:
        seconds = sum(part["stop"] - part["start"] for part in record["startstops"]
                      if part["action"] == "compute")
        key = str(record["key"])
        name = key.split("-")[1] if key.startswith("scanplan-") else key
        kinds.setdefault(name, []).append(seconds)
    return {name: (len(times), sum(times), max(times)) for name, times in kinds.items()}


def _plan_files(model: Path, params: dict[str, Any], out: Path, scheduler: str | None
                ) -> dict[str, Any]:
    from planner.io.readers import read_scene
    from planner.outputs.report import write_outputs
    from planner.parameters import PlanSpec
    from planner.pipeline import plan

    spec = PlanSpec.from_mapping(params)
    cpu_started = cpu_s()  # the client plans once per cluster size in one process
    scene = read_scene(model, max_edge_m=spec.max_edge_m, split_faces="as_needed")
    started = time.perf_counter()
    result = plan(scene, spec, dask_scheduler=scheduler)
    seconds = time.perf_counter() - started
    shutil.rmtree(out, ignore_errors=True)
    written = write_outputs(result, out)
    return {"seconds": seconds, "faces": result.scene.n_faces,
            "candidates": len(result.candidates), "pairs": result.table.n_pairs,
            "stages": {k: round(v, 2) for k, v in result.stats.seconds.items()},
            "files": sorted(p.name for p in written), "peak_mib": peak_mib(),
            "cpu_s": cpu_s() - cpu_started}


def _single(model: Path, params: dict[str, Any], out: Path,
            queue: multiprocessing.Queue[dict[str, Any]]) -> None:
    queue.put(_plan_files(model, params, out, None))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("model", nargs="?", type=Path)
    parser.add_argument("--storeys", type=int, default=8)
    parser.add_argument("--width-m", type=float, default=12.0)
    parser.add_argument("--depth-m", type=float, default=19.0)
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2, 4])
    parser.add_argument("--params", default="{}", help="JSON object of plan parameters")
    parser.add_argument("--out", type=Path, default=Path("/tmp/plan-distributed"))
    args = parser.parse_args()
    from distributed import Client, LocalCluster, get_task_stream

    params = json.loads(args.params)
    args.out.mkdir(parents=True, exist_ok=True)
    model = args.model
    if model is None:
        from benchmarks.ifc_office import build_ifc_office

        model = args.out / f"office-{args.storeys}x{args.width_m:g}x{args.depth_m:g}.ifc"
        if not model.exists():
            build_ifc_office(model, storeys=args.storeys, width_m=args.width_m,
                             depth_m=args.depth_m)
    print(f"model {model}, parameters {params}")
    context = multiprocessing.get_context("spawn")
    queue: multiprocessing.Queue[dict[str, Any]] = context.Queue()
    child = context.Process(target=_single, args=(model, params, args.out / "single", queue))
    child.start()
    single = queue.get()
    child.join()
    print(f"one machine: {single['faces']:,} faces, {single['candidates']:,} candidates, "
          f"{single['pairs']:,} pairs; plan {single['seconds']:.1f} s, peak "
          f"{single['peak_mib']:.0f} MiB, CPU {single['cpu_s']:.0f} s; stages {single['stages']}")
    for n in args.workers:
        with LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                          dashboard_address=None) as cluster, Client(cluster) as client:
            out = args.out / f"dask-{n}"
            with get_task_stream(client) as stream:
                fanned = _plan_files(model, params, out, cluster.scheduler_address)
            peaks = client.run(peak_mib)
            cpus = client.run(cpu_s)
            tasks = task_seconds(stream.data)
        differ = [name for name in single["files"]
                  if (args.out / "single" / name).read_bytes() != (out / name).read_bytes()]
        print(f"{n} worker(s): plan {fanned['seconds']:.1f} s; worker peaks "
              f"{', '.join(f'{p:.0f}' for p in peaks.values())} MiB (CPU "
              f"{', '.join(f'{c:.0f}' for c in cpus.values())} s); client peak "
              f"{fanned['peak_mib']:.0f} MiB, CPU {fanned['cpu_s']:.0f} s (runs every stage "
              "but the fanned ones); "
              f"stages {fanned['stages']}; "
              f"{len(single['files'])} files, "
              + ("all byte-identical" if not differ else f"DIFFER: {differ}"))
        print("  tasks: " + "; ".join(
            f"{name} {count} tasks, {total:.1f} s computing, the longest {longest:.2f} s"
            for name, (count, total, longest) in sorted(tasks.items())))
        serial_s = single["seconds"] - sum(single["stages"].get(stage, 0.0)
                                           for stage in FANNED_STAGES)
        for cores in CORES_REASONED:
            fanned_s = sum(max(total / cores, longest)
                           for _, total, longest in tasks.values())
            # the client cuts and sends every tile itself, besides the stages it runs: its
            # CPU beyond the single machine's (which computed the tiles' work too) is a
            # floor of the fanned stages' wall time
            cutting_s = max(fanned["cpu_s"] - single["cpu_s"], 0.0)
            print(f"  on {cores} one-thread workers, reasoned: about "
                  f"{serial_s + max(fanned_s, cutting_s):.0f} s: the stages that stay on the "
                  f"planning machine ({serial_s:.0f} s on one machine), then the tasks spread "
                  f"evenly ({fanned_s:.0f} s, none shorter than its longest task) or the "
                  f"client's CPU beyond one machine's ({cutting_s:.0f} s: it cuts and sends "
                  "every tile on its own), the longer")


if __name__ == "__main__":
    main()
