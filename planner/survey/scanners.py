"""Scanner presets: the limits of real instruments, from ``scanners.json``.

Each preset holds, per instrument, only figures with a source (title, year, address and the
quoted statement, listed in the file; a figure no source states is null with its reason, and
the plan keeps its own default for that limit): range limits, the vertical field of view (or
elevation limits), the angular steps the instrument offers as point spacing at 10 m, and the
duration of a full scan at each step where the source gives one. A preset sets the
*defaults* of the plan parameters it knows (:func:`preset_defaults`); parameters given
explicitly still win, which :meth:`planner.parameters.PlanSpec.from_mapping` arranges.
"""

from __future__ import annotations

import functools
import json
from dataclasses import dataclass
from importlib import resources
from typing import Any

from planner.errors import ParameterError

# point spacings in the file are stated at this distance (every maker quotes 10 m)
SETTING_DISTANCE_M = 10.0
# a plan's spacing matches a setting when they differ by less than this (metres at 10 m)
_SPACING_TOLERANCE_M = 1e-6


@dataclass(frozen=True)
class Setting:
    """One angular step the instrument offers."""

    name: str
    point_spacing_m_at_10m: float
    scan_duration_s: float | None  # None: the source gives no duration


@dataclass(frozen=True)
class Scanner:
    """One preset; ``None`` where the sources give no figure."""

    id: str
    name: str
    maker: str
    dof_min_m: float | None
    dof_max_m: float | None
    elevation_min_deg: float | None
    elevation_max_deg: float | None
    settings: tuple[Setting, ...]
    default_setting: str | None
    sources: dict[str, dict[str, Any]]

    def setting_for(self, point_spacing_m: float, reference_distance_m: float) -> Setting | None:
        """The setting with this spacing (scaled to 10 m), or None when it is not one."""
        at_10m = point_spacing_m * SETTING_DISTANCE_M / reference_distance_m
        for setting in self.settings:
            if abs(setting.point_spacing_m_at_10m - at_10m) < _SPACING_TOLERANCE_M:
                return setting
        return None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary for ``scanplan scanners`` and ``GET /processes/scan-plan``."""
        return {
            "id": self.id,
            "name": self.name,
            "maker": self.maker,
            "defaults": preset_defaults(self.id),
            "settings": [
                {"name": s.name, "point_spacing_m_at_10m": s.point_spacing_m_at_10m,
                 "scan_duration_s": s.scan_duration_s}
                for s in self.settings
            ],
            "default_setting": self.default_setting,
            "sources": self.sources,
        }


def _value(entry: dict[str, Any], key: str) -> float | None:
    """The figure's value; None when the file has none (a null value carries its reason)."""
    figure = entry.get(key)
    return None if figure is None or figure["value"] is None else float(figure["value"])


@functools.cache
def scanners() -> dict[str, Scanner]:
    """Every preset, keyed by id, in the order of the file."""
    text = resources.files("planner.survey").joinpath("scanners.json").read_text(encoding="utf-8")
    data = json.loads(text)
    result: dict[str, Scanner] = {}
    for entry in data["scanners"]:
        elevation_min = _value(entry, "elevation_min_deg")
        elevation_max = _value(entry, "elevation_max_deg")
        fov = _value(entry, "vertical_fov_deg")
        if fov is not None:
            # a vertical field of fov degrees leaves a blind cone of (360 - fov) degrees
            # under the instrument, so the lowest beam is at 90 - fov / 2 degrees elevation
            elevation_min, elevation_max = 90.0 - fov / 2.0, 90.0
        keys = {entry[k]["source"] for k in entry
                if isinstance(entry[k], dict) and entry[k].get("value") is not None}
        keys |= {s["source"] for s in entry["settings"]}
        result[entry["id"]] = Scanner(
            id=entry["id"],
            name=entry["name"],
            maker=entry["maker"],
            dof_min_m=_value(entry, "dof_min_m"),
            dof_max_m=_value(entry, "dof_max_m"),
            elevation_min_deg=elevation_min,
            elevation_max_deg=elevation_max,
            settings=tuple(
                Setting(s["name"], float(s["point_spacing_m_at_10m"]),
                        None if s.get("scan_duration_s") is None else float(s["scan_duration_s"]))
                for s in entry["settings"]
            ),
            default_setting=entry.get("default_setting"),
            sources={k: data["sources"][k] for k in sorted(keys)},
        )
    return result


def get(scanner_id: str) -> Scanner:
    """The preset ``scanner_id``; a :class:`ParameterError` naming the known ones if none."""
    known = scanners()
    if scanner_id not in known:
        raise ParameterError(
            "scanner", f"{scanner_id!r} is not a known preset; use one of {', '.join(known)} "
            "(scanplan scanners lists them) or null")
    return known[scanner_id]


def preset_defaults(scanner_id: str) -> dict[str, float]:
    """The plan parameters the preset sets, by their PlanSpec names."""
    scanner = get(scanner_id)
    values: dict[str, float] = {}
    for name in ("dof_min_m", "dof_max_m", "elevation_min_deg", "elevation_max_deg"):
        value = getattr(scanner, name)
        if value is not None:
            values[name] = value
    default = next((s for s in scanner.settings if s.name == scanner.default_setting), None)
    if default is not None:
        values["point_spacing_m"] = default.point_spacing_m_at_10m
        values["reference_distance_m"] = SETTING_DISTANCE_M
    return values
