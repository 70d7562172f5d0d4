"""``plan.ifc``: the input IFC model with the plan in it, written with ``ifcopenshell.api``.

Only for IFC input (:func:`absent_reason` says why it is absent otherwise). The file is the
input model with every entity it had unchanged (same STEP ids, same GlobalIds, same
attributes: scanplan adds relationships of its own instead of editing the model's), plus:

- per station an ``IfcAnnotation`` named ``Station <id>``: in IFC4X3 ``PredefinedType``
  SURVEY; in IFC2X3 and IFC4, which have no such type, ``ObjectType`` :data:`OBJECT_TYPE`.
  Its placement is the station (the scanner's axis at instrument height) in the model's
  coordinates and length unit, relative to its storey's placement; its representation a
  point (``Annotation`` / ``Point`` in the model's 3D context, a subcontext ``Annotation``
  added when the model has none). It is contained in its ``IfcBuildingStorey`` (the
  station's room's storey, else the one whose elevation matches its floor, see
  :mod:`planner.outputs.stations`) and referenced by the ``IfcSpace`` that holds it;
- per station the property set :data:`STATION_PSET` (id, visit, instrument height, the
  setting and scan time where the scanner profile gives them, areas, registration neighbours);
- per element scanplan reports on (``elements.csv``) the property set
  :data:`COVERAGE_PSET`: target, target / coverable / covered area, covered fraction and,
  where it cannot be covered, the reason (see :mod:`planner.outputs.bim`).

Lengths and areas are written in the model's own units (``IfcLengthMeasure`` /
``IfcAreaMeasure``). GUIDs and dates are fixed (see :mod:`planner.outputs.stations`): the
STEP header's time stamp and the owner history of what scanplan adds carry the epoch, and
that owner history names the application ``scanplan``.
"""

from __future__ import annotations

import hashlib
import importlib
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from planner.errors import SceneError
from planner.outputs import stations as station_facts

if TYPE_CHECKING:
    from planner.pipeline import PlanResult

STATION_PSET = "Scanplan_Station"
COVERAGE_PSET = "Scanplan_Coverage"
OBJECT_TYPE = "SURVEY: laser scanner station"
APPLICATION = "scanplan"


def absent_reason(result: PlanResult) -> str | None:
    """Why this plan has no ``plan.ifc`` (None: it has one)."""
    return reason_without_ifc(str(result.scene.metadata.get("format", "")))


def reason_without_ifc(input_format: str) -> str | None:
    """Why a plan of an input in ``input_format`` (plan.json ``scene.format``) has no
    ``plan.ifc``; None for IFC."""
    if input_format != "ifc":
        return (f"the input is {input_format.upper() or 'not IFC'}, not an IFC model to add "
                "the stations to (plan.bcf carries them for any input)")
    return None


def plan_ifc(result: PlanResult) -> bytes | None:
    """``plan.ifc`` bytes (see the module docstring), or None for a model that is not IFC.

    Raises
    ------
    SceneError
        the IFC file the plan was made from is gone or has changed since it was read
    """
    if absent_reason(result) is not None:
        return None
    import ifcopenshell

    metadata = result.scene.metadata
    path = Path(str(metadata["source_path"]))
    try:
        source = path.read_bytes()
    except OSError as exc:
        raise SceneError(f"plan.ifc: the model {path.name} cannot be read again: {exc}") from exc
    if hashlib.sha256(source).hexdigest() != metadata.get("source_sha256"):
        raise SceneError(f"plan.ifc: the model {path.name} changed after it was planned; "
                         "plan it again")
    model = ifcopenshell.open(str(path))
    writer = _Writer(model, result)
    writer.add_stations(station_facts.stations(result))
    writer.add_coverage()
    writer.fix_identities()
    header = model.header.file_name
    header.name = "plan.ifc"
    header.time_stamp = station_facts.FIXED_EPOCH.strftime("%Y-%m-%dT%H:%M:%S")
    return str(model.to_string()).encode("utf-8")


class _Writer:
    """Adds the plan to an opened model; every call goes through ``ifcopenshell.api``."""

    def __init__(self, model: Any, result: PlanResult) -> None:
        import ifcopenshell.util.unit

        self.model = model
        self.result = result
        self.first_new_id = max((e.id() for e in model), default=0) + 1
        self.length_scale = float(ifcopenshell.util.unit.calculate_unit_scale(model))
        self.area_scale = float(ifcopenshell.util.unit.calculate_unit_scale(model, "AREAUNIT"))
        self.namespace = station_facts.namespace(result)
        self.station_entities: dict[int, int] = {}  # STEP id -> station id

    def api(self, call: str, **arguments: Any) -> Any:
        """``ifcopenshell.api.<module>.<function>(model, **arguments)`` for ``call`` =
        ``"<module>.<function>"``."""
        module, function = call.split(".")
        api_module = importlib.import_module(f"ifcopenshell.api.{module}")
        return getattr(api_module, function)(self.model, **arguments)

    def length(self, metres: float) -> Any:
        return self.model.create_entity("IfcLengthMeasure", metres / self.length_scale)

    def area(self, square_metres: float) -> Any:
        return self.model.create_entity("IfcAreaMeasure", square_metres / self.area_scale)

    def add_stations(self, stations: list[station_facts.Station]) -> None:
        model = self.model
        context = self._annotation_context()
        by_storey: dict[int, list[Any]] = {}
        by_space: dict[int, list[Any]] = {}
        annotations = []
        survey_type = model.schema.upper().startswith("IFC4X3")
        for station in stations:
            annotation = self.api("root.create_entity", ifc_class="IfcAnnotation",
                                  name=f"Station {station.id}",
                                  predefined_type="SURVEY" if survey_type else None)
            self.station_entities[annotation.id()] = station.id
            self.api("attribute.edit_attributes", product=annotation, attributes={
                "Description": "laser scanner station planned by scanplan",
                "ObjectType": None if survey_type else OBJECT_TYPE,
            })
            container = self._container(station)
            if container is not None:
                by_storey.setdefault(container.id(), []).append(annotation)
            if station.space_global_id:
                space = _by_guid(model, station.space_global_id)
                if space is not None:
                    by_space.setdefault(space.id(), []).append(annotation)
            annotations.append((annotation, station))
        for structure, products in by_storey.items():
            rel = self.api("root.create_entity", ifc_class="IfcRelContainedInSpatialStructure")
            self.api("attribute.edit_attributes", product=rel, attributes={
                "RelatedElements": products, "RelatingStructure": model.by_id(structure)})
        for space, products in by_space.items():
            rel = self.api("root.create_entity", ifc_class="IfcRelReferencedInSpatialStructure")
            self.api("attribute.edit_attributes", product=rel, attributes={
                "RelatedElements": products, "RelatingStructure": model.by_id(space)})
        for annotation, station in annotations:
            matrix = np.eye(4)
            matrix[:3, 3] = station.position_m
            self.api("geometry.edit_object_placement", product=annotation, matrix=matrix,
                     is_si=True)
            point = model.create_entity("IfcCartesianPoint", Coordinates=(0.0, 0.0, 0.0))
            representation = model.create_entity(
                "IfcShapeRepresentation", ContextOfItems=context,
                RepresentationIdentifier="Annotation", RepresentationType="Point",
                Items=[point])
            self.api("geometry.assign_representation", product=annotation,
                     representation=representation)
            pset = self.api("pset.add_pset", product=annotation, name=STATION_PSET)
            self.api("pset.edit_pset", pset=pset, properties=self._station_properties(station))

    def _station_properties(self, station: station_facts.Station) -> dict[str, Any]:
        model, spec = self.model, self.result.spec
        survey = self.result.survey
        properties: dict[str, Any] = {
            "StationId": model.create_entity("IfcInteger", station.id),
            "SelectionOrder": model.create_entity("IfcInteger", station.id),
            "InstrumentHeight": self.length(spec.scanner_height_m),
            "PointSpacing": self.length(spec.point_spacing_m),
            "ReferenceDistance": self.length(spec.reference_distance_m),
            "StationArea": self.area(station.station_area_m2),
            "NewArea": self.area(station.new_area_m2),
            "RegistrationNeighbours": model.create_entity(
                "IfcLabel", ", ".join(str(n) for n in station.neighbours)),
            "Fixed": model.create_entity("IfcBoolean", station.fixed),
        }
        if station.visit is not None:
            properties["VisitOrder"] = model.create_entity("IfcInteger", station.visit)
        if survey is not None and survey.field_time.scanner is not None:
            properties["Scanner"] = model.create_entity("IfcLabel", survey.field_time.scanner)
        if survey is not None and survey.scans:
            scan = survey.scans[station.id - 1]  # selection order
            if scan.setting is not None:
                properties["Setting"] = model.create_entity("IfcLabel", scan.setting)
            if scan.scan_s is not None:
                properties["ScanTime"] = model.create_entity("IfcTimeMeasure", scan.scan_s)
        return properties

    def add_coverage(self) -> None:
        if not self.result.scene.elements:
            return
        from planner.outputs.bim import element_rows

        for row in element_rows(self.result):
            element = _by_guid(self.model, str(row["global_id"]))
            if element is None:
                continue
            properties: dict[str, Any] = {
                "Target": self.model.create_entity("IfcBoolean", bool(row["target"])),
                "TargetArea": self.area(row["target_area_m2"]),
                "CoverableArea": self.area(row["coverable_area_m2"]),
                "CoveredArea": self.area(row["covered_area_m2"]),
            }
            if row["fraction"] is not None:
                properties["CoveredFraction"] = self.model.create_entity(
                    "IfcNormalisedRatioMeasure", min(1.0, float(row["fraction"])))
            if row["uncoverable_reason"] is not None:
                properties["UncoverableReason"] = self.model.create_entity(
                    "IfcLabel", str(row["uncoverable_reason"]))
            pset = self.api("pset.add_pset", product=element, name=COVERAGE_PSET)
            self.api("pset.edit_pset", pset=pset, properties=properties)

    def _container(self, station: station_facts.Station) -> Any:
        """The storey of the station; without storeys the building, else the site."""
        if station.storey_global_id:
            storey = _by_guid(self.model, station.storey_global_id)
            if storey is not None:
                return storey
        for ifc_class in ("IfcBuilding", "IfcSite"):
            found = sorted(self.model.by_type(ifc_class), key=lambda e: e.id())
            if found:
                return found[0]
        return None

    def _annotation_context(self) -> Any:
        """The model's 3D ``Annotation`` subcontext, added under its 3D context if missing."""
        import ifcopenshell.util.representation as representation

        found = representation.get_context(self.model, "Model", "Annotation", "MODEL_VIEW")
        if found is not None:
            return found
        parent = representation.get_context(self.model, "Model")
        if parent is None:
            parent = self.api("context.add_context", context_type="Model")
        return self.api("context.add_context", context_type="Model",
                        context_identifier="Annotation", target_view="MODEL_VIEW",
                        parent=parent)

    def fix_identities(self) -> None:
        """Fixed GlobalIds for everything added, one owner history with the fixed date."""
        model = self.model
        added = [e for e in model if e.id() >= self.first_new_id]
        added.sort(key=lambda e: e.id())
        histories = [e for e in added if e.is_a("IfcOwnerHistory")]
        history = histories[0] if histories else None
        if history is not None:
            application = self.api(
                "owner.add_application", application_developer=None,
                version="1", application_full_name=APPLICATION,
                application_identifier=APPLICATION)
            epoch = int(station_facts.FIXED_EPOCH.timestamp())
            history.OwningApplication = application
            history.LastModifyingApplication = None
            history.LastModifyingUser = None
            history.ChangeAction = "ADDED"
            history.CreationDate = epoch
            history.LastModifiedDate = epoch  # IFC4 CorrectChangeAction: ADDED needs a date
        for entity in added:
            if entity.is_a("IfcRoot"):
                if history is not None:
                    entity.OwnerHistory = history
                station = self.station_entities.get(entity.id())
                name = (station_facts.station_name(station) if station is not None
                        else f"entity/{entity.id()}")
                entity.GlobalId = station_facts.ifc_global_id(self.namespace, name)
        for extra in histories[1:]:
            model.remove(extra)


def _by_guid(model: Any, global_id: str) -> Any:
    try:
        return model.by_guid(global_id)
    except RuntimeError:  # not in the model
        return None
