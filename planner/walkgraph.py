"""Where a person with a tripod can walk: a graph of floor samples built from the model.

Floor samples: a grid of vertical rays (``WALK_GRID_M`` apart) is cast down through the
whole model, level after level; a hit on a face flatter than ``MAX_WALK_SLOPE_DEG`` with
``HEADROOM_M`` free above it is a node. Two nodes in neighbouring grid columns (8
neighbours) are linked when their floor heights differ by at most ``STEP_M`` and the
straight segment between them hits nothing at ``KNEE_HEIGHT_M`` above the floor nor at any
of ``UPRIGHT_HEIGHTS_M`` up to head height (:func:`upright_free`: a person walks it
upright, not under a stair's flight or a beam lower than head room). The link costs its
3D length. So, without any IFC semantics:

- stairs join storeys whether modelled as steps (a riser is at most ``STEP_M`` between
  samples), as a sloped solid or as a ramp (up to ``MAX_WALK_SLOPE_DEG``, steeper than any
  stair: a ship's ladder or a wall is not walked);
- doors are passable whatever the leaf's modelled position: the walk rays skip door faces
  (:func:`door_faces`: IFC doors by class; in a plain mesh a closed leaf in a wall opening,
  found by :func:`mesh_door_faces`). IfcOpeningElement voids are never part of the mesh;
- around the outside at ground level: in a model without terrain, the ground plane at the
  ground floor (the lowest floor sample with something over it next to a column with
  nothing in it, a threshold; without one the lowest floor sample with something over it)
  is walkable outside the footprint and ``OUTSIDE_MARGIN_M`` around the model (*ground
  nodes*, after the model's own nodes), wherever a column has no surface below that
  height plus ``HEADROOM_M``; a model with its own terrain is walked on that terrain
  instead. Units or wings joined only through their front doors are joined.

Array letters: N nodes, E links.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from planner.rays import RayCaster
from planner.scene import Scene

WALK_GRID_M = 0.25  # floor sample spacing; finer than a stair tread (~0.26-0.30 m)
OUTSIDE_MARGIN_M = 1.0  # ground walked around a model without terrain
MAX_COLUMNS = 400_000  # the grid coarsens on very large models to stay within this
KNEE_HEIGHT_M = 0.5  # the link must be free at this height above the floor
# largest floor height change between neighbouring samples: a stair riser is <= 0.19 m in
# most building codes; two risers can fall between samples 0.25 m apart on steep stairs
STEP_M = 0.4
HEADROOM_M = 1.8  # free height a person needs above a floor sample
# a link is walked upright: free from the knee to the head, at these heights above the floor
# (the top 5 cm under HEADROOM_M: a ceiling exactly at head room over a sample is allowed)
UPRIGHT_HEIGHTS_M = (KNEE_HEIGHT_M, 0.8, 1.1, 1.4, HEADROOM_M - 0.05)
# steepest walked surface: a stair modelled as a sloped solid has the stair's pitch, at most
# 42 deg for a private stair (Building Regulations 2010, Approved Document K, 2013 edition,
# Table 1.1 note 1; https://stairplan.com/stair-plan-catalogues/BUILDING-REGULATIONS-
# DOCUMENT-K-2013-STAIRS/WebSearch/page0015.html); steeper than 45 deg is a ladder or a wall
MAX_WALK_SLOPE_DEG = 45.0
_MIN_FLOOR_NZ = math.cos(math.radians(MAX_WALK_SLOPE_DEG))
_LINKS_PER_BLOCK = 1 << 18
_MAX_LEVELS = 32  # surfaces followed down one grid column (slabs, furniture, stairs, roofs)
_EPS_M = 1e-3


# IFC classes modelled closed that a survey crew opens: people walk and scanners see through
OPEN_DOOR_CLASSES = ("IfcDoor",)
# a door leaf in a plain mesh (mesh_door_faces): a thin upright panel of a door's size whose
# two ends meet the jambs of a wall opening
DOOR_THICKNESS_MAX_M = 0.12
DOOR_WIDTH_M = (0.5, 2.6)  # one leaf to a double door
DOOR_HEIGHT_M = (1.8, 2.6)
DOOR_JAMB_GAP_MAX_M = 0.15  # from the panel's end to the jamb, at the panel's mid-height
_DOOR_BOX_M = 1e-3  # a part within a door panel's box, enlarged by this, is the door's


def door_faces(scene: Scene, caster: RayCaster | None = None) -> NDArray[np.bool_]:
    """(F,) bool: faces of doors. IFC models: the faces of ``OPEN_DOOR_CLASSES``
    elements. Plain meshes (no elements): with a ``caster`` over every face, the closed
    leaves in wall openings of :func:`mesh_door_faces`; without one, none."""
    if not scene.elements:
        if caster is None:
            return np.zeros(scene.n_faces, bool)
        return mesh_door_faces(scene, caster)
    door = np.array([e.ifc_class in OPEN_DOOR_CLASSES for e in scene.elements] + [False])
    # -1 picks the trailing False
    result: NDArray[np.bool_] = scene.of_file_faces(door[scene.file_face_element])
    return result


def mesh_door_faces(scene: Scene, caster: RayCaster) -> NDArray[np.bool_]:
    """(F,) bool: the faces of closed door leaves in a mesh without semantics.

    The rule: a *part* (faces joined by shared vertices, in the file's mesh) is a door
    when it is an upright panel (``DOOR_HEIGHT_M`` tall, ``DOOR_WIDTH_M`` wide
    along its main horizontal axis, 96 % of its area within ``DOOR_THICKNESS_MAX_M``
    across it, so handles do not count) and, at its
    mid-height, a horizontal ray from each of its two ends outward along the panel meets
    something within ``DOOR_JAMB_GAP_MAX_M``: the panel fills a gap in a wall. The parts
    inside the panel's box (its edges when an export gives each side its own vertices,
    handles, hinges) are the door's too. A door
    frame exported as a thin part of its own counts too (its faces are the door's, as in
    IFC). A leaf modelled open (swung into the room) does not fill the opening and stays
    an obstacle where it stands; the opening itself is free. A thin partition of door
    size between two walls is taken for a door: a rule from geometry alone cannot tell
    them apart.
    """
    from scipy.sparse.csgraph import connected_components

    vertices, faces = scene.file_mesh
    n_vertices = len(vertices)
    edges = sp.coo_matrix(
        (np.ones(2 * len(faces), np.int8),
         (np.concatenate([faces[:, 0], faces[:, 1]]),
          np.concatenate([faces[:, 1], faces[:, 2]]))),
        shape=(n_vertices, n_vertices))
    n_parts, part_of_vertex = connected_components(edges, directed=False)
    del edges
    lo = np.full((n_parts, 3), np.inf)
    hi = np.full((n_parts, 3), -np.inf)
    np.minimum.at(lo, part_of_vertex, vertices)
    np.maximum.at(hi, part_of_vertex, vertices)
    size = hi - lo
    tall = (size[:, 2] >= DOOR_HEIGHT_M[0]) & (size[:, 2] <= DOOR_HEIGHT_M[1])
    small = np.hypot(size[:, 0], size[:, 1]) <= math.hypot(DOOR_WIDTH_M[1],
                                                            DOOR_THICKNESS_MAX_M)
    door_part = np.zeros(n_parts, bool)
    panels: list[tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], float,
                       float, float, float]] = []
    part_of_face = part_of_vertex[faces[:, 0]]
    by_part = np.argsort(part_of_face, kind="stable")
    first = np.searchsorted(part_of_face[by_part], np.arange(n_parts + 1))
    for part in np.flatnonzero(tall & small):
        panel = vertices[faces[by_part[first[part]:first[part + 1]]]]  # (n, 3, 3)
        area = np.linalg.norm(np.cross(panel[:, 1] - panel[:, 0],
                                       panel[:, 2] - panel[:, 0]), axis=1)
        if area.sum() <= 0:
            continue
        # the panel's axes and thickness by area: a handle or a hinge adds corners, not area
        xy = panel[:, :, :2].reshape(-1, 2)
        weight = np.repeat(area, 3)
        centre = np.average(xy, axis=0, weights=weight)
        offset = xy - centre
        _, axes = np.linalg.eigh((offset * weight[:, None]).T @ offset)
        across, along = axes[:, 0], axes[:, 1]
        thickness = _weighted_spread(offset @ across, weight)
        t = offset @ along
        width = float(np.ptp(t))
        if thickness > DOOR_THICKNESS_MAX_M or not DOOR_WIDTH_M[0] <= width <= DOOR_WIDTH_M[1]:
            continue
        z = (lo[part, 2] + hi[part, 2]) / 2
        ends = np.array([[*(centre + (t.max() + _EPS_M) * along), z],
                         [*(centre + (t.min() - _EPS_M) * along), z]])
        outward = np.array([[*along, 0.0], [*(-along), 0.0]])
        _, gap = caster.first_hit(ends, outward)
        if (gap <= DOOR_JAMB_GAP_MAX_M).all():
            door_part[part] = True
            panels.append((centre, along, across, float(t.min()), float(t.max()),
                           float(lo[part, 2]), float(hi[part, 2])))
    # the rest of a door: the parts within a panel's box (a leaf's edges and top when its
    # sides are parts of their own, handles, hinges)
    small = (size <= DOOR_WIDTH_M[1] + DOOR_THICKNESS_MAX_M).all(axis=1)
    others = np.flatnonzero(small & ~door_part)
    box = np.stack([np.stack([np.where(corner & (1 << axis), hi[others, axis],
                                       lo[others, axis]) for axis in range(3)], axis=1)
                    for corner in range(8)], axis=1)  # (P, 8, 3) box corners of the parts
    for centre, along, across, t_min, t_max, z_min, z_max in panels:
        offset = box[:, :, :2] - centre
        t = offset @ along
        inside = ((t >= t_min - _DOOR_BOX_M) & (t <= t_max + _DOOR_BOX_M)
                  & (np.abs(offset @ across) <= DOOR_THICKNESS_MAX_M)
                  & (box[:, :, 2] >= z_min - _DOOR_BOX_M)
                  & (box[:, :, 2] <= z_max + _DOOR_BOX_M)).all(axis=1)
        door_part[others[inside]] = True
    on_file = door_part[part_of_face]
    result: NDArray[np.bool_] = on_file[scene.source_face] if scene.file_faces is not None \
        else on_file
    return result


def _weighted_spread(values: NDArray[np.float64], weight: NDArray[np.float64]) -> float:
    """Width of the middle 96 % (by ``weight``) of the (n,) ``values``."""
    order = np.argsort(values)
    share = np.cumsum(weight[order]) / weight.sum()
    ranked = values[order]
    low = ranked[int(np.searchsorted(share, 0.02))]
    high = ranked[min(int(np.searchsorted(share, 0.98)), len(values) - 1)]
    return float(high - low)


@dataclass(frozen=True, eq=False)
class WalkGraph:
    """Floor samples and the links between them.

    Attributes
    ----------
    floor_xyz : (N, 3) float64, floor points (metres); the model's own floor samples
        first, then the ground nodes (``n_ground`` of them)
    links : (N, N) CSR float64, symmetric, link length in metres
    """

    floor_xyz: NDArray[np.float64]
    links: sp.csr_matrix
    grid_m: float
    n_ground: int = 0

    @property
    def n_nodes(self) -> int:
        return len(self.floor_xyz)


@dataclass(frozen=True, eq=False)
class _Samples:
    """Floor samples of a grid of columns (see :func:`_floor_samples`)."""

    floor_xyz: NDArray[np.float64]  # (N, 3)
    ix: NDArray[np.int64]  # (N,) grid column of each sample
    iy: NDArray[np.int64]
    covered: NDArray[np.bool_]  # (N,) something over the sample (not open sky)
    lowest_z: NDArray[np.float64]  # (nx, ny) lowest surface of a column; -inf unknown
    nx: int
    ny: int


def _floor_samples(scene: Scene, caster: RayCaster, grid_m: float) -> _Samples:
    """The floor samples of the grid over the model's footprint, ordered by column, then
    height; the lowest surface of every column (+inf: none; -inf: more surfaces than
    followed)."""
    lo, hi = scene.bounds
    nx = math.floor((hi[0] - lo[0]) / grid_m) + 1
    ny = math.floor((hi[1] - lo[1]) / grid_m) + 1
    grid_x, grid_y = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    ix, iy = grid_x.ravel(), grid_y.ravel()
    xy = np.stack([lo[0] + (ix + 0.5) * grid_m, lo[1] + (iy + 0.5) * grid_m], axis=1)
    z = np.full(len(xy), hi[2] + 1.0)
    lowest = np.full(len(xy), np.inf)
    down = np.tile([0.0, 0.0, -1.0], (len(xy), 1))
    up = np.tile([0.0, 0.0, 1.0], (len(xy), 1))
    points: list[NDArray[np.float64]] = []
    columns: list[NDArray[np.int64]] = []
    covered: list[NDArray[np.bool_]] = []
    alive = np.arange(len(xy))
    for _ in range(_MAX_LEVELS):
        origins = np.column_stack([xy[alive], z[alive]])
        face, distance = caster.first_hit(origins, down[alive])
        hit = face >= 0
        alive, face, distance, origins = alive[hit], face[hit], distance[hit], origins[hit]
        if len(alive) == 0:
            break
        floor = origins.copy()
        floor[:, 2] -= distance
        lowest[alive] = floor[:, 2]
        # a face id past the scene's is a floor the walk adds (planner.survey.space_floors)
        horizontal = np.ones(len(face), bool)
        own = face < scene.n_faces
        horizontal[own] = np.abs(scene.normals[face[own], 2]) >= _MIN_FLOOR_NZ
        above = floor + np.array([0.0, 0.0, _EPS_M * 10])
        _, free = caster.first_hit(above, up[: len(above)])
        keep = horizontal & (free >= HEADROOM_M)
        points.append(floor[keep])
        columns.append(alive[keep])
        covered.append(np.isfinite(free[keep]))
        z[alive] = floor[:, 2] - _EPS_M  # continue below this surface
    else:
        lowest[alive] = -np.inf  # surfaces left below: the lowest one is not known
    lowest_z = lowest.reshape(nx, ny)
    if not points:
        return _Samples(np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros(0, np.int64),
                        np.zeros(0, bool), lowest_z, nx, ny)
    floor_xyz = np.concatenate(points)
    column = np.concatenate(columns)
    order = np.lexsort((floor_xyz[:, 2], column))  # by column, then height: deterministic
    floor_xyz, column = floor_xyz[order], column[order]
    return _Samples(floor_xyz, ix[column], iy[column], np.concatenate(covered)[order],
                    lowest_z, nx, ny)


def _ground_nodes(scene: Scene, samples: _Samples, grid_m: float
                  ) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.int64]]:
    """(G, 3) ground nodes and their (G,) grid columns (which may lie outside the model's
    grid, by up to ``OUTSIDE_MARGIN_M``): see the module docstring."""
    covered = samples.covered
    if not covered.any():
        return np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros(0, np.int64)
    nx, ny = samples.nx, samples.ny
    # the ground floor: the lowest indoor floor at the building's edge, next to a column
    # with nothing in it (a threshold); a basement is walled in. Else the lowest indoor floor
    empty = np.ones((nx + 2, ny + 2), bool)  # a ring of empty columns around the grid
    empty[1:-1, 1:-1] = np.isposinf(samples.lowest_z)
    at_edge = np.zeros(len(covered), bool)
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            at_edge |= empty[samples.ix + 1 + dx, samples.iy + 1 + dy]
    edge_floor = covered & at_edge
    ground_z = float(samples.floor_xyz[edge_floor if edge_floor.any() else covered, 2].min())
    margin = math.ceil(OUTSIDE_MARGIN_M / grid_m)
    grid_x, grid_y = np.meshgrid(np.arange(-margin, nx + margin),
                                 np.arange(-margin, ny + margin), indexing="ij")
    ix, iy = grid_x.ravel(), grid_y.ravel()
    inside = (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)
    lowest = np.full(len(ix), np.inf)
    lowest[inside] = samples.lowest_z[ix[inside], iy[inside]]
    free = lowest > ground_z + HEADROOM_M
    ix, iy = ix[free], iy[free]
    lo = scene.bounds[0]
    xyz = np.column_stack([lo[0] + (ix + 0.5) * grid_m, lo[1] + (iy + 0.5) * grid_m,
                           np.full(len(ix), ground_z)])
    return xyz, ix.astype(np.int64), iy.astype(np.int64)


def segment_free(caster: RayCaster, a: NDArray[np.float64], b: NDArray[np.float64]
                 ) -> NDArray[np.bool_]:
    """(K,) bool: the segments (K, 3) a -> (K, 3) b hit no face."""
    delta = b - a
    length = np.linalg.norm(delta, axis=1)
    free = np.ones(len(a), bool)
    moving = length > _EPS_M
    if moving.any():
        direction = delta[moving] / length[moving, None]
        _, distance = caster.first_hit(a[moving], direction)
        free[moving] = distance > length[moving]
    return free



def upright_free(caster: RayCaster, a: NDArray[np.float64], b: NDArray[np.float64]
                 ) -> NDArray[np.bool_]:
    """(K,) bool: a person walks upright from (K, 3) a to (K, 3) b, points at knee height:
    the segments at every ``UPRIGHT_HEIGHTS_M`` above the floor (a and b less the knee
    height) hit no face, cast both ways. The higher heights are cast only for the
    segments free at the knee."""
    free = segment_free(caster, a, b) & segment_free(caster, b, a)
    for height in UPRIGHT_HEIGHTS_M:
        if height == KNEE_HEIGHT_M or not free.any():
            continue
        lift = np.array([0.0, 0.0, height - KNEE_HEIGHT_M])
        index = np.flatnonzero(free)
        up_a, up_b = a[index] + lift, b[index] + lift
        free[index] = segment_free(caster, up_a, up_b) & segment_free(caster, up_b, up_a)
    return free


def cell_pairs(sorted_key: NDArray[np.int64], order: NDArray[np.int64],
               target: NDArray[np.int64]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Every (i, j) with point j in the cell ``target[i]``: (P,) i and (P,) j, for N points
    whose cell keys, sorted, are the (N,) ``sorted_key`` and ``order`` sorts them."""
    start = np.searchsorted(sorted_key, target, side="left")
    stop = np.searchsorted(sorted_key, target, side="right")
    counts = stop - start
    a = np.repeat(np.arange(len(target)), counts)
    b = order[np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
              + np.repeat(start, counts)]
    return a, b

def build_walk_graph(scene: Scene, caster: RayCaster, *, ground: bool = True) -> WalkGraph:
    """The walk graph of ``scene`` (see the module docstring); ``ground``: add the ground
    nodes of a model without terrain."""
    lo, hi = scene.bounds
    columns = ((hi[0] - lo[0]) / WALK_GRID_M + 1) * ((hi[1] - lo[1]) / WALK_GRID_M + 1)
    grid_m = WALK_GRID_M * max(1.0, math.sqrt(columns / MAX_COLUMNS))
    samples = _floor_samples(scene, caster, grid_m)
    floor_xyz, ix, iy = samples.floor_xyz, samples.ix, samples.iy
    n_ground = 0
    if ground:
        ground_xyz, ground_ix, ground_iy = _ground_nodes(scene, samples, grid_m)
        n_ground = len(ground_xyz)
        floor_xyz = np.concatenate([floor_xyz, ground_xyz])
        ix, iy = np.concatenate([ix, ground_ix]), np.concatenate([iy, ground_iy])
    n = len(floor_xyz)
    # nodes by grid column: a neighbour column's nodes are found by a sorted-key search
    # (columns shifted to start at 0; the model's own samples are sorted already)
    shift_x, shift_y = (int(ix.min()), int(iy.min())) if n else (0, 0)
    ix, iy = ix - shift_x, iy - shift_y
    width = int(iy.max()) + 2 if n else 1
    key = ix * width + iy
    by_key = np.lexsort((floor_xyz[:, 2], key))
    sorted_key = key[by_key]
    rows: list[NDArray[np.int64]] = []
    cols: list[NDArray[np.int64]] = []
    for dx, dy in ((1, 0), (0, 1), (1, 1), (1, -1)):
        target = (ix + dx) * width + (iy + dy)
        a, b = cell_pairs(sorted_key, by_key, target)
        close = np.abs(floor_xyz[a, 2] - floor_xyz[b, 2]) <= STEP_M
        rows.append(a[close])
        cols.append(b[close])
    a = np.concatenate(rows) if rows else np.zeros(0, np.int64)
    b = np.concatenate(cols) if cols else np.zeros(0, np.int64)
    knee = np.array([0.0, 0.0, KNEE_HEIGHT_M])
    # the links' knee-high segments, both ways, a block at a time: Embree's hit record is
    # some 50 bytes a ray, and a large floor has millions of links
    free = np.ones(len(a), bool)
    for first in range(0, len(a), _LINKS_PER_BLOCK):
        block = slice(first, first + _LINKS_PER_BLOCK)
        from_a, from_b = floor_xyz[a[block]] + knee, floor_xyz[b[block]] + knee
        free[block] = upright_free(caster, from_a, from_b)
    a, b = a[free], b[free]
    length = np.linalg.norm(floor_xyz[a] - floor_xyz[b], axis=1)
    links = sp.coo_matrix((np.concatenate([length, length]),
                           (np.concatenate([a, b]), np.concatenate([b, a]))),
                          shape=(n, n)).tocsr()
    return WalkGraph(floor_xyz=floor_xyz, links=links, grid_m=grid_m, n_ground=n_ground)
