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
    # coverage model (planner.method.sampled): "centroid" is the paper's one ray per face
    coverage_model: CoverageModel = "centroid"
    samples_per_face: int = 16
    min_sampled_fraction: float = 1.0
    # selection
    method: Method = "greedy"
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
    # survey (issue 11): presets, registration overlap, walking route, field time
    scanner: str | None = None  # a preset of planner/survey/scanners.json; sets the defaults above
    min_overlap_m2: float | None = None  # null: the paper's selection, no overlap constraint
    # a surface counts for registration at this density: 25 mm x 25 mm, the data density of
    # Level of Detail 2 in GSA BIM Guide Series 03, 3D Imaging (U.S. GSA, 2009)
    overlap_density_pts_m2: float = 1600.0
    route_start: tuple[float, float, float] | None = None  # null: the route chooses
    setup_time_s: float | None = None  # per station; null: the preset's, else 60 s
    walking_speed_m_s: float = 0.8

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
        _validate(self)

    @property
    def angular_step_rad(self) -> float:
        """SPS: the scanner's angular step, point spacing over its reference distance."""
        return self.point_spacing_m / self.reference_distance_m

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
            if not isinstance(values["scanner"], str):
                raise ParameterError("scanner", f"expected a preset id, got {values['scanner']!r}")
            from planner.survey.scanners import preset_defaults

            # the preset fills the defaults; what the caller gave explicitly wins
            values = {**preset_defaults(values["scanner"]), **values}
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
                    "fixed_stations"):
            value = getattr(self, key)
            data[key] = None if value is None else [
                list(p) if isinstance(p, tuple) else p for p in value
            ]
        return data


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
RANGES: dict[str, Range] = {
    "dof_min_m": Range(ge=0),
    "dof_max_m": Range(gt=0),
    "point_spacing_m": Range(gt=0),
    "reference_distance_m": Range(gt=0),
    "elevation_min_deg": Range(ge=-90, le=90),
    "elevation_max_deg": Range(ge=-90, le=90),
    "min_incidence_deg": Range(ge=0, le=90),
    "min_density_pts_m2": Range(ge=0),
    "coverage_goal": Range(gt=0, le=1, hint="0.8 means 80 % of the achievable area"),
    "optimal_time_limit_s": Range(gt=0),
    "max_edge_m": Range(gt=0, hint="or null to use the mesh as given"),
    "unit_scale": Range(gt=0, hint="0.001 for a model in millimetres"),
    "grid_spacing_m": Range(gt=0),
    "scanner_height_m": Range(gt=0),
    "clearance_m": Range(ge=0),
    "min_overlap_m2": Range(gt=0, hint="or null for no overlap constraint"),
    "overlap_density_pts_m2": Range(gt=0),
    "setup_time_s": Range(ge=0, hint="or null for the preset's"),
    "walking_speed_m_s": Range(gt=0, hint="0.8 is a slow walk with a tripod"),
    "samples_per_face": Range(ge=1, le=256, hint="a square number; use 16"),
    "min_sampled_fraction": Range(gt=0, le=1, hint="1 means the whole face"),
}
# the same for the per-group overrides (GroupRequirement)
GROUP_RANGES: dict[str, Range] = {
    "min_density_pts_m2": RANGES["min_density_pts_m2"],
    "min_incidence_deg": RANGES["min_incidence_deg"],
}


_NULLABLE = {"max_edge_m", "candidates", "area_of_interest", "storeys", "rooms",
             "curve_goals", "fixed_stations", "scanner", "min_overlap_m2", "route_start",
             "setup_time_s", "up_axis"}
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
    if name == "verify":
        if not isinstance(value, bool):
            raise ParameterError(name, f"expected true or false, got {value!r}")
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
        points.append(tuple(_number(f"{name}[{i}]", c) for c in point))
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


def _check(ok: bool, name: str, message: str) -> None:
    if not ok:
        raise ParameterError(name, message)


def check_range(name: str, value: float | None, bounds: Range) -> None:
    """A :class:`ParameterError` naming ``name`` when ``value`` is out of ``bounds``."""
    if value is None or bounds.contains(value):
        return
    hint = f"; {bounds.hint}" if bounds.hint else ""
    if bounds.ge == 0 and bounds.le is None and value < 0:
        raise ParameterError(name, f"{value} is negative; use 0 or more{hint}")
    raise ParameterError(name, f"{value} must be {bounds.describe()}{hint}")


def _validate(spec: PlanSpec) -> None:
    for name, bounds in RANGES.items():
        check_range(name, getattr(spec, name), bounds)
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
    if spec.area_of_interest is not None:
        _check(len(spec.area_of_interest) >= 3, "area_of_interest",
               "needs at least 3 [x, y] vertices")
    if spec.scanner is not None:
        from planner.survey.scanners import get

        get(spec.scanner)  # raises, naming the known presets
    for group, req in spec.group_requirements.items():
        for name, bounds in GROUP_RANGES.items():
            check_range(f"group_requirements.{group}.{name}", getattr(req, name), bounds)
