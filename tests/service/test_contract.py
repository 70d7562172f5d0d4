"""Things that must not drift: parameter schema vs PlanSpec, openapi.json vs the app."""

from __future__ import annotations

from dataclasses import fields
from pathlib import Path

from planner.parameters import GroupRequirement, PlanSpec
from service.openapi_export import render, spec
from service.problems import PROBLEMS, kind_of
from service.schemas import DEFAULTS, GroupRequirementModel, PlanParameters

ROOT = Path(__file__).resolve().parents[2]


def test_parameter_fields_match_planspec() -> None:
    assert set(PlanParameters.model_fields) == {f.name for f in fields(PlanSpec)}
    assert set(GroupRequirementModel.model_fields) == {f.name for f in fields(GroupRequirement)}
    for name, info in PlanParameters.model_fields.items():
        assert info.default == DEFAULTS[name], name


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
