"""Field time for any scanner: instrument profiles, scan duration from the angular step and
the coarsest setting each station needs (planner.scanners)."""

from __future__ import annotations

import csv
import io
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from planner.candidates.grid import read_candidates_csv
from planner.errors import ParameterError
from planner.io.readers import read_scene
from planner.outputs.report import plan_document, stations_csv
from planner.parameters import PlanSpec
from planner.pipeline import PlanResult, plan
from planner.scanners import (
    ScannerProfile,
    ScanSetting,
    coarsest_setting,
    presets,
    scan_duration_s,
)

# --- the duration model ----------------------------------------------------------------


def test_scan_duration_is_the_documented_formula_by_hand() -> None:
    # 1 mrad over 360 deg x 150 deg (-60 to 90): 6283.185 columns x 2617.994 rows
    # = 16 449 340.7 points; at 2 000 000 points/s 8.2247 s, plus 30 s overhead
    profile = ScannerProfile(name="hand", measurement_rate_pts_s=2e6, overhead_s=30.0)
    assert scan_duration_s(profile, 0.001, -60.0, 90.0) == pytest.approx(38.2247, abs=1e-4)
    # twice the step: a quarter of the points
    assert scan_duration_s(profile, 0.002, -60.0, 90.0) == pytest.approx(
        30.0 + 8.2247 / 4, abs=1e-4)
    # a setting's own duration wins over points / rate; the overhead is still added
    timed = ScanSetting("timed", 0.01, 10.0, duration_s=100.0)
    assert scan_duration_s(profile, 0.001, -60.0, 90.0, timed) == 130.0
    # no rate and no duration: unknown
    assert scan_duration_s(ScannerProfile(name="bare"), 0.001, -60.0, 90.0) is None


# --- profiles: validation and precedence ------------------------------------------------


@pytest.mark.parametrize(("scanner", "field"), [
    ({"name": "x", "measurement_rate_pts_s": 0}, "scanner.measurement_rate_pts_s"),
    ({"name": "x", "overhead_s": -1}, "scanner.overhead_s"),
    ({"name": "x", "setup_time_s": -5}, "scanner.setup_time_s"),
    ({"name": "x", "min_range_m": -1}, "scanner.min_range_m"),
    ({"name": "x", "max_range_m": 0}, "scanner.max_range_m"),
    ({"name": "x", "elevation_min_deg": -100}, "scanner.elevation_min_deg"),
    ({"name": "x", "elevation_max_deg": 91}, "scanner.elevation_max_deg"),
    ({"name": "x", "min_range_m": 5, "max_range_m": 2}, "scanner.min_range_m"),
    ({"name": "x", "elevation_min_deg": 10, "elevation_max_deg": 0}, "scanner.elevation_min_deg"),
    ({"name": "x", "speed": 3}, "scanner.speed"),
    ({"measurement_rate_pts_s": 1e6}, "scanner.name"),
    ({"name": ""}, "scanner.name"),
    ({"name": "x", "preset": "leica-x"}, "scanner.preset"),
    ({"name": "x", "measurement_rate_pts_s": "fast"}, "scanner.measurement_rate_pts_s"),
    ({"name": "x", "settings": {"fine": 1}}, "scanner.settings"),
    ({"name": "x", "settings": [{"name": "a", "point_spacing_m": 0.01}]},
     "scanner.settings[0].reference_distance_m"),
    ({"name": "x", "settings": [{"name": "a", "point_spacing_m": 0,
                                 "reference_distance_m": 10}]},
     "scanner.settings[0].point_spacing_m"),
    ({"name": "x", "settings": [{"name": "a", "point_spacing_m": 0.01,
                                 "reference_distance_m": 10, "duration_s": 0}]},
     "scanner.settings[0].duration_s"),
    ({"name": "x", "settings": [{"name": "a", "point_spacing_m": 0.01,
                                 "reference_distance_m": 10, "time": 5}]},
     "scanner.settings[0].time"),
    ({"name": "x", "settings": [
        {"name": "a", "point_spacing_m": 0.01, "reference_distance_m": 10},
        {"name": "a", "point_spacing_m": 0.02, "reference_distance_m": 10}]}, "scanner.settings"),
    ({"name": "x", "settings": [{"name": "a", "point_spacing_m": 1e-300,
                                 "reference_distance_m": 10_000}]},
     "scanner.settings[0].point_spacing_m"),
    (42, "scanner"),
    ("leica-x", "scanner"),
])
def test_every_profile_field_is_checked_and_named(scanner: Any, field: str) -> None:
    with pytest.raises(ParameterError) as caught:
        PlanSpec.from_mapping({"scanner": scanner})
    assert caught.value.parameter == field
    assert "\n" not in str(caught.value)


def test_a_step_finer_than_the_finest_setting_is_refused_naming_point_spacing() -> None:
    profile = {"name": "x", "settings": [
        {"name": "6 mm", "point_spacing_m": 0.006, "reference_distance_m": 10}]}
    with pytest.raises(ParameterError, match=r"^point_spacing_m: .*finer than the finest setting"):
        PlanSpec.from_mapping({"scanner": profile, "point_spacing_m": 0.003})


def test_explicit_parameter_wins_over_the_profile_which_wins_over_its_preset() -> None:
    # the Z+F preset states 360 m and a field from -70 deg (planner/scanners.json)
    based = {"name": "our 5016", "preset": "zf-imager-5016", "max_range_m": 120,
             "measurement_rate_pts_s": 1e6, "setup_time_s": 90,
             "settings": [{"name": "fine", "point_spacing_m": 0.003, "reference_distance_m": 10},
                          {"name": "coarse", "point_spacing_m": 0.012,
                           "reference_distance_m": 10}]}
    spec = PlanSpec.from_mapping({"scanner": based})
    assert spec.dof_max_m == 120.0  # the profile over the preset
    assert spec.elevation_min_deg == -70.0  # the preset fills what the profile leaves out
    # the step stays the plan's: a setting (3 mm) is at least as fine as the default
    assert (spec.point_spacing_m, spec.reference_distance_m) == (0.010, 10.0)
    assert spec.setup_time_s == 90.0
    explicit = PlanSpec.from_mapping({"scanner": based, "dof_max_m": 40.0,
                                      "point_spacing_m": 0.006, "setup_time_s": 30})
    assert (explicit.dof_max_m, explicit.point_spacing_m, explicit.setup_time_s) == (
        40.0, 0.006, 30.0)
    # plan.json keeps the object, and reading it back gives the same plan
    again = PlanSpec.from_mapping(json.loads(json.dumps(explicit.to_dict())))
    assert again == explicit


def test_every_preset_figure_has_a_source_a_reader_can_open_or_a_reason() -> None:
    text = Path(__file__).parents[2].joinpath("planner", "scanners.json").read_text()
    data = json.loads(text)
    assert "helios" in data["searched"].lower()  # where we looked
    for entry in data["scanners"]:
        figures = [v for v in entry.values() if isinstance(v, dict) and "value" in v]
        for figure in figures:
            if figure["value"] is None:
                assert figure["reason"]
                continue
            for key in (figure["source"], *figure.get("also", ())):
                source = data["sources"][key]
                assert source["verified"] is True and source["quote"]
                assert source["url"] or source["corpus_file"]
        assert entry["settings"]["values"] or entry["settings"]["reason"]
    # the simulator-sourced preset gives a measurement rate, so its field time is known
    vz400 = presets()["riegl-vz-400"].profile
    assert vz400.measurement_rate_pts_s == 125_000.0 and vz400.min_range_m == 1.5


# --- the coarsest setting per station on hall-full --------------------------------------

SETTINGS = [
    {"name": "6 mm", "point_spacing_m": 0.006, "reference_distance_m": 10.0},
    {"name": "10 mm", "point_spacing_m": 0.010, "reference_distance_m": 10.0},
    {"name": "20 mm", "point_spacing_m": 0.020, "reference_distance_m": 10.0},
]
FINEST_STEP_RAD = 0.0006
PROFILE = {"name": "crew scanner", "measurement_rate_pts_s": 2e6, "elevation_min_deg": -60.0,
           "elevation_max_deg": 90.0, "settings": SETTINGS, "overhead_s": 30.0}


def _hall_spec(scenes_dir: Path, name: str, **more: Any) -> tuple[Any, PlanSpec]:
    folder = scenes_dir / name
    scene = read_scene(folder / "hall.obj", max_edge_m=None)
    candidates = read_candidates_csv(folder / "candidates.csv")
    spec = PlanSpec.from_mapping({"candidates": candidates.tolist(), "max_edge_m": None, **more})
    return scene, spec


@pytest.fixture(scope="module")
def hall_full(scenes_dir: Path) -> PlanResult:
    # the check: the default goal (0.8) and the plan's own (default) step
    scene, spec = _hall_spec(scenes_dir, "hall-full", scanner=PROFILE)
    return plan(scene, spec)


def _hand_duration_s(step_rad: float) -> float:
    points = (2 * math.pi / step_rad) * (math.radians(150.0) / step_rad)
    return points / 2e6 + 30.0


def _lpd(result: PlanResult, station: int, faces: np.ndarray, step_rad: float) -> np.ndarray:
    """The paper's LPD = sin(alpha) / (SPS d)^2 at the face centroids, in float64."""
    position = result.candidates.positions[station]
    ray = result.scene.centroids[faces] - position
    d = np.linalg.norm(ray, axis=1)
    sin_alpha = np.abs(np.einsum("ij,ij->i", ray, result.scene.normals[faces])) / d
    return np.asarray(sin_alpha / (step_rad * d) ** 2)


def test_field_time_is_the_sum_of_the_formula_over_the_stations_settings(
        hall_full: PlanResult, scenes_dir: Path) -> None:
    document = plan_document(hall_full)
    stations = document["stations"]
    step_of = {s["name"]: s["point_spacing_m"] / s["reference_distance_m"] for s in SETTINGS}
    by_hand = sum(_hand_duration_s(step_of[s["setting"]]) for s in stations)
    assert document["field_time"]["scan_s"] == pytest.approx(by_hand, rel=0.01)
    assert "scan_unknown_reason" not in document["field_time"]
    for station in stations:
        assert station["scan_s"] == pytest.approx(_hand_duration_s(step_of[station["setting"]]),
                                                  abs=0.06)
    total = document["field_time"]
    assert total["total_s"] == pytest.approx(total["setup_s"] + total["scan_s"] + total["walk_s"],
                                             abs=0.2)
    # cheaper than scanning every station at the finest step
    assert total["scan_s"] < len(stations) * _hand_duration_s(FINEST_STEP_RAD) - 1.0
    # the plan keeps the paper's step: its stations are the paper's (expected.json)
    assert (document["parameters"]["point_spacing_m"],
            document["parameters"]["reference_distance_m"]) == (0.010, 10.0)
    assert "step_note" not in document["field_time"]
    expected = json.loads((scenes_dir / "hall-full" / "expected.json").read_text())
    assert [s["candidate_index"] for s in stations] == (
        expected["goal_0.8"]["greedy"]["stations"])
    # stations.csv carries the same setting and seconds
    rows = list(csv.DictReader(io.StringIO(stations_csv(hall_full).decode())))
    assert [r["setting"] for r in rows] == [s["setting"] for s in stations]
    assert [float(r["scan_s"]) for r in rows] == pytest.approx([s["scan_s"] for s in stations],
                                                               abs=0.06)


def test_each_station_is_scanned_at_the_coarsest_setting_its_credited_faces_allow(
        hall_full: PlanResult) -> None:
    result = hall_full
    required = result.spec.min_density_pts_m2
    steps = sorted(s["point_spacing_m"] / s["reference_distance_m"] for s in SETTINGS)
    names = {s["point_spacing_m"] / s["reference_distance_m"]: s["name"] for s in SETTINGS}
    covered: set[int] = set()
    chosen_steps = []
    for station in result.chosen.stations:
        # credited: the faces this station covers that no earlier station covered
        faces = np.asarray(sorted(set(result.table.faces_of(station).tolist()) - covered))
        covered |= set(faces.tolist())
        qualifying = [step for step in steps
                      if (_lpd(result, station, faces, step) >= required * (1 - 1e-6)).all()]
        assert qualifying, "the finest setting qualifies every credited face by construction"
        chosen_steps.append(max(qualifying))
    assert [names[s] for s in chosen_steps] == [s["setting"] for s in
                                                 plan_document(result)["stations"]]
    assert max(chosen_steps) > steps[0]  # not every station needs the finest setting


def test_the_coarsest_qualifying_setting_may_be_finer_than_the_plans_step() -> None:
    # LPD scales with 1 / SPS^2: a setting qualifies when margin * (plan / its step)^2 >= 1
    settings = (ScanSetting("6 mm", 0.006, 10.0), ScanSetting("8 mm", 0.008, 10.0),
                ScanSetting("20 mm", 0.02, 10.0))
    profile = ScannerProfile(name="no 10 mm", settings=settings)

    def name(margin: float) -> str | None:
        chosen = coarsest_setting(profile, 0.001, margin)
        return None if chosen is None else chosen.name

    assert name(1.0) == "8 mm"  # faces at the plan's full reach: the coarsest at least as fine
    assert name(1.0 - 1e-7) == "8 mm"  # a float32 density a hair under the requirement
    assert name(0.5) == "6 mm"  # (10/8)^2 = 1.5625 is too little, (10/6)^2 = 2.78 enough
    assert name(3.99) == "8 mm" and name(4.0) == "20 mm"
    assert name(math.inf) == "20 mm"  # no credited face needs a density
    assert coarsest_setting(ScannerProfile(name="bare"), 0.001, 1.0) is None


def test_settings_all_coarser_than_the_default_step_set_the_plans_step_and_say_so(
        scenes_dir: Path) -> None:
    coarse = [{"name": "12 mm", "point_spacing_m": 0.012, "reference_distance_m": 10.0},
              {"name": "24 mm", "point_spacing_m": 0.024, "reference_distance_m": 10.0}]
    profile = {**PROFILE, "settings": coarse}
    # an explicit step wins, coarser or between the settings; finer than all is refused
    explicit = PlanSpec.from_mapping({"scanner": profile, "point_spacing_m": 0.015})
    assert (explicit.point_spacing_m, explicit.reference_distance_m) == (0.015, 10.0)
    with pytest.raises(ParameterError, match=r"^point_spacing_m: .*finer than the finest"):
        PlanSpec.from_mapping({"scanner": profile, "point_spacing_m": 0.010})
    # left out: no setting keeps the default 10 mm, so the plan takes the finest, 12 mm
    scene, spec = _hall_spec(scenes_dir, "hall-small", scanner=profile)
    assert (spec.point_spacing_m, spec.reference_distance_m) == (0.012, 10.0)
    document = plan_document(plan(scene, spec))
    assert document["parameters"]["point_spacing_m"] == 0.012
    note = document["field_time"]["step_note"]
    assert "as fine as the default step" in note and "12 mm" in note
    assert [s["setting"] for s in document["stations"]] == ["12 mm"] * len(document["stations"])
    # plan.json read back gives the same plan (the step now explicit, the same step)
    assert PlanSpec.from_mapping(document["parameters"]) == spec


def test_without_durations_the_reason_names_the_missing_figure_and_field(
        scenes_dir: Path) -> None:
    scene, spec = _hall_spec(scenes_dir, "hall-small", scanner={
        "name": "no rate", "settings": SETTINGS[:2]})
    document = plan_document(plan(scene, spec))
    field_time = document["field_time"]
    assert field_time["scan_s"] is None and field_time["total_s"] is None
    assert field_time["scanner"] == "no rate"
    assert "measurement_rate_pts_s" in field_time["scan_unknown_reason"]
    assert "scanner.settings[].duration_s" in field_time["scan_unknown_reason"]
    assert all(s["scan_s"] is None and s["setting"] in ("6 mm", "10 mm")
               for s in document["stations"])


def test_without_settings_every_station_uses_the_plans_step(scenes_dir: Path) -> None:
    scene, spec = _hall_spec(scenes_dir, "hall-small", scanner="riegl-vz-400",
                             elevation_min_deg=-60.0, elevation_max_deg=90.0, dof_min_m=1.5)
    document = plan_document(plan(scene, spec))
    one = (2 * math.pi / 0.001) * (math.radians(150.0) / 0.001) / 125_000.0
    assert [s["setting"] for s in document["stations"]] == [None] * len(document["stations"])
    assert document["field_time"]["scan_s"] == pytest.approx(one * len(document["stations"]),
                                                             abs=0.1)
    assert document["field_time"]["scanner"] == "riegl-vz-400"


def test_preview_lists_each_stations_setting_and_scan_time(hall_full: PlanResult) -> None:
    from planner.outputs.drawing import draw_preview

    texts = "\n".join(t.get_text() for t in draw_preview(hall_full).figure.texts)
    table = texts[texts.index("no.      x"):].splitlines()
    assert table[0].split()[-2:] == ["setting", "scan"]
    assert hall_full.survey is not None
    for row, scan in zip(table[1:15], hall_full.survey.scans, strict=False):
        assert row.split()[-3:] == [*(scan.setting or "").split(), f"{scan.scan_s:.0f}s"]
    assert "crew scanner: scans" in texts
    # the table's title: the plan's stations and the fewest any plan of its goal needs
    n = len(hall_full.chosen.stations)
    lower = hall_full.selection_report["lower_bound"]
    title = f"{n} stations, at least {lower} needed" if lower < n else f"{n} stations"
    assert title in texts.splitlines()
    assert table[-1].strip() == "x, y, z: model coordinates, m"
