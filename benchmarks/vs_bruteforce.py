"""``scanplan plan`` against the paper's brute-force method, side by side in one run.

Usage: python benchmarks/vs_bruteforce.py [SCENE_DIR] [--repeat K]

The paper (shared/seed/paper.txt, section 3) casts one ray from every candidate to every
face centroid with Open3D's ``RaycastingScene`` (closest hit: the face is visible when the
ray hits it first), then applies the analytic limits of shared/docs/method.md to the
visible pairs and chooses stations greedily. This script runs that method as the
paper describes it, in a child process, and ``scanplan plan SCENE --candidates ... --out
DIR`` as a user would (default parameters, every output file), in another, and prints for
each its wall time and peak RSS (``ru_maxrss`` from ``wait4``), the best of ``--repeat``
runs, and the ratio. Both must choose the same greedy stations at goal 0.8: the script
says whether they do.

Defaults to shared/scenes/hall-full with its candidates.csv. Needs Open3D, which is not
a dependency of scanplan: ``pip install -e '.[bench]'``; Open3D's wheel links
``libusb-1.0.so.0`` (Debian package ``libusb-1.0-0``) even for ray casting.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
SCANPLAN = Path(sys.executable).with_name("scanplan")

# the paper's Table 2 (method.md's defaults)
DOF_MIN_M, DOF_MAX_M = 1.5, 50.0
ANGULAR_STEP_RAD = 0.010 / 10.0
ELEVATION_MIN_DEG, ELEVATION_MAX_DEG = -60.0, 90.0
MIN_INCIDENCE_DEG, MIN_DENSITY_PTS_M2 = 15.0, 45_000.0
GOAL = 0.8
RAYS_PER_BATCH = 2_000_000


def brute_force(scene_dir: Path) -> list[int]:
    """The paper's method with Open3D: every pair's ray, then the limits, then greedy."""
    import open3d as o3d

    mesh = o3d.io.read_triangle_mesh(str(scene_dir / "hall.obj"))
    vertices = np.asarray(mesh.vertices, np.float64)
    faces = np.asarray(mesh.triangles, np.int64)
    triangles = vertices[faces]  # (F, 3, 3)
    centroids = triangles.mean(axis=1)
    cross = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    areas = 0.5 * np.linalg.norm(cross, axis=1)
    normals = cross / np.maximum(2 * areas, 1e-300)[:, None]
    candidates = np.loadtxt(scene_dir / "candidates.csv", delimiter=",", skiprows=1)

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(vertices.astype(np.float32)),
                        o3d.core.Tensor(faces.astype(np.uint32)))
    n_faces = len(faces)
    per_batch = max(1, RAYS_PER_BATCH // n_faces)
    rows: list[np.ndarray] = []
    for start in range(0, len(candidates), per_batch):
        block = candidates[start:start + per_batch]  # (B, 3)
        offset = centroids[None, :, :] - block[:, None, :]  # (B, F, 3)
        distance = np.linalg.norm(offset, axis=2)
        direction = offset / np.maximum(distance, 1e-300)[:, :, None]
        rays = np.concatenate([np.broadcast_to(block[:, None, :], offset.shape), direction],
                              axis=2).reshape(-1, 6).astype(np.float32)
        hit = scene.cast_rays(o3d.core.Tensor(rays))["primitive_ids"].numpy()
        visible = hit.reshape(len(block), n_faces).astype(np.int64) == np.arange(n_faces)
        sin_elevation = direction[:, :, 2]
        sin_incidence = np.abs(np.einsum("bfk,fk->bf", direction, normals))
        lpd = sin_incidence / (ANGULAR_STEP_RAD * distance) ** 2
        qualified = (visible & (distance >= DOF_MIN_M) & (distance <= DOF_MAX_M)
                     & (sin_elevation >= np.sin(np.radians(ELEVATION_MIN_DEG)))
                     & (sin_elevation <= np.sin(np.radians(ELEVATION_MAX_DEG)))
                     & (sin_incidence >= np.sin(np.radians(MIN_INCIDENCE_DEG)))
                     & (lpd >= MIN_DENSITY_PTS_M2))
        rows.extend(np.flatnonzero(row) for row in qualified)
    achievable = np.zeros(n_faces, bool)
    for row in rows:
        achievable[row] = True
    need = GOAL * areas[achievable].sum()
    uncovered = np.ones(n_faces, bool)
    covered, stations = 0.0, []
    while covered < need - 1e-9:
        gains = np.array([areas[row[uncovered[row]]].sum() for row in rows])
        best = int(np.argmax(gains))
        covered += gains[best]
        uncovered[rows[best]] = False
        stations.append(best)
    return stations


def timed(command: list[str], env: dict[str, str] | None = None,
          cwd: Path | None = None) -> tuple[float, float, str]:
    """Wall seconds, peak RSS in MB and stdout of a child process (``env``: its whole
    environment, default this one's)."""
    started = time.perf_counter()
    child = subprocess.Popen(command, stdout=subprocess.PIPE, text=True, env=env, cwd=cwd)
    assert child.stdout is not None
    output = child.stdout.read()
    _, status, usage = os.wait4(child.pid, 0)
    seconds = time.perf_counter() - started
    child.returncode = os.waitstatus_to_exitcode(status)
    if child.returncode:
        raise SystemExit(f"{command[0]} failed with status {child.returncode}")
    return seconds, usage.ru_maxrss / 1024, output


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene_dir", nargs="?", default=str(SHARED / "scenes" / "hall-full"))
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--brute-force-only", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    scene_dir = Path(args.scene_dir)
    if args.brute_force_only:
        print(json.dumps(brute_force(scene_dir)))
        return 0
    best: dict[str, tuple[float, float]] = {}
    answers: dict[str, list[int]] = {}
    for run in range(args.repeat):
        for name in ("brute force (Open3D)", "scanplan plan"):
            with tempfile.TemporaryDirectory() as out:
                if name == "scanplan plan":
                    seconds, peak_mb, _ = timed([
                        str(SCANPLAN), "plan", str(scene_dir / "hall.obj"), "--candidates",
                        str(scene_dir / "candidates.csv"), "--out", out, "--quiet"])
                    plan = json.loads((Path(out) / "plan.json").read_text())
                    answers[name] = [s["candidate_index"] for s in plan["stations"]]
                else:
                    seconds, peak_mb, output = timed([
                        sys.executable, __file__, str(scene_dir), "--brute-force-only"])
                    answers[name] = json.loads(output)
            print(f"run {run + 1}: {name}: {seconds:.2f} s, peak RSS {peak_mb:.0f} MB",
                  flush=True)
            previous = best.get(name)
            if previous is None or seconds < previous[0]:
                best[name] = (seconds, peak_mb)
    (brute_s, brute_mb), (ours_s, ours_mb) = best["brute force (Open3D)"], best["scanplan plan"]
    print(f"best of {args.repeat}: brute force {brute_s:.2f} s ({brute_mb:.0f} MB), "
          f"scanplan plan {ours_s:.2f} s ({ours_mb:.0f} MB): {brute_s / ours_s:.1f}x faster")
    same = answers["brute force (Open3D)"] == answers["scanplan plan"]
    print(f"greedy stations at goal {GOAL}: scanplan {answers['scanplan plan']}, brute force "
          f"{answers['brute force (Open3D)']}: {'the same' if same else 'DIFFERENT'}")
    return 0 if same else 1


if __name__ == "__main__":
    raise SystemExit(main())
