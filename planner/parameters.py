"""Every knob of a plan, with the defaults of the paper's Table 2.

The names are the API contract: the CLI's ``--params`` JSON, the service's request body and
``plan.json`` all use exactly these keys. :class:`PlanSpec` is frozen; build one with
:meth:`PlanSpec.from_mapping`, which validates and names the offending key in its error.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, fields, replace
from typing import Any, Literal

from planner.errors import ParameterError

Method = Literal["greedy", "weighted_greedy", "optimal"]
METHODS: tuple[Method, ...] = ("greedy", "weighted_greedy", "optimal")
Occluders = Literal["remeshed", "file"]
OCCLUDERS: tuple[Occluders, ...] = ("remeshed", "file")


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
    # selection
    method: Method = "greedy"
    optimal_time_limit_s: float = 60.0
    # scene preparation
    max_edge_m: float | None = 0.2
    unit_scale: float = 1.0
    # visibility: rays tested against the remeshed pieces, or the file's own faces (a ray
    # cache the size of the file; coincident faces may then break ties differently)
    occluders: Occluders = "remeshed"
    # candidates
    candidates: tuple[tuple[float, float, float], ...] | None = None
    grid_spacing_m: float = 0.5
    scanner_height_m: float = 1.5
    clearance_m: float = 0.3
    area_of_interest: tuple[tuple[float, float], ...] | None = None
    storeys: tuple[str, ...] | None = None
    rooms: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        # accept plain data too (dicts, lists), as from_mapping does
        object.__setattr__(self, "group_requirements",
                           _group_requirements(self.group_requirements))
        for name, dims in (("candidates", 3), ("area_of_interest", 2)):
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, _points(name, value, dims))
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
        for key in ("candidates", "area_of_interest", "storeys", "rooms"):
            value = getattr(self, key)
            data[key] = None if value is None else [
                list(p) if isinstance(p, tuple) else p for p in value
            ]
        return data


_NULLABLE = {"max_edge_m", "candidates", "area_of_interest", "storeys", "rooms"}
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
    if name == "occluders":
        if value not in OCCLUDERS:
            raise ParameterError(name, f"{value!r} is not one of {', '.join(OCCLUDERS)}")
        return value
    if name == "candidates":
        return None if value is None else _points(name, value, 3)
    if name == "area_of_interest":
        return None if value is None else _points(name, value, 2)
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


def _validate(spec: PlanSpec) -> None:
    _check(spec.dof_min_m >= 0, "dof_min_m", f"{spec.dof_min_m} is negative; use 0 or more")
    _check(
        spec.dof_min_m < spec.dof_max_m,
        "dof_min_m",
        f"{spec.dof_min_m} must be less than dof_max_m ({spec.dof_max_m})",
    )
    for name in ("point_spacing_m", "reference_distance_m", "grid_spacing_m",
                 "unit_scale", "optimal_time_limit_s"):
        value = getattr(spec, name)
        _check(value > 0, name, f"{value} must be greater than 0")
    _check(
        spec.max_edge_m is None or spec.max_edge_m > 0,
        "max_edge_m",
        f"{spec.max_edge_m} must be greater than 0, or null to use the mesh as given",
    )
    _check(
        -90 <= spec.elevation_min_deg < spec.elevation_max_deg <= 90,
        "elevation_min_deg",
        f"need -90 <= elevation_min_deg ({spec.elevation_min_deg}) < elevation_max_deg "
        f"({spec.elevation_max_deg}) <= 90",
    )
    _check(
        0 <= spec.min_incidence_deg <= 90,
        "min_incidence_deg",
        f"{spec.min_incidence_deg} is outside [0, 90]",
    )
    _check(
        spec.min_density_pts_m2 >= 0,
        "min_density_pts_m2",
        f"{spec.min_density_pts_m2} is negative; use 0 or more",
    )
    _check(
        0 < spec.coverage_goal <= 1,
        "coverage_goal",
        f"{spec.coverage_goal} is outside (0, 1]; 0.8 means 80 % of the achievable area",
    )
    _check(spec.method in METHODS, "method", f"{spec.method!r} is not one of {METHODS}")
    _check(spec.occluders in OCCLUDERS, "occluders",
           f"{spec.occluders!r} is not one of {OCCLUDERS}")
    _check(spec.scanner_height_m > 0, "scanner_height_m",
           f"{spec.scanner_height_m} must be greater than 0")
    _check(spec.clearance_m >= 0, "clearance_m", f"{spec.clearance_m} is negative")
    if spec.candidates is not None:
        _check(len(spec.candidates) > 0, "candidates",
               "is an empty list; give at least one [x, y, z] or null to generate a grid")
    if spec.area_of_interest is not None:
        _check(len(spec.area_of_interest) >= 3, "area_of_interest",
               "needs at least 3 [x, y] vertices")
    for group, req in spec.group_requirements.items():
        where = f"group_requirements.{group}"
        if req.min_density_pts_m2 is not None:
            _check(req.min_density_pts_m2 >= 0, f"{where}.min_density_pts_m2",
                   f"{req.min_density_pts_m2} is negative")
        if req.min_incidence_deg is not None:
            _check(0 <= req.min_incidence_deg <= 90, f"{where}.min_incidence_deg",
                   f"{req.min_incidence_deg} is outside [0, 90]")
