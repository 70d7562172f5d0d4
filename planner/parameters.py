"""Every knob of a plan, with the defaults of the paper's Table 2.

The names are the API contract: the CLI's ``--params`` JSON, the service's request body and
``plan.json`` all use exactly these keys. :class:`PlanSpec` is frozen; build one with
:meth:`PlanSpec.from_mapping`, which validates and names the offending key in its error.

Adding a number parameter with a range: add the field to :class:`PlanSpec` and one line to
:data:`RANGES` (e.g. ``"scan_time_s": Range(gt=0)``). The validator checks it from there, and
the service's HTTP model (``service/schemas.py``) puts the same bounds into the OpenAPI
schema, so a client can validate before it calls. Checks between fields (``dof_min_m <
dof_max_m``) stay in :func:`_validate`: JSON Schema cannot say them.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, fields, replace
from typing import Any, Literal

from planner.errors import ParameterError
from planner.scanners import (
    PROFILE_FIELDS,
    SETTING_FIELDS,
    STEP_TOLERANCE,
    ScannerProfile,
    ScanSetting,
    StationScan,
    fallback_step,
    missing_duration_reason,
    plan_defaults,
    preset,
    resolve,
    station_scans,
)

Method = Literal["greedy", "weighted_greedy", "optimal"]
METHODS: tuple[Method, ...] = ("greedy", "weighted_greedy", "optimal")
GlbCompression = Literal["meshopt", "none"]
GLB_COMPRESSIONS: tuple[GlbCompression, ...] = ("meshopt", "none")
FloorLevels = Literal["storeys", "walkable", "lowest", "all"]
FLOOR_LEVELS: tuple[FloorLevels, ...] = ("storeys", "walkable", "lowest", "all")
UpAxis = Literal["+Z", "-Z", "+Y", "-Y", "+X", "-X", "auto"]
UP_AXES: tuple[UpAxis, ...] = ("+Z", "-Z", "+Y", "-Y", "+X", "-X", "auto")
CoverageModel = Literal["centroid", "sampled"]
COVERAGE_MODELS: tuple[CoverageModel, ...] = ("centroid", "sampled")
Occluders = Literal["file", "remeshed"]
OCCLUDERS: tuple[Occluders, ...] = ("file", "remeshed")
# seconds to set up one station when neither the plan nor its scanner gives a figure
DEFAULT_SETUP_TIME_S = 60.0
# the radius a robust plan holds its faces within when no placement_tolerance_m is given: a
# tripod centred over a mark by eye, without a plummet, lands within some 0.25 m of it
ROBUST_TOLERANCE_M = 0.25


@dataclass(frozen=True)
class GroupRequirement:
    """Per-group overrides, keyed by group name (OBJ group, glTF node, IFC class or GlobalId).

    ``None`` keeps the plan-wide value. ``target=False``: the faces block rays but need no
    coverage (terrain). ``occludes=False``: rays pass through them (glass).
    """

    min_density_pts_m2: float | None = None
    min_incidence_deg: float | None = None
    target: bool = True
    occludes: bool = True


@dataclass(frozen=True)
class PlanSpec:
    """Scanner, requirements, candidates and selection method of one plan."""

    # equipment (paper Table 2)
    dof_min_m: float = 1.5
    dof_max_m: float = 50.0
    point_spacing_m: float = 0.010
    reference_distance_m: float = 10.0
    elevation_min_deg: float = -60.0
    elevation_max_deg: float = 90.0
    # requirements
    min_incidence_deg: float = 15.0
    min_density_pts_m2: float = 45_000.0
    coverage_goal: float = 0.8
    group_requirements: Mapping[str, GroupRequirement] = field(default_factory=dict)
    # coverage model (planner.visibility.sampled): "centroid" is the paper's one ray per face
    coverage_model: CoverageModel = "centroid"
    samples_per_face: int = 16
    min_sampled_fraction: float = 1.0
    # selection
    method: Method = "greedy"
    # a budget: the plan with the most coverage in this many stations (greedy or weighted
    # greedy, maximum coverage), whether or not it reaches the goal; null: the fewest
    # stations that reach the goal
    max_stations: int | None = None
    # a budget of hours in the field (setup, scans at the plan's step and the walk between
    # stations, as plan.json's field_time counts them): the plan with the most coverage a
    # crew can survey in that time (greedy or weighted greedy, with a scanner whose scan
    # times are known); null: no time budget
    max_field_time_h: float | None = None
    optimal_time_limit_s: float = 60.0
    curve_goals: tuple[float, ...] | None = None  # goals of the curve's optimal row
    fixed_stations: tuple[tuple[float, float, float], ...] | None = None  # re-scan
    # scene preparation
    max_edge_m: float | None = 0.2
    unit_scale: float = 1.0
    up_axis: UpAxis | None = None  # None: the format's own (+Y glTF/GLB, +Z otherwise)
    # visibility: rays tested against the file's own faces (a hit counts when it is the
    # target piece's source face; the ray cache stays the size of the file), or against
    # the remeshed pieces (a BVH as large as the remeshed model)
    occluders: Occluders = "file"
    # candidates
    candidates: tuple[tuple[float, float, float], ...] | None = None
    grid_spacing_m: float = 0.5
    scanner_height_m: float = 1.5
    # several instrument heights: candidates at each over the same floor points (null: only
    # scanner_height_m, the paper's single height)
    scanner_heights_m: tuple[float, ...] | None = None
    clearance_m: float = 0.3
    area_of_interest: tuple[tuple[float, float], ...] | None = None
    # "storeys": every level with floor area and head room that is not raised furniture,
    # reached on foot or not; "walkable": the lowest floor and every level a person reaches
    # from it on foot (stairs, not machine tops); "lowest": the lowest surface only; "all":
    # every flat surface with head room
    floor_levels: FloorLevels = "storeys"
    storeys: tuple[str, ...] | None = None
    rooms: tuple[str, ...] | None = None
    # outputs
    glb_compression: GlbCompression = "meshopt"
    # after the outputs: a simulated scan of the stations checks the plan's promise and
    # writes verification.json (planner.truth; as `scanplan verify` does)
    verify: bool = False
    # survey: presets, registration overlap, walking route, field time
    # a preset id (planner/scanners.json) or an instrument profile; sets the defaults above
    scanner: str | ScannerProfile | None = None
    min_overlap_m2: float | None = None  # null: the paper's selection, no overlap constraint
    # a surface counts for registration at this density: 25 mm x 25 mm, the data density of
    # Level of Detail 2 in GSA BIM Guide Series 03, 3D Imaging (U.S. GSA, 2009)
    overlap_density_pts_m2: float = 1600.0
    # the registration overlap measured on the file's faces split to pieces of at most this
    # edge, coarser than max_edge_m: faster on large models, but an edge's constraint
    # moves with the pieces, so a few edges near its threshold flip (docs: performance);
    # null: on the coverage's own pieces
    overlap_max_edge_m: float | None = None
    route_start: tuple[float, float, float] | None = None  # null: the route chooses
    setup_time_s: float | None = None  # per station; null: the preset's, else 60 s
    walking_speed_m_s: float = 0.8
    # placement tolerance (planner.candidates.placement): the report of what each station keeps
    # when set up anywhere within this radius (null or 0: no report), and robust planning (a
    # face counts for a candidate only when it qualifies from every displaced position;
    # within ROBUST_TOLERANCE_M when no radius is given)
    placement_tolerance_m: float | None = None
    robust: bool = False
    # rays: decide every one in float64 as the brute-force reference does (a second Embree
    # cast and float64 arbitration where float32 cannot decide a grazing ray), instead of
    # one cast with the pinned kernels (planner.rays.pinned)
    exact_rays: bool = False

    def __post_init__(self) -> None:
        # accept plain data too (dicts, lists), as from_mapping does
        object.__setattr__(self, "group_requirements",
                           _group_requirements(self.group_requirements))
        for name, dims in (("candidates", 3), ("area_of_interest", 2), ("fixed_stations", 3)):
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, _points(name, value, dims))
        if self.route_start is not None:
            object.__setattr__(self, "route_start",
                               _points("route_start", [self.route_start], 3)[0])
        object.__setattr__(self, "scanner", _scanner(self.scanner))
        if self.scanner_heights_m is not None:
            object.__setattr__(self, "scanner_heights_m",
                               _convert("scanner_heights_m", self.scanner_heights_m))
        _validate(self)

    @property
    def scanner_profile(self) -> ScannerProfile | None:
        """The instrument ``scanner`` stands for (a preset's figures filled in), or None."""
        return None if self.scanner is None else resolve(self.scanner)

    @property
    def tolerance_radius_m(self) -> float:
        """The radius of the placement-tolerance report and of robust planning:
        ``placement_tolerance_m``, else :data:`ROBUST_TOLERANCE_M` for a robust plan, else
        0 (no report)."""
        if self.placement_tolerance_m is not None:
            return self.placement_tolerance_m
        return ROBUST_TOLERANCE_M if self.robust else 0.0

    @property
    def heights_m(self) -> tuple[float, ...]:
        """The instrument heights of generated candidates: ``scanner_heights_m``, or
        ``scanner_height_m`` alone when that is null."""
        return self.scanner_heights_m or (self.scanner_height_m,)

    @property
    def angular_step_rad(self) -> float:
        """SPS: the scanner's angular step, point spacing over its reference distance."""
        return self.point_spacing_m / self.reference_distance_m

    @property
    def setup_per_station_s(self) -> float:
        """Seconds to set up one station: ``setup_time_s``, else the scanner's, else
        :data:`DEFAULT_SETUP_TIME_S`."""
        if self.setup_time_s is not None:
            return self.setup_time_s
        profile = self.scanner_profile
        return DEFAULT_SETUP_TIME_S if profile is None or profile.setup_time_s is None \
            else profile.setup_time_s

    def plan_step_scan(self) -> StationScan | None:
        """One station's scan with ``scanner`` at the plan's step, its setting and seconds
        (None when unknown); None without a scanner."""
        profile = self.scanner_profile
        return None if profile is None else station_scans(
            profile, self.angular_step_rad, self.elevation_min_deg, self.elevation_max_deg,
            [1.0])[0]

    @property
    def station_time_s(self) -> float | None:
        """Seconds to set up one station and scan it at the plan's step: what a budget of
        hours counts for every station; None without a scanner or its scan time."""
        scan = self.plan_step_scan()
        return None if scan is None or scan.scan_s is None \
            else self.setup_per_station_s + scan.scan_s

    def requirement_for(self, group: str) -> GroupRequirement:
        """The overrides for ``group`` (all defaults when it has none)."""
        return self.group_requirements.get(group, GroupRequirement())

    def with_changes(self, **changes: Any) -> PlanSpec:
        """A validated copy with some fields replaced."""
        return replace(self, **changes)

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any]) -> PlanSpec:
        """Build from JSON-like data; unknown keys and wrong types are a :class:`ParameterError`."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ParameterError(
                unknown[0], f"unknown parameter; known ones are {', '.join(sorted(known))}"
            )
        if values.get("scanner") is not None:
            # the profile fills the defaults; what the caller gave explicitly wins. The
            # step stays the plan's (given as a pair: point_spacing_m with its
            # reference_distance_m, else the default) unless no setting is that fine
            scanner = _scanner(values["scanner"])
            assert scanner is not None
            profile = resolve(scanner)
            defaults: dict[str, float] = plan_defaults(profile)
            finest = None if any(values.get(k) is not None for k in (
                "point_spacing_m", "reference_distance_m")) else fallback_step(
                profile, DEFAULT_ANGULAR_STEP_RAD)
            if finest is not None:
                defaults["point_spacing_m"] = finest.point_spacing_m
                defaults["reference_distance_m"] = finest.reference_distance_m
            values = {**defaults, **{k: v for k, v in values.items()
                                     if v is not None or k in _NULLABLE}}
        kwargs: dict[str, Any] = {}
        for name, value in values.items():
            if value is None and name not in _NULLABLE:
                continue
            kwargs[name] = _convert(name, value)
        return cls(**kwargs)

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-ready data, keys sorted by the caller's serializer."""
        data = asdict(self)
        data["group_requirements"] = {
            k: asdict(v) for k, v in sorted(self.group_requirements.items())
        }
        data["route_start"] = None if self.route_start is None else list(self.route_start)
        for key in ("candidates", "area_of_interest", "storeys", "rooms", "curve_goals",
                    "fixed_stations", "scanner_heights_m"):
            value = getattr(self, key)
            data[key] = None if value is None else [
                list(p) if isinstance(p, tuple) else p for p in value
            ]
        return data


# the paper's step (Table 2: 10 mm at 10 m); a scanner keeps it unless no setting is as fine
DEFAULT_ANGULAR_STEP_RAD = PlanSpec.point_spacing_m / PlanSpec.reference_distance_m


@dataclass(frozen=True)
class Range:
    """Bounds of a number parameter: ``ge``/``gt`` below, ``le``/``lt`` above (None: open).

    ``hint`` is appended to the error message: the fix in the user's words.
    """

    ge: float | None = None
    gt: float | None = None
    le: float | None = None
    lt: float | None = None
    hint: str = ""

    def contains(self, value: float) -> bool:
        return ((self.ge is None or value >= self.ge) and (self.gt is None or value > self.gt)
                and (self.le is None or value <= self.le)
                and (self.lt is None or value < self.lt))

    def describe(self) -> str:
        """The interval in words: "greater than 0", "in (0, 1]", "0 or more"."""
        low = self.ge if self.ge is not None else self.gt
        high = self.le if self.le is not None else self.lt
        if high is None:
            return f"{_g(low)} or more" if self.ge is not None else f"greater than {_g(low)}"
        if low is None:
            return f"{_g(high)} or less" if self.le is not None else f"less than {_g(high)}"
        return (f"in {'[' if self.ge is not None else '('}{_g(low)}, {_g(high)}"
                f"{']' if self.le is not None else ')'}")


def _g(number: float | None) -> str:
    return f"{number:g}"


# The one table of ranges: the validator below and the service's OpenAPI schema read it.
# Every bound is finite, so no value the schema accepts overflows the arithmetic after it;
# the upper bounds are generous ceilings (no instrument or site comes near them), not
# instrument figures.
RANGES: dict[str, Range] = {
    "dof_min_m": Range(ge=0, le=10_000),
    "dof_max_m": Range(gt=0, le=10_000),
    "point_spacing_m": Range(gt=0, le=10),
    "reference_distance_m": Range(gt=0, le=10_000),
    "elevation_min_deg": Range(ge=-90, le=90),
    "elevation_max_deg": Range(ge=-90, le=90),
    "min_incidence_deg": Range(ge=0, le=90),
    "min_density_pts_m2": Range(ge=0, le=1e9),
    "coverage_goal": Range(gt=0, le=1, hint="0.8 means 80 % of the achievable area"),
    "optimal_time_limit_s": Range(gt=0, le=86_400, hint="86400 is one day"),
    "max_edge_m": Range(gt=0, le=10_000, hint="or null to use the mesh as given"),
    "unit_scale": Range(gt=0, le=1e6, hint="0.001 for a model in millimetres"),
    "grid_spacing_m": Range(gt=0, le=10_000),
    "scanner_height_m": Range(gt=0, le=1_000),
    "placement_tolerance_m": Range(ge=0, le=5, hint="null or 0 turns the tolerance report off"),
    "clearance_m": Range(ge=0, le=1_000),
    "min_overlap_m2": Range(gt=0, le=1e9, hint="or null for no overlap constraint"),
    "overlap_density_pts_m2": Range(gt=0, le=1e9),
    "overlap_max_edge_m": Range(gt=0, le=10_000,
                                hint="or null to measure the overlap on the coverage's pieces"),
    "setup_time_s": Range(ge=0, le=86_400, hint="or null for the preset's"),
    "walking_speed_m_s": Range(gt=0, le=100, hint="0.8 is a slow walk with a tripod"),
    "samples_per_face": Range(ge=1, le=256, hint="a square number; use 16"),
    "max_stations": Range(ge=1, le=100_000, hint="a budget of stations; null: no budget"),
    "max_field_time_h": Range(gt=0, le=10_000, hint="hours in the field; null: no budget"),
    "min_sampled_fraction": Range(gt=0, le=1, hint="1 means the whole face"),
}
# each coordinate of candidates, fixed_stations, area_of_interest and route_start, in model
# units (a georeferenced model in millimetres has northings near 1e10)
COORDINATE_RANGE = Range(ge=-1e12, le=1e12, hint="coordinates are in model units")
# the most items a list (or, for group_requirements, keys an object) parameter may have
MAX_ITEMS: dict[str, int] = {
    "candidates": 1_000_000, "fixed_stations": 10_000, "area_of_interest": 100_000,
    "curve_goals": 100, "storeys": 10_000, "rooms": 100_000, "group_requirements": 100_000,
    "scanner_heights_m": 16,
}
# the same for the figures of a scanner profile (planner.scanners.ScannerProfile) ...
SCANNER_RANGES: dict[str, Range] = {
    "min_range_m": RANGES["dof_min_m"],
    "max_range_m": RANGES["dof_max_m"],
    "elevation_min_deg": RANGES["elevation_min_deg"],
    "elevation_max_deg": RANGES["elevation_max_deg"],
    "measurement_rate_pts_s": Range(ge=1, le=1e9,
                                    hint="points recorded per second, e.g. 2000000"),
    "setup_time_s": RANGES["setup_time_s"],
    "overhead_s": Range(ge=0, le=86_400, hint="imaging, tilt and any other constant per scan"),
}
# ... and of each of its settings (planner.scanners.ScanSetting)
SETTING_RANGES: dict[str, Range] = {
    "point_spacing_m": RANGES["point_spacing_m"],
    "reference_distance_m": RANGES["reference_distance_m"],
    "duration_s": Range(gt=0, le=86_400,
                        hint="or leave it out to compute it from measurement_rate_pts_s"),
}
MAX_SETTINGS = 32
# the finest angular step a setting may have: 0.01 mm at 10 m, far below any instrument's
MIN_STEP_RAD = 1e-6
# the same for the per-group overrides (GroupRequirement)
GROUP_RANGES: dict[str, Range] = {
    "min_density_pts_m2": RANGES["min_density_pts_m2"],
    "min_incidence_deg": RANGES["min_incidence_deg"],
}


_NULLABLE = {"max_edge_m", "candidates", "area_of_interest", "storeys", "rooms",
             "curve_goals", "fixed_stations", "scanner", "min_overlap_m2", "route_start",
             "setup_time_s", "up_axis", "scanner_heights_m", "placement_tolerance_m",
             "max_stations", "overlap_max_edge_m", "max_field_time_h"}
_FLOATS = {
    f.name
    for f in fields(PlanSpec)
    if f.type in ("float", "float | None")
}


def _number(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ParameterError(name, f"expected a number, got {value!r}")
    number = float(value)
    if not math.isfinite(number):
        raise ParameterError(name, f"expected a finite number, got {value!r}")
    return number


def _convert(name: str, value: Any) -> Any:
    if name in _FLOATS:
        return None if value is None else _number(name, value)
    if name == "method":
        if value not in METHODS:
            raise ParameterError(name, f"{value!r} is not one of {', '.join(METHODS)}")
        return value
    if name == "glb_compression":
        if value not in GLB_COMPRESSIONS:
            raise ParameterError(name, f"{value!r} is not one of {', '.join(GLB_COMPRESSIONS)}; "
                                       "use none for glTF loaders without a meshopt decoder")
        return value
    if name == "floor_levels":
        if value not in FLOOR_LEVELS:
            raise ParameterError(name, f"{value!r} is not one of {', '.join(FLOOR_LEVELS)}")
        return value
    if name == "up_axis":
        if value is not None and value not in UP_AXES:
            raise ParameterError(name, f"{value!r} is not one of {', '.join(UP_AXES)}, "
                                 "or null for the format's own")
        return value
    if name == "coverage_model":
        if value not in COVERAGE_MODELS:
            raise ParameterError(name, f"{value!r} is not one of {', '.join(COVERAGE_MODELS)}")
        return value
    if name in ("verify", "robust", "exact_rays"):
        if not isinstance(value, bool):
            raise ParameterError(name, f"expected true or false, got {value!r}")
        return value
    if name == "max_stations":
        if value is not None and (isinstance(value, bool) or not isinstance(value, int)):
            raise ParameterError(name, f"expected a whole number of stations or null, got "
                                 f"{value!r}")
        return value
    if name == "samples_per_face":
        if isinstance(value, bool) or not isinstance(value, int):
            raise ParameterError(name, f"expected a whole number (1, 4, 9, 16, ...), got {value!r}")
        return value
    if name == "occluders":
        if value not in OCCLUDERS:
            raise ParameterError(name, f"{value!r} is not one of {', '.join(OCCLUDERS)}")
        return value
    if name in ("candidates", "fixed_stations"):
        return None if value is None else _points(name, value, 3)
    if name == "scanner_heights_m":
        if value is None:
            return None
        if not isinstance(value, list | tuple):
            raise ParameterError(name, "expected a list of heights in metres, e.g. [1.2, 1.5, 1.8]")
        return tuple(_number(f"{name}[{i}]", v) for i, v in enumerate(value))
    if name == "curve_goals":
        if value is None:
            return None
        if not isinstance(value, list | tuple):
            raise ParameterError(name, "expected a list of goals in (0, 1], e.g. [0.8, 1.0]")
        return tuple(_number(f"{name}[{i}]", v) for i, v in enumerate(value))
    if name == "area_of_interest":
        return None if value is None else _points(name, value, 2)
    if name == "route_start":
        return None if value is None else _points(name, [value], 3)[0]
    if name in ("storeys", "rooms"):
        if value is None:
            return None
        if not isinstance(value, list | tuple) or not all(isinstance(v, str) for v in value):
            raise ParameterError(name, "expected a list of names or GlobalIds")
        return tuple(value)
    if name == "group_requirements":
        return _group_requirements(value)
    if name == "scanner":
        return _scanner(value)
    return value


def _points(name: str, value: Any, dims: int) -> tuple[tuple[float, ...], ...]:
    if not isinstance(value, list | tuple):
        raise ParameterError(name, f"expected a list of [{', '.join('xyz'[:dims])}] points")
    points = []
    for i, point in enumerate(value):
        if not isinstance(point, list | tuple) or len(point) != dims:
            raise ParameterError(
                name, f"point {i} is {point!r}; each point needs exactly {dims} coordinates"
            )
        coordinates = tuple(_number(f"{name}[{i}]", c) for c in point)
        for c in coordinates:
            check_range(f"{name}[{i}]", c, COORDINATE_RANGE)
        points.append(coordinates)
    return tuple(points)


def _group_requirements(value: Any) -> dict[str, GroupRequirement]:
    if not isinstance(value, Mapping):
        raise ParameterError("group_requirements", "expected an object keyed by group name")
    known = {f.name for f in fields(GroupRequirement)}
    result: dict[str, GroupRequirement] = {}
    for group, overrides in value.items():
        where = f"group_requirements.{group}"
        if isinstance(overrides, GroupRequirement):
            result[str(group)] = overrides
            continue
        if not isinstance(overrides, Mapping):
            raise ParameterError(where, f"expected an object with keys {sorted(known)}")
        unknown = sorted(set(overrides) - known)
        if unknown:
            raise ParameterError(f"{where}.{unknown[0]}", f"unknown key; use {sorted(known)}")
        kwargs: dict[str, Any] = {}
        for key, item in overrides.items():
            if key in ("target", "occludes"):
                if not isinstance(item, bool):
                    raise ParameterError(f"{where}.{key}", f"expected true or false, got {item!r}")
                kwargs[key] = item
            elif item is not None:
                kwargs[key] = _number(f"{where}.{key}", item)
        result[str(group)] = GroupRequirement(**kwargs)
    return result


def _scanner(value: Any) -> str | ScannerProfile | None:
    """A preset id or a :class:`ScannerProfile` from plain data (ranges: :func:`_validate`)."""
    if value is None or isinstance(value, ScannerProfile):
        return value
    if isinstance(value, str):
        preset(value)  # raises, naming the known presets
        return value
    if not isinstance(value, Mapping):
        raise ParameterError("scanner", "expected a preset id (scanplan scanners lists them) or "
                                        "an object {name, measurement_rate_pts_s, settings, ...}")
    _known_keys("scanner", value, PROFILE_FIELDS)
    kwargs: dict[str, Any] = {"name": _text("scanner.name", value.get("name"))}
    if value.get("preset") is not None:
        kwargs["preset"] = _text("scanner.preset", value["preset"])
        if kwargs["preset"] not in _preset_ids():
            raise ParameterError("scanner.preset", f"{kwargs['preset']!r} is not a known preset; "
                                 f"use one of {', '.join(_preset_ids())} or leave it out")
    for key in SCANNER_RANGES:
        if value.get(key) is not None:
            kwargs[key] = _number(f"scanner.{key}", value[key])
    settings = value.get("settings") or []
    if not isinstance(settings, list | tuple):
        raise ParameterError("scanner.settings", "expected a list of {name, point_spacing_m, "
                                                 "reference_distance_m, duration_s?}")
    kwargs["settings"] = tuple(_setting(f"scanner.settings[{i}]", s)
                               for i, s in enumerate(settings))
    return ScannerProfile(**kwargs)


def _preset_ids() -> list[str]:
    from planner.scanners import presets

    return list(presets())


def _setting(where: str, value: Any) -> ScanSetting:
    if isinstance(value, ScanSetting):
        return value
    if not isinstance(value, Mapping):
        raise ParameterError(where, "expected an object {name, point_spacing_m, "
                                    "reference_distance_m, duration_s?}")
    _known_keys(where, value, SETTING_FIELDS)
    kwargs: dict[str, Any] = {"name": _text(f"{where}.name", value.get("name"))}
    for key in ("point_spacing_m", "reference_distance_m"):
        if value.get(key) is None:
            raise ParameterError(f"{where}.{key}", "is missing; a setting is a point spacing at "
                                 "a distance, e.g. point_spacing_m 0.006, reference_distance_m 10")
        kwargs[key] = _number(f"{where}.{key}", value[key])
    if value.get("duration_s") is not None:
        kwargs["duration_s"] = _number(f"{where}.duration_s", value["duration_s"])
    return ScanSetting(**kwargs)


def _known_keys(where: str, value: Mapping[str, Any], known: tuple[str, ...]) -> None:
    unknown = sorted(set(value) - set(known))
    if unknown:
        raise ParameterError(f"{where}.{unknown[0]}", f"unknown key; use {', '.join(known)}")


def _text(name: str, value: Any) -> str:
    if not isinstance(value, str) or not value.strip() or len(value) > 100:
        raise ParameterError(name, f"expected a name of 1 to 100 characters, got {value!r}")
    return value


def _check_scanner(spec: PlanSpec) -> None:
    """The ranges of the scanner object's figures, and the plan's step against its settings."""
    profile = spec.scanner_profile
    if profile is None:
        return
    if isinstance(spec.scanner, ScannerProfile):  # a preset's figures are checked by its tests
        for key, bounds in SCANNER_RANGES.items():
            check_range(f"scanner.{key}", getattr(spec.scanner, key), bounds)
        for i, setting in enumerate(spec.scanner.settings):
            for key, bounds in SETTING_RANGES.items():
                check_range(f"scanner.settings[{i}].{key}", getattr(setting, key), bounds)
            step = setting.angular_step_rad
            _check(MIN_STEP_RAD <= step < math.pi, f"scanner.settings[{i}].point_spacing_m",
                   f"{setting.point_spacing_m} m at {setting.reference_distance_m} m is an "
                   f"angular step of {step:g} rad; a scanner's step lies between "
                   f"{MIN_STEP_RAD:g} rad (0.01 mm at 10 m) and pi")
        _check(len(spec.scanner.settings) <= MAX_SETTINGS, "scanner.settings",
               f"has {len(spec.scanner.settings)} settings; at most {MAX_SETTINGS}")
        names = [s.name for s in spec.scanner.settings]
        _check(len(set(names)) == len(names), "scanner.settings",
               f"names must differ, got {names}")
    low, high = profile.min_range_m, profile.max_range_m
    _check(low is None or high is None or low < high, "scanner.min_range_m",
           f"{low} must be less than scanner.max_range_m ({high})")
    low, high = profile.elevation_min_deg, profile.elevation_max_deg
    _check(low is None or high is None or low < high, "scanner.elevation_min_deg",
           f"{low} must be less than scanner.elevation_max_deg ({high})")
    finest = profile.finest()
    if finest is not None:
        # every station must be scannable at some setting: the plan's promise may not need
        # a finer step than the finest the instrument has
        _check(spec.angular_step_rad >= finest.angular_step_rad * (1 - STEP_TOLERANCE),
               "point_spacing_m",
               f"{spec.point_spacing_m} m at {spec.reference_distance_m} m is finer than the "
               f"finest setting of scanner {profile.name!r} ({finest.name}: "
               f"{finest.point_spacing_m} m at {finest.reference_distance_m} m); give a "
               "coarser one, or leave point_spacing_m and reference_distance_m out (the plan "
               "then keeps 0.01 m at 10 m, or the finest setting when none is that fine)")


def _check_time_budget(spec: PlanSpec) -> None:
    """A field-time budget: a greedy method, and a scanner whose scan at the plan's step
    has a known duration (the budget counts it for every station)."""
    _check(spec.method != "optimal", "max_field_time_h",
           "plans a budget with greedy or weighted_greedy (the most coverage in that much "
           "field time); optimal finds the fewest stations for the goal: drop one of them")
    profile = spec.scanner_profile
    _check(profile is not None, "max_field_time_h",
           "needs a scanner (a preset id or a profile with measurement_rate_pts_s): the "
           "budget counts each station's scan time")
    assert profile is not None
    one_s = spec.station_time_s
    if one_s is None:
        scan = spec.plan_step_scan()
        assert scan is not None
        raise ParameterError("max_field_time_h", "needs each station's scan time, which is "
                             "unknown: " + missing_duration_reason(profile, (scan,)))
    _check(spec.max_field_time_h is None or spec.max_field_time_h * 3600.0 >= one_s,
           "max_field_time_h", f"{spec.max_field_time_h:g} h is less than one station's "
           f"setup and scan ({one_s / 60.0:.1f} min with {profile.name}); raise it")


def _check(ok: bool, name: str, message: str) -> None:
    if not ok:
        raise ParameterError(name, message)


def check_range(name: str, value: float | None, bounds: Range) -> None:
    """A :class:`ParameterError` naming ``name`` when ``value`` is out of ``bounds``."""
    if value is None or bounds.contains(value):
        return
    hint = f"; {bounds.hint}" if bounds.hint else ""
    if bounds.ge == 0 and value < 0:
        use = "0 or more" if bounds.le is None else f"a value {bounds.describe()}"
        raise ParameterError(name, f"{value} is negative; use {use}{hint}")
    raise ParameterError(name, f"{value} must be {bounds.describe()}{hint}")


def _validate(spec: PlanSpec) -> None:
    _check_scanner(spec)  # first: the profile's figures are the defaults checked below
    for name, bounds in RANGES.items():
        check_range(name, getattr(spec, name), bounds)
    for name, most in MAX_ITEMS.items():
        items = getattr(spec, name)
        _check(items is None or len(items) <= most, name,
               f"has {0 if items is None else len(items)} items, more than {most}")
    _check(
        spec.dof_min_m < spec.dof_max_m,
        "dof_min_m",
        f"{spec.dof_min_m} must be less than dof_max_m ({spec.dof_max_m})",
    )
    _check(
        spec.elevation_min_deg < spec.elevation_max_deg,
        "elevation_min_deg",
        f"elevation_min_deg ({spec.elevation_min_deg}) must be less than elevation_max_deg "
        f"({spec.elevation_max_deg})",
    )
    _check(spec.method in METHODS, "method", f"{spec.method!r} is not one of {METHODS}")
    _check(spec.glb_compression in GLB_COMPRESSIONS, "glb_compression",
           f"{spec.glb_compression!r} is not one of {GLB_COMPRESSIONS}")
    _check(spec.floor_levels in FLOOR_LEVELS, "floor_levels",
           f"{spec.floor_levels!r} is not one of {', '.join(FLOOR_LEVELS)}")
    _check(spec.up_axis is None or spec.up_axis in UP_AXES, "up_axis",
           f"{spec.up_axis!r} is not one of {', '.join(UP_AXES)}, or null for the format's own")
    _check(spec.coverage_model in COVERAGE_MODELS, "coverage_model",
           f"{spec.coverage_model!r} is not one of {COVERAGE_MODELS}")
    _check(
        1 <= spec.samples_per_face <= 256
        and math.isqrt(spec.samples_per_face) ** 2 == spec.samples_per_face,
        "samples_per_face",
        f"{spec.samples_per_face} is not a square number from 1 to 256 (the samples form an "
        "n x n barycentric grid); use 16",
    )
    _check(spec.occluders in OCCLUDERS, "occluders",
           f"{spec.occluders!r} is not one of {OCCLUDERS}")
    if spec.candidates is not None:
        _check(len(spec.candidates) > 0, "candidates",
               "is an empty list; give at least one [x, y, z] or null to generate a grid")
    if spec.curve_goals is not None:
        for i, goal in enumerate(spec.curve_goals):
            _check(0 < goal <= 1, f"curve_goals[{i}]",
                   f"{goal} is outside (0, 1]; 0.8 means 80 % of the achievable area")
    if spec.scanner_heights_m is not None:
        _check(len(spec.scanner_heights_m) > 0, "scanner_heights_m",
               "is an empty list; give at least one height or null for scanner_height_m")
        _check(len(set(spec.scanner_heights_m)) == len(spec.scanner_heights_m),
               "scanner_heights_m", f"{list(spec.scanner_heights_m)} repeats a height")
        for i, height in enumerate(spec.scanner_heights_m):
            check_range(f"scanner_heights_m[{i}]", height, RANGES["scanner_height_m"])
        _check(spec.candidates is None, "scanner_heights_m",
               "applies to generated candidates; explicit candidates carry their own z "
               "(leave scanner_heights_m null or drop candidates)")
    if spec.max_stations is not None:
        _check(spec.method != "optimal", "max_stations",
               "plans a budget with greedy or weighted_greedy (the most coverage in that many "
               "stations); optimal finds the fewest stations for the goal: drop one of them")
        _check(spec.fixed_stations is None or spec.max_stations >= len(spec.fixed_stations),
               "max_stations", "is below the number of fixed_stations, which every plan "
               "keeps; raise it or drop stations from fixed_stations")
    if spec.max_field_time_h is not None:
        _check_time_budget(spec)
    _check(not spec.robust or spec.tolerance_radius_m > 0, "robust",
           "needs placement_tolerance_m greater than 0 or null (the radius a setup may be "
           f"off; null: {ROBUST_TOLERANCE_M} m)")
    if spec.area_of_interest is not None:
        _check(len(spec.area_of_interest) >= 3, "area_of_interest",
               "needs at least 3 [x, y] vertices")
    for group, req in spec.group_requirements.items():
        for name, bounds in GROUP_RANGES.items():
            check_range(f"group_requirements.{group}.{name}", getattr(req, name), bounds)
