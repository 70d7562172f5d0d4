"""Refuse, before queueing, a plan whose work would exceed the service's caps.

The estimate uses only what the upload stored (faces, total area, bounds) and the
parameters, so it costs nothing per request:

- faces after remeshing: a triangle whose edges are all at most ``max_edge_m`` has at most
  the area of the equilateral one, (√3/4)·max_edge_m², so a mesh with every face split has
  at least ``total area / ((√3/4)·max_edge_m²)`` faces. The plan splits only the faces a
  candidate can qualify part of (:mod:`planner.visibility.splitting`), which the upload cannot
  know: on a model with much area out of every candidate's reach the estimate is high;
- grid points: the model's XY bounding box (or the area of interest's) divided by
  ``grid_spacing_m``², the grid the candidate stage walks before it drops points;
- candidate x face pairs: candidates (explicit, or the grid) times faces.

Each cap is a field of :class:`service.config.Settings` (``SCANPLAN_MAX_FACES``, ...).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from planner.parameters import PlanSpec
from service.config import Settings
from service.problems import JobTooLargeError

_EQUILATERAL_AREA_FACTOR = math.sqrt(3) / 4


@dataclass(frozen=True)
class WorkEstimate:
    """The estimated size of one plan (floats: absurd parameters give inf, not an error)."""

    faces: float
    candidates: float
    pairs: float


def estimate(summary: dict[str, Any], spec: PlanSpec) -> WorkEstimate:
    """The work of planning ``spec`` on a mesh with upload ``summary`` (see module doc)."""
    scale = np.float64(spec.unit_scale)
    faces = float(summary["faces"])
    # float64 with errors ignored: 1e-300 m spacings must give inf, which every cap refuses
    with np.errstate(all="ignore"):
        if spec.max_edge_m is not None:
            area_m2 = np.float64(summary["total_area_m2"]) * scale * scale
            smallest_face_m2 = _EQUILATERAL_AREA_FACTOR * np.square(np.float64(spec.max_edge_m))
            faces = max(faces, float(area_m2 / smallest_face_m2))
        if spec.candidates is not None:
            candidates = float(len(spec.candidates))
        else:
            if spec.area_of_interest is not None:
                xs = [p[0] for p in spec.area_of_interest]
                ys = [p[1] for p in spec.area_of_interest]
                width_m, depth_m = max(xs) - min(xs), max(ys) - min(ys)
            else:
                (x0, y0, _), (x1, y1, _) = summary["bounds"]
                width_m, depth_m = (x1 - x0) * scale, (y1 - y0) * scale
            columns = np.floor(np.float64(width_m) / spec.grid_spacing_m) + 1
            rows = np.floor(np.float64(depth_m) / spec.grid_spacing_m) + 1
            candidates = float(columns * rows)
        pairs = float(np.float64(faces) * candidates)
    return WorkEstimate(faces=faces, candidates=candidates, pairs=pairs)


def check(summary: dict[str, Any], spec: PlanSpec, settings: Settings) -> WorkEstimate:
    """The estimate, or a :class:`JobTooLargeError` naming the parameter to change."""
    work = estimate(summary, spec)
    if work.faces > settings.max_faces:
        parameter = "max_edge_m" if spec.max_edge_m is not None else "unit_scale"
        raise JobTooLargeError(parameter, (
            f"{parameter}: about {work.faces:.3g} faces after remeshing (max_edge_m "
            f"{spec.max_edge_m}), more than this service plans ({settings.max_faces:.3g}, "
            "SCANPLAN_MAX_FACES); use a larger max_edge_m or null to keep the mesh as given"))
    grid = spec.candidates is None
    if not grid and work.candidates > settings.max_candidates:
        raise JobTooLargeError("candidates", (
            f"candidates: {work.candidates:.0f} positions, more than this service plans "
            f"({settings.max_candidates}, SCANPLAN_MAX_CANDIDATES); give fewer"))
    if grid and work.candidates > settings.max_grid_points:
        raise JobTooLargeError("grid_spacing_m", (
            f"grid_spacing_m: {spec.grid_spacing_m} m gives about {work.candidates:.3g} grid "
            f"points, more than this service plans ({settings.max_grid_points:.3g}, "
            "SCANPLAN_MAX_GRID_POINTS); use a larger grid_spacing_m or an area_of_interest"))
    if work.pairs > settings.max_candidate_face_pairs:
        parameter = "grid_spacing_m" if grid else "candidates"
        raise JobTooLargeError(parameter, (
            f"{parameter}: about {work.candidates:.3g} candidates x {work.faces:.3g} faces = "
            f"{work.pairs:.3g} pairs, more than this service plans "
            f"({settings.max_candidate_face_pairs:.3g}, SCANPLAN_MAX_CANDIDATE_FACE_PAIRS); "
            f"use fewer candidates (a larger grid_spacing_m) or a larger max_edge_m"))
    return work
