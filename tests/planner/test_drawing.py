"""preview.png and curve.png: decodable, the right size, stations where the plan puts them,
floor colours of faces.npz, same bytes twice."""

from __future__ import annotations

import dataclasses
import io
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from scipy import ndimage

from planner.candidates.grid import CandidateSet, read_candidates_csv
from planner.io.readers import read_scene
from planner.outputs import drawing
from planner.outputs.report import OUTPUTS, PICTURE_GROUPS, faces_npz, write_outputs
from planner.parameters import PlanSpec
from planner.pipeline import PlanResult, plan


def plan_hall_small(scenes_dir: Path) -> PlanResult:
    folder = scenes_dir / "hall-small"
    scene = read_scene(folder / "hall.obj", max_edge_m=None)
    candidates = read_candidates_csv(folder / "candidates.csv")
    return plan(scene, PlanSpec(candidates=tuple(map(tuple, candidates.tolist())),
                                max_edge_m=None))


@pytest.fixture(scope="module")
def result(scenes_dir: Path) -> PlanResult:
    return plan_hall_small(scenes_dir)


def decode(data: bytes) -> np.ndarray:
    image = Image.open(io.BytesIO(data))
    assert image.format == "PNG"
    return np.asarray(image.convert("RGB"))


def pixel_of(ax, xy: np.ndarray, size: tuple[int, int]) -> np.ndarray:  # type: ignore[no-untyped-def]
    """Model (x, y) -> image (column, row), from the panel's box and limits alone."""
    width, height = size
    box = ax.get_position()
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    fx = box.x0 + (xy[:, 0] - x0) / (x1 - x0) * box.width
    fy = box.y0 + (xy[:, 1] - y0) / (y1 - y0) * box.height
    return np.stack([fx * width, (1 - fy) * height], axis=1)


def test_face_classes_by_hand() -> None:
    faces = {"covered": np.array([True, False, False, False]),
             "n_candidates": np.array([3, 2, 0, 0])}
    target = np.array([True, True, True, False])
    assert drawing.face_classes(faces, target).tolist() == [
        drawing.COVERED, drawing.MISSED, drawing.UNREACHABLE, drawing.NOT_TARGET]


def test_covered_shading_runs_from_requirement_to_saturation() -> None:
    faces = {"covered": np.array([True, True, True]), "n_candidates": np.array([1, 1, 1]),
             "best_lpd_pts_m2": np.array([100.0, 800.0, 5000.0])}
    rgb = drawing.face_rgb(faces, np.ones(3, bool), np.full(3, 100.0))
    assert tuple(rgb[0]) == drawing.COVERED_LOW_RGB
    assert tuple(rgb[1]) == drawing.COVERED_HIGH_RGB
    assert tuple(rgb[2]) == drawing.COVERED_HIGH_RGB


def test_preview_size_and_determinism(result: PlanResult) -> None:
    data = drawing.preview_png(result)
    image = decode(data)
    assert image.shape == (1240, 1753, 3)  # A4 landscape at 150 dpi
    assert drawing.preview_png(result) == data


def test_curve_size_and_determinism(result: PlanResult) -> None:
    data = drawing.curve_png(result)
    assert decode(data).shape == (750, 1200, 3)
    assert drawing.curve_png(result) == data


def test_stations_land_where_the_plan_puts_them(result: PlanResult) -> None:
    preview = drawing.draw_preview(result)
    image = decode(drawing.preview_png(result))
    size = (image.shape[1], image.shape[0])
    (ax,) = preview.axes
    expected = pixel_of(ax, result.candidates.positions[list(result.chosen.stations), :2], size)
    # the station discs are the only pixels of exactly the station colour inside the map
    mask = np.all(image == np.array(drawing.STATION_RGB, np.uint8), axis=2)
    box = ax.get_position()
    inside = np.zeros_like(mask)
    rows = slice(int((1 - box.y1) * size[1]) + 2, int((1 - box.y0) * size[1]) - 2)
    cols = slice(int(box.x0 * size[0]) + 2, int(box.x1 * size[0]) - 2)
    inside[rows, cols] = True
    labels, n = ndimage.label(mask & inside)
    sizes = ndimage.sum(mask, labels, range(1, n + 1))
    blobs = [i + 1 for i, s in enumerate(sizes) if s > 40]
    centres = np.array(ndimage.center_of_mass(mask, labels, blobs))[:, ::-1]  # (col, row)
    assert len(centres) == len(result.chosen.stations)
    for point in expected:
        assert np.min(np.linalg.norm(centres - point, axis=1)) < 3.0


def test_printed_scale_is_what_the_sheet_says(result: PlanResult) -> None:
    preview = drawing.draw_preview(result)
    (ax,) = preview.axes
    size = (1753, 1240)
    one_metre = pixel_of(ax, np.array([[0.0, 0.0], [1.0, 0.0]]), size)
    mm_on_paper = (one_metre[1, 0] - one_metre[0, 0]) / drawing.DPI * 25.4
    assert mm_on_paper == pytest.approx(1000 / preview.scale, rel=0.01)


def test_floor_colours_match_faces_npz(result: PlanResult) -> None:
    arrays = np.load(io.BytesIO(faces_npz(result)))
    rgb = drawing.face_rgb(arrays, result.limits.target, result.limits.min_density_pts_m2)
    preview = drawing.draw_preview(result)
    image = decode(drawing.preview_png(result))
    (ax,) = preview.axes
    scene = result.scene
    floor = np.flatnonzero((scene.normals[:, 2] > 0.9) & (scene.centroids[:, 2] < 0.01))
    pixels = np.rint(pixel_of(ax, scene.centroids[floor, :2], (1753, 1240))).astype(int)
    seen = image[pixels[:, 1], pixels[:, 0]]
    matches = np.all(seen == rgb[floor], axis=1)
    # dots, circles, stations and cut lines hide a few; almost all show their own colour
    assert matches.mean() > 0.85
    # floor under machines is hidden by their tops; the open floor is covered or missed
    classes = drawing.face_classes(arrays, result.limits.target)[floor]
    for k in (drawing.COVERED, drawing.MISSED):
        assert matches[classes == k].mean() > 0.85, drawing.CLASS_NAMES[k]


@pytest.mark.parametrize("run", ["short", "all but one"])
def test_floor_drawn_in_runs_gives_the_same_picture(result: PlanResult, run: str,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    """The floor is made into paths and drawn a run of triangles at a time: the picture of
    all at once, also when the last run would be one triangle, but for pixels on the edges
    between two paths (each covers part of such a pixel, and which one fills it depends on
    the paths)."""
    whole = decode(drawing.preview_png(result))
    (level,) = drawing.levels(result)
    n = len(drawing.floor_faces(result, level))
    monkeypatch.setattr(drawing, "_DRAW_FACES", 7 if run == "short" else n - 1)
    parts = decode(drawing.preview_png(result))
    differ = np.any(parts != whole, axis=2)
    # hall-small: 0.9 % of the pixels with runs of 7 triangles, from one floor colour to another
    assert differ.mean() < 0.02
def test_one_panel_per_level(result: PlanResult) -> None:
    upper = result.candidates.positions + np.array([0.0, 0.0, 3.0])
    both = CandidateSet(positions=np.concatenate([result.candidates.positions, upper]),
                        source="explicit", considered=2 * len(upper))
    two = dataclasses.replace(result, candidates=both)
    levels = drawing.levels(two)
    assert [len(lv.candidates) for lv in levels] == [len(upper), len(upper)]
    assert levels[1].section_z == pytest.approx(4.5)
    assert len(drawing.draw_preview(two).axes) == 2


def test_levels_extents_in_one_pass_are_each_levels_own(result: PlanResult) -> None:
    """The preview and the print set find every level's extent in one pass over the faces
    and keep it with the plan: the extents are those each level gives alone, and each holds
    its level's candidates."""
    upper = result.candidates.positions + np.array([0.0, 0.0, 3.0])
    both = CandidateSet(positions=np.concatenate([result.candidates.positions, upper]),
                        source="explicit", considered=2 * len(upper))
    two = dataclasses.replace(result, candidates=both)
    levels = drawing.levels(two)
    together = drawing.level_extents(two, levels)
    alone = [drawing.level_extents(dataclasses.replace(two), [level])[0] for level in levels]
    assert together == alone
    assert drawing.level_extents(two, levels[::-1]) == together[::-1]  # kept, in any order
    for level, (x0, y0, x1, y1) in zip(levels, together, strict=True):
        xy = two.candidates.positions[level.candidates, :2]
        assert (xy >= (x0, y0)).all() and (xy <= (x1, y1)).all()
    # the extent, worked out with numpy from every corner of the level's faces (centroid
    # from 0.2 m under its floor to its top), cut to the candidates' reach, with the margin
    scene, reach = two.scene, two.limits.reach_m
    centroid_z = scene.vertices[scene.faces].mean(axis=1)[:, 2]
    for level, extent in zip(levels, together, strict=True):
        inside = (centroid_z >= level.floor_z - 0.2) & (centroid_z <= level.top_z)
        xy = two.candidates.positions[level.candidates, :2]
        points = np.concatenate([xy, scene.vertices[scene.faces[inside].ravel(), :2]])
        least = np.maximum(points.min(axis=0), xy.min(axis=0) - reach)
        most = np.minimum(points.max(axis=0), xy.max(axis=0) + reach)
        margin = 0.04 * float(max(most - least)) + 0.3
        assert extent == (float(least[0]) - margin, float(least[1]) - margin,
                          float(most[0]) + margin, float(most[1]) + margin)


def test_registered_outputs(result: PlanResult, tmp_path: Path) -> None:
    assert {"preview.png", "curve.png", "coverage.glb"} <= set(OUTPUTS)
    written = write_outputs(result, tmp_path, names=("preview.png", "curve.png"))
    assert sorted(p.name for p in written) == ["curve.png", "preview.png"]
    assert (tmp_path / "preview.png").read_bytes() == drawing.preview_png(result)


def test_data_files_land_before_pictures(result: PlanResult, tmp_path: Path) -> None:
    """A BIM platform watching the folder gets plan.json and the other data files first;
    the pictures, rendered in threads meanwhile, are the same bytes as rendered alone."""
    written = write_outputs(result, tmp_path)
    names = [p.name for p in written]
    assert names == [name for name in OUTPUTS if (tmp_path / name).exists()]  # OUTPUTS order
    assert names[0] == "plan.json"
    pictures = {name for group in PICTURE_GROUPS for name in group}
    assert {"preview.png", "curve.png", "coverage.glb", "plan.dxf", "plan.pdf"} == pictures
    assert pictures <= set(names)
    modified = {p.name: p.stat().st_mtime_ns for p in written}
    assert max(t for n, t in modified.items() if n not in pictures) <= min(
        modified[n] for n in pictures)
    for path in written:
        assert path.read_bytes() == OUTPUTS[path.name](result), path.name
