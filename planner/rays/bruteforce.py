"""The reference occlusion test: every ray against every face, closest hit must be the target.

Slow (P x F work) and exact in float64; kept to check the Embree backend pair for pair.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from planner.scene import Scene

if TYPE_CHECKING:
    from planner.rays.protocols import ExactRays

_CHUNK_WORK = 1_000_000  # ray-triangle tests per numpy step (~200 MB of temporaries)


class BruteForceOcclusion:
    """Moller-Trumbore in numpy over the occluding faces plus each ray's own target."""

    exact = True  # float64 throughout: it is the reference

    def __init__(self, scene: Scene, occludes: NDArray[np.bool_]) -> None:
        self._triangles = scene.triangles
        self._occluders = np.flatnonzero(occludes)

    def visible(
        self,
        origins: NDArray[np.floating[Any]],
        directions: NDArray[np.floating[Any]],
        distances_m: NDArray[np.floating[Any]],
        target_faces: NDArray[np.integer[Any]],
        exact_rays: ExactRays | None = None,
    ) -> NDArray[np.bool_]:
        # float64 throughout: this is the reference
        if exact_rays is not None:
            origins64, directions64 = exact_rays(np.arange(len(origins), dtype=np.int64))
        else:
            origins64 = np.asarray(origins, np.float64)
            directions64 = np.asarray(directions, np.float64)
        targets64 = np.asarray(target_faces, np.int64)
        result = np.empty(len(origins), bool)
        step = max(1, _CHUNK_WORK // max(1, len(self._occluders)))
        for start in range(0, len(origins), step):
            part = slice(start, start + step)
            result[part] = self._closest_is_target(
                origins64[part], directions64[part], targets64[part]
            )
        return result

    def _closest_is_target(
        self, origins: NDArray[np.float64], directions: NDArray[np.float64],
        targets: NDArray[np.int64],
    ) -> NDArray[np.bool_]:
        tri = self._triangles[self._occluders]  # (O, 3, 3)
        # (R, O) hit distances of every ray with every occluder
        t_occ = ray_triangle_distance(origins[:, None, :], directions[:, None, :], tri[None])
        own = ray_triangle_distance(origins, directions, self._triangles[targets])  # (R,)
        own_t = np.where(np.isfinite(own), own, np.inf)
        is_self = self._occluders[None, :] == targets[:, None]
        t_occ = np.where(is_self, np.inf, t_occ)
        # the target is the closest hit: nothing else strictly in front of it
        return np.isfinite(own_t) & ~(t_occ < own_t[:, None]).any(axis=1)


def ray_triangle_distance(
    origin: NDArray[np.float64], direction: NDArray[np.float64], tri: NDArray[np.float64],
    edge_tolerance: float = 1e-12,
) -> NDArray[np.float64]:
    """Ray parameter of the hit with each triangle (two-sided), inf for a miss.

    ``edge_tolerance`` widens (positive) or narrows (negative) every triangle in barycentric
    terms, to tell a ray that grazes an edge from one that clearly hits or misses.
    """
    v0, v1, v2 = tri[..., 0, :], tri[..., 1, :], tri[..., 2, :]
    e1, e2 = v1 - v0, v2 - v0
    p = np.cross(direction, e2)
    det = np.einsum("...k,...k->...", e1, p)
    ok = np.abs(det) > 1e-14
    inv = np.divide(1.0, det, out=np.zeros_like(det), where=ok)
    s = origin - v0
    u = np.einsum("...k,...k->...", s, p) * inv
    q = np.cross(s, e1)
    v = np.einsum("...k,...k->...", direction, q) * inv
    t = np.einsum("...k,...k->...", e2, q) * inv
    eps = edge_tolerance
    hit = ok & (u >= -eps) & (v >= -eps) & (u + v <= 1 + eps) & (t > 1e-9)
    return np.where(hit, t, np.inf)
