"""Bundles: the pieces of one file face in a small square, ruled out by four rays.

A model split into 0.2 m pieces has hundreds of pieces per wall, and from a station most
walls within the overlap reach (25 m) lie in other rooms: every one of their pieces passes
the analytic limits and costs a ray that ends in a wall between. A *bundle* is the pieces
of one file face whose centroids fall in one square of that face's plane (sides
:data:`BUNDLE_SIDES_M`, coarse to fine, nested); its *corners* are the corners of the
smallest rectangle (in the plane's own axes) around those centroids. Four rays, from a
candidate to the corners, rule out the whole bundle when they all hit the same occluding
triangle T *clearly*:

- each hit lies more than the clear margin inside every edge of T (the margin Embree's
  rounding cannot cross, as for a single ray in :mod:`planner.rays.embree`);
- the candidate lies more than the margin in front of T's plane, and each corner more
  than the margin behind it.

Then every ray from the candidate to a point of the rectangle crosses T's plane inside T
(the crossing points of the four rays span a convex region inside T, and T is convex) and
before its target (the rectangle lies behind the plane, corners and all): a ray to any
piece of the bundle hits T first, in float64 and in either float32 mode, so the piece's
verdict is "hidden" exactly as its own ray would give.

T may also be the convex quad of two triangles of one plane that share their longest
edge (:func:`planner.rays.embree.quad_partners`: a wall's rectangle, whose diagonal
would otherwise split most bundles behind it), when the four rays hit one or the other;
the margins are then taken from the quad's outer edges. A ray that crosses the quad well
inside them hits one of the two triangles in Embree's robust (watertight) mode; where the
fast mode slips through the shared diagonal the two casts disagree and float64 decides,
with edges widened, that the ray is hidden, so again the verdict is "hidden".

The pieces of a bundle ruled out are left out before the analytic limits are even
computed; nothing else changes, so the qualified pairs are the same
(``tests/planner/test_bundles.py`` compares them). A bundle not ruled out has its quarters
tried, down to the finest side; then its pieces get their own rays.

Array letters: F faces, K bundles, B candidates of a block, P (candidate, bundle) pairs.
"""

from __future__ import annotations

import threading
import weakref
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numba
import numpy as np
from numpy.typing import NDArray

from planner.scene import Scene
from planner.threads import in_block_order
from planner.visibility.cells import PointGrid, Points, pairs_in_reach
from planner.visibility.solids import ClosedShells, closed_shells

# sides of the bundles' squares in their face's plane, coarse to fine: a 2 m square of a
# wall two rooms away usually fits behind one triangle of the wall between; where it does
# not, its four 1 m quarters are tried, then their 0.5 m quarters, then the pieces
BUNDLE_SIDES_M = (2.0, 1.0, 0.5)
# bundles pay where a search reaches into other rooms. Measured on generated IFC offices:
# the overlap search (25 m at the default overlap density) of 40 stations of a 2-storey
# office (1.28 M pieces) 37.5 M rays and 7.5 CPU s without bundles, 13.7 M rays and 3.2 s
# with; the coverage search (4.7 m) of 497 of the 2,977 candidates of a larger one (3.7 M
# pieces) 32.5 M rays and 8.7 CPU s without, 24.5 M rays and 7.6 s with (27.1 M and 8.2 s
# before bundles could hide behind a quad, when they did not pay at this reach)
BUNDLE_MIN_REACH_M = 4.0
# a bundle of fewer pieces is not worth its four rays: its pieces get their own
MIN_BUNDLE_PIECES = 8
# faces per step when the bundle keys and their sides are computed: bounds the (b, 3) scratch
_KEY_BLOCK_FACES = 1 << 20
# bins per axis of a face's plane at the finest side that a key holds (2 km at 0.5 m; a
# longer face shares its last bin)
_BINS = 1 << 12


@dataclass(frozen=True, eq=False)
class BundleLevel:
    """The bundles of one side (:data:`BUNDLE_SIDES_M`).

    Attributes
    ----------
    corners : (K, 4, 3) float64, each bundle's rectangle (metres, plan frame)
    centre : (K, 3) float64, the rectangle's centre
    radius_m : (K,) float64, from the centre to the farthest corner
    pieces : (K,) int64, how many faces the bundle holds
    parent : (K,) int64, the bundle of the next coarser level that holds it (the coarsest
        level: -1)
    """

    corners: NDArray[np.float64]
    centre: NDArray[np.float64]
    radius_m: NDArray[np.float64]
    pieces: NDArray[np.int64]
    parent: NDArray[np.int64]

    def __len__(self) -> int:
        return len(self.radius_m)


@dataclass(frozen=True, eq=False)
class Bundles:
    """The bundles of a scene, level by level from coarse to fine.

    Attributes
    ----------
    bundle_of : (F,) int32, each face's bundle of the finest level, -1 for a face in none
        (a degenerate file face, or one of fewer than :data:`MIN_BUNDLE_PIECES` pieces)
    levels : one :class:`BundleLevel` per side of :data:`BUNDLE_SIDES_M`
    """

    bundle_of: NDArray[np.int32]
    levels: tuple[BundleLevel, ...]

    def __len__(self) -> int:
        return len(self.levels[-1])


# (F,) int32 the finest bundle of each face (-1: none) and (B, K) bool the finest bundles
# hidden from each of B points
HiddenBundles = tuple[NDArray[np.int32], NDArray[np.bool_]]

_CACHE: weakref.WeakKeyDictionary[Scene, Bundles | None] = weakref.WeakKeyDictionary()
_CACHE_LOCK = threading.Lock()


def bundles_of(scene: Scene) -> Bundles | None:
    """The bundles of ``scene`` (computed once per scene), or None when it has none: a scene
    that was never split has one piece per file face, so nothing to bundle."""
    with _CACHE_LOCK:
        if scene not in _CACHE:
            _CACHE[scene] = _make_bundles(scene) if scene.file_faces is not None else None
        return _CACHE[scene]


def forget_bundles(scene: Scene) -> None:
    """Let the bundles of ``scene`` go (some 10 bytes a piece) while the scene lives on: a
    finished plan keeps its scene for the outputs, which never cast a ray."""
    with _CACHE_LOCK:
        _CACHE.pop(scene, None)


def _plane_axes(scene: Scene) -> tuple[NDArray[np.float64], NDArray[np.float64],
                                       NDArray[np.float64], NDArray[np.bool_]]:
    """Each file face's plane: (F0, 3) origin (its first corner), (F0, 3) unit u along its
    first edge, (F0, 3) unit v = n x u, and (F0,) whether the face has a plane at all."""
    file_vertices, file_faces = scene.file_mesh
    corner = file_vertices[file_faces]  # (F0, 3, 3)
    u_axis = corner[:, 1] - corner[:, 0]
    normal = np.cross(u_axis, corner[:, 2] - corner[:, 0])
    length = np.linalg.norm(u_axis, axis=1)
    doubled = np.linalg.norm(normal, axis=1)
    usable = (length > 0) & (doubled > 0)
    u_axis = np.divide(u_axis, length[:, None], out=np.zeros_like(u_axis),
                       where=usable[:, None])
    normal = np.divide(normal, doubled[:, None], out=np.zeros_like(normal),
                       where=usable[:, None])
    return corner[:, 0].copy(), u_axis, np.cross(normal, u_axis), usable


def _piece_uv(scene: Scene, axes: tuple[NDArray[np.float64], NDArray[np.float64],
                                         NDArray[np.float64], NDArray[np.bool_]], block: slice
              ) -> tuple[NDArray[np.float64], NDArray[np.int32]]:
    """(b, 2) the plane coordinates of a block of faces' centroids, and their file face."""
    origin, u_axis, v_axis, _ = axes
    source = scene.source_face[block]
    offset = scene.centroids_of(block) - origin[source]
    uv = np.stack([np.einsum("ij,ij->i", offset, u_axis[source]),
                   np.einsum("ij,ij->i", offset, v_axis[source])], axis=1)
    return uv, source


def _make_bundles(scene: Scene) -> Bundles | None:
    axes = _plane_axes(scene)
    origin, u_axis, v_axis, usable = axes
    finest = BUNDLE_SIDES_M[-1]
    n = scene.n_faces
    # each piece's key: its file face, then the finest square's bins; the bundles are the
    # distinct keys in ascending order
    bundle_of = np.empty(n, np.int32)  # -1: a piece in no bundle (see below)
    # a file face of fewer than MIN_BUNDLE_PIECES pieces has no bundle that would ever get
    # rays, at any level: its pieces go in no bundle, as a face without a plane. A furnished
    # interior's props (a million file faces of one piece each) then cost no bundles: a
    # 1.06 M-face one kept 3.2 M of them over the three levels (their arrays some 450 MB)
    # for the 2,382 that get rays
    bundled = usable & (scene.pieces_per_file_face() >= MIN_BUNDLE_PIECES)

    def keyed(block: slice) -> tuple[NDArray[np.int64], NDArray[np.int64],
                                     NDArray[np.float64], NDArray[np.float64]]:
        """A block's distinct keys (ascending, the faces in no bundle left out), each
        piece's index among them (-1: in no bundle) and each key's (k, 2) extent."""
        uv, source = _piece_uv(scene, axes, block)
        bins = np.clip(np.floor(uv / finest), 0, _BINS - 1).astype(np.int64)
        key = np.where(bundled[source],
                       (source.astype(np.int64) * _BINS + bins[:, 0]) * _BINS + bins[:, 1], -1)
        keys, inverse = np.unique(key, return_inverse=True)
        first = 1 if len(keys) and keys[0] < 0 else 0  # key -1: faces in no bundle
        index = np.where(key < 0, -1, inverse.reshape(-1) - first)
        low, high = np.full((len(keys) - first, 2), np.inf), np.full((len(keys) - first, 2),
                                                                     -np.inf)
        _extents(index, uv, low, high)
        return keys[first:], index, low, high

    # blocks of whole file faces hold keys no other block has: keyed on the thread pool (no
    # sort of F int64 keys), then numbered one block after the other
    blocks = scene.file_face_blocks(_KEY_BLOCK_FACES)
    block_keys: list[NDArray[np.int64]] = []
    lows: list[NDArray[np.float64]] = []
    highs: list[NDArray[np.float64]] = []
    k = 0
    for block, (keys, index, block_low, block_high) in zip(
            blocks, in_block_order(keyed, blocks), strict=True):
        bundle_of[block] = np.where(index < 0, -1, index + k)
        block_keys.append(keys)
        lows.append(block_low)
        highs.append(block_high)
        k += len(keys)
    if k == 0:
        return None
    keys = np.concatenate(block_keys)
    # the finest bundles' extents in their plane
    low, high = np.concatenate(lows), np.concatenate(highs)
    del lows, highs
    pieces = np.bincount(bundle_of[bundle_of >= 0], minlength=k).astype(np.int64)
    file_face = keys // (_BINS * _BINS)
    bins = np.stack([(keys // _BINS) % _BINS, keys % _BINS], axis=1)
    # coarser levels: a square of side finest * 2^j holds the finest bins >> j (nested)
    levels: list[BundleLevel] = []
    coarser_of: NDArray[np.intp] | None = None  # (K,) each finest bundle's, a level up
    for side in BUNDLE_SIDES_M:
        shift = round(float(np.log2(side / finest)))
        level_key = (file_face * _BINS + (bins[:, 0] >> shift)) * _BINS + (bins[:, 1] >> shift)
        level_keys, member_of = np.unique(level_key, return_inverse=True)
        member_of = member_of.reshape(-1)  # (K,) each finest bundle's at this level
        m = len(level_keys)
        level_low, level_high = np.full((m, 2), np.inf), np.full((m, 2), -np.inf)
        np.minimum.at(level_low, member_of, low)
        np.maximum.at(level_high, member_of, high)
        parent = np.full(m, -1, np.int64)
        if coarser_of is not None:
            parent[member_of] = coarser_of
        levels.append(_level(origin, u_axis, v_axis, level_keys // (_BINS * _BINS),
                             level_low, level_high,
                             np.bincount(member_of, weights=pieces, minlength=m)
                             .astype(np.int64), parent))
        coarser_of = member_of
    return Bundles(bundle_of, tuple(levels))


def _level(origin: NDArray[np.float64], u_axis: NDArray[np.float64],
           v_axis: NDArray[np.float64], source: NDArray[np.int64], low: NDArray[np.float64],
           high: NDArray[np.float64], pieces: NDArray[np.int64], parent: NDArray[np.int64]
           ) -> BundleLevel:
    """A level's rectangles from each bundle's file face and (K, 2) extent in its plane."""
    # the corners in order around the rectangle: (u0, v0), (u1, v0), (u1, v1), (u0, v1)
    us = np.stack([low[:, 0], high[:, 0], high[:, 0], low[:, 0]], axis=1)  # (K, 4)
    vs = np.stack([low[:, 1], low[:, 1], high[:, 1], high[:, 1]], axis=1)
    corners = (origin[source][:, None, :] + us[:, :, None] * u_axis[source][:, None, :]
               + vs[:, :, None] * v_axis[source][:, None, :])
    centre = corners.mean(axis=1)
    radius_m = np.linalg.norm(corners - centre[:, None, :], axis=2).max(axis=1)
    return BundleLevel(corners, centre, radius_m, pieces, parent)


@runtime_checkable
class BundleRays(Protocol):
    """The occlusion's side of bundling: whether four rays rule a bundle out."""

    def bundles_hidden(self, origins: NDArray[np.float64], corners: NDArray[np.float64]
                       ) -> NDArray[np.bool_]:
        """(P,) bool: from each of the (P, 3) origins, are the (P, 4, 3) corners all behind
        one occluding triangle or quad, clearly (see the module docstring)?"""
        ...


class BundleCuller:
    """Which bundles are hidden from a block of candidates, for a pair search of reach
    ``reach_m``: the coarsest bundles within reach first, then the quarters of those not
    ruled out, down to the finest level (a bundle inside a hidden one is hidden)."""

    def __init__(self, bundles: Bundles, reach_m: float, rays: BundleRays,
                 shells: ClosedShells | None = None,
                 normals_of: Callable[[NDArray[np.int64]], NDArray[np.float64]] | None = None
                 ) -> None:
        """``shells`` and the scene's ``normals_of`` ((k,) faces -> (k, 3) unit normals,
        :meth:`planner.scene.Scene.normals_of`): a bundle whose pieces all lie on
        one closed shell, far from its other faces (``shells.side``), is hidden from a point
        outside every shell and behind the bundle's plane, without rays (the rule of
        :mod:`planner.visibility.solids`, which holds for each of its pieces)."""
        self.bundles = bundles
        self.reach_m = reach_m
        self._rays = rays
        # the shells and, per level, each bundle's shared side and normal
        self._shelled = None if shells is None or normals_of is None else (
            shells, _level_sides(bundles, shells, normals_of))
        self._searches = [_LevelSearch.of(level, side, reach_m)
                          for level, side in zip(bundles.levels, BUNDLE_SIDES_M, strict=True)]

    def hidden(self, points: NDArray[np.float64]) -> tuple[HiddenBundles, int]:
        """The bundles hidden from each of the (B, 3) ``points`` (for
        :meth:`planner.visibility.pairs.PairFinder.find`), and the number of rays cast."""
        points = np.asarray(points, np.float64)
        hidden = np.zeros((len(points), 0), bool)
        rays = 0
        shelled = self._shelled
        outside = None if shelled is None else shelled[0].outside(points)  # (B,)
        for index, (level, search) in enumerate(zip(self.bundles.levels, self._searches,
                                                    strict=True)):
            # (B, K) hidden inside a hidden bundle of the level above
            hidden = (hidden[:, level.parent] if hidden.shape[1]
                      else np.zeros((len(points), len(level)), bool))
            point, bundle = search.pairs(points, len(level))
            todo = ~hidden[point, bundle]
            point, bundle = point[todo], bundle[todo]
            if shelled is not None and outside is not None:
                shells, (side, normal) = shelled[0], shelled[1][index]
                # how far each point lies behind its bundle's plane, out of the shell
                behind_m = side[bundle] * np.einsum(
                    "ij,ij->i", level.corners[bundle, 0] - points[point], normal[bundle])
                inside = outside[point] & (side[bundle] != 0) & (behind_m > shells.margin_m)
                hidden[point[inside], bundle[inside]] = True
                point, bundle = point[~inside], bundle[~inside]
            if len(point):
                ruled_out = self._rays.bundles_hidden(points[point], level.corners[bundle])
                hidden[point[ruled_out], bundle[ruled_out]] = True
                rays += 4 * len(point)
        return (self.bundles.bundle_of, hidden), rays


# the bundles of a level are searched in classes of radius: class 0 up to the half
# diagonal of the level's square (a bundle's rectangle bounds centroids inside its square),
# class c up to 2^c times that (a face whose corners lie before its first corner along its
# first edge has its nearest bins clipped: long thin triangles make bundles metres long)
_RADIUS_CLASS_SLACK = 1.0 + 1e-6


@dataclass(frozen=True, eq=False)
class _RadiusClass:
    """Bundles of one class of radius in a grid for the reach plus their largest radius."""

    bundle: NDArray[np.int64]  # (k,) the bundles, ascending
    centre: NDArray[np.float64]  # (k, 3)
    radius_m: NDArray[np.float64]  # (k,)
    grid: PointGrid


@dataclass(frozen=True, eq=False)
class _LevelSearch:
    """Which bundles of a level come within reach of a point, for the culler.

    Only bundles of :data:`MIN_BUNDLE_PIECES` or more take part (the others never get
    rays: a plan of a furnished interior has a bundle per prop triangle, a million of
    them, each of a single piece), and they are searched in classes of radius, each in a
    grid of cells the reach plus the class's own largest radius wide (one grid for the
    largest radius of the level made every point scan cells sized for a few bundles
    metres long). The pairs are those of one search over all bundles with that many
    pieces, in the same order (by point, then bundle)."""

    classes: tuple[_RadiusClass, ...]
    reach_m: float

    @classmethod
    def of(cls, level: BundleLevel, side_m: float, reach_m: float) -> _LevelSearch:
        eligible = np.flatnonzero(level.pieces >= MIN_BUNDLE_PIECES)
        radius = level.radius_m[eligible]
        nominal = side_m / np.sqrt(2.0) * _RADIUS_CLASS_SLACK
        radius_class = np.ceil(np.log2(np.maximum(radius / nominal, 1.0))).astype(np.int64)
        classes = []
        for c in np.unique(radius_class):
            members = eligible[radius_class == c]
            centre = np.ascontiguousarray(level.centre[members])
            radius_m = level.radius_m[members]
            grid = PointGrid.of(Points.rows(centre), np.arange(len(members), dtype=np.int32),
                                reach_m + float(radius_m.max()))
            classes.append(_RadiusClass(members, centre, radius_m, grid))
        return cls(tuple(classes), reach_m)

    def pairs(self, points: NDArray[np.float64], n_bundles: int
              ) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """(P,) point and (P,) bundle of every bundle that comes within reach of one of the
        (B, 3) ``points``, by point, then bundle (``n_bundles``: the level's)."""
        found = []
        for radius_class in self.classes:
            point, k = pairs_in_reach(points, radius_class.centre, radius_class.radius_m,
                                      self.reach_m, radius_class.grid)
            found.append((point, radius_class.bundle[k]))
        if not found:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        if len(found) == 1:
            return found[0]
        point = np.concatenate([p for p, _ in found])
        bundle = np.concatenate([b for _, b in found])
        order = np.argsort(point * n_bundles + bundle, kind="stable")
        return point[order], bundle[order]


def bundle_culler(scene: Scene, reach_m: float, occlusion: object, *,
                  always: bool = False) -> BundleCuller | None:
    """A culler for a pair search of ``reach_m`` on ``scene`` with ``occlusion``; None when
    the scene has no bundles, the occlusion cannot rule bundles out (the brute force), or
    the reach is short of :data:`BUNDLE_MIN_REACH_M` (unless ``always``)."""
    if not isinstance(occlusion, BundleRays) or (reach_m < BUNDLE_MIN_REACH_M and not always):
        return None  # decided before the bundles are made: a short search never needs them
    bundles = bundles_of(scene)
    return None if bundles is None else BundleCuller(
        bundles, reach_m, occlusion, closed_shells(scene, occlusion), scene.normals_of)


_SIDES: weakref.WeakKeyDictionary[
    Bundles, tuple[ClosedShells, list[tuple[NDArray[np.int8], NDArray[np.float64]]]]] = \
    weakref.WeakKeyDictionary()


def _level_sides(bundles: Bundles, shells: ClosedShells,
                 normals_of: Callable[[NDArray[np.int64]], NDArray[np.float64]]
                 ) -> list[tuple[NDArray[np.int8], NDArray[np.float64]]]:
    """Per level, (K,) the side every piece of each bundle shares (``shells.side`` of its
    faces, 0 where they differ) and (K, 3) its pieces' normal (a bundle is of one file face,
    one plane); made once per bundles and shells (a plan's tolerance makes a culler per
    station)."""
    with _CACHE_LOCK:
        kept = _SIDES.get(bundles)
        if kept is not None and kept[0] is shells:
            return kept[1]
    finest = bundles.bundle_of
    n = len(bundles.levels[-1])
    # per bundle, its pieces and those facing out (+1) and in (-1) of their shell (whole
    # counts in float64, as np.bincount's weighted sums give them), and the normal of its
    # last piece; counted a block of pieces at a time, in order, so that no (F, 3) array of
    # the normals is made (92 MB on a 3.8 M-face sports hall, the peak of its visibility)
    total: NDArray[Any] = np.zeros(n)
    out: NDArray[Any] = np.zeros(n)
    into: NDArray[Any] = np.zeros(n)
    normal = np.zeros((n, 3))
    for start in range(0, len(finest), _KEY_BLOCK_FACES):
        faces = start + np.flatnonzero(finest[start:start + _KEY_BLOCK_FACES] >= 0)
        bundle, side = finest[faces], shells.side[faces]
        total += np.bincount(bundle, minlength=n)
        out += np.bincount(bundle, weights=side == 1, minlength=n)
        into += np.bincount(bundle, weights=side == -1, minlength=n)
        normal[bundle] = normals_of(faces)
    sides = []
    for index in range(len(bundles.levels) - 1, -1, -1):
        shared = np.where(total == 0, 0, np.where(out == total, 1, np.where(
            into == total, -1, 0))).astype(np.int8)
        sides.append((shared, normal))
        if index == 0:
            break
        parent = bundles.levels[index].parent
        k = len(bundles.levels[index - 1])
        total, out, into = (np.bincount(parent, weights=x, minlength=k)
                            for x in (total, out, into))
        up_normal = np.zeros((k, 3))
        up_normal[parent] = normal
        normal = up_normal
    sides = sides[::-1]
    with _CACHE_LOCK:
        _SIDES[bundles] = (shells, sides)
    return sides


@numba.njit(nogil=True, cache=True)
def _extents(index: NDArray[np.int64], uv: NDArray[np.float64], low: NDArray[np.float64],
             high: NDArray[np.float64]) -> None:  # compiled; see test_bundles
    """The (k, 2) ``low`` and ``high`` corners of the (n, 2) ``uv`` of each of k groups
    (``index``: each point's group, -1 for none), lowered and raised in place."""
    for i in range(len(index)):
        g = index[i]
        if g < 0:
            continue
        for axis in range(2):
            value = uv[i, axis]
            if value < low[g, axis]:
                low[g, axis] = value
            if value > high[g, axis]:
                high[g, axis] = value
