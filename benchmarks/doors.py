"""Doors found in plain meshes against the IFC model's own doors, on every shared building.

For each IFC building in ``shared/scenes/buildings`` and the shared IFC houses: the model is
read with IfcOpenShell (:func:`planner.io.ifc.read_ifc`), exported as a plain mesh (no
classes, no groups: :func:`tests.planner.buildings.export_plain_mesh`), read back as a user's
OBJ is read, and the plain mesh's door rule (:func:`planner.walkgraph.door_faces` with a
caster over every face) is run on it. The exported faces keep the IFC reading's order, so
the IFC model's door faces (``door_faces`` of the IFC scene: ``IfcDoor``) are the truth.

A *found door* is a group of found faces that touch (bounding boxes within ``TOUCH_M``); it
is *true* when at least half of its area is on IfcDoor faces, else *false*. An IfcDoor is
*found* when at least half of its area is found; the rest are *missed*. ``rule s`` is the
rule's CPU time. Prints a table; never passes or fails::

    .venv/bin/python benchmarks/doors.py [model.ifc ...] [--cache DIR]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from planner.io.ifc import read_ifc
from planner.io.readers import read_scene
from planner.rays import make_ray_caster
from planner.walkgraph import door_faces
from tests.planner.buildings import export_plain_mesh

SCENES = Path(__file__).resolve().parents[2] / "shared" / "scenes"
TOUCH_M = 0.05  # found faces this close belong to one found door
_CELL_M = 0.5  # the grid that pairs nearby faces


def default_models() -> list[Path]:
    return sorted((SCENES / "buildings").glob("*.ifc")) + sorted(SCENES.glob("*.ifc"))


def touching_groups(triangles: NDArray[np.float64]) -> NDArray[np.int64]:
    """(T,) group of each of the (T, 3, 3) triangles: triangles whose boxes, grown by
    ``TOUCH_M``, overlap are joined (transitively)."""
    n = len(triangles)
    if n == 0:
        return np.zeros(0, np.int64)
    lo = triangles.min(axis=1) - TOUCH_M
    hi = triangles.max(axis=1) + TOUCH_M
    first = np.floor(lo / _CELL_M).astype(np.int64)
    last = np.floor(hi / _CELL_M).astype(np.int64)
    cells: dict[tuple[int, int, int], list[int]] = {}
    for i in range(n):
        for cx in range(first[i, 0], last[i, 0] + 1):
            for cy in range(first[i, 1], last[i, 1] + 1):
                for cz in range(first[i, 2], last[i, 2] + 1):
                    cells.setdefault((cx, cy, cz), []).append(i)
    rows: list[NDArray[np.int64]] = []
    cols: list[NDArray[np.int64]] = []
    for members in cells.values():
        m = np.asarray(members)
        if len(m) < 2:
            continue
        a, b = np.triu_indices(len(m), 1)
        a, b = m[a], m[b]
        overlap = ((lo[a] <= hi[b]) & (lo[b] <= hi[a])).all(axis=1)
        rows.append(a[overlap])
        cols.append(b[overlap])
    r = np.concatenate(rows) if rows else np.zeros(0, np.int64)
    c = np.concatenate(cols) if cols else np.zeros(0, np.int64)
    graph = coo_matrix((np.ones(len(r), np.int8), (r, c)), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    return labels.astype(np.int64)


def score(path: Path, folder: Path) -> dict[str, object]:
    ifc = read_ifc(path)
    truth = door_faces(ifc)  # (F,) IfcDoor faces of the IFC reading = of the plain export
    element = np.asarray(ifc.face_element)
    n_doors = sum(e.ifc_class == "IfcDoor" for e in ifc.elements)
    plain = export_plain_mesh(path, folder / f"{path.stem}.obj", ifc)
    scene = read_scene(plain, max_edge_m=None)
    assert scene.n_faces == ifc.n_faces and not scene.elements
    caster = make_ray_caster(scene, np.ones(scene.n_faces, bool))
    t0 = time.process_time()
    found = door_faces(scene, caster)
    seconds = time.process_time() - t0
    triangles = scene.triangles
    area = np.linalg.norm(np.cross(triangles[:, 1] - triangles[:, 0],
                                   triangles[:, 2] - triangles[:, 0]), axis=1) / 2
    index = np.flatnonzero(found)
    groups = touching_groups(triangles[index])
    n_groups = int(groups.max()) + 1 if len(groups) else 0
    on_door = np.bincount(groups, area[index] * truth[index], n_groups)
    total = np.bincount(groups, area[index], n_groups)
    true_groups = int((on_door >= 0.5 * total).sum())
    door_ids = np.unique(element[truth])
    door_area = np.bincount(element[truth], area[truth], element.max() + 1)
    found_area = np.bincount(element[truth & found], area[truth & found], element.max() + 1)
    doors_found = int((found_area[door_ids] >= 0.5 * door_area[door_ids]).sum())
    return {"model": path.stem, "IfcDoor": n_doors, "found": n_groups,
            "true": true_groups, "false": n_groups - true_groups,
            "IfcDoor found": doors_found, "missed": n_doors - doors_found,
            "rule s": round(seconds, 2), "faces": scene.n_faces}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("models", nargs="*", type=Path)
    parser.add_argument("--cache", type=Path, help="keep the plain meshes here")
    args = parser.parse_args()
    models = args.models or default_models()
    columns = ["model", "faces", "IfcDoor", "found", "true", "false", "IfcDoor found",
               "missed", "rule s"]
    print(" | ".join(columns))
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.cache or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        for path in models:
            row = score(path, folder)
            print(" | ".join(str(row[c]) for c in columns), flush=True)


if __name__ == "__main__":
    main()
