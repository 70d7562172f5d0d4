"""``scanplan plan``: files written, same bytes twice, one-line errors."""

from __future__ import annotations

import json
import subprocess
import sys
from importlib import metadata
from pathlib import Path

import numpy as np
import pytest

from planner.rays.pinned import KERNELS


def scanplan(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "planner", *args], capture_output=True,
                          text=True, timeout=300, check=False)


@pytest.fixture(scope="module")
def hall_small(scenes_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    params = tmp_path_factory.mktemp("params") / "params.json"
    # exact rays: the curve is compared with the reference's (expected.json) at every goal
    params.write_text(json.dumps({"max_edge_m": None, "method": "weighted_greedy",
                                  "exact_rays": True}))
    outs = {}
    for run in ("a", "b"):
        out = tmp_path_factory.mktemp(f"out-{run}")
        done = scanplan("plan", str(scenes_dir / "hall-small" / "hall.obj"), "--candidates",
                        str(scenes_dir / "hall-small" / "candidates.csv"), "--params",
                        str(params), "--out", str(out))
        assert done.returncode == 0, done.stderr
        assert "stations cover" in done.stdout
        assert done.stderr == ""  # piped: no progress bar
        outs[run] = out
    return outs


def test_plan_json_has_the_contract(hall_small: dict[str, Path], scenes_dir: Path) -> None:
    plan = json.loads((hall_small["a"] / "plan.json").read_text())
    expected = json.loads((scenes_dir / "hall-small" / "expected.json").read_text())
    assert plan["totals"]["faces"] == expected["faces"]
    assert plan["totals"]["max_achievable_area_m2"] == pytest.approx(
        expected["max_achievable_area_m2"], rel=1e-3)
    stations = [s["candidate_index"] for s in plan["stations"]]
    assert stations == expected["goal_0.8"]["weighted_greedy"]["stations"]
    assert plan["curve"]["greedy"] == expected["coverage_curve"]["greedy"]
    assert plan["parameters"]["method"] == "weighted_greedy"
    assert plan["rays"] == {"kernels": KERNELS, "exact": True}
    assert plan["candidates"]["count"] == expected["candidates"]
    first = plan["stations"][0]
    assert set(first) >= {"candidate_index", "position", "new_area_m2", "covered_area_m2",
                          "coverage_fraction"}


def test_faces_npz_agrees_with_plan(hall_small: dict[str, Path]) -> None:
    plan = json.loads((hall_small["a"] / "plan.json").read_text())
    with np.load(hall_small["a"] / "faces.npz") as faces:
        assert faces["covered"].dtype == bool
        assert faces["best_lpd_pts_m2"].dtype == np.float32
        assert len(faces["covered"]) == plan["totals"]["faces"]
        assert faces["first_station"].max() == len(plan["stations"]) - 1
        assert ((faces["n_candidates"] > 0) | ~faces["covered"]).all()


def test_stations_csv(hall_small: dict[str, Path]) -> None:
    lines = (hall_small["a"] / "stations.csv").read_text().splitlines()
    assert lines[0] == "id,x,y,z,order,candidate_index,visit"
    assert len(lines) == 1 + len(json.loads((hall_small["a"] / "plan.json").read_text())[
        "stations"])


def test_same_input_same_bytes(hall_small: dict[str, Path]) -> None:
    names = sorted(p.name for p in hall_small["a"].iterdir())
    assert names == sorted(p.name for p in hall_small["b"].iterdir())
    for name in names:
        assert (hall_small["a"] / name).read_bytes() == (hall_small["b"] / name).read_bytes(), name


def test_errors_are_one_line_naming_the_parameter(tmp_path: Path, scenes_dir: Path) -> None:
    params = tmp_path / "p.json"
    params.write_text(json.dumps({"dof_min_m": -1}))
    done = scanplan("plan", str(scenes_dir / "hall-small" / "hall.obj"), "--params",
                    str(params), "--out", str(tmp_path / "out"))
    assert done.returncode == 2
    assert done.stderr.count("\n") == 1
    assert done.stderr.startswith("scanplan: error: dof_min_m: -1.0 is negative")
    assert not (tmp_path / "out").exists()


def test_unreadable_model_is_one_line(tmp_path: Path) -> None:
    model = tmp_path / "model.obj"
    model.write_bytes(b"\x00\x01binary junk" * 100)
    done = scanplan("plan", str(model), "--out", str(tmp_path / "out"))
    assert done.returncode == 2
    assert "not a model format" in done.stderr
    assert done.stderr.count("\n") == 1


def test_help_imports_no_heavy_library() -> None:
    """``scanplan --help`` lists every subcommand without loading the planner's numerical
    stack or the web stack (that is what keeps the command quick to start)."""
    probe = (
        "import sys\n"
        "from planner.__main__ import main\n"
        "try:\n"
        "    main(['--help'])\n"
        "except SystemExit:\n"
        "    pass\n"
        "heavy = {'numpy', 'scipy', 'trimesh', 'numba', 'embreex', 'matplotlib', 'fastapi',\n"
        "         'pydantic', 'pydantic_settings', 'sqlalchemy', 'huey'}\n"
        "print(sorted(heavy & {name.split('.')[0] for name in sys.modules}), file=sys.stderr)\n"
    )
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                          timeout=60, check=False)
    assert "serve" in done.stdout and "plan" in done.stdout
    assert done.stderr.strip() == "[]"


def test_planner_package_exports_load_on_use() -> None:
    import planner

    assert planner.PlanSpec.from_mapping({}).max_edge_m is not None
    assert callable(planner.plan) and callable(planner.read_scene)
    assert {"plan", "read_scene", "write_outputs"} <= set(dir(planner))
    with pytest.raises(AttributeError, match="no_such_name"):
        planner.no_such_name  # noqa: B018


def test_version_is_the_package_s() -> None:
    done = scanplan("--version")
    assert done.returncode == 0
    assert done.stdout.strip() == f"scanplan {metadata.version('scanplan')}"


def test_an_example_is_listed_copied_and_planned_with_the_command_it_prints(
        tmp_path: Path) -> None:
    listed = scanplan("examples")
    assert listed.returncode == 0, listed.stderr
    names = [line.split()[0] for line in listed.stdout.splitlines()[:-2] if line.strip()]
    assert {"hall-small", "ifcopenhouse", "fzk-haus", "amersfoort"} <= set(names)
    copied = subprocess.run([sys.executable, "-m", "planner", "examples", "ifcopenhouse",
                             "--to", "models"], capture_output=True, text=True, timeout=60,
                            cwd=tmp_path, check=False)
    assert copied.returncode == 0, copied.stderr
    assert (tmp_path / "models" / "IfcOpenHouse_IFC4.ifc").is_file()
    command = copied.stdout.splitlines()[-1].split()
    assert command[:2] == ["scanplan", "plan"]
    planned = subprocess.run([sys.executable, "-m", "planner", *command[1:], "--quiet"],
                             capture_output=True, text=True, timeout=300, cwd=tmp_path,
                             check=False)
    assert planned.returncode == 0, planned.stderr
    plan = json.loads((tmp_path / "ifcopenhouse-plan" / "plan.json").read_text())
    assert plan["scanplan_version"] == metadata.version("scanplan")
    assert plan["totals"]["stations"] >= 1 and plan["goal_reached"]


def test_an_unknown_example_is_one_line_naming_the_known_ones(tmp_path: Path) -> None:
    done = scanplan("examples", "no-such-house", "--to", str(tmp_path))
    assert done.returncode == 2
    assert done.stderr.count("\n") == 1 and "hall-small" in done.stderr


def test_a_budget_of_hours_says_its_field_time_and_bound(tmp_path: Path,
                                                         scenes_dir: Path) -> None:
    params = tmp_path / "p.json"
    scanner = {"name": "crew scanner", "measurement_rate_pts_s": 2e6, "overhead_s": 30.0}
    params.write_text(json.dumps({"max_edge_m": None, "scanner": scanner,
                                  "max_field_time_h": 0.2}))
    done = scanplan("plan", str(scenes_dir / "hall-small" / "hall.obj"), "--candidates",
                    str(scenes_dir / "hall-small" / "candidates.csv"), "--params",
                    str(params), "--out", str(tmp_path / "out"))
    assert done.returncode == 0, done.stderr
    spent = json.loads((tmp_path / "out" / "plan.json").read_text())["selection"]["budget"]
    line = next(line for line in done.stdout.splitlines() if line.startswith("budget 0.2 h"))
    assert f"takes {spent['field_time']['plan_field_time_h']:.2f} h" in line
    assert f"one station more {spent['field_time']['one_station_more_field_time_h']:.2f} h" \
        in line
    assert f"covers more than {100 * spent['upper_bound_fraction']:.1f} %" in line
