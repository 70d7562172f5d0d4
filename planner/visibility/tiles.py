"""Tiles: a few candidates with the part of the model their pairs can reach, to be
computed on another machine (:mod:`planner.scaleout`) with the same result as at home.

A *tile* is some candidates of a plan (a contiguous block of them for the coverage table:
candidates come in grid and storey order, so a block stands close together) and what their
pair search of reach ``reach_m`` needs:

- the *targets*: every target face whose centroid lies within ``reach_m`` of one of the
  tile's candidates. The limits kernel rejects every pair farther than the reach before
  any other test (:mod:`planner.visibility.pairs`), so no other face can qualify. Faces
  keep the model's order (a tile's faces are the model's, ascending), their corners'
  float64 coordinates (so their centroids) and the model's normals and areas, so the
  kernel makes the same tests;
- the *occluders*: the faces the rays are tested against, whole. With ``occluders``
  "file" (the default) on a split model these are the file's faces, as read, before the
  split: a small part of the model (the 9.7 M-face office is split from far fewer). On an
  unsplit model (or ``occluders`` "remeshed") they are every occluding face of the scene.

Why the occluders are not cut to the tile's reach as well: Embree reports, of two faces a
ray meets at exactly the same float32 distance (a window member flush with its wall, a
duplicated surface), the one its BVH's traversal reaches first. A BVH over a part of the
faces traverses differently: on IfcOpenHouse, 81 of one candidate's 19,559 rays changed
their verdict against a BVH of the occluders within reach. Over the same faces in the same
order Embree builds the same BVH, so the tile's verdicts are the model's, and so are the
clear margin and the quads (:class:`~planner.rays.embree.BvhPart`).

A tile whose targets are many is cut in *parts* (:meth:`TileCutter.cut_parts`): each
with all the tile's candidates and some of its targets, the pieces of whole file faces in
the file's order (so a part's bundles are the tile's). Which pairs qualify is decided
pair by pair, so the parts' pairs together are the tile's, and so are each candidate's
rows; a part is as big as the budget, whatever the reach takes in.

The occluders are the same for every tile of a plan, so on a split model they travel apart
(:class:`Occluders`, :meth:`Tile.detached`): a worker receives the file's mesh once and
builds one BVH over it, in the file's order, for all the plan's tiles it runs.

Bundles are made from the tile's pieces: a bundle may hold fewer pieces than in the model,
which changes how many rays rule pieces out, never which pairs qualify
(:mod:`planner.visibility.bundles`). The tile's qualified pairs, numbered back to the
model's candidates and faces, are therefore the model's, in the same order.

Array letters: C candidates, F faces, n a tile's candidates, f its faces.
"""

from __future__ import annotations

import copy
import dataclasses
import threading
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from typing import Any

import numba
import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from planner.limits import FaceLimits
from planner.memory import release_freed_memory
from planner.rays.embree import BvhFaces, BvhPart, EmbreeBvh, EmbreeOcclusion
from planner.scene import Scene, compact_indices, unit_normals
from planner.visibility.bundles import bundle_culler
from planner.visibility.cells import PointGrid, Points, point_xyz
from planner.visibility.coverage import QualifiedPairs
from planner.visibility.overlap import overlap_row
from planner.visibility.pairs import PairFinder
from planner.visibility.qualify import qualify_pairs


@dataclass(frozen=True, eq=False)
class Tile:
    """Candidates of a plan and the part of its model their searches can meet.

    Attributes
    ----------
    scene : the part: the target pieces within reach (and every occluding piece, when
        the rays meet the pieces), with the file's mesh (whole, when the rays meet it;
        left out of a :meth:`detached` tile)
    limits : the part's limits; targets are only the faces within reach
    faces : (f,) int32, each face of the part's index in the model, ascending
    positions : (n, 3) float64, the tile's candidates
    candidates : (n,) int64, their indices in the plan, ascending
    reach_m : the model's pair search reach
    file_faces : the rays meet the file's faces (``occluders`` "file" on a split model)
    bvh : what makes the part's BVH decide as the model's
    """

    scene: Scene
    limits: FaceLimits
    faces: NDArray[np.int32]
    positions: NDArray[np.float64]
    candidates: NDArray[np.int64]
    reach_m: float
    file_faces: bool
    bvh: BvhPart

    def occlusion(self, occluders: Occluders | None = None) -> EmbreeOcclusion:
        """The occlusion test over the part, deciding as the model's: over the BVH of
        ``occluders`` (shared by the tiles of a worker) when given, else over its own."""
        return EmbreeOcclusion(self.scene, self.limits.occludes, file_faces=self.file_faces,
                               part_of=self.bvh,
                               bvh=None if occluders is None else occluders.bvh())

    def detached(self) -> Tile:
        """The tile without the file's mesh and which of its faces occlude (what
        :meth:`TileCutter.occluders` holds), and without its faces' areas and normals
        (what its vertices give again, the same bits: each face's arithmetic is the
        model's, whatever faces stand beside it): what travels in a task, valid again once
        :meth:`attached` to the occluders on the worker."""
        if self.scene.file_faces is None or self.bvh.bvh_occludes is None:
            return self
        scene = copy.copy(self.scene)
        for name in ("file_vertices", "file_faces", "file_normals", "areas"):
            object.__setattr__(scene, name, None)
        return dataclasses.replace(self, scene=scene,
                                   bvh=dataclasses.replace(self.bvh, bvh_occludes=None))

    def attached(self, occluders: Occluders) -> Tile:
        """The :meth:`detached` tile with the file's mesh of ``occluders`` (the same arrays,
        not copies), its faces' areas derived again and its file faces'
        normals the occluders' (derived once on a worker)."""
        scene = self.scene.over_file_mesh(occluders.vertices, occluders.faces,
                                          occluders.normals())
        return dataclasses.replace(self, scene=scene, bvh=occluders.part)

    @property
    def nbytes(self) -> int:
        """The size of the tile's arrays (what a worker receives)."""
        scene = self.scene
        arrays: list[NDArray[Any] | None] = [
            scene.vertices, scene.faces, scene.source_face, scene.file_face_group,
            scene.file_face_element, scene.file_normals, scene.areas,
            scene.file_vertices, scene.file_faces, self.faces, self.positions,
            self.candidates, self.limits.target, self.limits.occludes,
            self.limits.min_density_pts_m2, self.limits.min_incidence_deg,
            self.bvh.bvh_occludes]
        return int(sum(a.nbytes for a in arrays if a is not None))


class Occluders:
    """The file's mesh a split model's rays meet, whole, and which of its faces occlude
    (:class:`~planner.rays.embree.BvhPart`): what every tile of a plan shares, sent to a
    worker once rather than in each task (:mod:`planner.scaleout`).

    :meth:`bvh` builds the Embree BVH over the occluding faces in the file's order (the
    model's BVH, so the model's verdicts) the first time a tile asks, and keeps it while
    this object lives: on a Dask worker, as long as the worker holds it for the plan.
    Pickling carries the arrays only.

    Attributes
    ----------
    vertices : (V0, 3) float64, the file's vertices
    faces : (F0, 3) int32, the file's faces
    part : which faces occlude, the model's clear margin and quads
    """

    def __init__(self, vertices: NDArray[np.float64], faces: NDArray[np.int32],
                 part: BvhPart) -> None:
        if part.bvh_occludes is None or len(part.bvh_occludes) != len(faces):
            raise ValueError("the occluders need one occluding flag per file face")
        self.vertices = vertices
        self.faces = faces
        self.part = part
        self._bvh: EmbreeBvh | None = None
        self._normals: NDArray[np.float64] | None = None
        self._lock = threading.Lock()

    def __reduce__(self) -> tuple[type[Occluders], tuple[NDArray[np.float64],
                                                         NDArray[np.int32], BvhPart]]:
        return (Occluders, (self.vertices, self.faces, self.part))

    def bvh(self) -> EmbreeBvh:
        """The BVH over the occluding faces, built once."""
        with self._lock:
            if self._bvh is None:
                assert self.part.bvh_occludes is not None
                self._bvh = EmbreeBvh(self.vertices, self.faces, self.part.bvh_occludes,
                                      scale_m=self.part.scale_m, quads=self.part.quads)
            return self._bvh

    def normals(self) -> NDArray[np.float64]:
        """(F0, 3) the file faces' unit normals (its tiles' pieces share them), derived
        once."""
        with self._lock:
            if self._normals is None:
                self._normals = unit_normals(self.vertices, self.faces)
                self._normals.flags.writeable = False
            return self._normals

    @property
    def nbytes(self) -> int:
        """The size of the arrays (what a worker receives once)."""
        assert self.part.bvh_occludes is not None
        return int(self.vertices.nbytes + self.faces.nbytes + self.part.bvh_occludes.nbytes)


class TileCutter:
    """Cuts tiles of a model for pair searches of ``reach_m`` (targets: ``limits.target``)
    whose rays are tested by ``occlusion`` (over the faces where ``occludes``)."""

    def __init__(self, scene: Scene, limits: FaceLimits, occludes: NDArray[np.bool_],
                 occlusion: EmbreeOcclusion, reach_m: float) -> None:
        self.scene = scene
        self.limits = limits
        self.occludes = occludes
        self.reach_m = reach_m
        self.bvh: BvhFaces = occlusion.bvh_faces()
        self._targets = np.flatnonzero(limits.target).astype(np.int32)
        self._centroids = Points.face_centroids(scene)
        self._target_grid = PointGrid.of(self._centroids, self._targets, reach_m)
        # the rays meet the file's faces: the part holds the file's whole mesh, and which
        # of its faces occlude (the pieces of the part do not say it for the others)
        self._file_bvh = self.bvh.file_faces and scene.file_faces is not None
        self._bvh_occludes: NDArray[np.bool_] | None = None
        if self._file_bvh:
            self._bvh_occludes = np.zeros(len(self.bvh.faces), bool)
            self._bvh_occludes[self.bvh.occluding] = True
        # else the rays meet the scene's own faces: every occluding one is in every part
        self._occluding = np.flatnonzero(occludes).astype(np.int64)

    def occluders(self) -> Occluders | None:
        """What every tile of this cutter shares and :meth:`Tile.detached` leaves out (the
        file's mesh, when the rays meet it), None when the tiles hold their occluders."""
        file_vertices, file_faces = self.scene.file_vertices, self.scene.file_faces
        if not self._file_bvh or file_vertices is None or file_faces is None:
            return None
        return Occluders(file_vertices, file_faces,
                         BvhPart(self._bvh_occludes, self.bvh.scale_m, self.bvh.quads,
                                 self.bvh.exact))

    def cut(self, candidates: NDArray[np.int64], positions: NDArray[np.float64], *,
            detached: bool = False) -> Tile:
        """The tile of the plan's ``candidates`` (ascending) at the (n, 3) ``positions``
        (:meth:`Tile.detached` with ``detached``, without gathering what it leaves out)."""
        return self._cut(candidates, positions, self._within_reach(positions), detached)

    def cut_parts(self, candidates: NDArray[np.int64], positions: NDArray[np.float64],
                  most_faces: int, *, detached: bool = False) -> Iterator[tuple[Tile, bool]]:
        """The tile of :meth:`cut` in parts of about ``most_faces`` targets at most, each
        with whether it is the last part: each part holds all the candidates and some of
        their targets (the pieces of whole file faces, in the file's order, see
        :func:`target_parts`), and the parts' pairs (rows) together are the tile's. Parts
        are cut as they are asked for. Only a tile whose rays meet the file's mesh is cut
        in parts (another holds every occluding face of the model in each part)."""
        targets = self._within_reach(positions)
        if not self._file_bvh or len(targets) <= most_faces:
            yield self._cut(candidates, positions, targets, detached), True
            return
        parts = target_parts(targets, self.scene.source_face, most_faces)
        # the tile's vertices, renumbered once: a part's are then renumbered among these,
        # not among every vertex of the model
        corners = compact_indices(self.scene.faces[targets], len(self.scene.vertices))
        while parts:
            ids = parts.pop(0)
            yield self._cut(candidates, positions, targets[ids], detached,
                            (corners[0], corners[1][ids])), not parts

    def _within_reach(self, positions: NDArray[np.float64]) -> NDArray[np.int64]:
        """(k,) int64, ascending: the target faces whose centroids lie within reach of one
        of the (n, 3) ``positions``."""
        low, high = positions.min(axis=0), positions.max(axis=0)
        # the targets within reach (with a hair of slack: the kernel decides the rest)
        reach = self.reach_m * (1 + 1e-6) + 1e-9
        near = self._targets[_in_box(self._target_grid, low - reach, high + reach)]
        return np.sort(near[_within(self._centroids, near, positions, low, high, reach)]
                       ).astype(np.int64)

    def _cut(self, candidates: NDArray[np.int64], positions: NDArray[np.float64],
             targets: NDArray[np.int64], detached: bool,
             corners: tuple[NDArray[np.int64], NDArray[np.int32]] | None = None) -> Tile:
        """The tile of ``candidates`` at ``positions`` with the (k,) ascending ``targets``
        (``corners``: see :func:`_part_scene`)."""
        scene, limits, bvh = self.scene, self.limits, self.bvh
        faces = targets if self._file_bvh else np.union1d(targets, self._occluding)
        # a detached tile's faces travel without their centroids, normals and areas
        bare = detached and self._file_bvh and scene.file_faces is not None
        part = _part_scene(scene, faces, keep_file_mesh=self._file_bvh, face_values=not bare,
                           corners=corners)
        target = np.zeros(len(faces), bool)
        target[np.searchsorted(faces, targets)] = True
        part_limits = dataclasses.replace(
            limits,
            min_incidence_deg=np.ascontiguousarray(limits.min_incidence_deg[faces]),
            min_density_pts_m2=np.ascontiguousarray(limits.min_density_pts_m2[faces]),
            target=target & limits.target[faces],
            occludes=np.ascontiguousarray(self.occludes[faces]))
        tile = Tile(part, part_limits, faces.astype(np.int32),
                    np.ascontiguousarray(positions, np.float64),
                    np.asarray(candidates, np.int64), self.reach_m, bvh.file_faces,
                    BvhPart(self._bvh_occludes, bvh.scale_m, bvh.quads, bvh.exact))
        return tile.detached() if detached else tile


def target_parts(targets: NDArray[np.int64], source_face: NDArray[np.int32],
                 most_faces: int) -> list[NDArray[np.intp]]:
    """The (k,) ascending ``targets`` in parts of about ``most_faces`` at most, each given
    by its places in ``targets`` (ascending): the pieces of one file face (``source_face``:
    (F,) int32, each face's file face) stay in one part, so a part's bundles are the
    tile's, and the parts follow the file's faces in order (a building's elements one after
    another: a part stands in a few of them). A part exceeds ``most_faces`` by less than
    its last file face's pieces; one part when the targets are no more than
    ``most_faces``."""
    most_faces = max(1, most_faces)
    if len(targets) <= most_faces:
        return [np.arange(len(targets))]
    # as many parts as the budget asks for, of about the same size each
    size = -(-len(targets) // -(-len(targets) // most_faces))
    source = source_face[targets]
    pieces = np.bincount(source)  # (F0',) the targets' pieces of each file face
    before = np.cumsum(pieces) - pieces  # (F0',) the targets of the file faces before
    part = before[source] // size  # (k,) by where its file face starts
    del source, pieces, before
    order = np.argsort(part, kind="stable")  # each part's targets stay ascending
    bounds = np.flatnonzero(np.diff(part[order])) + 1
    return np.split(order, bounds)


def _in_box(grid: PointGrid, low: NDArray[np.float64], high: NDArray[np.float64]
            ) -> NDArray[np.int64]:
    """The members of ``grid`` (positions in its subset) in the cells that meet the box
    from ``low`` to ``high`` (a superset of the points in the box)."""
    first = np.clip(np.floor((low - grid.origin) / grid.cell_m), 0, grid.dims - 1).astype(int)
    last = np.clip(np.floor((high - grid.origin) / grid.cell_m), 0, grid.dims - 1).astype(int)
    parts = []
    for gx in range(first[0], last[0] + 1):
        for gy in range(first[1], last[1] + 1):
            base = (gx * grid.dims[1] + gy) * grid.dims[2]
            parts.append(grid.members[grid.start[base + first[2]]:
                                      grid.start[base + last[2] + 1]])
    return np.concatenate(parts).astype(np.int64) if parts else np.zeros(0, np.int64)


def _part_scene(scene: Scene, faces: NDArray[np.int64], *, keep_file_mesh: bool,
                face_values: bool = True,
                corners: tuple[NDArray[np.int64], NDArray[np.int32]] | None = None) -> Scene:
    """The part of ``scene`` of its ``faces`` (ascending): with ``keep_file_mesh`` (a split
    scene whose rays meet the file's faces) over the file's whole mesh, else over the file
    faces of its own faces; without its faces' centroids, normals and areas unless
    ``face_values`` (see :meth:`Tile.detached`). ``corners``: the faces' corners given
    among a subset of the vertices, the (u,) ascending vertex ids of the subset and the
    (f, 3) int32 corners as indices into it (the same part, renumbered among those)."""
    if corners is None:
        used, triangles = compact_indices(scene.faces[faces], len(scene.vertices))
    else:
        subset, among = corners
        used, triangles = compact_indices(among, len(subset))
        used = subset[used]
    vertices = scene.vertices[used]
    if scene.file_faces is not None and scene.file_vertices is not None:
        if keep_file_mesh:
            file_ids = np.arange(len(scene.file_faces), dtype=np.int64)
            file_vertices, file_faces = scene.file_vertices, scene.file_faces
            file_normals = scene.file_normals
            source = scene.source_face[faces]
        else:
            file_ids = np.unique(scene.source_face[faces]).astype(np.int64)
            file_used, file_faces = compact_indices(scene.file_faces[file_ids],
                                                    len(scene.file_vertices))
            file_vertices = scene.file_vertices[file_used]
            file_normals = scene.file_normals[file_ids]
            source = np.searchsorted(file_ids, scene.source_face[faces]).astype(np.int32)
        fields: dict[str, Any] = {
            "file_face_group": scene.file_face_group[file_ids], "source_face": source,
            "file_face_element": np.full(len(file_ids), -1, np.int32),
            "file_vertices": file_vertices, "file_faces": file_faces}
    else:
        file_normals = scene.file_normals[faces]
        fields = {"file_face_group": scene.file_face_group[faces],
                  "source_face": np.arange(len(faces), dtype=np.int32),
                  "file_face_element": np.full(len(faces), -1, np.int32)}
    # the model's own float64 values, whatever the part's arithmetic would give (and so
    # none of it is done)
    if not face_values:
        return Scene.with_face_values(None, None, vertices=vertices, faces=triangles,
                                      groups=scene.groups, **fields)
    return Scene.with_face_values(
        file_normals, scene.areas[faces],
        vertices=vertices, faces=triangles, groups=scene.groups, **fields)


def _within(xyz: Points, points: NDArray[np.integer[Any]],
            positions: NDArray[np.float64], low: NDArray[np.float64],
            high: NDArray[np.float64], reach: float) -> NDArray[np.bool_]:
    """(k,) bool: which of the (k,) ``points`` (of ``xyz``) lie within
    ``reach`` of one of the (n, 3) ``positions`` (``low`` and ``high``: their box), as a
    k-d tree of the positions finds them. Only the points the cheap bounds leave in doubt
    are looked up in the tree: those clearly within reach of the position nearest the box's
    middle are in, those clearly farther than the reach from the box are out (a margin of
    1e-9 of the reach, far beyond any rounding of the distances, so the tree would decide
    both the same)."""
    middle = positions[np.argmin(((positions - (low + high) / 2) ** 2).sum(axis=1))]
    verdict = np.empty(len(points), np.int8)
    _bounds_verdict(xyz.xyz, xyz.corners, points, middle, low, high,
                    (reach * (1 - 1e-9)) ** 2,
                    (reach * (1 + 1e-9)) ** 2, verdict)
    sure: NDArray[np.bool_] = verdict == _IN
    doubt = np.flatnonzero(verdict == _DOUBT)
    if len(doubt):
        distance, _ = cKDTree(positions).query(xyz.at(points[doubt]),
                                               distance_upper_bound=reach)
        sure[doubt] = np.isfinite(distance)
    return sure


_OUT, _IN, _DOUBT = 0, 1, 2


@numba.njit(nogil=True, cache=True)
def _bounds_verdict(xyz: NDArray[np.float64], corners: NDArray[np.int32],
                    points: NDArray[np.integer[Any]],
                    middle: NDArray[np.float64], low: NDArray[np.float64],
                    high: NDArray[np.float64], inside2: float, outside2: float,
                    verdict: NDArray[np.int8]) -> None:  # compiled; see test_distributed
    """Each point's verdict (into ``verdict``): :data:`_IN` within ``inside2`` (squared)
    of ``middle``, :data:`_OUT` farther than ``outside2`` (squared) from the box from
    ``low`` to ``high``, :data:`_DOUBT` else (points of
    :class:`~planner.visibility.cells.Points` ``xyz``, ``corners``)."""
    point = np.empty(3)
    for i in range(len(points)):
        point[0], point[1], point[2] = point_xyz(xyz, corners, points[i])
        to_middle = 0.0
        to_box = 0.0
        for axis in range(3):
            value = point[axis]
            d = value - middle[axis]
            to_middle += d * d
            if value < low[axis]:
                to_box += (low[axis] - value) ** 2
            elif value > high[axis]:
                to_box += (value - high[axis]) ** 2
        if to_middle <= inside2:
            verdict[i] = _IN
        elif to_box > outside2:
            verdict[i] = _OUT
        else:
            verdict[i] = _DOUBT


def _at_work(tile: Tile, occluders: Occluders | None) -> tuple[Tile, EmbreeOcclusion]:
    """The tile as a task runs it (a :meth:`~Tile.detached` one attached again to its
    ``occluders``) and its occlusion test (over the occluders' shared BVH, if given)."""
    if occluders is not None:
        tile = tile.attached(occluders)
    return tile, tile.occlusion(occluders)


def qualify_tile(tile: Tile, occluders: Occluders | None = None
                 ) -> tuple[QualifiedPairs, int, int]:
    """The qualified pairs of a tile's candidates, numbered by the model's candidates and
    faces and sorted by (candidate, face), with the pairs tested and the rays cast (run
    on a worker: one thread, as the worker runs tasks side by side). A
    :meth:`~Tile.detached` tile comes with its ``occluders``."""
    result = _qualified(*_at_work(tile, occluders))
    release_freed_memory()  # the task's scratch, before the worker's next task
    return result


def _qualified(tile: Tile, occlusion: EmbreeOcclusion) -> tuple[QualifiedPairs, int, int]:
    parts, tested, rays = [], 0, 0
    for qualified, block_tested, block_rays in qualify_pairs(
            tile.scene, tile.positions, tile.limits, occlusion, threads=1,
            reach_m=tile.reach_m):
        parts.append(qualified)
        tested += block_tested
        rays += block_rays
    merged = QualifiedPairs.concatenate(parts)
    return (QualifiedPairs(tile.candidates[merged.candidate].astype(np.int32),
                           tile.faces[merged.face], merged.lpd_pts_m2), tested, rays)


def overlap_tile(tile: Tile, occluders: Occluders | None = None
                 ) -> tuple[list[NDArray[np.int32]], int]:
    """The overlap rows of a tile's candidates (its limits are the overlap limits, its
    occluders the rows'), each the model's faces ascending, and the rays cast. A
    :meth:`~Tile.detached` tile comes with its ``occluders``."""
    result = _rows(*_at_work(tile, occluders))
    release_freed_memory()  # the task's scratch, before the worker's next task
    return result


def _rows(tile: Tile, occlusion: EmbreeOcclusion) -> tuple[list[NDArray[np.int32]], int]:
    culler = bundle_culler(tile.scene, tile.reach_m, occlusion)
    finder = PairFinder(tile.scene, tile.limits, reach_m=tile.reach_m,
                        bundle_of=None if culler is None else culler.bundles.bundle_of)
    rows, rays = [], 0
    for index in range(len(tile.positions)):
        faces, cast = overlap_row(finder, culler, occlusion, tile.positions, tile.scene,
                                  index)
        rows.append(tile.faces[faces])
        rays += cast
    return rows, rays


def contiguous_tiles(n_candidates: int, size: int) -> Iterable[NDArray[np.int64]]:
    """Blocks of ``size`` consecutive candidates (the last one shorter)."""
    for start in range(0, n_candidates, size):
        yield np.arange(start, min(start + size, n_candidates), dtype=np.int64)
