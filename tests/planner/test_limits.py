"""Hand-computed cases of the analytic limits and the occlusion test."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from planner.candidates.grid import read_candidates_csv
from planner.density import density_range_m, local_point_density
from planner.io.readers import read_scene
from planner.limits import FaceLimits
from planner.parameters import GroupRequirement, PlanSpec
from planner.pipeline import plan
from planner.visibility.pairs import PairFinder, lpd_of_faces
from tests.planner.scenes import scene_of, small_triangle, square

ORIGIN = (0.0, 0.0, 0.0)


def qualified_faces(scene, spec: PlanSpec) -> set[int]:
    result = plan(scene, spec)
    return set(np.flatnonzero(result.table.achievable).tolist())


def spec_at(*points: tuple[float, float, float], **changes: object) -> PlanSpec:
    return PlanSpec(candidates=tuple(points), max_edge_m=None, **changes)  # type: ignore[arg-type]


def test_lpd_of_a_face_five_metres_away_head_on_is_40000() -> None:
    lpd = local_point_density(np.array([1.0]), np.array([5.0]), 0.010 / 10)
    assert lpd[0] == pytest.approx(40_000.0)


def test_lpd_falls_with_the_sine_of_the_incidence_angle() -> None:
    lpd = local_point_density(np.array([math.sin(math.radians(30))]), np.array([4.0]), 0.001)
    assert lpd[0] == pytest.approx(0.5 / 0.004**2)


def test_density_range_with_the_papers_defaults_is_4_71_m() -> None:
    assert density_range_m(45_000, 0.001) == pytest.approx(4.714, abs=1e-3)
    assert density_range_m(0, 0.001) == math.inf


def test_density_limit_decides_head_on_faces_around_4_71_m() -> None:
    near = small_triangle((4.6, 0, 0), (1, 0, 0))
    far = small_triangle((4.8, 0, 0.05), (1, 0, 0))  # beside the near one, not behind it
    scene = scene_of(near, far)
    assert qualified_faces(scene, spec_at(ORIGIN)) == {0}
    # a lower requirement reaches the far face too: 1 / (0.001 * 4.8)^2 ~ 43 400
    assert qualified_faces(scene, spec_at(ORIGIN, min_density_pts_m2=43_000)) == {0, 1}


def test_face_at_five_metres_passes_only_below_40000() -> None:
    scene = scene_of(small_triangle((5.0, 0, 0), (1, 0, 0)))
    assert qualified_faces(scene, spec_at(ORIGIN, min_density_pts_m2=39_999)) == {0}
    with pytest.raises(Exception, match="no face qualifies"):
        plan(scene, spec_at(ORIGIN, min_density_pts_m2=40_001))


def test_depth_of_field_limits_are_inclusive_of_the_range() -> None:
    too_close = small_triangle((1.4, 0, 0), (1, 0, 0))
    inside = small_triangle((3.0, 0, 0.1), (1, 0, 0))
    scene = scene_of(too_close, inside)
    assert qualified_faces(scene, spec_at(ORIGIN)) == {1}
    # dof_max below 3 m removes the second face as well
    spec = spec_at(ORIGIN, dof_min_m=0.5, dof_max_m=2.0)
    assert qualified_faces(scene, spec) == {0}


def test_blind_cone_under_the_scanner() -> None:
    # scanner 1.5 m above the floor; floor faces at 50 deg and 70 deg below the horizon
    scanner = (0.0, 0.0, 1.5)
    at_50 = small_triangle((1.5 / math.tan(math.radians(50)), 0, 0), (0, 0, 1))
    at_70 = small_triangle((1.5 / math.tan(math.radians(70)), 0, 0), (0, 0, 1))
    scene = scene_of(at_50, at_70)
    spec = spec_at(scanner, dof_min_m=0.5, min_density_pts_m2=0, min_incidence_deg=0)
    assert qualified_faces(scene, spec) == {0}
    # a scanner without a blind cone sees both
    assert qualified_faces(scene, spec.with_changes(elevation_min_deg=-90)) == {0, 1}


def test_grazing_faces_fail_the_incidence_limit() -> None:
    # a wall seen at 10 deg and one seen at 20 deg, both 3 m away
    def wall(angle_deg: float, y: float) -> tuple[np.ndarray, np.ndarray]:
        a = math.radians(angle_deg)
        # normal at (90 - angle) from the ray along +x: sin(incidence) = cos(90 - a) = sin a
        return small_triangle((3.0, y, 0), (math.sin(a), math.cos(a), 0))

    scene = scene_of(wall(10, 0.0), wall(20, 0.3))
    spec = spec_at(ORIGIN, min_density_pts_m2=0)
    assert qualified_faces(scene, spec) == {1}
    assert qualified_faces(scene, spec.with_changes(min_incidence_deg=5)) == {0, 1}


def test_an_occluder_blocks_exactly_the_faces_behind_it() -> None:
    # a wall of 9 faces at x = 4 and a 1 m square screen at x = 2 in front of its middle;
    # the rays to the outer faces pass the screen's plane 0.75 m off its centre
    wall_faces = [small_triangle((4.0, y, z), (1, 0, 0), 0.05)
                  for y in (-1.5, 0.0, 1.5) for z in (-1.5, 0.0, 1.5)]
    screen = square((2.0, 0.0, 0.0), 1.0, 0)
    open_scene = scene_of(*wall_faces)
    blocked_scene = scene_of(*wall_faces, screen)
    spec = spec_at(ORIGIN, min_density_pts_m2=0, dof_min_m=0.5)
    assert qualified_faces(open_scene, spec) == set(range(9))
    seen = qualified_faces(blocked_scene, spec)
    middle = 4  # (y, z) = (0, 0), behind the screen
    assert middle not in seen
    assert seen & set(range(9)) == set(range(9)) - {middle}


def test_a_group_that_does_not_occlude_lets_rays_through() -> None:
    target = small_triangle((4.0, 0, 0), (1, 0, 0), 0.05)
    glass = square((2.0, 0.0, 0.0), 1.0, 0)
    scene = scene_of(target, glass, groups=["wall", "glass"])
    spec = spec_at(ORIGIN, min_density_pts_m2=0, dof_min_m=0.5)
    assert 0 not in qualified_faces(scene, spec)
    glass_passes = spec.with_changes(
        group_requirements={"glass": GroupRequirement(occludes=False, target=False)})
    assert qualified_faces(scene, glass_passes) == {0}


def test_per_group_density_requirement() -> None:
    pipe = small_triangle((4.0, 0, 0), (1, 0, 0))
    wall = small_triangle((4.0, 1.0, 0), (1, 0, 0))
    scene = scene_of(pipe, wall, groups=["pipes", "walls"])
    # head-on at ~4 m: LPD ~ 62 500 (pipe) and ~58 800 (wall at 4.12 m)
    spec = PlanSpec.from_mapping({"candidates": [list(ORIGIN)], "max_edge_m": None,
                                  "group_requirements": {"pipes": {"min_density_pts_m2": 70_000}}})
    assert qualified_faces(scene, spec) == {1}


def test_each_face_keeps_its_own_groups_incidence_and_density() -> None:
    # eight faces 3 m from the scanner, seen at 20 or 40 degrees, of four groups in mixed
    # order; at 3 m the LPD is sin(alpha) * 111 111: 38 000 at 20 deg, 71 400 at 40 deg
    def face(angle_deg: float, bearing_deg: float) -> tuple[np.ndarray, np.ndarray]:
        b, turn = math.radians(bearing_deg), math.radians(bearing_deg + 90 - angle_deg)
        # the normal is (90 - angle) off the ray: sin(incidence) = sin(angle)
        return small_triangle((3 * math.cos(b), 3 * math.sin(b), 0),
                              (math.cos(turn), math.sin(turn), 0))

    layout = [("a", 20), ("c", 40), ("b", 20), ("d", 40), ("c", 20), ("a", 40), ("d", 20),
              ("b", 40)]
    scene = scene_of(*(face(angle, 10 * i) for i, (_, angle) in enumerate(layout)),
                     groups=[group for group, _ in layout])
    spec = PlanSpec.from_mapping({
        "candidates": [list(ORIGIN)], "max_edge_m": None,
        "group_requirements": {
            "a": {"min_incidence_deg": 30},  # 20 deg is too grazing
            "b": {"min_incidence_deg": 10, "min_density_pts_m2": 50_000},  # 38 000 too few
            "c": {"min_incidence_deg": 10, "min_density_pts_m2": 30_000},  # both pass
        }})  # d: the defaults, 15 deg and 45 000: 38 000 too few
    assert qualified_faces(scene, spec) == {1, 3, 4, 5, 7}


def test_lpd_of_faces_is_the_limits_kernels_value_bit_for_bit(scenes_dir: Path) -> None:
    # the plan's per-face densities are computed again from the stations' table rows with
    # lpd_of_faces: they must be the very float32 values the pair search wrote
    scene = read_scene(scenes_dir / "hall-small/hall.obj", max_edge_m=0.2, split_faces="all")
    limits = FaceLimits.from_spec(PlanSpec(max_edge_m=0.2), scene)
    positions = read_candidates_csv(scenes_dir / "hall-small/candidates.csv")[::25]
    pairs, _ = PairFinder(scene, limits).find(positions, 0)
    assert len(pairs) > 10_000
    for c, point in enumerate(positions):
        mine = pairs.candidate == c
        lpd = lpd_of_faces(scene, limits, point, pairs.face[mine])
        assert lpd.dtype == np.float32
        np.testing.assert_array_equal(lpd.view(np.int32), pairs.lpd_pts_m2[mine].view(np.int32))
