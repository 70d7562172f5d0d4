"""HTTP models. The plan parameters take their defaults from :class:`planner.PlanSpec`.

Field names and types are written out (a generated client needs them); every default is
read from the dataclass, and a test fails when a field is added to one but not the other.
Pydantic checks types strictly (no "1.5" for a number); ranges and consistency stay in
:meth:`PlanSpec.from_mapping`, the one validator of values.
"""

from __future__ import annotations

from dataclasses import MISSING, fields
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, Strict, StrictBool

from planner.parameters import PlanSpec


def _defaults() -> dict[str, Any]:
    values: dict[str, Any] = {}
    for f in fields(PlanSpec):
        if f.default is not MISSING:
            values[f.name] = f.default
        elif f.default_factory is not MISSING:
            values[f.name] = f.default_factory()
    return values


DEFAULTS = _defaults()
Number = Annotated[float, Strict()]
Point3 = Annotated[list[Number], Field(min_length=3, max_length=3)]
Point2 = Annotated[list[Number], Field(min_length=2, max_length=2)]


def _d(name: str, description: str) -> Any:
    """A field whose default is PlanSpec's."""
    return Field(default=DEFAULTS[name], description=description)


class GroupRequirementModel(BaseModel):
    """Overrides for the faces of one group (OBJ group, glTF node, IFC class/GlobalId)."""

    model_config = ConfigDict(extra="forbid")

    min_density_pts_m2: Number | None = Field(default=None,
                                              description="points per m², null: plan-wide")
    min_incidence_deg: Number | None = Field(default=None, description="degrees, null: plan-wide")
    target: StrictBool = Field(default=True, description="false: blocks rays, needs no coverage")
    occludes: StrictBool = Field(default=True, description="false: rays pass through (glass)")


class PlanParameters(BaseModel):
    """Every knob of a plan; names, units and defaults exactly as in the planner."""

    model_config = ConfigDict(extra="forbid")

    dof_min_m: Number = _d("dof_min_m", "nearest usable range of the scanner, metres")
    dof_max_m: Number = _d("dof_max_m", "farthest usable range of the scanner, metres")
    point_spacing_m: Number = _d("point_spacing_m", "point spacing at reference_distance_m")
    reference_distance_m: Number = _d("reference_distance_m",
                                      "distance at which point_spacing_m holds, metres")
    elevation_min_deg: Number = _d("elevation_min_deg", "lowest beam elevation, degrees")
    elevation_max_deg: Number = _d("elevation_max_deg", "highest beam elevation, degrees")
    min_incidence_deg: Number = _d("min_incidence_deg",
                                   "least angle between beam and surface, degrees")
    min_density_pts_m2: Number = _d("min_density_pts_m2", "required points per m²")
    coverage_goal: Number = _d("coverage_goal", "fraction of the achievable area, (0, 1]")
    group_requirements: dict[str, GroupRequirementModel] = _d(
        "group_requirements", "per-group overrides keyed by group name")
    method: Literal["greedy", "weighted_greedy", "optimal"] = _d(
        "method", "station selection method")
    optimal_time_limit_s: Number = _d("optimal_time_limit_s", "MILP time limit, seconds")
    max_edge_m: Number | None = _d("max_edge_m",
                                   "split faces to this edge length, metres; null: as given")
    unit_scale: Number = _d("unit_scale", "model units to metres (0.001 for millimetres)")
    occluders: Literal["remeshed", "file"] = _d(
        "occluders", "faces rays are tested against: the remeshed pieces or the file's own")
    candidates: list[Point3] | None = _d(
        "candidates", "scanner positions [x, y, z] in model coordinates; null: a grid")
    grid_spacing_m: Number = _d("grid_spacing_m", "spacing of generated candidates, metres")
    scanner_height_m: Number = _d("scanner_height_m", "height above the floor, metres")
    clearance_m: Number = _d("clearance_m", "least distance to any surface, metres")
    area_of_interest: list[Point2] | None = _d(
        "area_of_interest", "polygon [x, y] the generated candidates stay in; null: all")
    storeys: list[str] | None = _d("storeys", "IFC storeys to plan for; null: all")
    rooms: list[str] | None = _d("rooms", "IFC spaces to plan for; null: all")


class ExecuteInputs(BaseModel):
    """The inputs of the scan-plan process."""

    model_config = ConfigDict(extra="forbid")

    mesh: str = Field(..., description="id of an uploaded mesh (its sha256)",
                      min_length=1, max_length=64)
    parameters: PlanParameters = Field(default_factory=PlanParameters)


class ExecuteRequest(BaseModel):
    """``POST /processes/scan-plan/execution`` body (OGC API - Processes)."""

    model_config = ConfigDict(extra="forbid")

    inputs: ExecuteInputs


class Link(BaseModel):
    """A web link (OGC style)."""

    href: str
    rel: str
    type: str | None = None
    title: str | None = None


class StatusInfo(BaseModel):
    """A job's status document (OGC ``statusInfo`` plus a few fields of ours)."""

    jobID: str  # noqa: N815 - OGC's name
    processID: str = "scan-plan"  # noqa: N815
    type: str = "process"
    status: Literal["accepted", "running", "successful", "failed", "dismissed"]
    message: str
    progress: int = Field(..., ge=0, le=100)
    created: str
    started: str | None = None
    finished: str | None = None
    updated: str
    mesh: str
    attempts: int
    timings_s: dict[str, float] | None = Field(
        None, description="seconds per stage (reading, candidates, visibility, ...)")
    problem: dict[str, Any] | None = Field(default=None,
                                           description="RFC 9457 problem of a failure")
    links: list[Link]


class JobList(BaseModel):
    """A page of jobs."""

    jobs: list[StatusInfo]
    numberMatched: int  # noqa: N815
    links: list[Link]


class MeshInfo(BaseModel):
    """An uploaded mesh."""

    id: str = Field(..., description="sha256 of the bytes")
    format: str
    bytes: int
    filename: str | None
    faces: int
    vertices: int
    total_area_m2: float
    bounds: list[list[float]]
    groups: dict[str, int] = Field(..., description="faces per group")
    created: str
    links: list[Link]


class OutputRef(BaseModel):
    """One output file of a job."""

    href: str
    type: str
    bytes: int
    sha256: str


class JobResults(BaseModel):
    """``GET /jobs/{id}/results``: the plan inline, every output by reference."""

    plan: dict[str, Any]
    outputs: dict[str, OutputRef]
    links: list[Link]
