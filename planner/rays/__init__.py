"""Ray casting over the scene: the occlusion test and first hits, one protocol, two backends.

Takes a :class:`~planner.scene.Scene` and the (F,) faces that occlude; gives an
:class:`Occlusion` (is the segment from a candidate to a face centroid free of other faces?)
and a :class:`RayCaster` (the first face a ray hits: floors, head room, the walk graph).

One "reverse" ray per pair that passed the analytic limits, never a fixed angular pattern,
so no face is missed by chance. Faces are two-sided. Backends share one protocol
(:mod:`planner.rays.protocols`): ``embree`` (the fast one, :mod:`planner.rays.embree`) and
``bruteforce`` (the reference, :mod:`planner.rays.bruteforce`: every occluder tested,
closest hit must be the target).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from planner.rays.protocols import (
    FAR_LIMIT_FACTOR,
    Backend,
    ExactRays,
    Occlusion,
    RayCaster,
)
from planner.scene import Scene

__all__ = ["FAR_LIMIT_FACTOR", "Backend", "ExactRays", "Occlusion", "RayCaster",
           "make_occlusion", "make_ray_caster"]


def make_ray_caster(scene: Scene, occludes: NDArray[np.bool_], *,
                    file_faces: bool = False) -> RayCaster:
    """An Embree first-hit caster over the faces where ``occludes`` (F,) is true.

    ``file_faces``: cast against the model's faces before remeshing (``scene.file_mesh``).
    """
    from planner.rays.embree import EmbreeOcclusion

    return EmbreeOcclusion(scene, occludes, file_faces=file_faces)


def make_occlusion(scene: Scene, occludes: NDArray[np.bool_], backend: Backend, *,
                   file_faces: bool = False, like: Occlusion | None = None,
                   exact: bool = False) -> Occlusion:
    """The occlusion test over the faces where ``occludes`` (F,) is true.

    ``file_faces`` (Embree only): the rays are tested against the model's faces before
    remeshing, and a hit on the target's ``source_face`` counts as reaching the target.
    The brute-force reference always tests the scene's own (remeshed) faces. ``like``: an
    occlusion whose BVH is shared when it holds the same faces of the same mesh (the
    verdicts are then the same as a new one's, without building it again). ``exact``
    (Embree only; the reference always is): every ray decided in float64 as the reference
    decides it, not by one float32 cast.
    """
    if backend == "embree":
        from planner.rays.embree import EmbreeOcclusion

        bvh = like.reused_bvh(scene, occludes, file_faces=file_faces) \
            if isinstance(like, EmbreeOcclusion) else None
        return EmbreeOcclusion(scene, occludes, file_faces=file_faces, bvh=bvh, exact=exact)
    if backend == "bruteforce":
        from planner.rays.bruteforce import BruteForceOcclusion

        return BruteForceOcclusion(scene, occludes)
    raise ValueError(f"unknown visibility backend {backend!r}; use 'embree' or 'bruteforce'")
