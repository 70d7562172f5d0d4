"""HiGHS against OR-Tools CP-SAT on the same fewest-stations programs.

For each model and goal, plans the model (default parameters; the halls with their
explicit candidates), builds the partial-cover program ``optimal`` hands to HiGHS (face
classes, relaxed per voxel above ``MAX_NONZEROS``, from the better heuristic's plan as a
start: :func:`planner.selection.optimal._partial_cover`) and solves it with both, each
under the same wall-clock limit on the machine's cores:

- HiGHS (highspy), as ``optimal`` runs it (in a child process, as ``optimal`` does);
- CP-SAT: ``x`` and ``y`` binary (a class is covered whole or not), the areas in whole
  square millimetres (the goal rounded up), the heuristic's plan as a hint, with
  ``max_time_in_seconds``; and again with ``max_deterministic_time`` instead (its
  deterministic work limit, the same answer on any machine), set to the seconds given.
  In a child process: OR-Tools' wheel bundles its own HiGHS, whose symbols clash with
  highspy's in one process (either imported second fails to load).

Prints per row the stations found, the proven lower bound and the seconds; figures, never
a pass or a fail::

    .venv/bin/python benchmarks/solvers.py [--models hall-full,renga] [--goals 0.8,0.95]
        [--seconds 30]
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT.parent / "shared" / "scenes"
MODELS = {
    "hall-small": SCENES / "hall-small",
    "hall-full": SCENES / "hall-full",
    "renga": SCENES / "buildings" / "Renga-House.ifc",
    "fzk": SCENES / "AC20-FZK-Haus.ifc",
}


def _table(name: str) -> tuple[object, np.ndarray, dict[str, object]]:
    """The coverage table, the faces' centroids and the heuristics' orders of ``name``."""
    from planner.candidates.grid import read_candidates_csv
    from planner.io.readers import read_scene
    from planner.parameters import PlanSpec
    from planner.pipeline import plan

    path = MODELS[name]
    if path.is_dir():
        scene = read_scene(path / "hall.obj", max_edge_m=None)
        spec = PlanSpec.from_mapping({
            "candidates": read_candidates_csv(path / "candidates.csv").tolist(),
            "max_edge_m": None})
    else:
        spec = PlanSpec()
        scene = read_scene(path, max_edge_m=spec.max_edge_m, split_faces="as_needed")
    result = plan(scene, spec, keep_table=True)
    return result.table, result.scene.centroids, dict(result.selections)


def _program(table: object, centroids: np.ndarray, goal: float, start: list[int]
             ) -> tuple[sp.csr_matrix, np.ndarray, float]:
    """(C, K) class cover, (K,) areas and the area to cover: ``_partial_cover``'s program."""
    from planner.selection.classes import class_table
    from planner.selection.greedy import GOAL_SLACK_M2
    from planner.selection.optimal import MAX_NONZEROS, relaxed_classes

    need = goal * table.max_achievable_area_m2 - GOAL_SLACK_M2  # type: ignore[attr-defined]
    classes = class_table(table, table.achievable)  # type: ignore[arg-type, attr-defined]
    cover, area, _ = relaxed_classes(classes.table, centroids[classes.first_face],
                                     MAX_NONZEROS)
    return sp.csr_matrix(cover), area, need


def _highs(cover: sp.csr_matrix, area: np.ndarray, need: float, start: list[int],
           seconds: float) -> tuple[int | None, int, float]:
    from planner.selection.highs_worker import solve
    from planner.selection.program import ProgramBuilder

    n_cand, n_class = cover.shape
    builder = ProgramBuilder(n_cand)
    builder.set_cost(0, np.ones(n_cand))
    builder.add_variables(np.zeros(n_class), integer=False, lower=0.0, upper=1.0)
    builder.add_rows(sp.hstack([-cover.T, sp.identity(n_class)], format="csr"), -np.inf, 0.0)
    builder.add_rows(sp.hstack([sp.csr_matrix((1, n_cand)), sp.csr_matrix(area[None, :])]),
                     need, np.inf)
    x0 = np.zeros(n_cand)
    x0[start] = 1.0
    builder.start = np.concatenate([x0, np.minimum(1.0, cover.T @ x0)])
    t0 = time.perf_counter()
    answer = solve(builder.build(), seconds)
    found = None if answer.x is None else round(float(answer.x[:n_cand].sum()))
    bound = 0 if answer.dual_bound is None else math.ceil(answer.dual_bound - 1e-6)
    return found, bound, time.perf_counter() - t0


def _cp_sat(cover: sp.csr_matrix, area: np.ndarray, need: float, start: list[int],
            seconds: float, deterministic: bool) -> tuple[int | None, int, float]:
    from ortools.sat.python import cp_model

    n_cand, n_class = cover.shape
    model = cp_model.CpModel()
    x = [model.NewBoolVar(f"x{c}") for c in range(n_cand)]
    y = [model.NewBoolVar(f"y{k}") for k in range(n_class)]
    by_class = cover.tocsc()
    for k in range(n_class):
        members = by_class.indices[by_class.indptr[k]:by_class.indptr[k + 1]]
        model.AddBoolOr([x[int(c)] for c in members]).OnlyEnforceIf(y[k])
    weights = np.floor(area * 1e6).astype(np.int64)  # mm², rounded down: never more
    model.Add(sum(int(w) * v for w, v in zip(weights, y, strict=True))
              >= math.ceil(need * 1e6))
    model.Minimize(sum(x))
    chosen = set(start)
    for c in range(n_cand):
        model.AddHint(x[c], c in chosen)
    solver = cp_model.CpSolver()
    if deterministic:
        solver.parameters.max_deterministic_time = seconds
    else:
        solver.parameters.max_time_in_seconds = seconds
    solver.parameters.num_workers = 2
    t0 = time.perf_counter()
    status = solver.Solve(model)
    found = round(solver.ObjectiveValue()) if status in (cp_model.OPTIMAL,
                                                         cp_model.FEASIBLE) else None
    return found, math.ceil(solver.BestObjectiveBound() - 1e-6), time.perf_counter() - t0


def _child(solver: str, npz: str, seconds: float, deterministic: bool = False
           ) -> tuple[int | None, int, float]:
    """``solver`` ("highs", "cp-sat") on the program saved in ``npz``, in a process of its
    own."""
    import json
    import subprocess

    done = subprocess.run([sys.executable, __file__, f"--{solver}", npz, str(seconds),
                           "1" if deterministic else "0"], capture_output=True, text=True,
                          check=True, cwd=ROOT)
    found, bound, took = json.loads(done.stdout.strip().splitlines()[-1])
    return found, bound, took


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", default="hall-full,renga")
    parser.add_argument("--goals", default="0.8,0.95")
    parser.add_argument("--seconds", type=float, default=30.0)
    args = parser.parse_args()
    print("| model | goal | classes | nonzeros | heuristic | HiGHS found / bound / s "
          "| CP-SAT found / bound / s | CP-SAT (deterministic limit) found / bound / s |")
    print("|---|---|---|---|---|---|---|---|")
    for name in args.models.split(","):
        table, centroids, selections = _table(name)
        for goal in (float(g) for g in args.goals.split(",")):
            best = min(selections.values(), key=lambda s: s.count_for_goal(goal))
            start = list(best.stations[:best.count_for_goal(goal)])
            cover, area, need = _program(table, centroids, goal, start)
            npz = str(Path(tempfile.mkdtemp()) / "program.npz")
            sp.save_npz(npz, cover)
            np.savez(npz.replace(".npz", "-rest.npz"), area=area, need=need,
                     start=np.asarray(start))
            answers = [_child("highs", npz, args.seconds),
                       _child("cp-sat", npz, args.seconds, False),
                       _child("cp-sat", npz, args.seconds, True)]
            rows = [f"{found} / {bound} / {seconds:.1f}" for found, bound, seconds in answers]
            print(f"| {name} | {goal:.0%} | {cover.shape[1]:,} | {cover.nnz:,} "
                  f"| {len(start)} | " + " | ".join(rows) + " |", flush=True)


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT))
    if len(sys.argv) == 5 and sys.argv[1] in ("--cp-sat", "--highs"):
        import json

        rest = np.load(sys.argv[2].replace(".npz", "-rest.npz"))
        program = (sp.load_npz(sys.argv[2]).tocsr(), rest["area"], float(rest["need"]),
                   rest["start"].tolist(), float(sys.argv[3]))
        print(json.dumps(_highs(*program) if sys.argv[1] == "--highs"
                         else _cp_sat(*program, sys.argv[4] == "1")))
    else:
        main()
