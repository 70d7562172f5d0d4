"""Things that must not drift: parameter schema vs PlanSpec, openapi.json vs the app."""

from __future__ import annotations

from dataclasses import fields
from pathlib import Path

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
