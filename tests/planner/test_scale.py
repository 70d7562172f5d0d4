"""Building scale: blockwise remesh, rays against the file's own faces, bounded memory."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import trimesh

from planner import pipeline
from planner import scene as scene_module
from planner.candidates.grid import read_candidates_csv
from planner.io.readers import read_scene
from planner.limits import FaceLimits
from planner.parameters import PlanSpec
from planner.pipeline import plan
from planner.rays import make_occlusion
from planner.scene import build_scene, remesh
from planner.visibility import bundles
from planner.visibility.coverage import CoverageTable, StationRows
from planner.visibility.pairs import PairFinder
from tests.planner.plan_files import assert_same_files, files_of

ROOT = Path(__file__).resolve().parents[2]


def _room_with_pillar() -> trimesh.Trimesh:
    """A closed 8 x 6 x 3 m room (big faces) and a 0.4 x 0.4 x 2 m cabinet: occlusion.

    The cabinet stands 0.2 m off the floor so that no face coincides with another (two
    coincident faces tie, and Embree's order among ties depends on the BVH).
    """
    room = trimesh.creation.box(extents=(8.0, 6.0, 3.0))
    room.invert()  # normals inward, as the walls of a room
    pillar = trimesh.creation.box(extents=(0.4, 0.4, 2.0))
    pillar.apply_translation((1.0, 0.5, -0.3))
    mesh = trimesh.util.concatenate([room, pillar])
    mesh.apply_translation((0.0, 0.0, 1.5))
    return mesh


def test_blockwise_remesh_gives_the_pieces_of_one_call(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    mesh = _room_with_pillar()
    raw = build_scene(mesh.vertices, mesh.faces)
    whole = remesh(raw, 0.25)
    monkeypatch.setattr(scene_module, "_REMESH_BLOCK_PIECES", 64)  # many tiny blocks
    monkeypatch.setattr(scene_module, "_DERIVE_BLOCK_FACES", 1000)
    blocks = remesh(raw, 0.25)
    assert blocks.n_faces == whole.n_faces > 20 * raw.n_faces
    for name in ("centroids", "normals", "areas", "source_face", "face_group"):
        assert np.array_equal(getattr(blocks, name), getattr(whole, name)), name
    assert np.array_equal(blocks.triangles, whole.triangles)
    # the file's mesh stays beside the pieces, for the rays
    assert blocks.file_mesh[1].shape == (raw.n_faces, 3)
    assert np.array_equal(blocks.file_mesh[0], raw.vertices)


def test_rays_against_file_faces_find_the_same_pairs_as_against_pieces() -> None:
    mesh = _room_with_pillar()
    scene = remesh(build_scene(mesh.vertices, mesh.faces), 0.2)
    # off the mesh's lattice: a ray through a cabinet's corner edge exactly may slip between
    # two pieces but not through the watertight file faces (seen with a candidate at 0, 0)
    spec = PlanSpec(candidates=((-2.47, -1.53, 1.5), (2.51, 2.03, 1.6), (0.03, -0.07, 1.5)))
    limits = FaceLimits.from_spec(spec, scene)
    pairs, _ = PairFinder(scene, limits).find(np.array(spec.candidates), 0)
    rays = (pairs.origin, pairs.direction, pairs.distance_m, pairs.face)
    pieces = make_occlusion(scene, limits.occludes, "embree").visible(*rays)
    files = make_occlusion(scene, limits.occludes, "embree", file_faces=True).visible(*rays)
    assert 0 < pieces.sum() < len(pieces)  # the cabinet hides some pieces
    assert np.array_equal(files, pieces)


def test_first_hit_on_file_faces_names_a_piece_of_the_face_hit() -> None:
    mesh = _room_with_pillar()
    scene = remesh(build_scene(mesh.vertices, mesh.faces), 0.2)
    caster = make_occlusion(scene, np.ones(scene.n_faces, bool), "embree", file_faces=True)
    origins = np.array([[0.0, 0.0, 1.5], [1.0, 0.5, 2.9]])
    face, distance = caster.first_hit(origins, np.array([[0.0, 0.0, -1.0]] * 2))  # type: ignore[attr-defined]
    assert distance.tolist() == pytest.approx([1.5, 0.7])  # the floor, the cabinet's top
    floor, cabinet_top = face
    assert scene.centroids[floor, 2] == pytest.approx(0.0)
    assert scene.centroids[cabinet_top, 2] == pytest.approx(2.2)


def test_a_plan_keeps_its_stations_rows_and_writes_the_files_of_the_whole_table(
        scenes_dir: Path, tmp_path: Path) -> None:
    """A plan lets its coverage table go before the survey and keeps its stations' rows
    (StationRows): every file it writes is the one a plan that kept the table writes, and
    it answers for its stations as the table does."""
    scene = read_scene(scenes_dir / "IfcOpenHouse_IFC4.ifc", split_faces="as_needed")
    whole = plan(scene, PlanSpec(), keep_table=True)
    lean = plan(scene, PlanSpec())
    assert isinstance(whole.table, CoverageTable) and isinstance(lean.table, StationRows)
    assert lean.chosen.stations == whole.chosen.stations
    assert lean.table.n_pairs == whole.table.n_pairs
    assert lean.table.n_candidates == whole.table.n_candidates
    assert lean.table.max_achievable_area_m2 == whole.table.max_achievable_area_m2
    np.testing.assert_array_equal(lean.table.achievable, whole.table.achievable)
    for station in lean.chosen.stations:
        np.testing.assert_array_equal(lean.table.faces_of(station), whole.table.faces_of(station))
    other = next(c for c in range(whole.table.n_candidates) if c not in lean.chosen.stations)
    with pytest.raises(KeyError, match="keep_table=True"):
        lean.table.faces_of(other)
    assert_same_files(files_of(whole, tmp_path / "whole"), files_of(lean, tmp_path / "lean"))


def test_bundles_let_go_for_the_selection_give_the_same_files(
        scenes_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """On a large model the plan lets the pieces' bundles go before the selection and the
    overlap rows make them again: the files are those of a plan that kept them."""
    scene = read_scene(scenes_dir / "IfcOpenHouse_IFC4.ifc", split_faces="as_needed")
    kept = files_of(plan(scene, PlanSpec()), tmp_path / "kept")
    held_in_selection: list[bool] = []
    choose = pipeline.choose

    def watched(sight: Any, *args: Any, **kwargs: Any) -> Any:
        held_in_selection.append(sight.scene in bundles._CACHE)
        return choose(sight, *args, **kwargs)

    monkeypatch.setattr(pipeline, "choose", watched)
    monkeypatch.setattr(pipeline, "BOUNDED_HEAP_FACES", 0)  # this house counts as large
    scene = read_scene(scenes_dir / "IfcOpenHouse_IFC4.ifc", split_faces="as_needed")
    result = plan(scene, PlanSpec())
    made_again = files_of(result, tmp_path / "again")
    assert held_in_selection == [False]
    assert bundles.bundles_of(result.scene) is not None, "the house has no bundles to let go"
    assert_same_files(kept, made_again)


def test_file_faces_keep_the_hall_results(scenes_dir: Path) -> None:
    """hall-small remeshed at 0.1 m: the same stations either way, the same areas to 1e-4.

    Of 1.09 M qualified pairs, a few dozen differ: rays that pass exactly through an edge
    or vertex of the lattice-aligned hall (a watertight file face catches a ray that can
    slip between two pieces, and the other way round at a piece's own edge).
    """
    hall = scenes_dir / "hall-small"
    scene = read_scene(hall / "hall.obj", max_edge_m=0.1)
    assert scene.file_faces is not None and scene.n_faces > len(scene.file_faces)
    positions = read_candidates_csv(hall / "candidates.csv")[::4]
    spec = PlanSpec(candidates=tuple(map(tuple, positions.tolist())), max_edge_m=0.1)
    pieces = plan(scene, dataclasses.replace(spec, occluders="remeshed"), keep_table=True)
    files = plan(scene, dataclasses.replace(spec, occluders="file"), keep_table=True)
    assert files.chosen.stations == pieces.chosen.stations
    assert files.table.max_achievable_area_m2 == pytest.approx(
        pieces.table.max_achievable_area_m2, rel=1e-4)
    differ = (files.table.by_candidate != pieces.table.by_candidate).nnz
    assert differ < 1e-4 * pieces.table.n_pairs


_CHILD = r"""
import importlib.util, json, resource, sys
spec_path, model, budget = sys.argv[1], sys.argv[2], int(sys.argv[3])
from planner.parameters import PlanSpec
from planner.pipeline import plan
from planner.io.readers import read_scene
from planner.scene import build_scene
import numpy as np
# warm up: every library imported, the kernel compiled, Embree's and the pools' threads up
tiny = build_scene(np.array([[3.0, -1, 0], [3, 1, 0], [3, 0, 2]]), np.array([[0, 1, 2]]))
plan(tiny, PlanSpec(candidates=((0.0, 0.0, 1.0),), min_density_pts_m2=1.0))
def status(key):
    for line in open("/proc/self/status"):
        if line.startswith(key + ":"):
            return int(line.split()[1]) * 1024
reserved = status("VmSize") - status("VmRSS")  # mapped, not resident: stacks, code, arenas
resource.setrlimit(resource.RLIMIT_AS, (reserved + budget, reserved + budget))
scene = read_scene(model, split_faces="as_needed")  # as scanplan plan reads it
params = json.loads(open(spec_path).read())
result = plan(scene, PlanSpec.from_mapping(params))
print(json.dumps({"faces": result.scene.n_faces, "pairs": result.table.n_pairs,
                  "candidates": len(result.candidates),
                  "stations": len(result.chosen.stations),
                  "edges": len(result.survey.registration.edges),
                  "reserved": reserved, "limit": reserved + budget,
                  "peak_rss": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024}))
"""


def _plan_scale_module() -> object:
    import importlib.util

    spec = importlib.util.spec_from_file_location("plan_scale", ROOT / "benchmarks" /
                                                  "plan_scale.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_a_3m_face_interior_plans_within_2_gb(tmp_path: Path) -> None:
    """A 3 M-face plan (after remeshing) runs under an address-space cap of 2 GiB, the way
    ``scanplan plan`` runs it: faces split as needed, grid candidates, default parameters
    but the grid's spacing (below), the survey included.

    RLIMIT_AS caps virtual memory, not RSS: numba/LLVM, Embree's thread pool, thread stacks
    and malloc arenas reserve address space they never touch. So the child first warms up
    on a one-triangle plan (all of that mapped), measures what is mapped but not resident
    (VmSize - VmRSS), and caps its address space at that plus 2 GiB. Everything it then
    makes resident is also mapped, so reading, remeshing and planning the benchmark's
    3 M-face interior fails with MemoryError unless its resident memory stays under 2 GiB;
    the cap is stricter than RSS, because new reservations (a pool's threads) count too.

    Every parameter is the default but the grid: candidates 1 m apart (1,193 of them)
    instead of 0.5 m (5,550). The face count does not change (3.2 M: every long face has a
    candidate in its room either way, so the same faces are split), nor do the stages that
    hold the peak: reading and splitting the scene (0.8 GB resident) and the survey at the
    end (1.0 GB, 981-1,012 MB measured at either spacing). What the coarser grid cuts is ray
    work: 13 M qualified pairs instead of 57 M, about half the CPU time of the plan.
    """
    plan_scale = _plan_scale_module()
    n_rooms = 96  # about 3 M faces after remeshing at 0.2 m
    model = tmp_path / "interior.obj"
    plan_scale.build_interior(n_rooms).write_obj(model)  # type: ignore[attr-defined]
    params = tmp_path / "params.json"
    params.write_text(json.dumps({"grid_spacing_m": 1.0}))
    budget = 2 * 2**30
    done = subprocess.run(
        [sys.executable, "-c", _CHILD, str(params), str(model), str(budget)],
        capture_output=True, text=True, cwd=ROOT, check=False,
        env={**os.environ, "OMP_NUM_THREADS": "2"},
    )
    assert done.returncode == 0, done.stderr[-2000:]
    figures = json.loads(done.stdout.strip().splitlines()[-1])
    assert figures["faces"] > 2_700_000
    assert figures["candidates"] > 1_000  # a candidate a square metre of free floor
    assert figures["pairs"] > 0
    assert figures["stations"] > 96  # more than one a room, each registered to another
    assert figures["edges"] > 0
    assert figures["peak_rss"] < budget, figures
