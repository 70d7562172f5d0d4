"""The tripod's clearance test looks only at faces near the tripods, and misses none."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import trimesh

from planner.candidates import grid as candidates
from planner.scene import build_scene, remesh
from tests.planner.buildings import STOREY_M, office_building


@pytest.mark.parametrize("n_points", [40, 3000])
def test_faces_far_from_every_tripod_change_no_clearance_verdict(
        monkeypatch: pytest.MonkeyPatch, n_points: int) -> None:
    """A few setups (the placement tolerance's) or a dense grid (candidates): leaving out
    the faces whose widened footprint box holds no tripod gives the verdicts of testing
    every face."""
    mesh = office_building(2, 2)
    scene = remesh(build_scene(np.asarray(mesh.vertices), np.asarray(mesh.faces)), 0.2)
    rng = np.random.default_rng(n_points)
    low, high = scene.vertices.min(axis=0), scene.vertices.max(axis=0)
    points = rng.uniform(low, high, size=(n_points, 3))
    floor_z = points[:, 2] - rng.uniform(0.5, 2.0, n_points)
    near = candidates.closer_than(scene, points, 0.3, floor_z)
    monkeypatch.setattr(candidates._NearPoints, "any_in",
                        lambda self, low_xy, high_xy: np.ones(len(low_xy), bool))
    every_face = candidates.closer_than(scene, points, 0.3, floor_z)
    assert 0 < near.sum() < n_points
    assert np.array_equal(near, every_face)


def test_faces_between_the_storeys_spans_change_no_clearance_verdict(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Tripods on two storeys: only faces reaching into some tripod's own span are split
    and searched (a floor and the slab under the next storey lie between the spans); the
    verdicts are those of the whole range from the lowest floor to the highest tripod. A
    shelf hangs in the top of each storey's spans (1.5 - 1.7 m over the floor, the tripods'
    spans reaching 1.8 m), another between them (2.2 - 2.4 m), with tripods around both."""
    office = office_building(2, 2)
    low, high = office.bounds
    shelf_xy = (low[:2] + high[:2]) / 2 + [1.0, 0.0]
    shelves = [trimesh.creation.box(extents=[0.6, 0.4, 0.2], transform=trimesh.transformations
                                    .translation_matrix([*shelf_xy, storey + z]))
               for storey in (0.0, STOREY_M) for z in (1.6, 2.3)]
    mesh = trimesh.util.concatenate([office, *shelves])
    scene = dataclasses.replace(
        build_scene(np.asarray(mesh.vertices), np.asarray(mesh.faces)), split_max_edge_m=0.2)
    rng = np.random.default_rng(7)
    xy = np.vstack([rng.uniform(low[:2], high[:2], size=(2000, 2)),
                    shelf_xy + rng.uniform(-1.0, 1.0, size=(400, 2))])
    floor_z = STOREY_M * rng.integers(0, 2, len(xy))
    points = np.column_stack([xy, floor_z + 1.5])
    spans = candidates._merged_spans(floor_z + 0.01, points[:, 2] + 0.3)
    assert len(spans[0]) == 2  # one span a storey
    near = candidates.closer_than(scene, points, 0.3, floor_z)
    monkeypatch.setattr(candidates, "_merged_spans", lambda lows, highs: (
        np.array([lows.min()]), np.array([highs.max()])))
    hull = candidates.closer_than(scene, points, 0.3, floor_z)
    assert 0 < near.sum() < len(points)
    assert np.array_equal(near, hull)
