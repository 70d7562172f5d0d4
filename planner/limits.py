"""The analytic limits of every face: what a pair must pass before any ray is cast.

Takes the plan's parameters and the scene (its groups, IFC classes and GlobalIds for
``group_requirements``); gives :class:`FaceLimits`: the scanner's depth of field, field of
view and angular step, and per face the least incidence, the least density, whether it is
a target and whether it occludes; and from them the plan's reach
(:attr:`FaceLimits.reach_m`), which the candidates use to keep to the building and the
visibility to find its pairs (:mod:`planner.visibility.pairs`).

Array letters: F faces.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np
from numpy.typing import NDArray

from planner.density import density_range_m
from planner.parameters import GroupRequirement, PlanSpec
from planner.scene import Scene


@dataclass(frozen=True, eq=False)
class FaceLimits:
    """The plan's limits resolved per face.

    Attributes
    ----------
    min_incidence_deg : (F,) float64
    min_density_pts_m2 : (F,) float64
    target : (F,) bool, the face needs coverage
    occludes : (F,) bool, the face blocks rays

    Read-only: an array that is the same for every face is a broadcast view of one value.
    """

    dof_min_m: float
    dof_max_m: float
    elevation_min_deg: float
    elevation_max_deg: float
    angular_step_rad: float
    min_incidence_deg: NDArray[np.float64]
    min_density_pts_m2: NDArray[np.float64]
    target: NDArray[np.bool_]
    occludes: NDArray[np.bool_]

    @classmethod
    def from_spec(cls, spec: PlanSpec, scene: Scene) -> FaceLimits:
        """Resolve ``group_requirements`` by group name, then by IFC class and GlobalId."""
        n = scene.n_faces
        # one value for every face until a requirement says otherwise: a read-only view of
        # it (no 18 bytes a face for a model without group requirements)
        incidence = _uniform(spec.min_incidence_deg, n)
        density = _uniform(spec.min_density_pts_m2, n)
        target = _uniform(True, n)
        occludes = _uniform(True, n)
        for mask, req in _requirement_masks(spec, scene):
            if req.min_incidence_deg is not None:
                incidence = _assigned(incidence, mask, req.min_incidence_deg)
            if req.min_density_pts_m2 is not None:
                density = _assigned(density, mask, req.min_density_pts_m2)
            target = _assigned(target, mask, req.target)
            occludes = _assigned(occludes, mask, req.occludes)
        return cls(
            dof_min_m=spec.dof_min_m,
            dof_max_m=spec.dof_max_m,
            elevation_min_deg=spec.elevation_min_deg,
            elevation_max_deg=spec.elevation_max_deg,
            angular_step_rad=spec.angular_step_rad,
            min_incidence_deg=incidence,
            min_density_pts_m2=density,
            target=target,
            occludes=occludes,
        )

    @cached_property
    def reach_m(self) -> float:
        """No pair farther than this can qualify: the DOF or the density range head-on.
        Found once per limits, without a gathered copy of the targets' densities (asked
        for by every pair search: on a 9.7 M-face office some 80 MB and 40 ms a time)."""
        density, target = self.min_density_pts_m2, self.target
        if not target.any():
            return 0.0
        uniform = density.strides == (0,) or len(density) == 0
        lowest = float(density[0]) if uniform else float(
            np.min(density, where=target, initial=np.inf))
        return min(self.dof_max_m, density_range_m(lowest, self.angular_step_rad))


def _uniform(value: float | bool, n: int) -> NDArray[Any]:
    """(n,) read-only view of ``value`` (float64 or bool): no memory per face."""
    return np.broadcast_to(np.float64(value) if not isinstance(value, bool) else np.bool_(value),
                           (n,))


def _assigned(per_face: NDArray[Any], mask: NDArray[np.bool_], value: float | bool
              ) -> NDArray[Any]:
    """``per_face`` with ``value`` where ``mask``; a uniform view stays one when nothing
    changes, and becomes an array of its own when something does."""
    if not per_face.flags.writeable:
        if not mask.any() or per_face[0] == value:
            return per_face
        per_face = per_face.copy()
    per_face[mask] = value
    return per_face


def _requirement_masks(
    spec: PlanSpec, scene: Scene
) -> list[tuple[NDArray[np.bool_], GroupRequirement]]:
    """(mask, requirement) in the order they apply: groups, then IFC classes, then GlobalIds.

    Later entries win, so a GlobalId override beats its class's.
    """
    masks: list[tuple[NDArray[np.bool_], GroupRequirement]] = []
    # a reader's defaults (IFC: glass neither targets nor occludes) come first, the user's win
    defaults = scene.metadata.get("default_group_requirements", {})
    reqs = {**PlanSpec.from_mapping({"group_requirements": defaults}).group_requirements,
            **spec.group_requirements}
    group_index = {name: i for i, name in enumerate(scene.groups)}
    for key, req in reqs.items():
        if key in group_index:
            masks.append((scene.of_file_faces(scene.file_face_group == group_index[key]), req))
    if scene.elements:
        classes = [e.ifc_class for e in scene.elements]
        ids = [e.global_id for e in scene.elements]

        def faces_of(names: list[str], key: str) -> NDArray[np.bool_]:
            """(F,) the faces of the elements whose name is ``key``: an (E,) test, then
            one byte a face (no (F,) array of names: 80 bytes a face on a split model)."""
            per_element = np.array([name == key for name in names] + [key == ""], bool)
            # -1 (no element) picks the last entry
            return scene.of_file_faces(per_element[scene.file_face_element])

        for key, req in reqs.items():
            if key not in group_index and key in set(classes):
                masks.append((faces_of(classes, key), req))
        for key, req in reqs.items():
            if key in set(ids):
                masks.append((faces_of(ids, key), req))
    return masks
