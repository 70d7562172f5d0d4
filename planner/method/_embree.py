"""Embree occlusion queries (the only module that imports embreex).

A missing embreex is a loud error: there is no silent slow path.
"""

from __future__ import annotations

import threading
from typing import Any

import numpy as np
from numpy.typing import NDArray

from planner.errors import PlannerError
from planner.method._bruteforce import ray_triangle_distance
from planner.method.visibility import FAR_LIMIT_FACTOR, ExactRays
from planner.scene import Scene

try:
    from embreex import rtcore_scene
    from embreex.mesh_construction import TriangleMesh
except ImportError as exc:  # pragma: no cover - depends on the installation
    raise PlannerError(
        "embreex is not installed; install the project with its dependencies "
        "(pip install -e .) to get the Embree ray caster"
    ) from exc


# probe rays for a ray float32 cannot decide run this far beside it, on four sides: 20x the
# float32 rounding of a point 5 m away, far below the size of any face that matters
_PROBE_OFFSET_M = 1e-5
# doubtful rays decided together: bounds the chunk's (ray, occluder) pairs (some 100 a ray)
_EXACT_RAYS_PER_CHUNK = 1024


def _ragged_ranges(starts: NDArray[np.int64], counts: NDArray[np.int64]) -> NDArray[np.int64]:
    """The ranges [starts[i], starts[i] + counts[i]) one after another, as one array."""
    ends = np.cumsum(counts)
    return np.repeat(starts - ends + counts, counts) + np.arange(int(ends[-1]) if len(ends)
                                                                 else 0)


class EmbreeOcclusion:
    """Occlusion test against the occluding faces of a scene, one Embree BVH.

    By default the BVH holds the scene's faces. With ``file_faces`` it holds the model's
    own faces (``scene.file_mesh``, before remeshing) instead of the remeshed pieces: a ray
    reaches its target piece when the first face it hits is the piece's ``source_face``. A
    file face is planar, so a ray meets it at one point, the piece's centroid it was aimed
    at; the float32 far limit (``FAR_LIMIT_FACTOR`` past the centroid's distance) holds as
    for the piece itself, because the centroid lies on the file face's plane. A face that
    coincides with the target (a duplicated surface) may win the tie against the file face
    where it lost against the piece, or the other way round: Embree's order among equal
    distances depends on the BVH. ``occludes`` is a property of the file's face (groups,
    classes and elements travel with ``source_face``): a file face occludes when its
    pieces do.

    float32 cannot decide every ray: one that grazes an edge or a corner of an occluder
    (common in models built on a grid, where a ray from a grid point to a centroid often
    passes exactly through a vertex) is decided by rounding, and Embree's rounding depends
    on the instruction set the CPU offers (AVX2 and AVX-512 disagree on a few rays). So
    ``visible`` casts every ray twice, in Embree's robust (watertight) mode and in its
    fast mode, and decides the rays where the two disagree in float64 as the brute-force
    reference does, against the faces either cast hit and every face sharing a vertex with
    them. Measured: 150 of hall-small's 3.0 M rays and 2,296 of hall-full's 17.6 M disagree;
    the robust cast alone was wrong on 21 and 35 of them, enough to change the stations
    the coverage curve needs at 100 % on hall-small (37 instead of the reference's 36) on
    an AVX2 machine. The second cast costs a second BVH and ray time: hall-full's
    visibility stage went from 2.15 s to 3.93 s on 2 cores (benchmarks/plan_hall.py).

    ``visible`` releases the GIL inside Embree, so threads calling it run in parallel.
    """

    def __init__(self, scene: Scene, occludes: NDArray[np.bool_], *,
                 file_faces: bool = False) -> None:
        remeshed = file_faces and scene.file_faces is not None
        bvh_vertices, bvh_faces = scene.file_mesh if remeshed else (scene.vertices, scene.faces)
        # (F,) the BVH face each scene face is part of (the identity on an unremeshed scene)
        self._source_face = scene.source_face if remeshed else None
        if remeshed:
            file_occludes = np.zeros(len(bvh_faces), bool)
            file_occludes[scene.source_face[occludes]] = True
            # (F0,) a scene face of every file face (its first piece), for first_hit
            self._first_piece = np.full(len(bvh_faces), -1, np.int64)
            pieces_of, first = np.unique(scene.source_face, return_index=True)
            self._first_piece[pieces_of] = first
        else:
            file_occludes = occludes
        self._scene = rtcore_scene.EmbreeScene(robust=True)
        # the same faces in Embree's fast mode: where the two casts disagree, float64 decides
        self._check_scene = rtcore_scene.EmbreeScene(robust=False)
        self._faces = np.flatnonzero(file_occludes)
        self._empty = len(self._faces) == 0
        if not self._empty:
            # indexed (shared vertices): a third faster to build than a triangle soup
            vertices32 = bvh_vertices.astype(np.float32)
            faces32 = bvh_faces[self._faces].astype(np.int32)
            self._mesh = TriangleMesh(self._scene, vertices32, faces32)
            self._check_mesh = TriangleMesh(self._check_scene, vertices32, faces32)
        self._occludes = occludes
        self._all_occlude = bool(file_occludes.all())
        self._scene_faces = (scene.vertices, scene.faces)
        self._bvh_mesh = (bvh_vertices, bvh_faces)
        # (V0 + 1,) and (3 f,): the occluders (indices into self._faces) at each BVH vertex,
        # built the first time a ray needs deciding in float64
        self._vertex_occluders: tuple[NDArray[np.int64], NDArray[np.int64]] | None = None
        self._lock = threading.Lock()

    def visible(
        self,
        origins: NDArray[np.floating[Any]],
        directions: NDArray[np.floating[Any]],
        distances_m: NDArray[np.floating[Any]],
        target_faces: NDArray[np.integer[Any]],
        exact_rays: ExactRays | None = None,
    ) -> NDArray[np.bool_]:
        """Closest-hit semantics, as the brute-force reference: the target must be hit first.

        The ray stops just past the target (so Embree prunes everything behind it). A face
        that coincides with the target (a duplicated surface) may be hit first and then
        hides it, exactly as in the reference. A target that does not occlude (glass
        asked to be covered) is not in the BVH: it is visible when nothing is hit before it.
        """
        if self._empty or len(origins) == 0:
            return np.ones(len(origins), bool)
        origins32 = np.ascontiguousarray(origins, np.float32)
        directions32 = np.ascontiguousarray(directions, np.float32)
        far = np.multiply(distances_m, FAR_LIMIT_FACTOR, dtype=np.float32)
        prim = np.asarray(self._scene.run(origins32, directions32, dists=far,
                                          query="INTERSECT"), np.int64)
        check = np.asarray(self._check_scene.run(origins32, directions32, dists=far,
                                                 query="INTERSECT"), np.int64)
        targets: NDArray[np.int64] = np.asarray(target_faces, np.int64)
        visible = self._reaches(prim, targets)
        doubtful = np.flatnonzero(visible != self._reaches(check, targets))
        if len(doubtful):
            if exact_rays is not None:
                origins64, directions64 = exact_rays(doubtful)
            else:
                origins64 = np.asarray(origins, np.float64)[doubtful]
                directions64 = np.asarray(directions, np.float64)[doubtful]
                directions64 /= np.linalg.norm(directions64, axis=1)[:, None]
            visible[doubtful] = self._decide_exactly(
                origins64, directions64, targets[doubtful], prim[doubtful],
                check[doubtful])
        return visible

    def _bvh_face(self, faces: NDArray[np.int64]) -> NDArray[np.int64]:
        """The BVH face (file face, or the face itself) of scene faces."""
        return faces if self._source_face is None else self._source_face[faces].astype(np.int64)

    def _reaches(self, prim: NDArray[np.int64], target_faces: NDArray[np.int64]
                 ) -> NDArray[np.bool_]:
        """Closest-hit verdict of one cast: (P,) Embree primitive ids -> (P,) bool."""
        target_in_bvh = self._bvh_face(target_faces)
        if self._all_occlude:  # the BVH's primitive ids are the file's face ids
            reached: NDArray[np.bool_] = prim == target_in_bvh
            return reached
        hit = np.where(prim >= 0, self._faces[np.maximum(prim, 0)], -1)
        reached = (hit == target_in_bvh) | ((hit < 0) & ~self._occludes[target_faces])
        return reached

    def _vertex_table(self) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """(V0 + 1,) starts and (3 f,) occluders (indices into self._faces) at each BVH
        vertex: the occluders at vertex v are ``occluder[starts[v]:starts[v + 1]]``."""
        with self._lock:
            if self._vertex_occluders is None:
                corner_vertex = self._bvh_mesh[1][self._faces].ravel()
                order = np.argsort(corner_vertex, kind="stable")
                starts = np.searchsorted(corner_vertex[order],
                                         np.arange(len(self._bvh_mesh[0]) + 1))
                self._vertex_occluders = (starts, order // 3)
            return self._vertex_occluders

    def _probe_hits(self, origins: NDArray[np.float64], directions: NDArray[np.float64]
                    ) -> NDArray[np.int64]:
        """(K, 8) primitive ids hit by rays parallel to K rays, ``_PROBE_OFFSET_M`` to
        each of four sides, in both modes (-1: a miss)."""
        helper = np.where(np.abs(directions[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
        side_a = np.cross(directions, helper)
        side_a /= np.linalg.norm(side_a, axis=1)[:, None]
        side_b = np.cross(directions, side_a)
        offsets = np.stack([side_a, -side_a, side_b, -side_b], axis=1) * _PROBE_OFFSET_M
        probe_origins = (origins[:, None, :] + offsets).reshape(-1, 3).astype(np.float32)
        probe_directions = np.repeat(directions, 4, axis=0).astype(np.float32)
        hits = [np.asarray(scene.run(probe_origins, probe_directions, query="INTERSECT"),
                           np.int64).reshape(-1, 4)
                for scene in (self._scene, self._check_scene)]
        return np.concatenate(hits, axis=1)

    def _decide_exactly(
        self, origins: NDArray[np.float64], directions: NDArray[np.float64],
        target_faces: NDArray[np.int64], prim: NDArray[np.int64], check: NDArray[np.int64],
    ) -> NDArray[np.bool_]:
        """Float64 closest-hit verdicts of K rays the two casts disagree on.

        Tested: the target (its own piece) and, as occluders, the faces either cast hit,
        the faces that rays offset by ``_PROBE_OFFSET_M`` to four sides hit (a face the
        exact ray grazes but neither cast hit), and every occluder sharing a vertex with
        any of them (the neighbour across a grazed edge). All rays' (ray, occluder) pairs
        are tested together, ``_EXACT_RAYS_PER_CHUNK`` rays at a time.
        """
        verdict = np.empty(len(target_faces), bool)
        for start in range(0, len(target_faces), _EXACT_RAYS_PER_CHUNK):
            chunk = slice(start, start + _EXACT_RAYS_PER_CHUNK)
            verdict[chunk] = self._decide_chunk(origins[chunk], directions[chunk],
                                                target_faces[chunk], prim[chunk], check[chunk])
        return verdict

    def _decide_chunk(
        self, origins: NDArray[np.float64], directions: NDArray[np.float64],
        target_faces: NDArray[np.int64], prim: NDArray[np.int64], check: NDArray[np.int64],
    ) -> NDArray[np.bool_]:
        """:meth:`_decide_exactly` of k rays."""
        vertices, faces = self._scene_faces
        bvh_vertices, bvh_faces = self._bvh_mesh
        # (k,) the target's own distance; a ray that misses its target does not reach it
        own = ray_triangle_distance(origins, directions, vertices[faces[target_faces]])
        # (h,) the primitives the casts and the probes hit, with their ray
        hits = np.column_stack([prim, check, self._probe_hits(origins, directions)])  # (k, 10)
        hit_ray = np.repeat(np.arange(len(hits)), hits.shape[1])
        hit = hits.ravel()
        hit_ray, hit = hit_ray[hit >= 0], hit[hit >= 0]
        # every occluder at a corner of a hit face (the neighbours across its edges)
        starts, occluder = self._vertex_table()
        corner = bvh_faces[self._faces[hit]].ravel()  # (3 h,) BVH vertices
        corner_ray = np.repeat(hit_ray, 3)
        counts = starts[corner + 1] - starts[corner]
        neighbour_ray = np.repeat(corner_ray, counts)
        neighbour = occluder[_ragged_ranges(starts[corner], counts)]
        # (pairs,) distinct (ray, occluder) pairs, the target's own BVH face left out
        pair_ray = np.concatenate([hit_ray, neighbour_ray])
        pair_face = self._faces[np.concatenate([hit, neighbour])]  # BVH faces
        key = np.unique(pair_ray * np.int64(len(bvh_faces)) + pair_face)
        pair_ray, pair_face = key // len(bvh_faces), key % len(bvh_faces)
        other = pair_face != self._bvh_face(target_faces)[pair_ray]
        pair_ray, pair_face = pair_ray[other], pair_face[other]
        t = ray_triangle_distance(origins[pair_ray], directions[pair_ray],
                                  bvh_vertices[bvh_faces[pair_face]])
        blocked = np.bincount(pair_ray[t < own[pair_ray]], minlength=len(own)) > 0
        reached: NDArray[np.bool_] = np.isfinite(own) & ~blocked
        return reached

    def first_face(
        self, origins: NDArray[np.floating[Any]], directions: NDArray[np.floating[Any]]
    ) -> NDArray[np.int64]:
        """The closest face each (R, 3) ray hits, -1 for a miss; no distances (faster).

        The simulated scan (:mod:`planner.truth.simulation`) casts millions of rays and computes
        the distance from the face's plane itself, which is cheaper than Embree's output
        dictionary.
        """
        if self._empty or len(origins) == 0:
            return np.full(len(origins), -1, np.int64)
        prim = np.asarray(self._scene.run(
            np.ascontiguousarray(origins, np.float32),
            np.ascontiguousarray(directions, np.float32),
            query="INTERSECT",
        ), np.int64)
        face: NDArray[np.int64] = np.where(prim >= 0, self._faces[np.maximum(prim, 0)], -1)
        return face

    def first_hit(
        self, origins: NDArray[np.floating[Any]], directions: NDArray[np.floating[Any]]
    ) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        """The closest face each (R, 3) ray hits and its distance; -1 and inf for a miss.

        On a remeshed scene the face is the first piece of the file face that was hit (same
        plane, group and element as the piece under the hit point).
        """
        if self._empty or len(origins) == 0:
            return np.full(len(origins), -1, np.int64), np.full(len(origins), np.inf)
        info = self._scene.run(
            np.ascontiguousarray(origins, np.float32),
            np.ascontiguousarray(directions, np.float32),
            output=True,
        )
        prim = np.asarray(info["primID"], np.int64)
        hit = prim >= 0
        face = np.where(hit, self._faces[np.where(hit, prim, 0)], -1)
        if self._source_face is not None:
            face = np.where(hit, self._first_piece[np.maximum(face, 0)], -1)
        distance = np.where(hit, np.asarray(info["tfar"], np.float64), np.inf)
        return face, distance
