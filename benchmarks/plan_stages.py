"""Where a plan spends its time and memory, stage by stage, in one process.

Runs what ``scanplan plan`` runs: ``read_scene`` (faces split as needed), ``plan()``, then
every output of :data:`planner.outputs.report.OUTPUTS` one after the other (``scanplan``
renders the pictures in background threads; here each output is timed alone). Prints per
stage the wall time, the CPU time of the process (user + sys of all its threads, from
``getrusage``: on a shared machine wall time is stretched by other work, CPU time much
less), the peak resident memory during the stage and of the process so far; then the
planner's own breakdown (``result.stats.seconds``), faces, candidates and stations. While
``plan()`` runs, its progress goes to stderr (a long run can be followed with ``tail``).

Peak memory per stage comes from the kernel's high-water mark (``VmHWM``), reset before each
stage through ``/proc/self/clear_refs``; where that is not possible only the process peak
is shown. The reset lowers ``ru_maxrss`` too (and what ``/usr/bin/time`` reports at exit), so
the process peak printed here is the largest stage peak so far. Prints figures, never passes
or fails on time::

    .venv/bin/python benchmarks/plan_stages.py MODEL [--params JSON|FILE] [--out DIR]
        [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

MIB = 1024.0  # ru_maxrss and /proc/self/status are in KiB


@dataclass
class StageFigures:
    stage: str
    wall_s: float
    cpu_s: float
    stage_peak_mib: float | None  # None where the high-water mark cannot be reset
    process_peak_mib: float
    rss_after_mib: float
    note: str = ""


def cpu_seconds() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def maxrss_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / MIB


def status_kib(field: str) -> float | None:
    """A field of ``/proc/self/status`` in KiB (``VmRSS``, ``VmHWM``), None where unknown."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith(field + ":"):
                return float(line.split()[1])
    except OSError:
        pass
    return None


def reset_peak() -> bool:
    """Reset the kernel's peak-RSS mark of this process; False where it cannot."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
    except OSError:
        return False
    return True


class StageTimer:
    """Collects :class:`StageFigures`, printing each as it is finished."""

    def __init__(self) -> None:
        self.stages: list[StageFigures] = []
        self.peak_mib = maxrss_mib()  # of the process, whatever the resets
        print(f"{'stage':<22}{'wall s':>9}{'cpu s':>9}{'peak MiB':>10}{'proc peak':>11}"
              f"{'rss after':>11}  note", flush=True)

    @contextmanager
    def stage(self, name: str) -> Iterator[list[str]]:
        """Time the block; the yielded list takes notes (sizes, counts) for the line."""
        notes: list[str] = []
        can_reset = reset_peak()
        wall, cpu = time.perf_counter(), cpu_seconds()
        yield notes
        hwm = status_kib("VmHWM") if can_reset else None
        rss = status_kib("VmRSS")
        self.peak_mib = max(self.peak_mib, maxrss_mib(), 0.0 if hwm is None else hwm / MIB)
        figures = StageFigures(
            stage=name, wall_s=time.perf_counter() - wall, cpu_s=cpu_seconds() - cpu,
            stage_peak_mib=None if hwm is None else hwm / MIB,
            process_peak_mib=self.peak_mib,
            rss_after_mib=0.0 if rss is None else rss / MIB, note=", ".join(notes))
        self.stages.append(figures)
        peak = "-" if figures.stage_peak_mib is None else f"{figures.stage_peak_mib:.0f}"
        print(f"{name:<22}{figures.wall_s:9.1f}{figures.cpu_s:9.1f}{peak:>10}"
              f"{figures.process_peak_mib:11.0f}{figures.rss_after_mib:11.0f}  {figures.note}",
              flush=True)


class ProgressLog:
    """Prints to stderr when ``plan()`` enters a stage and at every tenth of it, with the
    wall and CPU seconds since the start and the resident memory: on a long run it tells
    how far it is. A thread samples the resident memory every ``SAMPLE_S`` and keeps the
    largest per progress stage (``peak_mib``), so the stage that sets the plan's peak is
    known (the stages ``plan()`` reports; the survey runs inside "selection"). The wall and
CPU seconds between one call and the next are added to the stage of the first
(``seconds``: stage -> [wall, cpu]): CPU time per progress stage, which
``result.stats.seconds`` (wall only) lacks."""

    SAMPLE_S = 0.1

    def __init__(self) -> None:
        self.wall, self.cpu = time.perf_counter(), cpu_seconds()
        self.last: tuple[str, int] = ("", -1)
        self.stage = "start"
        self.peak_mib: dict[str, float] = {}
        self.seconds: dict[str, list[float]] = {}
        self._mark = (self.wall, self.cpu)
        self._running = True
        self._sampler = threading.Thread(target=self._sample, daemon=True)
        self._sampler.start()

    def _sample(self) -> None:
        while self._running:
            rss = status_kib("VmRSS")
            if rss is not None:
                stage = self.stage
                self.peak_mib[stage] = max(self.peak_mib.get(stage, 0.0), rss / MIB)
            time.sleep(self.SAMPLE_S)

    def _charge(self) -> None:
        """Add the seconds since the last call to the stage running until now."""
        wall, cpu = time.perf_counter(), cpu_seconds()
        spent = self.seconds.setdefault(self.stage, [0.0, 0.0])
        spent[0] += wall - self._mark[0]
        spent[1] += cpu - self._mark[1]
        self._mark = (wall, cpu)

    def stop(self) -> None:
        self._charge()
        self._running = False
        self._sampler.join()

    def __call__(self, stage: str, fraction: float) -> bool:
        self._charge()
        self.stage = stage
        step = (stage, int(fraction * 10))
        if step != self.last:
            self.last = step
            rss = status_kib("VmRSS") or 0.0
            print(f"  [{time.perf_counter() - self.wall:7.0f} s wall, "
                  f"{cpu_seconds() - self.cpu:7.0f} s cpu, {rss / MIB:6.0f} MiB] "
                  f"{stage} {fraction:4.0%}", file=sys.stderr, flush=True)
        return False  # never cancel


def load_params(value: str | None) -> dict[str, Any]:
    """Parameters as JSON text or as the path of a JSON file."""
    if value is None:
        return {}
    path = Path(value)
    text = path.read_text() if path.is_file() else value
    params = json.loads(text)
    if not isinstance(params, dict):
        raise SystemExit("--params: give a JSON object, e.g. '{\"grid_spacing_m\": 1.0}'")
    return params


def run(model: Path, params: dict[str, Any], out: Path | None) -> dict[str, Any]:
    """Time every stage of planning ``model``; returns the figures and the plan's counts."""
    try:  # the kernels of the target ``scanplan`` compiles for, from the cache it fills
        from planner.kernels import pin_numba_target
    except ImportError:  # a checkout from before the pin (matrix.py --source)
        pass
    else:
        pin_numba_target()
    from planner.io.readers import read_scene
    from planner.outputs.report import OUTPUTS
    from planner.parameters import PlanSpec
    from planner.pipeline import PlanResult, plan

    timer = StageTimer()
    spec = PlanSpec.from_mapping(params)
    with timer.stage("read_scene") as notes:
        scene = read_scene(model, max_edge_m=spec.max_edge_m, unit_scale=spec.unit_scale,
                           up_axis=spec.up_axis, split_faces="as_needed")
        notes.append(f"{scene.n_faces:,} file faces")
    result: PlanResult
    log = ProgressLog()
    with timer.stage("plan") as notes:
        result = plan(scene, spec, progress=log)
        notes.append(f"{result.scene.n_faces:,} faces after split, "
                     f"{len(result.candidates):,} candidates, "
                     f"{len(result.chosen.stations)} stations")
    log.stop()
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
    render: Callable[[PlanResult], bytes | None]
    for name, render in OUTPUTS.items():
        with timer.stage(name) as notes:
            data = render(result)
            notes.append("not written" if data is None else f"{len(data) / 1e6:.2f} MB")
        if out is not None and data is not None:
            (out / name).write_bytes(data)
        del data

    print("\nplan() stages (result.stats.seconds, wall):")
    for stage, seconds in result.stats.seconds.items():
        print(f"  {stage:<28}{seconds:9.1f}")
    print("plan() progress stages (wall s, CPU s):")
    for stage, (wall_s, cpu_s) in log.seconds.items():
        print(f"  {stage:<28}{wall_s:9.1f}{cpu_s:9.1f}")
    print("plan() resident memory, largest sample per progress stage (MiB):")
    for stage, mib in log.peak_mib.items():
        print(f"  {stage:<28}{mib:9.0f}")
    stats = result.stats
    survey = result.survey
    unreachable = None if survey is None else len(survey.route.unreachable)
    counts = {
        "model": str(model), "params": params,
        "file_faces": scene.n_faces, "faces_after_split": result.scene.n_faces,
        "candidates": len(result.candidates), "stations": len(result.chosen.stations),
        "pairs_tested": stats.pairs_tested, "rays_cast": stats.rays_cast,
        "qualified_pairs": stats.qualified_pairs, "overlap_rows": stats.overlap_rows,
        "route_unreachable": unreachable,
    }
    for key, value in counts.items():
        if key not in ("model", "params"):
            print(f"{key:<22}{value:,}" if isinstance(value, int) else f"{key:<22}{value}")
    total_wall = sum(s.wall_s for s in timer.stages)
    total_cpu = sum(s.cpu_s for s in timer.stages)
    print(f"{'total':<22}{total_wall:.1f} s wall, {total_cpu:.1f} s CPU, "
          f"peak {timer.peak_mib:.0f} MiB")
    return {**counts, "plan_seconds": dict(stats.seconds), "plan_peak_mib": log.peak_mib,
            "plan_progress_s": {stage: {"wall_s": wall_s, "cpu_s": cpu_s}
                                for stage, (wall_s, cpu_s) in log.seconds.items()},
            "stages": [asdict(s) for s in timer.stages]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("model", type=Path)
    parser.add_argument("--params", help="plan parameters: JSON text or a JSON file")
    parser.add_argument("--out", type=Path, help="also write each output into this directory")
    parser.add_argument("--json", type=Path, help="write the figures to this JSON file")
    args = parser.parse_args()
    figures = run(args.model, load_params(args.params), args.out)
    if args.json is not None:
        args.json.write_text(json.dumps(figures, indent=2) + "\n")


if __name__ == "__main__":
    main()
