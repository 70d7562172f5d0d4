"""The simulated scan against the analytic density, and ``scanplan verify`` on a small plan."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from planner.limits import FaceLimits
from planner.parameters import PlanSpec
from planner.truth.simulation import ScanPattern, simulate_scan
from tests.planner.scenes import scene_of, square


def analytic_returns(centre: tuple[float, float, float], size_m: float, normal_axis: int,
                     step_rad: float) -> float:
    """Returns an azimuth x elevation grid puts on a square seen from the origin:
    the integral of sin(incidence) / (step d)^2 / cos(elevation) over the square (midpoint
    rule, 400 x 400 cells)."""
    n = 400
    offsets = (np.arange(n) + 0.5) / n * size_m - size_m / 2
    u, v = np.meshgrid(offsets, offsets, indexing="ij")
    points = np.zeros((n * n, 3)) + centre
    axes = [a for a in range(3) if a != normal_axis]
    points[:, axes[0]] += u.ravel()
    points[:, axes[1]] += v.ravel()
    d = np.linalg.norm(points, axis=1)
    sin_incidence = np.abs(points[:, normal_axis]) / d
    cos_elevation = np.hypot(points[:, 0], points[:, 1]) / d
    lpd = sin_incidence / (step_rad * d) ** 2 / cos_elevation
    return float(lpd.mean() * size_m * size_m)


@pytest.mark.parametrize(
    ("centre", "normal_axis", "elevation_deg"),
    [((2.5, 0.0, 0.0), 0, (-15.0, 15.0)),  # a wall head-on at 2.5 m
     ((1.2, 0.0, 2.0), 2, (40.0, 80.0))],  # a ceiling patch at 59 deg elevation
)
def test_simulated_density_equals_the_analytic_value(
        centre: tuple[float, float, float], normal_axis: int,
        elevation_deg: tuple[float, float]) -> None:
    step = 0.002
    spec = PlanSpec(point_spacing_m=step * 10, reference_distance_m=10.0,
                    elevation_min_deg=elevation_deg[0], elevation_max_deg=elevation_deg[1],
                    dof_min_m=0.5)
    scene = scene_of(square(centre, 0.6, normal_axis))
    counts = simulate_scan(scene, FaceLimits.from_spec(spec, scene), ScanPattern.from_spec(spec),
                           np.zeros((1, 3)))
    expected = analytic_returns(centre, 0.6, normal_axis, step)
    assert expected > 10_000  # enough returns that the grid's edge effects stay small
    assert counts.returns.sum() == pytest.approx(expected, rel=0.02)
    assert (counts.returns > 0).all()  # each triangle gets its returns


def test_range_window_drops_returns_outside_it() -> None:
    spec = PlanSpec(point_spacing_m=0.02, reference_distance_m=10.0, elevation_min_deg=-15.0,
                    elevation_max_deg=15.0, dof_min_m=3.0)
    scene = scene_of(square((2.5, 0.0, 0.0), 0.6, 0))
    counts = simulate_scan(scene, FaceLimits.from_spec(spec, scene), ScanPattern.from_spec(spec),
                           np.zeros((1, 3)))
    assert counts.hits[0] > 0  # the rays hit the wall ...
    assert counts.returns.sum() == 0  # ... nearer than dof_min_m: no point recorded


def test_pattern_of_the_defaults_has_16_4_million_rays() -> None:
    pattern = ScanPattern.from_spec(PlanSpec())
    assert len(pattern.azimuths_rad) == 6283
    assert len(pattern.elevations_rad) == 2618
    assert pattern.elevations_rad.max() < np.radians(90.0)


def scanplan(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "planner", *args], capture_output=True,
                          text=True, timeout=300, check=False)


@pytest.fixture(scope="module")
def room_plan(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A 4 x 4 x 3 m room with a post, planned from two candidates at a coarse 4 mrad, and a
    slab 20 m away that no candidate can qualify (its faces are not split)."""
    import trimesh

    room = trimesh.creation.box(extents=(4.0, 4.0, 3.0))
    room.apply_translation((2.0, 2.0, 1.5))
    room.invert()
    post = trimesh.creation.box(extents=(0.2, 0.2, 3.0))
    post.apply_translation((2.0, 2.6, 1.5))
    far_slab = trimesh.creation.box(extents=(2.0, 2.0, 0.2))
    far_slab.apply_translation((25.0, 2.0, 0.1))
    mesh = trimesh.util.concatenate([room, post, far_slab])
    work = tmp_path_factory.mktemp("room")
    model = work / "room.obj"
    mesh.export(model)
    params = work / "params.json"
    params.write_text(json.dumps({
        "point_spacing_m": 0.04, "reference_distance_m": 10.0, "min_density_pts_m2": 2000,
        "candidates": [[1.0, 1.0, 1.5], [3.0, 3.2, 1.5]], "coverage_goal": 1.0,
        "max_edge_m": 0.5,
    }))
    out = work / "plan"
    done = scanplan("plan", str(model), "--params", str(params), "--out", str(out), "--quiet")
    assert done.returncode == 0, done.stderr
    return model, out


def test_verify_writes_verification_and_verified_faces(room_plan: tuple[Path, Path]) -> None:
    model, out = room_plan
    done = scanplan("verify", str(out), "--scene", str(model))
    assert done.returncode == 0, done.stderr
    assert "promised" in done.stdout
    first = (out / "verification.json").read_bytes()
    report = json.loads(first)
    plan = json.loads((out / "plan.json").read_text())
    totals = report["totals"]
    assert totals["promised_area_m2"] == pytest.approx(plan["totals"]["covered_area_m2"])
    assert report["pattern"]["rays_per_station"] == 1571 * 654
    assert len(report["stations"]) == plan["totals"]["stations"]
    # the scan delivers most of what the centroid model promised in an empty room
    assert totals["promised_not_delivered_area_m2"] < 0.05 * totals["promised_area_m2"]
    with np.load(out / "faces.npz") as faces:
        verified = faces["verified_lpd_pts_m2"]
        assert len(verified) == plan["totals"]["faces"]
        # verify split the model as the plan did: the far slab's 12 faces (2 m edges, the
        # last of the file) stayed whole, the room's were split
        pieces = np.bincount(faces["source_face"])
        assert (pieces[-12:] == 1).all() and (pieces[:-12] > 1).any()
        assert faces["covered"].shape == verified.shape  # the plan's arrays are kept
        delivered = faces["verified_delivered"]
        areas_delivered = delivered.sum()
    assert areas_delivered > 0
    # same plan, same bytes
    again = scanplan("verify", str(out), "--scene", str(model), "--quiet")
    assert again.returncode == 0 and again.stdout == ""
    assert (out / "verification.json").read_bytes() == first


def test_verify_with_the_wrong_model_is_one_line_error(room_plan: tuple[Path, Path],
                                                       tmp_path: Path) -> None:
    _, out = room_plan
    other = tmp_path / "other.obj"
    import trimesh

    trimesh.creation.box(extents=(1.0, 1.0, 1.0)).export(other)
    done = scanplan("verify", str(out), "--scene", str(other))
    assert done.returncode == 2
    assert done.stderr.count("\n") == 1 and "--scene" in done.stderr


def test_verify_without_a_plan_names_plan_dir(tmp_path: Path) -> None:
    done = scanplan("verify", str(tmp_path), "--scene", str(tmp_path / "x.obj"))
    assert done.returncode == 2
    assert "PLAN_DIR" in done.stderr
