"""A new user's first plan: with numba's cache empty, again with the cache it made, and
with the cache ``scanplan compile-kernels`` makes.

Usage: python benchmarks/first_plan.py [MODEL ...] [--candidates CSV]

Each model (default: the IfcOpenHouse example the package ships) is planned by
``scanplan plan`` as a separate process, three times, each with its own numba cache
folder (``NUMBA_CACHE_DIR``; the user's own cache is not touched):

- *first plan*: an empty cache, so the plan compiles every kernel it calls;
- *second plan*: the cache the first plan left;
- *after compile-kernels*: a fresh cache that ``scanplan compile-kernels`` filled (its own
  wall time and peak printed too), then the plan; numba's log (``NUMBA_DEBUG_CACHE``)
  says how many kernels that plan still compiled.

Prints wall seconds and the process's peak RSS (``wait4``'s rusage, as
``benchmarks/vs_bruteforce.py`` times its runs); figures, never a pass
or a fail. Wall times on a shared machine: compare runs taken together.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.vs_bruteforce import timed

ROOT = Path(__file__).resolve().parents[1]
IFC_HOUSE = ROOT / "planner" / "example_data" / "IfcOpenHouse_IFC4.ifc"


def run(arguments: list[str], cache: Path) -> tuple[float, float, int]:
    """(wall s, peak RSS MB, kernels compiled) of ``scanplan ARGUMENTS`` with ``cache``."""
    environ = {name: value for name, value in os.environ.items()
               if not name.startswith("NUMBA_")}
    environ.update(NUMBA_CACHE_DIR=str(cache), NUMBA_DEBUG_CACHE="1")
    seconds, peak_mb, output = timed([sys.executable, "-m", "planner", *arguments],
                                     env=environ, cwd=ROOT)
    return seconds, peak_mb, output.count("[cache] data saved")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("models", nargs="*", default=[str(IFC_HOUSE)])
    parser.add_argument("--candidates", help="a candidates CSV for every model")
    args = parser.parse_args()
    print(f"{'model':<28} {'run':<24} {'wall s':>7} {'peak MB':>8} {'compiled':>8}")
    for model in args.models:
        with tempfile.TemporaryDirectory() as tmp:
            plan = ["plan", str(Path(model).resolve()), "--quiet"]
            if args.candidates:
                plan += ["--candidates", str(Path(args.candidates).resolve())]
            cold, warmed = Path(tmp) / "cold", Path(tmp) / "compiled"
            rows = [("first plan", run([*plan, "--out", f"{tmp}/a"], cold)),
                    ("second plan", run([*plan, "--out", f"{tmp}/b"], cold)),
                    ("compile-kernels", run(["compile-kernels", "--quiet"], warmed)),
                    ("after compile-kernels", run([*plan, "--out", f"{tmp}/c"], warmed))]
            for label, (seconds, peak_mb, compiled) in rows:
                print(f"{Path(model).name:<28} {label:<24} {seconds:>7.1f} {peak_mb:>8.0f} "
                      f"{compiled:>8}", flush=True)


if __name__ == "__main__":
    main()
