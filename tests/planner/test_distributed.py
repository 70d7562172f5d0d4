"""One plan fanned out over a real Dask cluster (two worker processes on this machine) gives
the same files, byte for byte, as the plan made on one machine; a worker killed mid-plan
loses nothing; a scheduler that cannot be reached is named in the error."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

distributed = pytest.importorskip("distributed")

from planner.candidates.grid import read_candidates_csv  # noqa: E402
from planner.errors import SchedulerUnreachableError  # noqa: E402
from planner.io.readers import read_scene  # noqa: E402
from planner.parameters import PlanSpec  # noqa: E402
from planner.pipeline import PlanResult, plan  # noqa: E402
from planner.scaleout import DaskFanout  # noqa: E402
from planner.scaleout.cluster import RESULTS_BUFFERED_PER_THREAD  # noqa: E402
from planner.scene import Scene  # noqa: E402
from tests.planner.plan_files import assert_same_files, files_of  # noqa: E402

# a house at a coarser grid and split than the defaults: every stage runs, in seconds
HOUSE = {"grid_spacing_m": 1.0, "max_edge_m": 0.4}


@pytest.fixture(scope="module")
def cluster() -> Any:
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as local:
        yield local


@pytest.fixture(scope="module")
def house(scenes_dir: Path) -> Scene:
    return read_scene(scenes_dir / "IfcOpenHouse_IFC4.ifc", max_edge_m=HOUSE["max_edge_m"],
                      split_faces="as_needed")


def assert_same_plans(local: PlanResult, fanned: PlanResult, tmp_path: Path) -> None:
    assert fanned.table.n_pairs == local.table.n_pairs
    assert_same_files(files_of(local, tmp_path / "local"), files_of(fanned, tmp_path / "dask"))


@pytest.mark.parametrize("method, min_overlap_m2", [
    ("greedy", None),
    ("weighted_greedy", 2.0),
    ("optimal", 2.0),
])
def test_house_same_bytes(cluster: Any, house: Scene, tmp_path: Path, method: str,
                          min_overlap_m2: float | None) -> None:
    spec = PlanSpec.from_mapping({**HOUSE, "method": method, "min_overlap_m2": min_overlap_m2})
    local = plan(house, spec)
    fanned = plan(house, spec, dask_scheduler=cluster.scheduler_address)
    assert_same_plans(local, fanned, tmp_path)


def test_hall_same_bytes(cluster: Any, scenes_dir: Path, tmp_path: Path) -> None:
    """An unsplit mesh with given candidates (as tests/planner/test_expected.py plans the
    halls), a part of them."""
    folder = scenes_dir / "hall-small"
    scene = read_scene(folder / "hall.obj", max_edge_m=None)
    candidates = read_candidates_csv(folder / "candidates.csv")[::5]
    spec = PlanSpec(candidates=tuple(map(tuple, candidates.tolist())), max_edge_m=None,
                    placement_tolerance_m=0.0)
    local = plan(scene, spec)
    fanned = plan(scene, spec, dask_scheduler=cluster.scheduler_address)
    assert_same_plans(local, fanned, tmp_path)


def _wait_for_last(item: tuple[int, int, str]) -> int:
    """A task of the map below: item 0 waits until the last item's task has finished (it
    leaves a file), so the tasks finish out of order; each notes when it ends."""
    index, last, folder = item
    if index == 0:
        for _ in range(1200):
            if (Path(folder) / str(last)).exists():
                break
            time.sleep(0.05)
    (Path(folder) / str(index)).touch()
    with open(Path(folder) / "finished", "a") as finished:
        finished.write(f"{index}\n")
    return index


def test_map_yields_in_item_order(cluster: Any, tmp_path: Path) -> None:
    """The first item's task ends last: while it runs, the other worker goes on with the
    later items (the next is submitted when any task ends), and the results still come in
    the order of the items."""
    with DaskFanout(cluster.scheduler_address) as fanout:
        fanout.client.wait_for_workers(2)
        n = RESULTS_BUFFERED_PER_THREAD * fanout.threads
        results = list(fanout.map(_wait_for_last,
                                  [(k, n - 1, str(tmp_path)) for k in range(n)]))
    assert results == list(range(n))
    finished = [int(line) for line in (tmp_path / "finished").read_text().split()]
    assert sorted(finished) == list(range(n))
    assert finished[-1] == 0  # the last item finished before the first


def test_worker_killed_mid_plan(cluster: Any, house: Scene, tmp_path: Path) -> None:
    """One worker process is killed while the visibility's tasks run: its tasks run again on
    the other (or on the worker its nanny starts again) and the plan is the same."""
    spec = PlanSpec.from_mapping({**HOUSE, "min_overlap_m2": 2.0})
    local = plan(house, spec)
    client = distributed.Client(cluster.scheduler_address)
    pids = client.run(os.getpid)
    client.close()
    killed: list[int] = []

    def progress(stage: str, fraction: float) -> None:
        if stage == "visibility" and fraction > 0 and not killed:
            victim = next(iter(pids.values()))
            os.kill(victim, signal.SIGKILL)
            killed.append(victim)

    fanned = plan(house, spec, dask_scheduler=cluster.scheduler_address, progress=progress)
    assert killed
    assert_same_plans(local, fanned, tmp_path)


def test_unreachable_scheduler_is_named() -> None:
    address = "tcp://127.0.0.1:9"  # the discard port: nothing listens
    with pytest.raises(SchedulerUnreachableError) as error:
        DaskFanout(address, connect_timeout_s=1.0)
    message = str(error.value)
    assert address in message and "cannot be reached" in message
    assert "SCANPLAN_DASK_SCHEDULER" in message


HouseTiles = tuple[Any, Any, Any]  # the split house's Sight, its candidates, a TileCutter


@pytest.fixture(scope="module")
def house_tiles(house: Scene) -> HouseTiles:
    """The house's sight split for its candidates, and a cutter of tiles of the coverage
    pair search, as the fan-out makes them."""
    from planner.candidates.generate import plan_candidates
    from planner.visibility.qualify import Sight
    from planner.visibility.tiles import TileCutter

    spec = PlanSpec.from_mapping(HOUSE)
    sight = Sight.of(house, spec, "embree")
    candidates, _ = plan_candidates(house, spec, sight.caster)
    sight = sight.split_as_needed(candidates.positions)
    limits = sight.limits
    cutter = TileCutter(sight.scene, limits, limits.occludes, sight.occlusion,
                        min(limits.reach_m, limits.dof_max_m))
    return sight, candidates, cutter


def test_tiles_hold_part_of_the_model(house_tiles: HouseTiles) -> None:
    """A tile's targets are those within reach of its candidates, not the model's."""
    sight, candidates, cutter = house_tiles
    limits = sight.limits
    ids = np.arange(min(8, len(candidates.positions)))
    tile = cutter.cut(ids, candidates.positions[ids])
    assert 0 < len(tile.faces) < sight.scene.n_faces
    centroids = sight.scene.centroids
    within = (np.linalg.norm(centroids[:, None, :] - candidates.positions[ids][None], axis=2)
              .min(axis=1) <= cutter.reach_m) & limits.target
    assert set(np.flatnonzero(within)) <= set(tile.faces[tile.limits.target].tolist())


def test_tiles_travel_without_the_file_mesh(house_tiles: HouseTiles) -> None:
    """A task's tile leaves the file's mesh out (the worker gets it once, as the shared
    occluders, and builds one BVH over it for all its tiles), and still gives the same
    pairs and rows as the whole tile."""
    import pickle

    from planner.visibility.tiles import overlap_tile, qualify_tile

    sight, candidates, cutter = house_tiles
    occluders = cutter.occluders()
    assert occluders is not None
    occluders = pickle.loads(pickle.dumps(occluders))  # as a worker receives them
    file_vertices, file_faces = sight.scene.file_mesh
    for start in (0, 8):
        ids = np.arange(start, min(start + 8, len(candidates.positions)))
        tile = cutter.cut(ids, candidates.positions[ids])
        sent = tile.detached()
        assert sent.scene.file_faces is None and sent.scene.areas is None
        bare = cutter.cut(ids, candidates.positions[ids], detached=True)  # as a task's
        assert bare.nbytes == sent.nbytes
        assert np.array_equal(bare.faces, sent.faces)
        assert np.array_equal(bare.scene.vertices, sent.scene.vertices)
        assert np.array_equal(bare.scene.faces, sent.scene.faces)
        for name in ("centroids", "normals", "areas"):  # derived again, the same bits
            assert np.array_equal(getattr(bare.attached(occluders).scene, name),
                                  getattr(tile.scene, name))
        assert (len(pickle.dumps(tile)) - len(pickle.dumps(sent))
                >= file_vertices.nbytes + file_faces.nbytes)
        whole, shared = qualify_tile(tile), qualify_tile(pickle.loads(pickle.dumps(sent)),
                                                         occluders)
        assert whole[1:] == shared[1:] and len(whole[0].face) == len(shared[0].face) > 0
        for a, b in zip((whole[0].candidate, whole[0].face, whole[0].lpd_pts_m2),
                        (shared[0].candidate, shared[0].face, shared[0].lpd_pts_m2),
                        strict=True):
            assert np.array_equal(a, b)
        rows, rows_shared = overlap_tile(tile), overlap_tile(sent, occluders)
        assert rows[1] == rows_shared[1]
        assert all(np.array_equal(a, b) for a, b in zip(rows[0], rows_shared[0], strict=True))
    assert occluders.bvh() is occluders.bvh()  # one BVH for every tile


def test_overlap_groups_stand_close_together() -> None:
    """The overlap rows' tasks group candidates standing within a few metres of one
    another (so a task's tile spans the reach around them, not three reaches), every
    candidate once, at most ``size`` a group, each group ascending."""
    from planner.scaleout.cluster import GROUP_SPREAD_M, _near_groups

    # two storeys of an 80 x 19 m floor at a 3 m grid, in grid and storey order
    x, y, z = np.meshgrid(np.arange(1.5, 80, 3.0), np.arange(1.5, 19, 3.0), [1.5, 5.0],
                          indexing="ij")
    positions = np.stack([a.transpose(2, 0, 1).ravel() for a in (x, y, z)], axis=1)
    candidates = np.arange(0, len(positions), 2, dtype=np.int64)
    groups = _near_groups(candidates, positions, 5)
    assert np.array_equal(np.sort(np.concatenate(groups)), candidates)
    assert [int(g[0]) for g in groups] == sorted(int(g[0]) for g in groups)
    for group in groups:
        assert 0 < len(group) <= 5 and np.all(np.diff(group) > 0)
        spread = positions[group].max(axis=0) - positions[group].min(axis=0)
        assert np.all(spread < GROUP_SPREAD_M)
    assert len(groups) < len(candidates) / 2  # groups share their tiles


def test_tile_cut_bounds_decide_as_the_k_d_tree() -> None:
    """A tile's targets: the points the bounds are sure of and those the k-d tree decides
    are the points a k-d tree of the candidates finds within reach; its vertices are
    renumbered as ``np.unique`` would."""
    from scipy.spatial import cKDTree

    from planner.scene import compact_indices
    from planner.visibility.cells import Points
    from planner.visibility.tiles import _within

    rng = np.random.default_rng(7)
    for _ in range(10):
        positions = rng.uniform(0.0, 8.0, (int(rng.integers(1, 30)), 3))
        xyz = rng.uniform(-40.0, 50.0, (20_000, 3))
        points = np.sort(rng.choice(len(xyz), 10_000, replace=False)).astype(np.int32)
        distance, _ = cKDTree(positions).query(xyz[points], distance_upper_bound=25.0)
        within = _within(Points.rows(xyz), points, positions, positions.min(axis=0),
                         positions.max(axis=0), 25.0)
        assert np.array_equal(within, np.isfinite(distance))
        indices = rng.integers(0, 5_000, (3_000, 3)).astype(np.int32)
        used, renumbered = compact_indices(indices, 5_000)
        unique, inverse = np.unique(indices, return_inverse=True)
        assert np.array_equal(used, unique)
        assert np.array_equal(renumbered, inverse.reshape(-1, 3))


@pytest.mark.parametrize("method, min_overlap_m2", [
    ("greedy", 2.0),
    ("weighted_greedy", None),
    ("optimal", 2.0),
])
def test_house_in_parts_same_bytes(cluster: Any, house: Scene, tmp_path: Path,
                                   monkeypatch: pytest.MonkeyPatch, method: str,
                                   min_overlap_m2: float | None) -> None:
    """Tiles sent in parts of a few thousand faces (a task's faces bounded as on a large
    building, where the overlap rows' reach takes in much of it) give the same files."""
    from planner.scaleout import cluster as scaleout

    spec = PlanSpec.from_mapping({**HOUSE, "method": method, "min_overlap_m2": min_overlap_m2})
    local = plan(house, spec)
    monkeypatch.setattr(scaleout, "TILE_FACES", 3_000)
    fanned = plan(house, spec, dask_scheduler=cluster.scheduler_address)
    assert_same_plans(local, fanned, tmp_path)


def test_tile_parts_hold_few_faces_and_give_the_tiles_pairs(house_tiles: HouseTiles) -> None:
    """A tile cut in parts of at most about ``most_faces`` targets: each part's faces are
    bounded by that budget, not by the tile's reach or the model, its faces are the model's
    ascending and whole file faces; the parts' pairs and rows, merged as the fan-out merges
    them, are the whole tile's."""
    import pickle

    from planner.scaleout.cluster import _by_candidate_and_face
    from planner.visibility.tiles import _part_scene, overlap_tile, qualify_tile

    sight, candidates, cutter = house_tiles
    scene = sight.scene
    occluders = pickle.loads(pickle.dumps(cutter.occluders()))
    ids = np.arange(min(8, len(candidates.positions)))
    whole = cutter.cut(ids, candidates.positions[ids], detached=True)
    most_faces = 2_000
    largest = int(np.bincount(scene.source_face[whole.faces]).max())
    assert len(whole.faces) > 3 * most_faces  # cut in several parts
    parts = list(cutter.cut_parts(ids, candidates.positions[ids], most_faces, detached=True))
    assert [last for _, last in parts] == [False] * (len(parts) - 1) + [True]
    tiles = [tile for tile, _ in parts]
    assert len(tiles) >= len(whole.faces) // (most_faces + largest)
    for tile in tiles:
        assert 0 < len(tile.faces) < most_faces + largest
        assert np.all(np.diff(tile.faces) > 0)
        assert np.array_equal(tile.candidates, whole.candidates)
        alone = _part_scene(scene, tile.faces.astype(np.int64), keep_file_mesh=True)
        assert np.array_equal(tile.scene.vertices, alone.vertices)  # as if cut alone
        assert np.array_equal(tile.scene.faces, alone.faces)
    every = np.concatenate([tile.faces for tile in tiles])
    assert np.array_equal(np.sort(every), whole.faces)  # each target in one part
    sources = [set(scene.source_face[tile.faces].tolist()) for tile in tiles]
    assert sum(len(s) for s in sources) == len(set().union(*sources))  # file faces whole
    pairs, _, rays = qualify_tile(whole, occluders)
    results = [qualify_tile(tile, occluders) for tile in tiles]
    merged = _by_candidate_and_face([result[0] for result in results])
    assert len(pairs.face) > 0
    # whole file faces in each part: the same bundles, so the same rays cast
    assert sum(r[2] for r in results) == rays
    for a, b in zip((pairs.candidate, pairs.face, pairs.lpd_pts_m2),
                    (merged.candidate, merged.face, merged.lpd_pts_m2), strict=True):
        assert a.dtype == b.dtype and np.array_equal(a, b)
    rows, rows_rays = overlap_tile(whole, occluders)
    part_rows = [overlap_tile(tile, occluders) for tile in tiles]
    assert sum(p[1] for p in part_rows) == rows_rays
    for k, row in enumerate(rows):
        assert np.array_equal(row, np.sort(np.concatenate([p[0][k] for p in part_rows])))
