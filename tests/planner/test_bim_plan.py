"""The plan back in the BIM: ``plan.ifc`` and ``plan.bcf`` as a BIM coordinator checks them.

``plan.ifc`` is read back with IfcOpenShell: every entity of the input is still there,
unchanged, ``ifcopenshell.validate`` finds no error the input did not have, each station
is an annotation in the storey its floor is on, at its ``plan.json`` position within 1 mm in
the model's own unit. ``plan.bcf`` validates against buildingSMART's BCF 3.0 XSDs (the
copies in ``shared/standards/bcf-3.0``) and has one topic per station with the camera at
the station. Models: IfcOpenHouse (IFC4, millimetres) and two storeys built here with
IfcOpenShell in IFC2X3 (no rooms: grid on both floors) and IFC4X3 (a room per storey).
"""

from __future__ import annotations

import io
import json
import re
import subprocess
import sys
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from planner.io.readers import read_scene
from planner.outputs import bim
from planner.outputs.bcf_plan import STATION_TYPE, UNCOVERABLE_TYPE, plan_bcf
from planner.outputs.ifc_plan import COVERAGE_PSET, OBJECT_TYPE, STATION_PSET, plan_ifc
from planner.outputs.report import absent_outputs, write_outputs
from planner.parameters import PlanSpec
from planner.pipeline import PlanResult, plan
from tests.data_files import BCF_XSD
from tests.planner.ifc_parts import body_and_building, placed

ifcopenshell = pytest.importorskip("ifcopenshell")
xmlschema = pytest.importorskip("xmlschema")

HOUSE = "IfcOpenHouse_IFC4.ifc"
MM = 0.001  # the plan.json positions are rounded to the micrometre; 1 mm is the contract


def _two_storeys(schema: str, path: Path, rooms: bool) -> None:
    """Two storeys of a 6 x 4 m room in millimetres (elevations 0 and 3 m): floor slabs,
    four walls each, a roof; with ``rooms`` an IfcSpace per storey."""
    from ifcopenshell.api import aggregate, geometry, owner, project, root, spatial, unit

    model = project.create_file(version=schema)  # IFC4X3: IFC4X3_ADD2
    if schema == "IFC2X3":  # every rooted entity needs an owner history there
        owner.add_person_and_organisation(
            model, person=owner.add_person(model), organisation=owner.add_organisation(model))
        owner.add_application(model)  # the API's default settings pick these two up
    ifc_project = root.create_entity(model, ifc_class="IfcProject", name="two storeys")
    unit.assign_unit(model, units=[
        unit.add_si_unit(model, unit_type="LENGTHUNIT", prefix="MILLI"),
        unit.add_si_unit(model, unit_type="AREAUNIT")])
    body, building = body_and_building(model, ifc_project)

    outline = [(0.0, 0.0), (6.0, 0.0), (6.0, 4.0), (0.0, 4.0)]
    for level, (name, z) in enumerate([("Ground", 0.0), ("Upper", 3.0)]):
        storey = root.create_entity(model, ifc_class="IfcBuildingStorey", name=name)
        storey.Elevation = z * 1000.0
        aggregate.assign_object(model, relating_object=building, products=[storey])
        parts = [placed(model, "IfcSlab", f"{name} floor", geometry.add_slab_representation(
            model, body, depth=0.2, polyline=outline), (0, 0, z - 0.2))]
        if level == 1:
            parts.append(placed(model, "IfcSlab", "Roof", geometry.add_slab_representation(
                model, body, depth=0.2, polyline=outline), (0, 0, z + 2.8)))
        for wall, length, x, y, turn in [("S", 6.0, 0, 0, 0.0), ("E", 4.0, 6, 0, 0.5),
                                         ("N", 6.0, 6, 4, 1.0), ("W", 4.0, 0, 4, 1.5)]:
            wall_body = geometry.add_wall_representation(
                model, body, length=length, height=2.8, thickness=0.2)
            parts.append(placed(model, "IfcWall", f"{name} {wall}", wall_body, (x, y, z),
                                turn * np.pi))
        spatial.assign_container(model, relating_structure=storey, products=parts)
        if rooms:
            space = placed(model, "IfcSpace", f"{level}01", geometry.add_slab_representation(
                model, body, depth=2.6, polyline=[(0.2, 0.2), (5.8, 0.2), (5.8, 3.8),
                                                  (0.2, 3.8)]), (0, 0, z))
            aggregate.assign_object(model, relating_object=storey, products=[space])
    model.write(str(path))


def _plan(path: Path, **parameters: Any) -> PlanResult:
    spec = PlanSpec.from_mapping({"grid_spacing_m": 1.0, **parameters})
    scene = read_scene(path, max_edge_m=spec.max_edge_m, split_faces="as_needed")
    return plan(scene, spec, threads=1)


@pytest.fixture(scope="module", params=["IFC2X3", "IFC4X3_ADD2", "IFC4-house"])
def planned(request: pytest.FixtureRequest, scenes_dir: Path,
            tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, PlanResult]:
    if request.param == "IFC4-house":
        path = scenes_dir / HOUSE
        return path, _plan(path)
    path = tmp_path_factory.mktemp(request.param) / "two-storeys.ifc"
    rooms = request.param == "IFC4X3_ADD2"
    _two_storeys(request.param, path, rooms=rooms)
    # without rooms the grid stands on every floor; the rooms' grid is a little finer
    return path, _plan(path, **({"grid_spacing_m": 0.8} if rooms else {"floor_levels": "all"}))


@pytest.fixture(scope="module")
def written(planned: tuple[Path, PlanResult], tmp_path_factory: pytest.TempPathFactory
            ) -> dict[str, Path]:
    out = tmp_path_factory.mktemp("out")
    return {p.name: p for p in write_outputs(planned[1], out)}


def _errors(model: Any, express_rules: bool) -> set[tuple[str, str, str]]:
    """(kind, rule or attribute, STEP id) of every error ``ifcopenshell.validate`` finds
    (the messages themselves carry memory addresses, so they are not compared)."""
    import ifcopenshell.validate

    logger = ifcopenshell.validate.json_logger()
    ifcopenshell.validate.validate(model, logger, express_rules=express_rules)
    out = set()
    for statement in logger.statements:
        instance = re.match(r"#\d+", str(statement.get("instance", "")))
        out.add((str(statement.get("type")), str(statement.get("attribute")),
                 instance.group(0) if instance else str(statement.get("message"))))
    return out


def _elevation_m(storey: Any, scale: float) -> float:
    import ifcopenshell.util.placement

    if storey.Elevation is not None:
        return float(storey.Elevation) * scale
    return float(ifcopenshell.util.placement.get_local_placement(storey.ObjectPlacement)[2, 3]
                 ) * scale


# plan.ifc ----------------------------------------------------------------------------------


def test_plan_ifc_is_the_input_unchanged_plus_the_stations(
        planned: tuple[Path, PlanResult], written: dict[str, Path]) -> None:
    import ifcopenshell.util.element
    import ifcopenshell.util.placement
    import ifcopenshell.util.unit

    path, result = planned
    before = ifcopenshell.open(str(path))
    after = ifcopenshell.open(str(written["plan.ifc"]))
    assert after.schema == before.schema
    for entity in before:  # same STEP id, same attributes, same GlobalId
        assert str(after.by_id(entity.id())) == str(entity)
    # the schema's rules (where rules, functions) too on the IFC2X3 building: they cost
    # some 5 s of CPU a file and schema
    express_rules = before.schema == "IFC2X3"
    assert _errors(after, express_rules) <= _errors(before, express_rules)
    scale = float(ifcopenshell.util.unit.calculate_unit_scale(after))
    document = json.loads(written["plan.json"].read_text("utf-8"))
    annotations = {a.Name: a for a in after.by_type("IfcAnnotation")
                   if not _has_guid(before, a.GlobalId)}
    assert len(annotations) == len(document["stations"]) > 0
    storeys = before.by_type("IfcBuildingStorey")
    for station in document["stations"]:
        annotation = annotations[f"Station {station['id']}"]
        if after.schema.startswith("IFC4X3"):
            assert annotation.PredefinedType == "SURVEY"
        else:
            assert annotation.ObjectType == OBJECT_TYPE
        at = ifcopenshell.util.placement.get_local_placement(annotation.ObjectPlacement)[:3, 3]
        np.testing.assert_allclose(at * scale, station["position"], atol=MM)
        (representation,) = annotation.Representation.Representations
        assert representation.RepresentationType == "Point"
        assert representation.Items[0].is_a("IfcCartesianPoint")
        (container,) = annotation.ContainedInStructure
        storey = container.RelatingStructure
        assert storey.is_a("IfcBuildingStorey")
        floor = station["position"][2] - result.spec.scanner_height_m
        # the storey whose elevation is the floor's: none other is nearer
        nearest = min(storeys, key=lambda s: abs(_elevation_m(s, scale) - floor))
        assert storey == after.by_id(nearest.id())
        properties = ifcopenshell.util.element.get_psets(annotation)[STATION_PSET]
        assert properties["StationId"] == station["id"]
        assert properties.get("VisitOrder") == station.get("visit")
        assert properties["InstrumentHeight"] * scale == pytest.approx(
            result.spec.scanner_height_m)
        assert properties["NewArea"] == pytest.approx(station["new_area_m2"], abs=1e-6)
        edges = document["registration"]["edges"]
        neighbours = sorted({e["b"] for e in edges if e["ok"] and e["a"] == station["id"]}
                            | {e["a"] for e in edges if e["ok"] and e["b"] == station["id"]})
        assert properties["RegistrationNeighbours"] == ", ".join(map(str, neighbours))
        room = station.get("label", {}).get("room_global_id")
        referenced = [r.RelatingStructure.GlobalId for r in after.by_type(
            "IfcRelReferencedInSpatialStructure") if annotation in r.RelatedElements]
        assert referenced == ([room] if room else referenced)
        if room:
            assert after.by_guid(room).Decomposes[0].RelatingObject == storey


def _has_guid(model: Any, global_id: str) -> bool:
    try:
        model.by_guid(global_id)
    except RuntimeError:
        return False
    return True


def test_every_reported_element_carries_its_coverage(
        planned: tuple[Path, PlanResult], written: dict[str, Path]) -> None:
    import ifcopenshell.util.element
    import ifcopenshell.util.unit

    after = ifcopenshell.open(str(written["plan.ifc"]))
    area_scale = float(ifcopenshell.util.unit.calculate_unit_scale(after, "AREAUNIT"))
    rows = bim.element_rows(planned[1])
    assert rows
    for row in rows:
        properties = ifcopenshell.util.element.get_psets(after.by_guid(row["global_id"]))[
            COVERAGE_PSET]
        assert properties["CoveredArea"] * area_scale == pytest.approx(row["covered_area_m2"])
        assert properties["TargetArea"] * area_scale == pytest.approx(row["target_area_m2"])
        assert properties.get("CoveredFraction") == (
            None if row["fraction"] is None else pytest.approx(row["fraction"]))
        assert properties.get("UncoverableReason") == row["uncoverable_reason"]


def test_plan_ifc_and_plan_bcf_are_the_same_bytes_every_time(
        planned: tuple[Path, PlanResult], written: dict[str, Path]) -> None:
    result = planned[1]
    assert plan_ifc(result) == written["plan.ifc"].read_bytes()
    assert plan_bcf(result) == written["plan.bcf"].read_bytes()
    text = written["plan.ifc"].read_text("utf-8")
    assert "FILE_NAME('plan.ifc','1970-01-01T00:00:00'" in text


# plan.bcf ----------------------------------------------------------------------------------


def _validate_bcf(data: bytes) -> dict[str, bytes]:
    schemas = {name: xmlschema.XMLSchema(str(BCF_XSD / name)) for name in (
        "version.xsd", "project.xsd", "extensions.xsd", "markup.xsd", "visinfo.xsd")}
    by_file = {"bcf.version": "version.xsd", "project.bcfp": "project.xsd",
               "extensions.xml": "extensions.xsd"}
    archive = zipfile.ZipFile(io.BytesIO(data))
    members = {name: archive.read(name) for name in archive.namelist()}
    for name, content in members.items():
        schema = by_file.get(name) or ("markup.xsd" if name.endswith(".bcf") else
                                       "visinfo.xsd" if name.endswith(".bcfv") else None)
        assert schema is not None, name
        schemas[schema].validate(content.decode("utf-8"))
    assert b'VersionId="3.0"' in members["bcf.version"]
    return members


def _topics(members: dict[str, bytes]) -> list[tuple[Any, Any]]:
    from bcf.v3 import model
    from bcf.xml_parser import XmlParserSerializer

    xml = XmlParserSerializer()
    out = []
    for name in sorted(members):
        if name.endswith("/markup.bcf"):
            markup = xml.parse(members[name], model.Markup)
            (point,) = markup.topic.viewpoints.view_point
            folder = name.rsplit("/", 1)[0]
            view = xml.parse(members[f"{folder}/{point.viewpoint}"], model.VisualizationInfo)
            out.append((markup.topic, view))
    return out


def test_plan_bcf_has_a_topic_per_station_with_the_camera_at_it(
        planned: tuple[Path, PlanResult], written: dict[str, Path]) -> None:
    members = _validate_bcf(written["plan.bcf"].read_bytes())
    document = json.loads(written["plan.json"].read_text("utf-8"))
    after = ifcopenshell.open(str(written["plan.ifc"]))
    stations = {t.title: (t, v) for t, v in _topics(members) if t.topic_type == STATION_TYPE}
    assert len(stations) == len(document["stations"])
    from bcf.v3 import model
    from bcf.xml_parser import XmlParserSerializer

    (project,) = after.by_type("IfcProject")
    for name in members:
        if name.endswith("/markup.bcf"):  # every topic is about plan.ifc
            (file,) = XmlParserSerializer().parse(members[name], model.Markup).header.files.file
            assert (file.filename, file.ifc_project) == ("plan.ifc", project.GlobalId)
    position = {s["id"]: np.asarray(s["position"]) for s in document["stations"]}
    legs = {leg["from"]: leg for leg in document["route"]["legs"]}
    for station in document["stations"]:
        topic, view = stations[f"Station {station['id']}"]
        visit = station.get("visit")
        assert (f"Visit: {visit} " if visit else "Visit: not reachable") in topic.description
        camera = view.perspective_camera
        eye = [camera.camera_view_point.x, camera.camera_view_point.y,
               camera.camera_view_point.z]
        np.testing.assert_allclose(eye, station["position"], atol=MM)
        direction = np.array([camera.camera_direction.x, camera.camera_direction.y,
                              camera.camera_direction.z])
        assert np.linalg.norm(direction) == pytest.approx(1.0, abs=1e-5)
        assert direction[2] == pytest.approx(0.0, abs=1e-6)  # looks level, at instrument height
        ahead = legs.get(station["id"])
        if ahead is not None:  # along the next leg: to its first point a step away
            points = [np.asarray(p) for p in ahead["path"]] + [position[ahead["to"]]]
            steps = [p - position[station["id"]] for p in points]
            step = next(d for d in steps if np.hypot(d[0], d[1]) >= 0.01)
            np.testing.assert_allclose(direction[:2], step[:2] / np.hypot(step[0], step[1]),
                                       atol=1e-5)
        (component,) = view.components.selection.component
        assert after.by_guid(component.ifc_guid).Name == f"Station {station['id']}"
        assert view.components.visibility.default_visibility is True


def test_each_uncoverable_element_is_a_topic_with_its_reason_and_guid(
        planned: tuple[Path, PlanResult], written: dict[str, Path]) -> None:
    path, result = planned
    rows = [r for r in bim.element_rows(result) if r["uncoverable_reason"] is not None]
    if path.name == HOUSE:
        assert rows, "IfcOpenHouse has elements no candidate covers"
    candidates = np.array([[float(v) for v in line.split(",")] for line in
                           written["candidates.csv"].read_text().splitlines()[1:]])
    by_guid = {}
    for topic, view in _topics(_validate_bcf(written["plan.bcf"].read_bytes())):
        if topic.topic_type == UNCOVERABLE_TYPE:
            (component,) = view.components.selection.component
            by_guid[component.ifc_guid] = (topic, view)
    assert set(by_guid) == {r["global_id"] for r in rows}
    for row in rows:
        topic, view = by_guid[row["global_id"]]
        assert row["uncoverable_reason"] in topic.description
        camera = view.perspective_camera.camera_view_point
        # seen from where a tripod could stand: the nearest candidate
        assert np.linalg.norm(candidates - [camera.x, camera.y, camera.z], axis=1).min() < MM


def test_a_mesh_plan_has_a_bcf_and_says_why_it_has_no_ifc(tmp_path: Path) -> None:
    from tests.planner.scenes import scene_of, square

    walls = [square((x, y, 1.5), 3.0, axis) for x, y, axis in
             [(1.5, 0, 1), (1.5, 3, 1), (0, 1.5, 0), (3, 1.5, 0)]]
    scene = scene_of(*walls, square((1.5, 1.5, 0.0), 3.0, 2), square((1.5, 1.5, 3.0), 3.0, 2))
    scene.metadata["format"] = "obj"
    result = plan(scene, PlanSpec(candidates=[[1.5, 1.5, 1.5]], dof_min_m=0.5,
                                  min_density_pts_m2=1000.0))
    names = {p.name for p in write_outputs(result, tmp_path)}
    assert "plan.bcf" in names and "plan.ifc" not in names
    assert "OBJ" in absent_outputs(result)["plan.ifc"]
    members = _validate_bcf((tmp_path / "plan.bcf").read_bytes())
    ((topic, view),) = _topics(members)
    assert topic.title == "Station 1" and view.components.selection is None
    np.testing.assert_allclose([view.perspective_camera.camera_view_point.x,
                                view.perspective_camera.camera_view_point.y,
                                view.perspective_camera.camera_view_point.z],
                               [1.5, 1.5, 1.5], atol=MM)


def test_the_cli_writes_both_and_names_the_missing_one(tmp_path: Path) -> None:
    obj = tmp_path / "room.obj"
    corners = [(0, 0, 0), (4, 0, 0), (4, 3, 0), (0, 3, 0), (0, 0, 3), (4, 0, 3), (4, 3, 3),
               (0, 3, 3)]
    quads = [(1, 2, 3, 4), (5, 8, 7, 6), (1, 5, 6, 2), (2, 6, 7, 3), (3, 7, 8, 4), (4, 8, 5, 1)]
    obj.write_text("".join(f"v {x} {y} {z}\n" for x, y, z in corners) + "".join(
        f"f {a} {b} {c}\nf {a} {c} {d}\n" for a, b, c, d in quads))
    params = tmp_path / "params.json"
    params.write_text(json.dumps({"candidates": [[2, 1.5, 1.5]], "dof_min_m": 0.5}))
    run = subprocess.run([sys.executable, "-m", "planner", "plan", str(obj), "--params",
                          str(params), "--out", str(tmp_path / "out")],
                         capture_output=True, text=True, check=True)
    assert "plan.bcf" in run.stdout
    assert re.search(r"^no plan\.ifc: .*OBJ", run.stdout, re.MULTILINE)
    assert (tmp_path / "out" / "plan.bcf").is_file()
    assert not (tmp_path / "out" / "plan.ifc").exists()
