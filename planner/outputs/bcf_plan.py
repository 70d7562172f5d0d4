"""``plan.bcf``: the plan as BCF 3.0 topics a BIM coordinator opens in any BCF viewer.

Written for every input (mesh or IFC) with the data model of IfcOpenShell's BCF library
(``bcf-client``: classes generated from buildingSMART's BCF-XML 3.0 schemas, serialised by
xsdata); the zip is assembled here so that its entries carry a fixed date. Contents:

- ``bcf.version`` (3.0), ``project.bcfp`` (the project id is the plan's UUID namespace,
  see :mod:`planner.outputs.stations`), ``extensions.xml`` (the topic types, statuses and
  labels used); for an IFC model each topic's header names ``plan.ifc`` and its
  IfcProject;
- one topic per station (type :data:`STATION_TYPE`, title ``Station <id>``, its visit,
  storey, room, areas and registration neighbours in the description) with one
  perspective viewpoint: the eye at the station, i.e. the scanner's axis at instrument
  height, looking horizontally along the route's next leg (the last station along the leg
  that reached it), up the model's up; for an IFC model the station's ``IfcAnnotation`` of
  ``plan.ifc`` is the selected component;
- one topic per element that cannot be covered from any candidate (type
  :data:`UNCOVERABLE_TYPE`; IFC models, see :mod:`planner.outputs.bim`) with the reason and
  the area per reason, its viewpoint from the nearest candidate looking at the element's
  centre, the element's GlobalId as the selected component.

No snapshots: a picture of a perspective view needs a renderer of the whole model per
station, which costs more than the rest of the file; BCF makes snapshots optional.

Coordinates are metres in the model's own axes (BCF's convention). Topic and viewpoint
GUIDs are name-based UUIDs in the plan's namespace, every date is
:data:`planner.outputs.stations.FIXED_EPOCH`: the same plan gives the same bytes.
"""

from __future__ import annotations

import io
import re
import zipfile
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from planner.io.orientation import scene_rotation, to_model
from planner.outputs import stations as station_facts

if TYPE_CHECKING:
    from planner.pipeline import PlanResult

STATION_TYPE = "Scan station"
UNCOVERABLE_TYPE = "Not coverable"
STATUS = "Open"
AUTHOR = "scanplan"
LABEL = "scanplan"
PROJECT_NAME = "scanplan plan"
FIELD_OF_VIEW_DEG = 60.0  # vertical, a normal lens; BCF allows (0, 180)
ASPECT_RATIO = 16 / 9
_ZIP_DATE = (1980, 1, 1, 0, 0, 0)  # the earliest a zip entry can carry
_IFC_GUID = re.compile(r"[0-9A-Za-z_$]{22}")
_DECIMALS = 6


def plan_bcf(result: PlanResult) -> bytes:
    """``plan.bcf`` bytes (see the module docstring)."""
    from bcf.v3 import model as bcf
    from bcf.xml_parser import XmlParserSerializer
    from xsdata.models.datatype import XmlDateTime

    xml = XmlParserSerializer()
    space = station_facts.namespace(result)
    date = XmlDateTime.from_datetime(station_facts.FIXED_EPOCH)
    is_ifc = result.scene.metadata.get("format") == "ifc"
    header = None
    project = str(result.scene.metadata.get("project_global_id", ""))
    if is_ifc and _IFC_GUID.fullmatch(project):  # the topics are about plan.ifc
        header = bcf.Header(files=bcf.HeaderFiles(file=[bcf.File(
            ifc_project=project, filename="plan.ifc", reference="plan.ifc", is_external=True,
            date=date)]))
    files: list[tuple[str, str]] = [
        ("bcf.version", xml.serialize(bcf.Version(version_id="3.0"))),
        ("project.bcfp", xml.serialize(bcf.ProjectInfo(
            project=bcf.Project(name=PROJECT_NAME, project_id=str(space))))),
        ("extensions.xml", xml.serialize(bcf.Extensions(
            topic_types=bcf.ExtensionsTopicTypes(topic_type=[STATION_TYPE, UNCOVERABLE_TYPE]),
            topic_statuses=bcf.ExtensionsTopicStatuses(topic_status=[STATUS]),
            topic_labels=bcf.ExtensionsTopicLabels(topic_label=[LABEL])))),
    ]

    def topic(name: str, title: str, topic_type: str, description: str,
              camera: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]],
              component: Any) -> None:
        topic_guid = str(station_facts.stable_uuid(space, f"bcf/topic/{name}"))
        view_guid = str(station_facts.stable_uuid(space, f"bcf/viewpoint/{name}"))
        eye, direction, up = camera
        components = bcf.Components(
            selection=None if component is None else bcf.ComponentSelection(
                component=[component]),
            visibility=bcf.ComponentVisibility(default_visibility=True))
        viewpoint = bcf.VisualizationInfo(
            guid=view_guid, components=components,
            perspective_camera=bcf.PerspectiveCamera(
                camera_view_point=bcf.Point(**_xyz(eye)),
                camera_direction=bcf.Direction(**_xyz(direction)),
                camera_up_vector=bcf.Direction(**_xyz(up)),
                field_of_view=FIELD_OF_VIEW_DEG, aspect_ratio=round(ASPECT_RATIO, _DECIMALS)))
        markup = bcf.Markup(header=header, topic=bcf.Topic(
            guid=topic_guid, topic_type=topic_type, topic_status=STATUS, title=title,
            labels=bcf.TopicLabels(label=[LABEL]), creation_date=date,
            creation_author=AUTHOR, description=description,
            viewpoints=bcf.TopicViewpoints(view_point=[
                bcf.ViewPoint(viewpoint="viewpoint.bcfv", guid=view_guid)])))
        files.append((f"{topic_guid}/markup.bcf", xml.serialize(markup)))
        files.append((f"{topic_guid}/viewpoint.bcfv", xml.serialize(viewpoint)))

    for station in station_facts.stations(result):
        component = None
        if is_ifc:  # the station's IfcAnnotation in plan.ifc
            component = bcf.Component(ifc_guid=station_facts.ifc_global_id(
                space, station_facts.station_name(station.id)))
        topic(station_facts.station_name(station.id), f"Station {station.id}", STATION_TYPE,
              _station_text(station),
              (np.asarray(station.position_m), np.asarray(station.view_direction),
               np.asarray(station.up)),
              component)
    for row, camera in _uncoverable(result):
        global_id = str(row["global_id"])
        component = (bcf.Component(ifc_guid=global_id) if _IFC_GUID.fullmatch(global_id)
                     else bcf.Component(authoring_tool_id=global_id))
        name = " ".join(p for p in (str(row["ifc_class"]), str(row["name"])) if p)
        topic(f"element/{global_id}", f"Cannot be covered: {name or global_id}",
              UNCOVERABLE_TYPE, _uncoverable_text(row), camera, component)
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        for name, text in files:
            info = zipfile.ZipInfo(name, date_time=_ZIP_DATE)
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = 0o644 << 16
            archive.writestr(info, text.encode("utf-8"))
    return buffer.getvalue()


def _xyz(v: NDArray[np.float64]) -> dict[str, float]:
    x, y, z = (round(float(c), _DECIMALS) + 0.0 for c in v)  # + 0.0: no "-0.0"
    return {"x": x, "y": y, "z": z}


def _station_text(station: station_facts.Station) -> str:
    x, y, z = station.position_m
    lines = [
        f"Laser scanner station {station.id} at x {x:.3f}, y {y:.3f}, z {z:.3f} m "
        "(the scanner's axis at instrument height, model coordinates).",
        "Visit: " + (f"{station.visit} on the walking route" if station.visit is not None
                     else "not reachable on foot from the route"),
    ]
    if station.storey_name:
        lines.append(f"Storey: {station.storey_name}")
    if station.space_global_id:
        lines.append(f"Room (IfcSpace): {station.space_global_id}")
    lines.append(f"Covers {station.station_area_m2:.2f} m² at the required density, "
                 f"{station.new_area_m2:.2f} m² of it new in selection order.")
    if station.neighbours:
        lines.append("Registers to stations " + ", ".join(map(str, station.neighbours)) + ".")
    if station.fixed:
        lines.append("Scanned before (fixed station).")
    return "\n".join(lines)


def _uncoverable_text(row: dict[str, Any]) -> str:
    reasons = row.get("reasons") or {}
    by_reason = ", ".join(f"{reason} {area:.2f} m²" for reason, area in reasons.items())
    storey = f" on storey {row['storey']}" if row.get("storey") else ""
    return (f"{row['ifc_class']} {row['global_id']}{storey}: no candidate position covers "
            f"any of its {row['target_area_m2']:.2f} m² of target surface at the required "
            f"density. Reason: {row['uncoverable_reason']} (area per reason: {by_reason}).")


def _uncoverable(result: PlanResult) -> list[tuple[dict[str, Any], tuple[
        NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]]]:
    """The uncoverable elements' rows, each with a camera (eye, direction, up; model axes)
    at the nearest candidate looking at the element's area-weighted centre."""
    scene = result.scene
    if not scene.elements:
        return []
    from planner.outputs.bim import element_rows

    index = {e.global_id: i for i, e in enumerate(scene.elements)}
    rotation = scene_rotation(scene.metadata)
    candidates = result.candidates.positions
    out = []
    face_element = scene.face_element  # (F,), made once for every row
    for row in element_rows(result):
        if row["uncoverable_reason"] is None:
            continue
        faces = face_element == index[row["global_id"]]
        weights = scene.areas[faces]
        centre = (scene.centroids_of(np.flatnonzero(faces)) * weights[:, None]).sum(axis=0) / max(
            float(weights.sum()), 1e-12)
        eye = candidates[int(np.argmin(np.linalg.norm(candidates - centre, axis=1)))]
        direction = centre - eye
        if float(np.linalg.norm(direction)) < 1e-6:
            direction = np.array([1.0, 0.0, 0.0])
        direction = direction / np.linalg.norm(direction)
        up = np.array([0.0, 0.0, 1.0]) - direction[2] * direction
        up = up / np.linalg.norm(up) if float(np.linalg.norm(up)) > 1e-6 else np.array(
            [1.0, 0.0, 0.0])
        model = to_model(rotation, np.stack([eye, direction, up]))
        out.append((row, (model[0], model[1], model[2])))
    return out
