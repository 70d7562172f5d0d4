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

from pydantic import (
    BaseModel,
    ConfigDict,
    Discriminator,
    Field,
    RootModel,
    Strict,
    StrictBool,
    Tag,
)

from planner.parameters import (
    COORDINATE_RANGE,
    GROUP_RANGES,
    MAX_ITEMS,
    MAX_SETTINGS,
    RANGES,
    SCANNER_RANGES,
    SETTING_RANGES,
    PlanSpec,
    Range,
)


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
Coordinate = Annotated[float, Strict(), Field(ge=COORDINATE_RANGE.ge, le=COORDINATE_RANGE.le)]
Point3 = Annotated[list[Coordinate], Field(min_length=3, max_length=3)]
Point2 = Annotated[list[Coordinate], Field(min_length=2, max_length=2)]
Goal = Annotated[float, Strict(), Field(gt=0, le=1)]  # as PlanSpec checks curve_goals[i]


def _ranged(default: Any, description: str, bounds: Range | None,
            max_items: int | None = None) -> Any:
    """A field with the bounds of the planner's range table (None: no bound)."""
    bounds = bounds or Range()
    return Field(default=default, description=description, ge=bounds.ge, gt=bounds.gt,
                 le=bounds.le, lt=bounds.lt, max_length=max_items)


def _d(name: str, description: str) -> Any:
    """A field whose default is PlanSpec's, whose range and most items are the planner's."""
    return _ranged(DEFAULTS[name], description, RANGES.get(name), MAX_ITEMS.get(name))


class GroupRequirementModel(BaseModel):
    """Overrides for the faces of one group (OBJ group, glTF node, IFC class/GlobalId)."""

    model_config = ConfigDict(extra="forbid")

    min_density_pts_m2: Number | None = _ranged(None, "points per m², null: plan-wide",
                                                GROUP_RANGES["min_density_pts_m2"])
    min_incidence_deg: Number | None = _ranged(None, "degrees, null: plan-wide",
                                               GROUP_RANGES["min_incidence_deg"])
    target: StrictBool = Field(default=True, description="false: blocks rays, needs no coverage")
    occludes: StrictBool = Field(default=True, description="false: rays pass through (glass)")


Name = Annotated[str, Strict(), Field(min_length=1, max_length=100)]


class ScanSettingModel(BaseModel):
    """One angular step of the instrument: a point spacing at a distance."""

    model_config = ConfigDict(extra="forbid")

    name: Name = Field(..., description="as the crew calls it, e.g. 6 mm @ 10 m")
    point_spacing_m: Number = _ranged(..., "point spacing at reference_distance_m, metres",
                                      SETTING_RANGES["point_spacing_m"])
    reference_distance_m: Number = _ranged(..., "distance at which the spacing holds, metres",
                                           SETTING_RANGES["reference_distance_m"])
    duration_s: Number | None = _ranged(
        None, "seconds of one scan at this setting; null: from measurement_rate_pts_s",
        SETTING_RANGES["duration_s"])


class ScannerProfileModel(BaseModel):
    """The instrument, described by the crew; null figures keep the plan's (or the preset's)."""

    model_config = ConfigDict(extra="forbid")

    name: Name = Field(..., description="the instrument's name, as plan.json will show it")
    preset: str | None = Field(default=None, description="a preset id whose figures fill what "
                               "this object leaves out (GET /processes/scan-plan lists them)")
    min_range_m: Number | None = _ranged(None, "nearest range, metres (sets dof_min_m)",
                                         SCANNER_RANGES["min_range_m"])
    max_range_m: Number | None = _ranged(None, "farthest range, metres (sets dof_max_m)",
                                         SCANNER_RANGES["max_range_m"])
    elevation_min_deg: Number | None = _ranged(None, "lowest beam elevation, degrees",
                                               SCANNER_RANGES["elevation_min_deg"])
    elevation_max_deg: Number | None = _ranged(None, "highest beam elevation, degrees",
                                               SCANNER_RANGES["elevation_max_deg"])
    measurement_rate_pts_s: Number | None = _ranged(
        None, "points recorded per second (scan duration = points / rate + overhead_s)",
        SCANNER_RANGES["measurement_rate_pts_s"])
    settings: list[ScanSettingModel] = Field(
        default_factory=list, max_length=MAX_SETTINGS,
        description="angular steps offered; each station is scanned at the coarsest that "
                    "still qualifies its faces at the plan's point_spacing_m (kept, unless no "
                    "setting is as fine as the default: then the finest sets it)")
    setup_time_s: Number | None = _ranged(None, "setup per station, seconds",
                                          SCANNER_RANGES["setup_time_s"])
    overhead_s: Number | None = _ranged(None, "imaging, tilt and any constant per scan, "
                                        "seconds", SCANNER_RANGES["overhead_s"])


def _scanner_kind(value: Any) -> str | None:
    if isinstance(value, str):
        return PRESET_TAG
    return OBJECT_TAG if isinstance(value, dict | ScannerProfileModel) else None


# the two forms of ``scanner``; an error in one names only that form, and the tags (never a
# field name) are left out of the parameter a problem names (service.main)
PRESET_TAG, OBJECT_TAG = "preset id", "object"
ScannerParameter = Annotated[
    Annotated[str, Strict(), Tag(PRESET_TAG)] | Annotated[ScannerProfileModel, Tag(OBJECT_TAG)],
    Discriminator(_scanner_kind, custom_error_type="scanner_type",
                  custom_error_message="expected a preset id or an object {name, "
                                       "measurement_rate_pts_s, settings, ...}"),
]


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
    max_stations: Annotated[int, Strict()] | None = _d(
        "max_stations", "a budget: the most coverage in this many stations (greedy or "
        "weighted_greedy), the goal reached or not; null: the fewest stations for the goal")
    max_field_time_h: Number | None = _d(
        "max_field_time_h", "a budget of hours in the field: the most coverage a crew can "
        "set up, scan (at the plan's step) and walk in this time (greedy or weighted_greedy; "
        "needs a scanner whose scan times are known); null: no time budget")
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
    scanner_heights_m: list[Annotated[float, Strict(), Field(
        gt=RANGES["scanner_height_m"].gt, le=RANGES["scanner_height_m"].le)]] | None = _d(
        "scanner_heights_m", "instrument heights above the floor for generated candidates, "
        "metres, each a separate candidate; null: scanner_height_m alone")
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
    scanner: ScannerParameter | None = _d(
        "scanner", "scanner preset id (GET /processes/scan-plan lists them) or the instrument "
        "as an object; sets the defaults of the limits it knows; null: Table 2")
    min_overlap_m2: Number | None = _d(
        "min_overlap_m2", "least shared area for a registration edge, m²; null: no constraint")
    overlap_density_pts_m2: Number = _d(
        "overlap_density_pts_m2", "density at which a surface counts for registration, pts/m²")
    overlap_max_edge_m: Number | None = _d(
        "overlap_max_edge_m", "largest edge of the pieces the registration overlap is "
        "measured on, m; null: the coverage's pieces")
    route_start: Point3 | None = _d("route_start",
                                    "walking route start [x, y, z]; null: chosen")
    setup_time_s: Number | None = _d("setup_time_s",
                                     "per-station setup, seconds; null: the preset's or 60")
    walking_speed_m_s: Number = _d("walking_speed_m_s", "walking speed with the kit, m/s")
    placement_tolerance_m: Number | None = _d(
        "placement_tolerance_m", "radius a tripod may land off its planned position, metres; "
        "the plan reports what each station keeps within it (null or 0: no report)")
    robust: StrictBool = _d("robust", "credit a face to a candidate only when it qualifies from "
                            "every position within placement_tolerance_m (null: 0.25 m)")
    exact_rays: StrictBool = _d(
        "exact_rays", "decide every ray in float64 as the brute-force reference does (slower); "
        "false: one Embree cast a ray, the same on every machine with AVX2")


class ExecuteInputs(BaseModel):
    """The inputs of the scan-plan process."""

    model_config = ConfigDict(extra="forbid")

    mesh: str = Field(..., description="id of an uploaded mesh (its sha256)",
                      min_length=1, max_length=64)
    parameters: PlanParameters = Field(default_factory=PlanParameters)


class Subscriber(BaseModel):
    """OGC ``subscriber``: where the job's status document is POSTed (callbacks).

    http(s) only, to a public address unless the operator allows more
    (``SCANPLAN_CALLBACK_ALLOW``); each POST is signed (``X-Scanplan-Signature``).
    """

    model_config = ConfigDict(extra="forbid")

    successUri: str = Field(  # noqa: N815 - OGC's name
        ..., min_length=1, max_length=2048, json_schema_extra={"format": "uri"},
        description="gets the status document with a link to every output once the job "
                    "succeeded")
    inProgressUri: str | None = Field(  # noqa: N815
        default=None, min_length=1, max_length=2048, json_schema_extra={"format": "uri"},
        description="gets the status document when the status or stage changes (at most "
                    "one every few seconds, SCANPLAN_CALLBACK_PROGRESS_INTERVAL_S)")
    failedUri: str | None = Field(  # noqa: N815
        default=None, min_length=1, max_length=2048, json_schema_extra={"format": "uri"},
        description="gets the status document with the problem once the job failed")


class ExecuteRequest(BaseModel):
    """``POST /processes/scan-plan/execution`` body (OGC API - Processes ``execute.yaml``).

    ``outputs`` and ``response`` are accepted as the standard defines them; every job keeps
    all its outputs and ``GET /jobs/{id}/results`` always answers the results document.
    """

    model_config = ConfigDict(extra="forbid")

    inputs: ExecuteInputs
    outputs: dict[str, dict[str, Any]] | None = Field(
        default=None, max_length=100, description="OGC: outputs wanted; every output is kept")
    response: Literal["raw", "document"] = Field(
        default="document", description="OGC: results as a document (the only form here)")
    subscriber: Subscriber | None = Field(
        default=None, description="OGC callbacks: URIs the status document is POSTed to")


class Link(BaseModel):
    """A web link (OGC style)."""

    href: str
    rel: str
    type: str | None = None
    title: str | None = None


JobStatus = Literal["accepted", "running", "successful", "failed", "dismissed"]


class AttemptInfo(BaseModel):
    """One ended attempt of a job: where and how it ended, and the figures of a death."""

    attempt: int = Field(..., description="1 for the first run")
    worker: str | None = Field(None, description="host:pid of the worker that ran it")
    started: str | None = None
    finished: str | None = None
    outcome: Literal["successful", "failed", "out of memory", "killed", "worker lost"] = Field(
        ..., description="killed: the planning process was ended by a signal from outside, "
        "its memory far below the limit (queued again until the last attempt); worker lost: "
        "the worker stopped heartbeating")
    stage: str | None = Field(None, description="the last stage the attempt reached")
    signal: str | None = Field(None, description="the signal that ended the planning process")
    exit_code: int | None = None
    peak_rss_mib: float | None = Field(None, description="resident peak of the planning "
                                       "process, MiB (wait4 ru_maxrss)")
    peak_address_space_mib: float | None = Field(None, description="its address space peak, "
                                                 "MiB, as last read")
    memory_limit_mib: float | None = Field(None, description="its address-space limit, MiB")


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
    attempt_log: list[AttemptInfo] = Field(default_factory=list,
                                           description="each ended attempt, oldest first")
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
