"""A job through a real ``scanplan serve``, from its submission to its results, with and
without the consumer's warm-up (``SCANPLAN_WARM_UP``).

Usage: python benchmarks/service_jobs.py [--jobs 3] [--workers 2]

For each setting, starts the service on a free port with a temporary data directory,
uploads the examples that ship with scanplan (hall-small with its candidates' grid left to
the plan, ``max_edge_m`` null as in the README; the IfcOpenHouse IFC), submits one job at a
time and polls ``GET /jobs/{id}`` every 20 ms until it is done: prints each job's seconds
from the POST to ``successful``, and the service's memory once it idles (the proportional
set size, ``Pss`` of /proc/PID/smaps_rollup, of every process of its session, so that
pages the processes share count once). Each job asks for a slightly different goal, so
that none is a repeat of another. Figures only, never pass/fail.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import httpx

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.e2e.service_process import Service  # noqa: E402

EXAMPLES = ROOT / "planner" / "example_data"
MODELS = ((EXAMPLES / "hall-small" / "hall.obj", {"max_edge_m": None}),
          (EXAMPLES / "IfcOpenHouse_IFC4.ifc", {}))


def pss_mib(pids: list[int]) -> float:
    """The proportional set size of ``pids`` together, MiB (a process gone counts 0)."""
    total_kib = 0
    for pid in pids:
        try:
            text = Path(f"/proc/{pid}/smaps_rollup").read_text()
        except OSError:
            continue
        total_kib += sum(int(line.split()[1]) for line in text.splitlines()
                         if line.startswith("Pss:"))
    return total_kib / 1024


def run(warm_up: bool, jobs: int, workers: int) -> None:
    with tempfile.TemporaryDirectory(prefix="scanplan-jobs-") as folder:
        started = time.perf_counter()
        service = Service(Path(folder) / "data", workers=workers,
                          env={"SCANPLAN_WARM_UP": str(warm_up).lower()}).start()
        try:
            service.wait_for_workers(timeout_s=120)
            print(f"warm_up={warm_up}: workers up {time.perf_counter() - started:.1f} s "
                  f"after the start, the service idles in {pss_mib(service.session_pids()):.0f}"
                  " MiB (Pss)")
            with httpx.Client(base_url=service.url, timeout=60) as client:
                for path, parameters in MODELS:
                    mesh = client.post(f"/meshes?filename={path.name}",
                                       content=path.read_bytes(),
                                       headers={"Content-Type": "application/octet-stream"})
                    mesh_id = mesh.json()["id"]
                    seconds = []
                    for number in range(jobs):
                        inputs = {"mesh": mesh_id, "parameters": {
                            **parameters, "coverage_goal": 0.8 - 0.001 * number}}
                        submitted = time.perf_counter()
                        job_id = client.post("/processes/scan-plan/execution",
                                             json={"inputs": inputs}).json()["jobID"]
                        while True:
                            status = client.get(f"/jobs/{job_id}").json()["status"]
                            if status in ("successful", "failed", "dismissed"):
                                break
                            time.sleep(0.02)
                        seconds.append(time.perf_counter() - submitted)
                        if status != "successful":
                            raise SystemExit(f"job {job_id} on {path.name}: {status}")
                    print(f"  {path.name:<24} " + "  ".join(f"{s:.2f}" for s in seconds)
                          + " s")
        finally:
            service.stop()
            service.kill_leftovers()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--jobs", type=int, default=3, help="jobs per model and setting")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    for warm_up in (False, True):
        run(warm_up, args.jobs, args.workers)


if __name__ == "__main__":
    main()
