"""Closed shells: a face seen from inside its shell is hidden, without a ray.

Most faces a candidate's pair search reaches face away from it: the far side of a wall, the
underside of the slab it stands on, the back of a column. A *closed shell* is a set of
occluding faces of one object (an IFC element; in a plain mesh, the faces joined by the
vertices the file writes for them, an object's own list), connected edge to edge, in which
every edge joins exactly two faces that run along it in opposite directions: a watertight,
consistently wound surface, which bounds a region R. Its signed volume tells whether its
normals point out of R or into it; ``side`` makes them point out.

**The rule.** Let c be a candidate outside R and p a point of a shell face f, with c behind
f's plane (on R's side of it, by more than the margin). The segment from c to p arrives at
p from R's side, so its last stretch lies inside R; it starts outside R, so it crosses the
shell at a point q before p. The ray to p meets an occluding face at q or earlier: the pair
(c, p) is hidden, and it is left out of the pair search, as a hidden bundle's pieces are.

**Why Embree agrees.** The BVH holds the shell's faces with the file's coordinates in
float32; the faces of a shell share their corners exactly (equal float32 coordinates), so
Embree's robust (watertight) cast cannot pass between two of them and hits the shell at q
or earlier. q lies before p by at least the distance from p to the shell's other faces
(points of the segment nearer p than that are inside R), and a piece is only ruled out when
that distance exceeds the clear-hit margin (:data:`planner.rays.embree.clear_margin_m`, 1,024
float32 steps at the model's largest coordinate), so float32 cannot order q after p. Where
the fast cast slips through an edge at q and reaches p, the two casts disagree and float64
decides, as for any ray: hidden. Nothing else changes, so the qualified pairs are the same
(``tests/planner/test_closed_shells.py`` compares them, and every output of the benchmark
models is byte-identical).

What is not ruled out, left to its ray: faces of shells that are not closed (an open mesh,
a T-junction, an edge of three faces, a face of zero area), shells of more than
:data:`MAX_SHELL_FACES` faces (the distance test is per face of the shell), faces no longer
than :data:`MIN_SHELL_EDGE_M` (shells are made of the longer faces only), pieces within the
margin of another face of their shell (along its edges, and in a shell thinner than the
margin), candidates inside or within the margin of any closed shell (all of their pairs),
and faces that do not occlude (glass; doors, for the overlap rows).

Array letters: F scene faces, B faces of the BVH's mesh, K closed shells, N points.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numba
import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.sparse.csgraph import connected_components

from planner.candidates.winding import coordinate_ranks, triangle_solid_angle
from planner.scene import Scene, face_centroid, longest_edges_m
from planner.threads import in_block_order

if TYPE_CHECKING:  # Embree is imported where a BVH is made
    from planner.rays.embree import BvhFaces

# a closed shell of more faces keeps its faces' rays: each of its pieces is tested against
# every other face of the shell (a wall with its openings: tens of faces)
MAX_SHELL_FACES = 512
# faces whose edges are all shorter are not taken into shells: a prop's millimetre facets
# (the cluttered interior: a million of them) save a ray each at most, and finding their
# shells cost 3.6 CPU s and 580 MB there
MIN_SHELL_EDGE_M = 0.1
# scene faces tested per task of the thread pool
_FACES_PER_TASK = 1 << 16


@runtime_checkable
class BvhMesh(Protocol):
    """The occlusion's side: the mesh its BVH holds (:class:`planner.rays.embree.
    EmbreeOcclusion`)."""

    def bvh_faces(self) -> BvhFaces:
        ...


@dataclass(frozen=True, eq=False)
class ClosedShells:
    """The closed shells of an occlusion's BVH and the scene faces they rule out from behind.

    Attributes
    ----------
    side : (F,) int8, per scene face: +1 its normal points out of its closed shell, -1 into
        it, 0 not ruled out from behind (see the module docstring)
    margin_m : the clear-hit margin of the occlusion's BVH
    lows, highs : (K, 3) float64, each shell's box widened by the margin
    starts : (K + 1,) int64, shell k's triangles are ``triangles[starts[k]:starts[k + 1]]``
    triangles : (T, 3, 3) float64, the shells' faces, wound as in the mesh
    """

    side: NDArray[np.int8]
    margin_m: float
    lows: NDArray[np.float64]
    highs: NDArray[np.float64]
    starts: NDArray[np.int64]
    triangles: NDArray[np.float64]

    def outside(self, points: NDArray[np.float64]) -> NDArray[np.bool_]:
        """(N,) bool: each of the (N, 3) points, rounded to float32 as the rays start, lies
        outside every closed shell by more than the margin (winding number under one half,
        distance over the margin); only such points may skip the faces behind them."""
        start = np.ascontiguousarray(np.asarray(points, np.float32), np.float64).reshape(-1, 3)
        ok = np.ones(len(start), bool)
        _outside_kernel(start, self.lows, self.highs, self.starts, self.triangles,
                        self.margin_m, ok)
        return ok


_BY_OCCLUSION: weakref.WeakKeyDictionary[Any, ClosedShells | None] = \
    weakref.WeakKeyDictionary()


def closed_shells(scene: Scene, occlusion: object) -> ClosedShells | None:
    """The closed shells of ``occlusion``'s BVH over ``scene`` (made once per occlusion);
    None when the occlusion holds no BVH (the brute-force reference casts every ray) or the
    scene has no face to rule out."""
    if not isinstance(occlusion, BvhMesh):
        return None
    try:
        return _BY_OCCLUSION[occlusion]
    except KeyError:
        pass
    shells = _closed_shells(scene, occlusion.bvh_faces())
    _BY_OCCLUSION[occlusion] = shells
    return shells


def _closed_shells(scene: Scene, bvh: BvhFaces) -> ClosedShells | None:
    from planner.rays.embree import clear_margin_m

    vertices, faces = bvh.vertices, bvh.faces
    occluding = bvh.occluding  # (b,) ascending
    # each BVH face's element (a file face's, or a piece's on a BVH of pieces)
    element = (scene.file_face_element if bvh.file_faces else scene.face_element)[occluding]
    members, starts, flips = _closed_members(vertices, faces[occluding], element)
    if len(flips) == 0:
        return None
    margin_m = clear_margin_m(bvh.scale_m)
    # per BVH face, the first closed shell it is on and its row there
    first_row = np.full(len(occluding), -1, np.int64)
    first_row[members[::-1]] = np.arange(len(members))[::-1]
    shell_of_row = np.repeat(np.arange(len(flips)), np.diff(starts))  # (T,)
    triangles = vertices[faces[occluding[members]]]  # (T, 3, 3)
    lows = np.minimum.reduceat(triangles.min(axis=1), starts[:-1]) - margin_m
    highs = np.maximum.reduceat(triangles.max(axis=1), starts[:-1]) + margin_m
    side = np.zeros(scene.n_faces, np.int8)

    def decide(first: int) -> int:
        """The side of the scene faces from ``first`` (``_FACES_PER_TASK`` of them): each
        one's BVH face, through its place among the occluding, then that face's first
        shell row. A block at a time: as (F,) int64 arrays they were some 400 MB at once
        on a 9.7 M-face office, its plan's peak."""
        block = np.arange(first, min(first + _FACES_PER_TASK, scene.n_faces))
        bvh_face = scene.source_face[block] if bvh.file_faces else block
        at = np.minimum(np.searchsorted(occluding, bvh_face), len(occluding) - 1)
        row = np.where(occluding[at] == bvh_face, first_row[at], -1)
        on_shell = row >= 0
        pieces, own_row = block[on_shell], row[on_shell]
        shell = shell_of_row[own_row]
        _far_from_shell(scene.vertices, scene.faces, pieces, own_row, shell, flips[shell], starts,
                        triangles, margin_m, side)
        return first

    list(in_block_order(decide, range(0, scene.n_faces, _FACES_PER_TASK)))
    if not side.any():
        return None
    return ClosedShells(side, margin_m, np.ascontiguousarray(lows),
                        np.ascontiguousarray(highs), starts, np.ascontiguousarray(triangles))


def _closed_members(vertices: NDArray[np.float64], faces: NDArray[np.int32],
                    element: NDArray[np.int32]
                    ) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int8]]:
    """The closed shells of the (b, 3) ``faces``: (T,) their faces (rows of ``faces``),
    shell by shell, (K + 1,) where each shell's start in them, and (K,) each shell's side.

    Faces of an element are joined within it. Faces of none (a plain mesh) are joined two
    ways, and the closed shells of both are taken (a face may be on two): across the whole
    mesh, which closes a box whose sides the file writes with vertices of their own but
    not two boxes that share an edge; and within each object (:func:`_objects`), which
    closes the boxes of a file that writes each object's vertices apart."""
    # small faces are left out: a shell made of them saves a ray or two a face, and the
    # faces kept may still close a shell (a box with a small fin on an edge)
    big = np.flatnonzero(longest_edges_m(vertices, faces) >= MIN_SHELL_EDGE_M)  # (k,)
    faces, element = faces[big], element[big]
    groupings = [element.astype(np.int64)]
    if (element < 0).any():
        groupings.append(_objects(faces, element))
    members, counts, flips = [], [], []
    for grouping in groupings:
        shell_of, side = _shells(vertices, faces, grouping)
        on_closed = np.flatnonzero(shell_of >= 0)
        on_closed = on_closed[side[shell_of[on_closed]] != 0]
        closed = np.flatnonzero(side != 0)
        renumber = np.full(len(side), -1, np.int64)
        renumber[closed] = np.arange(len(closed))
        shell = renumber[shell_of[on_closed]]
        members.append(big[on_closed[np.argsort(shell, kind="stable")]])
        counts.append(np.bincount(shell, minlength=len(closed)))
        flips.append(side[closed])
    count = np.concatenate(counts)
    starts = np.zeros(len(count) + 1, np.int64)
    np.cumsum(count, out=starts[1:])
    return np.concatenate(members), starts, np.concatenate(flips).astype(np.int8)


def _objects(faces: NDArray[np.int32], element: NDArray[np.int32]) -> NDArray[np.int64]:
    """(b,) the object of each of the (b, 3) faces: its element, or for a face of none,
    the faces joined to it through shared vertices (the vertex list a plain mesh's
    exporter writes per object: a wall's box shares no vertex with the slab it stands
    on, though their corners may coincide)."""
    n_elements = int(element.max(initial=-1)) + 1
    loose = np.flatnonzero(element < 0)
    objects = element.astype(np.int64)
    if len(loose):
        used, local = np.unique(faces[loose], return_inverse=True)
        n = len(loose) + len(used)  # faces, then vertices: one graph
        face_node = np.repeat(np.arange(len(loose)), 3)
        graph = sp.coo_matrix((np.ones(len(face_node)), (face_node,
                               len(loose) + local.ravel())), shape=(n, n))
        _, label = connected_components(graph, directed=False)
        objects[loose] = n_elements + label[:len(loose)]
    return objects


def _shells(vertices: NDArray[np.float64], faces: NDArray[np.int32],
            element: NDArray[np.int64]) -> tuple[NDArray[np.int64], NDArray[np.int8]]:
    """(b,) each face's shell (faces of one object joined edge to edge; -1 for a face of
    no area) and (K,) each shell's side: +1 its faces' normals point out of the region it
    bounds, -1 into it, 0 not a closed shell of at most ``MAX_SHELL_FACES`` faces.

    Corners are the same where their float32 coordinates are (as Embree sees them)."""
    n = len(faces)
    shell_of = np.full(n, -1, np.int64)
    if n == 0:
        return shell_of, np.zeros(0, np.int8)
    corners = vertices[faces]  # (b, 3, 3)
    doubled = np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0],
                                      corners[:, 2] - corners[:, 0]), axis=1)
    used, local = np.unique(faces, return_inverse=True)
    rank = coordinate_ranks(vertices[used].astype(np.float32).astype(np.float64))
    corner = rank[local.reshape(-1, 3)].astype(np.int64)  # (b, 3)
    a, b = corner, np.roll(corner, -1, axis=1)  # the directed edges a -> b of each face
    low, high = np.minimum(a, b).ravel(), np.maximum(a, b).ravel()  # (3 b,)
    group = np.repeat(element.astype(np.int64), 3)
    forward = (a < b).ravel()
    face = np.repeat(np.arange(n), 3)
    order = np.lexsort((high, low, group))
    low, high, group = low[order], high[order], group[order]
    forward, face = forward[order], face[order]
    new = np.r_[True, (low[1:] != low[:-1]) | (high[1:] != high[:-1])
                | (group[1:] != group[:-1])]
    run = np.cumsum(new) - 1  # (3 b,) the undirected edge of each directed one
    run_length = np.bincount(run)
    forwards = np.bincount(run, weights=forward.astype(np.float64))
    # an edge of two faces, one along each direction: a closed, consistently wound surface
    good_run = (run_length == 2) & (forwards == 1)
    bad_face = np.zeros(n, bool)
    bad_face[face[~good_run[run]]] = True
    bad_face |= ~(doubled > 0)
    first = np.flatnonzero(new & good_run[run])  # the two faces of a good edge: first, next
    graph = sp.coo_matrix((np.ones(len(first)), (face[first], face[first + 1])), shape=(n, n))
    n_shells, label = connected_components(graph, directed=False)
    closed = np.bincount(label, weights=bad_face.astype(np.float64), minlength=n_shells) == 0
    size = np.bincount(label, minlength=n_shells)
    # signed volume about each shell's first corner (its sign tells the winding)
    anchor = np.zeros((n_shells, 3))
    anchor[label[::-1]] = corners[::-1, 0]
    rel = corners - anchor[label][:, None, :]
    six_volume = np.einsum("ij,ij->i", rel[:, 0], np.cross(rel[:, 1], rel[:, 2]))
    volume = np.bincount(label, weights=six_volume, minlength=n_shells)
    side = np.where(closed & (size <= MAX_SHELL_FACES) & (volume != 0),
                    np.sign(volume), 0).astype(np.int8)
    shell_of[:] = label
    shell_of[~(doubled > 0)] = -1
    return shell_of, side


@numba.njit(nogil=True, cache=True)
def _point_triangle_distance(px: float, py: float, pz: float,
                             tri: NDArray[np.float64]) -> float:
    """The distance from a point to a (3, 3) triangle (Ericson, Real-Time Collision
    Detection, 5.1.5: the closest point by the point's Voronoi region)."""
    ax, ay, az = tri[0, 0], tri[0, 1], tri[0, 2]
    abx, aby, abz = tri[1, 0] - ax, tri[1, 1] - ay, tri[1, 2] - az
    acx, acy, acz = tri[2, 0] - ax, tri[2, 1] - ay, tri[2, 2] - az
    apx, apy, apz = px - ax, py - ay, pz - az
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:
        qx, qy, qz = ax, ay, az
    else:
        bpx, bpy, bpz = px - tri[1, 0], py - tri[1, 1], pz - tri[1, 2]
        d3 = abx * bpx + aby * bpy + abz * bpz
        d4 = acx * bpx + acy * bpy + acz * bpz
        cpx, cpy, cpz = px - tri[2, 0], py - tri[2, 1], pz - tri[2, 2]
        d5 = abx * cpx + aby * cpy + abz * cpz
        d6 = acx * cpx + acy * cpy + acz * cpz
        vc = d1 * d4 - d3 * d2
        vb = d5 * d2 - d1 * d6
        va = d3 * d6 - d5 * d4
        if d3 >= 0.0 and d4 <= d3:
            qx, qy, qz = tri[1, 0], tri[1, 1], tri[1, 2]
        elif d6 >= 0.0 and d5 <= d6:
            qx, qy, qz = tri[2, 0], tri[2, 1], tri[2, 2]
        elif vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
            t = d1 / (d1 - d3)
            qx, qy, qz = ax + t * abx, ay + t * aby, az + t * abz
        elif vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
            t = d2 / (d2 - d6)
            qx, qy, qz = ax + t * acx, ay + t * acy, az + t * acz
        elif va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
            t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
            qx = tri[1, 0] + t * (tri[2, 0] - tri[1, 0])
            qy = tri[1, 1] + t * (tri[2, 1] - tri[1, 1])
            qz = tri[1, 2] + t * (tri[2, 2] - tri[1, 2])
        else:
            denom = 1.0 / (va + vb + vc)
            v, w = vb * denom, vc * denom
            qx = ax + abx * v + acx * w
            qy = ay + aby * v + acy * w
            qz = az + abz * v + acz * w
    dx, dy, dz = px - qx, py - qy, pz - qz
    return float(np.sqrt(dx * dx + dy * dy + dz * dz))


@numba.njit(nogil=True, cache=True)
def _far_from_shell(vertices: NDArray[np.float64], corners: NDArray[np.int32],
                    pieces: NDArray[np.int64],
                    own_row: NDArray[np.int64], shell: NDArray[np.int64],
                    flip: NDArray[np.int8], starts: NDArray[np.int64],
                    triangles: NDArray[np.float64], margin_m: float,
                    side: NDArray[np.int8]) -> None:
    """``side[pieces[i]] = flip[i]`` where the piece's centroid (a face of ``vertices``,
    ``corners``: :func:`planner.scene.face_centroid`) lies farther than
    ``margin_m`` from every face of its shell but its own (row ``own_row[i]`` of
    ``triangles``); compiled.

    The pieces of one face (consecutive, the same ``own_row``) lie in that face's box, so
    only the shell's faces whose box, widened by the margin, meets it can come within the
    margin of one of them: those are found once for the face (a wall's few neighbours of
    its shell's hundreds of faces), then each piece is tested against them as against
    every face of the shell (the rest would fail the box test for every piece)."""
    near = np.empty(MAX_SHELL_FACES, np.int64)  # the rows a face's pieces are tested against
    i = 0
    while i < len(pieces):
        own = own_row[i]
        stop = i + 1
        while stop < len(pieces) and own_row[stop] == own:
            stop += 1
        # the own face's box, widened far past the rounding of its pieces' centroids
        tri = triangles[own]
        slack = _CENTROID_SLACK_M + margin_m
        k = 0
        for row in range(starts[shell[i]], starts[shell[i] + 1]):
            if row == own:
                continue
            other = triangles[row]
            if stop - i > 1 and _boxes_apart(tri, other, slack):
                continue
            near[k] = row
            k += 1
        for j in range(i, stop):
            f = pieces[j]
            cx, cy, cz = face_centroid(vertices, corners, f)
            if _far_from_rows(cx, cy, cz, near[:k], triangles, margin_m):
                side[f] = flip[j]
        i = stop


# far more than a centroid's rounding outside its face's box (some 1e-14 m at 100 m)
_CENTROID_SLACK_M = 1e-6


@numba.njit(nogil=True, cache=True)
def _boxes_apart(tri: NDArray[np.float64], other: NDArray[np.float64], gap_m: float) -> bool:
    """Whether the (3, 3) triangles' boxes are more than ``gap_m`` apart along some axis."""
    for axis in range(3):
        if (min(other[0, axis], other[1, axis], other[2, axis])
                > max(tri[0, axis], tri[1, axis], tri[2, axis]) + gap_m
                or max(other[0, axis], other[1, axis], other[2, axis])
                < min(tri[0, axis], tri[1, axis], tri[2, axis]) - gap_m):
            return True
    return False


@numba.njit(nogil=True, cache=True)
def _far_from_rows(px: float, py: float, pz: float, rows: NDArray[np.int64],
                   triangles: NDArray[np.float64], margin_m: float) -> bool:
    """Whether the point lies farther than ``margin_m`` from each of the ``rows`` of
    ``triangles`` (a box test first, the distance where the point is in the widened box)."""
    for row in rows:
        tri = triangles[row]
        if (px < min(tri[0, 0], tri[1, 0], tri[2, 0]) - margin_m
                or px > max(tri[0, 0], tri[1, 0], tri[2, 0]) + margin_m
                or py < min(tri[0, 1], tri[1, 1], tri[2, 1]) - margin_m
                or py > max(tri[0, 1], tri[1, 1], tri[2, 1]) + margin_m
                or pz < min(tri[0, 2], tri[1, 2], tri[2, 2]) - margin_m
                or pz > max(tri[0, 2], tri[1, 2], tri[2, 2]) + margin_m):
            continue
        if _point_triangle_distance(px, py, pz, tri) <= margin_m:
            return False
    return True


@numba.njit(nogil=True, cache=True)
def _outside_kernel(points: NDArray[np.float64], lows: NDArray[np.float64],
                    highs: NDArray[np.float64], starts: NDArray[np.int64],
                    triangles: NDArray[np.float64], margin_m: float,
                    ok: NDArray[np.bool_]) -> None:
    """``ok[i] = False`` for each point inside some shell's widened box that lies inside
    the shell (its winding number, the solid angles of the shell's triangles over 4 pi,
    is one half or more in size) or within ``margin_m`` of it; compiled."""
    for i in range(len(points)):
        px, py, pz = points[i, 0], points[i, 1], points[i, 2]
        for k in range(len(lows)):
            if (px < lows[k, 0] or px > highs[k, 0] or py < lows[k, 1] or py > highs[k, 1]
                    or pz < lows[k, 2] or pz > highs[k, 2]):
                continue
            solid_angle = 0.0
            for row in range(starts[k], starts[k + 1]):
                if _point_triangle_distance(px, py, pz, triangles[row]) <= margin_m:
                    ok[i] = False
                    break
                solid_angle += triangle_solid_angle(triangles, row, px, py, pz)
            if not ok[i]:
                break
            if abs(solid_angle) >= 2.0 * np.pi:  # winding number of one half or more
                ok[i] = False
                break
