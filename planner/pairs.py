"""Candidate-face pairs and the analytic limits, all known before any ray is cast.

A pair (candidate c, face f) *passes* when, with d the distance from c to the centroid of f
and alpha the incidence angle (``sin alpha = |ray . normal|``):

- ``dof_min_m <= d <= dof_max_m``;
- the ray's elevation above the scanner's horizontal plane lies in
  ``[elevation_min_deg, elevation_max_deg]`` (the blind cone under the scanner);
- ``alpha >= min_incidence_deg`` of the face's group;
- ``LPD >= min_density_pts_m2`` of the face's group.

Limits are inclusive and compared in degrees, as method.md states them. Only the pairs that
pass need an occlusion ray. Array letters: C candidates, F faces, P pairs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from planner.density import density_range_m, local_point_density
from planner.parameters import PlanSpec
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
        incidence = np.full(n, spec.min_incidence_deg)
        density = np.full(n, spec.min_density_pts_m2)
        target = np.ones(n, bool)
        occludes = np.ones(n, bool)
        for mask, req in _requirement_masks(spec, scene):
            if req.min_incidence_deg is not None:
                incidence[mask] = req.min_incidence_deg
            if req.min_density_pts_m2 is not None:
                density[mask] = req.min_density_pts_m2
            target[mask] = req.target
            occludes[mask] = req.occludes
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

    @property
    def reach_m(self) -> float:
        """No pair farther than this can qualify: the DOF or the density range head-on."""
        targets = self.min_density_pts_m2[self.target]
        if len(targets) == 0:
            return 0.0
        return min(self.dof_max_m, density_range_m(float(targets.min()), self.angular_step_rad))


def _requirement_masks(spec: PlanSpec, scene: Scene) -> list[tuple[NDArray[np.bool_], object]]:
    """(mask, requirement) in the order they apply: groups, then IFC classes, then GlobalIds.

    Later entries win, so a GlobalId override beats its class's.
    """
    masks: list[tuple[NDArray[np.bool_], object]] = []
    # a reader's defaults (IFC: glass neither targets nor occludes) come first, the user's win
    defaults = scene.metadata.get("default_group_requirements", {})
    reqs = {**PlanSpec.from_mapping({"group_requirements": defaults}).group_requirements,
            **spec.group_requirements}
    group_index = {name: i for i, name in enumerate(scene.groups)}
    for key, req in reqs.items():
        if key in group_index:
            masks.append((scene.face_group == group_index[key], req))
    if scene.elements:
        classes = np.array([e.ifc_class for e in scene.elements] + [""])
        ids = np.array([e.global_id for e in scene.elements] + [""])
        face_class = classes[scene.face_element]  # -1 picks the trailing ""
        face_id = ids[scene.face_element]
        for key, req in reqs.items():
            if key not in group_index and key in set(classes[:-1]):
                masks.append((face_class == key, req))
        for key, req in reqs.items():
            if key in set(ids[:-1]):
                masks.append((face_id == key, req))
    return masks


@dataclass(frozen=True, eq=False)
class Pairs:
    """Pairs that pass the analytic limits.

    Attributes
    ----------
    candidate : (P,) int64, candidate index
    face : (P,) int64, face index
    distance_m : (P,) float64
    direction : (P, 3) float64, unit vector from candidate to face centroid
    lpd_pts_m2 : (P,) float64
    """

    candidate: NDArray[np.int64]
    face: NDArray[np.int64]
    distance_m: NDArray[np.float64]
    direction: NDArray[np.float64]
    lpd_pts_m2: NDArray[np.float64]

    def __len__(self) -> int:
        return int(len(self.face))

    def subset(self, keep: NDArray[np.bool_]) -> Pairs:
        return Pairs(self.candidate[keep], self.face[keep], self.distance_m[keep],
                     self.direction[keep], self.lpd_pts_m2[keep])


class PairFinder:
    """Finds the passing pairs of a block of candidates, faces sorted by x for a quick cut."""

    def __init__(self, scene: Scene, limits: FaceLimits) -> None:
        self.limits = limits
        self.reach_m = limits.reach_m
        targets = np.flatnonzero(limits.target)
        order = np.argsort(scene.centroids[targets, 0], kind="stable")
        self._faces = targets[order]
        self._x = scene.centroids[self._faces, 0]
        self._centroids = scene.centroids
        self._normals = scene.normals

    def find(self, candidates_xyz: NDArray[np.float64], first_index: int) -> tuple[Pairs, int]:
        """Passing pairs of (B, 3) candidates numbered from ``first_index``.

        Returns the pairs, sorted by (candidate, face), and how many pairs were tested.
        """
        lim = self.limits
        lo = np.searchsorted(self._x, candidates_xyz[:, 0].min() - self.reach_m, "left")
        hi = np.searchsorted(self._x, candidates_xyz[:, 0].max() + self.reach_m, "right")
        faces = np.sort(self._faces[lo:hi])
        offsets = self._centroids[faces][None, :, :] - candidates_xyz[:, None, :]  # (B, f, 3)
        dist2 = np.einsum("bfk,bfk->bf", offsets, offsets)
        tested = int(dist2.size)
        reach = min(self.reach_m, lim.dof_max_m)
        near = (dist2 <= reach * reach) & (dist2 >= lim.dof_min_m * lim.dof_min_m)
        rows, cols = np.nonzero(near)
        offsets = offsets[rows, cols]
        distance = np.sqrt(dist2[rows, cols])
        face = faces[cols]
        # exact inclusive DOF test on the distance itself (the squares above only cut)
        keep = (distance >= lim.dof_min_m) & (distance <= lim.dof_max_m) & (distance > 0)
        rows, face, offsets, distance = rows[keep], face[keep], offsets[keep], distance[keep]
        direction = offsets / distance[:, None]
        elevation = np.degrees(np.arcsin(np.clip(direction[:, 2], -1.0, 1.0)))
        keep = (elevation >= lim.elevation_min_deg) & (elevation <= lim.elevation_max_deg)
        sin_incidence = np.abs(np.einsum("pk,pk->p", direction, self._normals[face]))
        incidence = np.degrees(np.arcsin(np.clip(sin_incidence, 0.0, 1.0)))
        keep &= incidence >= lim.min_incidence_deg[face]
        lpd = local_point_density(sin_incidence, distance, lim.angular_step_rad)
        keep &= lpd >= lim.min_density_pts_m2[face]
        pairs = Pairs(
            candidate=(rows[keep] + first_index).astype(np.int64),
            face=face[keep].astype(np.int64),
            distance_m=distance[keep],
            direction=direction[keep],
            lpd_pts_m2=lpd[keep],
        )
        return pairs, tested
