"""Properties that hold on any scene: Embree agrees with brute force, occluders only take
coverage away, the optimal plan is never longer than either greedy's, and runs are deterministic."""

from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from planner.errors import NothingVisibleError
from planner.outputs.report import faces_npz, plan_json
from planner.parameters import PlanSpec
from planner.pipeline import plan
from planner.scene import Scene, build_scene

SETTINGS = settings(max_examples=15, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow])


def boxes_scene(boxes: list[tuple[float, float, float, float]]) -> Scene:
    """A 6 x 6 x 3 m room with axis-aligned boxes (x, y, size, height) standing in it.

    Every part is subdivided on its own (faces <= 0.8 m), so adding a box appends faces and
    keeps the earlier ones where they were.
    """
    import trimesh

    room = trimesh.creation.box(extents=(6, 6, 3))
    room.apply_translation((3, 3, 1.5))
    parts = [room]
    for x, y, size, height in boxes:
        box = trimesh.creation.box(extents=(size, size, height))
        box.apply_translation((x, y, height / 2))
        parts.append(box)
    vertices, faces, offset = [], [], 0
    for part in parts:
        v, f = trimesh.remesh.subdivide_to_size(part.vertices, part.faces, 0.8)
        vertices.append(v)
        faces.append(f + offset)
        offset += len(v)
    return build_scene(np.concatenate(vertices), np.concatenate(faces))


def first_hit_is_undefined(scene: Scene, candidate: np.ndarray, face: int) -> bool:
    """The ray to ``face`` has no well-defined first hit: it grazes an occluder's edge (hit
    or miss depends on a 1e-6 tolerance), or another face lies at the target's distance
    (a duplicated surface, where either may count as first)."""
    from planner.rays.bruteforce import ray_triangle_distance

    offset = scene.centroids[face] - candidate
    distance = float(np.linalg.norm(offset))
    direction = offset / distance
    others = np.delete(scene.triangles, face, axis=0)
    wide = ray_triangle_distance(candidate, direction, others, edge_tolerance=1e-6)
    narrow = ray_triangle_distance(candidate, direction, others, edge_tolerance=-1e-6)
    blocks_wide = bool((wide < distance * (1 - 1e-9)).any())
    blocks_narrow = bool((narrow < distance * (1 - 1e-9)).any())
    duplicated = bool((np.abs(wide - distance) <= 1e-6 * distance).any())
    return blocks_wide != blocks_narrow or duplicated


box_st = st.tuples(st.floats(1.0, 5.0), st.floats(1.0, 5.0), st.floats(0.2, 1.2),
                   st.floats(0.3, 2.5))
candidate_st = st.tuples(st.floats(0.5, 5.5), st.floats(0.5, 5.5), st.floats(1.0, 2.0))


def in_free_space(boxes: list[tuple[float, float, float, float]],
                  candidates: list[tuple[float, float, float]], margin_m: float = 0.05) -> bool:
    """No candidate inside or on a box: a scanner stands in free space, and a ray that
    starts on a surface has no defined first hit."""
    for x, y, z in candidates:
        for bx, by, size, height in boxes:
            half = size / 2 + margin_m
            if abs(x - bx) <= half and abs(y - by) <= half and z <= height + margin_m:
                return False
    return True


def spec_for(candidates: list[tuple[float, float, float]], **changes: object) -> PlanSpec:
    return PlanSpec(candidates=tuple(candidates), max_edge_m=None, min_density_pts_m2=2_000,
                    **changes)  # type: ignore[arg-type]


@SETTINGS
@given(boxes=st.lists(box_st, min_size=1, max_size=3),
       candidates=st.lists(candidate_st, min_size=1, max_size=3))
def test_embree_equals_brute_force_pair_for_pair(boxes, candidates) -> None:
    assume(in_free_space(boxes, candidates))
    scene = boxes_scene(boxes)
    spec = spec_for(candidates)
    try:
        fast = plan(scene, spec, keep_table=True)
    except NothingVisibleError:  # both backends must agree on that too
        with np.testing.assert_raises(NothingVisibleError):
            plan(scene, spec, backend="bruteforce")
        return
    slow = plan(scene, spec, backend="bruteforce", keep_table=True)
    a, b = fast.table.by_candidate.tocoo(), slow.table.by_candidate.tocoo()
    pairs_a = set(zip(a.row.tolist(), a.col.tolist(), strict=True))
    pairs_b = set(zip(b.row.tolist(), b.col.tolist(), strict=True))
    # float32 (Embree) and float64 rays may disagree only where the first hit is undefined
    positions = np.asarray(candidates, float)
    for c, f in pairs_a ^ pairs_b:
        assert first_hit_is_undefined(scene, positions[c], f), (c, f)


@SETTINGS
@given(boxes=st.lists(box_st, min_size=0, max_size=2), extra=box_st,
       candidates=st.lists(candidate_st, min_size=1, max_size=3))
def test_an_added_occluder_never_adds_coverage(boxes, extra, candidates) -> None:
    assume(in_free_space([*boxes, extra], candidates))
    before = boxes_scene(boxes)
    after = boxes_scene([*boxes, extra])
    spec = spec_for(candidates, group_requirements={})
    try:
        table_before = plan(before, spec, keep_table=True).table
    except NothingVisibleError:
        return
    n_old = before.n_faces  # the old faces come first in the new scene, in the same order
    try:
        table_after = plan(after, spec, keep_table=True).table
    except NothingVisibleError:
        return  # nothing visible any more: coverage only went down
    old_after = table_after.by_candidate[:, :n_old] != 0
    old_before = table_before.by_candidate != 0
    # every pair still qualified was qualified before, but where the first hit is undefined
    # (two boxes in one place: which twin face a ray meets first may change with the BVH)
    gained = (old_after > old_before).tocoo()
    positions = np.asarray(candidates, float)
    for c, f in zip(gained.row.tolist(), gained.col.tolist(), strict=True):
        assert first_hit_is_undefined(before, positions[c], f), (c, f)


@SETTINGS
@given(boxes=st.lists(box_st, min_size=1, max_size=2),
       candidates=st.lists(candidate_st, min_size=2, max_size=6),
       goal=st.sampled_from([0.5, 0.8, 0.95, 1.0]))
def test_optimal_never_needs_more_stations_than_greedy(boxes, candidates, goal) -> None:
    scene = boxes_scene(boxes)
    spec = spec_for(candidates, method="optimal", coverage_goal=goal, optimal_time_limit_s=10)
    try:
        result = plan(scene, spec)
    except NothingVisibleError:
        return
    heuristic = min(s.count_for_goal(goal) for s in result.selections.values())
    assert result.optimal is not None
    assert len(result.chosen.stations) <= heuristic
    assert result.optimal.lower_bound <= len(result.chosen.stations)
    covered = result.chosen.covered_area_m2[-1]
    assert covered >= goal * result.table.max_achievable_area_m2 - 1e-6


@settings(max_examples=5, deadline=None)
@given(boxes=st.lists(box_st, min_size=1, max_size=2),
       candidates=st.lists(candidate_st, min_size=1, max_size=4))
def test_same_input_same_bytes(boxes, candidates) -> None:
    scene = boxes_scene(boxes)
    spec = spec_for(candidates, method="weighted_greedy")
    try:
        first = plan(scene, spec, threads=1)
    except NothingVisibleError:
        return
    second = plan(scene, spec, threads=2)
    assert plan_json(first) == plan_json(second)
    assert faces_npz(first) == faces_npz(second)
