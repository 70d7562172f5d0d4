"""Embree occlusion queries (the only module that imports embreex).

A missing embreex is a loud error: there is no silent slow path.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from planner.errors import PlannerError
from planner.method.visibility import FAR_LIMIT_FACTOR
from planner.scene import Scene

try:
    from embreex import rtcore_scene
    from embreex.mesh_construction import TriangleMesh
except ImportError as exc:  # pragma: no cover - depends on the installation
    raise PlannerError(
        "embreex is not installed; install the project with its dependencies "
        "(pip install -e .) to get the Embree ray caster"
    ) from exc


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
        self._scene = rtcore_scene.EmbreeScene()
        self._faces = np.flatnonzero(file_occludes)
        self._empty = len(self._faces) == 0
        if not self._empty:
            # indexed (shared vertices): a third faster to build than a triangle soup
            self._mesh = TriangleMesh(self._scene, bvh_vertices.astype(np.float32),
                                      bvh_faces[self._faces].astype(np.int32))
        self._occludes = occludes
        self._all_occlude = bool(file_occludes.all())

    def visible(
        self,
        origins: NDArray[np.floating[Any]],
        directions: NDArray[np.floating[Any]],
        distances_m: NDArray[np.floating[Any]],
        target_faces: NDArray[np.integer[Any]],
    ) -> NDArray[np.bool_]:
        """Closest-hit semantics, as the brute-force reference: the target must be hit first.

        The ray stops just past the target (so Embree prunes everything behind it). A face
        that coincides with the target (a duplicated surface) may be hit first and then
        hides it, exactly as in the reference. A target that does not occlude (glass
        asked to be covered) is not in the BVH: it is visible when nothing is hit before it.
        """
        if self._empty or len(origins) == 0:
            return np.ones(len(origins), bool)
        prim = np.asarray(self._scene.run(
            np.ascontiguousarray(origins, np.float32),
            np.ascontiguousarray(directions, np.float32),
            dists=np.multiply(distances_m, FAR_LIMIT_FACTOR, dtype=np.float32),
            query="INTERSECT",
        ))
        target_in_bvh = (target_faces if self._source_face is None
                         else self._source_face[target_faces])
        if self._all_occlude:  # the BVH's primitive ids are the file's face ids
            visible: NDArray[np.bool_] = prim == target_in_bvh
            return visible
        hit = np.where(prim >= 0, self._faces[np.maximum(prim, 0)], -1)
        visible = (hit == target_in_bvh) | ((hit < 0) & ~self._occludes[target_faces])
        return visible

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
