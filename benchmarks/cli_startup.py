"""Time the ``scanplan`` command as a user runs it: start-up, and a whole plan as a process.

Usage: python benchmarks/cli_startup.py [--repeat K] [--plan-repeat N] [--source DIR]

Prints, best and median of K runs, the wall time of ``python -c pass`` (the interpreter
alone) and of ``scanplan --help``; then, best of N, ``scanplan plan`` on hall-full (its
candidates.csv, the mesh as given: ``{"max_edge_m": null}``) as a separate process: when
``plan.json`` appeared in the output folder, when the process ended, and its peak RSS
(``wait4``'s rusage of that one process). ``--source DIR`` runs the planner sources in DIR
(an unpacked older commit, say) with this interpreter, to compare before and after.
Figures are wall times on a shared machine: compare best-of runs, taken together.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
HALL = ROOT.parent / "shared" / "scenes" / "hall-full"
_POLL_S = 0.005


def wall_s(command: list[str], cwd: Path) -> float:
    started = time.perf_counter()
    subprocess.run(command, cwd=cwd, check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - started


def plan_process(source: Path) -> tuple[float, float, float]:
    """(seconds until plan.json exists, seconds until exit, peak RSS in MB) of one plan."""
    with tempfile.TemporaryDirectory() as tmp:
        params = Path(tmp) / "params.json"
        params.write_text(json.dumps({"max_edge_m": None}))
        out = Path(tmp) / "out"
        command = [sys.executable, "-m", "planner", "plan", str(HALL / "hall.obj"),
                   "--candidates", str(HALL / "candidates.csv"), "--params", str(params),
                   "--out", str(out), "--quiet"]
        started = time.perf_counter()
        process = subprocess.Popen(command, cwd=source)
        plan_json_s: float | None = None
        while True:
            if plan_json_s is None and (out / "plan.json").exists():
                plan_json_s = time.perf_counter() - started
            pid, status, usage = os.wait4(process.pid, os.WNOHANG)
            if pid:
                break
            time.sleep(_POLL_S)
        exit_s = time.perf_counter() - started
        process.returncode = os.waitstatus_to_exitcode(status)
        if process.returncode != 0:
            raise SystemExit(f"scanplan plan failed with status {process.returncode}")
        peak_mb = usage.ru_maxrss / 1024  # KiB on Linux
        return exit_s if plan_json_s is None else plan_json_s, exit_s, peak_mb


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=10, help="start-up runs (default 10)")
    parser.add_argument("--plan-repeat", type=int, default=3,
                        help="hall-full plans (default 3; 0 skips them)")
    parser.add_argument("--source", type=Path, default=ROOT,
                        help="folder holding the planner/ and service/ sources to run")
    args = parser.parse_args()
    source = args.source.resolve()
    commands = {
        "python -c pass": [sys.executable, "-c", "pass"],
        "scanplan --help": [sys.executable, "-m", "planner", "--help"],
    }
    for label, command in commands.items():
        times = [wall_s(command, source) for _ in range(args.repeat)]
        print(f"{label:16s} best {min(times):.3f} s, median {statistics.median(times):.3f} s "
              f"({args.repeat} runs)")
    if args.plan_repeat <= 0:
        return 0
    runs = [plan_process(source) for _ in range(args.plan_repeat)]
    for k, (first, end, rss) in enumerate(runs, 1):
        print(f"hall-full plan run {k}: plan.json after {first:.2f} s, done after {end:.2f} s, "
              f"peak RSS {rss:.0f} MB")
    print(f"hall-full plan best of {len(runs)}: plan.json after "
          f"{min(r[0] for r in runs):.2f} s, done after {min(r[1] for r in runs):.2f} s, "
          f"peak RSS {min(r[2] for r in runs):.0f} MB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
