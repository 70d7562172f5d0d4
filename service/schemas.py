"""HTTP models. The plan parameters take their defaults from :class:`planner.PlanSpec`.

Field names and types are written out (a generated client needs them); every default is
read from the dataclass and every range from :data:`planner.parameters.RANGES`, and a test
fails when a field is added to one but not the other. Pydantic checks types strictly (no
"1.5" for a number) and the ranges; checks between fields stay in
:meth:`PlanSpec.from_mapping`, which runs after it.
"""

from __future__ import annotations

from dataclasses import MISSING, fields
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, RootModel, Strict, StrictBool

from planner.parameters import GROUP_RANGES, RANGES, PlanSpec, Range


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
Goal = Annotated[float, Strict(), Field(gt=0, le=1)]  # as PlanSpec checks curve_goals[i]


def _ranged(default: Any, description: str, bounds: Range | None) -> Any:
    """A field with the bounds of the planner's range table (None: no bound)."""
    bounds = bounds or Range()
    return Field(default=default, description=description, ge=bounds.ge, gt=bounds.gt,
                 le=bounds.le, lt=bounds.lt)


def _d(name: str, description: str) -> Any:
    """A field whose default is PlanSpec's and whose range is the planner's."""
    return _ranged(DEFAULTS[name], description, RANGES.get(name))


class GroupRequirementModel(BaseModel):
    """Overrides for the faces of one group (OBJ group, glTF node, IFC class/GlobalId)."""

    model_config = ConfigDict(extra="forbid")

    min_density_pts_m2: Number | None = _ranged(None, "points per m², null: plan-wide",
                                                GROUP_RANGES["min_density_pts_m2"])
    min_incidence_deg: Number | None = _ranged(None, "degrees, null: plan-wide",
                                               GROUP_RANGES["min_incidence_deg"])
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
    curve_goals: list[Goal] | None = _d(
        "curve_goals", "goals in (0, 1] of the curve's optimal row; null: the plan's goal "
        "when method is optimal")
    fixed_stations: list[Point3] | None = _d(
        "fixed_stations", "stations already scanned [x, y, z]: in every plan, first")
    coverage_model: Literal["centroid", "sampled"] = _d(
        "coverage_model", "centroid: one ray per face (the paper); sampled: samples_per_face "
        "points per face, density LPD / cos(elevation)")
    samples_per_face: Annotated[int, Strict()] = _d(
        "samples_per_face", "sampled model: points per face, a square number (n x n grid)")
    min_sampled_fraction: Number = _d(
        "min_sampled_fraction", "sampled model: share of a face's area its samples must cover")
    max_edge_m: Number | None = _d("max_edge_m",
                                   "split faces to this edge length, metres; null: as given")
    unit_scale: Number = _d("unit_scale", "model units to metres (0.001 for millimetres)")
    up_axis: Literal["+Z", "-Z", "+Y", "-Y", "+X", "-X", "auto"] | None = _d(
        "up_axis", "the model's up axis; auto finds gravity; null: +Y for glTF/GLB, +Z else")
    occluders: Literal["file", "remeshed"] = _d(
        "occluders", "faces rays are tested against: the file's own or the remeshed pieces")
    candidates: list[Point3] | None = _d(
        "candidates", "scanner positions [x, y, z] in model coordinates; null: a grid")
    grid_spacing_m: Number = _d("grid_spacing_m", "spacing of generated candidates, metres")
    scanner_height_m: Number = _d("scanner_height_m", "height above the floor, metres")
    clearance_m: Number = _d("clearance_m", "least distance to any surface, metres")
    glb_compression: Literal["meshopt", "none"] = _d(
        "glb_compression", "coverage.glb: meshopt-compressed, or none for plain loaders")
    verify: StrictBool = _d("verify", "after the outputs, check the plan by a simulated scan "
                            "of its stations: verification.json and verified faces.npz arrays")
    area_of_interest: list[Point2] | None = _d(
        "area_of_interest", "polygon [x, y] the generated candidates stay in; null: all")
    floor_levels: Literal["storeys", "walkable", "lowest", "all"] = _d(
        "floor_levels", "grid on every storey (floor area and head room, not furniture), "
        "on the lowest floor and the levels reached from it on foot, on the lowest surface "
        "only, or on every flat surface with head room (meshes)")
    storeys: list[str] | None = _d("storeys", "IFC storeys to plan for; null: all")
    rooms: list[str] | None = _d("rooms", "IFC spaces to plan for; null: all")
    scanner: str | None = _d("scanner", "scanner preset id (GET /processes/scan-plan lists "
                             "them); sets the defaults of the limits it knows; null: Table 2")
    min_overlap_m2: Number | None = _d(
        "min_overlap_m2", "least shared area for a registration edge, m²; null: no constraint")
    overlap_density_pts_m2: Number = _d(
        "overlap_density_pts_m2", "density at which a surface counts for registration, pts/m²")
    route_start: Point3 | None = _d("route_start",
                                    "walking route start [x, y, z]; null: chosen")
    setup_time_s: Number | None = _d("setup_time_s",
                                     "per-station setup, seconds; null: the preset's or 60")
    walking_speed_m_s: Number = _d("walking_speed_m_s", "walking speed with the kit, m/s")


class ExecuteInputs(BaseModel):
    """The inputs of the scan-plan process."""

    model_config = ConfigDict(extra="forbid")

    mesh: str = Field(..., description="id of an uploaded mesh (its sha256)",
                      min_length=1, max_length=64)
    parameters: PlanParameters = Field(default_factory=PlanParameters)


class ExecuteRequest(BaseModel):
    """``POST /processes/scan-plan/execution`` body (OGC API - Processes ``execute.yaml``).

    ``outputs`` and ``response`` are accepted as the standard defines them; every job keeps
    all its outputs and ``GET /jobs/{id}/results`` always answers the results document.
    """

    model_config = ConfigDict(extra="forbid")

    inputs: ExecuteInputs
    outputs: dict[str, dict[str, Any]] | None = Field(
        default=None, description="OGC: outputs wanted; every output is kept")
    response: Literal["raw", "document"] = Field(
        default="document", description="OGC: results as a document (the only form here)")


class Link(BaseModel):
    """A web link (OGC style)."""

    href: str
    rel: str
    type: str | None = None
    title: str | None = None


JobStatus = Literal["accepted", "running", "successful", "failed", "dismissed"]


class StatusInfo(BaseModel):
    """A job's status document (OGC ``statusInfo`` plus a few fields of ours)."""

    jobID: str  # noqa: N815 - OGC's name
    processID: str = "scan-plan"  # noqa: N815
    type: str = "process"
    status: JobStatus
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
    warnings: list[str] | None = Field(
        default=None, description="at submission: what looks wrong before any work is done "
        "(e.g. a model size that suggests another unit_scale)")
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
    warnings: list[str] = Field(
        default_factory=list,
        description="e.g. a size that suggests another unit: names unit_scale and the fix")
    created: str
    links: list[Link]


class OutputRef(BaseModel):
    """One output file of a job."""

    href: str
    type: str
    bytes: int
    sha256: str


class JobResults(RootModel[dict[str, dict[str, Any]]]):
    """``GET /jobs/{id}/results`` (OGC ``results.yaml``): output id -> value or link.

    ``plan`` is the plan inline (the content of plan.json); every file output (``plan.json``,
    ``faces.npz``, ...) is a link ``{href, type, bytes, sha256}``.
    """
