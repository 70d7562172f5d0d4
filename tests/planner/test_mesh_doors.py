"""Doors as authoring tools export them, in plain meshes: the real buildings of
``shared/scenes/buildings`` exported without classes (:func:`export_plain_mesh`), their doors
found by :func:`planner.walkgraph.mesh_doors` against the IFC model's own IfcDoor, and the
route through them, with the real Embree caster.

Bounds: at least 90 % of the IfcDoor found (a door is found when a quarter of its area is:
its leaf, beside a frame and a lining), so that a crew is not sent round more than one door
in ten; and no more false doors than a tenth of the IfcDoor plus two, each a thin panel of
door height under a lintel between two rooms (a window to the floor, a screen): a false door
lets the walk through such a panel, never through a wall, since a wall is thicker than its
leaf or as thick at every height.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.sparse.csgraph import connected_components

from planner.io.readers import read_scene
from planner.rays import make_ray_caster
from planner.scene import Scene
from planner.walkgraph import build_walk_graph, door_faces, mesh_doors
from tests.planner.buildings import door_score, export_plain_mesh
from tests.planner.ifc_models import read_ifc_once

pytest.importorskip("ifcopenshell")

# a building per tool: Renga (a leaf as one box, flush with the jambs), Revit (frames,
# linings and leaves as parts, feet, a site around), ArchiCAD (leaves ajar, finely tessellated)
BUILDINGS = ("Renga-House", "Lantern_Hollow", "AC90R1-niedriha-V2-2x3")


@pytest.fixture(scope="module")
def plain_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("plain-doors")


def building(name: str, scenes_dir: Path, plain_dir: Path) -> tuple[Scene, Scene]:
    """(the IFC reading, its plain export read back as a user's OBJ)."""
    path = scenes_dir / "buildings" / f"{name}.ifc"
    if not path.exists():
        pytest.skip(f"{path} is not in the shared scenes")
    ifc = read_ifc_once(path)
    obj = plain_dir / f"{name}.obj"
    if not obj.exists():
        export_plain_mesh(path, obj, ifc)
    plain = read_scene(obj, max_edge_m=None)
    assert plain.n_faces == ifc.n_faces and not plain.elements
    return ifc, plain


@pytest.mark.parametrize("name", BUILDINGS)
def test_the_doors_of_a_plain_export_are_the_ifc_models_doors(
        name: str, scenes_dir: Path, plain_dir: Path) -> None:
    ifc, plain = building(name, scenes_dir, plain_dir)
    caster = make_ray_caster(plain, np.ones(plain.n_faces, bool))
    doors = mesh_doors(plain, caster)
    np.testing.assert_array_equal(doors >= 0, door_faces(plain, caster))
    score = door_score(ifc, doors >= 0)
    assert score.ifc_doors_found >= 0.9 * score.ifc_doors, score
    assert score.false <= score.ifc_doors // 4 + 1, score
    # every door is numbered once, in order
    assert np.array_equal(np.unique(doors[doors >= 0]), np.arange(doors.max() + 1))


@pytest.mark.parametrize("name", ["Lantern_Hollow", "Renga-House"])
def test_the_plain_exports_walk_joins_every_room_the_ifc_doors_join(
        name: str, scenes_dir: Path, plain_dir: Path) -> None:
    """The walk graph with the rule's doors open joins every part of the floor that it
    joins with the IFC model's own doors open (the same mesh, IfcDoor faces open): no room
    is left behind a door the rule missed. (Revit, Renga; a part of at least 2 m².)"""
    ifc, plain = building(name, scenes_dir, plain_dir)
    caster = make_ray_caster(plain, np.ones(plain.n_faces, bool))
    parts = {}
    for how, doors in (("rule", door_faces(plain, caster)), ("IfcDoor", door_faces(ifc))):
        graph = build_walk_graph(plain, make_ray_caster(plain, ~doors))
        _, labels = connected_components(graph.links, directed=False)
        keys = [tuple(k) for k in np.round(graph.floor_xyz / 0.01).astype(np.int64).tolist()]
        parts[how] = dict(zip(keys, labels.tolist(), strict=True))
    common = sorted(set(parts["rule"]) & set(parts["IfcDoor"]))
    truth = np.array([parts["IfcDoor"][k] for k in common])
    found = np.array([parts["rule"][k] for k in common])
    assert len(common) >= 0.95 * len(parts["IfcDoor"])
    smallest = 2.0 / 0.25**2  # floor samples in 2 m^2
    split = []  # parts joined by IfcDoor with a piece of 2 m^2 or more cut off by the rule
    for part in np.unique(truth):
        pieces = np.bincount(found[truth == part])
        if (np.sort(pieces)[:-1] >= smallest).any():
            split.append(int(part))
    assert split == [], f"{len(split)} parts of the floor joined through IfcDoor are cut"
