"""Results in BIM terms: coverage per IFC element, per storey and per room.

Outputs (registered in :data:`planner.outputs.report.OUTPUTS`, written only for scenes with
elements, i.e. IFC models):

- ``elements.csv``: one row per element, in the scene's order (IFC class, GlobalId);
- ``elements.json``: the same rows, a summary per storey, the stations per room, and the
  elements that cannot be covered from any candidate with the reason.

Per element: ``area_m2`` (all its faces), ``target`` (some of its faces need coverage),
``target_area_m2``, ``coverable_area_m2`` (target faces that qualify from at least one
candidate), ``covered_area_m2`` (target faces the plan covers) and ``fraction``
(covered over target area; null for an element that is no target, such as glazing or the
site).

Why an element cannot be covered
--------------------------------
For an element with target area but no coverable face, every target face is tested again
against every candidate with the analytic limits of :mod:`planner.visibility.pairs`. Each pair fails
some of four checks:

- ``too_close``: nearer than ``dof_min_m``;
- ``too_far``: beyond ``dof_max_m``, or too far for the density even head-on;
- ``outside_field_of_view``: the ray's elevation is outside the scanner's vertical field;
- ``too_grazing``: the incidence angle is below the minimum, or it is the slant (not the
  distance) that puts the density below the minimum.

A face that passes them all from some candidate is ``occluded`` (the pipeline cast that
ray and something was in the way). Otherwise its reason is the check most often failed by
its nearest misses, the candidates that fail the fewest checks (ties in the order of
``REASONS``). The element's reason is the one that covers the most of its target area;
``reasons`` gives the area per reason.
"""

from __future__ import annotations

import csv
import io
import weakref
from typing import TYPE_CHECKING, Any

import numba
import numpy as np
from numpy.typing import NDArray

from planner.outputs.canonical import canonical_json
from planner.scene import face_centroid
from planner.threads import in_block_order

if TYPE_CHECKING:
    from planner.pipeline import PlanResult

REASONS = ("occluded", "too_close", "too_far", "outside_field_of_view", "too_grazing")
FORMAT_VERSION = 1
COLUMNS = ("global_id", "ifc_class", "name", "storey", "faces", "area_m2", "target",
           "target_area_m2", "coverable_area_m2", "covered_area_m2", "fraction",
           "uncoverable_reason")
_PAIRS_PER_CHUNK = 2_000_000
_DECIMALS = 6
# elements.csv and elements.json share the rows; the reasons cost seconds on a big model.
# Weak keys: a result's rows live as long as the result and no longer.
_ROWS: weakref.WeakKeyDictionary[PlanResult, list[dict[str, Any]]] = (
    weakref.WeakKeyDictionary())


def _r(value: float) -> float:
    rounded = round(float(value), _DECIMALS)
    return 0.0 if rounded == 0 else rounded


def element_rows(result: PlanResult) -> list[dict[str, Any]]:
    """One plain-data row per element of ``result.scene`` (see the module docstring)."""
    cached = _ROWS.get(result)
    if cached is not None:
        return [dict(row) for row in cached]
    rows = _element_rows(result)
    _ROWS[result] = rows
    return [dict(row) for row in rows]


def _element_rows(result: PlanResult) -> list[dict[str, Any]]:
    scene, limits = result.scene, result.limits
    faces = np.zeros(len(scene.elements), np.int64)
    total, target_area, coverable, covered = np.zeros((4, len(scene.elements)))
    _element_sums(scene.face_element, scene.areas, limits.target, result.table.achievable,
                  np.asarray(result.faces["covered"], bool), faces, total, target_area,
                  coverable, covered)
    reasons = uncoverable_reasons(result, np.flatnonzero((target_area > 0) & (coverable == 0)))
    rows = []
    for e, element in enumerate(scene.elements):
        has_target = bool(target_area[e] > 0)
        row: dict[str, Any] = {
            "global_id": element.global_id,
            "ifc_class": element.ifc_class,
            "name": element.name,
            "storey": element.storey,
            "faces": int(faces[e]),
            "area_m2": _r(total[e]),
            "target": has_target,
            "target_area_m2": _r(target_area[e]),
            "coverable_area_m2": _r(coverable[e]),
            "covered_area_m2": _r(covered[e]),
            "fraction": _r(covered[e] / target_area[e]) if has_target else None,
            "uncoverable_reason": None,
        }
        if e in reasons:
            by_reason = reasons[e]
            row["uncoverable_reason"] = max(
                by_reason, key=lambda r: (by_reason[r], -REASONS.index(r)))
            row["reasons"] = {r: _r(a) for r, a in sorted(by_reason.items())}
        rows.append(row)
    return rows


@numba.njit(nogil=True, cache=True)
def _element_sums(owner: NDArray[np.int32], areas: NDArray[np.float64],
                  target: NDArray[np.bool_], achievable: NDArray[np.bool_],
                  covered: NDArray[np.bool_], faces: NDArray[np.int64],
                  total: NDArray[np.float64], target_area: NDArray[np.float64],
                  coverable: NDArray[np.float64], covered_area: NDArray[np.float64]) -> None:
    """Per element (E,) of the F faces' ``owner`` (-1: none), add up in place: its faces,
    their areas, those of its target faces, of the target faces ``achievable`` and of the
    target faces ``covered``.

    One pass in face order, so each sum is the one ``np.bincount`` with weights gives (the
    same additions in the same order), without its (F,) temporaries: 200 MB on a 10 M-face
    model.
    """
    for f in range(owner.shape[0]):
        e = owner[f]
        if e < 0:
            continue
        area = areas[f]
        faces[e] += 1
        total[e] += area
        if target[f]:
            target_area[e] += area
            if achievable[f]:
                coverable[e] += area
            if covered[f]:
                covered_area[e] += area


def uncoverable_reasons(result: PlanResult, elements: NDArray[np.int64]
                        ) -> dict[int, dict[str, float]]:
    """Area per reason of the target faces of ``elements``, for elements with no coverable face.

    Returns ``{element index: {reason: area_m2}}`` (reasons with zero area left out).
    """
    scene, limits = result.scene, result.limits
    if len(elements) == 0:
        return {}
    face_element = scene.face_element  # (F,), made once
    faces = np.flatnonzero(np.isin(face_element, elements) & limits.target)
    codes = face_reasons(result, faces)
    out: dict[int, dict[str, float]] = {}
    area = np.zeros((len(scene.elements), len(REASONS)))
    np.add.at(area, (face_element[faces], codes), scene.areas[faces])
    for e in elements.tolist():
        out[int(e)] = {REASONS[k]: float(a) for k, a in enumerate(area[e]) if a > 0}
    return out


def face_reasons(result: PlanResult, faces: NDArray[np.int64]) -> NDArray[np.int64]:
    """(n,) index into ``REASONS`` for each face of ``faces`` (see the module docstring).

    Every (candidate, face) pair is tested, so the cost is candidates x faces: a compiled
    loop over blocks of faces on a thread pool (the loop releases the GIL), stopping at a
    face's first candidate that passes every check (it is then ``occluded``). The numpy
    formulation it replaces made some thirty (C, n) temporaries a block: on a 10 M-face
    IFC office with 5,900 candidates it was most of the time spent on the outputs.
    """
    lim = result.limits
    positions = np.ascontiguousarray(result.candidates.positions, np.float64)
    codes = np.zeros(len(faces), np.int64)
    if len(faces) == 0 or len(positions) == 0:
        return codes
    faces = np.ascontiguousarray(faces, np.int64)
    step = max(1, min(4096, _PAIRS_PER_CHUNK // len(positions)))

    def block(start: int) -> int:
        chunk = slice(start, start + step)
        _reason_codes(faces[chunk], result.scene.vertices, result.scene.faces,
                      result.scene.file_normals,
                      result.scene.source_face, positions,
                      lim.min_incidence_deg, lim.min_density_pts_m2, lim.dof_min_m,
                      lim.dof_max_m, lim.elevation_min_deg, lim.elevation_max_deg,
                      lim.angular_step_rad, codes[chunk])
        return start

    for _ in in_block_order(block, range(0, len(faces), step)):
        pass
    return codes


@numba.njit(nogil=True, cache=True)
def _reason_codes(  # compiled; compared with the numpy formulation in tests/planner/test_ifc.py
    faces: NDArray[np.int64], vertices: NDArray[np.float64], corners: NDArray[np.int32],
    normals: NDArray[np.float64],
    source: NDArray[np.int32], positions: NDArray[np.float64],
    min_incidence_deg: NDArray[np.float64], min_density: NDArray[np.float64],
    dof_min_m: float, dof_max_m: float,
    elevation_min_deg: float, elevation_max_deg: float, angular_step_rad: float,
    out: NDArray[np.int64],
) -> None:
    """Write the reason code of each of the n ``faces`` (of ``vertices``, ``corners``)
    into (n,) ``out``.

    Per (candidate, face) pair, the four checks of ``REASONS[1:]`` with the same float64
    formulas as the analytic limits (distance, elevation and incidence in degrees, head-on
    density); the face's code is 0 (occluded) when some candidate fails none, otherwise
    1 + the check most often failed by the candidates that fail the fewest (first maximum).
    """
    n_candidates = positions.shape[0]
    tally = np.zeros(4, np.int64)
    # the sines of the limits, with a margin far above float64 rounding: a sine clearly on
    # one side decides its check without the arcsin (the costly part of a pair); one near
    # a limit is decided by the degrees, as the analytic limits state them
    margin = 1e-9
    sin_elevation_min = np.sin(np.radians(elevation_min_deg))
    sin_elevation_max = np.sin(np.radians(elevation_max_deg))
    for i in range(faces.shape[0]):
        f = faces[i]
        cx, cy, cz = face_centroid(vertices, corners, f)
        g = source[f]  # the normal is the file face's
        nx, ny, nz = normals[g, 0], normals[g, 1], normals[g, 2]
        density = min_density[f]
        incidence_min = min_incidence_deg[f]
        sin_incidence_min = np.sin(np.radians(incidence_min))
        fewest = 5
        tally[:] = 0
        for c in range(n_candidates):
            ox = cx - positions[c, 0]
            oy = cy - positions[c, 1]
            oz = cz - positions[c, 2]
            distance = np.sqrt(ox * ox + oy * oy + oz * oz)
            safe = max(distance, 1e-12)
            sin_elevation = min(max(oz / safe, -1.0), 1.0)
            if sin_elevation_min + margin < sin_elevation < sin_elevation_max - margin:
                outside = False
            elif sin_elevation < sin_elevation_min - margin or (
                    sin_elevation > sin_elevation_max + margin):
                outside = True
            else:
                elevation = np.degrees(np.arcsin(sin_elevation))
                outside = elevation < elevation_min_deg or elevation > elevation_max_deg
            sin_incidence = abs(ox * nx + oy * ny + oz * nz) / safe
            if sin_incidence > sin_incidence_min + margin:
                below_incidence = False
            elif sin_incidence < sin_incidence_min - margin:
                below_incidence = True
            else:
                incidence = np.degrees(np.arcsin(min(max(sin_incidence, 0.0), 1.0)))
                below_incidence = incidence < incidence_min
            spacing = max(angular_step_rad * distance, 1e-12)
            head_on = 1.0 / (spacing * spacing)
            lpd = sin_incidence * head_on
            too_close = distance < dof_min_m
            too_far = distance > dof_max_m or head_on < density
            grazing = below_incidence or (lpd < density and head_on >= density)
            count = int(too_close) + int(too_far) + int(outside) + int(grazing)
            if count < fewest:
                fewest = count
                tally[:] = 0
                if count == 0:
                    break
            if count == fewest:
                tally[0] += too_close
                tally[1] += too_far
                tally[2] += outside
                tally[3] += grazing
        out[i] = 0 if fewest == 0 else 1 + int(np.argmax(tally))


def storey_rows(result: PlanResult, rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Totals per storey (model order), with the stations that stand on it."""
    storeys = [str(s["name"]) for s in result.scene.metadata.get("storeys", [])]
    names = list(dict.fromkeys(storeys + [str(r["storey"]) for r in rows]))
    labels = result.candidates.labels
    out = []
    for name in names:
        mine = [r for r in rows if r["storey"] == name]
        stations = [i + 1 for i, c in enumerate(result.chosen.stations)
                    if labels and labels[c].get("storey") == name]
        target = sum(r["target_area_m2"] for r in mine)
        covered = sum(r["covered_area_m2"] for r in mine)
        out.append({
            "storey": name,
            "elements": len(mine),
            "target_area_m2": _r(target),
            "coverable_area_m2": _r(sum(r["coverable_area_m2"] for r in mine)),
            "covered_area_m2": _r(covered),
            "fraction": _r(covered / target) if target > 0 else None,
            "stations": stations,
        })
    return out


def room_rows(result: PlanResult) -> list[dict[str, Any]]:
    """Per room: how many candidates stand in it and which stations were chosen there."""
    labels = result.candidates.labels
    if not labels:
        return []
    chosen = {int(c): i + 1 for i, c in enumerate(result.chosen.stations)}
    rooms: dict[str, dict[str, Any]] = {}
    for c, label in enumerate(labels):
        key = label.get("room_global_id", "")
        room = rooms.setdefault(key, {
            "room": label.get("room", ""), "room_global_id": key,
            "storey": label.get("storey", ""), "candidates": 0, "stations": [],
        })
        room["candidates"] += 1
        if c in chosen:
            room["stations"].append(chosen[c])
    for room in rooms.values():
        room["stations"].sort()
    return list(rooms.values())


def elements_document(result: PlanResult) -> dict[str, Any]:
    """The content of ``elements.json`` as plain data."""
    rows = element_rows(result)
    uncoverable = [
        {key: row[key] for key in ("global_id", "ifc_class", "name", "storey",
                                   "target_area_m2", "uncoverable_reason", "reasons")}
        for row in rows if row["uncoverable_reason"] is not None
    ]
    return {
        "format_version": FORMAT_VERSION,
        "elements": rows,
        "storeys": storey_rows(result, rows),
        "rooms": room_rows(result),
        "uncoverable": uncoverable,
        "reasons": list(REASONS),
    }


def elements_json(result: PlanResult) -> bytes | None:
    """``elements.json`` bytes, or None for a scene without elements."""
    if not result.scene.elements:
        return None
    return canonical_json(elements_document(result))


def elements_csv(result: PlanResult) -> bytes | None:
    """``elements.csv`` bytes (``COLUMNS``), or None for a scene without elements."""
    if not result.scene.elements:
        return None
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(COLUMNS)
    for row in element_rows(result):
        writer.writerow([_cell(row[c]) for c in COLUMNS])
    return out.getvalue().encode("utf-8")


def _cell(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return f"{value:.6f}"
    return str(value)
