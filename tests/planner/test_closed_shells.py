"""Closed shells: a face seen from inside its closed shell is left out of the pair search
without a ray, and every pair left out is one its ray finds hidden."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from planner.io.readers import read_scene
from planner.limits import FaceLimits
from planner.parameters import PlanSpec
from planner.rays import make_occlusion
from planner.scene import Element, Scene, build_scene, remesh
from planner.visibility.bundles import BundleCuller, bundles_of
from planner.visibility.overlap import overlap_limits
from planner.visibility.pairs import PairFinder
from planner.visibility.solids import closed_shells
from tests.planner.buildings import office_building


def _left_out_and_cast(scene: Scene, positions: np.ndarray, limits: FaceLimits
                       ) -> tuple[int, np.ndarray, np.ndarray]:
    """The pairs the search finds without shells, which of them it leaves out with the
    occlusion's closed shells, and every pair's verdict cast with its own ray."""
    occlusion = make_occlusion(scene, limits.occludes, "embree", file_faces=True)
    shells = closed_shells(scene, occlusion)
    assert shells is not None
    every, _ = PairFinder(scene, limits).find(positions, 0)
    kept, _ = PairFinder(scene, limits, shells=shells).find(positions, 0)
    key_every = every.candidate.astype(np.int64) * scene.n_faces + every.face
    key_kept = kept.candidate.astype(np.int64) * scene.n_faces + kept.face
    assert np.isin(key_kept, key_every).all()  # the shells only ever leave pairs out
    left_out = ~np.isin(key_every, key_kept)
    visible = occlusion.visible(every.origin, every.direction, every.distance_m, every.face,
                                exact_rays=every.exact_rays(positions, scene))
    return len(every), left_out, visible


def test_faces_behind_the_office_walls_need_no_ray() -> None:
    # a plain mesh: the generated office's boxes share corners where they meet, so only
    # the boxes that stand alone (desks, some walls) are closed shells of their own
    mesh = office_building(1, 2)
    scene = remesh(build_scene(np.asarray(mesh.vertices), np.asarray(mesh.faces)), 0.2)
    low, high = scene.vertices.min(axis=0), scene.vertices.max(axis=0)
    positions = np.array([(x, y, low[2] + 1.53)
                          for x in np.linspace(low[0] + 1.1, high[0] - 1.3, 4)
                          for y in np.linspace(low[1] + 1.7, high[1] - 1.9, 3)])
    limits = FaceLimits.from_spec(PlanSpec(), scene)
    n, left_out, visible = _left_out_and_cast(scene, positions, limits)
    assert left_out.sum() > n // 50  # the far sides of the free-standing boxes
    assert not visible[left_out].any()
    assert visible.sum() > 1_000


def test_a_real_house_leaves_out_only_hidden_pairs(scenes_dir: Path) -> None:
    scene = read_scene(scenes_dir / "IfcOpenHouse_IFC4.ifc", max_edge_m=0.2,
                       split_faces="all")
    limits = FaceLimits.from_spec(PlanSpec(max_edge_m=0.2, min_density_pts_m2=1600.0), scene)
    low, high = scene.vertices.min(axis=0), scene.vertices.max(axis=0)
    positions = np.array([[x, y, z] for x in np.linspace(low[0], high[0], 6)[1:-1]
                          for y in np.linspace(low[1], high[1], 6)[1:-1]
                          for z in (low[2] + 1.5, low[2] + 4.0)])
    n, left_out, visible = _left_out_and_cast(scene, positions, limits)
    assert left_out.sum() > n // 10
    assert not visible[left_out].any()


def _box(low: tuple[float, float, float], high: tuple[float, float, float]
         ) -> trimesh.Trimesh:
    return trimesh.creation.box(bounds=np.array([low, high], float))


def _elements_scene(*meshes: trimesh.Trimesh) -> Scene:
    """One element a mesh, split at 0.25 m."""
    vertices, faces, element = [], [], []
    base = 0
    for e, mesh in enumerate(meshes):
        vertices.append(np.asarray(mesh.vertices))
        faces.append(np.asarray(mesh.faces) + base)
        element.append(np.full(len(mesh.faces), e))
        base += len(mesh.vertices)
    elements = tuple(Element(f"id{e}", "IfcWall", f"wall {e}", "") for e in range(len(meshes)))
    scene = build_scene(np.concatenate(vertices), np.concatenate(faces),
                        face_element=np.concatenate(element), elements=elements)
    return remesh(scene, 0.25)


def test_a_point_inside_a_closed_shell_keeps_every_ray() -> None:
    # a hollow room drawn as a closed box: from inside, its inner faces are what one sees
    room = _box((0, 0, 0), (6, 5, 3))
    scene = _elements_scene(room, _box((8, 0, 0), (8.2, 5, 3)))
    limits = FaceLimits.from_spec(PlanSpec(min_density_pts_m2=1600.0), scene)
    occlusion = make_occlusion(scene, limits.occludes, "embree", file_faces=True)
    shells = closed_shells(scene, occlusion)
    assert shells is not None
    inside, outside = np.array([[3.0, 2.5, 1.5]]), np.array([[7.0, 2.5, 1.5]])
    assert not shells.outside(inside).any()
    assert shells.outside(outside).all()
    every, _ = PairFinder(scene, limits).find(inside, 0)
    kept, _ = PairFinder(scene, limits, shells=shells).find(inside, 0)
    assert len(kept) == len(every)
    visible = occlusion.visible(kept.origin, kept.direction, kept.distance_m, kept.face)
    assert visible.sum() > 100  # the room's inner faces, seen from behind their normals
    # from outside, the room's faces behind their normals and the far side of the wall
    # beyond it are left out
    every, _ = PairFinder(scene, limits).find(outside, 0)
    kept, _ = PairFinder(scene, limits, shells=shells).find(outside, 0)
    assert len(kept) < len(every)


def test_open_and_thin_shells_and_edges_keep_their_rays() -> None:
    open_box = _box((0, 0, 0), (2, 2, 2))
    open_box.update_faces(np.arange(len(open_box.faces)) >= 2)  # one side left open
    thin = _box((4, 0, 0), (6, 2, 0.0002))  # a sheet thinner than the clear margin
    wall = _box((8, 0, 0), (8.3, 4, 3))
    scene = _elements_scene(open_box, thin, wall)
    limits = FaceLimits.from_spec(PlanSpec(), scene)
    occlusion = make_occlusion(scene, limits.occludes, "embree", file_faces=True)
    shells = closed_shells(scene, occlusion)
    assert shells is not None
    element = scene.face_element
    assert not shells.side[element == 0].any()
    assert not shells.side[element == 1].any()
    wall_faces = np.flatnonzero(element == 2)
    assert (shells.side[wall_faces] == 1).mean() > 0.9  # the box's normals point out
    # its pieces within the margin of another of its faces (none here: 0.25 m pieces
    # have their centroids well inside) and only those keep their rays
    assert set(np.unique(shells.side[wall_faces]).tolist()) <= {0, 1}


def test_bundles_behind_a_shell_are_ruled_out_without_rays() -> None:
    mesh = office_building(1, 2)
    scene = remesh(build_scene(np.asarray(mesh.vertices), np.asarray(mesh.faces)), 0.2)
    limits = overlap_limits(FaceLimits.from_spec(PlanSpec(), scene), 1600.0)
    occlusion = make_occlusion(scene, limits.occludes, "embree", file_faces=True)
    bundles = bundles_of(scene)
    shells = closed_shells(scene, occlusion)
    assert bundles is not None and shells is not None
    reach_m = PairFinder(scene, limits).reach_m
    low, high = scene.vertices.min(axis=0), scene.vertices.max(axis=0)
    points = np.array([(x, y, low[2] + 1.53) for x in np.linspace(low[0] + 1.1, high[0] - 1.3, 4)
                       for y in np.linspace(low[1] + 1.7, high[1] - 1.9, 3)])
    (bundle_of, by_rays), rays = BundleCuller(bundles, reach_m, occlusion).hidden(points)
    (_, by_shells), fewer = BundleCuller(bundles, reach_m, occlusion, shells,
                                         scene.normals_of).hidden(points)
    assert fewer < rays
    # every piece of a bundle the shells hide is hidden when its own ray is cast
    point, bundle = np.nonzero(by_shells & ~by_rays)
    assert len(point) > 100
    member = bundle_of >= 0
    faces = np.flatnonzero(member)
    pieces = [(p, f) for p, b in zip(point[:300], bundle[:300], strict=True)
              for f in faces[bundle_of[faces] == b]]
    origin = points[[p for p, _ in pieces]]
    target = np.array([f for _, f in pieces])
    offset = scene.centroids[target] - origin
    distance = np.linalg.norm(offset, axis=1)
    visible = occlusion.visible(origin, offset / distance[:, None], distance, target)
    assert not visible.any()


def test_the_bundles_shared_sides_are_the_same_counted_in_blocks_of_any_size(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Each bundle's side (+1 out of its shell, -1 into it, 0 when its pieces differ) and
    normal, counted a block of pieces at a time, are those of its pieces: the same for
    blocks of any size, and as the pieces themselves give them."""
    from planner.visibility import bundles as module

    mesh = office_building(1, 2)
    scene = remesh(build_scene(np.asarray(mesh.vertices), np.asarray(mesh.faces)), 0.2)
    limits = FaceLimits.from_spec(PlanSpec(), scene)
    occlusion = make_occlusion(scene, limits.occludes, "embree", file_faces=True)
    bundles = bundles_of(scene)
    shells = closed_shells(scene, occlusion)
    assert bundles is not None and shells is not None
    assert scene.n_faces > 10 * 1_000
    made = {}
    for size in (1_000, 1 << 30):
        monkeypatch.setattr(module, "_KEY_BLOCK_FACES", size)
        module._SIDES.pop(bundles, None)  # kept per bundles: count again
        made[size] = module._level_sides(bundles, shells, scene.normals_of)
    for (side, normal), (side_once, normal_once) in zip(made[1_000], made[1 << 30],
                                                       strict=True):
        assert np.array_equal(side, side_once) and np.array_equal(normal, normal_once)
    finest_side, finest_normal = made[1_000][-1]
    assert {0, 1} <= set(np.unique(finest_side).tolist())  # shared sides and mixed ones
    for bundle in range(0, len(finest_side), 7):
        pieces = np.flatnonzero(bundles.bundle_of == bundle)
        sides = set(shells.side[pieces].tolist())
        assert finest_side[bundle] == (sides.pop() if len(sides) == 1 else 0)
        assert any(np.array_equal(finest_normal[bundle], scene.normals[p]) for p in pieces)


def test_each_pieces_side_is_its_distance_to_every_other_face_of_its_shell(
        scenes_dir: Path) -> None:
    """A piece is given its shell's side only when its centroid lies farther than the
    margin from every face of the shell but its own; the pieces of a file face are tested
    only against the faces near that face's box. Tested here against every face, in numpy:
    the same sides, on a real house (walls cut by openings, slabs, a roof)."""
    from planner.visibility.solids import _point_triangle_distance

    scene = read_scene(scenes_dir / "IfcOpenHouse_IFC4.ifc", max_edge_m=0.2,
                       split_faces="all")
    limits = FaceLimits.from_spec(PlanSpec(), scene)
    occlusion = make_occlusion(scene, limits.occludes, "embree", file_faces=True)
    shells = closed_shells(scene, occlusion)
    assert shells is not None
    sided = np.flatnonzero(shells.side != 0)
    assert len(sided) > 10_000
    bvh = occlusion.bvh_faces()  # type: ignore[attr-defined]
    occluding = bvh.occluding
    triangles = shells.triangles  # (T, 3, 3), shell after shell
    # each shell row's BVH face, found by its corners
    row_face = {tuple(np.round(t.ravel(), 9)): r for r, t in enumerate(triangles)}
    file_corners = bvh.vertices[bvh.faces[occluding]]
    row_of_bvh = np.array([row_face.get(tuple(np.round(t.ravel(), 9)), -1)
                           for t in file_corners])
    shell_of_row = np.repeat(np.arange(len(shells.starts) - 1), np.diff(shells.starts))
    rng = np.random.default_rng(3)
    # every piece of some file faces on a shell, and of every one with a piece not sided
    # (slivers within the margin of a neighbour: 64 pieces of 4 faces in this house)
    on_shell = np.flatnonzero(row_of_bvh >= 0)
    bvh_row = np.full(len(bvh.faces), -1)
    bvh_row[occluding] = np.arange(len(occluding))
    on_shell_piece = np.isin(bvh_row[scene.source_face], on_shell)
    unsided = np.unique(bvh_row[scene.source_face[on_shell_piece & (shells.side == 0)]])
    assert len(unsided) >= 4
    chosen = np.union1d(rng.choice(on_shell, size=min(40, len(on_shell)), replace=False),
                        unsided)
    checked = 0
    for b in chosen:
        own = row_of_bvh[b]
        rows = np.arange(shells.starts[shell_of_row[own]], shells.starts[shell_of_row[own] + 1])
        pieces = np.flatnonzero(scene.source_face == occluding[b])
        for piece in pieces:
            point = scene.centroids[piece]
            far = all(_point_triangle_distance(*point, triangles[r]) > shells.margin_m
                      for r in rows if r != own)
            assert (shells.side[piece] != 0) == far, (b, piece)
            checked += 1
    assert checked > 1_000
