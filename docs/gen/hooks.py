"""MkDocs hooks: tables generated from the code at build time, so the pages cannot drift.

A page asks for a table with a marker on a line of its own; :func:`on_page_markdown`
replaces it:

- ``<!-- generated: plan-parameters -->``: every field of ``planner.parameters.PlanSpec``
  with its default, its range from ``RANGES`` (or its choices, or its most items) and the
  description the HTTP schema gives it (``openapi/openapi.json``);
- ``<!-- generated: nested-ranges -->``: the ranges of the scanner object, its settings,
  the group requirements and the coordinates;
- ``<!-- generated: service-settings -->``: every field of ``service.config.Settings`` with
  its environment variable, default and description;
- ``<!-- generated: cli-help -->``: the ``--help`` of ``scanplan`` and of each subcommand
  (the service's ``serve`` and ``worker`` included, through their entry point);
- ``<!-- generated: benchmark-matrix -->``: the rows of ``benchmarks/matrix_baseline.json``
  when the file exists.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import sys
import typing
from collections.abc import Callable
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
OPENAPI = ROOT / "openapi" / "openapi.json"
MATRIX = ROOT / "benchmarks" / "matrix_baseline.json"

log = logging.getLogger("mkdocs.hooks.scanplan")


def _import_root() -> None:
    """Import ``planner`` and ``service`` from this checkout, whatever is installed."""
    root = str(ROOT)
    if root not in sys.path:
        sys.path.insert(0, root)


def _cell(value: Any) -> str:
    """Text for a Markdown table cell: pipes escaped, no line breaks."""
    return str(value).replace("|", "\\|").replace("\n", " ")


def _json(value: Any) -> str:
    """A default as the JSON a user writes (null, [1.2, 1.5], {})."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        value = dataclasses.asdict(value)
    return json.dumps(value, ensure_ascii=False, default=list)


def _number(value: float) -> str:
    return f"{value:g}"


def _range_text(bounds: Any) -> str:
    """The interval in the validator's own words, and its hint."""
    text = bounds.describe()
    return f"{text} ({bounds.hint})" if bounds.hint else text


def _schema_descriptions(schema: str) -> dict[str, str]:
    """``property -> description`` of one schema of openapi/openapi.json."""
    spec = json.loads(OPENAPI.read_text(encoding="utf-8"))
    properties = spec["components"]["schemas"][schema]["properties"]
    return {name: prop.get("description", "") for name, prop in properties.items()}


def _choices(hint: Any) -> list[str] | None:
    """The values a ``Literal`` (optionally ``| None``) allows, as JSON."""
    if typing.get_origin(hint) is typing.Literal:
        return [json.dumps(v) for v in typing.get_args(hint)]
    args = typing.get_args(hint)
    literal = [a for a in args if typing.get_origin(a) is typing.Literal]
    if literal and all(a is type(None) or a in literal for a in args):
        return [json.dumps(v) for v in typing.get_args(literal[0])] + ["null"]
    return None


def plan_parameters_table() -> str:
    _import_root()
    from planner import parameters

    hints = typing.get_type_hints(parameters.PlanSpec)
    described = _schema_descriptions("PlanParameters")
    rows = ["| parameter | default | range or values | meaning |", "|---|---|---|---|"]
    for field in dataclasses.fields(parameters.PlanSpec):
        if field.default is not dataclasses.MISSING:
            default: Any = field.default
        elif field.default_factory is not dataclasses.MISSING:
            default = field.default_factory()
        else:
            default = None
        allowed = []
        if field.name in parameters.RANGES:
            allowed.append(_range_text(parameters.RANGES[field.name]))
        choices = _choices(hints.get(field.name))
        if choices:
            allowed.append("one of " + ", ".join(f"`{c}`" for c in choices))
        if hints.get(field.name) is bool:
            allowed.append("`true` or `false`")
        if field.name in parameters.MAX_ITEMS:
            allowed.append(f"at most {parameters.MAX_ITEMS[field.name]:,} items")
        rows.append(
            f"| `{field.name}` | `{_cell(_json(default))}` | "
            f"{_cell('; '.join(allowed) or '—')} | {_cell(described.get(field.name, ''))} |")
    return "\n".join(rows)


def nested_ranges_table() -> str:
    _import_root()
    from planner import parameters

    groups: list[tuple[str, dict[str, Any]]] = [
        ("scanner", parameters.SCANNER_RANGES),
        ("scanner.settings[i]", parameters.SETTING_RANGES),
        ("group_requirements.<group>", parameters.GROUP_RANGES),
    ]
    rows = ["| field | range |", "|---|---|"]
    for prefix, ranges in groups:
        for name, bounds in ranges.items():
            rows.append(f"| `{prefix}.{name}` | {_cell(_range_text(bounds))} |")
    rows.append(f"| each coordinate of `candidates`, `fixed_stations`, `area_of_interest`, "
                f"`route_start` | {_cell(_range_text(parameters.COORDINATE_RANGE))} |")
    if hasattr(parameters, "MAX_SETTINGS"):
        rows.append(f"| `scanner.settings` | at most {parameters.MAX_SETTINGS} settings |")
    return "\n".join(rows)


def service_settings_table() -> str:
    _import_root()
    from service.config import Settings

    rows = ["| variable | default | meaning |", "|---|---|---|"]
    for name, field in Settings.model_fields.items():
        if field.default_factory is not None:
            made = field.default_factory()  # type: ignore[call-arg]
            default = _json(made) if made == [] else "(computed)"
        else:
            value = field.default
            default = _json(str(value) if isinstance(value, Path) else value)
        rows.append(f"| `SCANPLAN_{name.upper()}` | `{_cell(default)}` | "
                    f"{_cell(field.description or '')} |")
    return "\n".join(rows)


def cli_help() -> str:
    """``scanplan --help`` and each subcommand's, as the command prints them."""
    import argparse
    import os

    _import_root()
    from planner.__main__ import build_parser

    columns = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = "92"  # argparse wraps to the terminal's width
    try:
        parser = build_parser()
        parts = ["```text", parser.format_help().rstrip(), "```"]
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    parts += ["", f"### `scanplan {name}`", "", "```text",
                              sub.format_help().rstrip(), "```"]
    finally:
        if columns is None:
            os.environ.pop("COLUMNS", None)
        else:
            os.environ["COLUMNS"] = columns
    return "\n".join(parts)


def _flat(value: Any) -> str:
    """A cell's text: numbers as they read (1750, 6.5, 1e+09), objects as ``key value; ...``."""
    if isinstance(value, bool) or value is None:
        return json.dumps(value)
    if isinstance(value, float):
        return f"{value:g}"
    if isinstance(value, dict):
        return "; ".join(f"{k} {_flat(v)}" for k, v in value.items())
    if isinstance(value, list):
        return ", ".join(_flat(v) for v in value)
    return str(value)


def benchmark_matrix() -> str:
    """The matrix's rows as a table; tolerant of a format still being settled."""
    name = "benchmarks/matrix_baseline.json"
    if not MATRIX.exists():
        return (f"!!! note \"Not recorded yet\"\n    The benchmark matrix has not been "
                f"recorded yet: `{name}` does not exist in this checkout.")
    try:
        data = json.loads(MATRIX.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        log.warning("%s cannot be read: %s", name, exc)
        return f"`{name}` cannot be read ({_cell(exc)})."
    rows = data.get("rows") if isinstance(data, dict) else None
    if not isinstance(rows, list) or not all(isinstance(r, dict) for r in rows):
        log.info("%s has no list of row objects under 'rows'; not rendered", name)
        return (f"`{name}` exists but holds no list of rows under `\"rows\"`, the form this "
                "page renders.")
    columns: list[str] = []
    for row in rows:
        columns += [key for key in row if key not in columns]
    lines = []
    about = {k: v for k, v in data.items() if k != "rows" and v not in ("", None)}
    for key, value in about.items():
        lines.append(f"- **{_cell(key)}**: {_cell(_flat(value))}")
    if lines:
        lines.append("")
    if not rows:
        return "\n".join([*lines, f"`{name}` holds no rows yet."])
    lines.append("| " + " | ".join(_cell(c) for c in columns) + " |")
    lines.append("|" + "---|" * len(columns))
    for row in rows:
        lines.append("| " + " | ".join(_cell(_flat(row.get(c, ""))) for c in columns) + " |")
    return "\n".join(lines)


GENERATORS: dict[str, Callable[[], str]] = {
    "plan-parameters": plan_parameters_table,
    "nested-ranges": nested_ranges_table,
    "service-settings": service_settings_table,
    "cli-help": cli_help,
    "benchmark-matrix": benchmark_matrix,
}


def on_page_markdown(markdown: str, **_: Any) -> str:
    if "<!-- generated: " not in markdown:
        return markdown
    for key, generate in GENERATORS.items():
        marker = f"<!-- generated: {key} -->"
        if marker in markdown:
            markdown = markdown.replace(marker, generate())
    return markdown
