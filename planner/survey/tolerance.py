"""What a plan keeps when each tripod lands up to ``placement_tolerance_m`` off its station.

Every station is evaluated at its displaced setups (:mod:`planner.method.placement`: the
station and 8 points on the circle, those that stand on its floor). Definitions:

- A station's *area lost* at a setup: the area of the faces the plan covers from that
  station alone (no other chosen station qualifies for them) that no longer qualify from
  the setup, the other stations in place. Faces another station also covers are not lost;
  faces the setup gains do not offset a loss. ``worst_loss_m2`` is the largest over the
  setups, ``worst_offset_m`` its horizontal offset (the first such setup on a tie, (0, 0)
  when nothing is lost).
- The *worst case* of the plan: every station displaced at once, each to any of its setups.
  A face is then surely covered when some station covering it qualifies for it from every
  one of its setups; ``worst_case_covered_area_m2`` is the area of those faces (a lower
  bound of the covered area whatever setups the crew ends up with). ``goal_holds``: that
  area still meets the goal (as ``goal_reached`` judges the plan). A station is
  *critical* when its worst setup alone, the others in place, breaks the goal; when the goal
  holds, no station is critical.
- ``network_holds``: the registration network (:mod:`planner.survey.registration`) stays
  connected when each station's overlap row keeps only the faces it qualifies for at the
  overlap density from every setup (the worst case again; only the faces two stations
  share are tested, the others carry no edge).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.sparse.csgraph import minimum_spanning_tree

from planner.method.coverage import CoverageTable, QualifiedPairs
from planner.method.pairs import FaceLimits, PairFinder
from planner.method.placement import Displaced, Qualify, kept_faces
from planner.method.selection import GOAL_SLACK_M2
from planner.method.visibility import Occlusion, make_occlusion
from planner.method.walkgraph import door_faces
from planner.scene import Scene
from planner.survey.registration import (
    Registration,
    overlap_limits,
    shared_faces_only,
    station_registration,
)

# pair tests of a station's displaced setups made at a time by the worst-case network:
# a station shares up to some 10^5 faces with its neighbours, and almost all of them pass
# from every setup, at some 70 bytes a pair until its ray is cast (two threads run)
NETWORK_TESTS_PER_BLOCK = 1_000_000


@dataclass(frozen=True)
class StationTolerance:
    worst_loss_m2: float
    worst_offset_m: tuple[float, float]
    setups: int  # displaced setups evaluated, the station itself included
    critical: bool

    def to_dict(self) -> dict[str, Any]:
        return {"worst_loss_m2": round(self.worst_loss_m2, 6),
                "worst_offset_m": [round(v, 6) + 0.0 for v in self.worst_offset_m],
                "setups": self.setups, "critical": self.critical}


@dataclass(frozen=True)
class Tolerance:
    """The plan's ``tolerance`` report (see the module docstring)."""

    placement_tolerance_m: float
    setups_per_station: int
    stations: tuple[StationTolerance, ...]
    goal_area_m2: float
    worst_case_covered_area_m2: float
    goal_holds: bool
    network_holds: bool
    worst_case_components: tuple[tuple[int, ...], ...]

    def to_dict(self) -> dict[str, Any]:
        return {
            "placement_tolerance_m": self.placement_tolerance_m,
            "setups_per_station": self.setups_per_station,
            "goal_area_m2": round(self.goal_area_m2, 6),
            "worst_case_covered_area_m2": round(self.worst_case_covered_area_m2, 6),
            "goal_holds": self.goal_holds,
            "network_holds": self.network_holds,
            "worst_case_components": [list(c) for c in self.worst_case_components],
            "critical_stations": [i + 1 for i, s in enumerate(self.stations) if s.critical],
        }


def placement_tolerance(
    scene: Scene, table: CoverageTable, stations: tuple[int, ...], displaced: Displaced,
    limits: FaceLimits, qualify: Qualify, *, tolerance_m: float, covered_area_m2: float,
    goal_area_m2: float,
    station_overlap: sp.csr_matrix, min_overlap_m2: float | None,
    overlap_density_pts_m2: float, occlusion: Occlusion, file_faces: bool,
    threads: int | None = None,
) -> Tolerance:
    """The tolerance report of the chosen ``stations`` (candidate indices into ``table``),
    at their ``displaced`` setups (N = S), with ``qualify`` the plan's coverage model.

    ``covered_area_m2`` is the plan's covered area and ``goal_area_m2`` the area the goal
    asks for; ``station_overlap`` the stations' (S, F) overlap rows (as the survey has them).
    """
    rows = [table.faces_of(c) for c in stations]
    holders = np.zeros(scene.n_faces, np.int32)  # (F,) chosen stations covering each face
    for faces in rows:
        holders[faces] += 1
    surely = np.zeros(scene.n_faces, bool)  # (F,) kept from every setup of some station
    per_station = []
    limit = goal_area_m2 - GOAL_SLACK_M2
    for s, (faces, kept) in enumerate(kept_faces(scene, displaced, rows.__getitem__, limits,
                                                 qualify, threads=threads)):
        alone = holders[faces] == 1
        lost_m2 = (~kept & alone) @ scene.areas[faces]  # (K,) per setup
        worst = int(np.argmax(lost_m2))
        surely[faces[kept.all(axis=0)]] = True
        per_station.append(StationTolerance(
            worst_loss_m2=float(lost_m2[worst]),
            worst_offset_m=(float(displaced.offsets_m[worst, 0]),
                            float(displaced.offsets_m[worst, 1])),
            setups=int(displaced.valid[s].sum()),
            critical=bool(covered_area_m2 - float(lost_m2[worst]) < limit)))
    worst_case_m2 = float(scene.areas[surely].sum())
    del rows, holders, surely  # (F,) arrays and every station's faces: not held below
    components = _worst_case_network(
        scene, displaced, limits, station_overlap, min_overlap_m2, overlap_density_pts_m2,
        occlusion, file_faces, threads)
    return Tolerance(
        placement_tolerance_m=tolerance_m,
        setups_per_station=len(displaced.offsets_m), stations=tuple(per_station),
        goal_area_m2=goal_area_m2, worst_case_covered_area_m2=worst_case_m2,
        goal_holds=worst_case_m2 >= limit, network_holds=len(components) <= 1,
        worst_case_components=components)


def _worst_case_network(
    scene: Scene, displaced: Displaced, limits: FaceLimits, station_overlap: sp.csr_matrix,
    min_overlap_m2: float | None, overlap_density_pts_m2: float, occlusion: Occlusion,
    file_faces: bool, threads: int | None,
) -> tuple[tuple[int, ...], ...]:
    """Components (station ids) of the registration network when every station keeps only
    the shared overlap faces it qualifies for from all its setups.

    Connectivity needs a spanning tree only: the faces each station shares with its
    neighbours on the strongest spanning tree of the nominal network (most overlap) are
    tested first; when every tree edge survives, the network holds. Otherwise every shared
    face is tested and the components are those of the whole worst-case network.
    """
    doors = door_faces(scene)
    overlap = overlap_limits(limits, overlap_density_pts_m2)
    if (doors & limits.occludes).any():  # doors are open for the overlap rays, as the survey's
        overlap = dataclasses.replace(overlap, occludes=limits.occludes & ~doors)
        occlusion = make_occlusion(scene, overlap.occludes, "embree", file_faces=file_faces)
    shared = shared_faces_only(station_overlap)
    rows = [np.asarray(shared.indices[shared.indptr[n]:shared.indptr[n + 1]], np.int32)
            for n in range(shared.shape[0])]

    def qualify(positions: NDArray[np.float64], cut: FaceLimits) -> Iterator[QualifiedPairs]:
        # kept_faces reads them in any order: no sort. Nearly every shared face passes the
        # limits from every setup, so the setups go a few at a time (NETWORK_TESTS_PER_BLOCK)
        finder = PairFinder(scene, cut)
        for start, stop in finder.blocks(positions, most_tests=NETWORK_TESTS_PER_BLOCK):
            pairs, _ = finder.find(positions[start:stop], start, ordered=False)
            visible = occlusion.visible(
                pairs.origin, pairs.direction, pairs.distance_m, pairs.face,
                exact_rays=pairs.exact_rays(positions, scene.centroids))
            yield QualifiedPairs(pairs.candidate[visible], pairs.face[visible],
                                 pairs.lpd_pts_m2[visible])

    def components(tested: list[NDArray[np.int32]]) -> tuple[tuple[int, ...], ...]:
        kept_rows = [faces[kept.all(axis=0)] for faces, kept in
                     kept_faces(scene, displaced, tested.__getitem__, overlap, qualify,
                                threads=threads)]
        indptr = np.zeros(len(kept_rows) + 1, np.int64)
        np.cumsum([len(r) for r in kept_rows], out=indptr[1:])
        indices = np.concatenate(kept_rows) if kept_rows else np.zeros(0, np.int32)
        worst = sp.csr_matrix((np.ones(len(indices), bool), indices, indptr),
                              shape=(len(kept_rows), scene.n_faces))
        return station_registration(scene, worst, min_overlap_m2,
                                    overlap_density_pts_m2).components

    nominal = station_registration(scene, shared, min_overlap_m2, overlap_density_pts_m2)
    if len(rows) > 1 and len(nominal.components) == 1:
        neighbours = _strongest_tree(nominal, len(rows))
        tree_rows = [np.intersect1d(rows[n], np.concatenate([rows[m] for m in neighbours[n]]),
                                    assume_unique=False) for n in range(len(rows))]
        found = components(tree_rows)
        if len(found) == 1:
            return found
    return components(rows)


def _strongest_tree(registration: Registration, n: int) -> list[list[int]]:
    """Per station (0-based), its neighbours on a spanning tree of the ok edges that keeps
    the largest overlaps (a minimum spanning tree of the reversed overlaps)."""
    ok = [e for e in registration.edges if e.ok]
    top = max(e.overlap_m2 for e in ok)
    weights = sp.coo_matrix(([top + 1.0 - e.overlap_m2 for e in ok],
                             ([e.a - 1 for e in ok], [e.b - 1 for e in ok])), shape=(n, n))
    tree = minimum_spanning_tree(weights.tocsr()).tocoo()
    neighbours: list[list[int]] = [[] for _ in range(n)]
    for a, b in zip(tree.row.tolist(), tree.col.tolist(), strict=True):
        neighbours[a].append(b)
        neighbours[b].append(a)
    return neighbours
