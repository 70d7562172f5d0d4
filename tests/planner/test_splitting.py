"""Faces that no candidate can qualify any part of are kept whole (planner.visibility.splitting)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import trimesh

from planner.parameters import PlanSpec
from planner.pipeline import plan
from planner.scene import Scene, build_scene, remesh
from tests.planner.survey_scenes import Box, room_shell

MAX_EDGE_M = 0.5


def _file_scene(boxes: list[Box]) -> Scene:
    """Boxes as a file would hold them: two triangles a side, nothing split."""
    parts = [trimesh.creation.box(bounds=np.array(box, float)) for box in boxes]
    offsets = np.cumsum([0] + [len(p.vertices) for p in parts])
    return build_scene(np.concatenate([p.vertices for p in parts]),
                       np.concatenate([p.faces + o for p, o in zip(parts, offsets, strict=False)]))


def test_faces_no_candidate_can_qualify_stay_whole_and_the_plan_is_the_same() -> None:
    shelf: Box = ((0.2, 3.5, 1.49), (0.6, 3.9, 1.51))  # its top and bottom level with the scanner
    far_slab: Box = ((30.0, 0.0, 0.0), (40.0, 4.0, 0.2))  # 26 m beyond the density range
    boxes = [*room_shell(0.0, 4.0, 0.0, 4.0), shelf, far_slab]
    file_scene = _file_scene(boxes)
    spec = PlanSpec(candidates=tuple((x, y, 1.5) for x in (1.0, 2.0, 3.0) for y in (1.0, 3.0)),
                    max_edge_m=MAX_EDGE_M)
    every = plan(remesh(file_scene, MAX_EDGE_M), spec)
    needed = plan(dataclasses.replace(file_scene, split_max_edge_m=MAX_EDGE_M), spec)

    pieces = np.bincount(needed.scene.source_face, minlength=file_scene.n_faces)
    every_pieces = np.bincount(every.scene.source_face, minlength=file_scene.n_faces)
    kept_whole = (pieces == 1) & (every_pieces > 1)
    # the far slab (12 faces, all long) and the shelf's top and bottom (4) stay whole
    first_of = np.cumsum([0] + [12] * len(boxes))
    assert set(np.flatnonzero(kept_whole)) == (
        set(range(first_of[-2], first_of[-1]))  # the far slab
        | {f for f in range(first_of[-3], first_of[-2])  # the shelf's horizontal faces
           if abs(file_scene.normals[f, 2]) == 1.0})
    assert needed.scene.n_faces < every.scene.n_faces
    # no piece of a face kept whole qualified from any candidate when everything was split
    assert (every.faces["n_candidates"][kept_whole[every.scene.source_face]] == 0).all()
    # and nothing else changed: stations, coverage, and every split face's pieces
    assert needed.chosen.stations == every.chosen.stations
    assert needed.chosen.covered_area_m2 == every.chosen.covered_area_m2
    split_every = ~kept_whole[every.scene.source_face]
    split_needed = ~kept_whole[needed.scene.source_face]
    for name, values in every.faces.items():
        assert np.array_equal(values[split_every], needed.faces[name][split_needed]), name


def _piece_rows(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F,) the pieces' corners in their order, as sortable byte rows."""
    corners = np.ascontiguousarray(vertices[faces].reshape(len(faces), 9))
    return np.sort(corners.view(np.dtype((np.void, 72))).ravel())


def test_kept_pieces_are_the_split_s_pieces_big_faces_quartered_first(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """kept_pieces gives the pieces subdivide gives, corner for corner, also where a face
    too big for one block is first quartered as trimesh's first step does, and a sliver
    (one or two long edges) that cannot be is split whole; ``keep`` drops the rest,
    quarters it drops included."""
    import planner.scene as scene_module
    from planner.scene import kept_pieces, subdivide

    monkeypatch.setattr(scene_module, "_SIFTED_BLOCK_PIECES", 64)
    monkeypatch.setattr(scene_module, "_QUARTER_PIECES", 16)
    vertices = np.array([[0.0, 0.0, 0.0], [7.3, 0.4, 0.0], [2.1, 5.9, 1.3],  # big
                         [0.0, 0.0, 2.0], [6.0, 0.0, 2.0], [6.0, 0.1, 2.0],  # one long edge
                         [0.0, 0.0, 3.0], [4.0, 0.0, 3.0], [2.0, 0.15, 3.0],  # two long edges
                         [1.0, 1.0, 0.0], [1.1, 1.0, 0.0], [1.0, 1.1, 0.0]])  # small
    faces = np.arange(12, dtype=np.int32).reshape(4, 3)
    split = subdivide(vertices, faces, MAX_EDGE_M)
    assert split is not None
    every = _piece_rows(*split[:2])
    assert len(every) > 4 * 64  # the big face alone is more than one block

    def everything(v: np.ndarray, f: np.ndarray) -> np.ndarray:
        return np.ones(len(f), bool)

    kept_vertices, kept_faces = kept_pieces(vertices, faces, MAX_EDGE_M, everything)
    assert np.array_equal(_piece_rows(kept_vertices, kept_faces), every)

    def low(v: np.ndarray, f: np.ndarray) -> np.ndarray:
        """A box test, as kept_pieces needs: reaches below 0.5 m near x = 1 m."""
        return (v[f, 2].min(axis=1) < 0.5) & (v[f, 0].min(axis=1) < 1.0)

    kept_vertices, kept_faces = kept_pieces(vertices, faces, MAX_EDGE_M, low)
    near_ground = split[1][low(split[0], split[1])]
    assert 0 < len(near_ground) < len(split[1]) // 4  # most quarters of the big face dropped
    assert np.array_equal(_piece_rows(kept_vertices, kept_faces),
                          _piece_rows(split[0], near_ground))


def test_split_to_size_gives_trimesh_s_pieces_value_for_value() -> None:
    """split_to_size, the split's own subdivision with less scratch, gives what
    trimesh.remesh.subdivide_to_size gives: the same vertices (the midpoints numbered
    alike), faces and source faces, in the same order, for meshes with shared edges,
    slivers (one or two long edges), repeated and degenerate faces."""
    from planner.scene import split_to_size

    rng = np.random.default_rng(7)
    meshes = [trimesh.creation.icosphere(subdivisions=2, radius=3.0),
              trimesh.creation.box(extents=(4.0, 0.3, 2.5)),
              trimesh.creation.cylinder(radius=0.4, height=6.0, sections=17)]
    for number, mesh in enumerate(meshes):
        vertices = np.asarray(mesh.vertices) * rng.uniform(0.2, 1.5, 3) + rng.uniform(-50, 50, 3)
        faces = np.asarray(mesh.faces)
        faces = np.concatenate([faces, faces[:4], [[0, 0, 1]], faces[::-1, ::-1]])
        for max_edge_m in (0.07, 0.33, 1.1):
            expected = trimesh.remesh.subdivide_to_size(
                vertices, faces, max_edge=max_edge_m, max_iter=12, return_index=True)
            got = split_to_size(vertices, faces, max_edge_m, 12)
            for name, want, have in zip(("vertices", "faces", "index"), expected, got,
                                        strict=True):
                assert np.array_equal(want, have), (number, max_edge_m, name)
    with pytest.raises(ValueError, match="max_iter"):
        split_to_size(np.array([[0.0, 0, 0], [9, 0, 0], [0, 9, 0]]), np.array([[0, 1, 2]]),
                      0.1, 2)


def test_long_edges_are_those_trimesh_measures_bit_for_bit() -> None:
    """The split's compiled edge test finds the same long edges as trimesh's numpy
    measure, also for a limit equal to an edge's own length (to the last bit)."""
    from planner.scene import _long_edges

    rng = np.random.default_rng(3)
    vertices = rng.uniform(-300, 300, (20_000, 3)) * rng.choice([1e-3, 1.0, 10.0], (20_000, 1))
    faces = rng.integers(0, len(vertices), (50_000, 3)).astype(np.int32)
    # the lengths as trimesh measures them: from the smaller corner index to the larger
    ends = np.sort(np.stack([faces, np.roll(faces, -1, axis=1)], axis=2), axis=2)
    length_m = ((vertices[ends[..., 0]] - vertices[ends[..., 1]]) ** 2).sum(axis=2) ** 0.5
    for max_edge_m in (0.2, 1.0, 50.0, *length_m[:50, 2]):
        assert np.array_equal(_long_edges(vertices, faces, float(max_edge_m)),
                              length_m > max_edge_m)


def test_pieces_per_file_face_counts_each_file_faces_pieces() -> None:
    """The count of pieces per file face, read off the pieces in file order without an
    (F,) copy, is the count numpy's bincount gives, and so when the pieces are not in
    file order."""
    boxes = _file_scene(room_shell(0.0, 4.0, 0.0, 3.0))
    scene = remesh(boxes, 0.4, split=np.arange(boxes.n_faces) % 3 > 0)
    expected = np.bincount(scene.source_face, minlength=len(scene.file_mesh[1]))
    assert (expected > 1).any() and (expected == 1).any()
    assert np.array_equal(scene.pieces_per_file_face(), expected)
    shuffled = np.random.default_rng(5).permutation(scene.n_faces)
    unordered = Scene(vertices=scene.vertices, faces=scene.faces[shuffled],
                      file_face_group=scene.file_face_group, groups=scene.groups,
                      source_face=scene.source_face[shuffled],
                      file_face_element=scene.file_face_element,
                      file_vertices=scene.file_vertices, file_faces=scene.file_faces)
    assert np.array_equal(unordered.pieces_per_file_face(), expected)
