"""Embree's kernels decide grazing rays: the device is pinned to one instruction set, so
every machine that has it casts every ray the same way."""

from __future__ import annotations

import ctypes
import platform
from pathlib import Path

import numpy as np
import pytest

from planner.candidates.grid import read_candidates_csv
from planner.io.readers import read_scene
from planner.limits import FaceLimits
from planner.parameters import PlanSpec
from planner.rays import FAR_LIMIT_FACTOR
from planner.rays import pinned as pinned_module
from planner.rays.pinned import KERNELS, PinnedScene
from planner.visibility.pairs import PairFinder

X86 = platform.machine().lower() in ("x86_64", "amd64")


def test_an_x86_machine_is_pinned_to_a_named_set() -> None:
    if X86:
        assert KERNELS in ("avx2", "sse4.2", "sse2")
    else:
        assert "default kernels" in KERNELS


def _hall_small_rays(scenes_dir: Path) -> tuple[np.ndarray, ...]:
    """hall-small's occluding mesh and its coverage rays, as Embree takes them: (V, 3)
    vertices and (B, 3) faces, the rays' (R, 3) origins and directions and (R,) far
    limits (float32). The candidates are a grid and the faces one, so many rays run through
    the corners the faces share."""
    scene = read_scene(scenes_dir / "hall-small/hall.obj", max_edge_m=None)
    limits = FaceLimits.from_spec(PlanSpec(max_edge_m=None), scene)
    positions = read_candidates_csv(scenes_dir / "hall-small/candidates.csv")
    pairs, _ = PairFinder(scene, limits).find(positions, 0)
    far = np.multiply(pairs.distance_m, FAR_LIMIT_FACTOR, dtype=np.float32)
    return (scene.vertices.astype(np.float32), scene.faces[limits.occludes].astype(np.int32),
            pairs.origin.astype(np.float32), pairs.direction.astype(np.float32), far)


def test_the_instruction_set_decides_grazing_rays(scenes_dir: Path) -> None:
    """hall-small's coverage rays (a grid of candidates, rays through the corners of a
    grid of faces): kernels of another set than the pinned one decide some of them
    otherwise, the pinned device and an explicit cap at its own set decide all alike."""
    if not X86 or KERNELS != "avx2":
        pytest.fail(f"this test compares x86 kernels on an AVX2 CPU; this one runs {KERNELS}")
    vertices32, faces32, origins32, directions32, far = _hall_small_rays(scenes_dir)

    def hits(max_isa: str | None) -> np.ndarray:
        caster = PinnedScene(vertices32, faces32, robust=True, max_isa=max_isa)
        return caster.first_hits(origins32, directions32, far)

    pinned = hits(None)
    np.testing.assert_array_equal(pinned, hits("avx2"))
    np.testing.assert_array_equal(pinned, hits(None))  # and twice alike
    older = hits("sse4.2")
    differ = int((older != pinned).sum())
    assert 0 < differ < len(pinned) * 1e-4


def _one_ray_at_a_time(caster: PinnedScene, origins32: np.ndarray, directions32: np.ndarray,
                       far32: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each ray cast alone with Embree's ``rtcIntersect1``: (R,) first triangle (-1: none)
    and (R,) tfar, the reference for the packets :meth:`PinnedScene.first_hits` casts."""
    intersect1 = pinned_module._LIB.rtcIntersect1
    intersect1.argtypes = [ctypes.c_void_p] * 3
    intersect1.restype = None
    buffer = np.zeros(24 + 4, np.float32)  # one RTCRayHit (96 bytes), aligned to 16
    start = ((16 - buffer.ctypes.data % 16) % 16) // 4
    ray = buffer[start:start + 24]
    words = ray.view(np.uint32)
    prim = np.empty(len(origins32), np.int64)
    tfar = np.empty(len(origins32), np.float32)
    for r in range(len(origins32)):
        ray[:] = 0.0
        ray[0:3], ray[4:7], ray[8] = origins32[r], directions32[r], far32[r]
        words[9] = 0xFFFFFFFF  # mask: every geometry
        words[17:21] = 0xFFFFFFFF  # primID, geomID, instID, instPrimID: none yet
        intersect1(caster._scene, ray.ctypes.data, None)
        prim[r] = -1 if words[18] == 0xFFFFFFFF else int(words[17])
        tfar[r] = ray[8]
    return prim, tfar


def test_packets_hit_what_single_rays_hit(scenes_dir: Path) -> None:
    """The rays are cast eight to a packet (``rtcIntersect8``); each must end where it
    ends cast alone: the same first triangle and the same distance, grazing rays included.
    hall-small's coverage rays run through the corners of a grid of faces: the rays that
    kernels of another instruction set decide otherwise (the ties between the triangles
    that share a corner) and a sample of the rest, each compared with ``rtcIntersect1``."""
    vertices32, faces32, origins32, directions32, far = _hall_small_rays(scenes_dir)
    caster = PinnedScene(vertices32, faces32, robust=True)
    packets, packet_tfar = caster.first_hits_and_distances(origins32, directions32)
    grazing = np.flatnonzero(packets != PinnedScene(
        vertices32, faces32, robust=True, max_isa="sse4.2").first_hits(
            origins32, directions32))
    sample = np.random.default_rng(7).choice(len(packets), 20_000, replace=False)
    rays = np.union1d(grazing, sample)
    if len(rays) % 8 == 0:
        rays = rays[:-1]  # the last packet holds fewer than eight rays
    single, single_tfar = _one_ray_at_a_time(caster, origins32[rays], directions32[rays],
                                             np.full(len(rays), np.inf, np.float32))
    assert len(grazing) > 0 and (single >= 0).all()
    np.testing.assert_array_equal(packets[rays], single)
    np.testing.assert_array_equal(packet_tfar[rays], single_tfar)
    # with a far limit, and the rays in another grouping into packets
    shifted = rays[1:]
    hits = caster.first_hits(origins32[shifted], directions32[shifted], far[shifted])
    alone, _ = _one_ray_at_a_time(caster, origins32[shifted], directions32[shifted],
                                  far[shifted])
    np.testing.assert_array_equal(hits, alone)
