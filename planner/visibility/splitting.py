"""Which faces are split: the long faces some candidate can qualify part of.

``max_edge_m`` splits faces so that a face's centroid stands for the whole face. A face that
no candidate can qualify anywhere gains nothing from it: every piece would fail the limits
and stay uncovered. Such a face is kept whole, which saves its pieces in every later stage
(visibility, the table, the survey, the outputs) without changing a single pair.

The test, for a long target face f and a candidate c, with h the distance from c to f's plane
(faces are two-sided) and d the distance from c to a point p of f: the pair (c, p) can pass
only if

- ``d <= dof_max_m``,
- ``sin(incidence) = h / d >= sin(min_incidence_deg)``: ``d <= h / sin(min_incidence_deg)``,
- ``LPD = (h / d) / (angular_step_rad * d)**2 >= min_density``:
  ``d <= cbrt(h / (angular_step_rad**2 * min_density))``,

where min_density is the lower of the face's density and the overlap density (the survey's
registration qualifies faces at that one). The smallest d over the face is the distance from c
to the triangle, so when it exceeds that reach for every candidate no piece of f can qualify:
f is kept whole. The blind cone and ``dof_min_m`` are left out (the test stays on the safe
side: it may split a face that did not need it, never the other way round). Candidates are
found with a k-d tree within the face's bounding sphere plus the density range.
"""

from __future__ import annotations

import numpy as np
import trimesh
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from planner.density import density_range_m
from planner.limits import FaceLimits
from planner.scene import Scene, longest_edges_m

# long faces per k-d tree query, and face-candidate pairs per chunk of the test (bounds the
# chunk's (p, 3, 3) triangles to about 40 MB)
_FACES_PER_BLOCK = 256
_PAIRS_PER_CHUNK = 1 << 19
# candidates nearest each face's centre, tested before all candidates in reach
_NEAREST_FIRST = 8
# relative and absolute slack on the reach: rounding never keeps a face whole that a
# candidate qualifies part of
_SLACK = 1e-6


def faces_to_split(scene: Scene, positions_xyz: NDArray[np.float64], limits: FaceLimits,
                   max_edge_m: float, overlap_density_pts_m2: float) -> NDArray[np.bool_]:
    """(F,) bool: the faces of ``scene`` longer than ``max_edge_m`` that some of the (C, 3)
    candidates can qualify part of (see the module docstring)."""
    long = longest_edges_m(scene.vertices, scene.faces) > max_edge_m  # (F,) as remesh sees it
    split = np.zeros(scene.n_faces, bool)
    faces = np.flatnonzero(long & limits.target)  # (f,) the faces the test is for
    if len(faces) == 0 or len(positions_xyz) == 0:
        return split
    triangles = scene.vertices[scene.faces[faces]]  # (f, 3, 3)
    density = np.minimum(limits.min_density_pts_m2[faces], overlap_density_pts_m2)  # (f,)
    reach = np.minimum(limits.dof_max_m, [density_range_m(float(x), limits.angular_step_rad)
                                          for x in density])  # (f,) head-on, no incidence
    min_sin = np.sin(np.radians(limits.min_incidence_deg[faces]))  # (f,)
    centre = scene.centroids_of(faces)
    radius = np.linalg.norm(triangles - centre[:, None, :], axis=2).max(axis=1)  # (f,)
    tree = cKDTree(positions_xyz)
    step2 = limits.angular_step_rad ** 2
    found = np.zeros(len(faces), bool)  # (f,) some candidate qualifies part of the face

    def qualifies(face: NDArray[np.intp], candidate: NDArray[np.intp]) -> NDArray[np.bool_]:
        """(p,) the test of the module docstring for (p,) faces (into ``faces``) and
        candidates; the bounding sphere decides most pairs, the exact distance the rest."""
        c = positions_xyz[candidate]  # (p, 3)
        h = np.abs(np.einsum("pk,pk->p", c - triangles[face, 0], scene.normals_of(faces[face])))
        allowed = np.minimum(reach[face], _reach_at(h, min_sin[face], density[face], step2))
        allowed = allowed * (1 + _SLACK) + _SLACK
        gap = np.linalg.norm(c - centre[face], axis=1)
        ok: NDArray[np.bool_] = gap + radius[face] <= allowed  # all of the face is in reach
        unsure = np.flatnonzero(~ok & (gap - radius[face] <= allowed))
        if len(unsure):
            closest = np.asarray(trimesh.triangles.closest_point(  # type: ignore[no-untyped-call]
                triangles[face[unsure]], c[unsure]))
            ok[unsure] = np.linalg.norm(closest - c[unsure], axis=1) <= allowed[unsure]
        return ok

    def test(face: NDArray[np.intp], candidate: NDArray[np.intp]) -> None:
        for first in range(0, len(face), _PAIRS_PER_CHUNK):
            chunk = slice(first, first + _PAIRS_PER_CHUNK)
            found[face[chunk][qualifies(face[chunk], candidate[chunk])]] = True

    # first the candidates nearest each face's centre: in a building one of them mostly
    # qualifies the face, and the search of every candidate in reach is left for the rest
    k = min(_NEAREST_FIRST, len(positions_xyz))
    _, nearest = tree.query(centre, k=k)
    test(np.repeat(np.arange(len(faces)), k), np.asarray(nearest).reshape(-1))
    rest = np.flatnonzero(~found)
    for start in range(0, len(rest), _FACES_PER_BLOCK):
        block = rest[start:start + _FACES_PER_BLOCK]
        near = tree.query_ball_point(centre[block], reach[block] + radius[block] + _SLACK)
        counts = np.array([len(n) for n in near])
        if counts.sum():
            test(np.repeat(block, counts),
                 np.concatenate([np.asarray(n, np.intp) for n in near if n]))
    split[faces[found]] = True
    return split


def _reach_at(h_m: NDArray[np.float64], min_sin: NDArray[np.float64],
              min_density: NDArray[np.float64], step2: float) -> NDArray[np.float64]:
    """(p,) farthest distance at which a point of a plane ``h_m`` away can pass the incidence
    and the density limits (inf where a limit is 0)."""
    by_incidence = np.full(len(h_m), np.inf)
    np.divide(h_m, min_sin, out=by_incidence, where=min_sin > 0)
    by_density = np.full(len(h_m), np.inf)
    np.divide(h_m, step2 * min_density, out=by_density, where=min_density > 0)
    reach: NDArray[np.float64] = np.minimum(by_incidence, np.cbrt(by_density))
    return reach
