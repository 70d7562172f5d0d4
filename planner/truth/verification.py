"""Check a plan's promise with a simulated scan: ``verification.json`` and the verified
densities in ``faces.npz``.

The plan promises the faces it marks ``covered``. The simulated scan of its stations
(:mod:`planner.truth.simulation`) delivers, per face, a density from each station. A face is
*delivered* when its best station's density meets the face's ``min_density_pts_m2`` (the
same per-station reading as the promise; the merged density of all stations is reported
beside it). A station counts for a face only when it sees the face at the face's
``min_incidence_deg`` or more (the angle of the ray to the face centroid, as the
requirement is stated per face); its returns are counted whatever the incidence.
Totals compare the two sets by area:

- ``promised_area_m2``: target faces the plan covers;
- ``delivered_area_m2``: target faces the simulated scan delivers;
- ``promised_not_delivered_area_m2``: false promises;
- ``delivered_not_promised_area_m2``: misses of the model (area the plan could count);
- ``hole_area_m2``: bins of promised faces that no station samples at half the requirement
  (bins defined in :mod:`planner.truth.simulation`).

Same plan, same bytes: counts are integers and timings stay out of the file.
"""

from __future__ import annotations

import io
import json
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from planner.errors import PlannerError
from planner.io.orientation import scene_rotation, to_plan
from planner.limits import FaceLimits
from planner.parameters import PlanSpec
from planner.progress import ProgressCallback
from planner.scene import Scene, remesh
from planner.truth.simulation import (
    HOLE_BIN_EDGE_M,
    HOLE_DENSITY_FRACTION,
    ScanCounts,
    ScanPattern,
    simulate_scan,
)

VERIFICATION_FORMAT_VERSION = 1
_DECIMALS = 6


def _r(value: float) -> float:
    rounded = round(float(value), _DECIMALS)
    return 0.0 if rounded == 0 else rounded


@dataclass(frozen=True, eq=False)
class Verification:
    """The simulated scan of a plan compared with its promise.

    Attributes
    ----------
    promised : (F,) bool, target faces the plan covers
    best_lpd_pts_m2 : (F,) float64, density delivered by the best station
    merged_lpd_pts_m2 : (F,) float64, density of all stations' returns together
    delivered : (F,) bool, target faces whose best station meets the requirement
    hole_area_m2 : (F,) float64, area of the face's hole bins (promised faces only)
    required_lpd_pts_m2 : (F,) float64, the face's min_density_pts_m2
    station_delivers : (S, F) bool, the station alone delivers the face (density and
        incidence)
    """

    scene: Scene
    counts: ScanCounts
    stations_xyz: NDArray[np.float64]
    target: NDArray[np.bool_]
    promised: NDArray[np.bool_]
    best_lpd_pts_m2: NDArray[np.float64]
    merged_lpd_pts_m2: NDArray[np.float64]
    delivered: NDArray[np.bool_]
    hole_area_m2: NDArray[np.float64]
    required_lpd_pts_m2: NDArray[np.float64]
    station_delivers: NDArray[np.bool_]

    def totals(self) -> dict[str, Any]:
        area = self.scene.areas
        promised = float(area[self.promised].sum())
        false_promises = self.promised & ~self.delivered
        misses = self.delivered & ~self.promised
        merged = self.target & (self.merged_lpd_pts_m2 >= self.required_lpd_pts_m2)
        return {
            "promised_area_m2": _r(promised),
            "delivered_area_m2": _r(area[self.delivered].sum()),
            "delivered_merged_area_m2": _r(area[merged].sum()),
            "promised_not_delivered_area_m2": _r(area[false_promises].sum()),
            "promised_not_delivered_fraction": _r(
                area[false_promises].sum() / promised if promised else 0.0),
            "promised_not_delivered_faces": int(false_promises.sum()),
            "delivered_not_promised_area_m2": _r(area[misses].sum()),
            "delivered_not_promised_faces": int(misses.sum()),
            "hole_area_m2": _r(self.hole_area_m2.sum()),
            "hole_faces": int((self.hole_area_m2 > 0).sum()),
        }



def verify(
    scene: Scene,
    spec: PlanSpec,
    stations_xyz: NDArray[np.float64],
    promised: NDArray[np.bool_],
    *,
    progress: ProgressCallback | None = None,
    threads: int | None = None,
) -> Verification:
    """Simulate the scan of (S, 3) stations and compare it with (F,) ``promised`` faces."""
    limits = FaceLimits.from_spec(spec, scene)
    counts = simulate_scan(scene, limits, ScanPattern.from_spec(spec), stations_xyz,
                           progress=progress, threads=threads)
    area = scene.areas
    required = limits.min_density_pts_m2
    safe_area = np.where(area > 0, area, np.inf)
    stations = np.asarray(stations_xyz, np.float64).reshape(-1, 3)
    usable = _meets_incidence(scene, limits, stations)
    best = np.where(usable, counts.returns, 0).max(axis=0, initial=0) / safe_area
    merged = counts.returns.sum(axis=0) / safe_area
    target = limits.target
    promised = np.asarray(promised, bool) & target
    # (S, F): the station alone meets both the incidence and the density of the face
    station_delivers = (usable & target & (counts.returns > 0)
                        & (counts.returns / safe_area >= required))
    delivered: NDArray[np.bool_] = np.any(station_delivers, axis=0)
    bins = counts.bins
    bin_area = area[bins.face] / (bins.splits[bins.face] ** 2)
    hole = (bins.valid & promised[bins.face]
            & (counts.best_bin_lpd_pts_m2 < HOLE_DENSITY_FRACTION * required[bins.face]))
    hole_area = np.bincount(bins.face, weights=np.where(hole, bin_area, 0.0),
                            minlength=scene.n_faces).astype(np.float64)
    result = Verification(scene=scene, counts=counts, stations_xyz=stations,
                          target=target, promised=promised, best_lpd_pts_m2=best,
                          merged_lpd_pts_m2=merged, delivered=delivered,
                          hole_area_m2=hole_area, required_lpd_pts_m2=required,
                          station_delivers=station_delivers)
    return result


def _meets_incidence(scene: Scene, limits: FaceLimits,
                     stations_xyz: NDArray[np.float64]) -> NDArray[np.bool_]:
    """(S, F) bool: station s sees face f at its min_incidence_deg or more (centroid ray)."""
    usable = np.zeros((len(stations_xyz), scene.n_faces), bool)
    min_sin = np.sin(np.radians(limits.min_incidence_deg))
    normals, centroids = scene.normals, scene.centroids
    for s, position in enumerate(stations_xyz):
        ray = centroids - position
        length = np.linalg.norm(ray, axis=1)
        facing = np.abs(np.einsum("ij,ij->i", ray, normals))
        usable[s] = facing >= min_sin * length
    return usable


def verification_document(result: Verification, spec: PlanSpec) -> dict[str, Any]:
    """The content of ``verification.json``."""
    area = result.scene.areas
    counts = result.counts
    stations = []
    for i, position in enumerate(result.stations_xyz):
        meets = result.station_delivers[i]
        stations.append({
            "id": i + 1,
            "position": [_r(v) for v in position],
            "rays": int(counts.rays[i]),
            "hits": int(counts.hits[i]),
            "returns_counted": int(counts.returns[i].sum()),
            "delivered_area_m2": _r(area[meets].sum()),
        })
    return {
        "format_version": VERIFICATION_FORMAT_VERSION,
        "coverage_model": getattr(spec, "coverage_model", "centroid"),
        "pattern": counts.pattern.to_dict(),
        "holes": {
            "bin_edge_max_m": HOLE_BIN_EDGE_M,
            "density_fraction": HOLE_DENSITY_FRACTION,
            "definition": "each face split into n x n equal triangles of a barycentric grid, "
                          "n = ceil(longest edge / bin_edge_max_m) (at most 16); a bin of a "
                          "promised face is a hole when no station samples it at "
                          "density_fraction of the face's min_density_pts_m2",
        },
        "totals": result.totals(),
        "stations": stations,
    }


def verification_json(result: Verification, spec: PlanSpec) -> bytes:
    from planner.outputs.report import canonical_json

    return canonical_json(verification_document(result, spec))


# faces.npz members the verification adds beside the plan's own
VERIFIED_FACE_ARRAYS = ("verified_lpd_pts_m2", "verified_merged_lpd_pts_m2",
                        "verified_delivered", "verified_hole_area_m2")


def verified_face_arrays(result: Verification) -> dict[str, NDArray[Any]]:
    """Per-face arrays, each (F,): best-station density (float32, pts/m^2), all stations
    merged (float32), delivered (bool) and hole area (float32, m^2)."""
    return {
        "verified_lpd_pts_m2": result.best_lpd_pts_m2.astype(np.float32),
        "verified_merged_lpd_pts_m2": result.merged_lpd_pts_m2.astype(np.float32),
        "verified_delivered": result.delivered.copy(),
        "verified_hole_area_m2": result.hole_area_m2.astype(np.float32),
    }


def _npz_bytes(arrays: dict[str, NDArray[Any]]) -> bytes:
    """npz bytes with fixed zip timestamps, as :func:`planner.outputs.report.faces_npz` writes."""
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        for name, array in arrays.items():
            member = io.BytesIO()
            np.lib.format.write_array(member, np.ascontiguousarray(array), allow_pickle=False)
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            archive.writestr(info, member.getvalue())
    return buffer.getvalue()


@dataclass(frozen=True)
class PlanFiles:
    """What verification reads back from a plan directory."""

    spec: PlanSpec
    stations_xyz: NDArray[np.float64]
    faces: dict[str, NDArray[Any]]
    n_faces: int


def read_plan_dir(plan_dir: str | Path) -> PlanFiles:
    """plan.json (parameters, stations) and faces.npz (``covered``) of a plan directory."""
    directory = Path(plan_dir)
    plan_path, faces_path = directory / "plan.json", directory / "faces.npz"
    for path in (plan_path, faces_path):
        if not path.is_file():
            raise PlannerError(f"PLAN_DIR: {path} is missing; give the --out directory of "
                               "'scanplan plan'")
    try:
        document = json.loads(plan_path.read_text(encoding="utf-8"))
        spec = PlanSpec.from_mapping(document["parameters"])
        stations = np.array([s["position"] for s in document["stations"]], np.float64)
        n_faces = int(document["totals"]["faces"])
    except (json.JSONDecodeError, KeyError, TypeError) as exc:
        raise PlannerError(f"PLAN_DIR: {plan_path} is not a scanplan plan.json ({exc}); "
                           "plan again with 'scanplan plan'") from exc
    with np.load(faces_path, allow_pickle=False) as npz:
        faces = {name: npz[name] for name in npz.files}
    if "covered" not in faces or len(faces["covered"]) != n_faces:
        raise PlannerError(f"PLAN_DIR: {faces_path} does not match plan.json "
                           f"({n_faces} faces); plan again with 'scanplan plan'")
    return PlanFiles(spec, stations.reshape(-1, 3), faces, n_faces)


def split_as_planned(scene: Scene, files: PlanFiles) -> Scene:
    """``scene`` (read with ``split_faces="as_needed"``) split as the plan in ``files`` split
    it: a file face in more than one piece of faces.npz ``source_face`` was split, the others
    were kept whole (:mod:`planner.visibility.splitting`)."""
    if scene.split_max_edge_m is None:
        return scene
    source_face = files.faces.get("source_face")
    if source_face is None or len(source_face) == 0 or source_face.max() >= scene.n_faces:
        return remesh(scene, scene.split_max_edge_m)  # not this model's plan: split it all
    pieces = np.bincount(source_face, minlength=scene.n_faces)
    return remesh(scene, scene.split_max_edge_m, split=pieces > 1)


def verify_plan_dir(
    plan_dir: str | Path,
    scene: Scene,
    files: PlanFiles,
    *,
    progress: ProgressCallback | None = None,
    threads: int | None = None,
) -> tuple[Verification, list[Path]]:
    """Verify the plan in ``plan_dir`` on ``scene`` (the model read with the plan's
    ``max_edge_m`` and ``unit_scale``); write verification.json and add the verified
    arrays to faces.npz."""
    from planner.outputs.report import atomic_write

    if scene.n_faces != files.n_faces or (
            "source_face" in files.faces
            and not np.array_equal(files.faces["source_face"], scene.source_face)):
        raise PlannerError(
            f"--scene: the model has {scene.n_faces} faces after preparation but the plan "
            f"has {files.n_faces}; give the model the plan was made from")
    # plan.json holds model coordinates; the scene was levelled when read (up_axis)
    stations_xyz = to_plan(scene_rotation(scene.metadata), files.stations_xyz)
    result = verify(scene, files.spec, stations_xyz, files.faces["covered"].astype(bool),
                    progress=progress, threads=threads)
    directory = Path(plan_dir)
    faces = {name: array for name, array in files.faces.items()
             if name not in VERIFIED_FACE_ARRAYS}
    faces.update(verified_face_arrays(result))
    written = [atomic_write(directory / "verification.json",
                            verification_json(result, files.spec)),
               atomic_write(directory / "faces.npz", _npz_bytes(faces))]
    return result, written
