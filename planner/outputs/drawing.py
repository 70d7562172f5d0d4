"""Pictures of a plan: ``preview.png`` (the floor plan) and ``curve.png`` (the coverage curve).

Both are drawn on a :class:`matplotlib.figure.Figure` with the Agg canvas (no pyplot, no
global state), at a fixed size and with fixed PNG metadata, so the same plan always gives
the same bytes.

The preview is a plan view of every storey that holds candidates, printed to a standard
scale (1:50, 1:100, ...) on A4 landscape:

- the model cut by a horizontal plane at scanner height: each cut face is a thick line
  coloured by its coverage class over a thin black core (walls read as walls, and show
  whether they are covered);
- the up-facing surfaces below the cut (floor, tops of machines), coloured by class and
  painted from low to high;
- the candidate grid as faint dots, the chosen stations as numbered discs in their order,
  each with a dashed circle of the head-on density range;
- scale bar, north arrow (+Y of the model), legend, totals and the station list.

Storeys come from the candidates' labels (``storey``, set by the IFC room candidates) with
elevations from ``scene.metadata["storeys"]`` when the reader gives them; otherwise the
candidates' heights are split into levels wherever they jump by more than
``LEVEL_GAP_M``.

Face classes (shared with :mod:`planner.outputs.glb`): covered by the plan (green, darker the more
the best LPD exceeds the requirement), coverable but not covered (orange), not coverable
from any candidate (crimson), and faces with no requirement (grey).
"""

from __future__ import annotations

import gc
import io
import math
import threading
import weakref
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Generic, TypeVar, overload

import numba
import numpy as np
import shapely
import trimesh
from matplotlib.artist import allow_rasterization
from matplotlib.axes import Axes
from matplotlib.backend_bases import RendererBase
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import Collection, LineCollection, PolyCollection
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Circle, Patch, Rectangle
from matplotlib.path import Path
from matplotlib.ticker import MaxNLocator
from numpy.typing import NDArray

from planner.candidates.grid import levels_line
from planner.density import density_range_m
from planner.io.orientation import scene_rotation, to_model
from planner.memory import release_freed_memory
from planner.outputs.outline import group_triangles
from planner.parameters import PlanSpec
from planner.pipeline import PlanResult
from planner.scene import Scene, corner_extremes, face_centroid
from planner.selection.curve import coverage_curve

# --- face classes and their colours (sRGB 0-255) -------------------------------------------

COVERED, MISSED, UNREACHABLE, NOT_TARGET = 0, 1, 2, 3
CLASS_NAMES = ("covered", "coverable_not_covered", "not_coverable", "not_target")
CLASS_LABELS = (
    "covered by the plan",
    "coverable, not covered by the plan",
    "not coverable from any candidate",
    "no requirement (not a target)",
)
COVERED_LOW_RGB = (161, 217, 155)  # best LPD just meets the requirement
COVERED_HIGH_RGB = (0, 90, 50)  # best LPD >= COVERED_SATURATION x the requirement
COVERED_SATURATION = 8.0
CLASS_RGB = ((49, 163, 84), (240, 150, 20), (190, 30, 60), (200, 200, 200))
STATION_RGB = (20, 60, 160)
VISIT_RGB = (0.85, 0.35, 0.0)  # the walking route and visit numbers (matplotlib 0-1)
EDGE_RGB = (0.15, 0.45, 0.15)  # registration edges
# ring around a critical station (its worst setup within placement_tolerance_m breaks the goal)
CRITICAL_RGB = (0.85, 0.1, 0.1)
# a glazed opening the route passes that may be a fixed window (route.door_checks)
CHECK_RGB = (0.85, 0.1, 0.1)

DPI = 150
PREVIEW_SIZE_IN = (11.69, 8.27)  # A4 landscape
CURVE_SIZE_IN = (8.0, 5.0)
LEVEL_GAP_M = 1.0
_PNG_METADATA: dict[str, str | None] = {"Software": None}
_SCALES = (10, 20, 25, 30, 40, 50, 75, 100, 125, 150, 200, 250, 300, 400, 500, 750, 1000,
           1250, 1500, 2000, 2500, 5000, 10000, 20000, 25000, 50000, 100000)
_UP_NZ = 0.3  # faces whose normal has at least this upward part are drawn from above
# per-face work on the whole scene goes this many faces at a time, so that no (F, 3) float64
# array (230 MB on a 10 M-face model) is made
CHUNK_FACES = 1 << 20
_SHADE_FACES = 1 << 18  # face_rgb's chunk: a few (n, 3) float64 at once
_DRAW_FACES = 1 << 16  # floor triangles made into paths and drawn at a time
_PATH_TRIANGLES = 1 << 12  # floor triangles filled as one path at most
# a face is handed to the exact cut when it has a corner above the section plane and one
# below this much above it (trimesh counts corners within 1e-8 m as on the plane)
_SECTION_MARGIN_M = 1e-6


def face_classes(faces: Mapping[str, NDArray[Any]], target: NDArray[np.bool_]) -> NDArray[np.uint8]:
    """(F,) uint8 class per face from the per-face arrays of a plan (``faces.npz``).

    ``COVERED`` when ``covered``; else ``MISSED`` when ``n_candidates > 0``; else
    ``UNREACHABLE`` for a target face and ``NOT_TARGET`` for a face with no requirement.
    """
    covered = np.asarray(faces["covered"], bool)
    coverable = np.asarray(faces["n_candidates"]) > 0
    classes = np.full(len(covered), UNREACHABLE, np.uint8)
    classes[~np.asarray(target, bool)] = NOT_TARGET
    classes[coverable] = MISSED
    classes[covered] = COVERED
    return classes


def face_rgb(faces: Mapping[str, NDArray[Any]], target: NDArray[np.bool_],
             min_density_pts_m2: NDArray[np.float64],
             index: NDArray[np.integer[Any]] | None = None) -> NDArray[np.uint8]:
    """(F, 3) uint8 sRGB colour per face: its class colour, covered faces shaded by LPD;
    with ``index``, (n,) face indices, the (n, 3) colours of those faces only.

    A covered face goes from ``COVERED_LOW_RGB`` (best LPD at the requirement) to
    ``COVERED_HIGH_RGB`` (``COVERED_SATURATION`` times the requirement or more) on a log
    scale. The shading is worked out ``_SHADE_FACES`` faces at a time: float64 (F, 3)
    colours of a 10 M-face model would be 230 MB.
    """
    if index is not None:  # each face's colour depends on its own values alone
        faces = {name: np.asarray(faces[name])[index]
                 for name in ("covered", "n_candidates", "best_lpd_pts_m2")}
        target = np.asarray(target)[index]
        min_density_pts_m2 = np.asarray(min_density_pts_m2)[index]
    classes = face_classes(faces, target)
    rgb = np.asarray(CLASS_RGB, np.uint8)[classes]
    best_lpd = np.asarray(faces["best_lpd_pts_m2"])  # read once: an npz reads on each access
    min_density = np.asarray(min_density_pts_m2)
    low, high = np.asarray(COVERED_LOW_RGB, float), np.asarray(COVERED_HIGH_RGB, float)
    for start in range(0, len(classes), _SHADE_FACES):
        covered = start + np.flatnonzero(classes[start:start + _SHADE_FACES] == COVERED)
        required = np.asarray(min_density[covered], np.float64)
        best = np.asarray(best_lpd[covered], np.float64)
        ratio = np.divide(best, required, out=np.full_like(best, COVERED_SATURATION),
                          where=required > 0)
        t = np.clip(np.log(np.maximum(ratio, 1.0)) / math.log(COVERED_SATURATION), 0.0, 1.0)
        rgb[covered] = np.rint(low + t[:, None] * (high - low)).astype(np.uint8)
    return rgb


def _packed(rgb: NDArray[np.uint8]) -> NDArray[np.int64]:
    """(n,) int64 ``0xRRGGBB`` of (n, 3) uint8 colours: one sortable key a colour."""
    return ((rgb[:, 0].astype(np.int64) << 16) | (rgb[:, 1].astype(np.int64) << 8)
            | rgb[:, 2])


def _rgb(colour: Sequence[float]) -> tuple[float, float, float]:
    return (colour[0] / 255.0, colour[1] / 255.0, colour[2] / 255.0)


# --- storeys ------------------------------------------------------------------------------


@dataclass(frozen=True)
class Level:
    """One storey drawn as a panel.

    ``candidates`` are indices into the plan's candidates; faces between ``floor_z - 0.2``
    and ``section_z`` are painted from above; faces reaching up to ``top_z`` count for the
    panel's extent.
    """

    name: str
    floor_z: float
    section_z: float
    top_z: float
    candidates: NDArray[np.int64]


def levels(result: PlanResult) -> list[Level]:
    """The storeys of the plan, lowest first (see the module docstring)."""
    positions = result.candidates.positions
    z = positions[:, 2]
    height = result.spec.scanner_height_m
    labels = result.candidates.labels
    groups: list[tuple[str, NDArray[np.int64]]] = []
    if labels and all(label.get("storey") for label in labels):
        names = sorted({label["storey"] for label in labels},
                       key=lambda n: float(np.median(z[[lab["storey"] == n for lab in labels]])))
        for name in names:
            groups.append((name, np.flatnonzero([lab["storey"] == name for lab in labels])))
    else:
        order = np.argsort(z, kind="stable")
        breaks = np.flatnonzero(np.diff(z[order]) > LEVEL_GAP_M) + 1
        for i, chunk in enumerate(np.split(order, breaks)):
            groups.append((f"level {i + 1}" if len(breaks) else "", np.sort(chunk)))
    elevations = _storey_elevations(result.scene.metadata)
    top = float(result.scene.bounds[1, 2])
    floors = []
    for name, members in groups:
        floor = elevations.get(name, float(z[members].min()) - height)
        floors.append(floor)
    out = []
    for i, (name, members) in enumerate(groups):
        next_floor = floors[i + 1] if i + 1 < len(groups) else top
        section = float(np.median(z[members]))
        out.append(Level(name=name, floor_z=floors[i], section_z=section,
                         top_z=max(next_floor, section), candidates=members.astype(np.int64)))
    return out


def _storey_elevations(metadata: Mapping[str, Any]) -> dict[str, float]:
    """Storey name -> elevation from reader metadata, tolerant of its exact shape."""
    storeys = metadata.get("storeys")
    out: dict[str, float] = {}
    if isinstance(storeys, Mapping):
        items: list[Any] = [{"name": k, "elevation": v} for k, v in storeys.items()]
    elif isinstance(storeys, list | tuple):
        items = list(storeys)
    else:
        return out
    for item in items:
        if isinstance(item, Mapping):
            name, elevation = item.get("name"), item.get("elevation")
            if isinstance(name, str) and isinstance(elevation, int | float):
                out[name] = float(elevation)
    return out


# --- preview.png -----------------------------------------------------------------------


@dataclass(frozen=True)
class Preview:
    """The drawn preview: its figure, one axes per level, and the print scale (1:scale)."""

    figure: Figure
    axes: tuple[Axes, ...]
    levels: tuple[Level, ...]
    scale: int


def _panel_grid(n: int) -> tuple[int, int]:
    if n <= 2:
        return 1, n
    return 2, math.ceil(n / 2)


def draw_preview(result: PlanResult) -> Preview:
    """Draw the plan view; :func:`preview_png` turns it into bytes."""
    fig = Figure(figsize=PREVIEW_SIZE_IN, dpi=DPI)
    FigureCanvasAgg(fig)
    all_levels = levels(result)
    chosen = set(result.chosen.stations)
    shown = [lv for lv in all_levels if chosen.intersection(lv.candidates.tolist())]
    shown = (shown or all_levels)[:4] if len(all_levels) > 4 else all_levels
    rows, cols = _panel_grid(len(shown))
    # map area in figure fractions: left part of the sheet; the right column is the key
    map_left, map_bottom, map_width, map_height = 0.025, 0.035, 0.70, 0.835
    gap = 0.02
    cell_w = (map_width - gap * (cols - 1)) / cols
    cell_h = (map_height - gap * 1.5 * (rows - 1)) / rows
    width_in, height_in = PREVIEW_SIZE_IN
    extents = level_extents(result, shown)
    scale = _print_scale(extents, cell_w * width_in, cell_h * height_in)
    axes = []
    for i, (level, extent) in enumerate(zip(shown, extents, strict=True)):
        r, c = divmod(i, cols)
        left = map_left + c * (cell_w + gap)
        bottom = map_bottom + (rows - 1 - r) * (cell_h + gap * 1.5)
        ax = fig.add_axes((left, bottom, cell_w, cell_h))
        _limits_at_scale(ax, extent, cell_w * width_in, cell_h * height_in, scale)
        _draw_level(ax, result, level)
        scale_bar(ax)
        title = level.name or "plan"
        ax.set_title(f"{title}: section at {level.section_z:.2f} m, floor {level.floor_z:.2f} m"
                     if level.name else
                     f"section at {level.section_z:.2f} m (scanner height), seen from above",
                     fontsize=9, loc="left")
        axes.append(ax)
    _key(fig, result, scale)
    line = levels_line(result.candidates.levels)
    if line:  # the storeys planned and what was left out, in one line under the maps
        fig.text(map_left, 0.012, line, fontsize=7, color="0.25", va="center")
    return Preview(figure=fig, axes=tuple(axes), levels=tuple(shown), scale=scale)


def preview_png(result: PlanResult) -> bytes:
    """``preview.png``: A4 landscape at 150 dpi (1754 x 1240 px)."""
    figure = draw_preview(result).figure
    try:
        return _png(figure)
    finally:
        release_figure(figure)


def release_figure(figure: Figure) -> None:
    """Free what a drawn figure holds now, not at the garbage collector's next full pass.

    A figure and its artists refer to each other, so only the cycle collector frees them;
    until it runs, the renderer's pixels and every artist's arrays stay resident after the
    bytes are written. The figure is empty afterwards.
    """
    figure.clear()
    gc.collect()
    release_freed_memory()  # and the heap's pages they took, to the system


def _png(fig: Figure) -> bytes:
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=DPI, metadata=_PNG_METADATA)
    return buffer.getvalue()


def _level_key(level: Level) -> tuple[str, float, float, float]:
    return (level.name, level.floor_z, level.section_z, level.top_z)


_Key = TypeVar("_Key")
_Value = TypeVar("_Value")


class _PerPlan(Generic[_Key, _Value]):
    """What the drawings made of a plan, by key, kept as long as the plan (weak keys) so
    that the print set reads what the preview made; thread-safe (the pictures render on
    background threads). Made outside the lock: two threads asking at once may both make
    a value, the same one."""

    def __init__(self) -> None:
        self._made: weakref.WeakKeyDictionary[PlanResult, dict[_Key, _Value]] = (
            weakref.WeakKeyDictionary())
        self._lock = threading.Lock()

    def made(self, result: PlanResult) -> dict[_Key, _Value]:
        """A copy of what was made of ``result`` so far."""
        with self._lock:
            return dict(self._made.get(result, {}))

    def keep(self, result: PlanResult, values: Mapping[_Key, _Value]) -> None:
        with self._lock:
            self._made.setdefault(result, {}).update(values)


# each level's extent, found once for the preview and the print set (the 9.7 M-piece
# office: 1.6 s a drawing, three passes over every piece's centroid)
_EXTENTS: _PerPlan[tuple[str, float, float, float], tuple[float, float, float, float]] = (
    _PerPlan())


def level_extents(result: PlanResult, levels: Sequence[Level]
                  ) -> list[tuple[float, float, float, float]]:
    """(xmin, ymin, xmax, ymax) of the faces of each level and its candidates, with a margin.

    The faces count as far as a station can reach: within the plan's reach
    (:attr:`FaceLimits.reach_m`) of the level's candidates. A site's terrain around a house
    is drawn around the house, not to the edge of the site (a 114 x 203 m terrain printed
    to scale is some 90 A3 sheets); a hall's walls, within reach of its candidates, are
    drawn whole.

    The levels not yet found share one compiled pass over the faces, which widens each
    level's extent by the corners of its faces as it meets them (no (F, 3, 2) gathered
    corners: 460 MB on a 10 M-face model; 0.1 s there instead of the 0.5 - 0.8 s of marking
    them level by level in numpy); a level's extent is kept with the result, so the print
    set reads the preview's.
    """
    known = _EXTENTS.made(result)
    missing = list({_level_key(lv): lv for lv in levels
                    if _level_key(lv) not in known}.values())
    if missing:
        found = _extents(result, missing)
        _EXTENTS.keep(result, found)
        known.update(found)
    return [known[_level_key(lv)] for lv in levels]


def _extents(result: PlanResult, levels: Sequence[Level]
             ) -> dict[tuple[str, float, float, float], tuple[float, float, float, float]]:
    """:func:`level_extents` of ``levels``, in one pass over the faces."""
    scene = result.scene
    candidates_xy = [result.candidates.positions[level.candidates, :2] for level in levels]
    # (L, 2) the least and the greatest x, y of each level's extent, from its candidates on
    lo = np.array([xy.min(axis=0) for xy in candidates_xy])
    hi = np.array([xy.max(axis=0) for xy in candidates_xy])
    _fold_level_corners(scene.vertices, scene.faces,
                        np.array([level.floor_z - 0.2 for level in levels]),
                        np.array([level.top_z for level in levels]), lo, hi)
    reach = result.limits.reach_m
    out = {}
    for level, xy, least, most in zip(levels, candidates_xy, lo, hi, strict=True):
        if len(xy) and reach > 0:  # no farther than a station reaches from the candidates
            least = np.maximum(least, xy.min(axis=0) - reach)
            most = np.minimum(most, xy.max(axis=0) + reach)
        margin = 0.04 * float(max(most - least)) + 0.3
        out[_level_key(level)] = (float(least[0]) - margin, float(least[1]) - margin,
                                  float(most[0]) + margin, float(most[1]) + margin)
    return out


@numba.njit(nogil=True, cache=True)
def _fold_level_corners(vertices: NDArray[np.float64], faces: NDArray[np.int32],
                        floor_m: NDArray[np.float64], top_m: NDArray[np.float64],
                        lo: NDArray[np.float64], hi: NDArray[np.float64]) -> None:  # compiled
    """Widen each level's (L, 2) ``lo`` and ``hi`` to the x, y of the corners of every face
    of (V, 3) ``vertices``, (F, 3) ``faces`` whose centroid's z lies in [``floor_m``,
    ``top_m``] (L,) of the level: one pass, no (V,) mask a level (a minimum and a maximum
    are the same whatever order their points come in)."""
    for f in range(faces.shape[0]):
        z = face_centroid(vertices, faces, f)[2]
        for level in range(floor_m.shape[0]):
            if z >= floor_m[level] and z <= top_m[level]:
                for corner in range(3):
                    v = faces[f, corner]
                    for axis in range(2):
                        value = vertices[v, axis]
                        lo[level, axis] = min(lo[level, axis], value)
                        hi[level, axis] = max(hi[level, axis], value)


def _print_scale(extents: Sequence[tuple[float, float, float, float]], width_in: float,
                 height_in: float) -> int:
    """The smallest standard scale 1:N at which every level fits its panel."""
    needed = max(max((x1 - x0) / (width_in * 0.0254), (y1 - y0) / (height_in * 0.0254))
                 for x0, y0, x1, y1 in extents)
    for scale in _SCALES:
        if scale >= needed:
            return scale
    return math.ceil(needed)


def _limits_at_scale(ax: Axes, extent: tuple[float, float, float, float], width_in: float,
                     height_in: float, scale: int) -> None:
    x0, y0, x1, y1 = extent
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    half_w = width_in * 0.0254 * scale / 2
    half_h = height_in * 0.0254 * scale / 2
    ax.set_xlim(cx - half_w, cx + half_w)
    ax.set_ylim(cy - half_h, cy + half_h)
    ax.set_xticks([])
    ax.set_yticks([])
    for spine in ax.spines.values():
        spine.set_linewidth(0.6)
        spine.set_color("0.4")


def section_at(vertices: NDArray[np.float64], faces: NDArray[np.integer[Any]], z: float
               ) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """The cut of the mesh (V, 3) ``vertices``, (F, 3) ``faces`` by the horizontal plane at
    height ``z``.

    Returns (S, 2, 2) float64 segments (x, y of both ends) and (S,) int64 the face each
    segment cuts: those of trimesh's ``mesh_plane`` on the whole mesh, in its order, to the
    bit. Only the faces with a corner above the plane and one on or below it are handed to
    it (found ``CHUNK_FACES`` at a time), as a mesh of their own corners: a trimesh of the
    whole scene would copy the faces to int64 and cache per-face arrays on it (250 MB on a
    10 M-face model), and most faces are nowhere near the plane. The cut gives each face
    the same segment either way: its corners' heights above the plane, and so the case
    and the edges it is cut along, do not depend on the other faces.
    """
    z_v = vertices[:, 2]
    # (V,) per vertex: 1 above the plane, 2 near or below it, 3 both (just above it)
    side = (z_v > z).view(np.uint8) | ((z_v < z + _SECTION_MARGIN_M).view(np.uint8) << 1)
    picked = []
    for start in range(0, len(faces), CHUNK_FACES):
        corners = side[faces[start:start + CHUNK_FACES]]
        straddles = (corners[:, 0] | corners[:, 1] | corners[:, 2]) == 3
        picked.append(start + np.flatnonzero(straddles))
    crossing = np.concatenate(picked) if picked else np.zeros(0, np.int64)
    if not len(crossing):
        return np.zeros((0, 2, 2)), np.zeros(0, np.int64)
    used, local = np.unique(faces[crossing], return_inverse=True)
    mesh = trimesh.Trimesh(vertices[used], local.reshape(-1, 3), process=False)
    lines, cut = trimesh.intersections.mesh_plane(  # type: ignore[no-untyped-call]
        mesh, plane_normal=[0.0, 0.0, 1.0], plane_origin=[0.0, 0.0, z], return_faces=True)
    if not len(lines):
        return np.zeros((0, 2, 2)), np.zeros(0, np.int64)
    return np.asarray(lines)[:, :, :2], crossing[np.asarray(cut, np.int64)]


def floor_faces(result: PlanResult, level: Level) -> NDArray[np.int64]:
    """(T,) faces of ``level`` seen from above under its section, lowest first (the order
    they are painted in)."""
    return _floor_faces(result, level)[0]


def _floor_faces(result: PlanResult, level: Level
                 ) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """:func:`floor_faces` and (T,) the height of each one's centroid."""
    scene = result.scene
    picked = []
    for start in range(0, scene.n_faces, CHUNK_FACES):
        block = slice(start, start + CHUNK_FACES)
        up = scene.normals_of(block)[:, 2] >= _UP_NZ
        cz = scene.centroids_of(block)[:, 2]
        picked.append(start + np.flatnonzero(
            up & (cz >= level.floor_z - 0.2) & (cz <= level.section_z)))
    below = np.concatenate(picked)
    height_m = scene.centroids_of(below)[:, 2]
    order = np.argsort(height_m, kind="stable")
    return below[order], height_m[order]


@dataclass(frozen=True)
class Floor:
    """A level's floor as drawn: T triangles in their colours, lowest first (the order
    they are painted in).

    Attributes
    ----------
    vertices : (V, 2 or more) float64, plan corners (x, y first)
    corners : (T, 3) int, each triangle's corners in ``vertices``
    rgb : (T, 3) uint8, each triangle's colour (:func:`face_rgb`)
    height_m : (T,) float64, each triangle's height in the paint order
    """

    vertices: NDArray[np.float64]
    corners: NDArray[np.integer[Any]]
    rgb: NDArray[np.uint8]
    height_m: NDArray[np.float64]

    def part(self, keep: NDArray[np.bool_]) -> Floor:
        """The triangles of (T,) bool ``keep``, in the same order."""
        return Floor(self.vertices, self.corners[keep], self.rgb[keep], self.height_m[keep])

    def boxes(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(T, 2) each: every triangle's least and most plan corner, a chunk at a time."""
        lo, hi = np.empty((len(self.corners), 2)), np.empty((len(self.corners), 2))
        for start in range(0, len(self.corners), CHUNK_FACES):
            block = slice(start, start + CHUNK_FACES)
            lo[block], hi[block] = corner_extremes(self.vertices[self.corners[block], :2])
        return lo, hi


# a floor group of fewer pieces is drawn piece by piece (:func:`floor_of`)
_GROUPED_LEAST_PIECES = 32
# the grouped floors of a split plan, made once for the preview and once for the print set
# (one thread draws both, one after the other; Lantern Hollow's plain mesh: 5 s a time)
_FLOORS: _PerPlan[tuple[float, float], Floor] = _PerPlan()


def floor_of(result: PlanResult, level: Level) -> Floor:
    """The floor of ``level`` (:func:`floor_faces`) in its colours (:func:`face_rgb`).

    A split scene's floor faces are drawn by group: the pieces of one file face with one
    colour as few triangles as their outline needs (:mod:`planner.outputs.outline`), at
    the height of the group's lowest piece, where the group holds at least
    ``_GROUPED_LEAST_PIECES`` pieces (Lantern Hollow's plain mesh: 2.08 M floor pieces,
    185,757 triangles). Every piece still shows its own colour; only pixels on a group's
    edge, partly covered by two colours, may take the other one."""
    scene, limits = result.scene, result.limits
    key = (level.floor_z, level.section_z)
    made = _FLOORS.made(result).get(key)
    if made is not None:
        return made
    below, height_m = _floor_faces(result, level)
    rgb = face_rgb(result.faces, limits.target, limits.min_density_pts_m2, below)
    if scene.file_faces is None or len(below) == 0:
        return Floor(scene.vertices, scene.faces[below], rgb, height_m)
    floor = _grouped_floor(scene, below, rgb, height_m)
    _FLOORS.keep(result, {key: floor})
    return floor


def _grouped_floor(scene: Scene, below: NDArray[np.int64], rgb: NDArray[np.uint8],
                   height_m: NDArray[np.float64]) -> Floor:
    """The (n,) floor faces ``below`` of a split ``scene`` (their (n, 3) colours and (n,)
    heights) drawn by group (:func:`floor_of`)."""
    group = (scene.source_face[below].astype(np.int64) << 24) | _packed(rgb)  # face, colour
    order = np.lexsort((below, group))  # each group's faces ascending, as group_triangles wants
    rows = below[order].astype(np.int32)
    starts = np.flatnonzero(np.diff(group[order], prepend=-1))  # (G,) each group's first
    # a group of few pieces is drawn piece by piece: its outline would cost more than the
    # triangles it saves
    sizes = np.diff(np.append(starts, len(rows)))
    alone = np.repeat(sizes < _GROUPED_LEAST_PIECES, sizes)  # (n,) faces drawn as themselves
    alone[starts] = True  # (n,) the first face of each group drawn, its own or not
    offsets = np.append(np.flatnonzero(alone), len(rows))
    corners, made = group_triangles(scene, rows, offsets.astype(np.int64))
    group_rgb = rgb[order[offsets[:-1]]]  # (G, 3)
    group_height_m = np.minimum.reduceat(height_m[order], offsets[:-1])  # (G,)
    rank = np.empty(len(made), np.int64)  # each group's place in the paint order
    rank[np.lexsort((np.arange(len(made)), group_height_m))] = np.arange(len(made))
    triangle_group = np.repeat(np.arange(len(made)), made)  # (T,)
    paint = np.argsort(rank[triangle_group], kind="stable")
    corners, triangle_group = corners[paint], triangle_group[paint]
    # the corners used, from the scene's vertices and the file's (a whole file face),
    # numbered in that order
    file_vertices, _ = scene.file_mesh
    n = len(scene.vertices)
    marked = np.zeros(n + len(file_vertices), bool)
    marked[corners.ravel()] = True
    used = np.flatnonzero(marked)
    number = np.cumsum(marked) - 1  # (V + V0,) each used vertex's number
    xy = np.empty((len(used), 2))
    in_scene = used < n
    xy[in_scene] = scene.vertices[used[in_scene], :2]
    xy[~in_scene] = file_vertices[used[~in_scene] - n, :2]
    return Floor(xy, number[corners].astype(np.int32), group_rgb[triangle_group],
                 group_height_m[triangle_group])


def draw_surfaces(ax: Axes, result: PlanResult, floor: Floor,
                  segments: NDArray[np.float64], cut_faces: NDArray[np.int64], *,
                  rasterized: bool = False) -> None:
    """The ``floor`` (:func:`floor_of`) painted in its colours, and the section
    ``segments`` (:func:`section_at`) as thick lines in the colours of the faces they cut
    over a thin black core.

    ``rasterized`` (for vector output: a PDF): the floor and the coloured lines become an
    image, the black core is drawn as the segments joined into polylines (a few hundred
    paths instead of one per cut face).

    The axes' limits are set before: the collections take no part in them (working out a
    million triangles' extent took seconds)."""
    limits = result.limits

    def rgb(index: NDArray[np.int64]) -> NDArray[np.uint8]:
        return face_rgb(result.faces, limits.target, limits.min_density_pts_m2, index)

    if len(floor.corners):
        ax.add_collection(_FloorFaces(floor.vertices, floor.corners, floor.rgb,
                                      floor.height_m, linewidths=0.0, antialiased=False,
                                      zorder=1, rasterized=rasterized), autolim=False)
    if len(segments):
        lines = LineCollection([], colors=rgb(cut_faces) / 255.0, linewidths=3.2,
                               capstyle="round", zorder=3, rasterized=rasterized)
        Collection.set_paths(lines, _Paths(segments, closed=False))
        ax.add_collection(lines, autolim=False)
        core = LineCollection([], colors="black", linewidths=0.7, zorder=4)
        if rasterized:
            Collection.set_paths(core, one_path(joined_lines(segments)))
        else:
            Collection.set_paths(core, _Paths(segments, closed=False))
        ax.add_collection(core, autolim=False)


class _Paths(Sequence[Path]):
    """The paths of (N, K, 2) ``vertices``, each made when the renderer asks for it.

    The same paths as PolyCollection (``closed``) or LineCollection would make of them up
    front, sharing one template's codes and flags; made up front, they cost ~400 bytes
    each for as long as the figure lives, 350 MB for the floors of a 10 M-face office.
    """

    def __init__(self, vertices: NDArray[np.float64], *, closed: bool) -> None:
        self.vertices = vertices
        self.template = Path(vertices[0], closed=closed)

    def __len__(self) -> int:
        return len(self.vertices)

    @overload
    def __getitem__(self, index: int) -> Path: ...

    @overload
    def __getitem__(self, index: slice) -> list[Path]: ...

    def __getitem__(self, index: int | slice) -> Path | list[Path]:
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        # what PolyCollection.set_verts calls for each polygon
        path: Path = Path._fast_from_codes_and_verts(  # type: ignore[attr-defined]
            self.vertices[index], self.template.codes, internals_from=self.template)
        return path


class _FloorFaces(PolyCollection):
    """Triangles filled in their colours, kept as (T, 3) corner indices into (V, 3)
    ``vertices``, (T, 3) uint8 sRGB colours and (T,) centroid heights, in the order they
    are painted (lowest first); their paths are made inside :meth:`draw`, ``_DRAW_FACES``
    triangles at a time, and let go after.

    The triangles of one height and one colour in a run are filled as one path of many
    closed triangles (turned counter-clockwise, so under the non-zero rule overlapping ones
    never cancel), runs of heights lowest first. A path a triangle (as a PolyCollection
    would have it) costs microseconds each to make and fill: on the 9.7 M-face office of
    ``benchmarks/ifc_office.py`` the preview takes 4.1 s instead of 6.5 s, ``plan.pdf``
    6.1 s instead of 8.3 s. Filled together, the pixels a triangle shares with its
    neighbours of the same colour are filled once their coverage adds up, where one at a
    time each could stay under Agg's half-pixel threshold; the colour a triangle shows is
    its own (``test_floor_colours_match_faces_npz``). At most ``_PATH_TRIANGLES`` go in
    one path, well within Agg's cell memory.
    """

    def __init__(self, vertices: NDArray[np.float64], corners: NDArray[np.integer[Any]],
                 rgb: NDArray[np.uint8], height_m: NDArray[np.float64], **kwargs: Any) -> None:
        super().__init__([], **kwargs)
        self._scene_vertices = vertices
        self._corner_indices = corners
        self._rgb = rgb
        self._height_m = height_m

    @allow_rasterization  # type: ignore[untyped-decorator]  # matplotlib's is untyped
    def draw(self, renderer: RendererBase) -> None:
        n = len(self._corner_indices)
        ends = [*range(_DRAW_FACES, n, _DRAW_FACES), n]
        if len(ends) > 1 and ends[-1] - ends[-2] == 1:
            del ends[-2]  # never a run of one triangle (see _draw_run)
        start = 0
        try:
            for end in ends:
                self._draw_run(renderer, slice(start, end))
                start = end
        finally:
            self.set_verts([])
            self.set_facecolor([])
            self.set_edgecolor([])

    def _draw_run(self, renderer: RendererBase, run: slice) -> None:
        xy = self._scene_vertices[self._corner_indices[run], :2]  # (t, 3, 2)
        turn = ((xy[:, 1, 0] - xy[:, 0, 0]) * (xy[:, 2, 1] - xy[:, 0, 1])
                - (xy[:, 1, 1] - xy[:, 0, 1]) * (xy[:, 2, 0] - xy[:, 0, 0]))
        xy[turn < 0] = xy[turn < 0][:, ::-1]  # counter-clockwise
        rgb = self._rgb[run]
        height = self._height_m[run]
        # (t,) which group each triangle paints in: heights in paint order, then colours
        level = np.concatenate([[0], np.cumsum(height[1:] != height[:-1])])
        group = (level << 24) | _packed(rgb)
        order = np.argsort(group, kind="stable")
        key = group[order]
        starts = np.flatnonzero(np.concatenate([[True], key[1:] != key[:-1]])).tolist()
        bounds = []  # (first, stop) in ``order`` of each path: a group, or a part of one
        for group_start, group_stop in zip(starts, [*starts[1:], len(key)], strict=True):
            for first in range(group_start, group_stop, _PATH_TRIANGLES):
                bounds.append((first, min(first + _PATH_TRIANGLES, group_stop)))
        if len(bounds) == 1 and len(order) > 1:
            # a lone path is drawn as a marker (another code path, snapped to pixels)
            bounds = [(0, len(order) // 2), (len(order) // 2, len(order))]
        closed = np.empty((len(order), 4, 2))  # the first corner again, as PolyCollection
        closed[:, :3] = xy[order]
        closed[:, 3] = closed[:, 0]
        codes = np.tile(np.array([Path.MOVETO, Path.LINETO, Path.LINETO, Path.CLOSEPOLY],
                                 Path.code_type), _PATH_TRIANGLES)
        paths = [Path(closed[a:b].reshape(-1, 2), codes[:4 * (b - a)]) for a, b in bounds]
        colours = rgb[order[[a for a, _ in bounds]]] / 255.0
        self.set_facecolor(colours)  # type: ignore[arg-type]  # stubs: sequences only
        self.set_edgecolor(colours)  # type: ignore[arg-type]
        Collection.set_paths(self, paths)
        del xy, closed, colours
        super().draw(renderer)


def joined_lines(segments: NDArray[np.float64], decimals: int = 6) -> list[NDArray[np.float64]]:
    """The (S, 2, 2) segments joined end to end into polylines, each (N, 2), collinear
    vertices dropped; ends equal to ``decimals`` places join."""
    if not len(segments):
        return []
    ends = np.round(segments, decimals)
    merged = shapely.line_merge(shapely.multilinestrings(list(ends)))
    return [np.asarray(shapely.get_coordinates(shapely.simplify(line, 0.0)))
            for line in shapely.get_parts(merged)]


def one_path(lines: list[NDArray[np.float64]]) -> list[Path]:
    """The polylines ``lines``, (N, 2) each, as one compound path (each starts with a move),
    or none. A vector backend writes a collection of many paths one at a time, each with
    its own graphics state: a sports hall's section, whose window bars the plane cuts into
    thousands of small loops, took seconds of ``plan.pdf``; as one path it is one stroke."""
    if not lines:
        return []
    vertices = np.concatenate(lines)
    codes = np.full(len(vertices), Path.LINETO, dtype=Path.code_type)
    codes[np.cumsum([0] + [len(line) for line in lines[:-1]])] = Path.MOVETO
    return [Path(vertices, codes)]


def _draw_level(ax: Axes, result: PlanResult, level: Level) -> None:
    scene = result.scene
    draw_surfaces(ax, result, floor_of(result, level),
                  *section_at(scene.vertices, scene.faces, level.section_z))
    candidates = result.candidates.positions[level.candidates]
    ax.scatter(candidates[:, 0], candidates[:, 1], s=2.5, c=[(0.35, 0.35, 0.35)],
               linewidths=0, alpha=0.55, zorder=5)
    reach = density_range_m(result.spec.min_density_pts_m2, result.spec.angular_step_rad)
    reach = min(reach, result.spec.dof_max_m)
    members = set(level.candidates.tolist())
    station_colour = _rgb(STATION_RGB)
    if result.survey is not None:
        _draw_survey(ax, result, level, members)
    for order, candidate in enumerate(result.chosen.stations):
        if candidate not in members:
            continue
        x, y = result.candidates.positions[candidate, :2]
        if math.isfinite(reach):
            ax.add_patch(Circle((x, y), reach, fill=False, linestyle=(0, (4, 3)),
                                linewidth=0.8, edgecolor=station_colour, alpha=0.55,
                                zorder=6))
        label = str(order + 1)
        size = 15 if len(label) < 3 else 19
        if is_critical(result, order):  # the goal breaks without it in place: a red ring
            ax.plot([x], [y], marker="o", markersize=size + 7, markerfacecolor="none",
                    markeredgecolor=CRITICAL_RGB, markeredgewidth=2.2, linestyle="none",
                    zorder=8)
        ax.plot([x], [y], marker="o", markersize=size, markerfacecolor=station_colour,
                markeredgecolor="white", markeredgewidth=1.2, linestyle="none", zorder=8)
        ax.text(x, y, label, ha="center", va="center_baseline", color="white",
                fontsize=8 if len(label) < 3 else 7, fontweight="bold", zorder=9)


def is_critical(result: PlanResult, order: int) -> bool:
    """The station's worst setup within the placement tolerance alone breaks the goal."""
    return result.tolerance is not None and result.tolerance.stations[order].critical


def _draw_survey(ax: Axes, result: PlanResult, level: Level, members: set[int]) -> None:
    """Registration edges (thin, dotted) and the walking route (legs, with visit numbers)."""
    assert result.survey is not None
    draw_survey_lines(ax, result, level, members)
    positions = result.candidates.positions
    stations = result.chosen.stations
    for order, candidate in enumerate(stations):
        visit = result.survey.visit_of(order + 1)
        if candidate in members and visit is not None:
            x, y = positions[candidate, :2]
            ax.annotate(f"v{visit}", (x, y), xytext=(8, 8), textcoords="offset points",
                        fontsize=7, color=VISIT_RGB, fontweight="bold", zorder=9)


def draw_survey_lines(ax: Axes, result: PlanResult, level: Level, members: set[int]) -> None:
    """Registration edges between stations of ``level`` (thin, dotted) and the walking
    route's legs within its height band (the axes' limits are set before)."""
    assert result.survey is not None
    positions = result.candidates.positions
    stations = result.chosen.stations
    for edge in result.survey.registration.edges:
        a, b = stations[edge.a - 1], stations[edge.b - 1]
        if edge.ok and a in members and b in members:
            ax.plot(positions[[a, b], 0], positions[[a, b], 1], linestyle=(0, (1, 2)),
                    linewidth=0.9, color=EDGE_RGB, zorder=6)
    low, high = level.floor_z - 0.3, level.section_z
    for leg in result.survey.route.legs:
        path = np.asarray(leg.path)
        inside = (path[:, 2] >= low) & (path[:, 2] <= high)
        segments = [path[i:i + 2, :2] for i in range(len(path) - 1) if inside[i] and inside[i + 1]]
        if segments:  # most legs are on another storey: nothing to draw
            ax.add_collection(LineCollection(segments, colors=[VISIT_RGB], linewidths=1.3,
                                             zorder=7), autolim=False)
    for check in result.survey.route.door_checks:  # at knee height: within the band
        x, y, z = check.at
        if low <= z <= high:
            ax.plot([x], [y], marker="^", markersize=9, color=CHECK_RGB,
                    markeredgecolor="white", markeredgewidth=0.6, zorder=9)
            ax.annotate(f"leg {check.leg}: check it opens", (x, y), xytext=(7, -9),
                        textcoords="offset points", fontsize=6, color=CHECK_RGB,
                        fontweight="bold", zorder=9)


def _nice_length(span_m: float) -> float:
    """A round length about a quarter of ``span_m``."""
    target = span_m / 4
    exponent = math.floor(math.log10(target))
    best = 10.0**exponent
    for mantissa in (1.0, 2.0, 5.0, 10.0):
        if mantissa * 10.0**exponent <= target:
            best = mantissa * 10.0**exponent
    return best


def scale_bar(ax: Axes) -> None:
    x0, x1 = ax.get_xlim()
    y0, y1 = ax.get_ylim()
    length = _nice_length(x1 - x0)
    height = (y1 - y0) * 0.012
    left, base = x0 + (x1 - x0) * 0.03, y0 + (y1 - y0) * 0.035
    ax.add_patch(Rectangle((left - (x1 - x0) * 0.01, base - height * 1.6),
                           length + (x1 - x0) * 0.045, height * 5.6, facecolor="white",
                           edgecolor="none", alpha=0.85, zorder=10))
    for k in range(4):
        ax.add_patch(Rectangle((left + k * length / 4, base), length / 4, height,
                               facecolor="black" if k % 2 == 0 else "white",
                               edgecolor="black", linewidth=0.6, zorder=11))
    unit = f"{length:g} m"
    ax.text(left, base + height * 1.4, "0", ha="center", va="bottom", fontsize=7, zorder=11)
    ax.text(left + length, base + height * 1.4, unit, ha="center", va="bottom", fontsize=7,
            zorder=11)


def _budget_words(spec: PlanSpec) -> str:
    """The plan's budget as the subtitle names it before the goal ("budget 2 h, "), or ""."""
    if spec.max_field_time_h is not None:
        return f"budget {spec.max_field_time_h:g} h, "
    if spec.max_stations is not None:
        return f"budget {spec.max_stations} stations, "
    return ""


def _key(fig: Figure, result: PlanResult, scale: int) -> None:
    """Title, north arrow, legend, totals and the station list in the right column."""
    doc_totals = _totals(result)
    fig.text(0.025, 0.965, "Scan plan: stations and coverage seen from above", fontsize=14,
             fontweight="bold", va="center")
    fig.text(0.025, 0.928,
             f"{doc_totals['stations']} stations ({result.chosen.method.replace('_', ' ')}), "
             f"{doc_totals['covered']:.1f} m² covered = {doc_totals['fraction'] * 100:.1f} % of "
             f"the {doc_totals['max']:.1f} m² coverable ({_budget_words(result.spec)}goal "
             f"{result.spec.coverage_goal * 100:.0f} %)",
             fontsize=10.5, va="center")
    north_arrow(fig, (0.935, 0.86, 0.05, 0.1))
    fig.text(0.755, 0.91, f"Scale 1:{scale} on A4", fontsize=10, fontweight="bold")
    fig.text(0.755, 0.885, "north arrow = +Y axis of the model", fontsize=7, color="0.3")
    fig.legend(handles=legend_handles(result), loc="upper left", bbox_to_anchor=(0.75, 0.865),
               fontsize=7.5, frameon=False, handlelength=2.2, borderaxespad=0.0,
               labelspacing=0.55)
    lines = plan_lines(result)
    # a sixth line (the scanner's field time) starts the block a line higher
    fig.text(0.755, 0.47 + 0.022 * (len(lines) - 5), "\n".join(lines), fontsize=7.5, va="top",
             linespacing=1.5)
    _station_table(fig, result, top=0.355)


def north_arrow(fig: Figure, rect: tuple[float, float, float, float]) -> None:
    """A north arrow (+Y of the model) in ``rect`` (figure fractions)."""
    nax = fig.add_axes(rect)
    nax.set_xlim(-1, 1)
    nax.set_ylim(-1, 1.4)
    nax.axis("off")
    nax.annotate("", xy=(0, 0.9), xytext=(0, -0.9),
                 arrowprops={"arrowstyle": "-|>,head_width=0.5,head_length=0.9",
                             "color": "black", "linewidth": 1.6})
    nax.text(0, 1.15, "N", ha="center", va="center", fontsize=12, fontweight="bold")
    nax.text(0, -1.05, "+Y", ha="center", va="top", fontsize=7)


def legend_handles(result: PlanResult) -> list[Any]:
    """The legend of a plan view: face classes, section, candidates, stations, range."""
    reach = density_range_m(result.spec.min_density_pts_m2, result.spec.angular_step_rad)
    handles = [
        Patch(facecolor=_rgb(COVERED_LOW_RGB), label="covered, density at requirement"),
        Patch(facecolor=_rgb(COVERED_HIGH_RGB),
              label=f"covered, density ≥ {COVERED_SATURATION:g}x requirement"),
        Patch(facecolor=_rgb(CLASS_RGB[MISSED]), label="coverable, not covered by the plan"),
        Patch(facecolor=_rgb(CLASS_RGB[UNREACHABLE]), label="not coverable from any candidate"),
        Patch(facecolor=_rgb(CLASS_RGB[NOT_TARGET]), label="no requirement"),
        Line2D([], [], color="black", linewidth=0.7, label="cut at scanner height"),
        Line2D([], [], marker="o", color="none", markerfacecolor=(0.35, 0.35, 0.35),
               markersize=3, markeredgewidth=0, label="candidate position"),
        Line2D([], [], marker="o", color="none", markerfacecolor=_rgb(STATION_RGB),
               markeredgecolor="white", markersize=11, label="station, in scan order"),
    ]
    if result.tolerance is not None and any(s.critical for s in result.tolerance.stations):
        handles.append(Line2D([], [], marker="o", color="none", markerfacecolor="none",
                              markeredgecolor=CRITICAL_RGB, markeredgewidth=2.0, markersize=13,
                              label=f"critical (crit.): goal breaks if set up "
                                    f"{result.spec.tolerance_radius_m:g} m off"))
    if math.isfinite(reach):
        handles.append(Line2D([], [], color=_rgb(STATION_RGB), linestyle=(0, (4, 3)),
                              alpha=0.7, label=f"head-on density range {reach:.2f} m"))
    if result.survey is not None and result.survey.route.door_checks:
        handles.append(Line2D([], [], marker="^", color="none", markerfacecolor=CHECK_RGB,
                              markeredgecolor="white", markersize=9,
                              label="glazing to the floor on the route: check it opens"))
    return handles


def plan_lines(result: PlanResult) -> list[str]:
    """The plan's model and scanner in a few lines: faces, areas, candidates, limits."""
    doc_totals = _totals(result)
    spec = result.spec
    lines = [
        f"Faces {result.scene.n_faces:,}, area {doc_totals['total']:.1f} m²",
        f"Coverable (max achievable) {doc_totals['max']:.1f} m²",
        f"Candidates {len(result.candidates):,}",
        f"Requirement {spec.min_density_pts_m2:,.0f} pts/m², incidence ≥ "
        f"{spec.min_incidence_deg:g}°",
        f"Scanner step {spec.point_spacing_m * 1000:g} mm at {spec.reference_distance_m:g} m, "
        f"range {spec.dof_min_m:g} to {spec.dof_max_m:g} m",
    ]
    field_time = None if result.survey is None else result.survey.field_time
    if field_time is not None and field_time.scanner is not None:  # a scanner was given
        scan = "unknown" if field_time.scan_s is None else f"{field_time.scan_s / 60:.1f} min"
        lines.append(f"{field_time.scanner}: scans {scan}, field time "
                     + ("unknown" if field_time.total_s is None
                        else f"{field_time.total_s / 60:.1f} min"))
    checks = () if result.survey is None else result.survey.route.door_checks
    if checks:  # a plain mesh's glazed doors on the route (planner.survey.route)
        lines.append(f"Route: {len(checks)} glazed opening{'s' if len(checks) > 1 else ''} "
                     "to check (route.door_checks)")
    return lines


def _totals(result: PlanResult) -> dict[str, float]:
    chosen = result.chosen
    max_area = chosen.max_achievable_area_m2
    covered = chosen.covered_area_m2[-1] if chosen.stations else 0.0
    return {"stations": len(chosen.stations), "covered": covered, "max": max_area,
            "fraction": covered / max_area if max_area else 0.0,
            "total": float(result.scene.areas.sum())}


def station_rows(result: PlanResult, orders: Iterable[int], *, visit: bool = False) -> list[str]:
    """A monospaced table of the stations at ``orders`` (0-based selection order), header
    first: number, (visit,) model coordinates, new area, cumulative coverage."""
    chosen = result.chosen
    max_area = chosen.max_achievable_area_m2
    # with a scanner: the setting each station is scanned at and its scan time
    scans = () if result.survey is None else result.survey.scans
    rows = [("  no. visit" if visit else "  no.") + "      x       y       z   new m²  cum. %"
            + (" setting   scan" if scans else "")]
    # the plan view is drawn levelled (up_axis); the table gives the model's coordinates
    positions = to_model(scene_rotation(result.scene.metadata), result.candidates.positions)
    for order in orders:
        x, y, z = positions[chosen.stations[order]]
        fraction = chosen.covered_area_m2[order] / max_area * 100 if max_area else 0.0
        place = ""
        if visit:
            number = None if result.survey is None else result.survey.visit_of(order + 1)
            place = f" {'-' if number is None else number:>5}"
        row = (f"{order + 1:5d}{place} {x:7.2f} {y:7.2f} {z:6.2f} "
               f"{chosen.new_area_m2[order]:8.2f} {fraction:7.1f}")
        if scans:
            scan = scans[order]
            seconds = "?" if scan.scan_s is None else f"{scan.scan_s:.0f}s"
            row += f" {(scan.setting or 'plan')[:8]:<8}{seconds:>6}"
        if is_critical(result, order):
            row += " crit."
        rows.append(row)
    return rows


def _stations_title(result: PlanResult) -> str:
    """The station table's title: how many stations, and how many the goal needs at least
    (``selection.lower_bound``) where that is fewer: what no plan can go below. A budget's
    plan: the most any plan of as many stations could cover (the share it covers is in the
    figure's subtitle); a budget of hours: the most any plan in those hours could cover.
    Short enough for the side panel at 8 pt (about 44 characters)."""
    n = len(result.chosen.stations)
    title = f"{n} station{'' if n == 1 else 's'}"
    budget = result.selection_report.get("budget")
    lower = result.selection_report.get("lower_bound")
    if budget is not None and "field_time" in budget:  # a budget of hours
        hours = budget["field_time"]["max_field_time_h"]
        title += f"; in {hours:g} h at most {100 * budget['upper_bound_fraction']:.1f} %"
    elif budget is not None:
        verb = "covers" if n == 1 else "cover"
        title += f"; any {n} {verb} at most {100 * budget['upper_bound_fraction']:.1f} %"
    elif lower is not None and int(lower) < n:
        title += f", at least {lower} needed"
    return title


def _station_table(fig: Figure, result: PlanResult, top: float) -> None:
    chosen = result.chosen
    limit = 14
    rows = station_rows(result, range(min(limit, len(chosen.stations))))
    scans = () if result.survey is None else result.survey.scans
    if len(chosen.stations) > limit:
        rows.append(f"  ... {len(chosen.stations) - limit} more in stations.csv")
    rows.append("  x, y, z: model coordinates, m")
    fig.text(0.755, top, _stations_title(result), fontsize=8, fontweight="bold",
             va="bottom")
    # the two scan columns take a smaller type to stay on the page
    fig.text(0.752, top - 0.006, "\n".join(rows), fontsize=5.8 if scans else 6.8,
             family="monospace", va="top", linespacing=1.35)


# --- curve.png ------------------------------------------------------------------------


def draw_curve(result: PlanResult) -> Figure:
    """The coverage curve: stations needed against the coverage goal, per method."""
    curve = coverage_curve(result.selections, result.optimal)
    goals = np.asarray(curve["goals"]) * 100
    fig = Figure(figsize=CURVE_SIZE_IN, dpi=DPI)
    FigureCanvasAgg(fig)
    ax = fig.add_axes((0.09, 0.12, 0.88, 0.76))
    styles = {"greedy": ("greedy", "o", (0.12, 0.35, 0.7)),
              "weighted_greedy": ("weighted greedy", "s", (0.85, 0.4, 0.05))}
    top = 1
    for method, (label, marker, colour) in styles.items():
        if method not in curve:
            continue
        counts = np.asarray(curve[method])
        top = max(top, int(counts.max()))
        ax.plot(goals, counts, marker=marker, markersize=4.5, color=colour, linewidth=1.6,
                drawstyle="default", label=label)
    goal = result.spec.coverage_goal * 100
    ax.axvline(goal, color="0.3", linestyle="--", linewidth=1.0)
    n_chosen = len(result.chosen.stations)
    ax.plot([goal], [n_chosen], marker="o", markersize=11, markerfacecolor="none",
            markeredgecolor="black", markeredgewidth=1.4, linestyle="none",
            label=f"the plan: {n_chosen} stations at {goal:.0f} % "
                  f"({result.chosen.method.replace('_', ' ')})")
    if result.optimal is not None:
        n_opt = len(result.optimal.selection.stations)
        ax.plot([goal], [n_opt], marker="*", markersize=13, color=(0.1, 0.55, 0.2),
                linestyle="none",
                label=f"optimal (MILP): {n_opt}, proven ≥ {result.optimal.lower_bound}")
    ax.set_xlim(0, 102)
    ax.set_ylim(0, top * 1.08 + 0.5)
    ax.set_xticks(np.arange(0, 101, 10))
    ax.yaxis.set_major_locator(MaxNLocator(integer=True))
    ax.grid(True, color="0.88", linewidth=0.7)
    ax.set_axisbelow(True)
    ax.set_xlabel("coverage goal (% of the coverable area)")
    ax.set_ylabel("stations needed")
    max_area = result.chosen.max_achievable_area_m2
    ax.set_title(f"Coverage curve: stations against goal (coverable area {max_area:.1f} m², "
                 f"{len(result.candidates):,} candidates)", fontsize=10, loc="left")
    ax.legend(loc="upper left", fontsize=8.5, frameon=True)
    return fig


def curve_png(result: PlanResult) -> bytes:
    """``curve.png``: 1200 x 750 px."""
    return _png(draw_curve(result))
