"""Overlap rows that take the coverage table's verdicts: the same rows, fewer rays."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from planner.candidates.generate import plan_candidates
from planner.io.readers import read_scene
from planner.parameters import PlanSpec
from planner.progress import Stats
from planner.scene import Scene, build_scene
from planner.visibility.coincident import covered_pieces, twin_pairs
from planner.visibility.coverage import CoverageTable
from planner.visibility.overlap import OverlapRows, SeenFaces
from planner.visibility.qualify import Sight, coverage_table
from planner.walkgraph import door_faces


@dataclasses.dataclass(frozen=True)
class House:
    sight: Sight
    table: CoverageTable
    positions: np.ndarray  # (C, 3) the candidates


@pytest.fixture(scope="module")
def house(scenes_dir: Path) -> House:
    """The IFC house with doors, split as a plan splits it, and its coverage table."""
    spec = PlanSpec()
    scene = read_scene(scenes_dir / "IfcOpenHouse_IFC4.ifc", max_edge_m=spec.max_edge_m,
                       split_faces="as_needed")
    sight = Sight.of(scene, spec, "embree")
    candidates, _ = plan_candidates(scene, spec, sight.caster)
    sight = sight.split_as_needed(candidates.positions)
    table = coverage_table(sight, candidates.positions, Stats())
    return House(sight, table, candidates.positions)


def _rows(house: House, picks: np.ndarray, seen: SeenFaces | None) -> OverlapRows:
    sight = house.sight
    return OverlapRows(sight.scene, house.positions[picks], sight.limits, sight.occlusion,
                       sight.spec.overlap_density_pts_m2, file_faces=sight.file_faces,
                       seen=seen)


def test_rows_are_the_same_with_fewer_rays(house: House) -> None:
    picks = np.arange(0, len(house.positions), 7)
    cast = _rows(house, picks, None)
    reused = _rows(house, picks, house.sight.seen_faces(house.table, house.positions, picks))
    a, b = cast.matrix(range(len(picks))), reused.matrix(range(len(picks)))
    assert a.nnz > 10_000
    assert np.array_equal(a.indptr, b.indptr) and np.array_equal(a.indices, b.indices)
    assert door_faces(house.sight.scene).any()  # doors: the rows' occluders differ
    assert reused.rays_saved > 0 and cast.rays_saved == 0
    assert reused.rays_cast + reused.rays_saved == cast.rays_cast


def test_only_faces_the_proof_covers_are_taken_over(house: House) -> None:
    """A face the table holds but whose verdict may differ is cast: doors (they occlude in
    the table, not in the rows) and pieces on a coplanar twin. Told that every face is
    visible from its candidates, the rows still hold only faces they would see."""
    picks = np.arange(3, len(house.positions), 11)
    sight = house.sight
    scene = sight.scene
    seen = sight.seen_faces(house.table, house.positions, picks)
    assert seen is not None
    rows = _rows(house, picks, seen)
    rows.ensure([0])
    reusable = rows._reusable
    assert reusable is not None
    assert not reusable[door_faces(scene) & sight.limits.occludes].any()
    # a table whose rows hold every face: the rows take over what it says only for the
    # faces the proof covers, so a hidden face outside them stays out
    everything = CoverageTable.from_blocks([], len(house.positions), scene.areas)
    n = scene.n_faces
    everything = dataclasses.replace(
        everything, run_ptr=np.arange(len(house.positions) + 1, dtype=np.int64),
        run_start=np.zeros(len(house.positions), np.int32),
        run_length=np.full(len(house.positions), n, np.int32),
        pair_ptr=np.arange(len(house.positions) + 1, dtype=np.int64) * n)
    lying = _rows(house, picks, dataclasses.replace(seen, table=everything))
    truth = _rows(house, picks, None).matrix(range(len(picks)))
    told = lying.matrix(range(len(picks)))
    extra = told - truth  # faces the lie added: only reusable ones, never a door
    extra.eliminate_zeros()
    assert extra.nnz > 0 and extra.min() >= 0
    assert reusable[extra.indices].all()
    assert not (door_faces(scene) & sight.limits.occludes)[extra.indices].any()


def test_no_proof_other_positions_or_sampled(house: House) -> None:
    picks = np.arange(0, len(house.positions), 9)
    sight = house.sight
    seen = sight.seen_faces(house.table, house.positions, picks)
    assert seen is not None
    assert _rows(house, picks, seen)._seen is not None
    moved = dataclasses.replace(seen, positions=house.positions + 1e-9)
    assert _rows(house, picks, moved)._seen is None  # not the table's positions
    shifted = dataclasses.replace(seen, candidates=seen.candidates[::-1].copy())
    assert _rows(house, picks, shifted)._seen is None
    sampled = dataclasses.replace(sight, spec=dataclasses.replace(sight.spec,
                                                                  coverage_model="sampled"))
    assert sampled.seen_faces(house.table, house.positions, picks) is None


def _twin_scene() -> Scene:
    """A 2 x 2 m floor square (two triangles) at z = 0, a 1 x 1 m square (two triangles)
    lying on it over [0, 1]^2 and a wall square standing on its edge."""
    vertices = np.array([
        [0, 0, 0], [2, 0, 0], [2, 2, 0], [0, 2, 0],  # floor
        [0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0],  # twin on the floor
        [2, 0, 0], [2, 2, 0], [2, 2, 1], [2, 0, 1],  # wall at x = 2
    ], np.float64)
    faces = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7], [8, 9, 10], [8, 10, 11]],
                     np.int32)
    return build_scene(vertices, faces)


def test_twins_are_coplanar_overlapping_faces() -> None:
    scene = _twin_scene()
    pairs = {tuple(sorted(p)) for p in twin_pairs(scene.vertices, scene.faces,
                                                  np.arange(6)).tolist()}
    # the floor's halves share their diagonal and the wall only touches the floor: no
    # twins; the small square's halves lie on the floor's halves
    assert (0, 1) not in pairs and (2, 3) not in pairs
    assert not any(4 in p or 5 in p for p in pairs)
    assert pairs == {(0, 2), (1, 3)}
    # a point of the floor on the small square is covered, one beside it is not
    centroids = np.array([[0.3, 0.6, 0.0], [1.5, 1.5, 0.0], [1.9, 0.1, 0.0]])
    covered = covered_pieces(centroids, np.array([1, 1, 0]), scene.vertices, scene.faces,
                             np.array(sorted(pairs), np.int64))
    assert covered.tolist() == [True, False, False]
