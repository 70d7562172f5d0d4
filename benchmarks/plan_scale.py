"""How plan cost grows with model size: synthetic interiors of 0.25, 1, 3 and 10 M faces.

Usage: python benchmarks/plan_scale.py [--sizes 0.25,1,3,10] [--limit-gb 8] [--keep DIR]

Each size is a deterministic furnished floor (a grid of 6 x 5 x 3 m rooms with 0.2 m walls,
doors between neighbours, tables and cabinets as boxes, columns and bins as cylinders,
small clutter boxes), written as an OBJ with groups of large, coarse faces as a BIM export
would have them. A fresh subprocess (capped with RLIMIT_AS at ``--limit-gb``) reads it with
the default ``max_edge_m`` (0.2 m) and plans with default parameters (grid candidates), then
writes plan.json, faces.npz and stations.csv. Printed per size: faces after remeshing,
candidates, seconds per stage (read, candidates, visibility, selection, outputs), peak RSS
(``ru_maxrss`` of the child); then the exponent b of a least-squares fit
``cost ~ faces ** b`` for time and memory.

Timings on a shared machine are noisy: ``--repeat`` keeps the best of N runs per size.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

ROOM_X_M, ROOM_Y_M, ROOM_Z_M = 6.0, 5.0, 3.0
WALL_M = 0.2
DOOR_W_M, DOOR_H_M = 0.9, 2.1
# faces one room yields after remeshing at 0.2 m (measured with --calibrate; the count
# is only used to choose the number of rooms for a target size)
FACES_PER_ROOM = 34_000


class _Builder:
    """Collects triangles per group; vertices are not shared between parts."""

    def __init__(self) -> None:
        self.vertices: list[NDArray[np.float64]] = []
        self.faces: list[NDArray[np.int64]] = []
        self.labels: list[NDArray[np.int64]] = []
        self.groups: dict[str, int] = {}
        self._n_vertices = 0

    def add(self, group: str, vertices: NDArray[np.float64], faces: NDArray[np.int64]) -> None:
        label = self.groups.setdefault(group, len(self.groups))
        self.vertices.append(vertices)
        self.faces.append(faces + self._n_vertices)
        self.labels.append(np.full(len(faces), label, np.int64))
        self._n_vertices += len(vertices)

    def box(self, group: str, lo: tuple[float, float, float],
            hi: tuple[float, float, float]) -> None:
        """An axis-aligned box, 12 outward triangles."""
        x0, y0, z0 = lo
        x1, y1, z1 = hi
        v = np.array([[x0, y0, z0], [x1, y0, z0], [x1, y1, z0], [x0, y1, z0],
                      [x0, y0, z1], [x1, y0, z1], [x1, y1, z1], [x0, y1, z1]])
        f = np.array([[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7], [0, 1, 5], [0, 5, 4],
                      [1, 2, 6], [1, 6, 5], [2, 3, 7], [2, 7, 6], [3, 0, 4], [3, 4, 7]])
        self.add(group, v, f)

    def cylinder(self, group: str, centre: tuple[float, float], radius_m: float,
                 z0: float, z1: float, segments: int = 24) -> None:
        """A closed upright cylinder: 2 x ``segments`` side triangles and two fans."""
        angle = np.linspace(0.0, 2 * math.pi, segments, endpoint=False)
        ring = np.column_stack([centre[0] + radius_m * np.cos(angle),
                                centre[1] + radius_m * np.sin(angle)])
        bottom = np.column_stack([ring, np.full(segments, z0)])
        top = np.column_stack([ring, np.full(segments, z1)])
        caps = np.array([[centre[0], centre[1], z0], [centre[0], centre[1], z1]])
        v = np.concatenate([bottom, top, caps])
        i = np.arange(segments)
        j = (i + 1) % segments
        side = np.concatenate([np.column_stack([i, j, j + segments]),
                               np.column_stack([i, j + segments, i + segments])])
        fans = np.concatenate([np.column_stack([np.full(segments, 2 * segments), j, i]),
                               np.column_stack([np.full(segments, 2 * segments + 1),
                                                i + segments, j + segments])])
        self.add(group, v, np.concatenate([side, fans]))

    def write_obj(self, path: Path) -> int:
        """Write an OBJ with one ``g`` block per group; returns the number of faces."""
        vertices = np.concatenate(self.vertices)
        faces = np.concatenate(self.faces)
        labels = np.concatenate(self.labels)
        order = np.argsort(labels, kind="stable")
        with path.open("w", encoding="ascii") as handle:
            np.savetxt(handle, vertices, fmt="v %.4f %.4f %.4f")
            for name, label in self.groups.items():
                handle.write(f"g {name}\n")
                np.savetxt(handle, faces[order][labels[order] == label] + 1, fmt="f %d %d %d")
        return len(faces)


def _wall_with_door(b: _Builder, lo: tuple[float, float, float],
                    hi: tuple[float, float, float], axis: int, door_at: float | None) -> None:
    """A wall box along ``axis`` (0 x, 1 y); a door opening centred at ``door_at``."""
    if door_at is None:
        b.box("wall", lo, hi)
        return
    a0, a1 = door_at - DOOR_W_M / 2, door_at + DOOR_W_M / 2
    left_hi, right_lo = list(hi), list(lo)
    left_hi[axis], right_lo[axis] = a0, a1
    b.box("wall", lo, (left_hi[0], left_hi[1], left_hi[2]))
    b.box("wall", (right_lo[0], right_lo[1], right_lo[2]), hi)
    lintel_lo, lintel_hi = list(lo), list(hi)
    lintel_lo[axis], lintel_hi[axis], lintel_lo[2] = a0, a1, DOOR_H_M
    b.box("wall", (lintel_lo[0], lintel_lo[1], lintel_lo[2]),
          (lintel_hi[0], lintel_hi[1], lintel_hi[2]))


def _furnish(b: _Builder, x0: float, y0: float, rng: np.random.Generator) -> None:
    """Furniture and clutter inside the room whose inner corner is (x0, y0)."""
    inner_x, inner_y = ROOM_X_M - WALL_M, ROOM_Y_M - WALL_M
    # a table in the middle third, a cabinet against the back wall
    tx = x0 + rng.uniform(1.5, inner_x - 3.1)
    ty = y0 + rng.uniform(1.5, inner_y - 2.3)
    b.box("furniture", (tx, ty, 0.72), (tx + 1.6, ty + 0.8, 0.75))
    for lx, ly in ((0.05, 0.05), (1.5, 0.05), (0.05, 0.7), (1.5, 0.7)):
        b.box("furniture", (tx + lx, ty + ly, 0.0), (tx + lx + 0.05, ty + ly + 0.05, 0.72))
    cx = x0 + rng.uniform(0.3, inner_x - 1.3)
    b.box("furniture", (cx, y0 + inner_y - 0.5, 0.0), (cx + 1.0, y0 + inner_y, 2.0))
    # a column or a bin
    r = float(rng.uniform(0.15, 0.35))
    b.cylinder("furniture", (x0 + rng.uniform(0.5, 1.2), y0 + rng.uniform(0.5, 1.2)), r,
               0.0, float(rng.choice([0.6, ROOM_Z_M])))
    # clutter on the floor and on the table
    for _ in range(int(rng.integers(10, 30))):
        size = rng.uniform(0.05, 0.3, 3)
        on_table = rng.random() < 0.4
        if on_table:
            px, py, pz = tx + rng.uniform(0, 1.3), ty + rng.uniform(0, 0.5), 0.75
        else:
            px, py, pz = x0 + rng.uniform(0, inner_x - 0.3), y0 + rng.uniform(0, inner_y - 0.3), 0.0
        b.box("clutter", (px, py, pz), (px + size[0], py + size[1], pz + size[2]))


def build_interior(n_rooms: int, seed: int = 8) -> _Builder:
    """A deterministic floor of ``n_rooms`` rooms in a near-square grid."""
    cols = max(1, math.ceil(math.sqrt(n_rooms * ROOM_Y_M / ROOM_X_M)))
    rows = math.ceil(n_rooms / cols)
    rng = np.random.default_rng(seed)
    b = _Builder()
    for k in range(n_rooms):
        i, j = k % cols, k // cols
        x, y = i * ROOM_X_M, j * ROOM_Y_M
        x0, y0 = x + WALL_M, y + WALL_M  # inner corner
        x1, y1 = x + ROOM_X_M, y + ROOM_Y_M
        # floor and ceiling of the room's inside: two big triangles each
        b.add("floor", np.array([[x0, y0, 0], [x1, y0, 0], [x1, y1, 0], [x0, y1, 0.0]]),
              np.array([[0, 1, 2], [0, 2, 3]]))
        b.add("ceiling", np.array([[x0, y0, ROOM_Z_M], [x1, y0, ROOM_Z_M], [x1, y1, ROOM_Z_M],
                                   [x0, y1, ROOM_Z_M]]), np.array([[0, 2, 1], [0, 3, 2]]))
        # the wall on the low-x side and the low-y side of every room; doors lead to the
        # neighbour there (outer walls have none)
        has_left, has_front = i > 0, j > 0
        _wall_with_door(b, (x, y, 0.0), (x + WALL_M, y + ROOM_Y_M, ROOM_Z_M), 1,
                        y + ROOM_Y_M / 2 if has_left else None)
        _wall_with_door(b, (x + WALL_M, y, 0.0), (x + ROOM_X_M, y + WALL_M, ROOM_Z_M), 0,
                        x + ROOM_X_M / 2 if has_front else None)
        _furnish(b, x0, y0, rng)
    # closing walls on the high-x and high-y sides of the whole floor
    width, depth = cols * ROOM_X_M, rows * ROOM_Y_M
    b.box("wall", (width, 0.0, 0.0), (width + WALL_M, depth + WALL_M, ROOM_Z_M))
    b.box("wall", (0.0, depth, 0.0), (width, depth + WALL_M, ROOM_Z_M))
    return b


def room_stations(n_rooms: int, height_m: float = 1.6) -> list[tuple[float, float, float]]:
    """Three explicit candidates per room, on its long axis, clear of the furniture."""
    cols = max(1, math.ceil(math.sqrt(n_rooms * ROOM_Y_M / ROOM_X_M)))
    inner_x, inner_y = ROOM_X_M - WALL_M, ROOM_Y_M - WALL_M
    points = []
    for k in range(n_rooms):
        x0 = (k % cols) * ROOM_X_M + WALL_M
        y0 = (k // cols) * ROOM_Y_M + WALL_M
        for fx in (0.3, 0.55, 0.8):
            points.append((round(x0 + fx * inner_x, 3), round(y0 + 0.5 * inner_y, 3), height_m))
    return points


def rooms_for(target_faces: float) -> int:
    return max(1, round(target_faces / FACES_PER_ROOM))


_CHILD = r"""
import json, resource, sys, tempfile, time
limit = int(sys.argv[2])
if limit > 0:
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
from planner.parameters import PlanSpec
from planner.pipeline import plan
from planner.io.readers import read_scene
from planner.outputs.report import write_outputs
t0 = time.perf_counter()
spec = PlanSpec.from_mapping(json.loads(sys.argv[3]) if len(sys.argv) > 3 else {})
scene = read_scene(sys.argv[1], split_faces="as_needed")  # as scanplan plan reads it
t1 = time.perf_counter()
result = plan(scene, spec)
t2 = time.perf_counter()
with tempfile.TemporaryDirectory() as out:
    write_outputs(result, out, names=("plan.json", "faces.npz", "stations.csv"))
t3 = time.perf_counter()
seconds = {"read": t1 - t0, **result.stats.seconds, "outputs": t3 - t2, "total": t3 - t0}
print(json.dumps({"faces": result.scene.n_faces, "candidates": len(result.candidates),
                  "stations": len(result.chosen.stations), "seconds": seconds,
                  "cpu_seconds": result.stats.cpu_seconds,
                  "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def run_child(model: Path, limit_bytes: int, spec: dict[str, object] | None = None
              ) -> dict[str, object]:
    """Plan ``model`` in a fresh interpreter (``spec``: plan parameters, default when None);
    its JSON line of figures."""
    root = Path(__file__).resolve().parents[1]
    extra = [] if spec is None else [json.dumps(spec)]
    done = subprocess.run([sys.executable, "-c", _CHILD, str(model), str(limit_bytes), *extra],
                          capture_output=True, text=True, cwd=root, check=False)
    if done.returncode != 0:
        return {"error": done.stderr.strip().splitlines()[-1] if done.stderr else "failed"}
    figures: dict[str, object] = json.loads(done.stdout.strip().splitlines()[-1])
    return figures


def _exponent(faces: list[float], values: list[float]) -> float:
    """b of the least-squares fit log(value) = a + b log(faces)."""
    slope, _ = np.polyfit(np.log(faces), np.log(values), 1)
    return float(slope)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="0.25,1,3,10", help="million faces, comma-separated")
    parser.add_argument("--limit-gb", type=float, default=8.0,
                        help="RLIMIT_AS of each child (virtual memory, not RSS)")
    parser.add_argument("--repeat", type=int, default=1)
    parser.add_argument("--candidates", choices=("grid", "rooms"), default="grid",
                        help="grid: generated (default parameters); rooms: three explicit "
                        "candidates per room, which leaves the candidate stage out")
    parser.add_argument("--occluders", choices=("remeshed", "file"), default="file",
                        help="the plan parameter occluders (default: file)")
    parser.add_argument("--keep", default=None, help="write the models here and keep them")
    args = parser.parse_args()
    sizes = [float(s) for s in args.sizes.split(",")]
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(args.keep or tmp)
        folder.mkdir(parents=True, exist_ok=True)
        rows: list[dict[str, object]] = []
        for size in sizes:
            model = folder / f"interior_{size:g}M.obj"
            n_rooms = rooms_for(size * 1e6)
            # -1: the model was kept from an earlier run (--keep)
            n_file = -1 if model.exists() else build_interior(n_rooms).write_obj(model)
            spec: dict[str, object] = {"occluders": args.occluders}
            if args.candidates == "rooms":
                spec["candidates"] = room_stations(n_rooms)
            best: dict[str, object] | None = None
            for _ in range(args.repeat):
                figures = run_child(model, int(args.limit_gb * 2**30), spec)
                if "error" in figures:
                    best = figures
                    break
                total = figures["seconds"]["total"]  # type: ignore[index]
                if best is None or total < best["seconds"]["total"]:  # type: ignore[index]
                    best = figures
            assert best is not None
            best["target_m_faces"] = size
            best["file_faces"] = n_file
            rows.append(best)
            print(json.dumps(best), flush=True)
    ok = [r for r in rows if "error" not in r]
    print()
    print(f"{'target':>7} {'faces':>10} {'cands':>6} {'read':>7} {'cands':>7} {'visib':>7} "
          f"{'select':>7} {'output':>7} {'total':>7} {'peak MB':>8}")
    for r in rows:
        if "error" in r:
            print(f"{r['target_m_faces']:>6}M  failed: {r['error']}")
            continue
        s = r["seconds"]
        print(f"{r['target_m_faces']:>6}M {r['faces']:>10,} {r['candidates']:>6} "  # type: ignore[index]
              f"{s['read']:>7.1f} {s['candidates']:>7.1f} {s['visibility']:>7.1f} "  # type: ignore[index]
              f"{s['selection']:>7.1f} {s['outputs']:>7.1f} {s['total']:>7.1f} "  # type: ignore[index]
              f"{r['peak_rss_mb']:>8.0f}")
    if len(ok) >= 2:
        faces = [float(r["faces"]) for r in ok]  # type: ignore[arg-type]
        total = [float(r["seconds"]["total"]) for r in ok]  # type: ignore[index]
        peak = [float(r["peak_rss_mb"]) for r in ok]  # type: ignore[arg-type]
        print(f"time ~ faces^{_exponent(faces, total):.2f}, "
              f"peak RSS ~ faces^{_exponent(faces, peak):.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
