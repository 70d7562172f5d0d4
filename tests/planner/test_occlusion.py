"""The Embree occlusion test. By default one cast a ray, on the pinned kernels; with exact
rays the fast-mode cast is left out only where it cannot change the verdict (a clear hit on
an occluder), so every ray's verdict is that of both casts and the float64 arbitration."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from planner.candidates.grid import read_candidates_csv
from planner.io.readers import read_scene
from planner.limits import FaceLimits
from planner.parameters import PlanSpec
from planner.rays import FAR_LIMIT_FACTOR, make_occlusion
from planner.rays import embree as _embree
from planner.visibility.pairs import PairFinder


@pytest.mark.parametrize("model", ["hall-small/hall.obj", "IfcOpenHouse_IFC4.ifc"])
def test_leaving_out_the_fast_cast_on_clear_hits_changes_no_verdict(
    scenes_dir: Path, model: str, monkeypatch: pytest.MonkeyPatch,
) -> None:
    scene = read_scene(scenes_dir / model, max_edge_m=0.2, split_faces="all")
    # at the registration overlap's density the rays reach through the rooms into walls
    spec = PlanSpec(max_edge_m=0.2, min_density_pts_m2=1600.0)
    limits = FaceLimits.from_spec(spec, scene)
    occlusion = make_occlusion(scene, limits.occludes, "embree", file_faces=True, exact=True)
    assert isinstance(occlusion, _embree.EmbreeOcclusion)
    if model.startswith("hall"):
        positions = read_candidates_csv(scenes_dir / "hall-small/candidates.csv")[::40]
    else:  # points in the house, 1.5 m over its lowest faces
        low, high = scene.vertices.min(axis=0), scene.vertices.max(axis=0)
        positions = np.array([[x, y, low[2] + 1.5] for x in np.linspace(low[0], high[0], 5)[1:-1]
                              for y in np.linspace(low[1], high[1], 5)[1:-1]])
    pairs, _ = PairFinder(scene, limits).find(positions, 0)
    rays = (pairs.origin, pairs.direction, pairs.distance_m, pairs.face)
    exact = pairs.exact_rays(positions, scene)
    skipped = _embree.EmbreeOcclusion._clear_hits

    def counted(self: _embree.EmbreeOcclusion, *args: np.ndarray) -> np.ndarray:
        clear = skipped(self, *args)
        counts.append(int(clear.sum()))
        return clear

    counts: list[int] = []
    monkeypatch.setattr(_embree.EmbreeOcclusion, "_clear_hits", counted)
    with_skips = occlusion.visible(*rays, exact_rays=exact)
    monkeypatch.setattr(_embree.EmbreeOcclusion, "_clear_hits",
                        lambda self, origins, *rest: np.zeros(len(origins), bool))
    both_casts = occlusion.visible(*rays, exact_rays=exact)
    np.testing.assert_array_equal(with_skips, both_casts)
    assert sum(counts) > len(pairs) // 5  # the fast cast really was left out on many rays
    assert 0 < with_skips.sum() < len(pairs)


def test_one_cast_differs_from_the_exact_verdicts_only_on_grazing_rays(scenes_dir: Path) -> None:
    """The default (one robust cast on the pinned kernels) and exact rays give the same
    verdict on every ray but a handful, and each of those is a ray the robust and the fast
    cast disagree on: one float32 cannot decide (it grazes an edge or a corner)."""
    scene = read_scene(scenes_dir / "hall-small/hall.obj", max_edge_m=None)
    limits = FaceLimits.from_spec(PlanSpec(max_edge_m=None), scene)
    positions = read_candidates_csv(scenes_dir / "hall-small/candidates.csv")
    pairs, _ = PairFinder(scene, limits).find(positions, 0)
    rays = (pairs.origin, pairs.direction, pairs.distance_m, pairs.face)
    one_cast = make_occlusion(scene, limits.occludes, "embree")
    exact = make_occlusion(scene, limits.occludes, "embree", exact=True)
    assert not one_cast.exact and exact.exact
    default_verdicts = one_cast.visible(*rays)
    exact_verdicts = exact.visible(*rays, exact_rays=pairs.exact_rays(positions, scene))
    differ = np.flatnonzero(default_verdicts != exact_verdicts)
    assert 0 < len(differ) < len(pairs) * 1e-4
    assert isinstance(exact, _embree.EmbreeOcclusion)
    far = np.multiply(pairs.distance_m[differ], FAR_LIMIT_FACTOR, dtype=np.float32)
    origins32 = pairs.origin[differ].astype(np.float32)
    directions32 = pairs.direction[differ].astype(np.float32)
    robust = exact._bvh.scene
    assert robust is not None
    robust_hits = robust.first_hits(origins32, directions32, far)
    fast_hits = exact._bvh.check_scene().first_hits(origins32, directions32, far)
    assert (robust_hits != fast_hits).all()
    # and a second cast of the default gives the same verdicts, bit for bit
    np.testing.assert_array_equal(one_cast.visible(*rays), default_verdicts)
