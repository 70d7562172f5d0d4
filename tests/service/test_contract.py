"""Things that must not drift: parameter schema vs PlanSpec, openapi.json vs the app."""

from __future__ import annotations

import math
from dataclasses import fields
from pathlib import Path
from typing import Any

from planner.parameters import GroupRequirement, PlanSpec
from service.openapi_export import render, spec
from service.problems import PROBLEMS, kind_of
from service.schemas import (
    DEFAULTS,
    GroupRequirementModel,
    PlanParameters,
    ScannerProfileModel,
    ScanSettingModel,
)

ROOT = Path(__file__).resolve().parents[2]


def test_parameter_fields_match_planspec() -> None:
    assert set(PlanParameters.model_fields) == {f.name for f in fields(PlanSpec)}
    assert set(GroupRequirementModel.model_fields) == {f.name for f in fields(GroupRequirement)}
    for name, info in PlanParameters.model_fields.items():
        assert info.default == DEFAULTS[name], name


def test_scanner_object_matches_the_profile_and_its_ranges() -> None:
    from planner.parameters import SCANNER_RANGES, SETTING_RANGES
    from planner.scanners import PROFILE_FIELDS, SETTING_FIELDS

    assert tuple(ScannerProfileModel.model_fields) == PROFILE_FIELDS
    assert tuple(ScanSettingModel.model_fields) == SETTING_FIELDS
    keywords = {"ge": "minimum", "gt": "exclusiveMinimum", "le": "maximum",
                "lt": "exclusiveMaximum"}
    for model, table in ((ScannerProfileModel, SCANNER_RANGES), (ScanSettingModel, SETTING_RANGES)):
        properties = model.model_json_schema()["properties"]
        for name, bounds in table.items():
            schema = properties[name]
            number = next(s for s in schema.get("anyOf", [schema]) if s.get("type") == "number")
            for attribute, keyword in keywords.items():
                assert number.get(keyword) == getattr(bounds, attribute), (name, keyword)


def test_openapi_json_is_current() -> None:
    checked_in = ROOT / "openapi" / "openapi.json"
    assert checked_in.read_text(encoding="utf-8") == render(spec()), (
        "openapi/openapi.json differs from the app; run `make openapi` and commit it")


def test_every_planner_error_has_a_status() -> None:
    from planner import errors

    for name in dir(errors):
        cls = getattr(errors, name)
        if isinstance(cls, type) and issubclass(cls, errors.PlannerError):
            assert kind_of(cls.__new__(cls)).status in (409, 415, 422), name
    assert all(400 <= kind.status < 600 for kind in PROBLEMS.values())


def test_schema_ranges_are_the_validators() -> None:
    """Each bound of RANGES is in the schema, and both sides agree at and past the bound."""
    import pytest
    from pydantic import ValidationError

    from planner.errors import ParameterError
    from planner.parameters import RANGES

    properties = PlanParameters.model_json_schema()["properties"]
    keywords = {"ge": "minimum", "gt": "exclusiveMinimum", "le": "maximum",
                "lt": "exclusiveMaximum"}
    assert set(RANGES) <= set(properties)
    for name, bounds in RANGES.items():
        schema = properties[name]
        number = next(s for s in schema.get("anyOf", [schema])
                      if s.get("type") in ("number", "integer"))
        step = 1 if number["type"] == "integer" else 1e-6
        for attribute, keyword in keywords.items():
            assert number.get(keyword) == getattr(bounds, attribute), (name, keyword)
        # the values at and just past each bound: accepted or refused by both alike
        edges = [v for v in (bounds.ge, bounds.gt, bounds.le, bounds.lt) if v is not None]
        for value in [e + d for e in edges for d in (-step, 0, step)]:
            value = int(value) if step == 1 else value
            schema_ok = True
            try:
                PlanParameters.model_validate({name: value})
            except ValidationError:
                schema_ok = False
            planner_ok = bounds.contains(value)
            assert schema_ok == planner_ok, (name, value)
            if not planner_ok:
                with pytest.raises(ParameterError):
                    from planner.parameters import check_range

                    check_range(name, value, bounds)


def _accepted_schemas(document: dict[str, Any]) -> list[tuple[str, dict[str, Any]]]:
    """(where, schema) of every request parameter and body of the OpenAPI document."""
    found = []
    for path, operations in document["paths"].items():
        for method, operation in operations.items():
            for parameter in operation.get("parameters", []):
                found.append((f"{method} {path} {parameter['name']}", parameter["schema"]))
            for media, content in operation.get("requestBody", {}).get("content", {}).items():
                found.append((f"{method} {path} body {media}", content.get("schema", {})))
    return found


def _unbounded(document: dict[str, Any], schema: Any, where: str,
               seen: frozenset[str] = frozenset()) -> list[str]:
    """Every number without a finite bound on each side and every list without maxItems."""
    if isinstance(schema, list):
        return [w for i, s in enumerate(schema) for w in _unbounded(document, s, where, seen)]
    if not isinstance(schema, dict):
        return []
    if "$ref" in schema:
        ref = schema["$ref"]
        if ref in seen:
            return []
        target: Any = document
        for part in ref.removeprefix("#/").split("/"):
            target = target[part]
        return _unbounded(document, target, f"{where} > {ref.rsplit('/', 1)[-1]}", seen | {ref})
    problems = []
    kind = schema.get("type")
    if kind in ("number", "integer"):
        low = schema.get("minimum", schema.get("exclusiveMinimum"))
        high = schema.get("maximum", schema.get("exclusiveMaximum"))
        if low is None or high is None or not math.isfinite(low) or not math.isfinite(high):
            problems.append(f"{where}: {kind} in [{low}, {high}]")
    if kind == "array" and "maxItems" not in schema:
        problems.append(f"{where}: array without maxItems")
    if kind == "object" and isinstance(schema.get("additionalProperties"), dict) \
            and "maxProperties" not in schema:
        problems.append(f"{where}: object keyed by the client without maxProperties")
    for key, value in schema.items():
        if key == "properties":
            for name, item in value.items():
                problems += _unbounded(document, item, f"{where}.{name}", seen)
        elif key in ("items", "additionalProperties", "anyOf", "oneOf", "allOf"):
            problems += _unbounded(document, value, where, seen)
    return problems


def test_every_number_and_list_the_api_accepts_is_bounded() -> None:
    """No schema-valid request carries a number or a list the database or planner cannot take
    (an offset of 2.7e21 was a 500): finite bounds on each side, maxItems on every list."""
    document = spec()
    problems = [p for where, schema in _accepted_schemas(document)
                for p in _unbounded(document, schema, where)]
    assert problems == []
