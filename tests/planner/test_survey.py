"""Scanner presets, registration overlap, walking route and field time."""

from __future__ import annotations

import itertools
import json
from pathlib import Path

import numpy as np
import pytest
import trimesh

from planner.__main__ import main
from planner.candidates.grid import read_candidates_csv
from planner.errors import ParameterError
from planner.io.readers import read_scene
from planner.limits import FaceLimits
from planner.outputs.report import plan_document, stations_csv
from planner.parameters import PlanSpec
from planner.pipeline import PlanResult, plan
from planner.rays import make_occlusion, make_ray_caster
from planner.scene import Scene, build_scene, remesh
from planner.selection import connectivity
from planner.selection.connected import MIN_CONSTRAINT
from planner.survey.fieldwork import survey
from planner.survey.registration import station_registration
from planner.survey.route import (
    TreeCache,
    exact_open_tour,
    open_tour,
    parts_may_join_outside,
    plan_route,
)
from planner.visibility.overlap import overlap_matrix, shared_faces_only
from planner.walkgraph import (
    KNEE_HEIGHT_M,
    WALK_AREA_MARGIN_M,
    build_walk_graph,
    segment_free,
    walk_area,
)
from tests.planner.survey_scenes import (
    MEZZANINE_Z_M,
    boxes_scene,
    room_shell,
    staircase,
    two_room_candidates,
    two_rooms,
)

# --- scanner presets -------------------------------------------------------------------


def test_preset_sets_defaults_and_explicit_parameters_win() -> None:
    preset = PlanSpec.from_mapping({"scanner": "zf-imager-5016"})
    # sourced: maximum range and a 320 deg vertical field (blind cone of 40 deg)
    assert preset.dof_max_m == 360.0
    assert (preset.elevation_min_deg, preset.elevation_max_deg) == (-70.0, 90.0)
    # no sourced minimum range or settings: the plan's own defaults stay
    assert preset.dof_min_m == PlanSpec().dof_min_m
    assert preset.point_spacing_m == PlanSpec().point_spacing_m
    explicit = PlanSpec.from_mapping({"scanner": "zf-imager-5016", "dof_max_m": 40.0,
                                      "dof_min_m": 0.5})
    assert (explicit.dof_min_m, explicit.dof_max_m) == (0.5, 40.0)


def test_preset_without_sourced_figures_keeps_every_default() -> None:
    bare = PlanSpec.from_mapping({"scanner": "riegl-vz-400i"})
    assert bare.with_changes(scanner=None) == PlanSpec()


def test_no_preset_keeps_the_papers_table_2() -> None:
    assert PlanSpec.from_mapping({}) == PlanSpec()
    assert PlanSpec().scanner is None and PlanSpec().dof_min_m == 1.5


def test_unknown_preset_names_the_parameter_and_the_known_ones() -> None:
    with pytest.raises(ParameterError, match=r"scanner: 'leica-x' is not a known preset.*"
                                             r"trimble-x7"):
        PlanSpec.from_mapping({"scanner": "leica-x"})


def test_scanners_lists_every_preset_with_each_figure_and_its_source(
        capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["scanners", "--json"]) == 0
    listed = json.loads(capsys.readouterr().out)
    assert len({s["maker"] for s in listed}) >= 5
    assert all(s["sources"] or not s["defaults"] for s in listed)
    for preset in listed:
        for figure in preset["figures"].values():
            assert figure["reason"] if figure["value"] is None else figure["source"] in (
                preset["sources"])
    assert main(["scanners"]) == 0
    lines = capsys.readouterr().out.splitlines()
    headers = [line.split()[0] for line in lines if not line.startswith(" ")]
    assert headers == [s["id"] for s in listed] + ["sources"]
    # every figure a line: its value and source key, or "-" and why there is none
    vz400 = lines[lines.index(next(x for x in lines if x.startswith("riegl-vz-400 "))) + 1:]
    assert vz400[0].split()[:3] == ["min_range_m", "1.5", "helios-scanners-tls"]
    assert any("https://github.com/3dgeo-heidelberg/helios" in line for line in lines)


# --- registration overlap --------------------------------------------------------------


@pytest.fixture(scope="module")
def rooms() -> tuple[PlanResult, PlanResult]:
    scene = two_rooms()
    spec = PlanSpec(candidates=two_room_candidates(), max_edge_m=None)
    return plan(scene, spec), plan(scene, spec.with_changes(min_overlap_m2=2.0))


def test_papers_plan_is_disconnected_and_the_constrained_plan_connected(
        rooms: tuple[PlanResult, PlanResult]) -> None:
    paper, constrained = rooms
    rows = overlap_matrix(paper.scene, paper.candidates.positions[list(paper.chosen.stations)],
                          paper.limits, make_occlusion(paper.scene, paper.limits.occludes,
                                                       "embree"), 1600.0)
    assert not station_registration(paper.scene, rows, 2.0, 1600.0).connected
    # the rows cut to the faces two stations share register the same, to the last bit
    cut = shared_faces_only(rows)
    assert cut.nnz < rows.nnz
    assert (station_registration(paper.scene, cut, 2.0, 1600.0)
            == station_registration(paper.scene, rows, 2.0, 1600.0))
    document = plan_document(constrained)
    registration = document["registration"]
    assert registration["connected"] and registration["min_overlap_m2"] == 2.0
    assert registration["components"] == [list(range(1, len(constrained.chosen.stations) + 1))]
    assert document["goal_reached"]
    # the paper's selection is untouched by the constraint (only the plan changes)
    assert constrained.selections["greedy"].stations == paper.selections["greedy"].stations


def test_optimal_with_the_constraint_returns_a_connected_plan_from_its_flow_milp() -> None:
    # at 90 % the two rooms need one station each: unconstrained, the optimum (2) cannot
    # register; the flow MILP adds the third station joining them and proves 3 the fewest
    scene = two_rooms()
    spec = PlanSpec(candidates=two_room_candidates(), max_edge_m=None, method="optimal",
                    coverage_goal=0.9)
    free = plan_document(plan(scene, spec))
    assert free["selection"]["stations"] == 2 and free["selection"]["proven_optimal"]
    assert not free["registration"]["connected"]
    assert "connectivity" not in free["selection"]
    joined = plan_document(plan(scene, spec.with_changes(min_overlap_m2=2.0)))
    selection = joined["selection"]
    assert joined["registration"]["connected"] and joined["goal_reached"]
    assert selection["method"] == "optimal" and selection["stations"] == 3
    assert selection["proven_optimal"] and selection["lower_bound"] == 3
    assert selection["connectivity"]["formulation"] == "flow"
    assert selection["connectivity"]["overlap_edges"] > 0


def test_too_many_overlap_edges_leave_the_connected_greedy_plan(
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(connectivity, "MAX_FLOW_EDGES", 10)
    spec = PlanSpec(candidates=two_room_candidates(), max_edge_m=None, method="optimal",
                    coverage_goal=0.9, min_overlap_m2=2.0)
    document = plan_document(plan(two_rooms(), spec))
    selection = document["selection"]
    assert document["registration"]["connected"] and document["goal_reached"]
    assert selection["connectivity"]["formulation"] == "connected_greedy"
    assert "exceed 10" in selection["connectivity"]["note"]
    assert "too many for the flow MILP" in selection["status"]
    assert selection["stations"] == selection["heuristics"]["greedy"]


def test_edge_overlap_is_the_area_of_the_faces_both_stations_qualify_for(
        rooms: tuple[PlanResult, PlanResult]) -> None:
    _, result = rooms
    positions = result.candidates.positions[list(result.chosen.stations)]
    rows = overlap_matrix(result.scene, positions, result.limits,
                          make_occlusion(result.scene, result.limits.occludes, "embree"), 1600.0)
    edges = plan_document(result)["registration"]["edges"]
    assert any(e["ok"] for e in edges)
    for edge in edges:
        a, b = rows[edge["a"] - 1].indices, rows[edge["b"] - 1].indices
        shared = np.intersect1d(a, b)
        assert edge["overlap_m2"] == pytest.approx(result.scene.areas[shared].sum(), rel=0.01)
        normals = result.scene.normals[shared]
        scatter = (normals * result.scene.areas[shared, None]).T @ normals
        ratio = np.linalg.eigvalsh(scatter)[0] / np.trace(scatter)
        assert edge["constraint"] == pytest.approx(ratio, abs=1e-5)
        assert edge["ok"] == (edge["overlap_m2"] >= 2.0 and ratio >= MIN_CONSTRAINT)


def test_overlap_on_coarser_pieces_is_the_area_both_stations_qualify_for_on_them() -> None:
    # the rooms split as needed into 0.25 m pieces for the coverage; the overlap measured
    # on pieces of at most 1 m: the same stations and coverage, and every edge is the area
    # of the 1 m pieces both stations qualify for (an independent split of every face)
    scene = two_rooms().replaced(split_max_edge_m=0.25)
    spec = PlanSpec(candidates=two_room_candidates(), max_edge_m=0.25)
    fine = plan(scene, spec)
    coarse = plan(scene, spec.with_changes(overlap_max_edge_m=1.0))
    assert coarse.chosen.stations == fine.chosen.stations
    assert np.array_equal(coarse.faces["covered"], fine.faces["covered"])
    pieces = remesh(two_rooms(), 1.0)
    assert pieces.n_faces < fine.scene.n_faces / 2
    limits = FaceLimits.from_spec(spec, pieces)
    positions = coarse.candidates.positions[list(coarse.chosen.stations)]
    rows = overlap_matrix(pieces, positions, limits,
                          make_occlusion(pieces, limits.occludes, "embree", file_faces=True),
                          1600.0)
    edges = plan_document(coarse)["registration"]["edges"]
    fine_edges = plan_document(fine)["registration"]["edges"]
    assert [(e["a"], e["b"]) for e in edges] == [(e["a"], e["b"]) for e in fine_edges]
    for edge in edges:
        shared = np.intersect1d(rows[edge["a"] - 1].indices, rows[edge["b"] - 1].indices)
        assert edge["overlap_m2"] == pytest.approx(pieces.areas[shared].sum(), abs=1e-6)
    # measured on other pieces than the coverage's: the areas differ at the limits' edges
    assert [e["overlap_m2"] for e in edges] != [e["overlap_m2"] for e in fine_edges]


# stations of the eager connected greedy (every candidate's overlap row computed up front,
# as before the rows became lazy), min_overlap_m2 5, the halls' candidates.csv
EAGER_STATIONS = {
    ("hall-small", "greedy"): [149, 57],
    ("hall-small", "weighted_greedy"): [35, 189, 128],
    ("hall-full", "greedy"): [374, 924, 269, 986, 976, 754],
}


@pytest.mark.parametrize(("name", "method"), sorted(EAGER_STATIONS))
def test_lazy_overlap_rows_choose_the_stations_of_the_eager_greedy(
        scenes_dir: Path, name: str, method: str) -> None:
    folder = scenes_dir / name
    scene = read_scene(folder / "hall.obj", max_edge_m=None)
    candidates = read_candidates_csv(folder / "candidates.csv")
    spec = PlanSpec(candidates=tuple(map(tuple, candidates.tolist())), max_edge_m=None,
                    min_overlap_m2=5.0, method=method)
    result = plan(scene, spec)
    assert list(result.chosen.stations) == EAGER_STATIONS[(name, method)]
    # only the candidates the greedy considered: a few per station, not every candidate
    assert result.stats.overlap_rows <= 4 * len(result.chosen.stations)
    assert plan_document(result)["registration"]["connected"]


@pytest.mark.parametrize(("method", "eager"), [("greedy", [4, 6, 8, 7, 1, 3]),
                                             ("weighted_greedy", [13, 9, 11, 12, 10, 14, 16])])
def test_lazy_relay_is_the_relay_of_the_eager_greedy(method: str, eager: list[int]) -> None:
    # 30 m^2 of overlap is more than the doorway lets through: one relay (no new area)
    result = plan(two_rooms(), PlanSpec(candidates=two_room_candidates(), max_edge_m=None,
                                        coverage_goal=0.95, min_overlap_m2=30.0, method=method))
    assert list(result.chosen.stations) == eager
    assert result.chosen.new_area_m2.count(0.0) == 1


def test_plan_json_and_stations_csv_carry_the_visit(rooms: tuple[PlanResult, PlanResult]) -> None:
    _, result = rooms
    document = plan_document(result)
    visits = [s["visit"] for s in document["stations"]]
    assert sorted(visits) == list(range(1, len(visits) + 1))
    assert sorted(document["route"]["visits"]) == [s["id"] for s in document["stations"]]
    lines = stations_csv(result).decode().splitlines()
    assert lines[0].endswith(",visit")
    assert [int(line.split(",")[-1]) for line in lines[1:]] == visits
    field = document["field_time"]
    assert field["setup_s"] == 60.0 * len(visits)
    assert field["walk_s"] == pytest.approx(document["route"]["length_m"] / 0.8, abs=0.1)
    assert field["scan_s"] is None and field["total_s"] is None  # no preset: no scan time


def test_field_time_without_a_sourced_scan_duration_leaves_the_scan_time_open() -> None:
    # no stored source gives a preset's scan durations: setup and walk only, no total
    scene = two_rooms()
    spec = PlanSpec.from_mapping({"scanner": "trimble-x7", "max_edge_m": None,
                                  "candidates": [list(c) for c in two_room_candidates()],
                                  "setup_time_s": 90.0, "walking_speed_m_s": 1.0})
    assert spec.dof_max_m == 80.0
    document = plan_document(plan(scene, spec))
    n = len(document["stations"])
    field = document["field_time"]
    assert field["scanner"] == "trimble-x7"
    assert field["setup_s"] == 90.0 * n
    assert field["scan_s"] is None and field["total_s"] is None


# --- walking route ---------------------------------------------------------------------


def _assert_free_at_knee_height(scene_caster: object, path: list[list[float]]) -> None:
    points = np.asarray(path, float)
    assert segment_free(scene_caster, points[:-1], points[1:]).all()  # type: ignore[arg-type]
    assert segment_free(scene_caster, points[1:], points[:-1]).all()  # type: ignore[arg-type]


def test_route_climbs_the_stairs() -> None:
    scene = staircase()
    caster = make_ray_caster(scene, np.ones(scene.n_faces, bool))
    stations = np.array([[1.5, 2.2, 1.5], [4.5, 1.5, MEZZANINE_Z_M + 1.5]])
    route = plan_route(build_walk_graph(scene, caster), caster, stations, None).to_dict()
    assert route["unreachable"] == [] and sorted(route["visits"]) == [1, 2]
    (leg,) = route["legs"]
    heights = sorted(p[2] for p in leg["path"])
    assert heights[0] == pytest.approx(KNEE_HEIGHT_M, abs=0.01)
    assert heights[-1] == pytest.approx(MEZZANINE_Z_M + KNEE_HEIGHT_M, abs=0.01)
    assert sum(1.0 < z < 2.0 for z in heights) >= 3  # on the steps, not a jump
    _assert_free_at_knee_height(caster, leg["path"])
    # walking is longer than the straight line, which goes through the mezzanine slab
    assert leg["length_m"] > np.linalg.norm(stations[1] - stations[0])


def test_routes_over_fewer_stations_from_kept_trees_are_the_routes_walked_afresh(
        scenes_dir: Path) -> None:
    """A budget of hours routes every start of an order: the trees of the first, largest
    route serve the others, which must be the same routes, paths and all."""
    scene = read_scene(scenes_dir / "hall-full" / "hall.obj", max_edge_m=None)
    caster = make_ray_caster(scene, np.ones(scene.n_faces, bool))
    graph = build_walk_graph(scene, caster)
    positions = read_candidates_csv(scenes_dir / "hall-full" / "candidates.csv")
    stations = positions[np.random.default_rng(5).choice(len(positions), 24, replace=False)]
    trees = TreeCache()
    whole = plan_route(graph, caster, stations, None, trees=trees)
    assert whole.to_dict() == plan_route(graph, caster, stations, None).to_dict()
    assert len(whole.visits) >= 20 and len(whole.legs) >= 19
    for subset in (stations[:7], stations[::3], stations[[4, 1, 9, 17]],
                   np.vstack([stations[:5], positions[:2]])):  # the last: two not kept
        assert plan_route(graph, caster, subset, None, trees=trees).to_dict() == \
            plan_route(graph, caster, subset, None).to_dict()


def test_unreachable_station_is_reported_not_joined() -> None:
    scene = two_rooms(closet=True)
    caster = make_ray_caster(scene, np.ones(scene.n_faces, bool))
    stations = np.array([[2.0, 2.0, 1.5], [11.0, 1.0, 1.5], [6.2, 3.0, 1.5]])
    route = plan_route(build_walk_graph(scene, caster), caster, stations, None).to_dict()
    # the sealed closet's station is walked in a part of its own: no leg joins it, the
    # step to it says why (the crew finds the way in on site)
    assert route["unreachable"] == []
    assert route["visits"][-1] == 2 and sorted(route["visits"]) == [1, 2, 3]
    assert all(2 not in (leg["from"], leg["to"]) for leg in route["legs"])
    (step,) = route["steps_between_parts"]
    assert step["to"] == 2 and step["from"] == route["visits"][-2]
    assert "cut off from the route" in step["note"], step
    assert "a room without a door or opening in the model" in step["note"], step
    assert [part["visits"] for part in route["parts"]] == [route["visits"][:2], [2]]
    assert route["parts"][1]["length_m"] == 0.0
    assert sum(part["length_m"] for part in route["parts"]) == pytest.approx(
        route["length_m"], abs=0.01)
    for leg in route["legs"]:
        _assert_free_at_knee_height(caster, leg["path"])
        # the only way between the rooms is the door
        xs = [p[0] for p in leg["path"]]
        door = [p for p in leg["path"] if 3.9 < p[0] < 4.3]
        assert min(xs) < 4.0 < max(xs) and door
        assert all(0.3 < p[1] < 1.2 for p in door)


def test_route_from_a_given_start() -> None:
    scene = two_rooms()
    caster = make_ray_caster(scene, np.ones(scene.n_faces, bool))
    stations = np.array([[2.0, 2.0, 1.5], [6.2, 3.0, 1.5], [1.0, 3.0, 1.5]])
    route = plan_route(build_walk_graph(scene, caster), caster, stations,
                       (7.0, 1.0, 1.5)).to_dict()
    assert route["legs"][0]["from"] is None and route["visits"][0] == 2
    assert route["length_m"] == pytest.approx(sum(leg["length_m"] for leg in route["legs"]),
                                              abs=0.01)
    with pytest.raises(ParameterError, match=r"route_start: \[20.0, 2.0, 1.5\] is not over a "):
        plan_route(build_walk_graph(scene, caster), caster, stations, (20.0, 2.0, 1.5))


@pytest.mark.parametrize("start", [None, 0])
def test_tour_of_up_to_ten_stations_is_the_exact_optimum(start: int | None) -> None:
    rng = np.random.default_rng(7)
    points = rng.random((8, 3)) * [20, 10, 3]
    cost = np.linalg.norm(points[:, None] - points[None], axis=2)

    def length(order: tuple[int, ...] | list[int]) -> float:
        return float(sum(cost[a, b] for a, b in itertools.pairwise(order)))

    firsts = range(8) if start is None else [start]
    best = min(length((f, *rest)) for f in firsts
               for rest in itertools.permutations([i for i in range(8) if i != f]))
    order = open_tour(cost, start)
    assert sorted(order) == list(range(8)) and length(order) == pytest.approx(best)
    assert start is None or order[0] == start


def test_long_tour_visits_every_station_once_and_beats_the_input_order() -> None:
    rng = np.random.default_rng(3)
    points = rng.random((30, 2)) * 50
    cost = np.linalg.norm(points[:, None] - points[None], axis=2)
    order = open_tour(cost, None)
    assert sorted(order) == list(range(30))
    walked = sum(cost[a, b] for a, b in itertools.pairwise(order))
    assert walked < sum(cost[i, i + 1] for i in range(29)) / 2
    assert order == open_tour(cost, None)  # deterministic
    assert exact_open_tour(cost[:5, :5], None) == open_tour(cost[:5, :5], None)


def test_model_without_a_floor_leaves_every_station_unreachable() -> None:
    scene = boxes_scene([((3.0, -2.0, 0.0), (3.2, 2.0, 3.0))])  # one free-standing wall
    caster = make_ray_caster(scene, np.ones(scene.n_faces, bool))
    graph = build_walk_graph(scene, caster)
    route = plan_route(graph, caster, np.array([[0.0, 0.0, 1.5], [1.0, 0.0, 1.5]]), None)
    document = route.to_dict()
    reasons = document.pop("unreachable_reasons")
    assert document == {"visits": [], "length_m": 0.0, "legs": [], "unreachable": [1, 2]}
    assert list(reasons) == ["1", "2"] and all(r.startswith("no floor") for r in reasons.values())


def test_shared_sums_equal_the_dense_masked_product() -> None:
    """The connected greedy's overlap sums, row by row, are the dense masked product's bits,
    also for an empty station row and rows that share nothing."""
    import scipy.sparse as sp

    from planner.selection.connected import _shared_with

    rng = np.random.default_rng(3)
    n_faces = 500
    area = rng.uniform(0.01, 0.5, n_faces)
    weights6 = rng.normal(size=(n_faces, 6))
    rows = [np.sort(rng.choice(n_faces, k, replace=False)) for k in (0, 40, 200, 3)]
    matrix = sp.csr_matrix((np.ones(sum(map(len, rows))), np.concatenate(rows),
                            np.r_[0, np.cumsum([len(r) for r in rows])]),
                           shape=(len(rows), n_faces))
    for station in (np.zeros(0, np.int64), rows[2], np.setdiff1d(np.arange(n_faces), rows[1])):
        mask = np.zeros(n_faces)
        mask[station] = 1.0
        dense = np.column_stack([matrix @ (area * mask), matrix @ (weights6 * mask[:, None])])
        shared = _shared_with(matrix, station, area, lambda faces: weights6[faces])
        assert shared.dtype == np.float64
        np.testing.assert_array_equal(shared, dense)


def test_station_pair_sums_equal_the_dense_masked_products() -> None:
    """The registration's compiled sums over the faces two stations share are the bits of
    the dense masked products (:func:`overlap_with`'s), for every pair: rows that share
    nothing, a row with no face, normals whose products cancel."""
    import scipy.sparse as sp

    from planner.selection.connected import SCATTER_TERMS
    from planner.survey.registration import _shared_sums

    rng = np.random.default_rng(5)
    n_faces = 400
    area = rng.uniform(0.01, 0.5, n_faces)
    file_normals = rng.normal(size=(n_faces // 4, 3))  # pieces share their file face's
    file_normals[::7, 0] = 0.0  # x products of exactly zero, some sums of +-0.0
    file_normals /= np.linalg.norm(file_normals, axis=1)[:, None]
    source = rng.integers(0, len(file_normals), n_faces).astype(np.int32)
    normals = file_normals[source]
    weights6 = np.stack([normals[:, i] * normals[:, j] * area for i, j in SCATTER_TERMS], 1)
    rows = [np.sort(rng.choice(n_faces, k, replace=False)) for k in (120, 0, 300, 5, 200)]
    rows.append(np.setdiff1d(np.arange(n_faces), rows[0]))  # shares nothing with row 0
    matrix = sp.csr_matrix((np.ones(sum(map(len, rows))), np.concatenate(rows),
                            np.r_[0, np.cumsum([len(r) for r in rows])]),
                           shape=(len(rows), n_faces))
    sums = _shared_sums(matrix.indptr.astype(np.int32), matrix.indices.astype(np.int32),
                        n_faces, area, file_normals, source, np.array(SCATTER_TERMS))
    assert sums.shape == (len(rows), len(rows), 7)
    for a, faces in enumerate(rows):
        mask = np.zeros(n_faces)
        mask[faces] = 1.0
        dense = np.column_stack([matrix @ (area * mask), matrix @ (weights6 * mask[:, None])])
        np.testing.assert_array_equal(sums[a], dense)
        assert not np.signbit(sums[a][dense == 0.0]).any()
    assert (sums[0, 5] == 0.0).all() and (sums[1] == 0.0).all()


def test_route_walks_the_building_not_its_site() -> None:
    """A house on a 110 x 100 m site: the walk covers the candidates' ground and
    ``WALK_AREA_MARGIN_M`` around it, not the whole terrain, and the route is the one the
    whole site's walk gives."""
    house = two_rooms()
    terrain = trimesh.creation.box(bounds=np.array([[-50.0, -50.0, -0.5], [60.0, 50.0, -0.2]]))
    scene = build_scene(np.concatenate([house.vertices, terrain.vertices]),
                        np.concatenate([house.faces, terrain.faces + len(house.vertices)]))
    caster = make_ray_caster(scene, np.ones(scene.n_faces, bool))
    candidates = np.array(two_room_candidates())
    stations = candidates[[0, 7, 16]]
    area = walk_area(candidates)
    assert area is not None
    assert area.tolist() == [[1.0 - WALK_AREA_MARGIN_M, 1.0 - WALK_AREA_MARGIN_M],
                             [7.2 + WALK_AREA_MARGIN_M, 3.0 + WALK_AREA_MARGIN_M]]
    whole = build_walk_graph(scene, caster)
    walked = build_walk_graph(scene, caster, area_xy=area)
    assert walked.n_nodes < whole.n_nodes / 20
    xy = walked.floor_xyz[:, :2]
    assert ((xy >= area[0] - walked.grid_m) & (xy <= area[1] + walked.grid_m)).all()
    # the house's own floor samples are the same points on either walk
    inside = ((whole.floor_xyz[:, :2] > [-0.2, -0.2]) & (whole.floor_xyz[:, :2] < [8.4, 4.2])
              ).all(axis=1)
    indoors = whole.floor_xyz[inside & (whole.floor_xyz[:, 2] > -0.1)].tolist()
    assert len(indoors) > 400
    assert {tuple(p) for p in indoors} <= {tuple(p) for p in walked.floor_xyz.tolist()}
    route = plan_route(walked, caster, stations, None).to_dict()
    reference = plan_route(whole, caster, stations, None).to_dict()
    assert route["visits"] == reference["visits"] and route["unreachable"] == []
    assert route["length_m"] == pytest.approx(reference["length_m"], abs=1e-6)
    for leg in route["legs"]:
        _assert_free_at_knee_height(caster, leg["path"])


def _site_with_a_fence() -> Scene:
    """110 x 100 m of flat terrain (top at z = -0.2) and a 3 m fence along x = 20 m from
    the site's edge at y = -50 to y = 40 m: walked round its far end only."""
    boxes = [((-50.0, -50.0, -0.5), (60.0, 50.0, -0.2)), ((20.0, -50.0, -0.2), (20.2, 40.0, 3.0))]
    meshes = [trimesh.creation.box(bounds=np.array(box)) for box in boxes]
    return build_scene(np.concatenate([m.vertices for m in meshes]),
                       np.concatenate([meshes[0].faces, meshes[1].faces + len(meshes[0].vertices)]))


def test_a_cut_off_piece_of_the_site_is_told_from_a_closed_room() -> None:
    """A one-room house with a doorway to its 40 x 25 m site, a sealed closet on the site,
    a pen of open ground fenced in all round (2.2 m fence, no gate) and a 2.3 m deep pit
    with sheer sides: the stations in the pen and the pit are on the site outside the
    building, the closet's in a room without a doorway."""
    house = boxes_scene([((-0.2, -0.2, -0.2), (4.2, 4.2, 0.0)),
                         ((-0.2, -0.2, 2.5), (4.2, 4.2, 2.7)),
                         ((4.0, -0.2, 0.0), (4.2, 4.2, 2.5)), ((0.0, -0.2, 0.0), (4.0, 0.0, 2.5)),
                         ((0.0, 4.0, 0.0), (4.0, 4.2, 2.5)),
                         # the west wall, with a doorway at y in [1.0, 1.9]
                         ((-0.2, -0.2, 0.0), (0.0, 1.0, 2.5)), ((-0.2, 1.9, 0.0), (0.0, 4.2, 2.5)),
                         ((-0.2, 1.0, 2.1), (0.0, 1.9, 2.5)),
                         *room_shell(10.0, 12.0, 0.0, 2.0)])
    site = [((-10.0, -10.0, -0.5), (22.0, 15.0, -0.2)), ((28.0, -10.0, -0.5), (30.0, 15.0, -0.2)),
            ((22.0, -10.0, -0.5), (28.0, -3.0, -0.2)), ((22.0, 3.0, -0.5), (28.0, 15.0, -0.2)),
            ((22.0, -3.0, -2.8), (28.0, 3.0, -2.5)),  # the pit's bottom
            # the pen's fence
            ((12.0, 6.0, -0.2), (12.2, 12.2, 2.0)), ((18.0, 6.0, -0.2), (18.2, 12.2, 2.0)),
            ((12.2, 6.0, -0.2), (18.0, 6.2, 2.0)), ((12.2, 12.0, -0.2), (18.0, 12.2, 2.0))]
    meshes = [trimesh.creation.box(bounds=np.array(box)) for box in site]
    offsets = np.cumsum([len(house.vertices)] + [len(m.vertices) for m in meshes])
    scene = build_scene(np.concatenate([house.vertices] + [m.vertices for m in meshes]),
                        np.concatenate([house.faces] + [m.faces + offset for m, offset
                                                        in zip(meshes, offsets, strict=False)]))
    caster = make_ray_caster(scene, np.ones(scene.n_faces, bool))
    # in the room, on the site, in the pen, in the pit, in the closet
    stations = np.array([[2.0, 2.0, 1.5], [-5.0, 2.0, 1.3], [15.0, 9.0, 1.3],
                         [25.0, 0.0, -1.0], [11.0, 1.0, 1.5]])
    route = plan_route(build_walk_graph(scene, caster), caster, stations, None)
    assert route.unreachable == ()
    reasons = {step.end: step.reason for step in route.steps}
    assert sorted(reasons) == [3, 4, 5]
    pen, pit, closet = reasons[3], reasons[4], reasons[5]
    assert pen.startswith("it stands on the site outside the building, cut off from the "
                          "route (33.1 m² of open ground at -0.20 m: no roof or ceiling over "
                          "it, outside the building's footprint)"), pen
    assert "something stands between them at 0.5 m above the ground (a wall, a fence" in pen
    assert pit.startswith("it stands on the site outside the building, cut off from the "
                          "route (36.0 m² of open ground at -2.50 m"), pit
    assert "no modelled ground joins it to the route (the route's floor nearest its " \
        "height, at -0.20 m, lies elsewhere)" in pit, pit
    assert closet.startswith("it stands in a part of the building cut off from the route "
                             "(4.0 m² of floor at +0.00 m)"), closet
    assert "a wall stands between them" in closet and "no doorway" in closet, closet


def test_route_looks_beyond_the_area_when_two_parts_reach_its_edge() -> None:
    """Two stations either side of a long fence: on the walked area alone (the candidates'
    ground and 5 m round it) they are apart, but both parts reach the area's edge, so the
    survey walks the whole site and goes round the fence's far end; a sealed closet's
    station stays apart without that (its part reaches no edge)."""
    scene = _site_with_a_fence()
    spec = PlanSpec(max_edge_m=None)
    limits = FaceLimits.from_spec(spec, scene)
    caster = make_ray_caster(scene, limits.occludes)
    stations = np.array([[15.0, 0.0, 1.3], [25.0, 0.0, 1.3]])
    area = walk_area(stations)
    walked = build_walk_graph(scene, caster, area_xy=area)
    assert [step.end for step in plan_route(walked, caster, stations, None).steps] == [2]
    assert parts_may_join_outside(walked, caster, stations)
    found = survey(scene, spec, stations, limits, make_occlusion(scene, limits.occludes,
                                                                 "embree"),
                   caster, {}, walk_area_xy=area).route.to_dict()
    assert found["unreachable"] == [] and "steps_between_parts" not in found
    (leg,) = found["legs"]
    assert max(p[1] for p in leg["path"]) > 40.0  # round the fence's end
    assert leg["length_m"] > 2 * 40.0
    closet = two_rooms(closet=True)
    closet_caster = make_ray_caster(closet, np.ones(closet.n_faces, bool))
    inside = np.array([[3.6, 2.0, 1.5], [11.0, 1.0, 1.5]])
    # an area that cuts room A and holds the closet whole
    graph = build_walk_graph(closet, closet_caster, area_xy=np.array([[3.0, -1.0], [13.0, 5.0]]))
    assert [step.end for step in plan_route(graph, closet_caster, inside, None).steps] == [2]
    assert len(graph.cut_nodes) and not parts_may_join_outside(graph, closet_caster, inside)
