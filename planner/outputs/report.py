"""The plan as files: canonical JSON, per-face arrays, a station list.

Same input, same bytes: JSON keys are sorted, floats rounded to fixed decimals, arrays
written without timestamps. Timings never enter these files (they live in
``PlanResult.stats`` and the service's job record).

Outputs of :func:`write_outputs` (the names the service serves too):

- ``plan.json``: totals, stations, coverage curve, parameters, candidates (+ optimal), and
  the survey (:mod:`planner.survey.fieldwork`): ``registration``, ``route``, ``field_time``;
- ``faces.npz``: per face ``covered``, ``best_lpd_pts_m2``, ``n_stations``,
  ``first_station``, ``n_candidates``, ``source_face``;
- ``stations.csv``: ``id,x,y,z,order,candidate_index,visit`` in model coordinates (``visit``:
  place on the walking route, empty when unreachable), with a scanner also ``setting,scan_s``;
- ``candidates.csv``: every candidate considered, ``x,y,z``;
- ``elements.csv``, ``elements.json``: coverage per BIM element (IFC models only, see
  :mod:`planner.outputs.bim`); a renderer that returns None writes no file;
- the pictures: ``preview.png``, ``curve.png`` (:mod:`planner.outputs.drawing`),
  ``coverage.glb`` (:mod:`planner.outputs.glb`), ``plan.dxf`` (CAD drawing,
  :mod:`planner.outputs.cad`) and ``plan.pdf`` (print set, :mod:`planner.outputs.printset`).
- ``plan.ifc`` (IFC models only, :mod:`planner.outputs.ifc_plan`; :func:`absent_outputs`
  says why it is missing) and ``plan.bcf`` (:mod:`planner.outputs.bcf_plan`): the plan
  back in the BIM.
"""

from __future__ import annotations

import csv
import gc
import importlib
import io
import os
import tempfile
import threading
import zipfile
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from planner.io.orientation import scene_rotation, to_model
from planner.memory import release_freed_memory
from planner.outputs.canonical import canonical_json as canonical_json  # re-exported
from planner.pipeline import PlanResult
from planner.rays.pinned import KERNELS as RAY_KERNELS
from planner.selection.curve import coverage_curve
from planner.selection.greedy import GOAL_SLACK_M2
from planner.version import __version__

FORMAT_VERSION = 1
_AREA_DECIMALS = 6
_POSITION_DECIMALS = 6

_NPZ_BLOCK = 1 << 20  # values of a faces.npz array compressed at a time
FACE_ARRAYS = ("covered", "best_lpd_pts_m2", "n_stations", "first_station", "n_candidates",
               "source_face")


def _r(value: float, decimals: int = _AREA_DECIMALS) -> float:
    rounded = round(float(value), decimals)
    return 0.0 if rounded == 0 else rounded  # no "-0.0"


def model_positions(result: PlanResult) -> np.ndarray:
    """(C, 3) candidate positions in the model's own coordinates (see ``up_axis``)."""
    return to_model(scene_rotation(result.scene.metadata), result.candidates.positions)


def _route_in_model(result: PlanResult) -> dict[str, Any]:
    """The walking route with its leg paths and door checks' points in the model's own
    coordinates (``up_axis``)."""
    assert result.survey is not None
    route = result.survey.route.to_dict()
    rotation = scene_rotation(result.scene.metadata)
    if rotation is not None:
        for leg in route["legs"]:
            if leg["path"]:
                leg["path"] = [[round(float(v), 3) for v in p]
                               for p in to_model(rotation, np.asarray(leg["path"]))]
        checks = result.survey.route.door_checks
        if checks:
            points = to_model(rotation, np.asarray([check.at for check in checks]))
            route["door_checks"] = [check.to_dict((float(x), float(y), float(z)))
                                    for check, (x, y, z) in zip(checks, points, strict=True)]
    return route


def _with_stations(summary: dict[str, Any], stations: list[dict[str, Any]],
                   also_in: tuple[tuple[str, ...], ...] = ()) -> dict[str, Any]:
    """``candidates`` of plan.json: for an IFC plan, each room's entry also counts the
    stations that stand on its floor (a room with candidates may need none: the stations
    in the rooms around it cover it). A station in rooms that overlap (``also_in``, per
    candidate) counts in each; a room's ``shared`` counts those of its stations that an
    earlier room it overlaps holds."""
    if summary.get("rooms") is None:
        return summary
    chosen: dict[str, int] = {}
    shared: dict[str, int] = {}
    for station in stations:
        room = station.get("label", {}).get("room_global_id")
        if room:
            chosen[room] = chosen.get(room, 0) + 1
        index = int(station["candidate_index"])
        for later in also_in[index] if index < len(also_in) else ():
            chosen[later] = chosen.get(later, 0) + 1
            shared[later] = shared.get(later, 0) + 1
    rooms = []
    for room in summary["rooms"]:
        gid = str(room["room_global_id"])
        entry = {**room, "stations": chosen.get(gid, 0)}
        if "shared" in room:
            entry["shared"] = {**room["shared"], "stations": shared.get(gid, 0)}
        rooms.append(entry)
    return {**summary, "rooms": rooms}


def plan_document(result: PlanResult) -> dict[str, Any]:
    """The content of ``plan.json`` as plain data."""
    table, chosen = result.table, result.chosen
    max_area = table.max_achievable_area_m2
    covered = chosen.covered_area_m2[-1] if chosen.stations else 0.0
    positions = model_positions(result)
    labels = result.candidates.labels
    stations = []
    for order, (candidate, new, cumulative) in enumerate(
        zip(chosen.stations, chosen.new_area_m2, chosen.covered_area_m2, strict=True)
    ):
        station: dict[str, Any] = {
            "id": order + 1,
            "candidate_index": int(candidate),
            "position": [_r(v, _POSITION_DECIMALS) for v in positions[candidate]],
            "new_area_m2": _r(new),
            "covered_area_m2": _r(cumulative),
            "coverage_fraction": _r(cumulative / max_area if max_area else 0.0),
        }
        if labels:
            station["label"] = dict(labels[candidate])
        if order < chosen.fixed:
            station["fixed"] = True  # re-scan: scanned before (fixed_stations)
        if result.survey is not None:
            station["visit"] = result.survey.visit_of(order + 1)
            if result.survey.scans:  # a scanner was given: its setting and scan time
                scan = result.survey.scans[order]
                station["setting"] = scan.setting
                station["scan_s"] = None if scan.scan_s is None else round(scan.scan_s, 1)
        heights = result.candidates.heights_m
        if heights is not None and np.isfinite(heights[candidate]):
            station["scanner_height_m"] = _r(heights[candidate])
        if result.tolerance is not None:
            station["tolerance"] = result.tolerance.stations[order].to_dict()
        stations.append(station)
    document: dict[str, Any] = {
        "format_version": FORMAT_VERSION,
        "scanplan_version": __version__,
        "method": chosen.method,
        "coverage_goal": result.spec.coverage_goal,
        "goal_reached": bool(covered >= result.spec.coverage_goal * max_area - GOAL_SLACK_M2),
        "totals": {
            "faces": result.scene.n_faces,
            "target_faces": int(result.limits.target.sum()),
            "candidates": len(result.candidates),
            "qualified_pairs": table.n_pairs,
            "total_area_m2": _r(result.scene.areas.sum()),
            "target_area_m2": _r(result.scene.areas[result.limits.target].sum()),
            "max_achievable_area_m2": _r(max_area),
            "covered_area_m2": _r(covered),
            "coverage_fraction": _r(covered / max_area if max_area else 0.0),
            "stations": len(chosen.stations),
        },
        "stations": stations,
        "curve": coverage_curve(result.selections, result.optimal_curve),
        "selection": result.selection_report,
        "parameters": result.spec.to_dict(),
        # which kernels decided the rays: plans are byte for byte the same on machines whose
        # kernels are the same (exact rays: on every machine)
        "rays": {"kernels": RAY_KERNELS, "exact": result.spec.exact_rays},
        "candidates": _with_stations(result.candidates.summary(), stations,
                                     result.candidates.also_in),
        "scene": {
            "format": result.scene.metadata.get("format", ""),
            "groups": list(result.scene.groups),
            "bounds": [[_r(v) for v in row] for row in result.scene.bounds],
            "orientation": result.scene.metadata.get("orientation"),
            "warnings": list(result.scene.metadata.get("warnings", [])),
        },
    }
    if result.survey is not None:
        document["registration"] = result.survey.registration.to_dict()
        document["route"] = _route_in_model(result)
        document["field_time"] = result.survey.field_time.to_dict()
    if result.tolerance is not None:
        document["tolerance"] = result.tolerance.to_dict()
    if result.spec.scanner_heights_m is not None and result.candidates.heights_m is not None:
        heights, counts = np.unique(result.candidates.heights_m[
            np.isfinite(result.candidates.heights_m)], return_counts=True)
        document["candidates"]["per_height"] = [
            {"scanner_height_m": _r(h), "candidates": int(n)}
            for h, n in zip(heights, counts, strict=True)]
    if result.optimal is not None:
        document["optimal"] = result.optimal.to_dict()
        document["optimal"]["greedy_stations"] = result.selections["greedy"].count_for_goal(
            result.spec.coverage_goal)
    return document


def plan_json(result: PlanResult) -> bytes:
    return canonical_json(plan_document(result))


# the type an array of ``faces.npz`` is stored as where it is not the plan's own
FACE_ARRAY_DTYPES = {"source_face": np.dtype(np.int64)}


def face_arrays(result: PlanResult) -> dict[str, np.ndarray]:
    """Per-face arrays of ``faces.npz``, each of length F, as the plan holds them (stored
    as :data:`FACE_ARRAY_DTYPES` says)."""
    arrays = dict(result.faces)
    arrays["source_face"] = result.scene.source_face
    return {name: arrays[name] for name in FACE_ARRAYS}


def faces_npz(result: PlanResult) -> bytes:
    """``faces.npz`` bytes with fixed zip timestamps (numpy's savez stamps the clock).

    Each array is streamed into its member ``_NPZ_BLOCK`` values at a time, cast to its
    stored type on the way: no whole-array copy (``source_face`` as int64 alone is 80 MB on
    a 10 M-face model), the same bytes.
    """
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        for name, values in face_arrays(result).items():
            dtype = FACE_ARRAY_DTYPES.get(name, values.dtype)
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            with archive.open(info, "w") as member:
                np.lib.format.write_array_header_1_0(member, {
                    "descr": np.lib.format.dtype_to_descr(dtype), "fortran_order": False,
                    "shape": values.shape})
                for start in range(0, len(values), _NPZ_BLOCK):
                    member.write(np.ascontiguousarray(values[start:start + _NPZ_BLOCK],
                                                      dtype).data)
    return buffer.getvalue()


def stations_csv(result: PlanResult) -> bytes:
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    scans = () if result.survey is None else result.survey.scans
    # with a scanner: each station's setting and scan seconds (empty when unknown)
    writer.writerow(["id", "x", "y", "z", "order", "candidate_index", "visit"]
                    + (["setting", "scan_s"] if scans else []))
    positions = model_positions(result)
    for order, candidate in enumerate(result.chosen.stations):
        x, y, z = (f"{v:.6f}" for v in positions[candidate])
        visit = None if result.survey is None else result.survey.visit_of(order + 1)
        # an unreachable station has no place on the route: an empty cell
        row = [order + 1, x, y, z, order + 1, int(candidate), "" if visit is None else visit]
        if scans:
            scan = scans[order]
            row += [scan.setting or "", "" if scan.scan_s is None else f"{scan.scan_s:.1f}"]
        writer.writerow(row)
    return out.getvalue().encode("utf-8")


def candidates_csv(result: PlanResult) -> bytes:
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(["x", "y", "z"])
    for x, y, z in model_positions(result):
        writer.writerow([f"{x:.6f}", f"{y:.6f}", f"{z:.6f}"])
    return out.getvalue().encode("utf-8")


def elements_csv(result: PlanResult) -> bytes | None:
    if not result.scene.elements:
        return None
    from planner.outputs import bim  # only IFC scenes have elements

    return bim.elements_csv(result)


def elements_json(result: PlanResult) -> bytes | None:
    if not result.scene.elements:
        return None
    from planner.outputs import bim

    return bim.elements_json(result)


# the modules the renderers import on first use (matplotlib, ezdxf, the glTF writer): on
# hall-full 1.0 CPU s together, a third of its outputs' time, most of it on the picture
# threads' path after the plan
RENDERER_MODULES = ("drawing", "printset", "glb", "cad", "ifc_plan", "bcf_plan")


def preload_renderers() -> threading.Thread:
    """Import :data:`RENDERER_MODULES` on a daemon thread, started now, so the pictures do
    not wait for them once the plan is done: a caller starts it when a core is idle (the
    plan's tail runs on one thread). An import that fails here is left to fail again, and
    be reported, when its output is rendered."""

    def load() -> None:
        for module in RENDERER_MODULES:
            try:
                importlib.import_module(f"planner.outputs.{module}")
            except Exception:  # raised again where the output is rendered
                continue

    thread = threading.Thread(target=load, name="scanplan-preload", daemon=True)
    thread.start()
    return thread


def _lazy(module: str, function: str, result: PlanResult) -> bytes:
    """Render with ``planner.outputs.<module>.<function>``, imported on first use (matplotlib)."""
    render: Callable[[PlanResult], bytes] = getattr(
        importlib.import_module(f"planner.outputs.{module}"), function)
    return render(result)


# name -> renderer (None: nothing to write for this plan); other modules register theirs here
OUTPUTS: dict[str, Callable[[PlanResult], bytes | None]] = {
    "plan.json": plan_json,
    "faces.npz": faces_npz,
    "stations.csv": stations_csv,
    "candidates.csv": candidates_csv,
    "elements.csv": elements_csv,
    "elements.json": elements_json,
    "preview.png": lambda result: _lazy("drawing", "preview_png", result),
    "curve.png": lambda result: _lazy("drawing", "curve_png", result),
    "coverage.glb": lambda result: _lazy("glb", "coverage_glb", result),
    "plan.dxf": lambda result: _lazy("cad", "plan_dxf", result),
    "plan.pdf": lambda result: _lazy("printset", "plan_pdf", result),
    "plan.ifc": lambda result: _lazy("ifc_plan", "plan_ifc", result),
    "plan.bcf": lambda result: _lazy("bcf_plan", "plan_bcf", result),
}


def absent_outputs(result: PlanResult) -> dict[str, str]:
    """Outputs of :data:`OUTPUTS` this plan has none of that a user may look for, with why."""
    from planner.outputs.ifc_plan import absent_reason

    reason = absent_reason(result)
    return {} if reason is None else {"plan.ifc": reason}


# outputs written straight into their file rather than returned whole: name -> writer
# (result, file, folder for scratch files). coverage.glb of a 10 M-face plan is 145 MB.
WRITERS: dict[str, Callable[[PlanResult, BinaryIO, Path], None]] = {
    "coverage.glb": lambda result, handle, folder: importlib.import_module(
        "planner.outputs.glb").write_coverage_glb(result, handle, spill_dir=folder),
}

# Pictures: slow to render and not what a BIM platform waits for, so they are drawn in
# background threads while the data files are written, and land on disk after them. One
# thread per group, the group's files one after the other: the matplotlib drawings in one
# group (matplotlib is not thread-safe, and side by side their peaks would add up), the
# 3D and CAD models, which never touch matplotlib, in the other. On the 9.7 M-face office
# the drawings take some 15 s and the models 8 s; together, one after the other, 23 s.
# The models start once the first drawing is made: the preview draws every storey's floor
# (kept for the print set) and coverage.glb outlines every feature, the two largest peaks
# of the outputs, which side by side had added up (Lantern Hollow's plain mesh: 1,018 MiB,
# over the plan's own peak); the print set that follows the preview reuses its floors.
PICTURE_GROUPS = (("preview.png", "curve.png", "plan.pdf"), ("coverage.glb", "plan.dxf"))


def write_outputs(result: PlanResult, out_dir: str | Path,
                  names: tuple[str, ...] | None = None) -> list[Path]:
    """Write every output into ``out_dir`` (created), each file atomically.

    The data files (plan.json first, in the order of :data:`OUTPUTS`) are on disk before any
    picture; the pictures render meanwhile (see :data:`PICTURE_GROUPS`) into hidden
    temporary files, renamed into place once the data files are written. Returns the paths
    in the order of :data:`OUTPUTS`, whatever order they were finished in.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    # Each drawing frees its figure with a full collection (drawing.release_figure), which
    # walks every object the process holds: 0.09 s a figure on hall-full. The objects that
    # exist now (the plan, the modules) are frozen out of those walks while the outputs
    # render, and handed back to the collector afterwards.
    gc.freeze()
    try:
        return _write_outputs(result, out, names)
    finally:
        gc.unfreeze()


def _write_outputs(result: PlanResult, out: Path, names: tuple[str, ...] | None
                   ) -> list[Path]:
    wanted = [name for name in OUTPUTS if names is None or name in names]
    pictures = {name for group in PICTURE_GROUPS for name in group}
    groups = [[name for name in group if name in wanted] for group in PICTURE_GROUPS]
    written: dict[str, Path] = {}
    data_files = _Gate()
    drawings, models = groups
    first_drawing = threading.Event()
    if not drawings:
        first_drawing.set()
    with ThreadPoolExecutor(max_workers=len(PICTURE_GROUPS),
                            thread_name_prefix="scanplan-pictures") as pool:
        rendering = [pool.submit(_write_all, result, drawings, out, data_files,
                                 first_done=first_drawing)] if drawings else []
        if models:
            rendering.append(pool.submit(_write_all, result, models, out, data_files,
                                         start_after=first_drawing))
        written_all = False
        try:
            for name in wanted:
                if name not in pictures:
                    written.update(_write_one(result, name, out))
            written_all = True
        finally:
            data_files.open(written_all)  # the pictures of a failed run stay unwritten
        for future in rendering:
            written.update(future.result())
    return [written[name] for name in wanted if name in written]


class _Gate:
    """Holds the pictures back until the data files are written (``open(True)``), or for
    good when writing them failed (``open(False)``)."""

    def __init__(self) -> None:
        self._event = threading.Event()
        self._passes = False

    def open(self, passes: bool) -> None:
        self._passes = passes
        self._event.set()

    def wait(self) -> bool:
        self._event.wait()
        return self._passes


def _write_all(result: PlanResult, group: list[str], out: Path, gate: _Gate, *,
               start_after: threading.Event | None = None,
               first_done: threading.Event | None = None) -> dict[str, Path]:
    """Write the outputs named in ``group``, one after the other, each renamed into place
    once ``gate`` lets it; begin once ``start_after`` is set, and set ``first_done`` when
    the first is written (or the group stops)."""
    written = {}
    try:
        if start_after is not None:
            start_after.wait()
        for name in group:
            written.update(_write_one(result, name, out, gate))
            if first_done is not None:
                first_done.set()
    finally:
        if first_done is not None:
            first_done.set()  # a failed drawing holds no other output back
    return written


def _write_one(result: PlanResult, name: str, out: Path, gate: _Gate | None = None
               ) -> dict[str, Path]:
    """Write output ``name`` into ``out``, renamed into place once ``gate`` lets it (at
    once without one): {name: path}, or {} when the plan has no such output or the gate
    stays shut."""
    path = out / name
    if name in WRITERS:
        writer = WRITERS[name]
        staged = _staged(path, lambda handle: writer(result, handle, out))
    else:
        data = OUTPUTS[name](result)
        if data is None:
            return {}
        staged = _staged(path, data)
        del data
    # what the output freed, back to the system: the heap would keep it under the next
    # output's peak (and a thread's allocator arena serves no other thread)
    release_freed_memory()
    try:
        if gate is not None:
            if not gate.wait():
                staged.unlink()
                return {}
            os.utime(staged)  # stamped when it lands, after the data files
        os.replace(staged, path)
    except BaseException:
        staged.unlink(missing_ok=True)
        raise
    return {name: path}


def atomic_write(path: Path, data: bytes) -> Path:
    """Write to a temporary file beside ``path`` and rename it into place."""
    os.replace(_staged(path, data), path)
    return path


def _staged(path: Path, data: bytes | Callable[[BinaryIO], None]) -> Path:
    """A temporary file beside ``path`` (hidden: its name starts with a dot) holding
    ``data``, or what ``data`` writes to it."""
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as handle:
            if isinstance(data, bytes):
                handle.write(data)
            else:
                data(handle)
        os.chmod(tmp, 0o644)  # mkstemp makes 0600; results are meant to be shared
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return Path(tmp)
