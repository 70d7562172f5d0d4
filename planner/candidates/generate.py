"""The candidate stage: explicit, from IFC rooms or on a grid, at every scanner height, with
the stations already scanned among them (see :mod:`planner.candidates`)."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np

from planner.candidates.fixed import fixed_candidates
from planner.candidates.grid import CandidateSet, explicit_candidates, generate_grid
from planner.candidates.placement import at_heights
from planner.candidates.rooms import room_candidates
from planner.candidates.scratch import stage_scratch
from planner.errors import NoCandidatesError
from planner.io.orientation import scene_rotation, to_plan
from planner.parameters import PlanSpec
from planner.rays import RayCaster
from planner.scene import Scene


def plan_candidates(scene: Scene, spec: PlanSpec, caster: RayCaster
                    ) -> tuple[CandidateSet, tuple[int, ...]]:
    """The plan's candidates and the candidate index of each of ``spec.fixed_stations``."""
    if spec.candidates is not None:
        # given in model coordinates; the planner works Z-up (up_axis, planner.io.orientation)
        candidates = explicit_candidates(
            to_plan(scene_rotation(scene.metadata), np.asarray(spec.candidates)))
    elif scene.metadata.get("spaces"):
        with _file_blamed(scene), stage_scratch(scene):
            candidates = at_heights(spec, lambda at: room_candidates(scene, at, caster))
    else:  # (stage_scratch: what every height and storey derives alike is made once)
        with _file_blamed(scene), stage_scratch(scene):
            candidates = at_heights(spec, lambda at: generate_grid(scene, at, caster))
    fixed: tuple[int, ...] = ()
    if spec.fixed_stations:  # re-scan: stations already scanned are candidates too
        fixed_xyz = to_plan(scene_rotation(scene.metadata), np.asarray(spec.fixed_stations))
        positions, fixed = fixed_candidates(
            candidates.positions, tuple((float(x), float(y), float(z)) for x, y, z in fixed_xyz))
        if len(positions) > len(candidates):
            added = len(positions) - len(candidates)
            candidates = dataclasses.replace(
                candidates, positions=positions,
                labels=candidates.labels + ({},) * added if candidates.labels else (),
                also_in=candidates.also_in + ((),) * added if candidates.also_in else (),
                heights_m=None if candidates.heights_m is None
                else np.r_[candidates.heights_m, np.full(added, np.nan)])
    return candidates, fixed


@contextmanager
def _file_blamed(scene: Scene) -> Iterator[None]:
    """A :class:`NoCandidatesError` on a model some of whose elements could not be read
    (``metadata["unread_elements"]``, :mod:`planner.io.ifc`) says first that the file, not
    the parameters, is the likely cause: a missing slab leaves no floor under the grid."""
    try:
        yield
    except NoCandidatesError as exc:
        unread = int(scene.metadata.get("unread_elements") or 0)
        if unread == 0:
            raise
        read_as = "; ".join(str(w) for w in scene.metadata.get("warnings", []))
        raise NoCandidatesError(
            f"the model file is the likely cause, not the parameters: the geometry of "
            f"{unread} of its elements could not be read ({read_as}); fix the file or "
            f"export it again. Without them: {exc}") from exc
