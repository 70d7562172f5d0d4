"""Bundles: four rays rule out the pieces hidden behind one wall, and no verdict changes."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import trimesh

from planner.limits import FaceLimits
from planner.parameters import PlanSpec
from planner.rays import make_occlusion
from planner.rays.embree import quad_partners
from planner.scene import Scene, build_scene, remesh
from planner.visibility.bundles import BundleCuller, bundles_of
from planner.visibility.overlap import OverlapRows, overlap_limits
from planner.visibility.pairs import PairFinder
from planner.visibility.qualify import qualify_pairs
from tests.planner.buildings import office_building


@pytest.fixture(scope="module")
def office() -> Scene:
    """Two storeys of the generated office (rooms, corridors, closed doors, stairs, desks),
    split at 0.2 m as a plan splits it: most pieces in a long reach lie in other rooms."""
    mesh = office_building(2, 2)
    return remesh(build_scene(np.asarray(mesh.vertices), np.asarray(mesh.faces)), 0.2)


def _stations(scene: Scene) -> np.ndarray:
    """Some points at scanner height inside the rooms and corridors of both storeys."""
    low, high = scene.vertices.min(axis=0), scene.vertices.max(axis=0)
    xs = np.linspace(low[0] + 1.1, high[0] - 1.3, 5)
    ys = np.linspace(low[1] + 1.7, high[1] - 1.9, 4)
    zs = low[2] + np.array([1.53, 4.71])
    return np.array([(x, y, z) for x in xs for y in ys for z in zs])


def _qualified(scene: Scene, positions: np.ndarray, limits: FaceLimits, bundles: bool
               ) -> tuple[tuple[np.ndarray, ...], int]:
    occlusion = make_occlusion(scene, limits.occludes, "embree", file_faces=True)
    blocks = list(qualify_pairs(scene, positions, limits, occlusion, bundles=bundles))
    columns = tuple(np.concatenate([getattr(q, name) for q, _, _ in blocks])
                    for name in ("candidate", "face", "lpd_pts_m2"))
    return columns, sum(rays for _, _, rays in blocks)


@pytest.mark.parametrize("density_pts_m2", [1600.0, 45_000.0])
def test_bundles_qualify_the_same_pairs_with_fewer_rays(office: Scene,
                                                        density_pts_m2: float) -> None:
    limits = overlap_limits(FaceLimits.from_spec(PlanSpec(), office), density_pts_m2)
    positions = _stations(office)
    (plain, plain_rays), (bundled, bundled_rays) = (
        _qualified(office, positions, limits, bundles) for bundles in (False, True))
    assert len(plain[0]) > 10_000
    for a, b in zip(plain, bundled, strict=True):
        assert np.array_equal(a, b)
    if density_pts_m2 == 1600.0:  # a 25 m reach: most rays end in another room's wall
        assert bundled_rays < 0.6 * plain_rays


def test_overlap_rows_are_the_same_with_and_without_bundles(office: Scene) -> None:
    spec = PlanSpec()
    limits = FaceLimits.from_spec(spec, office)
    occlusion = make_occlusion(office, limits.occludes, "embree", file_faces=True)
    positions = _stations(office)[::3]
    bundled = OverlapRows(office, positions, limits, occlusion, spec.overlap_density_pts_m2,
                          file_faces=True)
    plain = OverlapRows(office, positions, limits, occlusion, spec.overlap_density_pts_m2,
                        file_faces=True)
    plain._search = (plain._local_search()[0], None)  # every piece its own ray, no bundles
    a, b = bundled.matrix(range(len(positions))), plain.matrix(range(len(positions)))
    assert a.nnz > 1000
    assert (a != b).nnz == 0
    assert bundled.rays_cast < plain.rays_cast


def _wall_scene(hole: bool) -> Scene:
    """A 4 x 3 m target wall 3 m behind a 6 x 4 m screen (two triangles), with or without
    a 1 x 2 m hole in the screen in front of the target's middle."""
    target = trimesh.creation.box(extents=(4.0, 0.1, 3.0))
    target.apply_translation((0.0, 3.0, 1.5))
    if hole:
        parts = [trimesh.creation.box(extents=(2.5, 0.1, 4.0)),
                 trimesh.creation.box(extents=(2.5, 0.1, 4.0)),
                 trimesh.creation.box(extents=(1.0, 0.1, 2.0))]
        parts[0].apply_translation((-1.75, 0.0, 2.0))
        parts[1].apply_translation((1.75, 0.0, 2.0))
        parts[2].apply_translation((0.0, 0.0, 3.0))
        screen = trimesh.util.concatenate(parts)
    else:
        screen = trimesh.creation.box(extents=(6.0, 0.1, 4.0))
        screen.apply_translation((0.0, 0.0, 2.0))
    mesh = trimesh.util.concatenate([target, screen])
    return remesh(build_scene(np.asarray(mesh.vertices), np.asarray(mesh.faces)), 0.2)


@pytest.mark.parametrize("hole", [False, True])
def test_a_bundle_is_ruled_out_only_where_one_triangle_or_quad_hides_all_of_it(hole: bool
                                                                               ) -> None:
    scene = _wall_scene(hole)
    limits = overlap_limits(FaceLimits.from_spec(PlanSpec(), scene), 1600.0)
    occlusion = make_occlusion(scene, limits.occludes, "embree", file_faces=True)
    station = np.array([[0.3, -2.0, 1.5]])
    bundles = bundles_of(scene)
    assert bundles is not None
    (bundle_of, hidden), _ = BundleCuller(bundles, 25.0, occlusion).hidden(station)  # type: ignore[arg-type]
    finder = PairFinder(scene, limits)
    pairs, _ = finder.find(station, 0)
    visible = occlusion.visible(pairs.origin, pairs.direction, pairs.distance_m, pairs.face)
    ruled_out = hidden[0, bundle_of[pairs.face]] & (bundle_of[pairs.face] >= 0)
    assert not (ruled_out & visible).any()  # never a piece the station sees
    # the target's facing side: behind the screen, seen through the hole when there is one
    facing = np.isclose(scene.centroids[pairs.face, 1], 2.95)
    assert facing.sum() > 100
    if hole:
        assert visible[facing].any()
        assert not ruled_out[facing & visible].any()
    else:
        # the screen's side is one rectangle, two triangles: every bundle behind it is
        # ruled out, also those whose corners fall on both sides of its diagonal
        assert not visible[facing].any()
        assert ruled_out[facing].all()


def test_a_bundle_whose_corner_rays_miss_is_not_ruled_out() -> None:
    """Two corner rays that hit a lone triangle (no quad partner) and two that hit nothing
    (a bundle's rectangle reaches past a triangular face) rule nothing out, wherever the
    model's other vertices lie (here vertex 0 would make a quad with the triangle that
    holds where the two rays cross the screen's plane)."""
    vertices = np.array([[10.0, 0.0, -10.0], [-3.0, 0.0, 0.0], [3.0, 0.0, 0.0], [0.0, 0.0, 4.0]])
    scene = build_scene(vertices, np.array([[1, 2, 3]]))
    occlusion = make_occlusion(scene, np.ones(1, bool), "embree")
    origin = np.array([[0.0, -3.0, 1.0]])
    behind = np.array([[[-0.5, 3.0, 0.5], [0.5, 3.0, 0.5], [0.5, 3.0, 1.5], [-0.5, 3.0, 1.5]]])
    past = behind.copy()
    past[0, 1:3] = [[8.0, 3.0, -6.0], [8.5, 3.0, -6.0]]  # their rays pass below the screen
    assert occlusion.bundles_hidden(origin, behind).tolist() == [True]  # type: ignore[attr-defined]
    assert occlusion.bundles_hidden(origin, past).tolist() == [False]  # type: ignore[attr-defined]


def test_a_bundle_with_a_corner_at_the_origin_is_not_ruled_out_and_the_others_are() -> None:
    """A corner where the rays start gives no direction: that bundle keeps its pieces' own
    rays, and the bundles beside it in the same call are still decided by theirs."""
    vertices = np.array([[-3.0, 0.0, -3.0], [3.0, 0.0, -3.0], [3.0, 0.0, 3.0], [-3.0, 0.0, 3.0]])
    scene = build_scene(vertices, np.array([[0, 1, 2], [0, 2, 3]]))
    occlusion = make_occlusion(scene, np.ones(2, bool), "embree")
    origin = np.array([[0.1, -3.0, 0.2]] * 3)
    behind = np.array([[-0.5, 3.0, -0.5], [0.5, 3.0, -0.5], [0.5, 3.0, 0.5], [-0.5, 3.0, 0.5]])
    at_origin = behind.copy()
    at_origin[2] = origin[0].astype(np.float32)  # where the float32 rays start
    corners = np.stack([behind, at_origin, behind + np.array([0.2, 1.0, 0.1])])
    assert occlusion.bundles_hidden(origin, corners).tolist() == [  # type: ignore[attr-defined]
        True, False, True]


def test_quads_are_the_convex_halves_of_one_plane() -> None:
    """A rectangle's two halves make a quad; two triangles that share their longest edge
    but bend at it, or fold onto the same side of it, do not."""
    vertices = np.array([
        [0, 0, 0], [4, 0, 0], [4, 0, 3], [0, 0, 3],  # a rectangle in y = 0
        [10, 0, 0], [14, 0, 0], [14, 0, 3], [10, 1, 3],  # bent: one corner off the plane
        [20, 0, 0], [24, 0, 0], [21, 0, 1], [22, 0, 0.5],  # folded: both far corners above
    ], np.float32)
    faces = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7], [8, 9, 10], [8, 9, 11]],
                     np.int32)
    partner, shared_edge, far_vertex = quad_partners(vertices, faces, margin_m=1e-3)
    assert partner.tolist() == [1, 0, -1, -1, -1, -1]
    # triangle 0's longest edge is its diagonal 2 -> 0 (corners 2 and 0: edge 2), across
    # which the other half's far corner is vertex 3
    assert (shared_edge[0], far_vertex[0], far_vertex[1]) == (2, 3, 1)


@pytest.mark.parametrize("density_pts_m2", [45_000.0, 400_000.0])
def test_the_grid_finds_every_pair_a_scan_of_all_faces_finds(office: Scene,
                                                              density_pts_m2: float) -> None:
    """The pair search looks only in the grid cells that come within reach of a point (at
    400,000 pts/m2 the reach is 1.6 m: a small share of this office); every face of the
    model, tested by the module's rules in numpy, gives the same pairs."""
    limits = overlap_limits(FaceLimits.from_spec(PlanSpec(), office), density_pts_m2)
    finder = PairFinder(office, limits)
    rng = np.random.default_rng(7)
    low, high = office.centroids.min(axis=0), office.centroids.max(axis=0)
    points = np.vstack([_stations(office)[::4], rng.uniform(low, high, size=(6, 3))])
    pairs, _ = finder.find(points, 0)
    step = limits.angular_step_rad
    sin_low = np.sin(np.radians(limits.elevation_min_deg))
    sin_high = np.sin(np.radians(limits.elevation_max_deg))
    sin_incidence = np.sin(np.radians(limits.min_incidence_deg[0]))
    for c, point in enumerate(points):
        offset = office.centroids - point
        d2 = (offset[:, 0] * offset[:, 0] + offset[:, 1] * offset[:, 1]
              + offset[:, 2] * offset[:, 2])
        d = np.sqrt(d2)
        with np.errstate(divide="ignore", invalid="ignore"):
            u = offset / d[:, None]
            s = np.abs(u[:, 0] * office.normals[:, 0] + u[:, 1] * office.normals[:, 1]
                       + u[:, 2] * office.normals[:, 2])
            lpd = s / ((step * d) * (step * d))
        passes = ((d >= limits.dof_min_m) & (d <= limits.dof_max_m) & (d > 0)
                  & (u[:, 2] >= sin_low) & (u[:, 2] <= sin_high) & (s >= sin_incidence)
                  & (lpd >= limits.min_density_pts_m2[0]))
        found = pairs.face[pairs.candidate == c]
        assert np.array_equal(found, np.flatnonzero(passes)), f"point {c}"
    assert len(pairs) > 500


@pytest.mark.parametrize("density_pts_m2", [1600.0, 45_000.0])
def test_a_candidates_pairs_found_in_parts_are_those_found_at_once(office: Scene,
                                                                    density_pts_m2: float
                                                                    ) -> None:
    """An overlap row's pairs are found a part at a time (at 1,600 pts/m2 a candidate
    tests every face of this office, at 45,000 the grid cells in its reach): parts of
    any size give the pairs of one search, in its order, with the bundles hidden from
    the candidate left out of both."""
    limits = overlap_limits(FaceLimits.from_spec(PlanSpec(), office), density_pts_m2)
    occlusion = make_occlusion(office, limits.occludes, "embree", file_faces=True)
    bundles = bundles_of(office)
    assert bundles is not None
    finder = PairFinder(office, limits, bundle_of=bundles.bundle_of)
    culler = BundleCuller(bundles, finder.reach_m, occlusion)
    points = _stations(office)[::9]
    for c, point in enumerate(points):
        hidden, _ = culler.hidden(point[None])
        whole, _ = finder.find(point[None], c, hidden, ordered=False)
        assert len(whole) > 50
        for most_tests in (997, 20_011, 1 << 30):
            parts = list(finder.parts(point[None], c, hidden, most_tests=most_tests))
            assert len(parts) >= (1 if most_tests > 1 << 20 else 2)
            if density_pts_m2 == 1600.0:  # every face tested: parts of most_tests faces
                assert max(len(p) for p in parts) <= most_tests
            for name in ("candidate", "face", "origin", "direction", "distance_m",
                         "lpd_pts_m2"):
                assert np.array_equal(np.concatenate([getattr(p, name) for p in parts]),
                                      getattr(whole, name)), (c, most_tests, name)


def test_bundles_made_a_block_of_file_faces_at_a_time_are_those_made_at_once(
        office: Scene, monkeypatch: pytest.MonkeyPatch) -> None:
    """The bundles are numbered a block of whole file faces at a time; blocks of any size,
    and one block (pieces not in file order), give the same bundles, and the first piece of
    each file face is the one a sort of every piece finds."""
    from planner.visibility import bundles as module

    shuffled = dataclasses.replace(office, source_face=office.source_face[::-1].copy())
    assert len(office.file_face_blocks(5_000)) > 10
    assert shuffled.file_face_blocks(5_000) == [slice(0, office.n_faces)]
    for blocks in office.file_face_blocks(5_000), office.file_face_blocks(1 << 30):
        covered = np.concatenate([np.arange(b.start, b.stop) for b in blocks])
        assert np.array_equal(covered, np.arange(office.n_faces))
        # a block boundary never cuts a file face's pieces apart
        assert all(office.source_face[b.start - 1] != office.source_face[b.start]
                   for b in blocks[1:])
    for scene in (office, shuffled):
        present, first = np.unique(scene.source_face, return_index=True)
        found_present, found_first = scene.first_pieces()
        assert np.array_equal(found_present, present) and np.array_equal(found_first, first)
    made = {}
    for size in (3_000, 1 << 30):
        monkeypatch.setattr(module, "_KEY_BLOCK_FACES", size)
        made[size] = module._make_bundles(office)
    small, whole = made[3_000], made[1 << 30]
    assert small is not None and whole is not None
    assert np.array_equal(small.bundle_of, whole.bundle_of)
    for a, b in zip(small.levels, whole.levels, strict=True):
        for name in ("corners", "pieces", "parent"):
            assert np.array_equal(getattr(a, name), getattr(b, name))


def test_the_culler_searches_the_bundles_that_can_get_rays_in_radius_classes(
        office: Scene) -> None:
    """Only bundles of MIN_BUNDLE_PIECES pieces or more take part (a file face of fewer
    pieces has none), searched in classes of radius: the same (point, bundle) pairs, in
    the same order, as one search over them with a grid for the largest radius."""
    from planner.visibility import bundles as module
    from planner.visibility.cells import PointGrid, Points, pairs_in_reach

    bundles = bundles_of(office)
    assert bundles is not None
    per_file_face = np.bincount(office.source_face)
    few = per_file_face[office.source_face] < module.MIN_BUNDLE_PIECES
    assert few.any() and (bundles.bundle_of[few] == -1).all()
    rng = np.random.default_rng(3)
    n = 4_000  # bundles of a made-up level: radii up to 40 times the square's half diagonal
    centre = rng.uniform(0.0, 30.0, size=(n, 3))
    made_up = module.BundleLevel(np.zeros((n, 4, 3)), centre,
                                 0.7 * np.exp(rng.uniform(0.0, np.log(40.0), n)),
                                 rng.integers(1, 20, n), np.full(n, -1))
    levels = [*zip(bundles.levels, module.BUNDLE_SIDES_M, strict=True), (made_up, 1.0)]
    reach_m = 4.7
    points = np.vstack([_stations(office), rng.uniform(0.0, 30.0, size=(20, 3))])
    classes = 0
    for level, side in levels:
        search = module._LevelSearch.of(level, side, reach_m)
        classes = max(classes, len(search.classes))
        eligible = np.flatnonzero(level.pieces >= module.MIN_BUNDLE_PIECES).astype(np.int32)
        grid = PointGrid.of(Points.rows(level.centre), np.arange(len(level), dtype=np.int32),
                            reach_m + float(level.radius_m.max()))
        point, bundle = pairs_in_reach(points, level.centre, level.radius_m, reach_m, grid)
        keep = np.isin(bundle, eligible)
        found = search.pairs(points, len(level))
        assert len(found[0]) > 100
        assert np.array_equal(found[0], point[keep]) and np.array_equal(found[1], bundle[keep])
    assert classes > 4


def test_the_grid_keeps_each_cells_pieces_in_runs_of_one_bundle() -> None:
    """The pair search's grid orders each cell's points by group (a bundle; -1 first),
    then by index, and cuts them into runs of one group of at most the longest run: the
    same points per cell as a plain grid, every run one group."""
    from planner.visibility.cells import MOST_PER_RUN, PointGrid, Points, RunGrid

    rng = np.random.default_rng(11)
    xyz = rng.uniform(0, 10, size=(20_000, 3))
    group = rng.integers(-1, 40, size=len(xyz)).astype(np.int32)
    group[:2_000] = -1  # in one cell, more points in no group than a run holds
    xyz[:2_000] = rng.uniform(0.1, 0.9, size=(2_000, 3))
    subset = np.arange(0, len(xyz), 2, dtype=np.int32)
    plain = PointGrid.of(Points.rows(xyz), subset, 4.0, cells_per_reach=2)
    grid = RunGrid.grouped(Points.rows(xyz), subset, 4.0, 2, group)
    assert np.array_equal(plain.start, grid.start)
    n_runs = len(grid.run_group)
    assert grid.run_first[0] == 0 and grid.run_first[-1] == len(subset)
    assert grid.cell_runs[-1] == n_runs
    for cell in range(len(grid.start) - 1):
        members = grid.members[grid.start[cell]:grid.start[cell + 1]]
        assert sorted(members.tolist()) == plain.members[
            plain.start[cell]:plain.start[cell + 1]].tolist()
        keys = list(zip(group[subset[members]].tolist(), members.tolist(), strict=True))
        assert keys == sorted(keys)
        runs = range(grid.cell_runs[cell], grid.cell_runs[cell + 1])
        assert sum(grid.run_first[r + 1] - grid.run_first[r] for r in runs) == len(members)
        for r in runs:
            in_run = grid.members[grid.run_first[r]:grid.run_first[r + 1]]
            assert 0 < len(in_run) <= MOST_PER_RUN
            assert set(group[subset[in_run]].tolist()) == {grid.run_group[r]}
    assert (np.diff(grid.run_first) == MOST_PER_RUN).any()  # a cell's long run is cut
    # each run's float32 box holds every point of the run
    for r in range(n_runs):
        points = xyz[subset[grid.members[grid.run_first[r]:grid.run_first[r + 1]]]]
        assert grid.run_box.dtype == np.float32
        assert (grid.run_box[r, :3].astype(np.float64) <= points.min(axis=0)).all()
        assert (grid.run_box[r, 3:].astype(np.float64) >= points.max(axis=0)).all()


def test_the_grid_of_face_centroids_computes_them_with_numpys_bits(office: Scene) -> None:
    """The scene keeps no centroids: the kernels compute each where they read it. They
    must be the bits numpy's mean of the corners gives (what the plans were made with): the
    same centroids, grid, runs and run boxes as over the centroids as rows."""
    from planner.visibility.cells import Points, RunGrid

    numpy_centroids = office.vertices[office.faces].mean(axis=1)
    assert np.array_equal(office.centroids.view(np.int64), numpy_centroids.view(np.int64))
    some = np.arange(0, office.n_faces, 7)
    assert np.array_equal(office.centroids_of(some), numpy_centroids[some])
    faces = Points.face_centroids(office)
    assert np.array_equal(faces.at(some), numpy_centroids[some])
    subset = np.arange(1, office.n_faces, 3, dtype=np.int32)
    group = (np.arange(office.n_faces) // 50).astype(np.int32)
    computed = RunGrid.grouped(faces, subset, 6.0, 2, group)
    as_rows = RunGrid.grouped(Points.rows(numpy_centroids), subset, 6.0, 2, group)
    for name in ("origin", "start", "members", "cell_runs", "run_first", "run_box"):
        assert np.array_equal(getattr(computed, name), getattr(as_rows, name)), name


def _limits_passed(scene: Scene, limits: FaceLimits, point: np.ndarray, reach_m: float
                   ) -> np.ndarray:
    """(k,) the target faces that pass every analytic limit from the (3,) ``point``, each
    face tested on its own in numpy, in the pair search's own float64 operations."""
    faces = np.flatnonzero(limits.target)
    offset = scene.centroids[faces] - point
    d2 = offset[:, 0] * offset[:, 0] + offset[:, 1] * offset[:, 1] + offset[:, 2] * offset[:, 2]
    d = np.sqrt(d2)
    unit = offset / np.where(d > 0, d, 1.0)[:, None]
    normal = scene.file_normals[scene.source_face[faces]]
    sine = np.abs(unit[:, 0] * normal[:, 0] + unit[:, 1] * normal[:, 1]
                  + unit[:, 2] * normal[:, 2])
    spacing = limits.angular_step_rad * d
    ok = ((d2 <= reach_m * reach_m * (1.0 + 1e-9)) & (d >= limits.dof_min_m)
          & (d <= limits.dof_max_m) & (d > 0)
          & (unit[:, 2] >= np.sin(np.radians(limits.elevation_min_deg)))
          & (unit[:, 2] <= np.sin(np.radians(limits.elevation_max_deg)))
          & (sine >= np.sin(np.radians(limits.min_incidence_deg[faces])))
          & (sine / np.where(d > 0, spacing * spacing, 1.0)
             >= limits.min_density_pts_m2[faces]))
    return faces[ok]


@pytest.mark.parametrize("density", ["coverage", "overlap"])
def test_runs_ruled_out_whole_leave_the_pairs_of_testing_every_face(office: Scene,
                                                                     density: str) -> None:
    """The pair search skips a run of its grid whose box lies out of reach, or whose faces
    share a plane the station sees too obliquely or too far for any of them to pass: it
    finds exactly the faces that pass when every face is tested on its own."""
    limits = FaceLimits.from_spec(PlanSpec(), office)
    if density == "overlap":
        limits = overlap_limits(limits, 1600.0)
    bundles = bundles_of(office)
    assert bundles is not None
    finder = PairFinder(office, limits, bundle_of=bundles.bundle_of)
    stations = _stations(office)[::3]
    grid, reach = finder._grid, finder.reach_m
    # the cases are there: runs out of reach, and planar runs in reach but too oblique
    gap = np.maximum(np.maximum(grid.run_box[None, :, :3] - stations[:, None, :], 0.0),
                     stations[:, None, :] - grid.run_box[None, :, 3:])
    box_m = np.linalg.norm(gap, axis=2)  # (stations, runs)
    planar = finder._run_plane_face >= 0
    assert planar.mean() > 0.9
    normal = office.file_normals[np.maximum(finder._run_plane_face, 0)]  # (runs, 3)
    apart_m = np.max(np.abs(finder._run_plane[None, :, :] - (stations @ normal.T)[:, :, None]),
                     axis=2)
    oblique = planar & (box_m > 0) & (box_m <= reach) & (
        apart_m < np.sin(np.radians(limits.min_incidence_deg.min())) * box_m)
    if density == "coverage":
        assert (box_m > reach).sum() > 1_000
    assert oblique.sum() > 1_000
    near, _ = finder.find(stations, 0)
    assert len(near) > 10_000
    for c, point in enumerate(stations):
        found = np.sort(near.face[near.candidate == c])
        assert np.array_equal(found, _limits_passed(office, limits, point, reach))
