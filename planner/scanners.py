"""Scanner profiles: the instrument a crew brings, its settings, and how long a scan takes.

The plan parameter ``scanner`` is a preset id (``scanners.json`` beside this module, every
figure with its source) or a :class:`ScannerProfile` the user describes. A profile gives any
of the range and elevation limits, the measurement rate, the settings (angular steps) the
instrument offers, the setup time per station and a per-scan overhead. It sets the
*defaults* of the plan parameters it knows (:func:`plan_defaults`): a parameter given
explicitly wins over the profile, and a profile given as an object wins, figure by figure,
over the preset it names (``preset``).

Scan duration (:func:`scan_duration_s`) is a physical model, not a lookup. A setting with
angular step SPS = point spacing / reference distance (rad) fires, over a full turn of
2π and the vertical field V = ``elevation_max_deg`` - ``elevation_min_deg`` (rad)::

    points = (2π / SPS) · (V / SPS)
    duration = points / measurement_rate_pts_s + overhead_s

Assumptions: a full 360° turn at every station; every pulse is a recorded point (no
sub-sampling, no repeated lines); the measurement rate is the rate of recorded points;
imaging, tilt compensation and any other constant per scan only through ``overhead_s``
(0 when not given). A setting's own ``duration_s`` (a figure the crew measured or a data
sheet states) replaces ``points / rate``; ``overhead_s`` is still added.

This module lies at the level of :mod:`planner.parameters`, which reads it; the survey
(:mod:`planner.survey.fieldwork`) reads it too.
"""

from __future__ import annotations

import functools
import json
import math
from dataclasses import dataclass, fields, replace
from importlib import resources
from typing import Any

from planner.errors import ParameterError

# a setting qualifies when its density reaches the requirement within this share: the
# densities a plan keeps are float32 (6e-8 relative), and no crew measures a density closer
DENSITY_TOLERANCE = 1e-6
# two angular steps within this share are the same step (a spacing at another distance)
STEP_TOLERANCE = 1e-9


@dataclass(frozen=True)
class ScanSetting:
    """One angular step the instrument offers: ``point_spacing_m`` at ``reference_distance_m``."""

    name: str
    point_spacing_m: float
    reference_distance_m: float
    duration_s: float | None = None  # None: from the measurement rate

    @property
    def angular_step_rad(self) -> float:
        """SPS of this setting, radians."""
        return self.point_spacing_m / self.reference_distance_m


@dataclass(frozen=True)
class ScannerProfile:
    """An instrument; ``None`` where the profile gives no figure (the plan keeps its own)."""

    name: str
    preset: str | None = None  # a preset whose figures fill what this profile leaves out
    min_range_m: float | None = None
    max_range_m: float | None = None
    elevation_min_deg: float | None = None
    elevation_max_deg: float | None = None
    measurement_rate_pts_s: float | None = None
    settings: tuple[ScanSetting, ...] = ()
    setup_time_s: float | None = None
    overhead_s: float | None = None  # imaging, tilt, any constant per scan

    def finest(self) -> ScanSetting | None:
        """The setting with the smallest angular step (the first of equal ones)."""
        if not self.settings:
            return None
        return min(self.settings, key=lambda s: s.angular_step_rad)


PROFILE_FIELDS = tuple(f.name for f in fields(ScannerProfile))
SETTING_FIELDS = tuple(f.name for f in fields(ScanSetting))
# the numbers of a profile: each a figure with its source (or reason) in scanners.json
FIGURES = tuple(f for f in PROFILE_FIELDS if f not in ("name", "preset", "settings"))
# profile figure -> the plan parameter it sets the default of
PLAN_PARAMETER_OF = {"min_range_m": "dof_min_m", "max_range_m": "dof_max_m",
                     "elevation_min_deg": "elevation_min_deg",
                     "elevation_max_deg": "elevation_max_deg", "setup_time_s": "setup_time_s"}


@dataclass(frozen=True)
class Preset:
    """A profile scanplan ships, with the source of every figure (``scanners.json``)."""

    id: str
    maker: str
    profile: ScannerProfile
    figures: dict[str, dict[str, Any]]  # figure -> {value, source} or {value: null, reason}
    settings_note: dict[str, Any]  # {source} or {reason} of the settings
    sources: dict[str, dict[str, Any]]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: every figure with its source or the reason it is missing."""
        return {
            "id": self.id,
            "name": self.profile.name,
            "maker": self.maker,
            "figures": self.figures,
            "settings": [_setting_dict(s) for s in self.profile.settings],
            "settings_note": self.settings_note,
            "defaults": plan_defaults(self.profile),
            "sources": self.sources,
        }


def _setting_dict(setting: ScanSetting) -> dict[str, Any]:
    return {f: getattr(setting, f) for f in SETTING_FIELDS}


@functools.cache
def presets() -> dict[str, Preset]:
    """Every preset, keyed by id, in the order of ``scanners.json``."""
    text = resources.files("planner").joinpath("scanners.json").read_text(encoding="utf-8")
    data = json.loads(text)
    result: dict[str, Preset] = {}
    for entry in data["scanners"]:
        figures = {k: entry[k] for k in FIGURES if isinstance(entry.get(k), dict)}
        values: dict[str, Any] = {k: None if v["value"] is None else float(v["value"])
                                  for k, v in figures.items()}
        settings = tuple(ScanSetting(**s) for s in entry["settings"]["values"])
        note = {k: v for k, v in entry["settings"].items() if k != "values"}
        keys = {v["source"] for v in figures.values() if v["value"] is not None}
        keys |= {note["source"]} if "source" in note else set()
        for figure in figures.values():
            keys |= set(figure.get("also", ()))
        result[entry["id"]] = Preset(
            id=entry["id"], maker=entry["maker"],
            profile=ScannerProfile(name=entry["name"], settings=settings, **values),
            figures=figures, settings_note=note,
            sources={k: data["sources"][k] for k in sorted(keys)})
    return result


def preset(preset_id: str) -> Preset:
    """The preset ``preset_id``; a :class:`ParameterError` naming the known ones if none."""
    known = presets()
    if preset_id not in known:
        raise ParameterError(
            "scanner", f"{preset_id!r} is not a known preset; use one of {', '.join(known)} "
            "(scanplan scanners lists them), an object describing the instrument, or null")
    return known[preset_id]


def resolve(scanner: str | ScannerProfile) -> ScannerProfile:
    """The profile a ``scanner`` parameter stands for: a preset's, or the user's object
    with the figures it leaves out taken from the preset it names."""
    if isinstance(scanner, str):
        return preset(scanner).profile
    if scanner.preset is None:
        return scanner
    base = preset(scanner.preset).profile
    given = {f: getattr(scanner, f) for f in FIGURES if getattr(scanner, f) is not None}
    return replace(base, name=scanner.name, preset=scanner.preset,
                   settings=scanner.settings or base.settings, **given)


def plan_defaults(profile: ScannerProfile) -> dict[str, float]:
    """The plan parameters the profile sets, by their PlanSpec names.

    The plan's step (``point_spacing_m`` at ``reference_distance_m``) is not among them: it
    stays the plan's own, and each station is scanned at the coarsest setting that still
    delivers its share (:func:`coarsest_setting`); see :func:`fallback_step` for the one
    exception.
    """
    values: dict[str, float] = {}
    for figure, parameter in PLAN_PARAMETER_OF.items():
        value = getattr(profile, figure)
        if value is not None:
            values[parameter] = value
    return values


def fallback_step(profile: ScannerProfile, plan_step_rad: float) -> ScanSetting | None:
    """The setting whose step the plan takes instead of its default ``plan_step_rad``.

    A plan promises coverage at its step, and a station keeps that coverage under a
    setting at least as fine. When every setting is coarser than the default step, none
    could keep it: the plan then promises what the instrument delivers, the finest
    setting's step. None when some setting is at least as fine (or there are none).
    """
    finest = profile.finest()
    if finest is None or finest.angular_step_rad <= plan_step_rad * (1 + STEP_TOLERANCE):
        return None
    return finest


def step_note(profile: ScannerProfile, plan_step_rad: float, default_step_rad: float
              ) -> str | None:
    """Why the plan's step is not the default one (:func:`fallback_step`), or None."""
    finest = fallback_step(profile, default_step_rad)
    if finest is None or not math.isclose(finest.angular_step_rad, plan_step_rad,
                                          rel_tol=STEP_TOLERANCE):
        return None
    return (f"no setting of {profile.name} is as fine as the default step "
            f"({default_step_rad * 10:g} m at 10 m), so the plan's step is its finest setting, "
            f"{finest.name} ({finest.point_spacing_m:g} m at {finest.reference_distance_m:g} m)")


def full_dome_points(angular_step_rad: float, elevation_min_deg: float,
                     elevation_max_deg: float) -> float:
    """Points of a full 360° scan at this step over this vertical field (module docstring)."""
    vertical_rad = math.radians(elevation_max_deg - elevation_min_deg)
    return (2.0 * math.pi / angular_step_rad) * (vertical_rad / angular_step_rad)


def scan_duration_s(profile: ScannerProfile, angular_step_rad: float, elevation_min_deg: float,
                    elevation_max_deg: float, setting: ScanSetting | None = None
                    ) -> float | None:
    """Seconds of one scan at ``angular_step_rad`` (the ``setting``'s, when one is given);
    None when neither the setting's ``duration_s`` nor the measurement rate is known."""
    overhead_s = profile.overhead_s or 0.0
    if setting is not None and setting.duration_s is not None:
        return setting.duration_s + overhead_s
    if profile.measurement_rate_pts_s is None:
        return None
    points = full_dome_points(angular_step_rad, elevation_min_deg, elevation_max_deg)
    return points / profile.measurement_rate_pts_s + overhead_s


def coarsest_setting(profile: ScannerProfile, plan_step_rad: float, density_margin: float
                     ) -> ScanSetting | None:
    """The coarsest setting under which a station's credited faces still qualify.

    ``density_margin``: the least ratio, over the faces the station is credited with, of
    their density at the plan's step ``plan_step_rad`` to their requirement (inf: no face
    needs a density). The density LPD = sin(alpha) / (SPS d)² scales with 1 / SPS², so a
    setting qualifies when margin · (plan step / its step)² >= 1. Settings finer than the
    plan's step qualify too: a station whose faces need the plan's full step gets the
    coarsest setting at least that fine. None without settings; the finest setting when
    none qualifies (a margin rounded a hair under 1 with every setting coarser).
    """
    if not profile.settings:
        return None
    best: ScanSetting | None = None
    for setting in profile.settings:
        ratio = (plan_step_rad / setting.angular_step_rad) ** 2
        if density_margin * ratio >= 1.0 - DENSITY_TOLERANCE and (
                best is None or setting.angular_step_rad > best.angular_step_rad):
            best = setting
    return best if best is not None else profile.finest()


@dataclass(frozen=True)
class StationScan:
    """How one station is scanned: the setting (None: the plan's step) and its seconds."""

    setting: str | None
    angular_step_rad: float
    scan_s: float | None


def station_scans(profile: ScannerProfile, plan_step_rad: float, elevation_min_deg: float,
                  elevation_max_deg: float, density_margins: list[float]
                  ) -> tuple[StationScan, ...]:
    """Setting and duration of every station, in selection order, from the (S,) margins."""
    scans = []
    for margin in density_margins:
        setting = coarsest_setting(profile, plan_step_rad, margin)
        step = plan_step_rad if setting is None else setting.angular_step_rad
        scans.append(StationScan(
            setting=None if setting is None else setting.name, angular_step_rad=step,
            scan_s=scan_duration_s(profile, step, elevation_min_deg, elevation_max_deg,
                                   setting)))
    return tuple(scans)


def missing_duration_reason(profile: ScannerProfile, scans: tuple[StationScan, ...]) -> str:
    """Why some station's scan time is unknown: the missing figure and the field for it."""
    names = sorted({s.setting for s in scans if s.scan_s is None and s.setting is not None})
    where = "the scanner object (or a preset that states it)"
    if names:
        return (f"{profile.name}: setting {', '.join(names)} gives no duration_s and the "
                f"profile no measurement_rate_pts_s; give scanner.measurement_rate_pts_s or "
                f"scanner.settings[].duration_s in {where}")
    return (f"{profile.name} gives no measurement_rate_pts_s (and no settings with "
            f"duration_s); give scanner.measurement_rate_pts_s in {where}")

