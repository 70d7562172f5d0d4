"""Scanner positions to choose from: given explicitly, or generated on a grid.

The grid lies in the XY plane at multiples of ``grid_spacing_m`` (so a model moved by a
whole number of cells gets the same points), inside the optional ``area_of_interest``
polygon. Each point is put ``scanner_height_m`` above the floor under it, found by casting a
ray up from below the model (the lowest surface is the floor; multi-storey IFC models use
their rooms instead, see :mod:`planner.io.ifc`); with ``floor_levels`` "storeys" (the
default) on every storey too, told from furniture by :func:`storey_levels`. A point is
dropped, and counted under its reason, when

- ``outside_area_of_interest``: not covered by the polygon (boundary counts as inside);
  without a polygon, the area of interest is the building: a point on open ground with
  nothing of the building within reach is left out (:func:`on_the_building`);
- ``no_floor``: nothing under it, or the surface under it is steeper than 30 degrees;
- ``blocked_above_floor``: something lies between the floor and ``clearance_m`` above the
  scanner (a table, a low machine, a shelf);
- ``inside_geometry``: inside a closed object (generalised winding number of an object's
  faces above one half; objects are the model's groups, normals pointing outward);
- ``too_close``: an obstacle's footprint within ``clearance_m`` of the tripod's vertical axis,
  counting every face that reaches between the floor and ``clearance_m`` above the scanner
  (a tripod needs that room at the floor too, not only at the scanner head).

Array letters: C candidates, N grid points.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree
from shapely import Polygon, intersects_xy

from planner.candidates.scratch import keep, kept_or_none, reused
from planner.candidates.winding import (
    cells_winding_numbers,
    coordinate_ranks,
    needs_cells,
    winding_cells,
    winding_numbers,
)
from planner.errors import NoCandidatesError, ParameterError
from planner.limits import FaceLimits
from planner.memory import release_freed_memory
from planner.parameters import PlanSpec
from planner.rays import RayCaster
from planner.scene import (
    Scene,
    column_bounds,
    corner_extremes,
    kept_pieces,
    longest_edges_m,
)
from planner.threads import in_block_order
from planner.walkgraph import HEADROOM_M, KNEE_HEIGHT_M, build_walk_graph, cell_pairs

DROP_REASONS = (
    "outside_area_of_interest",
    "no_floor",
    "blocked_above_floor",
    "inside_geometry",
    "too_close",
)
_MAX_FLOOR_SLOPE_DEG = 30.0
# grid points per spatial query in closer_than: bounds its pair arrays
_POINTS_PER_QUERY = 256
# faces whose footprint closer_than measures at a time (bounds its (B, 3, 2) corners)
_FOOTPRINTS_PER_BLOCK = 1 << 20
# closer_than: a face's centre this much nearer than the radius puts the face within it,
# whatever the rounding of the distances (far below a micrometre on a model of kilometres)
_SURE_MARGIN_M = 1e-6
# floor_levels "all": surfaces followed up each ray, the step past each, the height gap
# that separates two levels, and the least area of a level (a table top or a stair tread
# is smaller; a landing of 2 x 2 m is not)
_MAX_SURFACES = 32
_SURFACE_STEP_M = 1e-4
_LEVEL_GAP_M = 0.15
_MIN_LEVEL_AREA_M2 = 4.0
# floor_levels "storeys": a floor is level. A walking surface steeper than 1:20 is a ramp
# (ADA 2010 405.1, ISO 21542), or the terrain around a building: it fills the heights
# between two floors, so only level surfaces tell a storey's height (a slope joins the level
# it meets, never two levels)
_LEVEL_FLOOR_NORMAL_Z = 20.0 / math.hypot(1.0, 20.0)
# floor_levels "storeys": a patch with a lower floor beside it along more than this share of
# its edge is raised (furniture), not a storey
_RAISED_EDGE_SHARE = 0.5
# a level with less than this share of the building's footprint (the grid cells with a floor
# on some level) is small: between two storeys it is a landing, not a storey. A stair's
# landing is a few m² (a 1.2 m wide stair's half landing: 3 to 6 m²), 1-3 % of an office's
# footprint and under 10 % of a house's; a storey, even an attic or a gallery, holds more
_MIN_STOREY_SHARE = 0.1
# a building of one storey is planned on its lowest surface (as floor_levels "lowest") when
# that gives at least this share of the storey's candidates: the lowest surface is then the
# floor. A slab modelled with its underside is not: the underside is the lowest surface,
# blocked by the slab's own top (Amersfoort's plain mesh: 1 candidate, its storey 1,458)
_LOWEST_SHARE = 0.5
# two floors closer in height than a person's head room (HEADROOM_M) are not one over the
# other: the smaller is a split level of the larger's storey (a house's rooms a few steps
# up or down, a stair landing a metre under the next storey)
_NOT_A_STOREY = {
    "split": "split level: within " + f"{HEADROOM_M:g}" + " m of the floor of the larger "
             "storey at {storey}, so not a storey of its own; its candidates count with it",
    "landing": "landing: a small floor between two storeys (less than "
               + f"{_MIN_STOREY_SHARE:.0%}" + " of the building's footprint); its "
               "candidates count with the storey at {storey}, below it",
}


# a model whose candidates are fewer than this share of the grid points over the building
# has little floor: a building's floors hold a candidate at 8 % (IfcOpenHouse, a small house
# amid the walls' reach) to 40 % (Lantern Hollow) of them; the shared buildings without
# their slabs (an architect's model, the slabs in the structural model) at 0.03 - 2 %, on
# stair treads, landings and the tops of walls and furniture
_LITTLE_FLOOR_SHARE = 0.04
# what such a model lacks, and what to send instead
_NO_SLABS = ("a model without its floor slabs (an architect's model, the slabs in the "
             "structural one)? Send it as IFC with its rooms (IfcSpace), whose bottoms are "
             "then the floors, or with its slabs")


def floor_note(candidates: int, building_points: int, grid_spacing_m: float) -> str | None:
    """What to tell a user whose model gives ``candidates`` of the ``building_points`` grid
    points over the building (those not outside it); None when that is floor enough."""
    if building_points <= 0 or candidates >= _LITTLE_FLOOR_SHARE * building_points:
        return None
    cell_m2 = grid_spacing_m ** 2
    return (f"the model has floor to stand on at {candidates} of the {building_points} grid "
            f"points over the building ({candidates * cell_m2:.1f} of "
            f"{building_points * cell_m2:.0f} m²): {_NO_SLABS}")


# the building, not the site (on_the_building): upright surfaces are sampled this far apart
_BUILDING_SAMPLE_M = 0.5


@dataclass(frozen=True, eq=False)
class CandidateSet:
    """The positions considered, and why the other grid points were left out.

    Attributes
    ----------
    positions : (C, 3) float64, metres, model coordinates
    source : "explicit", "grid" or "rooms"
    considered : grid points before any was dropped (C for explicit candidates)
    dropped : count per reason in ``DROP_REASONS``
    labels : per candidate, e.g. the room and storey it stands in (empty when unknown)
    levels : name, floor height (and for "storeys" area) and candidate count per level,
        and for "storeys" the levels left out with the reason (``excluded``)
    floor_from_space : room candidates: the rooms without a slab, standing on their
        IfcSpace's bottom
    rooms : room candidates: every IfcSpace with its storey, area, grid points,
        candidates and, where it has none, the reason (:func:`planner.candidates.rooms.
        room_report`)
    heights_m : (C,) float64, each candidate's height above its floor when it was placed
        on one (NaN: not known, e.g. a fixed station); None for explicit candidates
    also_in : room candidates: per candidate, the GlobalIds of the rooms besides its
        label's that it stands in (rooms overlapping the label's, listed after it; empty
        for most), or empty when unknown
    floor_note : grid candidates on a model with little floor for its footprint (an
        architect's model without its slabs): what is missing and what to send instead
    """

    positions: NDArray[np.float64]
    source: str
    considered: int
    dropped: dict[str, int] = field(default_factory=dict)
    labels: tuple[dict[str, str], ...] = ()
    levels: list[dict[str, object]] | None = None
    floor_from_space: tuple[str, ...] | None = None
    heights_m: NDArray[np.float64] | None = None
    rooms: list[dict[str, object]] | None = None
    also_in: tuple[tuple[str, ...], ...] = ()
    floor_note: str | None = None

    def __len__(self) -> int:
        return len(self.positions)

    def summary(self) -> dict[str, object]:
        summary: dict[str, object] = {
            "source": self.source,
            "count": len(self),
            "considered": self.considered,
            "dropped": dict(self.dropped),
        }
        if self.levels is not None:
            summary["levels"] = list(self.levels)
        if self.floor_from_space is not None:
            summary["floor_from_space"] = list(self.floor_from_space)
        if self.rooms is not None:
            summary["rooms"] = list(self.rooms)
        if self.floor_note is not None:
            summary["floor_note"] = self.floor_note
        return summary


def explicit_candidates(points: NDArray[np.float64] | tuple[tuple[float, float, float], ...]
                        ) -> CandidateSet:
    """Candidates given by the user, kept as they are and in their order."""
    positions = np.asarray(points, np.float64).reshape(-1, 3)
    if len(positions) == 0:
        raise NoCandidatesError("the candidate list is empty; give at least one x, y, z")
    if not np.isfinite(positions).all():
        bad = int(np.flatnonzero(~np.isfinite(positions).all(axis=1))[0])
        raise ParameterError("candidates", f"point {bad} has a non-finite coordinate")
    return CandidateSet(positions=positions, source="explicit", considered=len(positions))


def read_candidates_csv(path: str | Path) -> NDArray[np.float64]:
    """(C, 3) float64 from a CSV with a header row ``x,y,z``."""
    path = Path(path)
    try:
        with path.open(newline="", encoding="utf-8") as handle:
            rows = list(csv.reader(handle))
    except OSError as exc:
        raise ParameterError("candidates", f"cannot read {path}: {exc.strerror}") from exc
    if not rows or [h.strip().lower() for h in rows[0][:3]] != ["x", "y", "z"]:
        raise ParameterError("candidates", f"{path.name} needs a header row 'x,y,z'")
    points = []
    for line_no, row in enumerate(rows[1:], start=2):
        if not row or not "".join(row).strip():
            continue
        try:
            points.append([float(v) for v in row[:3]])
        except ValueError as exc:
            raise ParameterError(
                "candidates", f"{path.name} line {line_no}: {row!r} is not three numbers"
            ) from exc
        if len(points[-1]) != 3:
            raise ParameterError("candidates", f"{path.name} line {line_no}: needs x,y,z")
    return np.asarray(points, np.float64).reshape(-1, 3)


def grid_points_xy(
    bounds_xy: NDArray[np.float64], spacing_m: float, polygon: Polygon | None = None
) -> NDArray[np.float64]:
    """(N, 2) grid points at multiples of ``spacing_m`` inside (2, 2) bounds, row by row."""
    lo, hi = bounds_xy
    if polygon is not None:
        px0, py0, px1, py1 = polygon.bounds
        lo = np.maximum(lo, [px0, py0])
        hi = np.minimum(hi, [px1, py1])
    start = np.ceil(lo / spacing_m - 1e-9).astype(np.int64)
    stop = np.floor(hi / spacing_m + 1e-9).astype(np.int64)
    xs = np.arange(start[0], stop[0] + 1) * spacing_m
    ys = np.arange(start[1], stop[1] + 1) * spacing_m
    gx, gy = np.meshgrid(xs, ys)  # rows of constant y, x fastest
    return np.column_stack([gx.ravel(), gy.ravel()])


def generate_grid(scene: Scene, spec: PlanSpec, caster: RayCaster) -> CandidateSet:
    """Grid candidates over the model's footprint (see the module docstring)."""
    polygon = None
    if spec.area_of_interest is not None:
        polygon = Polygon(spec.area_of_interest)
        if not polygon.is_valid or polygon.area <= 0:
            raise ParameterError(
                "area_of_interest", "is not a valid polygon (self-intersecting or flat)"
            )
    bounds = scene.bounds
    xy = grid_points_xy(bounds[:, :2], spec.grid_spacing_m, polygon)
    considered = len(xy)
    dropped = dict.fromkeys(DROP_REASONS, 0)
    if polygon is not None and len(xy):
        inside = intersects_xy(polygon, xy[:, 0], xy[:, 1])
        dropped["outside_area_of_interest"] = int((~inside).sum())
        xy = xy[inside]
    if polygon is None and len(xy):  # the building, not the site: a quick first cut
        near = near_targets_xy(scene, spec, xy)
        dropped["outside_area_of_interest"] += int((~near).sum())
        xy = xy[near]
    outside_polygon = dropped["outside_area_of_interest"]
    labels: tuple[dict[str, str], ...] = ()
    levels: list[dict[str, object]] | None = None
    if spec.floor_levels == "all":
        positions, level_of = place_on_levels(scene, xy, spec, caster, dropped)
        # a point may stand on several levels: count what was looked at, level by level
        considered = len(positions) + sum(dropped.values())
        floors = positions[:, 2] - spec.scanner_height_m
        if polygon is None:  # the building, not the site (first: no clearance test on it)
            on = on_the_building(scene, spec, positions, floors, caster)
            dropped["outside_area_of_interest"] += int((~on).sum())
            positions, level_of, floors = positions[on], level_of[on], floors[on]
        keep = unclear_mask(scene, positions, spec.clearance_m, dropped, floors)
        positions, level_of = positions[keep], level_of[keep]
        levels, labels = _level_labels(positions[:, 2] - spec.scanner_height_m, level_of)
    else:
        positions = place_on_floor(scene, xy, spec, caster, dropped)
        if polygon is None:  # the building, not the site (first: no clearance test on it)
            floors = positions[:, 2] - spec.scanner_height_m
            on = on_the_building(scene, spec, positions, floors, caster)
            dropped["outside_area_of_interest"] += int((~on).sum())
            positions = positions[on]
        floors = positions[:, 2] - spec.scanner_height_m
        positions = drop_unclear(scene, positions, spec.clearance_m, dropped, floors)
        if spec.floor_levels == "storeys":
            placed, placed_level, report, storey_dropped = storey_levels(
                scene, xy, spec, caster, ground_candidates=len(positions))
            names: list[str] = []
            if placed is not None and placed_level is not None:
                storey_dropped["outside_area_of_interest"] += outside_polygon
                positions, dropped = placed, storey_dropped
                considered = len(positions) + sum(dropped.values())
                storey_z = [float(str(entry["floor_z_m"])) for entry in report
                            if "excluded" not in entry and int(str(entry["candidates"]))]
                named, labels = _level_labels(positions[:, 2] - spec.scanner_height_m,
                                              placed_level, storey_z)
                names = [str(entry["name"]) for entry in named]
            levels = _storey_report(report, len(positions) if placed is None else None, names)
        if spec.floor_levels == "walkable":
            walkable = walkable_levels(scene, xy, spec, caster,
                                       ground_found=len(positions) > 0)
            if walkable is not None:
                positions, level_of = walkable
                levels, labels = _level_labels(positions[:, 2] - spec.scanner_height_m,
                                               level_of)
    if len(positions) == 0:
        counts = ", ".join(f"{k}: {v}" for k, v in dropped.items() if v)
        if dropped.get("no_floor", 0) * 2 > considered - dropped["outside_area_of_interest"]:
            # most of the building's grid points found no floor under them: not a matter
            # of the parameters
            raise NoCandidatesError(
                f"no grid point is left out of {considered} ({counts}): most of the "
                f"building's points have no floor under them. {_NO_SLABS[0].upper()}"
                f"{_NO_SLABS[1:]}; or give candidates explicitly")
        raise NoCandidatesError(
            f"no grid point is left out of {considered} "
            f"({counts}); lower clearance_m "
            f"({spec.clearance_m}) or grid_spacing_m ({spec.grid_spacing_m}), check "
            "area_of_interest, or give candidates explicitly"
        )
    note = None if polygon is not None else floor_note(
        len(positions), considered - dropped["outside_area_of_interest"], spec.grid_spacing_m)
    return CandidateSet(positions=positions, source="grid", considered=considered,
                        dropped=dropped, labels=labels, levels=levels, floor_note=note)


def walkable_levels(
    scene: Scene, xy: NDArray[np.float64], spec: PlanSpec, caster: RayCaster, *,
    ground_found: bool,
) -> tuple[NDArray[np.float64], NDArray[np.int64]] | None:
    """``floor_levels`` "walkable": (C, 3) candidates on the lowest level of
    :func:`place_on_levels` and on every upper level a person reaches from it on foot, with
    their (C,) level; None when no upper level is reachable and ``ground_found`` (the
    lowest surface then gave the candidates, exactly as "lowest" does).

    The lowest *surface* under a point is the underside of a thick ground slab in many
    exported models, where "lowest" finds no floor at all; the lowest *level* is the first
    flat surface with head room. Reachable means: the candidate's floor point lies on a
    node of the walk graph (:mod:`planner.walkgraph`: floor samples linked within a
    step and free at knee height, so stairs join storeys) whose connected component also
    holds a floor point of the lowest level. A machine or table top is a flat surface with
    head room, but no step leads onto it.
    """
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    levels_dropped = dict.fromkeys(DROP_REASONS, 0)
    positions, level_of = place_on_levels(scene, xy, spec, caster, levels_dropped)
    floors = positions[:, 2] - spec.scanner_height_m
    keep = unclear_mask(scene, positions, spec.clearance_m, levels_dropped, floors)
    positions, level_of = positions[keep], level_of[keep]
    if len(positions) == 0 or (ground_found and not (level_of > level_of.min()).any()):
        return None
    ground = level_of == level_of.min()
    reachable = ground.copy()
    if not ground.all():
        graph = build_walk_graph(scene, caster)
        _, component = connected_components(graph.links, directed=False)
        tree = cKDTree(graph.floor_xyz)
        floor_xyz = positions - np.array([0.0, 0.0, spec.scanner_height_m])
        # a grid point lies within one walk-grid cell of some floor sample of its surface
        distance, node = tree.query(floor_xyz, distance_upper_bound=graph.grid_m)
        found = np.isfinite(distance)
        node_component = np.full(len(positions), -1)
        node_component[found] = component[node[found]]
        ground_components = np.unique(node_component[ground & found])
        reachable |= found & np.isin(node_component, ground_components)
    if ground_found and reachable.sum() == ground.sum():
        return None
    return positions[reachable], level_of[reachable]


def storey_levels(
    scene: Scene, xy: NDArray[np.float64], spec: PlanSpec, caster: RayCaster, *,
    ground_candidates: int,
) -> tuple[NDArray[np.float64] | None, NDArray[np.int64] | None, list[dict[str, object]],
           dict[str, int]]:
    """``floor_levels`` "storeys": (C, 3) candidates on every storey under the (N, 2) grid
    points with their (C,) level, the report of every level (storeys and what was
    excluded, with the reason) and the grid points dropped per reason (the points of
    excluded levels count as ``no_floor``). Positions and levels are None when the only
    storey is the lowest level and the ``ground_candidates`` that the lowest surface gives
    are at least ``_LOWEST_SHARE`` of the storey's: the lowest surface is the floor, and
    gives the candidates exactly as "lowest" does (a slab's underside is not the floor).

    How a storey is told from furniture, without semantics or the walk graph:

    1. *Floor with head room*: the walkable surfaces of :func:`walkable_surfaces` (flatter
       than 30 degrees, more than ``scanner_height_m`` + ``clearance_m`` free above, a
       ceiling over every surface but the lowest).
    2. *Patches*: surfaces of neighbouring grid points (8 neighbours) whose heights differ
       by at most ``_LEVEL_GAP_M`` are one patch (a room's floor, a table top).
    3. *Raised*: a patch that stands less than ``HEADROOM_M`` (1.8 m) above a floor beside
       it along most (``_RAISED_EDGE_SHARE``) of its edge is furniture, a machine or a
       platform (a table top is 0.75 m above the floor around it, a bed 0.5 m); an upper
       storey's edge meets walls, facades and stairwells, a mezzanine's the hall floor
       more than 1.8 m below, so people fit under it.
    4. *Area*: the patches that are not raised are grouped by height into levels; a level
       of less than ``_MIN_LEVEL_AREA_M2`` is stair treads or a small landing, no floor.
       Only level surfaces (no steeper than 1:20) are grouped so: a slope (a ramp, the
       terrain around the building) joins the level it meets and is no floor elsewhere,
       since it fills every height between two floors (:func:`_floor_levels`).
    5. *Split levels*: two floor levels closer in height than ``HEADROOM_M`` are not one
       over the other (nobody stands under a floor 1.8 m above his own), so they are one
       storey: the larger level is the storey, the smaller a split level of it (a
       house's rooms a few steps up, a landing a metre under the next storey).
    6. *Landings*: a level of less than ``_MIN_STOREY_SHARE`` of the building's footprint
       (the grid cells with a floor on any level) with a storey below it and one above is
       a stair's landing, part of the storey below (from which its stair leads up).

    Split levels and landings keep their candidates, labelled with their storey, and are
    listed in the report as not storeys, with the reason and the storey's height
    (:func:`_storeys_of_levels`). The rule is the geometry's alone: heights, areas and the
    footprint, no class or name of the model.

    A storey gets candidates whether or not a person can walk to it (the route reports a
    station nobody reaches, with the reason).
    """
    dropped = dict.fromkeys(DROP_REASONS, 0)
    point, floor_z, normal_z = walkable_surfaces(scene, xy, spec, caster, dropped)
    if spec.area_of_interest is None and len(point):  # the building, not the site (first:
        # no winding numbers over a site's terrain)
        on = on_the_building(scene, spec, np.column_stack(
            [xy[point], floor_z + spec.scanner_height_m]), floor_z, caster)
        dropped["outside_area_of_interest"] += int((~on).sum())
        point, floor_z, normal_z = point[on], floor_z[on], normal_z[on]
    # a grid point inside a wall stands on the wall's foot with the wall's height over it:
    # such surfaces would join a floor to the ground outside the wall, so they go before
    # the levels are found
    inside = inside_closed_groups(
        scene, np.column_stack([xy[point], floor_z + spec.scanner_height_m]))
    dropped["inside_geometry"] += int(inside.sum())
    point, floor_z, normal_z = point[~inside], floor_z[~inside], normal_z[~inside]
    if len(point) == 0:
        return None, None, [], dropped
    cell = spec.grid_spacing_m
    gx = np.round(xy[point] / cell).astype(np.int64)  # (K, 2) grid coordinates
    gx -= gx.min(axis=0)
    width = int(gx[:, 1].max()) + 3
    key = (gx[:, 0] + 1) * width + gx[:, 1] + 1  # a ring of empty columns around
    order = np.lexsort((floor_z, key))
    sorted_key, sorted_z = key[order], floor_z[order]
    n = len(point)
    rows: list[NDArray[np.int64]] = []
    cols: list[NDArray[np.int64]] = []
    neighbours: list[tuple[NDArray[np.int64], NDArray[np.int64]]] = []
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            if dx == 0 and dy == 0:
                continue
            target = key + dx * width + dy
            a, b = cell_pairs(sorted_key, order, target)
            neighbours.append((a, b))
            close = np.abs(floor_z[a] - floor_z[b]) <= _LEVEL_GAP_M
            rows.append(a[close])
            cols.append(b[close])
    del sorted_z
    a, b = np.concatenate(rows), np.concatenate(cols)
    graph = sp.coo_matrix((np.ones(len(a), np.int8), (a, b)), shape=(n, n))
    _, patch = connected_components(graph, directed=False)
    # raised: along the patch's edge (a grid point and a direction with no neighbour of the
    # same patch), how often a floor lies between _LEVEL_GAP_M and HEADROOM_M below
    edge = np.zeros(n, np.int64)
    lower = np.zeros(n, np.int64)
    for a, b in neighbours:
        same = np.zeros(n, bool)
        below = np.zeros(n, bool)
        np.logical_or.at(same, a, patch[a] == patch[b])
        drop = floor_z[a] - floor_z[b]
        np.logical_or.at(below, a, (drop > _LEVEL_GAP_M) & (drop < HEADROOM_M))
        edge += ~same
        lower += ~same & below
    n_patches = int(patch.max()) + 1
    patch_edge = np.bincount(patch, edge, n_patches)
    patch_lower = np.bincount(patch, lower, n_patches)
    raised_patch = patch_lower > _RAISED_EDGE_SHARE * np.maximum(patch_edge, 1)
    raised = raised_patch[patch]
    flat = normal_z >= _LEVEL_FLOOR_NORMAL_Z
    if not flat.any():  # no level surface (a mesh with noisy normals): heights alone
        flat[:] = True
    level, sloped_level = _floor_levels(floor_z, flat)
    n_levels = int(level.max()) + 1
    area = np.bincount(level, ~raised, n_levels) * cell ** 2
    # a floor needs its least area of level floor: slopes joined to a terrace do not make one
    floor_level = np.bincount(level, ~raised & flat, n_levels) * cell ** 2 \
        >= _MIN_LEVEL_AREA_M2
    eligible = floor_level[level] & ~raised
    dropped["no_floor"] += int((~eligible).sum())  # listed under the levels, with the reason
    positions = np.column_stack([xy[point[eligible]],
                                 floor_z[eligible] + spec.scanner_height_m])
    level_of = level[eligible]
    near = closer_than(scene, positions, spec.clearance_m,
                       positions[:, 2] - spec.scanner_height_m)
    dropped["too_close"] += int(near.sum())
    keep = ~near
    positions, level_of = positions[keep], level_of[keep]
    grid_row = point[eligible][keep]
    counts = np.bincount(level_of, minlength=n_levels)
    # a level's height is its level floor's (a slope joined to it spans heights)
    heights = np.array([float(np.median(floor_z[(level == k) & (flat | sloped_level[k])]))
                        for k in range(n_levels)])
    # the building's footprint: every grid cell with a floor on some level
    footprint_m2 = len(np.unique(key[~raised])) * cell ** 2
    storey_of, kind = _storeys_of_levels(heights, np.asarray(area, np.float64), counts,
                                         floor_level, footprint_m2)
    storey_ids = np.flatnonzero(storey_of == np.arange(n_levels))  # the anchors, by height
    rank = np.full(n_levels, -1, np.int64)
    rank[storey_ids] = np.arange(len(storey_ids))
    storey_of_candidate = rank[storey_of[level_of]]
    # storey by storey, grid rows within, lower floors first on a grid row
    order = np.lexsort((positions[:, 2], grid_row, storey_of_candidate))
    positions, storey_of_candidate = positions[order], storey_of_candidate[order]
    lowest_only = len(storey_of_candidate) == 0 or (storey_of_candidate
                                                     == storey_of_candidate.min()).all()
    if ground_candidates and lowest_only and ground_candidates >= _LOWEST_SHARE * len(positions):
        positions_out, level_out = None, None
    else:
        positions_out, level_out = positions, storey_of_candidate
    report: list[dict[str, object]] = []
    storey_counts = np.bincount(storey_of[level_of], minlength=n_levels)
    storey_area = np.bincount(storey_of[floor_level], area[floor_level], n_levels)
    for k in range(n_levels):
        members = level == k
        height = round(float(heights[k]), 3) + 0.0  # no -0.0
        if floor_level[k] and storey_of[k] == k:
            entry: dict[str, object] = {"floor_z_m": height,
                                        "area_m2": round(float(storey_area[k]), 2),
                                        "candidates": int(storey_counts[k])}
            parts = [round(float(heights[j]), 3) + 0.0 for j in range(n_levels)
                     if floor_level[j] and storey_of[j] == k and j != k]
            if parts:
                entry["with_levels_m"] = parts
            report.append(entry)
        elif floor_level[k]:
            owner = f"{round(float(heights[storey_of[k]]), 2) + 0.0:+.2f} m"  # no -0.00
            report.append({"floor_z_m": height, "area_m2": round(float(area[k]), 2),
                           "candidates": int(counts[k]), "storey_floor_z_m":
                           round(float(heights[storey_of[k]]), 3) + 0.0,
                           "excluded": _NOT_A_STOREY[kind[k]].format(storey=owner)})
        elif area[k] > 0 and sloped_level[k]:
            report.append({"floor_z_m": height, "area_m2": round(float(area[k]), 2),
                           "candidates": 0,
                           "excluded": "sloped: steeper than 1:20 (a ramp, the terrain) and "
                                       f"more than {_LEVEL_GAP_M:g} m from the height of "
                                       "any level floor, so no floor of a storey"})
        elif area[k] > 0:
            report.append({"floor_z_m": height, "area_m2": round(float(area[k]), 2),
                           "candidates": 0,
                           "excluded": f"too small: less than {_MIN_LEVEL_AREA_M2:g} m² of "
                                       "floor at this height (stair treads, a landing)"})
        up = members & raised
        if up.any():
            report.append({"floor_z_m": round(float(np.median(floor_z[up])), 3) + 0.0,
                           "area_m2": round(float(up.sum() * cell ** 2), 2), "candidates": 0,
                           "excluded": f"raised: less than {HEADROOM_M:g} m above the floor "
                                       "beside it along most of its edge (furniture, a "
                                       "machine top, a platform, a stair tread)"})
    return positions_out, level_out, report, dropped


def _storeys_of_levels(heights_m: NDArray[np.float64], area_m2: NDArray[np.float64],
                       candidates: NDArray[np.int64], floor_level: NDArray[np.bool_],
                       footprint_m2: float) -> tuple[NDArray[np.int64], list[str]]:
    """Which of L levels are storeys, and the storey each other floor level belongs to.

    ``heights_m``, ``area_m2`` (not raised), ``candidates``: (L,) per level, lowest first;
    ``floor_level``: (L,) bool, the levels of at least ``_MIN_LEVEL_AREA_M2``. Gives the
    (L,) storey of each level (its own index for a storey, -1 for a level that is no
    floor) and per level its kind: "storey", "split", "landing" or "" (no floor).

    The rule (``storey_levels``, steps 5 and 6): the floor levels are taken largest first
    (those with candidates before those without: a level with no room for a tripod does
    not anchor a storey; ties: the lower). The *large* ones (at least ``_MIN_STOREY_SHARE``
    of ``footprint_m2``) first, then the small ones. A level within ``HEADROOM_M`` of a
    storey's floor is a split level of the nearest such storey (ties: the lower); else a
    small level with a storey below and one above it is a landing of the storey below
    (whose stair leads up to it); else it is a storey.
    """
    n = len(heights_m)
    storey_of = np.full(n, -1, np.int64)
    kind = [""] * n
    large = area_m2 >= _MIN_STOREY_SHARE * footprint_m2
    order = sorted(np.flatnonzero(floor_level).tolist(),
                   key=lambda k: (not large[k], candidates[k] == 0, -area_m2[k], k))
    storeys: list[int] = []
    for k in order:
        gap = [abs(float(heights_m[k] - heights_m[s])) for s in storeys]
        near = [s for s, g in zip(storeys, gap, strict=True) if g < HEADROOM_M]
        below = [s for s in storeys if heights_m[s] < heights_m[k]]
        above = [s for s in storeys if heights_m[s] > heights_m[k]]
        if near:
            storey_of[k] = min(near, key=lambda s: (abs(float(heights_m[k] - heights_m[s])),
                                                    heights_m[s]))
            kind[k] = "split"
        elif not large[k] and below and above:
            storey_of[k] = max(below, key=lambda s: float(heights_m[s]))
            kind[k] = "landing"
        else:
            storey_of[k] = k
            kind[k] = "storey"
            storeys.append(k)
    return storey_of, kind


def walkable_surfaces(
    scene: Scene, xy: NDArray[np.float64], spec: PlanSpec, caster: RayCaster,
    dropped: dict[str, int],
) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]:
    """Every walkable surface under the (N, 2) points: (K,) point index, (K,) floor
    height and (K,) upward normal of the face under the point (1: level), by point, then
    height.

    Rays go up through the model, surface after surface. A surface is walkable when it is
    flatter than 30 degrees and the next surface above is more than ``scanner_height_m`` +
    ``clearance_m`` away (head room); above the lowest surface there must be a next surface
    (a roof's top is outside, not a level). The lowest surface of each point is accounted
    as :func:`place_on_floor` does.
    """
    if len(xy) == 0:
        return np.zeros(0, np.int64), np.zeros(0), np.zeros(0)
    steep = math.cos(math.radians(_MAX_FLOOR_SLOPE_DEG))
    reach = spec.scanner_height_m + spec.clearance_m
    hit_point: list[NDArray[np.int64]] = []
    hit_z: list[NDArray[np.float64]] = []
    hit_up: list[NDArray[np.float64]] = []
    active = np.arange(len(xy))
    z = np.full(len(xy), scene.bounds[0, 2] - 1.0)
    up = np.tile([0.0, 0.0, 1.0], (len(xy), 1))
    for _ in range(_MAX_SURFACES):
        face, distance = caster.first_hit(np.column_stack([xy[active], z[active]]),
                                          up[: len(active)])
        hit = face >= 0
        active, face, z_hit = active[hit], face[hit], z[active[hit]] + distance[hit]
        if len(active) == 0:
            break
        hit_point.append(active)
        hit_z.append(z_hit)
        hit_up.append(np.abs(scene.normals_of(face)[:, 2]))
        z[active] = z_hit + _SURFACE_STEP_M
    if not hit_point:
        dropped["no_floor"] += len(xy)
        return np.zeros(0, np.int64), np.zeros(0), np.zeros(0)
    point = np.concatenate(hit_point)
    order = np.lexsort((np.concatenate(hit_z), point))
    point, zs, up_z = point[order], np.concatenate(hit_z)[order], np.concatenate(hit_up)[order]
    flat = up_z >= steep
    last = np.r_[point[1:] != point[:-1], True]
    head_room = np.where(last, np.inf, np.r_[zs[1:], np.inf] - zs)
    first = np.r_[True, point[1:] != point[:-1]]
    dropped["no_floor"] += len(xy) - int(first.sum()) + int((first & ~flat).sum())
    dropped["blocked_above_floor"] += int((first & flat & (head_room <= reach)).sum())
    # above the lowest surface, a level needs a roof over it: the top of a roof is outside
    walkable = flat & (head_room > reach) & (first | np.isfinite(head_room))
    return point[walkable], zs[walkable], up_z[walkable]


def _height_levels(floor_z: NDArray[np.float64]) -> NDArray[np.int64]:
    """(K,) level of each floor height: heights grouped where they lie close together (a
    gap of more than ``_LEVEL_GAP_M`` starts a new level), numbered from the lowest."""
    by_height = np.argsort(floor_z, kind="stable")
    level_sorted = np.r_[0, np.cumsum(np.diff(floor_z[by_height]) > _LEVEL_GAP_M)]
    level = np.empty(len(floor_z), np.int64)
    level[by_height] = level_sorted
    return level


def _floor_levels(floor_z: NDArray[np.float64], flat: NDArray[np.bool_]
                  ) -> tuple[NDArray[np.int64], NDArray[np.bool_]]:
    """(K,) level of each floor height, numbered from the lowest, and per level whether it
    is sloped only. ``flat``: (K,) the surface is level (no steeper than 1:20).

    The level surfaces are grouped by :func:`_height_levels`; a sloped surface (a ramp,
    the terrain) joins the level whose level surface lies nearest its height, within
    ``_LEVEL_GAP_M``, and the sloped surfaces near no level floor are levels of their own,
    by height, marked sloped. So a slope between two floors (a house's terrain from its
    basement's door to its ground floor's) joins neither to the other. At least one
    surface must be level."""
    level = np.empty(len(floor_z), np.int64)
    level[flat] = _height_levels(floor_z[flat])
    level_z = floor_z[flat]
    by_height = np.argsort(level_z, kind="stable")
    sorted_z, sorted_level = level_z[by_height], level[flat][by_height]
    slope = np.flatnonzero(~flat)
    at = np.searchsorted(sorted_z, floor_z[slope])
    below = np.clip(at - 1, 0, len(sorted_z) - 1)
    above = np.clip(at, 0, len(sorted_z) - 1)
    d_below = np.abs(floor_z[slope] - sorted_z[below])
    d_above = np.abs(sorted_z[above] - floor_z[slope])
    nearest = np.where(d_below <= d_above, below, above)
    joins = np.minimum(d_below, d_above) <= _LEVEL_GAP_M
    level[slope[joins]] = sorted_level[nearest[joins]]
    alone = slope[~joins]
    n_flat = int(level[flat].max()) + 1
    if len(alone) == 0:
        return level, np.zeros(n_flat, bool)
    level[alone] = n_flat + _height_levels(floor_z[alone])
    n = int(level.max()) + 1
    sloped = np.arange(n) >= n_flat
    # number all levels from the lowest
    heights = np.array([float(floor_z[level == k].min()) for k in range(n)])
    rank = np.empty(n, np.int64)
    rank[np.argsort(heights, kind="stable")] = np.arange(n)
    sloped_ranked = np.empty(n, bool)
    sloped_ranked[rank] = sloped
    return rank[level], sloped_ranked


def place_on_levels(
    scene: Scene, xy: NDArray[np.float64], spec: PlanSpec, caster: RayCaster,
    dropped: dict[str, int],
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """(C, 3) positions above every walkable surface under the (N, 2) points, (C,) level.

    The surfaces are those of :func:`walkable_surfaces`, grouped into levels as the
    storeys' are (:func:`_floor_levels`): the level surfaces (no steeper than 1:20) by
    height, a sloped one (a ramp, the terrain) with the level floor nearest its height, or
    in a level of its own, so that a slope between two floors joins neither to the other;
    a level smaller than ``_MIN_LEVEL_AREA_M2`` of grid cells is a table top or a stair
    tread, not a floor, and its points count as ``no_floor``.
    """
    point, floor_z, normal_z = walkable_surfaces(scene, xy, spec, caster, dropped)
    if len(point) == 0:
        return np.zeros((0, 3)), np.zeros(0, np.int64)
    flat = normal_z >= _LEVEL_FLOOR_NORMAL_Z
    if not flat.any():  # no level surface (a mesh with noisy normals): heights alone
        flat[:] = True
    level, _ = _floor_levels(floor_z, flat)
    area = np.bincount(level) * spec.grid_spacing_m ** 2
    big = area[level] >= _MIN_LEVEL_AREA_M2
    dropped["no_floor"] += int((~big).sum())
    point, floor_z, level = point[big], floor_z[big], level[big]
    _, level = np.unique(level, return_inverse=True)  # renumber the levels that stay
    order = np.lexsort((point, level))  # level by level, grid rows within
    point, floor_z, level = point[order], floor_z[order], level[order]
    positions = np.column_stack([xy[point], floor_z + spec.scanner_height_m])
    return positions, level.astype(np.int64)


def _storey_report(report: list[dict[str, object]], lowest_candidates: int | None,
                   names: list[str]) -> list[dict[str, object]] | None:
    """``candidates.levels`` of "storeys": the storeys, named as the candidates' labels
    (``names``, from :func:`_level_labels`, for the storeys with candidates), then what
    was excluded; ``lowest_candidates``: the candidates stand on the lowest surface (one
    storey), this many. None when there is one storey and nothing was excluded."""
    levels: list[dict[str, object]] = []
    storeys = [entry for entry in report if "excluded" not in entry]
    if lowest_candidates is not None and storeys:  # the lowest surface gave them all
        storeys[0]["candidates"] = lowest_candidates
    k = 0
    for entry in storeys:
        if int(str(entry["candidates"])) > 0:
            k += 1
            name = names[k - 1] if k <= len(names) else \
                f"level {k} ({float(str(entry['floor_z_m'])):+.2f} m)"
            levels.append({"name": name, **entry})
        else:
            levels.append({"name": f"{float(str(entry['floor_z_m'])):+.2f} m", **entry,
                           "excluded": "no room: a storey, but no grid point on it has "
                                       "clearance_m free around the tripod"})
    levels += [{"name": f"{float(str(entry['floor_z_m'])):+.2f} m", **entry}
               for entry in report if "excluded" in entry]
    if len(levels) == 1 and "excluded" not in levels[0]:
        return None
    return levels


def levels_line(levels: list[dict[str, object]] | None) -> str | None:
    """``candidates.levels`` in one line (CLI, job message, preview): the storeys planned
    and what was left out; None when there is nothing to say (one level)."""
    if not levels:
        return None

    def height(entry: dict[str, object]) -> float:
        return float(str(entry["floor_z_m"]))

    storeys = [e for e in levels if "excluded" not in e]
    line = (f"{len(storeys)} storey{'s' if len(storeys) != 1 else ''} planned ("
            + ", ".join(f"{height(e):+.2f} m: {e['candidates']} candidates" for e in storeys)
            + ")")
    left_out = [e for e in levels if "excluded" in e]
    if left_out:
        kinds: dict[str, list[float]] = {}
        for entry in left_out:
            kinds.setdefault(str(entry["excluded"]).split(":")[0], []).append(
                float(str(entry["area_m2"])))
        line += "; not storeys: " + ", ".join(
            f"{len(areas)} {kind} ({sum(areas):.1f} m²)" for kind, areas in kinds.items())
        line += " (plan.json candidates.levels)"
    return line


def _level_labels(floor_z: NDArray[np.float64], level: NDArray[np.int64],
                  heights_m: list[float] | None = None
                  ) -> tuple[list[dict[str, object]], tuple[dict[str, str], ...]]:
    """The levels' summary for plan.json and a ``storey`` label per candidate (drawing).

    ``heights_m``: the floor height of each level that has candidates, in order (a storey
    with split levels or landings is named after its own floor); by default the median of
    its candidates' (C,) ``floor_z``."""
    summary: list[dict[str, object]] = []
    names: list[str] = []
    _, level = np.unique(level, return_inverse=True)  # only levels that kept candidates
    for k in range(int(level.max()) + 1 if len(level) else 0):
        members = level == k
        height = float(np.median(floor_z[members])) if heights_m is None else heights_m[k]
        names.append(f"level {k + 1} ({round(height, 2) + 0.0:+.2f} m)")  # no "-0.00"
        summary.append({"name": names[-1], "floor_z_m": round(height, 3),
                        "candidates": int(members.sum())})
    return summary, tuple({"storey": names[k]} for k in level)


def on_the_building(scene: Scene, spec: PlanSpec, positions: NDArray[np.float64],
                    floor_z_m: NDArray[np.float64], caster: RayCaster) -> NDArray[np.bool_]:
    """(C,) bool: the (C, 3) grid candidates (floors (C,) ``floor_z_m``) that stand in or
    around the building, not out on its site.

    The rule, from the plan's own requirements and the geometry alone: a candidate stands
    on the building when

    (a) *inside*: straight above the scanner the first surface is a target (a ceiling, a
        roof, a canopy), or
    (b) *around*: a target surface that is not a floor (steeper than
        ``_MAX_FLOOR_SLOPE_DEG``: a wall, a facade, a column, a door, a stair's riser) and
        rises more than ``KNEE_HEIGHT_M`` above the candidate's floor lies within the
        plan's reach of the scanner (:attr:`FaceLimits.reach_m`, the farthest a surface
        can qualify at its density and depth of field: 4.7 m with the defaults).

    Every other candidate stands on open ground with nothing of the building within
    reach: a site's terrain, a car park, a lawn. From there the scanner could reach only
    the ground it stands on. The rule holds whatever tool wrote the model: in IFC, terrain
    (IfcSite, and whatever else ``group_requirements`` makes no target) is neither a
    ceiling nor a wall here, so its slopes, banks and the sides of a terrain solid never
    keep a candidate; in a plain mesh every surface is a target, and a terrain's sides lie
    below the ground beside them (not above the candidate's floor) while its banks
    steeper than 30 degrees keep the candidates within reach of them. A hall's floor is
    under its roof, a yard between wings within reach of their facades. Applied only when
    no ``area_of_interest`` is given: a user who draws one chooses the ground to plan.
    """
    n = len(positions)
    if n == 0:
        return np.zeros(0, bool)
    limits = FaceLimits.from_spec(spec, scene)
    reach = limits.reach_m
    target = np.asarray(limits.target)
    up = np.tile([0.0, 0.0, 1.0], (n, 1))
    face, _ = caster.first_hit(positions, up)
    keep = face >= 0
    keep[keep] = target[face[keep]]
    samples, tree = reused(scene, ("upright samples", target.tobytes()),
                           lambda: _building_samples(scene, target))
    rest = np.flatnonzero(~keep)
    if len(samples) == 0 or len(rest) == 0 or reach <= 0 or tree is None:
        return keep
    above = floor_z_m[rest] + KNEE_HEIGHT_M
    _, nearest = tree.query(positions[rest], distance_upper_bound=reach)
    found = nearest < len(samples)
    keep[rest[found]] = samples[nearest[found], 2] > above[found]
    # the nearest surface is below the floor (a terrain's side, a basement wall): another
    # within reach may still rise above it
    again = np.flatnonzero(found & ~keep[rest])
    for start in range(0, len(again), _POINTS_PER_QUERY):
        chunk = again[start:start + _POINTS_PER_QUERY]
        lists = tree.query_ball_point(positions[rest[chunk]], reach)
        keep[rest[chunk]] = [bool(len(near)) and bool(
            (samples[np.asarray(near, np.int64), 2] > above[i]).any())
            for near, i in zip(lists, chunk, strict=True)]
    return keep


def near_targets_xy(scene: Scene, spec: PlanSpec, xy: NDArray[np.float64]
                    ) -> NDArray[np.bool_]:
    """(N,) bool: the (N, 2) grid points within the plan's reach, in the plane, of some
    target face's bounding box: every point :func:`on_the_building` can keep (a target
    over it, or an upright one within reach), found without rays. In IFC it cuts a site's
    terrain (no target) down to the building and its surroundings before any ray is
    cast; in a plain mesh, where the terrain is a target, it keeps what it is given."""
    limits = FaceLimits.from_spec(spec, scene)
    reach = limits.reach_m
    target = scene.on_file_faces(np.asarray(limits.target))
    vertices, faces = scene.file_mesh
    cell = spec.grid_spacing_m
    origin = xy.min(axis=0) - cell
    dims = np.floor((xy.max(axis=0) - origin) / cell).astype(np.int64) + 2
    count = np.zeros(dims + 1, np.int64)  # a difference array of the boxes, summed below
    flat = count.reshape(-1)  # (count's cells,) a view: adding to it adds to count
    for start in range(0, len(faces), _FOOTPRINTS_PER_BLOCK):
        block = faces[start:start + _FOOTPRINTS_PER_BLOCK][target[start:start
                                                                  + _FOOTPRINTS_PER_BLOCK]]
        corners = vertices[block][:, :, :2]
        least, most = corner_extremes(corners)
        first = np.floor((least - reach - origin) / cell).astype(np.int64)
        last = np.floor((most + reach - origin) / cell).astype(np.int64) + 1
        inside = (last > 0).all(axis=1) & (first < dims).all(axis=1)
        first = np.clip(first[inside], 0, dims)
        last = np.clip(last[inside], 0, dims)
        # the four corners of each box, counted by bincount over the flat array
        # (np.add.at of 4 x B elements is several times slower, the sums the same)
        width = int(dims[1]) + 1
        for rows, cols, sign in ((first, first, 1), (last, first, -1), (first, last, -1),
                                 (last, last, 1)):
            flat += sign * np.bincount(rows[:, 0] * width + cols[:, 1], minlength=len(flat))
    covered = count.cumsum(axis=0).cumsum(axis=1) > 0
    ij = np.floor((xy - origin) / cell).astype(np.int64)
    near: NDArray[np.bool_] = covered[ij[:, 0], ij[:, 1]]
    return near


def _building_samples(scene: Scene, target: NDArray[np.bool_]
                      ) -> tuple[NDArray[np.float64], cKDTree | None]:
    """The (S, 3) upright samples of the (F,) ``target`` faces and their tree (None when
    there are none), made once per candidate stage (:mod:`planner.candidates.scratch`)."""
    samples = _upright_samples(scene, scene.on_file_faces(target))
    return samples, cKDTree(samples) if len(samples) else None


def _upright_samples(scene: Scene, target_file: NDArray[np.bool_]) -> NDArray[np.float64]:
    """(S, 3) points on the file's target faces steeper than a floor, at most
    ``_BUILDING_SAMPLE_M`` apart (a face's corners, and points between them on a large
    face), one per cube of that size."""
    triangles = scene.file_triangles[np.asarray(target_file, bool)]
    if len(triangles) == 0:
        return np.zeros((0, 3))
    normal = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    length = np.linalg.norm(normal, axis=1)
    steep = math.cos(math.radians(_MAX_FLOOR_SLOPE_DEG))
    upright = (length > 0) & (np.abs(normal[:, 2]) < steep * np.maximum(length, 1e-300))
    triangles = triangles[upright]
    edge_m = np.linalg.norm(triangles - np.roll(triangles, 1, axis=1), axis=2)  # (T, 3)
    _, longest = corner_extremes(edge_m)
    steps = np.clip(np.ceil(longest / _BUILDING_SAMPLE_M), 1, 64).astype(np.int64)
    parts: list[NDArray[np.float64]] = []
    for k in np.unique(steps):
        i, j = np.meshgrid(np.arange(k + 1), np.arange(k + 1), indexing="ij")
        inside = i + j <= k
        u, v = i[inside] / k, j[inside] / k  # barycentric grid of the triangle
        tri = triangles[steps == k]
        points = (tri[:, None, 0] + u[None, :, None] * (tri[:, None, 1] - tri[:, None, 0])
                  + v[None, :, None] * (tri[:, None, 2] - tri[:, None, 0]))
        points = points.reshape(-1, 3)
        parts.append(points[_first_in_each_cube(points, _BUILDING_SAMPLE_M)])
    samples = np.concatenate(parts)
    return np.asarray(samples[_first_in_each_cube(samples, _BUILDING_SAMPLE_M)])


def _first_in_each_cube(points: NDArray[np.float64], size_m: float) -> NDArray[np.int64]:
    """(k,) ascending: the first of the (N, 3) points in each cube of ``size_m`` that holds
    any. The cubes' three integer coordinates are packed into one int64 key where they fit
    (a stable sort of N keys, not of N rows of three): the same points as ``np.unique`` of
    the rows with ``return_index``."""
    cube = np.floor(points / size_m).astype(np.int64)  # (N, 3)
    if len(cube) == 0:
        return np.zeros(0, np.int64)
    low, high = column_bounds(cube)
    span = high - low + 1  # (3,) cubes per axis
    if float(span[0]) * float(span[1]) * float(span[2]) < 2.0 ** 62:
        cube -= low
        key = (cube[:, 0] * span[1] + cube[:, 1]) * span[2] + cube[:, 2]
        # the first point in a cube starts a run of points in that cube: only the runs'
        # first points are sorted (a face's corners and a prop's neighbouring faces share
        # their cube: 3 M corners, some ten thousand runs)
        runs = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
        _, first_run = np.unique(key[runs], return_index=True)
        first = runs[first_run]
    else:
        _, first = np.unique(cube, axis=0, return_index=True)
    return np.sort(first).astype(np.int64)


def place_on_floor(
    scene: Scene, xy: NDArray[np.float64], spec: PlanSpec, caster: RayCaster,
    dropped: dict[str, int],
) -> NDArray[np.float64]:
    """(C, 3) positions ``scanner_height_m`` above the lowest surface under each (N, 2) point."""
    if len(xy) == 0:
        return np.zeros((0, 3))
    below = scene.bounds[0, 2] - 1.0
    origins = np.column_stack([xy, np.full(len(xy), below)])
    up = np.tile([0.0, 0.0, 1.0], (len(xy), 1))
    face, distance = caster.first_hit(origins, up)
    steep = math.cos(math.radians(_MAX_FLOOR_SLOPE_DEG))
    has_floor = face >= 0
    has_floor[has_floor] = np.abs(scene.normals_of(face[has_floor])[:, 2]) >= steep
    dropped["no_floor"] += int((~has_floor).sum())
    floor_z = below + distance[has_floor]
    xy = xy[has_floor]
    # from just above the floor to clearance above the scanner, nothing may stand
    lift = 0.01
    start = np.column_stack([xy, floor_z + lift])
    reach = spec.scanner_height_m + spec.clearance_m - lift
    _, dist_above = caster.first_hit(start, up[: len(xy)])
    clear = dist_above > reach
    dropped["blocked_above_floor"] += int((~clear).sum())
    return np.column_stack([xy[clear], floor_z[clear] + spec.scanner_height_m])


def drop_unclear(
    scene: Scene, positions: NDArray[np.float64], clearance_m: float, dropped: dict[str, int],
    floor_z_m: NDArray[np.float64] | None = None,
) -> NDArray[np.float64]:
    """Drop (C, 3) positions inside closed objects or within ``clearance_m`` of an obstacle.

    ``floor_z_m`` (C,) is the floor under each position; by default the lowest point of the
    model.
    """
    if floor_z_m is None:
        floor_z_m = np.full(len(positions), scene.bounds[0, 2])
    return positions[unclear_mask(scene, positions, clearance_m, dropped, floor_z_m)]


def unclear_mask(
    scene: Scene, positions: NDArray[np.float64], clearance_m: float, dropped: dict[str, int],
    floor_z_m: NDArray[np.float64],
) -> NDArray[np.bool_]:
    """(C,) bool: the (C, 3) positions that are neither inside objects nor too close."""
    keep = np.ones(len(positions), bool)
    if len(positions) == 0:
        return keep
    inside = inside_closed_groups(scene, positions)
    dropped["inside_geometry"] += int(inside.sum())
    keep[inside] = False
    index = np.flatnonzero(keep)
    near = closer_than(scene, positions[index], clearance_m,
                       np.asarray(floor_z_m, np.float64)[index])
    dropped["too_close"] += int(near.sum())
    keep[index[near]] = False
    return keep


def _merged_spans(low_m: NDArray[np.float64], high_m: NDArray[np.float64]
                  ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The union of the N height spans ``[low_m[i], high_m[i]]`` as (k,) ascending, disjoint
    spans (those that overlap or touch merged into one)."""
    spans = np.unique(np.column_stack([low_m, high_m]), axis=0)  # (u, 2) by low, then high
    lows: list[float] = []
    highs: list[float] = []
    for low, high in spans.tolist():
        if highs and low <= highs[-1]:
            highs[-1] = max(highs[-1], high)
        else:
            lows.append(low)
            highs.append(high)
    return np.array(lows), np.array(highs)


def _in_spans(low_m: NDArray[np.float64], high_m: NDArray[np.float64],
              span_low_m: NDArray[np.float64], span_high_m: NDArray[np.float64]
              ) -> NDArray[np.bool_]:
    """(B,) bool: the height range ``[low_m, high_m]`` of each of B faces reaches into one of
    the disjoint ascending spans (:func:`_merged_spans`): the first span that ends at or
    above the face's lowest point starts at or below its highest."""
    first = np.searchsorted(span_high_m, low_m, side="left")  # spans[first].high >= low
    inside = first < len(span_low_m)
    inside[inside] = span_low_m[first[inside]] <= high_m[inside]
    return inside


def closer_than(
    scene: Scene, points: NDArray[np.float64], radius_m: float, floor_z_m: NDArray[np.float64]
) -> NDArray[np.bool_]:
    """(N,) bool: some face within ``radius_m`` of the tripod's vertical axis.

    The axis runs from just above the floor (``floor_z_m`` + 1 cm) to ``radius_m`` above the
    scanner at (N, 3) ``points``; a face counts when its height range reaches into that span
    and its footprint (XY projection) comes closer than ``radius_m`` to the axis: a tripod
    needs that much room around it at every height, whatever the obstacle's height. A
    distance of exactly ``radius_m`` is clear. The faces of a scene still to be split
    (``split_max_edge_m``) count as the pieces a split gives them.
    """
    result = np.zeros(len(points), bool)
    if radius_m <= 0 or len(points) == 0:
        return result
    # Only faces reaching into some tripod's height span can be obstacles: their height
    # range, XY centre and spread, gathered a block of faces at a time (no (F, 3, 3) copy
    # of the corners, no (F,) array of every face's height range). The spans of all the
    # tripods, merged: a storey's floor and the slab under the next lie between two
    # storeys' spans, in none (on a 3-storey office most of the pieces a split would make)
    span_low_m, span_high_m = _merged_spans(floor_z_m + 0.01, points[:, 2] + radius_m)
    # And only faces whose XY bounding box, widened by radius_m, holds some point: any other
    # is farther than radius_m from every axis (a few setups around the stations need a few
    # faces, not per-face arrays over a whole split building).
    near = _NearPoints(points[:, :2], radius_m)
    parts: list[tuple[NDArray[np.int32], NDArray[np.float64], NDArray[np.float64]]] = []
    for start in range(0, scene.n_faces, _FOOTPRINTS_PER_BLOCK):
        block_faces = scene.faces[start:start + _FOOTPRINTS_PER_BLOCK]
        corner_z = scene.vertices[block_faces, 2]
        low, high = corner_extremes(corner_z)  # (B,) each
        keep = np.flatnonzero(_in_spans(low, high, span_low_m, span_high_m))
        corner_xy = scene.vertices[block_faces[keep], :2]  # (k, 3, 2): the faces kept so far
        keep = keep[near.any_in(*corner_extremes(corner_xy))]
        parts.append(((keep + start).astype(np.int32), low[keep], high[keep]))
    useful = np.concatenate([p[0] for p in parts])  # (U,) the faces kept
    z_low = np.concatenate([p[1] for p in parts])  # (U,) their lowest corner
    z_high = np.concatenate([p[2] for p in parts])  # (U,) and highest
    del parts
    vertices, faces = scene.vertices, scene.faces
    if scene.split_max_edge_m is not None:
        # a scene still to be split: the obstacles are the pieces a full split gives (a
        # piece reaches into the span over less than its whole face), split here for
        # these faces only. A face no longer than split_max_edge_m is its own one piece
        # (the split leaves it whole): only the longer ones go through the split, not the
        # million small faces of a furnished interior beside them
        long = longest_edges_m(vertices, faces[useful]) > scene.split_max_edge_m  # (U,)
        if long.any():
            def reaching(piece_vertices: NDArray[np.float64], piece_faces: NDArray[np.int32]
                         ) -> NDArray[np.bool_]:
                """(f,) bool: the pieces that reach into a span and whose footprint's box,
                widened by radius_m, holds some point (no other is an obstacle)."""
                low, high = corner_extremes(piece_vertices[piece_faces, 2])
                kept = _in_spans(low, high, span_low_m, span_high_m)
                kept[kept] = near.any_in(*corner_extremes(
                    piece_vertices[piece_faces[kept], :2]))
                return kept

            # split a block at a time, each block's pieces sifted as they are made (a
            # site's ground of 1,479 faces is 2.9 M pieces, a few thousand of them near a
            # tripod)
            piece_vertices, piece_faces = kept_pieces(vertices, faces[useful[long]],
                                                      scene.split_max_edge_m, reaching)
            low, high = corner_extremes(piece_vertices[piece_faces, 2])
            whole = ~long
            # the whole faces, then the pieces (their corners after the scene's own)
            faces = np.concatenate([faces[useful[whole]],
                                    piece_faces + np.int32(len(vertices))])
            vertices = np.concatenate([vertices, piece_vertices])
            z_low = np.concatenate([z_low[whole], low])
            z_high = np.concatenate([z_high[whole], high])
            useful = np.arange(len(faces), dtype=np.int32)
            del low, high, piece_vertices, piece_faces
            release_freed_memory()  # the split's scratch, freed into its threads' heaps

    def footprints(index: NDArray[np.int64]) -> NDArray[np.float64]:
        """(n, 3, 2) XY corners of the faces ``useful[index]``."""
        return np.asarray(vertices[faces[useful[index]], :2])

    centre_xy = np.empty((len(useful), 2))
    spread = np.empty(len(useful))

    def footprint_extent(start: int) -> None:
        """The centre and spread of a block of the faces, into their own rows."""
        block = np.arange(start, min(start + _FOOTPRINTS_PER_BLOCK, len(useful)))
        tri_xy = footprints(block)
        centre_xy[block] = tri_xy.mean(axis=1)
        spread[block] = np.linalg.norm(tri_xy - centre_xy[block, None, :], axis=2).max(axis=1)

    list(in_block_order(footprint_extent, range(0, len(useful), _FOOTPRINTS_PER_BLOCK)))
    # Faces are searched by their centre within radius + their own spread. One search
    # radius for all (the largest spread) would pair every point with every face of a
    # model that has one huge face; classes of similar spread keep the pairs local.
    spread_class = np.ceil(np.log2(np.maximum(spread, radius_m / 8) / (radius_m / 8))
                           ).astype(np.int16)
    for level in np.unique(spread_class):
        members = np.flatnonzero(spread_class == level)
        reach = radius_m + float(spread[members].max()) + 1e-9
        # (an unbalanced tree builds faster; the queries return their indices sorted, so
        # the pairs do not depend on the tree's shape or the query's threads)
        tree = cKDTree(centre_xy[members], balanced_tree=False, compact_nodes=False)

        def blocked(s: int, tree: cKDTree = tree, reach: float = reach,
                    members: NDArray[np.intp] = members) -> NDArray[np.int64]:
            """The points of a chunk with a face of this class closer than radius_m
            (the class's tree, reach and faces bound here: the chunks are all read
            before the next class)."""
            chunk = np.arange(s, min(s + _POINTS_PER_QUERY, len(points)))
            chunk = chunk[~result[chunk]]  # close to a face of an earlier class: decided
            if len(chunk) == 0:
                return np.zeros(0, np.int64)
            lists = tree.query_ball_point(points[chunk, :2], reach)
            counts = np.array([len(x) for x in lists])
            if counts.sum() == 0:
                return np.zeros(0, np.int64)
            point_of_pair = np.repeat(chunk, counts)
            face_of_pair = members[np.concatenate([np.asarray(x, np.int64) for x in lists
                                                   if x])]
            span_low = floor_z_m[point_of_pair] + 0.01
            span_high = points[point_of_pair, 2] + radius_m
            in_span = (z_high[face_of_pair] >= span_low) & (z_low[face_of_pair] <= span_high)
            p, f = point_of_pair[in_span], face_of_pair[in_span]
            # a face whose footprint's centre lies within radius_m of the axis, by more than
            # any rounding, is closer than radius_m (the centre is on the footprint): such a
            # point is close without the exact distance to its other faces (a counter top
            # among a million props: most of the pairs)
            offset = points[p, :2] - centre_xy[f]
            centre_near = np.hypot(offset[:, 0], offset[:, 1]) < radius_m - _SURE_MARGIN_M
            sure = np.unique(p[centre_near])
            rest = np.flatnonzero(~np.isin(p, sure))
            gap = _distance_to_triangles_xy(points[p[rest], :2], footprints(f[rest]))
            close: NDArray[np.int64] = np.concatenate([sure, p[rest][gap < radius_m]])
            return close

        # chunks of points on the thread pool, each querying the tree on its own thread
        for close in in_block_order(blocked, range(0, len(points), _POINTS_PER_QUERY)):
            result[close] = True
    return result


class _NearPoints:
    """Which boxes in the plane, widened by ``radius_m``, hold some of the (N, 2) points:
    point counts on a grid and their summed-area table. Conservative: a box is tested
    against the whole cells it touches, so a box that holds a point always says so."""

    _MAX_CELLS = 1 << 22

    def __init__(self, points_xy: NDArray[np.float64], radius_m: float) -> None:
        self.radius_m = radius_m
        self.origin = points_xy.min(axis=0)
        extent = np.maximum(points_xy.max(axis=0) - self.origin, 1e-9)
        self.cell_m = max(radius_m, float(extent.max()) / 4096.0, 1e-6)
        while np.prod(np.floor(extent / self.cell_m) + 1) > self._MAX_CELLS:
            self.cell_m *= 2.0
        self.dims = (np.floor(extent / self.cell_m) + 1).astype(np.int64)
        ij = np.minimum(np.floor((points_xy - self.origin) / self.cell_m).astype(np.int64),
                        self.dims - 1)
        counts = np.zeros(self.dims, np.int64)
        np.add.at(counts, (ij[:, 0], ij[:, 1]), 1)
        self.table = np.zeros(self.dims + 1, np.int64)  # (nx + 1, ny + 1) summed area
        self.table[1:, 1:] = counts.cumsum(axis=0).cumsum(axis=1)

    def any_in(self, low_xy: NDArray[np.float64], high_xy: NDArray[np.float64]
               ) -> NDArray[np.bool_]:
        """(B,) bool: some point lies in the box [low - r, high + r] of each of the (B, 2)
        ``low_xy`` / ``high_xy`` corners (or in a cell the widened box touches)."""
        first = np.floor((low_xy - self.radius_m - self.origin) / self.cell_m)
        last = np.floor((high_xy + self.radius_m - self.origin) / self.cell_m)
        outside = ((last < 0) | (first > self.dims - 1)).any(axis=1)
        first = np.clip(first, 0, self.dims - 1).astype(np.int64)
        last = np.clip(last, 0, self.dims - 1).astype(np.int64) + 1
        t = self.table
        inside = (t[last[:, 0], last[:, 1]] - t[first[:, 0], last[:, 1]]
                  - t[last[:, 0], first[:, 1]] + t[first[:, 0], first[:, 1]])
        held: NDArray[np.bool_] = (inside > 0) & ~outside
        return held


def _distance_to_triangles_xy(
    points: NDArray[np.float64], triangles: NDArray[np.float64]
) -> NDArray[np.float64]:
    """(N,) distance in the plane from (N, 2) points to (N, 3, 2) triangles (0 inside)."""
    a, b, c = triangles[:, 0], triangles[:, 1], triangles[:, 2]

    def cross(u: NDArray[np.float64], v: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.asarray(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0])

    d1, d2, d3 = cross(b - a, points - a), cross(c - b, points - b), cross(a - c, points - c)
    inside = ((d1 >= 0) & (d2 >= 0) & (d3 >= 0)) | ((d1 <= 0) & (d2 <= 0) & (d3 <= 0))
    inside &= np.abs(cross(b - a, c - a)) > 1e-15  # a vertical face projects to a segment

    def to_segment(p0: NDArray[np.float64], p1: NDArray[np.float64]) -> NDArray[np.float64]:
        edge = p1 - p0
        length2 = np.einsum("nk,nk->n", edge, edge)
        t = np.divide(np.einsum("nk,nk->n", points - p0, edge), length2,
                      out=np.zeros_like(length2), where=length2 > 0)
        closest = p0 + np.clip(t, 0.0, 1.0)[:, None] * edge
        return np.asarray(np.linalg.norm(points - closest, axis=1))

    gap = np.minimum(np.minimum(to_segment(a, b), to_segment(b, c)), to_segment(c, a))
    return np.where(inside, 0.0, gap)


def inside_closed_groups(scene: Scene, points: NDArray[np.float64]) -> NDArray[np.bool_]:
    """(N,) bool: the generalised winding number of some group's faces exceeds one half.

    Only points inside a group's bounding box are evaluated against that group. The faces
    are the file's (:attr:`Scene.file_triangles`): the pieces of a face subtend the same
    solid angle as the face, so the winding number is the same at a fraction of the cost.
    A group's winding cells, once built, serve the candidate stage's later calls
    (:mod:`planner.candidates.scratch`).
    """
    result = np.zeros(len(points), bool)
    triangles: NDArray[np.float64] | None = None  # made when a group is not kept
    vertex_rank: NDArray[np.integer] | None = None  # made when a group's cells are built
    face_group = scene.file_face_group
    for g in range(len(scene.groups)):
        kept = kept_or_none(scene, ("winding cells", g))
        if kept is not None:
            lo, hi, cells = kept
            boxed = np.flatnonzero(((points > lo) & (points < hi)).all(axis=1) & ~result)
            result[boxed] = cells_winding_numbers(cells, points[boxed]) > 0.5
            continue
        faces = np.flatnonzero(face_group == g)
        if len(faces) == 0:
            continue
        if triangles is None:
            triangles = scene.file_triangles
        # one group of every face (a plain mesh): the file's corners, not a copy
        tri = triangles if len(faces) == len(triangles) else triangles[faces]
        lo, hi = column_bounds(tri.reshape(-1, 3))
        boxed = np.flatnonzero(((points > lo) & (points < hi)).all(axis=1) & ~result)
        if needs_cells(len(tri), len(boxed)):
            vertices, file_faces = scene.file_mesh
            if vertex_rank is None:  # the corners' order by the file's V vertices
                vertex_rank = coordinate_ranks(vertices)
            cells = winding_cells(tri, vertex_rank[file_faces[faces]])
            keep(scene, ("winding cells", g), (lo, hi, cells))
            result[boxed] = cells_winding_numbers(cells, points[boxed]) > 0.5
        else:
            result[boxed] = winding_numbers(tri, points[boxed]) > 0.5
        del tri
    return result
