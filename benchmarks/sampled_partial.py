"""Evaluate a partial promise for the sampled model: the covered unit is the sample.

Usage: python benchmarks/sampled_partial.py [--scene hall-full] [--threads N] [--erode]

The ``sampled`` model promises whole faces (a face qualifies when its passing samples
stand for ``min_sampled_fraction`` of its area). This benchmark evaluates an alternative
considered for it: every sample point stands for 1/N of its face (the n x n barycentric
triangles, N = n^2), a station covers the samples that pass every test from it, greedy
chooses stations on those sample areas until ``goal`` of the achievable sample area, and
the simulated scan judges each promised sample area by the returns in its own triangle
(the scan's sub-face bins set to the same n x n triangles). It prints the achievable and
promised areas, and the promised area the scan does not deliver, per sample triangle and
per face (the returns in a face's promised triangles over their area). ``--erode`` counts
a sample only when the samples of the triangles around it pass too (a failing neighbour
means a limit, a shadow's edge say, crosses its triangle). Figures: README, "Coverage
models and verification".
"""

from __future__ import annotations

import argparse
import math
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

import planner.truth.simulation as simulation
from planner.candidates.grid import read_candidates_csv
from planner.io.readers import read_scene
from planner.limits import FaceLimits
from planner.parameters import PlanSpec
from planner.rays import make_occlusion
from planner.selection.greedy import greedy
from planner.truth.simulation import ScanPattern, simulate_scan
from planner.visibility.coverage import CoverageTable, QualifiedPairs
from planner.visibility.sampled import (
    SampledQualifier,
)

SHARED = Path(__file__).resolve().parents[1].parent / "shared"


def sample_masks(q: SampledQualifier, positions: NDArray[np.float64], first: int
                 ) -> tuple[NDArray[np.int32], NDArray[np.int32], NDArray[np.bool_]]:
    """(P,) candidate, (P,) face and (P, N) passing samples of a block of candidates."""
    pairs, _ = q.finder.find(positions, first)
    face, passes, _lpd, direction, distance = q.sample_limits(pairs)
    p_idx, s_idx = np.nonzero(passes)
    if len(p_idx):
        visible = q.occlusion.visible(pairs.origin[p_idx], direction[p_idx, s_idx],
                                      distance[p_idx, s_idx], face[p_idx])
        passes[p_idx[~visible], s_idx[~visible]] = False
    keep = passes.any(axis=1)
    return pairs.candidate[keep], pairs.face[keep], passes[keep]


def slot_of_sample(n: int) -> NDArray[np.int64]:
    """(N,) the hole-bin slot (row, col, upper) of each sample, in sample_weights order."""
    slots = []
    for row in range(n):
        for col in range(n - row):
            slots.append(2 * (row * n + col))
            if row + col < n - 1:
                slots.append(2 * (row * n + col) + 1)
    return np.array(slots, np.int64)


def neighbours(n: int) -> list[list[int]]:
    """The samples whose triangles share an edge with each sample's, in sample order."""
    order = []
    for row in range(n):
        for col in range(n - row):
            order.append((row, col, 0))
            if row + col < n - 1:
                order.append((row, col, 1))
    index = {key: i for i, key in enumerate(order)}
    result = []
    for row, col, upper in order:
        if upper:
            around = [(row, col, 0), (row + 1, col, 0), (row, col + 1, 0)]
        else:
            around = [(row, col, 1), (row - 1, col, 1), (row, col - 1, 1)]
        result.append([index[key] for key in around if key in index])
    return result


def erode(passes: NDArray[np.bool_], n: int) -> NDArray[np.bool_]:
    """(P, N) samples that pass with every neighbour: a failing neighbour means a limit
    (a shadow's edge, the density threshold) crosses the sample's triangle."""
    out = passes.copy()
    for k, around in enumerate(neighbours(n)):
        for j in around:
            out[:, k] &= passes[:, j]
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="hall-full")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--goal", type=float, default=0.8)
    parser.add_argument("--erode", action="store_true",
                        help="count a sample only when its neighbours pass too")
    args = parser.parse_args()
    scene_dir = SHARED / "scenes" / args.scene
    scene = read_scene(scene_dir / "hall.obj", max_edge_m=None)
    candidates = read_candidates_csv(scene_dir / "candidates.csv")
    spec = PlanSpec(candidates=tuple(map(tuple, candidates.tolist())), max_edge_m=None,
                    coverage_model="sampled")
    limits = FaceLimits.from_spec(spec, scene)
    occlusion = make_occlusion(scene, limits.occludes, "embree", file_faces=False)
    t0 = time.perf_counter()
    q = SampledQualifier(scene, limits, occlusion, spec.samples_per_face, 0.0)
    n_samples = len(q.weights)
    with ThreadPoolExecutor(max_workers=args.threads) as pool:
        parts = list(pool.map(lambda s: sample_masks(q, candidates[s:s + 4], s),
                              range(0, len(candidates), 4)))
    cand = np.concatenate([p[0] for p in parts])
    face = np.concatenate([p[1] for p in parts]).astype(np.int64)
    passes = np.concatenate([p[2] for p in parts])
    if args.erode:
        passes = erode(passes, math.isqrt(n_samples))
    t1 = time.perf_counter()
    # one column per sample: unit = face * N + k, area = face area / N
    p_idx, k_idx = np.nonzero(passes)
    units = QualifiedPairs(cand[p_idx].astype(np.int32),
                           (face[p_idx] * n_samples + k_idx).astype(np.int32),
                           np.ones(len(p_idx), np.float32))
    unit_area = np.repeat(scene.areas / n_samples, n_samples)
    table = CoverageTable.from_pairs(units, len(candidates), unit_area)
    selection = greedy(table).truncated(args.goal)
    promised_units = np.zeros(len(unit_area), bool)
    for c in selection.stations:
        promised_units[table.faces_of(c)] = True
    t2 = time.perf_counter()
    # the scan's bins: exactly the n x n sample triangles of every face
    n = math.isqrt(n_samples)
    simulation.HOLE_BIN_EDGE_M = 1e-9
    simulation._MAX_BIN_SPLITS = n
    stations = candidates[np.asarray(selection.stations, int)]
    counts = simulate_scan(scene, limits, ScanPattern.from_spec(spec), stations,
                           threads=args.threads)
    t3 = time.perf_counter()
    slot = (counts.bins.offset[:, None] + slot_of_sample(n)[None]).ravel()  # (F * N,)
    required = np.repeat(limits.min_density_pts_m2, n_samples)
    delivered_units = counts.best_bin_lpd_pts_m2[slot] >= required
    false_units = promised_units & ~delivered_units
    promised = float(unit_area[promised_units].sum())
    # per face: best returns in the promised triangles over their area
    bin_area = unit_area
    best_returns = counts.best_bin_lpd_pts_m2[slot] * bin_area
    face_returns = np.bincount(np.repeat(np.arange(scene.n_faces), n_samples),
                               weights=np.where(promised_units, best_returns, 0.0),
                               minlength=scene.n_faces)
    face_promised = np.bincount(np.repeat(np.arange(scene.n_faces), n_samples),
                                weights=np.where(promised_units, unit_area, 0.0),
                                minlength=scene.n_faces)
    face_false = (face_promised > 0) & (face_returns < limits.min_density_pts_m2 * face_promised)
    name = f"{args.scene}{' eroded' if args.erode else ''}"
    print(f"scene {name}: achievable {table.max_achievable_area_m2:.2f} m2, "
          f"stations {len(stations)}, promised {promised:.2f} m2 "
          f"(whole faces {int((face_promised >= scene.areas - 1e-12).sum())}, partial "
          f"{int(((face_promised > 0) & (face_promised < scene.areas - 1e-12)).sum())})")
    print(f"  false per sample triangle {unit_area[false_units].sum():.3f} m2 "
          f"({100 * unit_area[false_units].sum() / promised:.3f} %)")
    print(f"  false per face (promised part) {face_promised[face_false].sum():.3f} m2 "
          f"({100 * face_promised[face_false].sum() / promised:.3f} %)")
    print(f"  seconds: qualify {t1 - t0:.1f}, greedy {t2 - t1:.1f}, scan {t3 - t2:.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
