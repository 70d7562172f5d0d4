"""``plan.pdf``: the print set, one A3 sheet per storey at a standard scale, tiled when a
storey does not fit.

Every storey of :func:`planner.outputs.drawing.levels` (the storeys of ``preview.png``) gets
its own sheets, drawn as the preview draws a panel (floor coloured by coverage, the section
at instrument height, candidates, registration edges, walking route) and printed to scale
on A3 landscape (ISO 216, 420 x 297 mm): the map on the left, the key on the right (scale,
north arrow, legend, the plan's figures, the stations on the sheet).

The scale
    A station is a disc of ``MARKER_MM`` on paper with its number, and its visit number
    beside it: a marker needs ``MARKER_PITCH_MM`` of paper. The scale of a storey is the
    finest of 1:50, 1:100 and 1:200 at which the storey fits one sheet, if markers keep
    their pitch at it (the closest two stations of the storey are at least
    ``MARKER_PITCH_MM`` apart on paper); otherwise the coarsest of them at which markers
    keep their pitch, the storey tiled over several sheets. Stations closer than 0.5 m
    (10 mm at 1:50) are drawn at 1:25, 1:20 or 1:10. Stations one over the other (two
    floors in one drawn storey, two instrument heights at one spot) share a marker at any
    scale and do not set it (:func:`min_spacing_m`).
Tiles
    Neighbouring tiles share a strip of ``OVERLAP_MM``; they are named by column (A, B, ...
    from the west) and row (1, 2, ... from the north), and each tiled sheet carries a key
    plan: the storey's section with every tile outlined and this one shaded.
Stations
    The key lists the stations drawn on the sheet; when they do not all fit, the rest are
    on the station list at the end of the set, which then lists every station.

The floor (up to millions of small triangles) is embedded as an image at ``RASTER_DPI``;
everything else is vector. Same input, same bytes: no creation date, no producer version.
"""

from __future__ import annotations

import io
import math
import string
import zlib
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np
from matplotlib.artist import Artist
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.backends.backend_pdf import PdfPages
from matplotlib.collections import Collection, LineCollection, PatchCollection
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Circle, Rectangle
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from planner.density import density_range_m
from planner.outputs import drawing
from planner.outputs.drawing import Level
from planner.pipeline import PlanResult

SHEET_MM = (420.0, 297.0)  # A3 landscape, ISO 216
MARGIN_MM = 10.0
KEY_MM = 100.0  # the key's column on the right
TITLE_MM = 14.0  # the title band over the map
MAP_MM = (SHEET_MM[0] - 2 * MARGIN_MM - KEY_MM - 6.0, SHEET_MM[1] - 2 * MARGIN_MM - TITLE_MM)
MARKER_MM = 5.0  # diameter of a station's disc on paper
LABEL_GAP_MM = 0.4  # between the disc and its visit number
# paper a marker needs: its disc (5 mm) and its visit number beside it (up to 4.5 mm at
# 5.5 pt), so that two markers this far apart never overlap
MARKER_PITCH_MM = 10.0
STANDARD_SCALES = (50, 100, 200)
# stations more than STACKED_DZ_M apart in height stand one over the other: floors of one
# drawn storey are a head room apart (1.8 m and more), while a split level (0.45 m in the
# Renga house) or instrument heights at neighbouring spots keep their markers apart on
# paper and count. Closer than SAME_SPOT_M in plan they stand on one spot (instrument
# heights at one point). Either way their markers coincide at any scale. Pairs are looked
# for within STACKED_SEARCH_M (a marker's pitch at 1:200)
STACKED_DZ_M = 1.0
SAME_SPOT_M = 0.01
STACKED_SEARCH_M = 2.0
FINER_SCALES = (25, 20, 10)
OVERLAP_MM = 15.0
RASTER_DPI = 150
TABLE_ROW_MM = 2.95  # a row of the station table (6.5 pt, line spacing 1.29)
LIST_ROWS = 84  # rows of one column of the station list
LIST_COLUMNS = 3
_PDF_METADATA: dict[str, str | None] = {
    "Creator": "scanplan", "Producer": None, "CreationDate": None, "ModDate": None}
_MM = 1 / 25.4  # inch


@dataclass(frozen=True)
class Sheet:
    """One sheet of the set: a view of a storey (plan-frame metres) at 1:``scale``."""

    level: Level
    level_index: int
    scale: int
    view: tuple[float, float, float, float]  # xmin, ymin, xmax, ymax
    tile: str  # "B2"; "" when the storey fits one sheet
    tiles: tuple[tuple[str, tuple[float, float, float, float]], ...]  # every tile of the storey


@dataclass(frozen=True)
class DrawnSheet:
    """A drawn sheet and, per station drawn on it (selection order, 0-based), the artists of
    its marker (disc, number, visit label)."""

    figure: Figure
    sheet: Sheet
    markers: dict[int, tuple[Artist, ...]]


def min_spacing_m(xyz: NDArray[np.float64]) -> float:
    """The smallest plan distance between two of the (N, 3) stations whose markers could
    stand apart on paper, m: at least ``STACKED_SEARCH_M`` (1:200 keeps their pitch) when
    no two such are closer; inf for fewer than two stations.

    Stations one over the other (more than ``STACKED_DZ_M`` apart in height: floors of
    one drawn storey, or instrument heights at one spot) and stations on one spot (closer
    than ``SAME_SPOT_M``) share a marker position at every scale, so they do not set it:
    counted, a basement's station under a ground-floor one made a house's plain mesh 345
    sheets at 1:10 instead of a few at 1:200."""
    xyz = np.asarray(xyz, np.float64)
    if len(xyz) < 2:
        return math.inf
    tree = cKDTree(xyz[:, :2])
    pairs = tree.query_pairs(STACKED_SEARCH_M, output_type="ndarray")
    if len(pairs) == 0:  # none nearer than the search: the nearest pair sets the pitch
        distances, _ = tree.query(xyz[:, :2], k=2)
        return float(distances[:, 1].min())
    plan_m = np.linalg.norm(xyz[pairs[:, 0], :2] - xyz[pairs[:, 1], :2], axis=1)
    rise_m = np.abs(xyz[pairs[:, 0], 2] - xyz[pairs[:, 1], 2])
    apart = (plan_m >= SAME_SPOT_M) & (rise_m <= STACKED_DZ_M)
    return float(plan_m[apart].min()) if apart.any() else STACKED_SEARCH_M


def storey_scale(extent: tuple[float, float, float, float], spacing_m: float) -> int:
    """The scale 1:N of a storey spanning ``extent`` whose stations are ``spacing_m`` apart
    at the closest (see the module docstring)."""
    def keeps_pitch(scale: int) -> bool:
        return spacing_m * 1000.0 / scale >= MARKER_PITCH_MM

    def fits(scale: int) -> bool:
        x0, y0, x1, y1 = extent
        return (x1 - x0 <= MAP_MM[0] * scale / 1000.0
                and y1 - y0 <= MAP_MM[1] * scale / 1000.0)

    legible = [s for s in STANDARD_SCALES if keeps_pitch(s)]
    if not legible:
        return next((s for s in FINER_SCALES if keeps_pitch(s)), FINER_SCALES[-1])
    return next((s for s in legible if fits(s)), legible[-1])


def _tiles(extent: tuple[float, float, float, float], scale: int
           ) -> list[tuple[str, tuple[float, float, float, float]]]:
    """The views covering ``extent`` at 1:``scale``, named by column and row, row by row
    from the north-west."""
    width_m, height_m = (MAP_MM[0] * scale / 1000.0, MAP_MM[1] * scale / 1000.0)
    overlap_m = OVERLAP_MM * scale / 1000.0
    x0, y0, x1, y1 = extent

    def count(span: float, size: float) -> int:
        return 1 if span <= size else math.ceil((span - overlap_m) / (size - overlap_m))

    nx, ny = count(x1 - x0, width_m), count(y1 - y0, height_m)
    left = (x0 + x1) / 2 - (nx * (width_m - overlap_m) + overlap_m) / 2
    top = (y0 + y1) / 2 + (ny * (height_m - overlap_m) + overlap_m) / 2
    tiles = []
    for row in range(ny):
        for col in range(nx):
            vx = left + col * (width_m - overlap_m)
            vy = top - row * (height_m - overlap_m) - height_m
            name = f"{_column_name(col)}{row + 1}" if nx * ny > 1 else ""
            tiles.append((name, (vx, vy, vx + width_m, vy + height_m)))
    return tiles


def _column_name(index: int) -> str:
    letters = string.ascii_uppercase
    return letters[index] if index < 26 else letters[index // 26 - 1] + letters[index % 26]


def sheets(result: PlanResult) -> list[Sheet]:
    """The sheets of the set, storey by storey (lowest first), tiles row by row."""
    out: list[Sheet] = []
    positions = result.candidates.positions
    all_levels = drawing.levels(result)
    extents = drawing.level_extents(result, all_levels)
    for index, (level, extent) in enumerate(zip(all_levels, extents, strict=True)):
        members = np.asarray(sorted(set(level.candidates.tolist())
                                    .intersection(result.chosen.stations)), np.int64)
        scale = storey_scale(extent, min_spacing_m(positions[members]))
        tiles = tuple(_tiles(extent, scale))
        out += [Sheet(level=level, level_index=index, scale=scale, view=view, tile=name,
                      tiles=tiles) for name, view in tiles]
    return out


class _Storey:
    """What every sheet of one storey draws: its floor faces, section and stations."""

    def __init__(self, result: PlanResult, level: Level) -> None:
        scene = result.scene
        self.level = level
        self.floor = drawing.floor_of(result, level)
        self.floor_lo, self.floor_hi = self.floor.boxes()  # (T, 2) each: the plan boxes
        self.segments, self.cut_faces = drawing.section_at(scene.vertices, scene.faces,
                                                           level.section_z)
        self.members = set(level.candidates.tolist())
        self.orders = storey_orders(result, level)

    @cached_property
    def outline(self) -> list[NDArray[np.float64]]:
        """The section joined into polylines, (N, 2) each, made once for the key plans of
        all the storey's sheets (the segments are one a cut face)."""
        return drawing.joined_lines(self.segments)


def storey_orders(result: PlanResult, level: Level) -> list[int]:
    """Selection orders (0-based) of the stations of ``level``."""
    members = set(level.candidates.tolist())
    return [order for order, c in enumerate(result.chosen.stations) if c in members]


def _in_view(lo: NDArray[np.float64], hi: NDArray[np.float64],
             view: tuple[float, float, float, float]) -> NDArray[np.bool_]:
    """(N,) whether boxes (N, 2) ``lo``..``hi`` meet ``view``."""
    x0, y0, x1, y1 = view
    return (hi[:, 0] >= x0) & (lo[:, 0] <= x1) & (hi[:, 1] >= y0) & (lo[:, 1] <= y1)


def _figure() -> Figure:
    fig = Figure(figsize=(SHEET_MM[0] * _MM, SHEET_MM[1] * _MM), dpi=RASTER_DPI)
    FigureCanvasAgg(fig)
    return fig


def _rect(x_mm: float, y_mm: float, w_mm: float, h_mm: float) -> tuple[float, float, float,
                                                                          float]:
    """A rectangle in figure fractions from millimetres (origin bottom left)."""
    return (x_mm / SHEET_MM[0], y_mm / SHEET_MM[1], w_mm / SHEET_MM[0], h_mm / SHEET_MM[1])


def draw_sheet(result: PlanResult, sheet: Sheet, storey: _Storey, number: int, total: int
               ) -> DrawnSheet:
    """Draw one sheet of the set (page ``number`` of ``total``)."""
    fig = _figure()
    level, view = sheet.level, sheet.view
    ax = fig.add_axes(_rect(MARGIN_MM, MARGIN_MM, *MAP_MM))
    ax.set_xlim(view[0], view[2])
    ax.set_ylim(view[1], view[3])
    ax.set_xticks([])
    ax.set_yticks([])
    for spine in ax.spines.values():
        spine.set_linewidth(0.6)
        spine.set_color("0.4")
    floor = storey.floor.part(_in_view(storey.floor_lo, storey.floor_hi, view))
    segments = storey.segments
    cut = _in_view(segments.min(axis=1), segments.max(axis=1), view) if len(segments) else \
        np.zeros(0, bool)
    drawing.draw_surfaces(ax, result, floor, segments[cut],
                          storey.cut_faces[cut], rasterized=True)
    candidates = result.candidates.positions[level.candidates]
    shown = _in_view(candidates[:, :2], candidates[:, :2], view)
    ax.scatter(candidates[shown, 0], candidates[shown, 1], s=2.0, c=[(0.35, 0.35, 0.35)],
               linewidths=0, alpha=0.55, zorder=5)
    if result.survey is not None:
        drawing.draw_survey_lines(ax, result, level, storey.members)
    markers = _draw_markers(ax, result, sheet, storey)
    drawing.scale_bar(ax)
    _title(fig, result, sheet, storey, number, total)
    _key(fig, result, sheet, storey)
    return DrawnSheet(figure=fig, sheet=sheet, markers=markers)


def _on_sheet(result: PlanResult, sheet: Sheet, orders: Sequence[int]) -> list[int]:
    """Those of the stations at ``orders`` whose disc reaches into the sheet's view."""
    radius_m = MARKER_MM / 2 * sheet.scale / 1000.0
    x0, y0, x1, y1 = sheet.view
    shown = []
    for order in orders:
        x, y = result.candidates.positions[result.chosen.stations[order], :2]
        if x0 - radius_m <= x <= x1 + radius_m and y0 - radius_m <= y <= y1 + radius_m:
            shown.append(order)
    return shown


def _draw_markers(ax: Axes, result: PlanResult, sheet: Sheet, storey: _Storey
                  ) -> dict[int, tuple[Artist, ...]]:
    """Each station on the sheet: density range, disc, number, visit number."""
    radius_m = MARKER_MM / 2 * sheet.scale / 1000.0
    gap_m = LABEL_GAP_MM * sheet.scale / 1000.0
    reach = min(density_range_m(result.spec.min_density_pts_m2, result.spec.angular_step_rad),
                result.spec.dof_max_m)
    colour = tuple(c / 255 for c in drawing.STATION_RGB)
    markers: dict[int, tuple[Artist, ...]] = {}
    orders = _on_sheet(result, sheet, storey.orders)
    centres = result.candidates.positions[[result.chosen.stations[o] for o in orders], :2]
    if math.isfinite(reach) and orders:
        ax.add_collection(PatchCollection([Circle((x, y), reach) for x, y in centres],
                                          facecolors="none", edgecolors=[colour],
                                          linestyles=[(0, (4, 3))], linewidths=0.5,
                                          alpha=0.4, zorder=6))
    for order, (x, y) in zip(orders, centres, strict=True):
        # a critical station (placement tolerance) has a red rim instead of a white one,
        # inside the disc, so its marker takes no more paper
        critical = drawing.is_critical(result, order)
        disc = Circle((x, y), radius_m, facecolor=colour, linewidth=1.6 if critical else 0.8,
                      edgecolor=drawing.CRITICAL_RGB if critical else "white", zorder=8)
        ax.add_patch(disc)
        label = str(order + 1)
        artists: list[Artist] = [disc, ax.text(
            x, y, label, ha="center", va="center_baseline", color="white",
            fontsize=7 if len(label) < 3 else 5.5, fontweight="bold", zorder=9)]
        visit = None if result.survey is None else result.survey.visit_of(order + 1)
        if visit is not None:
            artists.append(ax.text(x + radius_m + gap_m, y, f"v{visit}", ha="left",
                                   va="center", fontsize=5.5, color=drawing.VISIT_RGB,
                                   fontweight="bold", zorder=9))
        markers[order] = tuple(artists)
    return markers


def _title(fig: Figure, result: PlanResult, sheet: Sheet, storey: _Storey, number: int,
           total: int) -> None:
    level = sheet.level
    name = level.name or "plan"
    where = f", sheet {sheet.tile} of {len(sheet.tiles)}" if sheet.tile else ""
    top = SHEET_MM[1] - MARGIN_MM
    fig.text(MARGIN_MM / SHEET_MM[0], (top - 4) / SHEET_MM[1],
             f"Scan plan, {name}{where}", fontsize=14, fontweight="bold", va="center")
    fig.text(MARGIN_MM / SHEET_MM[0], (top - 10) / SHEET_MM[1],
             f"section at {level.section_z:.2f} m (instrument height), floor "
             f"{level.floor_z:.2f} m; {len(storey.orders)} of the plan's "
             f"{len(result.chosen.stations)} stations on this storey",
             fontsize=9.5, va="center")
    _page_number(fig, number, total)


def _table_top_mm(sheet: Sheet) -> float:
    """Where the station table starts on the sheet (mm from the bottom): under the key
    plan on a tiled sheet."""
    return SHEET_MM[1] - MARGIN_MM - 114 - (58 if sheet.tile else 0)


def _table_rows(sheet: Sheet) -> int:
    """Station rows the key has room for (one line is kept for "... more")."""
    return int((_table_top_mm(sheet) - 6 - MARGIN_MM) / TABLE_ROW_MM) - 1


def _key(fig: Figure, result: PlanResult, sheet: Sheet, storey: _Storey) -> None:
    """Scale, north arrow, legend, plan figures, key plan and the sheet's stations."""
    left = SHEET_MM[0] - MARGIN_MM - KEY_MM
    top = SHEET_MM[1] - MARGIN_MM

    def at(x_mm: float, y_mm: float) -> tuple[float, float]:
        return x_mm / SHEET_MM[0], y_mm / SHEET_MM[1]

    fig.text(*at(left, top - 4), f"Scale 1:{sheet.scale} on A3", fontsize=12,
             fontweight="bold", va="center")
    fig.text(*at(left, top - 10), f"1 mm on paper = {sheet.scale / 1000:g} m; "
             "north arrow = +Y axis of the model", fontsize=7, color="0.3", va="center")
    drawing.north_arrow(fig, _rect(SHEET_MM[0] - MARGIN_MM - 14, top - 22, 14, 22))
    handles = [*drawing.legend_handles(result),
               Line2D([], [], color=drawing.VISIT_RGB, linewidth=1.3,
                      label="walking route; v3: third on the route"),
               Line2D([], [], color=drawing.EDGE_RGB, linestyle=(0, (1, 2)), linewidth=0.9,
                      label="registration: stations that overlap")]
    fig.legend(handles=handles, loc="upper left", bbox_to_anchor=at(left, top - 24),
               fontsize=7, frameon=False, handlelength=2.2, borderaxespad=0.0,
               labelspacing=0.5)
    fig.text(*at(left, top - 86), "\n".join(drawing.plan_lines(result)), fontsize=7,
             va="top", linespacing=1.45)
    table_top = _table_top_mm(sheet)
    if sheet.tile:
        _key_plan(fig, result, sheet, storey, _rect(left, table_top + 6, KEY_MM, 50))
    orders = _on_sheet(result, sheet, storey.orders)
    shown = orders[:_table_rows(sheet)]
    rows = drawing.station_rows(result, shown, visit=True)
    if len(orders) > len(shown):
        rows.append(f"  ... {len(orders) - len(shown)} more: station list, last pages")
    fig.text(*at(left, table_top), f"Stations on this sheet ({len(orders)}; model "
             "coordinates, m)", fontsize=7.5, fontweight="bold", va="bottom")
    fig.text(*at(left, table_top - 1), "\n".join(rows), fontsize=6.5, family="monospace",
             va="top", linespacing=1.29)


def _key_plan(fig: Figure, result: PlanResult, sheet: Sheet, storey: _Storey,
              rect: tuple[float, float, float, float]) -> None:
    """The whole storey small: its section, stations, every tile outlined, this one shaded."""
    ax = fig.add_axes(rect)
    ax.set_aspect("equal", adjustable="box")
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_title(f"key plan: {len(sheet.tiles)} sheets", fontsize=7, loc="left")
    if len(storey.segments):
        outline = LineCollection([], colors="0.45", linewidths=0.3)
        Collection.set_paths(outline, drawing.one_path(storey.outline))
        ax.add_collection(outline)
    xy = result.candidates.positions[[result.chosen.stations[o] for o in storey.orders], :2]
    ax.scatter(xy[:, 0], xy[:, 1], s=2.0, c=[tuple(c / 255 for c in drawing.STATION_RGB)],
               linewidths=0)
    for name, (x0, y0, x1, y1) in sheet.tiles:
        here = name == sheet.tile
        ax.add_patch(Rectangle((x0, y0), x1 - x0, y1 - y0, fill=here,
                               facecolor=(1.0, 0.85, 0.3, 0.45), edgecolor="black",
                               linewidth=1.0 if here else 0.5))
        ax.text((x0 + x1) / 2, (y0 + y1) / 2, name, ha="center", va="center", fontsize=7,
                fontweight="bold" if here else "normal")
    views = np.array([view for _, view in sheet.tiles])
    ax.set_xlim(views[:, 0].min(), views[:, 2].max())
    ax.set_ylim(views[:, 1].min(), views[:, 3].max())


def _station_list(result: PlanResult, orders: Sequence[int], number: int, total: int
                  ) -> Figure:
    """A page of the station list: ``orders`` in columns of ``LIST_ROWS``."""
    fig = _figure()
    top = SHEET_MM[1] - MARGIN_MM
    fig.text(MARGIN_MM / SHEET_MM[0], (top - 4) / SHEET_MM[1],
             "Scan plan, station list (model coordinates, m)", fontsize=14,
             fontweight="bold", va="center")
    width = (SHEET_MM[0] - 2 * MARGIN_MM) / LIST_COLUMNS
    for k in range(LIST_COLUMNS):
        column = orders[k * LIST_ROWS:(k + 1) * LIST_ROWS]
        if column:
            fig.text((MARGIN_MM + k * width) / SHEET_MM[0], (top - 12) / SHEET_MM[1],
                     "\n".join(drawing.station_rows(result, column, visit=True)),
                     fontsize=6.5, family="monospace", va="top", linespacing=1.29)
    _page_number(fig, number, total)
    return fig


def _page_number(fig: Figure, number: int, total: int) -> None:
    fig.text((SHEET_MM[0] - MARGIN_MM) / SHEET_MM[0], MARGIN_MM / 2 / SHEET_MM[1],
             f"page {number} of {total}", fontsize=7, ha="right", va="center", color="0.3")


def _list_pages(result: PlanResult, all_sheets: Sequence[Sheet]) -> list[list[int]]:
    """The station list's pages (selection orders on each): every station, when a sheet's
    key had no room for all of its stations; none otherwise."""
    storeys = {s.level_index: storey_orders(result, s.level) for s in all_sheets}
    for sheet in all_sheets:
        if len(_on_sheet(result, sheet, storeys[sheet.level_index])) > _table_rows(sheet):
            orders = list(range(len(result.chosen.stations)))
            per_page = LIST_ROWS * LIST_COLUMNS
            return [orders[i:i + per_page] for i in range(0, len(orders), per_page)]
    return []


def iter_set(result: PlanResult) -> Iterator[DrawnSheet | Figure]:
    """The pages of the set in order, drawn one at a time: the map sheets
    (:class:`DrawnSheet`), then the station list's pages when needed (figures)."""
    all_sheets = sheets(result)
    lists = _list_pages(result, all_sheets)
    total = len(all_sheets) + len(lists)
    storey: _Storey | None = None
    for number, sheet in enumerate(all_sheets, start=1):
        if storey is None or storey.level is not sheet.level:
            storey = _Storey(result, sheet.level)
        yield draw_sheet(result, sheet, storey, number, total)
    for k, orders in enumerate(lists):
        yield _station_list(result, orders, len(all_sheets) + k + 1, total)


def plan_pdf(result: PlanResult) -> bytes:
    """``plan.pdf`` bytes: see the module docstring."""
    buffer = io.BytesIO()
    with PdfPages(buffer, metadata=_PDF_METADATA) as pdf:
        for page in iter_set(result):
            figure = page.figure if isinstance(page, DrawnSheet) else page
            pdf.savefig(figure, dpi=RASTER_DPI)
            del page
            drawing.release_figure(figure)  # its raster image, before the next page's
            _deflate_images(getattr(pdf, "_file", None))
    return buffer.getvalue()


class _DeflatedImage:
    """A page's raster image (an (H, W, C) uint8 array) deflated while the PDF file waits
    to write it."""

    def __init__(self, image: NDArray[Any]) -> None:
        self.shape, self.dtype = image.shape, image.dtype
        self.data = zlib.compress(np.ascontiguousarray(image).tobytes(), 1)

    def inflated(self) -> NDArray[Any]:
        """The image as it was given (read-only)."""
        return np.frombuffer(zlib.decompress(self.data), self.dtype).reshape(self.shape)


def _deflate_images(pdf_file: Any) -> None:
    """Deflate the raster images matplotlib's PDF file (``pdf_file``, its ``PdfFile``)
    holds. It writes every page's images only when the file is closed, after the last
    page, and keeps them as arrays until then: a sheet's floor raster at ``RASTER_DPI`` is
    some 11 MB (Lantern Hollow: 622 -> 967 MiB resident by the last sheet), deflated a few
    hundred kB. Each image is inflated back, the same array, when the file writes it,
    where and as it would have written it, so the file's bytes are the same. The images
    are held by ``id()`` of their array, which a later array may reuse once this one is
    let go: each is held under its object number instead, in the same order. A
    matplotlib whose PDF file holds its images otherwise is left as it is."""
    images = getattr(pdf_file, "_images", None)
    unpack = getattr(pdf_file, "_unpack", None)
    if not isinstance(images, dict) or not callable(unpack) or not all(
            isinstance(entry, tuple) and len(entry) == 3 and hasattr(entry[2], "id")
            for entry in images.values()):
        return  # another matplotlib's layout: its images stay as they are
    if not getattr(pdf_file, "_scanplan_inflates", False):
        def inflating_unpack(image: Any) -> Any:
            return unpack(image.inflated() if isinstance(image, _DeflatedImage) else image)

        pdf_file._unpack = inflating_unpack
        pdf_file._scanplan_inflates = True
    entries = list(images.items())
    images.clear()
    for key, (image, name, ob) in entries:
        if isinstance(image, np.ndarray):
            image, key = _DeflatedImage(image), ("deflated", ob.id)
        images[key] = (image, name, ob)
