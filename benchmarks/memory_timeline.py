"""Where a plan's peak memory is: the resident memory sampled with every thread's stack.

``plan_stages.py`` gives the peak of each stage; a stage of a large model runs for minutes
and many functions, so this script samples, while ``plan()`` runs, the process's resident
memory (``VmRSS``) every ``--every-s`` seconds together with the planner frames of every
thread's stack (``sys._current_frames``), and prints a timeline and the samples of the
highest memory with what was running then. It found the survey's door boxes taking every
face's corners (700 MB on the 9.7 M-face office) at the end of the plan. ``--cli`` samples
the whole ``scanplan plan MODEL`` instead (reading, the plan with the renderers' modules
loaded from its selection stage on, every output): the peak a user's run reaches, which on
a 3.8 M-face sports hall lies 20 - 40 MiB above ``plan()``'s alone. Prints figures, never
passes or fails::

    .venv/bin/python benchmarks/memory_timeline.py MODEL [--params JSON|FILE]
        [--every-s 0.25] [--top 12] [--cli]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import threading
import time
import traceback
from dataclasses import dataclass
from pathlib import Path

from plan_stages import MIB, load_params, status_kib

FRAMES_SHOWN = 4  # the innermost planner frames of a thread's stack


@dataclass(frozen=True)
class Sample:
    seconds: float  # since plan() started
    rss_mib: float
    stacks: tuple[str, ...]  # per thread in the planner: its innermost planner frames


def planner_stacks() -> tuple[str, ...]:
    """Every thread's innermost planner frames, outermost first, as ``file:function``."""
    stacks = []
    for frame in sys._current_frames().values():
        names = [f"{Path(entry.filename).parent.name}/{Path(entry.filename).name}:{entry.name}"
                 for entry in traceback.extract_stack(frame) if "/planner/" in entry.filename]
        if names:
            stacks.append(" > ".join(names[-FRAMES_SHOWN:]))
    return tuple(stacks)


class Sampler:
    """Samples in a daemon thread from ``start()`` to ``stop()``."""

    def __init__(self, every_s: float) -> None:
        self.every_s = every_s
        self.samples: list[Sample] = []
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._run, name="memory-sampler", daemon=True)
        self._started = 0.0

    def start(self) -> None:
        self._started = time.perf_counter()
        self._thread.start()

    def stop(self) -> None:
        self._done.set()
        self._thread.join()

    def _run(self) -> None:
        while not self._done.wait(self.every_s):
            rss_kib = status_kib("VmRSS")
            if rss_kib is None:
                return
            self.samples.append(Sample(time.perf_counter() - self._started, rss_kib / MIB,
                                       planner_stacks()))


def plan_samples(args: argparse.Namespace) -> list[Sample]:
    """The samples of ``plan()`` alone, after the model is read; prints the plan's size."""
    from planner.io.readers import read_scene
    from planner.parameters import PlanSpec
    from planner.pipeline import plan

    spec = PlanSpec.from_mapping(load_params(args.params))
    scene = read_scene(args.model, max_edge_m=spec.max_edge_m, unit_scale=spec.unit_scale,
                       up_axis=spec.up_axis, split_faces="as_needed")
    sampler = Sampler(args.every_s)
    sampler.start()
    result = plan(scene, spec)
    sampler.stop()
    print(f"{result.scene.n_faces:,} faces, {len(result.candidates):,} candidates, "
          f"{len(result.chosen.stations)} stations; plan() stages, wall s: "
          + ", ".join(f"{k} {v:.1f}" for k, v in result.stats.seconds.items()))
    return sampler.samples


def cli_samples(args: argparse.Namespace) -> list[Sample]:
    """The samples of the whole ``scanplan plan`` run, in this process, into a scratch
    folder; prints its own summary line."""
    from planner.__main__ import main as scanplan

    with tempfile.TemporaryDirectory() as out:
        argv = ["plan", str(args.model), "--out", out]
        if args.params:  # the command line takes a file
            params = Path(out) / "params.json"
            params.write_text(json.dumps(load_params(args.params)), encoding="utf-8")
            argv += ["--params", str(params)]
        sampler = Sampler(args.every_s)
        sampler.start()
        scanplan(argv)
        sampler.stop()
    return sampler.samples


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("model", type=Path)
    parser.add_argument("--params", help="plan parameters: JSON text or a JSON file")
    parser.add_argument("--every-s", type=float, default=0.25)
    parser.add_argument("--top", type=int, default=12, help="how many of the highest samples")
    parser.add_argument("--cli", action="store_true",
                        help="sample the whole `scanplan plan MODEL` run, outputs included")
    args = parser.parse_args()
    samples = cli_samples(args) if args.cli else plan_samples(args)
    if not samples:
        raise SystemExit("no samples: /proc/self/status is not readable here")
    print("\ntimeline (s, MiB, the first thread's frames), about 40 lines:")
    for sample in samples[::max(1, len(samples) // 40)]:
        print(f"{sample.seconds:8.1f} {sample.rss_mib:8.0f}  "
              f"{sample.stacks[0] if sample.stacks else '-'}")
    print(f"\nthe {args.top} highest samples, with every thread's frames:")
    for sample in sorted(samples, key=lambda s: -s.rss_mib)[:args.top]:
        print(f"{sample.seconds:8.1f} {sample.rss_mib:8.0f}")
        for stack in sample.stacks:
            print(f"           {stack}")


if __name__ == "__main__":
    main()
