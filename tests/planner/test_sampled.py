"""The sampled coverage model against the centroid model on faces where they must differ."""

from __future__ import annotations

import numpy as np
import pytest

from planner.errors import ParameterError
from planner.parameters import PlanSpec
from planner.pipeline import plan
from planner.scene import Scene
from planner.visibility.sampled import sample_stages, sample_weights
from tests.planner.scenes import scene_of, small_triangle, square

SCANNER = [[0.0, 0.0, 0.0]]


def covered(scene: Scene, **params: object) -> np.ndarray:
    spec = PlanSpec.from_mapping({"candidates": SCANNER, "max_edge_m": None,
                                  "coverage_goal": 1.0, "dof_min_m": 1.0,
                                  "group_requirements": {"post": {"target": False}},
                                  **params})
    result = plan(scene, spec, threads=1)
    return np.asarray(result.faces["covered"], bool)


def test_face_half_behind_a_post_is_refused_by_the_sampled_model() -> None:
    # a triangle 3 m ahead, centroid at y = 0; a post at 1.5 m shadows y > 0.08 on it
    face = (np.array([[3.0, -0.3, -0.3], [3.0, 0.3, -0.3], [3.0, 0.0, 0.3]]),
            np.array([[0, 1, 2]]))
    post = square((1.5, 0.12, 0.0), 0.16, 0)
    seen = small_triangle((3.0, -1.0, 0.0), (1.0, 0.0, 0.0), 0.05)
    scene = scene_of(face, seen, post, groups=["face", "seen", "post"])
    centroid, sampled = covered(scene), covered(scene, coverage_model="sampled")
    assert centroid[0] and not sampled[0]
    assert centroid[1] and sampled[1]  # a face in plain view: both models agree
    # enough of it is seen for a relaxed fraction: the shadow covers under half the samples
    assert covered(scene, coverage_model="sampled", min_sampled_fraction=0.5)[0]


def test_ceiling_face_at_60_deg_elevation_is_accepted_by_the_sampled_model() -> None:
    # 5.37 m away at 60 deg: LPD = sin 60 / (0.001 * 5.37)^2 = 30 000 < 45 000 required,
    # while the scanner's grid is twice as dense there (1 / cos 60): 60 000
    elevation = np.radians(60.0)
    at = (5.37 * np.cos(elevation), 0.0, 5.37 * np.sin(elevation))
    ceiling = small_triangle(at, (0.0, 0.0, -1.0), 0.05)
    seen = small_triangle((2.0, 0.0, 0.0), (1.0, 0.0, 0.0), 0.05)
    scene = scene_of(ceiling, seen, groups=["ceiling", "seen"])
    centroid, sampled = covered(scene), covered(scene, coverage_model="sampled")
    assert not centroid[0] and sampled[0]
    assert centroid[1] and sampled[1]


def test_samples_are_equal_area_inside_the_face() -> None:
    weights = sample_weights(16)
    assert weights.shape == (16, 3)
    assert np.allclose(weights.sum(axis=1), 1.0)
    assert (weights > 0).all()
    assert np.allclose(weights.mean(axis=0), 1 / 3)  # equal shares: their mean is the centroid
    assert len({tuple(np.round(w, 9)) for w in weights}) == 16


@pytest.mark.parametrize("samples", [1, 4, 16, 64])
def test_stages_cast_every_sample_once_corners_first(samples: int) -> None:
    stages = sample_stages(samples)
    order = np.concatenate(stages)
    assert sorted(order.tolist()) == list(range(samples))
    if samples > 1:  # the first stages are the triangles in the face's three corners
        weights = sample_weights(samples)
        corners = weights[np.concatenate(stages[:2])]
        assert np.allclose(corners.max(axis=1), weights.max())  # nearest to a corner
        assert sorted(corners.argmax(axis=1).tolist()) == [0, 1, 2]


@pytest.mark.parametrize(("key", "value"), [("coverage_model", "corners"),
                                            ("samples_per_face", 10),
                                            ("samples_per_face", 1.5),
                                            ("min_sampled_fraction", 0.0)])
def test_bad_sampled_parameters_name_the_parameter(key: str, value: object) -> None:
    with pytest.raises(ParameterError) as caught:
        PlanSpec.from_mapping({key: value})
    assert caught.value.parameter == key
