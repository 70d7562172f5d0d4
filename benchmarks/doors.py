"""Doors found in plain meshes against the IFC model's own doors, on every shared building.

For each IFC building in ``shared/scenes/buildings`` and the shared IFC houses: the model is
read with IfcOpenShell (:func:`planner.io.ifc.read_ifc`), exported as a plain mesh (no
classes, no groups: :func:`tests.planner.buildings.export_plain_mesh`), read back as a user's
OBJ is read, and the plain mesh's door rule (:func:`planner.walkgraph.found_doors` with a
caster over every face) is run on it. The exported faces keep the IFC reading's order, so
the IFC model's door faces (``door_faces`` of the IFC scene: ``IfcDoor``) are the truth.

A *found door* is a group of found faces that touch (bounding boxes within 5 cm); it is
*true* when at least half of its area is on IfcDoor faces; an *IfcWindow to the floor* when
it is not, but at least half of it is on IfcDoor and IfcWindow faces and the window's frame
stands at most 0.2 m (one step) over the floor beside it: a French window (a sash to the
floor, as Jasmin's 2.035 m casements on a 0.1 m sill) or a door's glazed sidelight, which
geometry alone cannot tell from a glazed door, so the rule takes them by design; else
*false*. An IfcDoor is
*found* when a quarter of its area is found (its leaf: a frame and lining can be larger);
the rest are *missed* (:func:`tests.planner.buildings.door_score`). *Glazed* counts the
found doors whose filler at knee height is thinner than a door leaf (a route through one
carries a door check: :attr:`planner.walkgraph.MeshDoors.glazed`); *false at* gives the
middle of each false door's box (model metres). ``rule CPU s`` is the rule's CPU time.
Prints a table; never passes or fails::

    .venv/bin/python benchmarks/doors.py [model.ifc ...] [--cache DIR]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from planner.io.ifc import read_ifc
from planner.io.readers import read_scene
from planner.rays import make_ray_caster
from planner.walkgraph import found_doors
from tests.planner.buildings import door_score, export_plain_mesh

SCENES = Path(__file__).resolve().parents[2] / "shared" / "scenes"


def default_models() -> list[Path]:
    return sorted((SCENES / "buildings").glob("*.ifc")) + sorted(SCENES.glob("*.ifc"))


def score(path: Path, folder: Path) -> dict[str, object]:
    ifc = read_ifc(path)
    plain = export_plain_mesh(path, folder / f"{path.stem}.obj", ifc)
    scene = read_scene(plain, max_edge_m=None)
    assert scene.n_faces == ifc.n_faces and not scene.elements
    caster = make_ray_caster(scene, np.ones(scene.n_faces, bool))
    t0 = time.process_time()
    doors = found_doors(scene, caster)
    seconds = time.process_time() - t0
    result = door_score(ifc, doors.face_door >= 0)
    return {"model": path.stem, "faces": scene.n_faces, "IfcDoor": result.ifc_doors,
            "found": result.found, "true": result.true,
            "IfcWindow to the floor": result.windows_to_floor, "false": result.false,
            "IfcDoor found": result.ifc_doors_found, "missed": result.missed,
            "glazed": int(doors.glazed.sum()),
            "false at": "; ".join(f"({x}, {y}, {z})" for x, y, z in result.false_at) or "-",
            "rule CPU s": round(seconds, 2)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("models", nargs="*", type=Path)
    parser.add_argument("--cache", type=Path, help="keep the plain meshes here")
    args = parser.parse_args()
    models = args.models or default_models()
    columns = ["model", "faces", "IfcDoor", "found", "true", "IfcWindow to the floor",
               "false", "IfcDoor found", "missed", "glazed", "false at", "rule CPU s"]
    print(" | ".join(columns))
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.cache or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        for path in models:
            row = score(path, folder)
            print(" | ".join(str(row[c]) for c in columns), flush=True)


if __name__ == "__main__":
    main()
