"""Embree occlusion queries (through :mod:`planner.rays.pinned`, Embree on a device pinned to
one instruction set).

A missing embreex is a loud error: there is no silent slow path.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Any

import numba
import numpy as np
from numpy.typing import NDArray

from planner.rays.bruteforce import ray_triangle_distance
from planner.rays.pinned import PinnedScene
from planner.rays.protocols import FAR_LIMIT_FACTOR, ExactRays
from planner.scene import Scene, read_only

# probe rays for a ray float32 cannot decide run this far beside it, on four sides: 20x the
# float32 rounding of a point 5 m away, far below the size of any face that matters
_PROBE_OFFSET_M = 1e-5
# a hit this many float32 steps (of the largest coordinate) inside its triangle and in front
# of the target is one every mode of Embree finds: far above the rounding of either test
_CLEAR_HIT_ULPS = 1024.0
# doubtful rays decided together: bounds the chunk's (ray, occluder) pairs (some 100 a ray)
_EXACT_RAYS_PER_CHUNK = 1024


# bundles may hide behind the convex quad two coplanar triangles make (a wall's face) in a
# BVH of up to this many triangles (finding the quads costs some 300 bytes a triangle)
_QUAD_MAX_TRIANGLES = 1 << 20
# a quad's far corner lies at most this share of the clear margin off the other
# triangle's plane (float32 corners of one plane: a few micrometres at 50 m)
_QUAD_PLANE_SHARE = 1e-3
# and a quad rules a bundle out only for rays that cross its plane at least this steeply
_QUAD_MIN_SINE = 10 * _QUAD_PLANE_SHARE


# the empty arguments of the compiled kernels, read-only as the scene's arrays they stand in
# for are: numba compiles a kernel again for each read-only/writable mix of its arguments
_EMPTY_INT32 = read_only(np.zeros(0, np.int32))
_EMPTY_INT64 = read_only(np.zeros(0, np.int64))
_EMPTY_BOOL = read_only(np.zeros(0, np.bool_))


def quad_partners(vertices32: NDArray[np.float32], faces32: NDArray[np.int32],
                  margin_m: float
                  ) -> tuple[NDArray[np.int32], NDArray[np.int8], NDArray[np.int32]]:
    """Each of the n triangles' quad partner: the triangle across its longest edge when
    that edge is the other's longest too (a rectangle's two halves share their diagonal),
    the two lie in one plane (the far corner within ``_QUAD_PLANE_SHARE`` of ``margin_m``
    of it) and make a strictly convex quad. (n,) int32 partner (-1: none), (n,) int8 the
    shared edge (corners j, j + 1) and (n,) int32 the partner's far corner (a vertex).

    Edges are matched by their ends' float32 coordinates, as Embree holds them, so two
    triangles that repeat a vertex instead of sharing it still match.
    """
    n = len(faces32)
    partner = np.full(n, -1, np.int32)
    shared_edge = np.zeros(n, np.int8)
    far_vertex = np.zeros(n, np.int32)
    corner = vertices32[faces32].astype(np.float64)  # (n, 3, 3)
    edge = corner[:, [1, 2, 0]] - corner  # (n, 3, 3): corner j to j + 1
    longest = np.argmax(np.einsum("nij,nij->ni", edge, edge), axis=1)  # (n,)
    rows = np.arange(n)
    ends = np.stack([vertices32[faces32[rows, longest]],
                     vertices32[faces32[rows, (longest + 1) % 3]]], axis=1) + np.float32(0)
    first_low = _lexicographically_less(ends[:, 0], ends[:, 1])
    ordered = np.where(first_low[:, None, None], ends, ends[:, ::-1])  # (n, 2, 3)
    key = np.ascontiguousarray(ordered.reshape(n, 6)).view(np.dtype((np.void, 24))).ravel()
    _, group, count = np.unique(key, return_inverse=True, return_counts=True)
    twice = np.flatnonzero(count[group] == 2)  # triangles whose edge one other shares
    pair = twice[np.argsort(group[twice], kind="stable")].reshape(-1, 2)  # (m, 2)
    for this, other in ((pair[:, 0], pair[:, 1]), (pair[:, 1], pair[:, 0])):
        far = faces32[other, (longest[other] + 2) % 3]  # the partner's far corner
        a = corner[this, 0]
        normal = np.cross(edge[this, 0], corner[this, 2] - a)
        normal /= np.maximum(np.linalg.norm(normal, axis=1), 1e-300)[:, None]
        flat = np.abs(np.einsum("mk,mk->m", vertices32[far].astype(np.float64) - a, normal)
                      ) <= margin_m * _QUAD_PLANE_SHARE
        j = longest[this]
        around = np.stack([corner[this, (j + 2) % 3], corner[this, j],
                           vertices32[far].astype(np.float64), corner[this, (j + 1) % 3]],
                          axis=1)  # (m, 4, 3): as T runs
        side = np.roll(around, -1, axis=1) - around
        turn = np.einsum("mik,mk->mi", np.cross(side, np.roll(side, -1, axis=1)), normal)
        ok = flat & (turn > 0).all(axis=1)
        partner[this[ok]] = other[ok]
        shared_edge[this[ok]] = j[ok]
        far_vertex[this[ok]] = far[ok]
    return partner, shared_edge, far_vertex


def _lexicographically_less(p: NDArray[np.float32], q: NDArray[np.float32]
                            ) -> NDArray[np.bool_]:
    """(n,) whether each of the (n, 3) points ``p`` comes before ``q`` in (x, y, z) order."""
    less: NDArray[np.bool_] = (p[:, 0] < q[:, 0]) | ((p[:, 0] == q[:, 0]) & (
        (p[:, 1] < q[:, 1]) | ((p[:, 1] == q[:, 1]) & (p[:, 2] <= q[:, 2]))))
    return less


def _ragged_ranges(starts: NDArray[np.int64], counts: NDArray[np.int64]) -> NDArray[np.int64]:
    """The ranges [starts[i], starts[i] + counts[i]) one after another, as one array."""
    ends = np.cumsum(counts)
    return np.repeat(starts - ends + counts, counts) + np.arange(int(ends[-1]) if len(ends)
                                                                 else 0)


def _bvh_occludes(scene: Scene, occludes: NDArray[np.bool_], *, remeshed: bool
                  ) -> NDArray[np.bool_]:
    """Which BVH faces occlude: the (F,) ``occludes`` itself, or on the file's faces of a
    ``remeshed`` scene (F0,), a file face wherever one of its pieces occludes."""
    if not remeshed:
        return occludes
    file_occludes = np.zeros(len(scene.file_mesh[1]), bool)
    file_occludes[scene.source_face[occludes]] = True
    return file_occludes


@dataclass(frozen=True)
class BvhPart:
    """What makes a BVH over a part of a model's faces decide as the whole model's BVH
    does (a tile of the model sent to another machine, :mod:`planner.visibility.tiles`).

    Attributes
    ----------
    bvh_occludes : (n,) bool, which of the part's BVH faces occlude (the file faces of a
        remeshed part, whose pieces are not all in it; None: from the pieces' ``occludes``)
    scale_m : the largest coordinate of the whole BVH, which sets the clear-hit margin
    quads : whether bundles may hide behind quads (the whole BVH's size decides)
    exact : every ray decided in float64 as the reference does (the plan's ``exact_rays``)
    """

    bvh_occludes: NDArray[np.bool_] | None
    scale_m: float
    quads: bool
    exact: bool = False


def clear_margin_m(scale_m: float) -> float:
    """The clear-hit margin of a BVH whose largest coordinate is ``scale_m``:
    ``_CLEAR_HIT_ULPS`` float32 steps there, a distance Embree's rounding cannot cross."""
    return _CLEAR_HIT_ULPS * float(np.spacing(np.float32(scale_m)))


@dataclass(frozen=True, eq=False)
class BvhFaces:
    """The faces an :class:`EmbreeOcclusion` casts against, for cutting a part of them.

    Attributes
    ----------
    vertices : (V, 3) float64 and ``faces`` (B, 3) int32: the BVH's mesh (the file's mesh
        with ``file_faces`` on a remeshed scene, else the scene's own)
    occluding : (b,) int64, the BVH faces that occlude, ascending
    file_faces : the BVH holds the file's faces of a remeshed scene
    scale_m, quads, exact : as :class:`BvhPart`
    """

    vertices: NDArray[np.float64]
    faces: NDArray[np.int32]
    occluding: NDArray[np.int64]
    file_faces: bool
    scale_m: float
    quads: bool
    exact: bool


class EmbreeBvh:
    """The Embree BVH (robust mode; a fast-mode one too once exact rays need it) over the
    occluding faces of one mesh, and what deciding a ray in float64 needs of them: the
    state an :class:`EmbreeOcclusion` casts against, which several of them may share (a
    Dask worker's tiles of one plan, :class:`planner.visibility.tiles.Occluders`).

    ``vertices`` (V, 3) float64 and ``faces`` (B, 3) int32 are the mesh, ``occluding`` (B,)
    bool which of its faces the BVH holds (in the mesh's order: the same faces in the same
    order give the same BVH, and so the same verdicts). ``scale_m`` (the largest coordinate
    of the mesh, which sets the clear-hit margin) and ``quads`` (bundles may hide behind
    quads) default to this mesh's; a part of a larger model passes the model's.
    """

    def __init__(self, vertices: NDArray[np.float64], faces: NDArray[np.int32],
                 occluding: NDArray[np.bool_], *, scale_m: float | None = None,
                 quads: bool | None = None) -> None:
        self.mesh = (vertices, faces)
        # the mesh's own scale and quads, not a larger model's (reused_bvh)
        self.own_scale = scale_m is None and quads is None
        self.scene: PinnedScene | None = None
        # the same faces in Embree's fast mode, built when exact rays first need it
        self._check_scene: PinnedScene | None = None
        self.faces: NDArray[np.int64] = np.flatnonzero(occluding)  # (b,) the BVH's faces
        self.empty = len(self.faces) == 0
        self.all_occlude = bool(np.asarray(occluding, bool).all())
        self.scale_m = 1.0
        self.clear_margin_m = 0.0
        self.corners32 = (np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32))
        if not self.empty:
            # indexed (shared vertices): a third faster to build than a triangle soup
            vertices32 = vertices.astype(np.float32)
            faces32 = faces[self.faces].astype(np.int32)
            self.scene = PinnedScene(vertices32, faces32, robust=True)
            # the corners as Embree holds them (float32), for the clear-hit test
            self.corners32 = (vertices32, faces32)
            self.scale_m = (float(np.abs(vertices32).max(initial=1.0)) if scale_m is None
                            else scale_m)
            self.clear_margin_m = clear_margin_m(self.scale_m)
        self.quads_allowed = len(self.faces) <= _QUAD_MAX_TRIANGLES if quads is None else quads
        # (V + 1,) and (3 b,): the occluders (indices into self.faces) at each vertex, built
        # the first time a ray needs deciding in float64
        self._vertex_occluders: tuple[NDArray[np.int64], NDArray[np.int64]] | None = None
        self._quad_partners: tuple[NDArray[np.int32], NDArray[np.int8],
                                   NDArray[np.int32]] | None = None
        self._lock = threading.Lock()

    def check_scene(self) -> PinnedScene:
        """The occluding faces in Embree's fast mode, built the first time exact rays
        compare the two modes' verdicts (a second BVH, as large as the first)."""
        with self._lock:
            if self._check_scene is None:
                vertices32, faces32 = self.corners32
                self._check_scene = PinnedScene(vertices32, faces32, robust=False)
            return self._check_scene

    def quads(self) -> tuple[NDArray[np.int32], NDArray[np.int8], NDArray[np.int32]]:
        """The BVH triangles' quad partners (:func:`quad_partners`), found the first time
        bundles are ruled out; none (empty arrays) for a BVH of more than
        :data:`_QUAD_MAX_TRIANGLES`."""
        with self._lock:
            if self._quad_partners is None:
                vertices32, faces32 = self.corners32
                self._quad_partners = (
                    quad_partners(vertices32, faces32, self.clear_margin_m)
                    if self.quads_allowed
                    else (np.zeros(0, np.int32), np.zeros(0, np.int8), np.zeros(0, np.int32)))
            return self._quad_partners

    def vertex_table(self) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """(V + 1,) starts and (3 b,) occluders (indices into :attr:`faces`) at each
        vertex: the occluders at vertex v are ``occluder[starts[v]:starts[v + 1]]``."""
        with self._lock:
            if self._vertex_occluders is None:
                corner_vertex = self.mesh[1][self.faces].ravel()
                order = np.argsort(corner_vertex, kind="stable")
                starts = np.searchsorted(corner_vertex[order],
                                         np.arange(len(self.mesh[0]) + 1))
                self._vertex_occluders = (starts, order // 3)
            return self._vertex_occluders


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
    passes exactly through a vertex) is decided by rounding. Embree's rounding depends on
    its kernels, which :mod:`planner.rays.pinned` pins to one instruction set, so by
    default ``visible`` casts every ray once, in Embree's robust (watertight) mode, and
    every machine with that set decides it the same way.

    ``exact`` decides every ray as the brute-force reference does, in float64: unless the
    robust cast hit an occluder clearly (well inside its edges and in front of the target,
    a hit every mode finds), the ray is cast again in Embree's fast mode, and the rays
    where the two disagree are decided in float64 against the faces either cast hit and
    every face sharing a vertex with them. Measured: 150 of hall-small's 3.0 M rays and
    2,296 of hall-full's 17.6 M disagree; the robust cast alone differs from the reference
    on 21 and 35 of them, which moves the stations hall-small's coverage curve needs at
    100 % by one (37 instead of the reference's 36). The second cast costs a second BVH
    and ray time (tests/planner/test_occlusion.py compares the exact verdicts with the
    reference ray by ray).

    ``part_of`` (:class:`BvhPart`): the scene is a part of a larger model (a tile, cut
    with every occluder a ray of the part can meet); which BVH faces occlude, the clear
    margin and the quads are then the whole model's, so the part's verdicts are its.
    ``bvh`` (:class:`EmbreeBvh`): cast against that BVH, built once over this scene's BVH
    mesh (the file's mesh with ``file_faces``) and shared, instead of building one.
    ``exact`` (or ``part_of.exact``): decide every ray in float64, as above.

    ``visible`` releases the GIL inside Embree, so threads calling it run in parallel.
    """

    def __init__(self, scene: Scene, occludes: NDArray[np.bool_], *,
                 file_faces: bool = False, part_of: BvhPart | None = None,
                 bvh: EmbreeBvh | None = None, exact: bool = False) -> None:
        self.exact = exact or (part_of is not None and part_of.exact)
        remeshed = file_faces and scene.file_faces is not None
        bvh_vertices, bvh_faces = scene.file_mesh if remeshed else (scene.vertices, scene.faces)
        # (F,) the BVH face each scene face is part of (the identity on an unremeshed scene)
        self._source_face = scene.source_face if remeshed else None
        if remeshed:
            # (F0,) a scene face of every file face (its first piece), for first_hit
            self._first_piece = np.full(len(bvh_faces), -1, np.int64)
            pieces_of, first = scene.first_pieces()
            self._first_piece[pieces_of] = first
        if bvh is None:
            if part_of is not None and part_of.bvh_occludes is not None:
                file_occludes = np.asarray(part_of.bvh_occludes, bool)
            else:
                file_occludes = _bvh_occludes(scene, occludes, remeshed=remeshed)
            bvh = EmbreeBvh(bvh_vertices, bvh_faces, file_occludes,
                            scale_m=None if part_of is None else part_of.scale_m,
                            quads=None if part_of is None else part_of.quads)
        elif len(bvh.mesh[1]) != len(bvh_faces):
            raise ValueError("the shared BVH is not over this scene's BVH mesh")
        self._bvh = bvh
        # the BVH's own state, read through these names by the queries below
        self._scene = bvh.scene
        self._faces, self._empty = bvh.faces, bvh.empty
        self._corners32 = bvh.corners32
        self._scale_m, self._clear_margin_m = bvh.scale_m, bvh.clear_margin_m
        self._quads_allowed, self._all_occlude = bvh.quads_allowed, bvh.all_occlude
        self._bvh_mesh = bvh.mesh
        self._occludes = occludes
        self._scene_faces = (scene.vertices, scene.faces)

    def reused_bvh(self, scene: Scene, occludes: NDArray[np.bool_], *,
                   file_faces: bool = False) -> EmbreeBvh | None:
        """This occlusion's BVH when ``EmbreeOcclusion(scene, occludes, file_faces=...)``
        would build the same one (the same mesh arrays, the same occluding faces in the same
        order, the mesh's own scale and quads), else None. A scene split after the
        candidates casts against the file's faces, as the unsplit scene did: its BVH is the
        one already built (on a 1 M-face interior: 0.8 CPU s and a second BVH in memory)."""
        bvh = self._bvh
        remeshed = file_faces and scene.file_faces is not None
        vertices, faces = scene.file_mesh if remeshed else (scene.vertices, scene.faces)
        same_mesh = bvh.mesh[0] is vertices and bvh.mesh[1] is faces
        if not same_mesh or not bvh.own_scale:
            return None
        occluding = np.flatnonzero(_bvh_occludes(scene, occludes, remeshed=remeshed))
        return bvh if np.array_equal(occluding, bvh.faces) else None

    def bvh_faces(self) -> BvhFaces:
        """The faces this occlusion casts against (see :class:`BvhFaces`)."""
        vertices, faces = self._bvh_mesh
        return BvhFaces(vertices, faces, self._faces.astype(np.int64),
                        self._source_face is not None, self._scale_m, self._quads_allowed,
                        self.exact)

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
        assert self._scene is not None
        prim = self._scene.first_hits(origins32, directions32, far)
        targets: NDArray[np.int64] = np.asarray(target_faces, np.int64)
        visible = self._reaches(prim, targets)
        if not self.exact:
            return visible
        # the fast-mode cast, for the rays whose robust verdict is not a clear hit on an
        # occluder (a clear hit is found in either mode, so both casts would agree on it)
        unsure = np.flatnonzero(~self._clear_hits(origins32, directions32, prim, visible,
                                                  distances_m))
        check_unsure = self._bvh.check_scene().first_hits(
            origins32[unsure], directions32[unsure], far[unsure])
        differ = visible[unsure] != self._reaches(check_unsure, targets[unsure])
        doubtful, check = unsure[differ], check_unsure[differ]  # check: at the doubtful rays
        if len(doubtful):
            if exact_rays is not None:
                origins64, directions64 = exact_rays(doubtful)
            else:
                origins64 = np.asarray(origins, np.float64)[doubtful]
                directions64 = np.asarray(directions, np.float64)[doubtful]
                directions64 /= np.linalg.norm(directions64, axis=1)[:, None]
            visible[doubtful] = self._decide_exactly(
                origins64, directions64, targets[doubtful], prim[doubtful], check)
        return visible

    def _clear_hits(self, origins32: NDArray[np.float32], directions32: NDArray[np.float32],
                    prim: NDArray[np.int64], visible: NDArray[np.bool_],
                    distances_m: NDArray[np.floating[Any]]) -> NDArray[np.bool_]:
        """(P,) the rays whose robust cast hit an occluder (not the target) clearly: more than
        ``_clear_margin_m`` inside the hit face's edges and in front of the target.

        Such a hit is found by Embree's fast mode too (only rays at an edge or a corner are
        decided by rounding), so the fast cast's first hit is this face or one before it,
        never the target: the two casts agree and the fast cast is not needed. In a
        building most rays to faces in other rooms end inside a wall's face like this.
        """
        vertices32, faces32 = self._corners32
        clear = np.zeros(len(prim), bool)
        blocked = np.flatnonzero(~visible & (prim >= 0))
        if len(blocked):
            _clear_hit_kernel(origins32, directions32, np.asarray(distances_m, np.float64),
                              blocked, prim, vertices32, faces32, self._clear_margin_m, clear)
        return clear

    def bundles_hidden(self, origins: NDArray[np.float64], corners: NDArray[np.float64]
                       ) -> NDArray[np.bool_]:
        """(P,) bool: the bundles whose (P, 4, 3) ``corners`` all lie clearly behind one
        occluding triangle or quad seen from the (P, 3) ``origins``
        (:mod:`planner.visibility.bundles`): one robust cast of the four corner rays, the hits
        checked in float64. The rays start where the pieces' own rays do, at the float32
        origin."""
        hidden = np.zeros(len(origins), bool)
        if self._empty or len(origins) == 0:
            return hidden
        corners = np.ascontiguousarray(corners, np.float64)
        n = len(origins)
        # the four rays of each bundle, made in one compiled pass (numpy's temporaries of
        # the (P, 4, 3) offsets were some 4 % of a large plan's time)
        start = np.empty((n, 3))
        reaches = np.empty(n, bool)
        ray_origins32 = np.empty((4 * n, 3), np.float32)
        directions32 = np.empty((4 * n, 3), np.float32)
        far32 = np.empty(4 * n, np.float32)
        cast = _bundle_rays(np.ascontiguousarray(origins, np.float64), corners,
                            np.float32(FAR_LIMIT_FACTOR), start, reaches, ray_origins32,
                            directions32, far32)
        if cast < n:  # a corner at the origin: not ruled out (its pieces are cast)
            start, corners = start[:cast], corners[reaches]
        assert self._scene is not None
        prim = self._scene.first_hits(ray_origins32[:4 * cast], directions32[:4 * cast],
                                      far32[:4 * cast])
        vertices32, faces32 = self._corners32
        ruled_out = np.zeros(cast, bool)
        _bundle_hidden_kernel(start, corners, prim.reshape(-1, 4), vertices32, faces32,
                              *self._quads(), self._clear_margin_m, ruled_out)
        hidden[np.flatnonzero(reaches)[ruled_out]] = True
        return hidden

    def _quads(self) -> tuple[NDArray[np.int32], NDArray[np.int8], NDArray[np.int32]]:
        return self._bvh.quads()

    def _bvh_face(self, faces: NDArray[np.int64]) -> NDArray[np.int64]:
        """The BVH face (file face, or the face itself) of scene faces."""
        return faces if self._source_face is None else self._source_face[faces].astype(np.int64)

    def _reaches(self, prim: NDArray[np.int64], target_faces: NDArray[np.int64]
                 ) -> NDArray[np.bool_]:
        """Closest-hit verdict of one cast: (P,) Embree primitive ids -> (P,) bool."""
        reached = np.empty(len(prim), bool)
        # where every face occludes the kernel reads neither the BVH's faces nor
        # ``occludes`` (a plain mesh's is a broadcast True, of another array type)
        _reach_kernel(prim, target_faces, _EMPTY_INT32 if self._source_face is None
                      else self._source_face, _EMPTY_INT64 if self._all_occlude
                      else self._faces, _EMPTY_BOOL if self._all_occlude
                      else self._occludes, reached)
        return reached

    def _vertex_table(self) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        return self._bvh.vertex_table()

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
        assert self._scene is not None
        hits = [scene.first_hits(probe_origins, probe_directions).reshape(-1, 4)
                for scene in (self._scene, self._bvh.check_scene())]
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
        assert self._scene is not None
        prim = self._scene.first_hits(np.ascontiguousarray(origins, np.float32),
                                      np.ascontiguousarray(directions, np.float32))
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
        assert self._scene is not None
        prim, tfar = self._scene.first_hits_and_distances(
            np.ascontiguousarray(origins, np.float32),
            np.ascontiguousarray(directions, np.float32))
        hit = prim >= 0
        face = np.where(hit, self._faces[np.where(hit, prim, 0)], -1)
        if self._source_face is not None:
            face = np.where(hit, self._first_piece[np.maximum(face, 0)], -1)
        distance = np.where(hit, tfar.astype(np.float64), np.inf)
        return face, distance


@numba.njit(nogil=True, cache=True)
def _reach_kernel(prim: NDArray[np.int64], target_faces: NDArray[np.int64],
                  source_face: NDArray[np.int32], bvh_face: NDArray[np.int64],
                  occludes: NDArray[np.bool_], out: NDArray[np.bool_]) -> None:
    """``out[r]``: ray r's first hit (BVH primitive ``prim[r]``, -1 none) is its target.

    ``source_face`` (F,): the BVH face of each scene face (empty: the scene's own faces);
    ``bvh_face`` (n,): the BVH face of each primitive (empty: the same numbers, every face
    occludes). A target that does not occlude is not in the BVH: reached when nothing is
    hit."""
    pieces = source_face.shape[0] > 0
    mapped = bvh_face.shape[0] > 0
    for r in range(prim.shape[0]):
        target = target_faces[r]
        target_in_bvh = source_face[target] if pieces else target
        hit = prim[r]
        if hit >= 0 and mapped:
            hit = bvh_face[hit]
        # (where every BVH face occludes, the ids are the file's and no target is glass)
        out[r] = hit == target_in_bvh or (mapped and hit < 0 and not occludes[target])


@numba.njit(nogil=True, cache=True)
def _corner_and_edges(face: int, vertices32: NDArray[np.float32], faces32: NDArray[np.int32]
                      ) -> tuple[float, float, float, float, float, float, float, float,
                                 float]:
    """BVH triangle ``face`` in float64 from its float32 corners a, b, c: a, then the
    edges b - a and c - a (x, y, z each)."""
    a, b, c = faces32[face, 0], faces32[face, 1], faces32[face, 2]
    ax, ay, az = float(vertices32[a, 0]), float(vertices32[a, 1]), float(vertices32[a, 2])
    return (ax, ay, az,
            float(vertices32[b, 0]) - ax, float(vertices32[b, 1]) - ay,
            float(vertices32[b, 2]) - az,
            float(vertices32[c, 0]) - ax, float(vertices32[c, 1]) - ay,
            float(vertices32[c, 2]) - az)


@numba.njit(nogil=True, cache=True)
def _hit_inside(ox: float, oy: float, oz: float, dx: float, dy: float, dz: float, face: int,
                vertices32: NDArray[np.float32], faces32: NDArray[np.int32]
                ) -> tuple[float, float]:
    """Where the unit ray (o, d) meets BVH triangle ``face`` (its float32 corners, in
    float64): the distance t along the ray and how far inside the triangle the hit lies
    (metres to its nearest edge, negative outside); (nan, -inf) for a ray in its plane or a
    degenerate triangle."""
    ax, ay, az, e1x, e1y, e1z, e2x, e2y, e2z = _corner_and_edges(face, vertices32, faces32)
    # Moller-Trumbore: barycentric (w, u, v) of the hit and its distance t (unit ray)
    px, py, pz = dy * e2z - dz * e2y, dz * e2x - dx * e2z, dx * e2y - dy * e2x
    det = e1x * px + e1y * py + e1z * pz
    if det == 0.0:
        return np.nan, -np.inf
    sx, sy, sz = ox - ax, oy - ay, oz - az
    u = (sx * px + sy * py + sz * pz) / det
    qx, qy, qz = sy * e1z - sz * e1y, sz * e1x - sx * e1z, sx * e1y - sy * e1x
    v = (dx * qx + dy * qy + dz * qz) / det
    t = (e2x * qx + e2y * qy + e2z * qz) / det
    w = 1.0 - u - v
    # distance of the hit to each edge: barycentric coordinate x the height on that edge
    nx, ny, nz = e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x
    doubled_area = np.sqrt(nx * nx + ny * ny + nz * nz)
    fx, fy, fz = e2x - e1x, e2y - e1y, e2z - e1z
    edge_bc = np.sqrt(fx * fx + fy * fy + fz * fz)
    edge_ac = np.sqrt(e2x * e2x + e2y * e2y + e2z * e2z)
    edge_ab = np.sqrt(e1x * e1x + e1y * e1y + e1z * e1z)
    if edge_bc <= 0.0 or edge_ac <= 0.0 or edge_ab <= 0.0:
        return np.nan, -np.inf
    inside_m = min(w * doubled_area / edge_bc, u * doubled_area / edge_ac,
                   v * doubled_area / edge_ab)
    return t, inside_m


@numba.njit(nogil=True, cache=True)
def _clear_hit_kernel(  # compiled; compared with both casts in tests/planner/test_limits.py
    origins32: NDArray[np.float32], directions32: NDArray[np.float32],
    distances_m: NDArray[np.float64], rays: NDArray[np.int64], prim: NDArray[np.int64],
    vertices32: NDArray[np.float32], faces32: NDArray[np.int32], margin_m: float,
    out: NDArray[np.bool_],
) -> None:
    """Set ``out[r]`` for each ray r of ``rays`` whose hit on BVH face ``prim[r]`` lies more
    than ``margin_m`` inside every edge of that triangle and ``margin_m`` before
    ``distances_m[r]``, in float64 on the float32 ray and corners Embree was given."""
    for k in range(rays.shape[0]):
        r = rays[k]
        dx, dy, dz = (float(directions32[r, 0]), float(directions32[r, 1]),
                      float(directions32[r, 2]))
        length = np.sqrt(dx * dx + dy * dy + dz * dz)
        if length <= 0.0:
            continue
        t, inside_m = _hit_inside(float(origins32[r, 0]), float(origins32[r, 1]),
                                  float(origins32[r, 2]), dx / length, dy / length,
                                  dz / length, prim[r], vertices32, faces32)
        out[r] = inside_m > margin_m and margin_m < t < distances_m[r] - margin_m


@numba.njit(nogil=True, cache=True)
def _bundle_rays(  # compiled
    origins: NDArray[np.float64], corners: NDArray[np.float64], far_factor: np.float32,
    start: NDArray[np.float64], reaches: NDArray[np.bool_], ray_origins32: NDArray[np.float32],
    directions32: NDArray[np.float32], far32: NDArray[np.float32],
) -> int:
    """The rays from the (P, 3) ``origins`` to each of their bundle's four (P, 4, 3)
    ``corners``, from the float32 origin (as the pieces' own rays start), for the bundles
    whose corners all lie away from it (``reaches`` (P,)); returns how many do (n). Their
    origins as float64 go to ``start[:n]``, the rays to ``ray_origins32``,
    ``directions32`` (4n, 3) and ``far32`` (4n,): the float32 unit direction and
    ``far_factor`` times the distance, in float32. The same values, bit for bit, as
    numpy's ``linalg.norm`` over the offsets (((x * x + y * y) + z * z) ** 0.5), their
    quotients cast to float32, and ``multiply(distance, factor, dtype=float32)``."""
    n = 0
    for p in range(origins.shape[0]):
        ox, oy, oz = (np.float64(np.float32(origins[p, 0])), np.float64(np.float32(origins[p, 1])),
                      np.float64(np.float32(origins[p, 2])))
        # the rays go to places 4n .. 4n + 3, kept only when all four corners lie away
        # (else the next bundle writes over them)
        away = True
        for k in range(4):
            dx, dy, dz = corners[p, k, 0] - ox, corners[p, k, 1] - oy, corners[p, k, 2] - oz
            distance = np.sqrt((dx * dx + dy * dy) + dz * dz)
            if not distance > 0.0:
                away = False
                break
            ray = 4 * n + k
            ray_origins32[ray, 0] = np.float32(ox)
            ray_origins32[ray, 1] = np.float32(oy)
            ray_origins32[ray, 2] = np.float32(oz)
            directions32[ray, 0] = np.float32(dx / distance)
            directions32[ray, 1] = np.float32(dy / distance)
            directions32[ray, 2] = np.float32(dz / distance)
            far32[ray] = np.float32(distance) * far_factor
        reaches[p] = away
        if away:
            start[n, 0], start[n, 1], start[n, 2] = ox, oy, oz
            n += 1
    return n


@numba.njit(nogil=True, cache=True)
def _bundle_hidden_kernel(  # compiled; compared with the pieces' own rays in test_bundles
    origins: NDArray[np.float64], corners: NDArray[np.float64], prim: NDArray[np.int64],
    vertices32: NDArray[np.float32], faces32: NDArray[np.int32],
    partner: NDArray[np.int32], shared_edge: NDArray[np.int8], far_vertex: NDArray[np.int32],
    margin_m: float, out: NDArray[np.bool_],
) -> None:
    """Set ``out[p]`` where the four rays from ``origins[p]`` (P, 3) to ``corners[p]``
    (P, 4, 3) all hit BVH triangle T = ``prim[p, 0]`` (P, 4), or T and its quad partner
    (``partner``, ``shared_edge``, ``far_vertex``: :func:`quad_partners`), more than
    ``margin_m`` inside the edges of T (of the convex quad the two make); the origin
    lies more than ``margin_m`` in front of T's plane and every corner more than
    ``margin_m`` behind it (:mod:`planner.visibility.bundles`)."""
    for p in range(prim.shape[0]):
        face = prim[p, 0]
        if face < 0:
            continue
        other = partner[face] if partner.shape[0] > 0 else -1  # -1: T has no partner
        quad = False  # some ray hit T's partner: the quad's edges count, not T's
        on_t_or_quad = True
        for j in range(1, 4):
            if prim[p, j] == face:
                continue
            if other < 0 or prim[p, j] != other:  # a miss (-1) or another face
                on_t_or_quad = False
                break
            quad = True
        if not on_t_or_quad:
            continue
        ax, ay, az, e1x, e1y, e1z, e2x, e2y, e2z = _corner_and_edges(face, vertices32,
                                                                     faces32)
        nx, ny, nz = e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x
        norm = np.sqrt(nx * nx + ny * ny + nz * nz)
        if norm <= 0.0:
            continue
        nx, ny, nz = nx / norm, ny / norm, nz / norm
        ox, oy, oz = origins[p, 0], origins[p, 1], origins[p, 2]
        front = (ox - ax) * nx + (oy - ay) * ny + (oz - az) * nz  # the origin's side
        if abs(front) <= margin_m:
            continue
        hidden = True
        for j in range(4):
            qx, qy, qz = corners[p, j, 0], corners[p, j, 1], corners[p, j, 2]
            behind = (qx - ax) * nx + (qy - ay) * ny + (qz - az) * nz
            if behind * front >= 0.0 or abs(behind) <= margin_m:
                hidden = False
                break
            dx, dy, dz = qx - ox, qy - oy, qz - oz
            length = np.sqrt(dx * dx + dy * dy + dz * dz)
            dx, dy, dz = dx / length, dy / length, dz / length
            if quad:
                # where the ray crosses T's plane, and how far inside the quad's edges; a
                # ray steeper than _QUAD_MIN_SINE meets the partner's plane (at most
                # _QUAD_PLANE_SHARE margins off) less than a tenth of a margin away
                sine = dx * nx + dy * ny + dz * nz
                if abs(sine) < _QUAD_MIN_SINE:
                    hidden = False
                    break
                t = -front / sine
                inside_m = _inside_quad(ox + t * dx, oy + t * dy, oz + t * dz, face,
                                        int(shared_edge[face]), int(far_vertex[face]),
                                        nx, ny, nz, vertices32, faces32)
            else:
                t, inside_m = _hit_inside(ox, oy, oz, dx, dy, dz, face, vertices32, faces32)
            if not (inside_m > margin_m and margin_m < t < length - margin_m):
                hidden = False
                break
        out[p] = hidden


@numba.njit(nogil=True, cache=True)
def _inside_quad(x: float, y: float, z: float, face: int, edge: int, far: int,
                 nx: float, ny: float, nz: float, vertices32: NDArray[np.float32],
                 faces32: NDArray[np.int32]) -> float:
    """How far the point (x, y, z) of T's plane lies inside the quad of BVH triangle T =
    ``face`` and its partner across T's edge ``edge`` (corners ``edge``, ``edge + 1``),
    whose far corner is vertex ``far``: the least distance to the quad's four edges,
    negative outside. The quad runs as T does around its unit normal (nx, ny, nz)."""
    around = (faces32[face, (edge + 2) % 3], faces32[face, edge], far,
              faces32[face, (edge + 1) % 3])
    least = np.inf
    for k in range(4):
        a, b = around[k], around[(k + 1) % 4]
        px, py, pz = (float(vertices32[a, 0]), float(vertices32[a, 1]),
                      float(vertices32[a, 2]))
        ux, uy, uz = (float(vertices32[b, 0]) - px, float(vertices32[b, 1]) - py,
                      float(vertices32[b, 2]) - pz)
        length = np.sqrt(ux * ux + uy * uy + uz * uz)
        if length <= 0.0:
            return -np.inf
        wx, wy, wz = x - px, y - py, z - pz
        # (u x w) . n / |u|: the distance to the edge's line, positive on the quad's side
        side = ((uy * wz - uz * wy) * nx + (uz * wx - ux * wz) * ny
                + (ux * wy - uy * wx) * nz) / length
        least = min(least, side)
    return least
