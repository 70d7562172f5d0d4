"""Embree's kernels decide grazing rays: the device is pinned to one instruction set, so
every machine that has it casts every ray the same way."""

from __future__ import annotations

import platform
from pathlib import Path

import numpy as np
import pytest

from planner.candidates.grid import read_candidates_csv
from planner.io.readers import read_scene
from planner.limits import FaceLimits
from planner.parameters import PlanSpec
from planner.rays import FAR_LIMIT_FACTOR
from planner.rays.pinned import KERNELS, PinnedScene
from planner.visibility.pairs import PairFinder

X86 = platform.machine().lower() in ("x86_64", "amd64")


def test_an_x86_machine_is_pinned_to_a_named_set() -> None:
    if X86:
        assert KERNELS in ("avx2", "sse4.2", "sse2")
    else:
        assert "default kernels" in KERNELS


def test_the_instruction_set_decides_grazing_rays(scenes_dir: Path) -> None:
    """hall-small's coverage rays (a grid of candidates, rays through the corners of a
    grid of faces): kernels of another set than the pinned one decide some of them
    otherwise, the pinned device and an explicit cap at its own set decide all alike."""
    if not X86 or KERNELS != "avx2":
        pytest.fail(f"this test compares x86 kernels on an AVX2 CPU; this one runs {KERNELS}")
    scene = read_scene(scenes_dir / "hall-small/hall.obj", max_edge_m=None)
    limits = FaceLimits.from_spec(PlanSpec(max_edge_m=None), scene)
    positions = read_candidates_csv(scenes_dir / "hall-small/candidates.csv")
    pairs, _ = PairFinder(scene, limits).find(positions, 0)
    vertices32 = scene.vertices.astype(np.float32)
    faces32 = scene.faces[limits.occludes].astype(np.int32)
    far = np.multiply(pairs.distance_m, FAR_LIMIT_FACTOR, dtype=np.float32)
    origins32, directions32 = pairs.origin.astype(np.float32), pairs.direction.astype(np.float32)

    def hits(max_isa: str | None) -> np.ndarray:
        caster = PinnedScene(vertices32, faces32, robust=True, max_isa=max_isa)
        return caster.first_hits(origins32, directions32, far)

    pinned = hits(None)
    np.testing.assert_array_equal(pinned, hits("avx2"))
    np.testing.assert_array_equal(pinned, hits(None))  # and twice alike
    older = hits("sse4.2")
    differ = int((older != pinned).sum())
    assert 0 < differ < len(pinned) * 1e-4
