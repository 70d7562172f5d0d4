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

from planner.candidates.grid import generate_grid
from planner.io.readers import read_scene
from planner.parameters import PlanSpec
from planner.rays import make_ray_caster
from planner.scene import Scene
from planner.survey.route import plan_route
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


@pytest.mark.parametrize("name", ["Lantern_Hollow", "AC90R1-niedriha-V2-2x3"])
def test_the_route_of_a_plain_export_reaches_every_station_as_the_ifc_models_does(
        name: str, scenes_dir: Path, plain_dir: Path) -> None:
    """Both models' IFC plans reach every station (Revit, ArchiCAD); so must the plain
    mesh's route, through the doors the rule finds. Stations: candidates of every storey
    around the doors (the house, not Lantern Hollow's terrain), spread."""
    _, plain = building(name, scenes_dir, plain_dir)
    spec = PlanSpec(grid_spacing_m=1.0, max_edge_m=0.5)
    caster = make_ray_caster(plain, np.ones(plain.n_faces, bool))
    doors = door_faces(plain, caster)
    lo = plain.triangles[doors].reshape(-1, 3).min(axis=0) - 2.0
    hi = plain.triangles[doors].reshape(-1, 3).max(axis=0) + 2.0
    candidates = generate_grid(plain, spec, caster)
    xy = candidates.positions[:, :2]
    house = ((xy >= lo[:2]) & (xy <= hi[:2])).all(axis=1)
    stations = candidates.positions[house][::4]
    assert len(stations) >= 20
    walk_caster = make_ray_caster(plain, ~doors)
    route = plan_route(build_walk_graph(plain, walk_caster), walk_caster, stations, None)
    assert route.unreachable == (), list(zip(route.unreachable, route.unreachable_reasons,
                                             strict=True))
