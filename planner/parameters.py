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
}
# the same for the per-group overrides (GroupRequirement)
GROUP_RANGES: dict[str, Range] = {
    "min_density_pts_m2": RANGES["min_density_pts_m2"],
    "min_incidence_deg": RANGES["min_incidence_deg"],
}


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
    if spec.candidates is not None:
        _check(len(spec.candidates) > 0, "candidates",
               "is an empty list; give at least one [x, y, z] or null to generate a grid")
    if spec.area_of_interest is not None:
        _check(len(spec.area_of_interest) >= 3, "area_of_interest",
               "needs at least 3 [x, y] vertices")
    for group, req in spec.group_requirements.items():
        for name, bounds in GROUP_RANGES.items():
            check_range(f"group_requirements.{group}.{name}", getattr(req, name), bounds)
