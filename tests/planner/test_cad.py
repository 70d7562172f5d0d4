"""plan.dxf and plan.pdf: what a surveyor opens in CAD and prints.

plan.dxf passes ezdxf's audit, holds one station block per station on its storey's layer at
its plan.json position (also for a model read with another up axis), and the walls cut at
instrument height; plan.pdf has a page per storey at a standard scale, no two station
markers overlap on a sheet (a storey with a hundred stations), and both are the same bytes
twice. The two-storey case is the shared FZK-Haus, planned as in test_ifc (0.5 m remesh,
1 m grid) without the placement tolerance report.
"""

from __future__ import annotations

import dataclasses
import io
import itertools
import json
import os
import pickle
import subprocess
import sys
from pathlib import Path
from typing import Any

import ezdxf
import numpy as np
import pytest
import trimesh
from ezdxf.document import Drawing
from pypdf import PdfReader

from planner.candidates.grid import CandidateSet, read_candidates_csv
from planner.io.readers import read_scene
from planner.outputs import cad, drawing, printset
from planner.outputs.report import plan_document, write_outputs
from planner.parameters import PlanSpec
from planner.pipeline import PlanResult, plan
from planner.selection.greedy import Selection

A3_PT = (420 / 25.4 * 72, 297 / 25.4 * 72)


def _hall_small(scenes_dir: Path, path: Path | None = None, **spec: Any) -> PlanResult:
    folder = scenes_dir / "hall-small"
    scene = read_scene(path or folder / "hall.obj", max_edge_m=None,
                       up_axis=spec.get("up_axis"))
    candidates = read_candidates_csv(folder / "candidates.csv")
    if "candidates" in spec:
        candidates = np.asarray(spec.pop("candidates"))
    return plan(scene, PlanSpec(candidates=tuple(map(tuple, candidates.tolist())),
                                max_edge_m=None, **spec))


@pytest.fixture(scope="module")
def hall(scenes_dir: Path) -> PlanResult:
    return _hall_small(scenes_dir)


@pytest.fixture(scope="module")
def fzk(scenes_dir: Path) -> PlanResult:
    pytest.importorskip("ifcopenshell")
    scene = read_scene(scenes_dir / "AC20-FZK-Haus.ifc", max_edge_m=0.5,
                       split_faces="as_needed")
    # no placement tolerance report: its stage was 40 % of this plan, and the FZK tests
    # read the storeys' layers and sheets (the hall's plan keeps the report)
    return plan(scene, PlanSpec(max_edge_m=0.5, grid_spacing_m=1.0, placement_tolerance_m=0))


def read_dxf(data: bytes) -> Drawing:
    return ezdxf.read(io.StringIO(data.decode("utf-8")))


def assert_stations_on_their_layers(result: PlanResult, doc: Drawing,
                                    storey_of: dict[int, str]) -> None:
    """One station block per station, on its storey's layer, at its plan.json position."""
    stations = plan_document(result)["stations"]
    inserts = doc.modelspace().query(f'INSERT[name=="{cad.STATION_BLOCK}"]')
    assert len(inserts) == len(stations)
    by_id = {int(insert.get_attrib_text("ID")): insert for insert in inserts}
    assert sorted(by_id) == [s["id"] for s in stations]
    for station in stations:
        insert = by_id[station["id"]]
        assert insert.dxf.layer == f"{storey_of[station['id']]} - stations"
        where = insert.ocs().to_wcs(insert.dxf.insert)
        assert np.allclose(tuple(where), station["position"], atol=1e-3), station["id"]
        visit = station.get("visit")
        assert insert.get_attrib_text("VISIT") == ("" if visit is None else str(visit))
        assert float(insert.get_attrib_text("HEIGHT")) == pytest.approx(1.5, abs=1e-3)


def assert_audit_clean(doc: Drawing) -> None:
    auditor = doc.audit()
    assert not auditor.has_errors, [str(e) for e in auditor.errors]


# --- plan.dxf ---------------------------------------------------------------------------


def test_hall_dxf_audits_clean_and_places_every_station(hall: PlanResult) -> None:
    data = cad.plan_dxf(hall)
    assert cad.plan_dxf(hall) == data  # same input, same bytes
    doc = read_dxf(data)
    assert_audit_clean(doc)
    assert doc.units == ezdxf.units.M
    assert_stations_on_their_layers(hall, doc, dict.fromkeys(range(1, 100), "plan"))
    assert {layer.dxf.name for layer in doc.layers} >= {
        "plan - walls", "plan - stations", "plan - route", "plan - registration",
        "plan - labels"}


def test_same_bytes_in_another_process(hall: PlanResult, tmp_path: Path) -> None:
    """Not only twice in one process: ezdxf and matplotlib must not let string hashing
    (PYTHONHASHSEED) order anything they write."""
    saved = tmp_path / "plan.pickle"
    saved.write_bytes(pickle.dumps(hall))
    script = ("import pickle, sys; from planner.outputs import cad, printset; "
              "r = pickle.loads(open(sys.argv[1], 'rb').read()); "
              "open(sys.argv[2], 'wb').write(cad.plan_dxf(r) + b'|' + printset.plan_pdf(r))")
    outputs = []
    for seed in ("1", "4"):  # without a fixed order, ezdxf 1.4.5 orders CLASSES apart
        out = tmp_path / f"out-{seed}"
        subprocess.run([sys.executable, "-c", script, str(saved), str(out)], check=True,
                       env={**os.environ, "PYTHONHASHSEED": seed}, timeout=300)
        outputs.append(out.read_bytes())
    assert outputs[0] == outputs[1] == cad.plan_dxf(hall) + b"|" + printset.plan_pdf(hall)


def test_hall_dxf_walls_are_the_cut_at_instrument_height(hall: PlanResult) -> None:
    doc = read_dxf(cad.plan_dxf(hall))
    walls = doc.modelspace().query('LWPOLYLINE[layer=="plan - walls"]')
    points = np.array([p[:2] for line in walls for p in line.get_points("xy")])
    assert {line.dxf.elevation for line in walls} == {1.5}
    # the hall's outer walls are cut: the drawing spans the model's plan extent
    mesh = trimesh.Trimesh(hall.scene.vertices, hall.scene.faces, process=False)
    assert np.allclose(points.min(axis=0), mesh.bounds[0, :2], atol=0.01)
    assert np.allclose(points.max(axis=0), mesh.bounds[1, :2], atol=0.01)
    # every cut segment lies on the drawing's polylines: as many metres of wall as the cut
    segments, _ = drawing.section_at(hall.scene.vertices, hall.scene.faces, 1.5)
    cut_m = np.linalg.norm(segments[:, 1] - segments[:, 0], axis=1).sum()
    drawn_m = sum(np.linalg.norm(np.diff(np.array(
        [p[:2] for p in line.get_points("xy")] + ([line.get_points("xy")[0][:2]]
                                                   if line.closed else [])), axis=0),
        axis=1).sum() for line in walls)
    assert drawn_m == pytest.approx(cut_m, rel=1e-6)


def test_route_and_registration_follow_the_survey(hall: PlanResult) -> None:
    assert hall.survey is not None
    doc = read_dxf(cad.plan_dxf(hall))
    msp = doc.modelspace()
    edges = msp.query('LINE[layer=="plan - registration"]')
    assert len(edges) == len(hall.survey.registration.edges)
    legs = msp.query('POLYLINE[layer=="plan - route"]')
    drawn = sum(np.linalg.norm(np.diff(np.array([tuple(v) for v in leg.points()]), axis=0),
                               axis=1).sum() for leg in legs)
    assert drawn == pytest.approx(hall.survey.route.length_m, abs=0.01)


def test_y_up_model_gets_its_stations_in_its_own_coordinates(scenes_dir: Path,
                                                              tmp_path: Path) -> None:
    """The hall turned Y-up (as a glTF exporter writes it) and read with up_axis "+Y": the
    drawing is in the turned file's coordinates, its plan square to the model's up."""
    source = trimesh.load(scenes_dir / "hall-small" / "hall.obj", force="mesh", process=False)
    turn = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # model = T @ plan
    turned = tmp_path / "hall-y-up.obj"
    trimesh.Trimesh(source.vertices @ turn.T, source.faces, process=False).export(turned)
    candidates = read_candidates_csv(scenes_dir / "hall-small" / "candidates.csv") @ turn.T
    result = _hall_small(scenes_dir, turned, up_axis="+Y", candidates=candidates)
    doc = read_dxf(cad.plan_dxf(result))
    assert_audit_clean(doc)
    assert_stations_on_their_layers(result, doc, dict.fromkeys(range(1, 100), "plan"))
    for insert in doc.modelspace().query("INSERT"):
        assert np.allclose(tuple(insert.dxf.extrusion), (0.0, 1.0, 0.0))


def test_fzk_dxf_has_a_layer_set_per_storey(fzk: PlanResult) -> None:
    doc = read_dxf(cad.plan_dxf(fzk))
    assert_audit_clean(doc)
    stations = plan_document(fzk)["stations"]
    storey_of = {s["id"]: s["label"]["storey"] for s in stations}
    assert set(storey_of.values()) == {"Erdgeschoss", "Dachgeschoss"}
    assert_stations_on_their_layers(fzk, doc, storey_of)
    layers = {layer.dxf.name for layer in doc.layers}
    for storey, kind in itertools.product(("Erdgeschoss", "Dachgeschoss"),
                                          cad.LAYER_COLOURS):
        assert f"{storey} - {kind}" in layers
    # each storey's walls are cut at its own instrument height
    for storey in ("Erdgeschoss", "Dachgeschoss"):
        heights = {line.dxf.elevation for line in doc.modelspace().query(
            f'LWPOLYLINE[layer=="{storey} - walls"]')}
        z = {round(s["position"][2], 6) for s in stations if storey_of[s["id"]] == storey}
        assert len(heights) == 1 and heights.pop() == pytest.approx(float(np.median(list(z))))


# --- plan.pdf ---------------------------------------------------------------------------


def test_hall_pdf_is_one_a3_sheet_at_a_standard_scale(hall: PlanResult) -> None:
    data = printset.plan_pdf(hall)
    assert printset.plan_pdf(hall) == data  # same input, same bytes
    reader = PdfReader(io.BytesIO(data))
    assert len(reader.pages) == 1
    box = reader.pages[0].mediabox
    assert (float(box.width), float(box.height)) == pytest.approx(A3_PT, abs=0.5)
    (sheet,) = printset.sheets(hall)
    assert sheet.scale in printset.STANDARD_SCALES and sheet.tile == ""
    assert reader.metadata is not None and "/CreationDate" not in reader.metadata


def test_fzk_pdf_has_a_page_per_storey(fzk: PlanResult) -> None:
    reader = PdfReader(io.BytesIO(printset.plan_pdf(fzk)))
    sheets = printset.sheets(fzk)
    assert [s.level.name for s in sheets] == ["Erdgeschoss", "Dachgeschoss"]
    assert len(reader.pages) == len(sheets)



def test_pdf_rasters_deflated_until_written_give_the_same_bytes(
        fzk: PlanResult, monkeypatch: pytest.MonkeyPatch) -> None:
    """The sheets' raster images, deflated while matplotlib's PDF file waits to write them
    (and held under their object numbers, not their arrays' ids), make the same file as
    the arrays kept as they are."""
    deflated = printset.plan_pdf(fzk)
    monkeypatch.setattr(printset, "_deflate_images", lambda pdf_file: None)
    assert printset.plan_pdf(fzk) == deflated


def test_storey_scale_keeps_markers_apart_and_prefers_one_sheet() -> None:
    house = (0.0, 0.0, 12.0, 10.0)
    hall = (0.0, 0.0, 50.0, 40.0)
    assert printset.storey_scale(house, spacing_m=3.0) == 50
    assert printset.storey_scale(hall, spacing_m=3.0) == 200  # fits one A3 at 1:200
    assert printset.storey_scale(hall, spacing_m=1.5) == 100  # 1:200 would crowd: tiles
    assert printset.storey_scale(hall, spacing_m=0.6) == 50
    assert printset.storey_scale(house, spacing_m=0.3) == 25  # closer than 0.5 m


def test_stations_one_over_the_other_do_not_set_the_scale() -> None:
    """A drawn storey may hold two floors (a plain mesh's basement under its ground
    floor) or a spot planned at two instrument heights: such stations share a marker at
    any scale. Counted, Lantern Hollow's plain mesh printed 345 sheets at 1:10."""
    hall = (0.0, 0.0, 50.0, 40.0)
    ground = np.array([[x, y, 1.5] for x in (0.0, 6.0, 12.0) for y in (0.0, 5.0)])
    basement = ground - [0.0, 0.0, 2.6]  # every station of the ground floor, right below
    heights = np.array([[6.0, 0.0, 1.8]])  # a second instrument height at one spot
    stations = np.vstack([ground, basement, heights])
    assert printset.min_spacing_m(stations) >= printset.STACKED_SEARCH_M  # 5 m in fact
    assert printset.storey_scale(hall, printset.min_spacing_m(stations)) == 200
    # two stations on one floor half a metre apart still set it
    close = np.vstack([stations, [[0.5, 0.0, 1.5]]])
    assert printset.min_spacing_m(close) == pytest.approx(0.5)
    assert printset.storey_scale(hall, printset.min_spacing_m(close)) == 50


def hundred_stations(result: PlanResult) -> PlanResult:
    """The hall's plan with 100 stations spread over a 30 x 22 m storey, no two closer
    than 0.6 m (a jittered grid with a tight corner): tiled sheets at 1:50."""
    rng = np.random.default_rng(7)
    xs, ys = np.meshgrid(np.arange(10) * 3.0, np.arange(10) * 2.2)
    xy = np.column_stack([xs.ravel(), ys.ravel()]) + rng.uniform(-0.5, 0.5, (100, 2))
    xy[1:4] = xy[0] + np.array([[0.6, 0.0], [0.0, 0.6], [0.6, 0.6]])  # four close together
    positions = np.column_stack([xy, np.full(100, 1.5)])
    order = tuple(range(100))
    area = tuple(1.0 for _ in order)
    chosen = Selection(method="greedy", stations=order, new_area_m2=area,
                       covered_area_m2=tuple(float(k + 1) for k in order),
                       max_achievable_area_m2=100.0)
    return dataclasses.replace(result, chosen=chosen, survey=None, tolerance=None,
                               candidates=CandidateSet(
        positions=positions, source="explicit", considered=100))


def paper_boxes_mm(page: printset.DrawnSheet) -> dict[int, tuple[float, float, float, float]]:
    """Station -> its marker's extent on paper (disc, number and visit), mm."""
    renderer = page.figure.canvas.get_renderer()  # type: ignore[attr-defined]
    mm_per_px = 25.4 / page.figure.dpi
    boxes = {}
    for order, artists in page.markers.items():
        extents = [artist.get_window_extent(renderer) for artist in artists]
        boxes[order] = (min(e.x0 for e in extents) * mm_per_px,
                        min(e.y0 for e in extents) * mm_per_px,
                        max(e.x1 for e in extents) * mm_per_px,
                        max(e.y1 for e in extents) * mm_per_px)
    return boxes


def test_a_hundred_stations_never_overlap_on_a_sheet(hall: PlanResult) -> None:
    crowded = hundred_stations(hall)
    pages = list(printset.iter_set(crowded))
    sheets = [p for p in pages if isinstance(p, printset.DrawnSheet)]
    assert len(sheets) > 1 and all(s.sheet.tile for s in sheets)  # tiled, with key plans
    assert {s.sheet.scale for s in sheets} == {50}
    seen: set[int] = set()
    for page in sheets:
        boxes = paper_boxes_mm(page)
        seen |= set(boxes)
        for (a, box_a), (b, box_b) in itertools.combinations(boxes.items(), 2):
            apart = (box_a[2] <= box_b[0] or box_b[2] <= box_a[0]
                     or box_a[3] <= box_b[1] or box_b[3] <= box_a[1])
            assert apart, (page.sheet.tile, a + 1, b + 1)
        # the disc is MARKER_MM across on paper: the sheet is at its scale
        disc = page.markers[min(page.markers)][0].get_window_extent(
            page.figure.canvas.get_renderer())  # type: ignore[attr-defined]
        assert disc.width * 25.4 / page.figure.dpi == pytest.approx(printset.MARKER_MM,
                                                                     rel=0.02)
    assert seen == set(range(100))
    reader = PdfReader(io.BytesIO(printset.plan_pdf(crowded)))
    assert len(reader.pages) == len(pages)


def test_a_full_sheet_continues_on_the_station_list(hall: PlanResult) -> None:
    """100 stations a metre apart fit one sheet at 1:50, but not its key's table: the set
    ends with the station list, which lists them all."""
    grid = hundred_stations(hall)
    xs, ys = np.meshgrid(np.arange(10.0), np.arange(10.0))
    positions = np.column_stack([xs.ravel(), ys.ravel(), np.full(100, 1.5)])
    grid = dataclasses.replace(grid, candidates=CandidateSet(
        positions=positions, source="explicit", considered=100))
    pages = list(printset.iter_set(grid))
    assert len(pages) == 2 and isinstance(pages[0], printset.DrawnSheet)
    assert pages[0].sheet.tile == "" and len(pages[0].markers) == 100
    text = PdfReader(io.BytesIO(printset.plan_pdf(grid))).pages[1].extract_text()
    assert "station list" in text
    rows = [line.split() for line in text.splitlines()]
    assert [int(r[0]) for r in rows if r and r[0].isdigit()] == list(range(1, 101))


# --- the outputs folder ------------------------------------------------------------------


def test_written_with_the_other_outputs(hall: PlanResult, tmp_path: Path) -> None:
    written = write_outputs(hall, tmp_path)
    names = [p.name for p in written]
    assert {"plan.dxf", "plan.pdf"} <= set(names)
    assert (tmp_path / "plan.dxf").read_bytes() == cad.plan_dxf(hall)
    assert (tmp_path / "plan.pdf").read_bytes() == printset.plan_pdf(hall)
    assert json.loads((tmp_path / "plan.json").read_text())["totals"]["stations"] == len(
        hall.chosen.stations)
