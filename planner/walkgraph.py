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
  (:func:`door_faces`: IFC doors by class; in a plain mesh the thin fillers of wall
  openings that the walk meets, found by :func:`mesh_doors`). IfcOpeningElement voids are
  never part of the mesh;
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
from collections.abc import Iterator
from dataclasses import dataclass, field

import numba
import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy import ndimage

from planner.rays import RayCaster, make_ray_caster
from planner.scene import Scene, corner_extremes

WALK_GRID_M = 0.25  # floor sample spacing; finer than a stair tread (~0.26-0.30 m)
OUTSIDE_MARGIN_M = 1.0  # ground walked around a model without terrain
MAX_COLUMNS = 400_000  # the grid coarsens on very large models to stay within this
# the walk covers the ground of the plan's candidates and this much around it (``area_xy``):
# a crew walks between stations in and around the building, not across its site (a house's
# terrain of 114 x 203 m made 606,000 floor samples, most of them out on the site)
WALK_AREA_MARGIN_M = 5.0
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
_LINKS_PER_BLOCK = 1 << 16
_MAX_LEVELS = 32  # surfaces followed down one grid column (slabs, furniture, stairs, roofs)
_EPS_M = 1e-3


# IFC classes modelled closed that a survey crew opens: people walk and scanners see through
OPEN_DOOR_CLASSES = ("IfcDoor",)
# a door in a plain mesh (mesh_doors): a thin filler in a wall opening, as the walk meets it.
# Door leaves are 40-70 mm thick, up to ~0.12 m with glazing beads or a lock case; a wall
# that counts as a wall here is thicker than its leaf (DOOR_WALL_THICKER_M)
DOOR_FILLER_MAX_M = 0.15
# and at least this: a link from the air into a wall's solid (a floor sample inside a wall,
# on its bottom face) meets one face from both sides, 0 m apart; 6 mm glass is the thinnest
DOOR_FILLER_MIN_M = 0.005
# the faces met from both ends are the two sides of a panel: parallel within this (a link
# that cuts a wall's corner meets two sides at right angles, across little material)
DOOR_PARALLEL_DEG = 10.0
_PARALLEL_COS = math.cos(math.radians(DOOR_PARALLEL_DEG))  # |cos| of parallel normals
# the free height of a doorway: a leaf of 1.985-2.135 m (DIN 18101) to 2.5 m (commercial,
# Renga's 2.6 m glazed door included); a ceiling above 2.7 m is a room, not a lintel
DOOR_HEIGHT_M = (1.8, 2.7)
DOOR_WIDTH_MAX_M = 3.0  # a double door, a single garage door (2.5-3 m)
# the rooms on both sides are at least this much higher than the doorway's head
DOOR_LINTEL_STEP_M = 0.1
DOOR_LINTEL_REACH = 2  # grid steps beyond a link's ends searched for the rooms (a thick wall)
# heights over the floor probed for the wall over the doorway: one lies between a leaf's
# top and a room's ceiling in any storey up to 2.8 m high
DOOR_WALL_PROBES_M = (2.0, 2.2, 2.4, 2.6)
# the wall over the doorway (the lintel) is thicker than the filler by this, and a leaf a
# step along its plane is no thicker than where it was met by more than this
DOOR_WALL_THICKER_M = 0.02
DOOR_JOIN_M = 0.6  # crossings closer than this are one door (the two leaves of a double door)
# fittings (handles, hinges, locks, kick plates) stand at most this far proud of the leaf,
# and are no larger than this (box diagonal)
DOOR_FITTING_REACH_M = 0.1
DOOR_FITTING_SIZE_M = 0.35
# a door's faces rise to its head less this (the gap over a leaf, a frame's rebate): a thin
# part of a stair under the next flight is lower
DOOR_LEAF_GAP_M = 0.1
# and they rise in one piece: from knee height up, the leaf's parts (panels, rails, glass,
# beads) touch, so no height band wider than this is free of the door's faces. A stair's
# stringer met at knee height is as thin as a leaf, and the stringer of the flight above
# lies in its plane (NiedriHa: 1.46 m of air between them); every IfcDoor of the shared
# buildings is gap-free
DOOR_STACK_GAP_M = 0.2
# what a door stands on (the first surface under the filler, the doors open) is at most this
# above the higher floor beside it: a threshold or one step, no higher than a stair riser
# (<= 0.19 m in most building codes, see STEP_M). A window's sill is higher (Lantern
# Hollow's casements: 0.46 m); a French window's frame on a 0.1 m sill is a door here
DOOR_SILL_MAX_M = 0.2
# the thinnest door leaf in common use: 1 3/8 in (35 mm), the US interior flush door (WDMA
# I.S. 1A: 1 3/8 and 1 3/4 in); European leaves are 39-40 mm or more (DIN 68706-1). A filler
# thinner than this at knee height is a pane (glass 4-12 mm, a sealed unit up to ~30 mm as
# BIM tools draw it): a glazed door or a French window, which geometry cannot tell apart
DOOR_LEAF_MIN_M = 0.03
# a glazed door narrower than this is a strip of another door's opening (the glass edge of
# a leaf drawn ajar): narrower than a person's shoulders (bideltoid breadth, ISO 7250-1's
# measure, about 0.4 m and more in adults), so no one is sent through it alone
DOOR_CHECK_WIDTH_MIN_M = 0.4
# a filler is a panel, not a post: the walk's crossing moved this far along the filler's
# plane, to one side or the other, meets material parallel to it again, as thin. A leaf is
# at least DOOR_CHECK_WIDTH_MIN_M wide, so one of the two lands on it wherever the crossing
# met it; a post narrower than twice this (a round steel column, whose facets a crossing
# may meet as two parallel sides) is missed on both
DOOR_PANEL_PROBE_M = 0.15
# passes over the crossings with the doors found so far open: a leaf of panels and glass is
# met layer by layer (front, glass, back)
DOOR_PASSES = 3
_DOOR_TOL_M = 2e-3  # a face of the leaf lies in the leaf's box within this (rounding)


def door_faces(scene: Scene, caster: RayCaster | None = None) -> NDArray[np.bool_]:
    """(F,) bool: faces of doors. IFC models: the faces of ``OPEN_DOOR_CLASSES``
    elements. Plain meshes (no elements): with a ``caster`` over every face, the door
    fillers of :func:`mesh_doors`; without one, none."""
    if not scene.elements:
        if caster is None:
            return np.zeros(scene.n_faces, bool)
        found: NDArray[np.bool_] = mesh_doors(scene, caster) >= 0
        return found
    return scene.faces_of_classes(OPEN_DOOR_CLASSES)


@dataclass(frozen=True, eq=False)
class _Crossings:
    """Knee-height links of the walk blocked by something thin (see :func:`mesh_doors`).

    Attributes: K links; ``a``, ``b`` (K, 3) their knee points, ``x`` (K, 3) the middle of
    the filler on the link, ``floor_z`` (K,) the lower floor, ``thick`` (K,) the filler's
    thickness along the link, ``faces`` (K, 2) the file faces hit from a and from b (-1
    none).
    """

    a: NDArray[np.float64]
    b: NDArray[np.float64]
    x: NDArray[np.float64]
    floor_z: NDArray[np.float64]
    thick: NDArray[np.float64]
    faces: NDArray[np.int64]


@dataclass(frozen=True, eq=False)
class MeshDoors:
    """The doors :func:`mesh_doors` finds in a plain mesh: D doors.

    Attributes: ``face_door`` (F,) int64, the door of each scene face (0..D-1; -1 none);
    ``lo_m``, ``hi_m`` (D, 3) the corners of each door's box (plan frame, metres);
    ``filler_m`` (D,) how thick the filler the walk meets at knee height is, across its
    plane (the median over the door's crossings).
    """

    face_door: NDArray[np.int64]
    lo_m: NDArray[np.float64]
    hi_m: NDArray[np.float64]
    filler_m: NDArray[np.float64]

    @property
    def n_doors(self) -> int:
        return len(self.filler_m)

    @property
    def width_m(self) -> NDArray[np.float64]:
        """(D,) each door's width: its box's horizontal diagonal."""
        span = self.hi_m[:, :2] - self.lo_m[:, :2]  # (D, 2)
        width: NDArray[np.float64] = np.hypot(span[:, 0], span[:, 1])
        return width

    @property
    def glazed(self) -> NDArray[np.bool_]:
        """(D,) bool: doors whose filler at knee height is thinner than a door leaf
        (``DOOR_LEAF_MIN_M``): a pane of glass down to the floor, as in a glazed door and in
        a French window or a door's sidelight alike, which geometry cannot tell apart
        (:func:`mesh_doors`), at least ``DOOR_CHECK_WIDTH_MIN_M`` wide (a narrower one is
        a strip of another door's opening, which a person does not pass alone). A crew
        walked through one checks that it opens."""
        result: NDArray[np.bool_] = ((self.filler_m < DOOR_LEAF_MIN_M)
                                     & (self.width_m >= DOOR_CHECK_WIDTH_MIN_M))
        return result


def mesh_doors(scene: Scene, caster: RayCaster) -> NDArray[np.int64]:
    """(F,) int64: the door each face belongs to (0, 1, ...; -1: none), in a mesh without
    semantics, from geometry alone (:func:`found_doors`' ``face_door``)."""
    return found_doors(scene, caster).face_door


def found_doors(scene: Scene, caster: RayCaster) -> MeshDoors:
    """The doors of a mesh without semantics, from geometry alone: which faces, where, and
    how thick their filler is at knee height.

    The rule works on what the walk meets, not on how an exporter splits a door into parts
    or whether it shares vertices, so that door families from any authoring tool (frame,
    lining, a leaf of panels and glass, handles, threshold; single, double, sliding;
    closed or ajar) are found alike. On the walk's own floor samples (module docstring,
    every face blocking, the ground around a model without terrain included):

    1. *A thin filler.* Two floor samples one or two grid steps apart (in one of the 8
       directions; two steps: a column whose centre falls inside a leaf has no sample in
       the air), floors at most ``STEP_M`` apart, whose knee-height segment is blocked by
       ``DOOR_FILLER_MIN_M`` to ``DOOR_FILLER_MAX_M`` of material (from the first hit from
       one end to the first hit from the other), the faces met from both ends parallel
       within ``DOOR_PARALLEL_DEG``: the two sides of a panel. A sample inside a wall
       (on its bottom face) meets one face from both sides, and a segment cutting a wall's
       corner meets two sides at right angles: neither is a filler. Nor is a post: moved
       ``DOOR_PANEL_PROBE_M`` along the filler's plane to either side, the crossing meets
       nothing as thin and parallel to it (a pane drawn as one face counts; a leaf is wider
       than twice that; a round column's facets can meet a crossing as two parallel
       sides). Nor is a wall's end cut across (a partition met where it joins another
       wall, through part of its thickness): there the moved crossing meets the wall's
       whole thickness, more than ``DOOR_WALL_THICKER_M`` thicker; a leaf is as thick a
       step along (its panels and glass no thicker than its rails).
    2. *In a wall opening*: wall material above a gap of door height, the filler under
       it. Either (a) the head over one of the two samples (a ray up) lies within
       ``DOOR_HEIGHT_M`` of the floor, the filler's own top (a ray up from inside it) is no
       higher, within ``DOOR_LINTEL_REACH`` grid steps beyond each end the head rises
       at least ``DOOR_LINTEL_STEP_M`` higher, and across, from those higher rooms just
       over the head, the lintel is ``DOOR_WALL_THICKER_M`` thicker than the filler: a
       lintel, as deep as a wall, between two rooms (a partition as thick as a leaf under
       a steel beam, whose flange is a head and whose web is millimetres thick, is none);
       or (b) at one of ``DOOR_WALL_PROBES_M`` above the floor, over the filler's
       top and below the ceilings of both ends, the segment is blocked by material
       ``DOOR_WALL_THICKER_M`` thicker than the filler (the wall over a leaf in a thin
       wall). A thin partition fails both (it is as thick at every height, its top is
       the ceiling), and so does a screen of door height between two rooms (no wall over
       it).
    3. *One door per opening*: such crossings closer than ``DOOR_JOIN_M`` whose fillers are
       parallel are one door (both leaves of a double door; two doors at right angles in
       a corner stay two). Its faces: the faces the crossings met (each no wider than
       ``DOOR_WIDTH_MAX_M`` and no higher than ``DOOR_HEIGHT_M[1]``: a wall's face, met
       from a floor sample inside that wall with an open leaf beside it, is longer; and
       within ``DOOR_FILLER_MAX_M`` of the filler's median plane: a wall met past a jamb is
       not the door's), every face
       within their box (along the filler's main horizontal axis and across it, from the
       floor to ``DOOR_HEIGHT_M[1]``: the rest of the leaf, its panels, glass and edges),
       and the small faces (box diagonal up to ``DOOR_FITTING_SIZE_M``) within
       ``DOOR_FITTING_REACH_M`` of it across: handles, hinges, locks. A door whose faces
       do not stack, with no band of air wider than ``DOOR_STACK_GAP_M`` in them, from
       knee height or below up to ``DOOR_HEIGHT_M[0]`` less ``DOOR_LEAF_GAP_M`` is none:
       a leaf is one piece, a stair's stringer under the next flight's is not. Of its
       faces only that stack is the door's: faces in the box over a band of air wider than
       ``DOOR_STACK_GAP_M`` above the leaf (the steps of a stair that runs past the door's
       head) are not.
    4. *Layer by layer*: the crossings are cast again with the doors found so far open;
       what still blocks them thinly and parallel to the filler (the back of a panel,
       glass behind a rail) joins their door, for up to ``DOOR_PASSES`` passes in all.
    5. *On the floor*: with the doors open, the first surface under the filler (a ray
       down from each crossing's middle at knee height) lies, over the median of the
       door's crossings, at most ``DOOR_SILL_MAX_M`` above the higher of the two floors:
       a threshold or a step; a window's parapet is higher. Nothing under it (the open
       ground round a model without terrain) counts as floor. The doors left are
       renumbered in order.

    The walk then passes the opening whatever the leaf's position: a leaf open wide does
    not block it and is no door here; one ajar in the opening is the filler. The frame,
    the lining and the threshold are not needed to pass and stay as they are, as do the
    walls: no face outside a filler's box is taken. A window down to the floor (within
    ``DOOR_SILL_MAX_M``) under a lintel is taken for a door: geometry alone cannot tell a
    French window, or a door's glazed sidelight, from a glazed door. A door between floors
    more than ``STEP_M`` apart (an unmodelled step) is not found: the walk cannot use it
    anyway.

    A door whose filler at knee height is thinner than ``DOOR_LEAF_MIN_M`` across its plane
    (:attr:`MeshDoors.glazed`) is glass there: a glazed door, or a French window that may
    be fixed; the route warns where it passes one.
    """
    vertices, faces = scene.file_mesh
    result = np.full(len(faces), -1, np.int64)
    crossings = _thin_crossings(scene, caster)
    if len(crossings.thick) == 0:
        return _mesh_doors_of(scene, result, np.zeros(0))
    keep = _in_wall_opening(crossings, caster)
    triangles = vertices[faces]  # (F0, 3, 3)
    # the filler's plane at each crossing: the side met from a
    met = triangles[crossings.faces[keep, 0]]
    normal = np.cross(met[:, 1] - met[:, 0], met[:, 2] - met[:, 0])
    normal /= np.maximum(np.linalg.norm(normal, axis=1), _EPS_M * _EPS_M)[:, None]
    doors = _join_crossings(crossings.x[keep], normal)
    lo, hi = triangles.min(axis=1), triangles.max(axis=1)
    diagonal = np.linalg.norm(hi - lo, axis=1)
    # a face of a leaf fits in the largest leaf: no wider than DOOR_WIDTH_MAX_M, no higher
    # than DOOR_HEIGHT_M[1] (a wall's face met past a jamb or from inside the wall is longer)
    leaf_sized = ((np.linalg.norm(hi[:, :2] - lo[:, :2], axis=1) <= DOOR_WIDTH_MAX_M)
                  & (hi[:, 2] - lo[:, 2] <= DOOR_HEIGHT_M[1]))
    hit_faces = crossings.faces[keep]  # (K, 2) file faces, -1 none
    n_crossings = len(hit_faces)
    floor_z = crossings.floor_z[keep]
    found_of = np.full(int(doors.max()) + 1 if len(doors) else 0, -1)  # door of a join
    for attempt in range(DOOR_PASSES):
        result[:] = -1
        found_of[:] = -1
        n_found = 0
        for door in range(int(doors.max()) + 1 if len(doors) else 0):
            mine = doors == door
            hit = np.unique(hit_faces[mine])
            hit = hit[hit >= 0]
            hit = hit[leaf_sized[hit]]
            if len(hit) == 0:
                continue
            z0 = float(floor_z[mine].min())
            taken = _door_box_faces(triangles, lo, hi, diagonal, hit, z0)
            taken = taken[result[taken] < 0]
            # the leaf's own stack: a band of faces over a gap above it is not the door's
            taken = taken[_leaf_stack(lo[taken, 2], hi[taken, 2], z0)]
            if len(taken) == 0:
                continue
            result[taken] = n_found
            found_of[door] = n_found
            n_found += 1
        if attempt == DOOR_PASSES - 1 or n_found == 0:
            break
        # the crossings again, the doors open: what still blocks them thinly, parallel to
        # the filler, is more of it (the back of a panel, glass behind a rail)
        walk = _open_caster(scene, result)
        thick, _, face_ab, face_ba, _ = _through(walk, crossings.a[keep], crossings.b[keep])
        more = _file_faces_hit(scene, np.stack([face_ab, face_ba], axis=1))
        still = np.isfinite(thick) & (thick <= DOOR_FILLER_MAX_M)
        for side in range(2):
            met = triangles[np.maximum(more[:, side], 0)]
            turn = np.cross(met[:, 1] - met[:, 0], met[:, 2] - met[:, 0])
            turn /= np.maximum(np.linalg.norm(turn, axis=1), _EPS_M * _EPS_M)[:, None]
            aligned = np.abs(np.einsum("kc,kc->k", turn, normal)) >= _PARALLEL_COS
            more[~(still & aligned), side] = -1
        if (more < 0).all():
            break
        found_more = np.any(more >= 0, axis=1)
        hit_faces = np.concatenate([hit_faces, more[found_more]])
        # the crossings come first in doors and floor_z, the faces of later passes after
        doors = np.concatenate([doors, doors[:n_crossings][found_more]])
        floor_z = np.concatenate([floor_z, floor_z[:n_crossings][found_more]])
    door_of = found_of[doors[:n_crossings]]  # (K',) the door of each kept crossing
    # the filler's thickness across its plane: a link crosses it at an angle (diagonal
    # links, a door at 30 degrees to the grid)
    across = crossings.thick[keep] * np.abs(np.einsum(
        "kc,kc->k", crossings.b[keep] - crossings.a[keep], normal)) / np.maximum(
        np.linalg.norm(crossings.b[keep] - crossings.a[keep], axis=1), _EPS_M)
    filler_m = np.array([float(np.median(across[door_of == door]))
                         for door in range(int(result.max()) + 1)])
    if result.max() >= 0:
        result, standing = _on_the_floor(scene, crossings, keep, door_of, result)
        filler_m = filler_m[standing]
    return _mesh_doors_of(scene, result, filler_m)


def _mesh_doors_of(scene: Scene, result: NDArray[np.int64], filler_m: NDArray[np.float64]
                   ) -> MeshDoors:
    """:class:`MeshDoors` of the door of each file face, ``result`` (F0,), whose fillers are
    (D,) ``filler_m`` thick."""
    face_door = result if scene.file_faces is None else result[scene.source_face]
    n = len(filler_m)
    lo, hi = np.full((n, 3), np.inf), np.full((n, 3), -np.inf)
    if n:
        corners = scene.vertices[scene.faces[face_door >= 0]]  # (n', 3, 3)
        which = face_door[face_door >= 0]
        least, most = corner_extremes(corners)
        np.minimum.at(lo, which, least)
        np.maximum.at(hi, which, most)
    return MeshDoors(face_door, lo, hi, filler_m)


def _open_caster(scene: Scene, door: NDArray[np.int64]) -> RayCaster:
    """A caster over every file face but those of a door (``door`` (F0,) >= 0)."""
    opened = door < 0
    return make_ray_caster(scene, opened if scene.file_faces is None
                           else opened[scene.source_face],
                           file_faces=scene.file_faces is not None)


def _on_the_floor(scene: Scene, crossings: _Crossings, keep: NDArray[np.bool_],
                  door_of: NDArray[np.int64], result: NDArray[np.int64]
                  ) -> tuple[NDArray[np.int64], NDArray[np.bool_]]:
    """``result`` (F0,) without the doors that do not stand on the floor (rule step 5),
    the others renumbered in order, and which of the doors of ``result`` stand (D,) bool.
    ``keep`` (K,) the crossings in a wall opening, ``door_of`` (K',) the door of each kept
    crossing (-1 none)."""
    n_found = int(result.max()) + 1
    walk = _open_caster(scene, result)
    floor_z = crossings.floor_z[keep]
    start = crossings.x[keep].copy()
    start[:, 2] = floor_z + KNEE_HEIGHT_M
    down = np.tile([0.0, 0.0, -1.0], (len(start), 1))
    _, distance = walk.first_hit(start, down)  # inf: nothing below (the open ground)
    higher = np.maximum(crossings.a[keep, 2], crossings.b[keep, 2]) - KNEE_HEIGHT_M
    sill = start[:, 2] - distance - higher  # (K',) m above the higher floor, -inf: none
    standing = np.array([float(np.median(sill[door_of == door])) <= DOOR_SILL_MAX_M
                         for door in range(n_found)])
    number = np.where(standing, np.cumsum(standing) - 1, -1)
    renumbered: NDArray[np.int64] = np.where(result >= 0, number[np.maximum(result, 0)], -1)
    return renumbered, standing


def _thin_crossings(scene: Scene, caster: RayCaster) -> _Crossings:
    """The walk's links blocked at knee height by a thin filler (rule step 1)."""
    grid_m = _walk_grid_m(scene)
    samples = _floor_samples(scene, caster, grid_m)
    # the ground around a model without terrain too: the outside of a front door
    ground_xyz, ground_ix, ground_iy = _ground_nodes(scene, samples, grid_m)
    floor_xyz = np.concatenate([samples.floor_xyz, ground_xyz])
    ix = np.concatenate([samples.ix, ground_ix])
    iy = np.concatenate([samples.iy, ground_iy])
    knee = np.array([0.0, 0.0, KNEE_HEIGHT_M])
    kept: list[tuple[NDArray[np.int64], ...]] = []
    parts: list[tuple[NDArray[np.float64], ...]] = []
    for ia, ib in _links_in_blocks(floor_xyz, ix, iy):
        pa, pb = floor_xyz[ia] + knee, floor_xyz[ib] + knee
        thick, along, face_ab, face_ba, d_ab = _through(caster, pa, pb)
        thin = ((thick >= DOOR_FILLER_MIN_M) & (thick <= DOOR_FILLER_MAX_M)
                & (face_ba >= 0))
        thin[thin] = (np.abs(np.einsum("kc,kc->k", scene.normals_of(face_ab[thin]),
                                       scene.normals_of(face_ba[thin])))
                      >= _PARALLEL_COS)
        thin[thin] = _panel(scene, caster, scene.normals_of(face_ab[thin]), pa[thin], pb[thin],
                            thick[thin])
        x = pa[thin] + along[thin] * (d_ab[thin] + thick[thin] / 2)[:, None]
        kept.append((face_ab[thin], face_ba[thin]))
        parts.append((pa[thin], pb[thin], x, np.minimum(floor_xyz[ia[thin], 2],
                                                       floor_xyz[ib[thin], 2]), thick[thin]))
    if not parts:
        empty = np.zeros((0, 3))
        return _Crossings(empty, empty, empty, np.zeros(0), np.zeros(0),
                          np.zeros((0, 2), np.int64))
    hit = np.stack([np.concatenate([k[0] for k in kept]),
                    np.concatenate([k[1] for k in kept])], axis=1)
    pa, pb, x, floor_z, thick = (np.concatenate([p[i] for p in parts]) for i in range(5))
    return _Crossings(pa, pb, x, floor_z, thick, _file_faces_hit(scene, hit))


def _links_in_blocks(floor_xyz: NDArray[np.float64], ix: NDArray[np.int64],
                     iy: NDArray[np.int64]
                     ) -> Iterator[tuple[NDArray[np.int64], NDArray[np.int64]]]:
    """The (k,) a and b of the door search's links, ``_LINKS_PER_BLOCK`` at most at a
    time: the neighbours' links, then the pairs two columns apart (a column whose centre
    falls inside a leaf has no floor sample in the air, and its neighbours are not linked
    across it). One reach's links are made at a time and none are copied: on a house's
    114 x 203 m site, 4.8 M links, the two reaches' arrays and their concatenation had
    been 220 MiB at once, the peak of its plan."""
    for reach in (1, 2):
        a, b = _neighbour_pairs(floor_xyz, ix, iy, reach)
        for first in range(0, len(a), _LINKS_PER_BLOCK):
            # copies, not views: a block the caller still holds keeps no reach's arrays
            yield (a[first:first + _LINKS_PER_BLOCK].copy(),
                   b[first:first + _LINKS_PER_BLOCK].copy())
        del a, b  # before the next reach's are made


def _panel(scene: Scene, caster: RayCaster, normal: NDArray[np.float64],
           pa: NDArray[np.float64], pb: NDArray[np.float64], thick_m: NDArray[np.float64]
           ) -> NDArray[np.bool_]:
    """(K,) bool: the thin crossings ``pa`` -> ``pb`` (K, 3) of a filler with the (K, 3)
    unit ``normal``, ``thick_m`` (K,) through it, that meet it again
    ``DOOR_PANEL_PROBE_M`` to one side along its plane, no thicker (within
    ``DOOR_WALL_THICKER_M``): a panel, not a post, nor a wall cut at its end (rule step 1).
    A filler whose plane is not upright is kept."""
    side = np.stack([-normal[:, 1], normal[:, 0], np.zeros(len(normal))], axis=1)
    length = np.linalg.norm(side, axis=1)
    upright = length > 0.5
    side[upright] /= length[upright, None]
    panel: NDArray[np.bool_] = ~upright
    for sign in (1.0, -1.0):
        shift = sign * DOOR_PANEL_PROBE_M * side
        thick, _, face_ab, face_ba, _ = _through(caster, pa + shift, pb + shift)
        # the leaf, its glass or a panel in it (a pane drawn as one face is 0 m thick)
        met = ((thick <= np.minimum(thick_m + DOOR_WALL_THICKER_M, DOOR_FILLER_MAX_M))
               & (face_ab >= 0))
        for face in (face_ab, np.where(face_ba >= 0, face_ba, face_ab)):
            met &= np.abs(np.einsum("kc,kc->k", scene.normals_of(np.maximum(face, 0)), normal)
                          ) >= _PARALLEL_COS
        panel |= met
    return panel


def _file_faces_hit(scene: Scene, hit: NDArray[np.int64]) -> NDArray[np.int64]:
    """The file face of each scene face in ``hit`` (any shape), -1 kept for no hit."""
    on_file: NDArray[np.int64] = np.where(
        hit >= 0, scene.source_face[np.maximum(hit, 0)], -1).astype(np.int64)
    return on_file


def _through(caster: RayCaster, pa: NDArray[np.float64], pb: NDArray[np.float64]
             ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64],
                        NDArray[np.int64], NDArray[np.float64]]:
    """What blocks the (K, 3) segments pa -> pb: (K,) thickness of the material along
    each (from the first hit from pa to the first hit from pb; inf: free), (K, 3) unit
    directions, (K,) the faces hit from pa and from pb (-1: none within the segment) and
    (K,) the distance from pa to its hit."""
    delta = pb - pa
    length = np.linalg.norm(delta, axis=1)
    along = delta / np.maximum(length, _EPS_M)[:, None]
    face_ab, d_ab = caster.first_hit(pa, along)
    face_ba, d_ba = caster.first_hit(pb, -along)
    blocked = d_ab < length
    thick = np.where(blocked, np.maximum(length - d_ab - np.minimum(d_ba, length), 0.0),
                     np.inf)
    face_ab = np.where(blocked, face_ab, -1)
    face_ba = np.where(blocked & (d_ba < length), face_ba, -1)
    return thick, along, face_ab, face_ba, d_ab


# a sill looked for over the floor, in these steps, from a step up to head room: a door the
# model sets at another level's height, with wall under it (raised_openings)
_SILL_STEP_M = 0.05


def raised_openings(caster: RayCaster, a_xyz: NDArray[np.float64],
                    b_xyz: NDArray[np.float64]) -> NDArray[np.float64]:
    """(K,) the sill of an opening of door height in the wall that parts each pair of
    floor points (K, 3) a and b (floors within ``STEP_M`` of each other): metres over the
    higher floor; NaN where there is none. Over the pair, the segment from a to b, lifted
    in steps of ``_SILL_STEP_M``, is blocked by more than ``DOOR_FILLER_MAX_M`` of material
    (a wall, not a leaf) at every height from ``STEP_M`` up to the sill, and from there up
    to ``HEADROOM_M`` above the sill it is free or blocked only by a filler no thicker
    (a leaf, a pane), under the ceilings over both points (inside a slab a segment meets
    nothing): a door, or a window as tall, set higher than a step with wall under it. The
    sill is the first surface under the opening's lowest free height."""
    k = len(a_xyz)
    result = np.full(k, np.nan)
    if k == 0:
        return result
    floor_z = np.maximum(a_xyz[:, 2], b_xyz[:, 2])
    up = np.tile([0.0, 0.0, 1.0], (k, 1))
    knee = np.array([0.0, 0.0, KNEE_HEIGHT_M])
    ceiling_m = np.minimum(caster.first_hit(a_xyz + knee, up)[1],
                           caster.first_hit(b_xyz + knee, up)[1]) + KNEE_HEIGHT_M
    heights = np.arange(STEP_M, HEADROOM_M + HEADROOM_M + _EPS_M, _SILL_STEP_M)  # (H,)
    walled = np.zeros((k, len(heights)), bool)  # (K, H) more than a leaf at that height
    open_at = np.zeros((k, len(heights)), bool)  # (K, H) a leaf, a pane or nothing
    for j, height in enumerate(heights):
        pa, pb = a_xyz.copy(), b_xyz.copy()
        pa[:, 2] = pb[:, 2] = floor_z + height
        thick = _through(caster, pa, pb)[0]
        walled[:, j] = np.isfinite(thick) & (thick > DOOR_FILLER_MAX_M)
        open_at[:, j] = (thick <= DOOR_FILLER_MAX_M) & (height < ceiling_m)  # inf: free
    per_person = round(HEADROOM_M / _SILL_STEP_M)  # the heights a person fills over a sill
    for i in range(k):
        for j in range(1, len(heights) - per_person + 1):
            if not walled[i, j - 1]:
                break  # no wall under this height: a sill higher up stands on none
            if open_at[i, j:j + per_person].all():
                # the sill: the first surface under the opening's lowest probed height
                middle = (a_xyz[i] + b_xyz[i]) / 2
                middle[2] = floor_z[i] + heights[j]
                _, drop = caster.first_hit(middle[None], np.array([[0.0, 0.0, -1.0]]))
                result[i] = heights[j] - min(float(drop[0]), _SILL_STEP_M)
                break
    return result


def _in_wall_opening(crossings: _Crossings, caster: RayCaster) -> NDArray[np.bool_]:
    """(K,) bool: the thin crossings that lie in a wall opening (rule step 2)."""
    n = len(crossings.thick)
    up = np.tile([0.0, 0.0, 1.0], (n, 1))
    step = crossings.b - crossings.a
    knee_z = crossings.floor_z + KNEE_HEIGHT_M
    heads: dict[int, NDArray[np.float64]] = {}  # (K,) head height over the floor, by step
    for k in range(-DOOR_LINTEL_REACH, DOOR_LINTEL_REACH + 2):
        at = crossings.a + k * step
        at[:, 2] = knee_z
        _, distance = caster.first_hit(at, up)
        heads[k] = KNEE_HEIGHT_M + distance
    middle = np.stack([heads[0], heads[1]], axis=1)  # (K, 2) over the link's own ends
    at = crossings.x.copy()
    at[:, 2] = knee_z
    # from inside the filler: its own top (a leaf's, or a panel's in it); a wall's is the
    # ceiling
    filler_top = KNEE_HEIGHT_M + caster.first_hit(at, up)[1]
    low = (middle >= DOOR_HEIGHT_M[0]) & (middle <= DOOR_HEIGHT_M[1])
    lintel = np.where(low, middle, np.inf).min(axis=1)
    room_a = np.stack([heads[k] for k in range(-DOOR_LINTEL_REACH, 1)], axis=1)
    room_b = np.stack([heads[k] for k in range(1, DOOR_LINTEL_REACH + 2)], axis=1)
    rise = lintel + DOOR_LINTEL_STEP_M
    higher_a, higher_b = room_a >= rise[:, None], room_b >= rise[:, None]  # (K, R + 1)
    opening = (low.any(axis=1) & (filler_top <= lintel + _DOOR_TOL_M)
               & higher_a.any(axis=1) & higher_b.any(axis=1))
    if opening.any():
        # the lintel is a wall's depth, thicker than the filler: across, from the nearest
        # higher room on each side, just over the head. A wall as thick as the filler,
        # drawn in two pieces (a partition under a beam), has its joint there, not a head
        k_a = -np.argmax(higher_a[opening, ::-1], axis=1)  # (k,) steps from a, <= 0
        k_b = np.argmax(higher_b[opening], axis=1) + 1  # >= 1
        over = crossings.floor_z[opening] + lintel[opening] + DOOR_LINTEL_STEP_M / 2
        pa = crossings.a[opening] + k_a[:, None] * step[opening]
        pb = crossings.a[opening] + k_b[:, None] * step[opening]
        pa[:, 2] = pb[:, 2] = over
        deep = _through(caster, pa, pb)[0]
        opening[np.flatnonzero(opening)] = np.isfinite(deep) & (
            deep >= crossings.thick[opening] + DOOR_WALL_THICKER_M)
    ceiling = np.minimum(heads[0], heads[1])
    for height in DOOR_WALL_PROBES_M:
        probe = ~opening & (height < ceiling - _DOOR_TOL_M) & (filler_top <= height)
        if not probe.any():
            continue
        lift = np.zeros((int(probe.sum()), 3))
        lift[:, 2] = crossings.floor_z[probe] + height - crossings.a[probe, 2]
        lift_b = lift.copy()
        lift_b[:, 2] = crossings.floor_z[probe] + height - crossings.b[probe, 2]
        thick = _through(caster, crossings.a[probe] + lift, crossings.b[probe] + lift_b)[0]
        wall = np.isfinite(thick) & (thick >= crossings.thick[probe] + DOOR_WALL_THICKER_M)
        opening[np.flatnonzero(probe)[wall]] = True
    result: NDArray[np.bool_] = opening
    return result


def _join_crossings(x: NDArray[np.float64], normal: NDArray[np.float64]
                    ) -> NDArray[np.int64]:
    """(K,) door of each of the (K, 3) crossing points whose fillers have the (K, 3) unit
    ``normal``: points closer than ``DOOR_JOIN_M`` in parallel fillers (within
    ``DOOR_PARALLEL_DEG``) are one door, transitively (two doors at right angles in a
    corner stay two); doors numbered by their first point."""
    if len(x) == 0:
        return np.zeros(0, np.int64)
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    pairs = cKDTree(x).query_pairs(DOOR_JOIN_M, output_type="ndarray")
    parallel = (np.abs(np.einsum("kc,kc->k", normal[pairs[:, 0]], normal[pairs[:, 1]]))
                >= _PARALLEL_COS)
    pairs = pairs[parallel]
    graph = sp.coo_matrix((np.ones(len(pairs), np.int8), (pairs[:, 0], pairs[:, 1])),
                          shape=(len(x), len(x)))
    _, labels = connected_components(graph, directed=False)
    # renumbered by first appearance: deterministic whatever the component numbering
    _, first = np.unique(labels, return_index=True)
    order = np.argsort(first, kind="stable")
    rank = np.empty(len(order), np.int64)
    rank[order] = np.arange(len(order))
    result: NDArray[np.int64] = rank[labels]
    return result


def _leaf_stack(bottom_z: NDArray[np.float64], top_z: NDArray[np.float64], floor_z: float
                ) -> NDArray[np.bool_]:
    """(n,) bool: which of the faces spanning (n,) ``bottom_z`` to ``top_z`` are in a stack,
    with no free band wider than ``DOOR_STACK_GAP_M`` in it, from knee height over
    ``floor_z`` or below to a door's head (``DOOR_HEIGHT_M[0]`` less ``DOOR_LEAF_GAP_M``) or
    above: the leaf (rule step 3); none is when there is no leaf. Faces in a stack of their
    own over a gap (the steps of a stair beside the door, in its box) are not the door's."""
    if len(bottom_z) == 0:
        return np.zeros(0, bool)
    order = np.argsort(bottom_z, kind="stable")
    bottom, top = bottom_z[order], np.maximum.accumulate(top_z[order])
    # a new stack starts where a face begins above everything below it, plus the gap
    starts = np.concatenate([[True], bottom[1:] > top[:-1] + DOOR_STACK_GAP_M])
    first = np.flatnonzero(starts)
    stack_bottom = bottom[first]
    stack_top = np.maximum.reduceat(top, first)
    leaf = ((stack_bottom <= floor_z + KNEE_HEIGHT_M)
            & (stack_top >= floor_z + DOOR_HEIGHT_M[0] - DOOR_LEAF_GAP_M))
    result = np.zeros(len(bottom_z), bool)
    result[order] = leaf[np.cumsum(starts) - 1]
    return result


def _door_box_faces(triangles: NDArray[np.float64], lo: NDArray[np.float64],
                    hi: NDArray[np.float64], diagonal: NDArray[np.float64],
                    hit: NDArray[np.int64], z0: float) -> NDArray[np.int64]:
    """File faces of one door (rule step 3): the ``hit`` faces, the faces within their
    box and the fittings beside it. ``triangles`` (F0, 3, 3), ``lo``/``hi`` (F0, 3) their
    boxes, ``diagonal`` (F0,) the boxes' diagonals; ``z0`` the floor."""
    corners = triangles[hit].reshape(-1, 3)
    edge1 = triangles[hit, 1] - triangles[hit, 0]
    edge2 = triangles[hit, 2] - triangles[hit, 0]
    weight = np.repeat(np.linalg.norm(np.cross(edge1, edge2), axis=1) + _EPS_M, 3)
    centre = np.average(corners[:, :2], axis=0, weights=weight)
    offset = corners[:, :2] - centre
    _, axes = np.linalg.eigh((offset * weight[:, None]).T @ offset)
    across, along = axes[:, 0], axes[:, 1]
    # faces hit beside the filler's plane (a wall's side, met past a jamb) are not the door's
    plane = np.median(offset @ across)
    side = np.abs(triangles[hit, :, :2].mean(axis=1) @ across - centre @ across - plane)
    hit = hit[side <= DOOR_FILLER_MAX_M]
    corners = triangles[hit].reshape(-1, 3)
    offset = corners[:, :2] - centre
    t, s = offset @ along, offset @ across
    t_lo, t_hi = t.min() - _DOOR_TOL_M, t.max() + _DOOR_TOL_M
    s_lo, s_hi = s.min() - _DOOR_TOL_M, s.max() + _DOOR_TOL_M
    z_lo, z_hi = z0 - DOOR_FILLER_MAX_M, z0 + DOOR_HEIGHT_M[1]
    reach = DOOR_FITTING_REACH_M
    near = np.flatnonzero((lo[:, 2] >= z_lo) & (hi[:, 2] <= z_hi)
                          & (np.linalg.norm((lo[:, :2] + hi[:, :2]) / 2 - centre, axis=1)
                             <= (t_hi - t_lo) / 2 + (s_hi - s_lo) / 2 + reach + diagonal))
    flat = triangles[near][:, :, :2] - centre  # (n, 3, 2)
    ft, fs = flat @ along, flat @ across
    in_t = ((ft >= t_lo) & (ft <= t_hi)).all(axis=1)
    in_leaf = in_t & ((fs >= s_lo) & (fs <= s_hi)).all(axis=1)
    fitting = (in_t & ((fs >= s_lo - reach) & (fs <= s_hi + reach)).all(axis=1)
               & (diagonal[near] <= DOOR_FITTING_SIZE_M))
    result: NDArray[np.int64] = np.union1d(hit, near[in_leaf | fitting])
    return result


@dataclass(frozen=True, eq=False)
class WalkGraph:
    """Floor samples and the links between them.

    Attributes
    ----------
    floor_xyz : (N, 3) float64, floor points (metres); the model's own floor samples
        first, then the ground nodes (``n_ground`` of them)
    links : (N, N) CSR float64, symmetric, link length in metres
    cut_nodes : (K,) int64, ascending: on a graph of part of the footprint (``area_xy``),
        the nodes in its outermost columns where the area cuts the model's footprint;
        only these can have links, on the whole footprint's graph, to nodes outside it
    covered : (N,) bool, something over the node (a ceiling, a roof, a slab, a canopy),
        not the open sky; the ground nodes are under the sky (empty: not known)
    """

    floor_xyz: NDArray[np.float64]
    links: sp.csr_matrix
    grid_m: float
    n_ground: int = 0
    cut_nodes: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))
    covered: NDArray[np.bool_] = field(default_factory=lambda: np.zeros(0, bool))

    @property
    def n_nodes(self) -> int:
        return len(self.floor_xyz)


# a building's footprint is made of roofed patches at least this many walk columns across
# (0.75 m at the 0.25 m grid: narrower than a corridor, wider than a wall or a fence)
_ROOFED_MIN_COLUMNS = 3


def open_ground(graph: WalkGraph) -> NDArray[np.bool_]:
    """(N,) bool: the nodes of ``graph`` on open ground outside the building, from geometry
    alone (IFC model or plain mesh, with terrain or with the ground nodes round a model
    without it). A node is when it is

    - under the open sky: nothing over it (:attr:`WalkGraph.covered`), no roof or ceiling;
    - the lowest node of its column: the ground, not a balcony or a roof terrace over a
      floor;
    - outside the building's footprint: the columns with a node under a roof or ceiling,
      in patches at least ``_ROOFED_MIN_COLUMNS`` columns across, and whatever they
      enclose (a courtyard, an atrium, the walls' own columns). A narrower strip is the
      inside of a wall or a fence: a column's rays find the bottom of a solid that stands
      on the ground, under its own top (a fence round a pen would enclose the pen).

    All false where no node is covered (a model without a roof or a ceiling anywhere: its
    rooms cannot be told from its site) or the coverage is not known."""
    n = graph.n_nodes
    covered = graph.covered
    if len(covered) != n or not covered.any():
        return np.zeros(n, bool)
    xy = graph.floor_xyz[:, :2]
    # the nodes stand at column centres, whole grid steps apart
    cell = np.rint((xy - xy.min(axis=0)) / graph.grid_m).astype(np.int64)  # (N, 2)
    shape = cell.max(axis=0) + 1
    roofed = np.zeros((int(shape[0]), int(shape[1])), bool)
    roofed[cell[covered, 0], cell[covered, 1]] = True
    across = np.ones((_ROOFED_MIN_COLUMNS, _ROOFED_MIN_COLUMNS), bool)
    footprint = ndimage.binary_fill_holes(ndimage.binary_opening(roofed, across))
    key = cell[:, 0] * int(shape[1]) + cell[:, 1]
    lowest_z = np.full(int(shape[0]) * int(shape[1]), np.inf)
    np.minimum.at(lowest_z, key, graph.floor_xyz[:, 2])
    result: NDArray[np.bool_] = (~covered & (graph.floor_xyz[:, 2] <= lowest_z[key] + _EPS_M)
                                 & ~footprint[cell[:, 0], cell[:, 1]])
    return result


@dataclass(frozen=True, eq=False)
class _Samples:
    """Floor samples of a grid of columns (see :func:`_floor_samples`)."""

    floor_xyz: NDArray[np.float64]  # (N, 3)
    ix: NDArray[np.int64]  # (N,) grid column of each sample
    iy: NDArray[np.int64]
    covered: NDArray[np.bool_]  # (N,) something over the sample (not open sky)
    # (x1 - x0, y1 - y0) lowest surface of a column of the walked columns; -inf unknown
    lowest_z: NDArray[np.float64]
    nx: int  # columns over the whole model
    ny: int
    # the walked columns: ix in [x0, x1), iy in [y0, y1) (all nx x ny without an area)
    x0: int = 0
    x1: int = 0
    y0: int = 0
    y1: int = 0


def _columns(scene: Scene, grid_m: float, area_xy: NDArray[np.float64] | None
             ) -> tuple[int, int, int, int, int, int]:
    """nx, ny, the model's columns ``grid_m`` apart from its lower corner, and x0, x1, y0,
    y1, the walked ones: those whose centre lies in the (2, 2) ``area_xy`` ([[x, y] least,
    [x, y] most]; None: every column)."""
    lo, hi = scene.bounds
    nx = math.floor((hi[0] - lo[0]) / grid_m) + 1
    ny = math.floor((hi[1] - lo[1]) / grid_m) + 1
    if area_xy is None:
        return nx, ny, 0, nx, 0, ny
    first = np.ceil((area_xy[0] - lo[:2]) / grid_m - 0.5).astype(np.int64)
    last = np.floor((area_xy[1] - lo[:2]) / grid_m - 0.5).astype(np.int64) + 1
    x0, y0 = (min(max(int(v), 0), n) for v, n in zip(first, (nx, ny), strict=True))
    x1, y1 = (min(max(int(v), lo_), n) for v, lo_, n in zip(last, (x0, y0), (nx, ny),
                                                           strict=True))
    return nx, ny, x0, x1, y0, y1


def _floor_samples(scene: Scene, caster: RayCaster, grid_m: float,
                   area_xy: NDArray[np.float64] | None = None) -> _Samples:
    """The floor samples of the grid over the model's footprint (within the (2, 2)
    ``area_xy``, see :func:`_columns`), ordered by column, then height; the lowest surface
    of every column (+inf: none; -inf: more surfaces than followed)."""
    lo, hi = scene.bounds
    nx, ny, x0, x1, y0, y1 = _columns(scene, grid_m, area_xy)
    grid_x, grid_y = np.meshgrid(np.arange(x0, x1), np.arange(y0, y1), indexing="ij")
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
        horizontal[own] = np.abs(scene.normals_of(face[own])[:, 2]) >= _MIN_FLOOR_NZ
        above = floor + np.array([0.0, 0.0, _EPS_M * 10])
        _, free = caster.first_hit(above, up[: len(above)])
        keep = horizontal & (free >= HEADROOM_M)
        points.append(floor[keep])
        columns.append(alive[keep])
        covered.append(np.isfinite(free[keep]))
        z[alive] = floor[:, 2] - _EPS_M  # continue below this surface
    else:
        lowest[alive] = -np.inf  # surfaces left below: the lowest one is not known
    lowest_z = lowest.reshape(x1 - x0, y1 - y0)
    if not points:
        return _Samples(np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros(0, np.int64),
                        np.zeros(0, bool), lowest_z, nx, ny, x0, x1, y0, y1)
    floor_xyz = np.concatenate(points)
    column = np.concatenate(columns)
    order = np.lexsort((floor_xyz[:, 2], column))  # by column, then height: deterministic
    floor_xyz, column = floor_xyz[order], column[order]
    return _Samples(floor_xyz, ix[column], iy[column], np.concatenate(covered)[order],
                    lowest_z, nx, ny, x0, x1, y0, y1)


def _ground_nodes(scene: Scene, samples: _Samples, grid_m: float
                  ) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.int64]]:
    """(G, 3) ground nodes and their (G,) grid columns (which may lie outside the model's
    grid, by up to ``OUTSIDE_MARGIN_M``, on the sides where the walked columns reach its
    edge): see the module docstring."""
    covered = samples.covered
    if not covered.any():
        return np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros(0, np.int64)
    x0, x1, y0, y1 = samples.x0, samples.x1, samples.y0, samples.y1
    # the ground floor: the lowest indoor floor at the building's edge, next to a column
    # with nothing in it (a threshold); a basement is walled in. Else the lowest indoor floor
    empty = np.ones((x1 - x0 + 2, y1 - y0 + 2), bool)  # a ring of empty columns around
    empty[1:-1, 1:-1] = np.isposinf(samples.lowest_z)
    at_edge = np.zeros(len(covered), bool)
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            at_edge |= empty[samples.ix - x0 + 1 + dx, samples.iy - y0 + 1 + dy]
    edge_floor = covered & at_edge
    ground_z = float(samples.floor_xyz[edge_floor if edge_floor.any() else covered, 2].min())
    margin = math.ceil(OUTSIDE_MARGIN_M / grid_m)
    grid_x, grid_y = np.meshgrid(
        np.arange(x0 - margin if x0 == 0 else x0, x1 + margin if x1 == samples.nx else x1),
        np.arange(y0 - margin if y0 == 0 else y0, y1 + margin if y1 == samples.ny else y1),
        indexing="ij")
    ix, iy = grid_x.ravel(), grid_y.ravel()
    inside = (ix >= x0) & (ix < x1) & (iy >= y0) & (iy < y1)
    lowest = np.full(len(ix), np.inf)
    lowest[inside] = samples.lowest_z[ix[inside] - x0, iy[inside] - y0]
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
    free = free_both_ways(caster, a, b)
    for height in UPRIGHT_HEIGHTS_M:
        if height == KNEE_HEIGHT_M or not free.any():
            continue
        lift = np.array([0.0, 0.0, height - KNEE_HEIGHT_M])
        index = np.flatnonzero(free)
        free[index] = free_both_ways(caster, a[index] + lift, b[index] + lift)
    return free


def free_both_ways(caster: RayCaster, a: NDArray[np.float64], b: NDArray[np.float64]
                   ) -> NDArray[np.bool_]:
    """(K,) bool: the (K, 3) segments a -> b are free cast from a and from b (a ray from
    inside a solid meets nothing on its way out: one direction alone can miss a wall)."""
    result: NDArray[np.bool_] = segment_free(caster, a, b) & segment_free(caster, b, a)
    return result


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

def _walk_grid_m(scene: Scene, area_xy: NDArray[np.float64] | None = None) -> float:
    """The walk grid's spacing: ``WALK_GRID_M``, coarser where the walked ground (the
    model's footprint, within the (2, 2) ``area_xy`` when given) spans more than
    ``MAX_COLUMNS`` columns."""
    lo, hi = scene.bounds
    lo, hi = lo[:2], hi[:2]
    if area_xy is not None:
        lo, hi = np.maximum(lo, area_xy[0]), np.maximum(np.minimum(hi, area_xy[1]), lo)
    columns = ((hi[0] - lo[0]) / WALK_GRID_M + 1) * ((hi[1] - lo[1]) / WALK_GRID_M + 1)
    return WALK_GRID_M * max(1.0, math.sqrt(columns / MAX_COLUMNS))


def walk_area(positions: NDArray[np.float64]) -> NDArray[np.float64] | None:
    """(2, 2) [[x, y] least, [x, y] most]: the ground the walk covers for candidates at the
    (C, 3) ``positions``, their footprint and ``WALK_AREA_MARGIN_M`` around it (None: no
    candidates, the whole model)."""
    if len(positions) == 0:
        return None
    xy = np.asarray(positions, np.float64)[:, :2]
    return np.stack([xy.min(axis=0) - WALK_AREA_MARGIN_M, xy.max(axis=0) + WALK_AREA_MARGIN_M])


def _neighbour_pairs(floor_xyz: NDArray[np.float64], ix: NDArray[np.int64],
                     iy: NDArray[np.int64], reach: int = 1
                     ) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """(P,) a and (P,) b: the pairs of the (N, 3) floor samples in neighbouring grid
    columns (8 neighbours; columns (N,) ix, iy; ``reach`` 2: the columns two steps away
    along the same 8 directions instead) whose heights differ by at most ``STEP_M``, each
    pair once: direction by direction, by a, then by b's height in its column.

    Found by a compiled search of each neighbour column in the samples sorted by column,
    counted and then written: no (P,) temporaries. (As numpy's repeats and gathers of every
    pair in reach, filtered afterwards, the links of a house's 114 x 203 m site made its
    plan's peak.)"""
    n = len(floor_xyz)
    if n == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    # nodes by grid column: a neighbour column's nodes are found by a sorted-key search
    # (columns shifted to start at 0; the model's own samples are sorted already)
    ix, iy = ix - int(ix.min()), iy - int(iy.min())
    width = int(iy.max()) + 1 + reach
    key = ix * width + iy
    by_key = np.lexsort((floor_xyz[:, 2], key))
    sorted_key = key[by_key]
    z = np.ascontiguousarray(floor_xyz[:, 2])
    count = _neighbours(sorted_key, by_key, ix, iy, width, reach, z, STEP_M,
                        np.zeros(0, np.int64), np.zeros(0, np.int64))
    a, b = np.empty(count, np.int64), np.empty(count, np.int64)
    _neighbours(sorted_key, by_key, ix, iy, width, reach, z, STEP_M, a, b)
    return a, b


@numba.njit(nogil=True, cache=True)
def _neighbours(sorted_key: NDArray[np.int64], by_key: NDArray[np.int64],
                ix: NDArray[np.int64], iy: NDArray[np.int64], width: int, reach: int,
                z: NDArray[np.float64], step_m: float, out_a: NDArray[np.int64],
                out_b: NDArray[np.int64]) -> int:
    """Count the pairs of :func:`_neighbour_pairs`, writing them into ``out_a`` and
    ``out_b`` when they have room; compiled."""
    write = out_a.shape[0] > 0
    n = 0
    for dx, dy in ((1, 0), (0, 1), (1, 1), (1, -1)):
        for i in range(ix.shape[0]):
            target = (ix[i] + reach * dx) * width + (iy[i] + reach * dy)
            first = np.searchsorted(sorted_key, target, side="left")
            stop = np.searchsorted(sorted_key, target, side="right")
            for m in range(first, stop):
                j = by_key[m]
                if abs(z[i] - z[j]) <= step_m:
                    if write:
                        out_a[n] = i
                        out_b[n] = j
                    n += 1
    return n


def build_walk_graph(scene: Scene, caster: RayCaster, *, ground: bool = True,
                     area_xy: NDArray[np.float64] | None = None) -> WalkGraph:
    """The walk graph of ``scene`` (see the module docstring); ``ground``: add the ground
    nodes of a model without terrain; ``area_xy``: (2, 2), [[x, y] least, [x, y] most], the
    ground walked (:func:`walk_area`; None: the model's whole footprint)."""
    grid_m = _walk_grid_m(scene, area_xy)
    samples = _floor_samples(scene, caster, grid_m, area_xy)
    floor_xyz, ix, iy = samples.floor_xyz, samples.ix, samples.iy
    n_ground = 0
    if ground:
        ground_xyz, ground_ix, ground_iy = _ground_nodes(scene, samples, grid_m)
        n_ground = len(ground_xyz)
        floor_xyz = np.concatenate([floor_xyz, ground_xyz])
        ix, iy = np.concatenate([ix, ground_ix]), np.concatenate([iy, ground_iy])
    n = len(floor_xyz)
    a, b = _neighbour_pairs(floor_xyz, ix, iy)
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
    cut = np.zeros(n, bool)  # a column on a side where the area cuts the footprint
    for index, first, last, count in ((ix, samples.x0, samples.x1, samples.nx),
                                      (iy, samples.y0, samples.y1, samples.ny)):
        if first > 0:
            cut |= index == first
        if last < count:
            cut |= index == last - 1
    covered = np.concatenate([samples.covered, np.zeros(n_ground, bool)])
    return WalkGraph(floor_xyz=floor_xyz, links=links, grid_m=grid_m, n_ground=n_ground,
                     cut_nodes=np.flatnonzero(cut), covered=covered)
