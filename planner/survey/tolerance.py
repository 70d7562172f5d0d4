"""What a plan keeps when each tripod lands up to ``placement_tolerance_m`` off its station.

Every station is evaluated at its displaced setups (:mod:`planner.candidates.placement`: the
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
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.cluster.hierarchy import DisjointSet
from scipy.sparse.csgraph import minimum_spanning_tree

from planner.candidates.placement import Displaced, displaced_positions
from planner.limits import FaceLimits
from planner.memory import release_freed_memory
from planner.progress import Stats
from planner.rays import Occlusion, make_occlusion
from planner.scene import Scene
from planner.selection.connected import MIN_CONSTRAINT
from planner.selection.greedy import GOAL_SLACK_M2, Selection
from planner.survey.registration import Registration, station_registration
from planner.threads import in_block_order
from planner.visibility.bundles import forget_bundles
from planner.visibility.coverage import CoverageTable, QualifiedPairs
from planner.visibility.overlap import (
    OverlapRows,
    RowsFanout,
    overlap_limits,
    shared_faces_only,
)
from planner.visibility.pairs import PairFinder, visible_pairs
from planner.visibility.qualify import Sight
from planner.visibility.robust import Qualify, kept_faces
from planner.walkgraph import door_faces

# pair tests of a station's displaced setups made at a time by the worst-case network:
# a station shares up to some 10^5 faces with its neighbours, and almost all of them pass
# from every setup, at some 70 bytes a pair until its ray is cast (two threads run); a
# million a block made a 3.8 M-face sports hall's peak (1,082 MiB, against 1,043 for the
# rest of its plan), in the same time as this
NETWORK_TESTS_PER_BLOCK = 250_000
# and of the stations' own faces from their setups: a station of a cluttered interior
# qualifies for some 10^5 - 10^6 faces, so a block of the default 2 M tests holds a few of
# its setups, two such blocks (two threads) the largest scratch of the stage
STATION_TESTS_PER_BLOCK = 500_000


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
    threads: int | None = None, seconds: dict[str, float] | None = None,
    overlap: Sight | None = None,
) -> Tolerance:
    """The tolerance report of the chosen ``stations`` (candidate indices into ``table``),
    at their ``displaced`` setups (N = S), with ``qualify`` the plan's coverage model.

    ``covered_area_m2`` is the plan's covered area and ``goal_area_m2`` the area the goal
    asks for; ``station_overlap`` the stations' overlap rows (as the survey has them), over
    the pieces of ``overlap`` (its scene, limits and occlusion; default: ``scene``,
    ``limits`` and ``occlusion``, the coverage's). ``seconds`` gets the wall time of the
    worst-case network (``tolerance_network``).
    """
    rows = [table.faces_of(c) for c in stations]
    holders = np.zeros(scene.n_faces, np.int32)  # (F,) chosen stations covering each face
    first = np.zeros(scene.n_faces, np.int32)  # (F,) the first of them
    for s in reversed(range(len(rows))):
        holders[rows[s]] += 1
        first[rows[s]] = s
    surely = np.zeros(scene.n_faces, bool)  # (F,) kept from every setup of some station
    # A face another station covers too matters only for ``surely``: its first station
    # tests it, and the others only where that one loses it from some setup (a face is
    # surely covered when any of them keeps it)
    firsts = [faces[first[faces] == s] for s, faces in enumerate(rows)]
    per_station = []
    limit = goal_area_m2 - GOAL_SLACK_M2
    for s, (faces, kept) in enumerate(kept_faces(scene, displaced, firsts.__getitem__, limits,
                                                 qualify, threads=threads)):
        alone = holders[faces] == 1  # all of a station's faces no other covers are here
        lost_m2 = (~kept & alone) @ scene.areas[faces]  # (K,) per setup
        worst = int(np.argmax(lost_m2))
        surely[faces[kept.all(axis=0)]] = True
        per_station.append(StationTolerance(
            worst_loss_m2=float(lost_m2[worst]),
            worst_offset_m=(float(displaced.offsets_m[worst, 0]),
                            float(displaced.offsets_m[worst, 1])),
            setups=int(displaced.valid[s].sum()),
            critical=bool(covered_area_m2 - float(lost_m2[worst]) < limit)))
    del firsts
    others = [faces[(first[faces] != s) & ~surely[faces]] for s, faces in enumerate(rows)]
    for faces, kept in kept_faces(scene, displaced, others.__getitem__, limits, qualify,
                                  threads=threads):
        surely[faces[kept.all(axis=0)]] = True
    del others, first
    worst_case_m2 = float(scene.areas[surely].sum())
    del rows, holders, surely  # (F,) arrays and every station's faces: not held below
    started = time.perf_counter()
    if overlap is not None:
        scene, limits, occlusion = overlap.scene, overlap.limits, overlap.occlusion
    components = _worst_case_network(
        scene, displaced, limits, station_overlap, min_overlap_m2, overlap_density_pts_m2,
        occlusion, file_faces, threads)
    if seconds is not None:
        seconds["tolerance_network"] = time.perf_counter() - started
    return Tolerance(
        placement_tolerance_m=tolerance_m,
        setups_per_station=len(displaced.offsets_m), stations=tuple(per_station),
        goal_area_m2=goal_area_m2, worst_case_covered_area_m2=worst_case_m2,
        goal_holds=worst_case_m2 >= limit, network_holds=len(components) <= 1,
        worst_case_components=components)


def _worst_case_network(
    scene: Scene, displaced: Displaced, limits: FaceLimits, station_overlap: sp.csr_matrix,
    min_overlap_m2: float | None, overlap_density_pts_m2: float, occlusion: Occlusion,
    file_faces: bool, threads: int | None, *, forest_first: bool = True,
) -> tuple[tuple[int, ...], ...]:
    """Components (station ids) of the registration network when every station keeps only
    the shared overlap faces it qualifies for from all its setups.

    The components need a spanning forest only: the strongest spanning forest of the
    nominal network (most overlap, one tree per nominal component). Each forest edge is
    first judged on a sample of the faces its stations share (:func:`_sample`), which
    can prove that it holds whatever the other faces do (:func:`_holds`); an edge its
    sample cannot prove is judged on all its shared faces. When every forest edge holds
    and no edge between two nominal components can ever pass (:func:`_apart_for_good`),
    the worst-case components are the nominal ones. Otherwise every shared face is tested
    and the components are those of the whole worst-case network. On the 3.7 M-face
    office of ``benchmarks/ifc_office.py`` (``--width-m 25 --depth-m 37 --storeys 2``)
    the network cast 7.1 M rays instead of 36.0 M, with the same components.
    ``forest_first`` false tests every shared face straight away (the reference the
    forest is checked against).
    """
    doors = door_faces(scene)
    overlap = overlap_limits(limits, overlap_density_pts_m2)
    if (doors & limits.occludes).any():  # doors are open for the overlap rays, as the survey's
        overlap = dataclasses.replace(overlap, occludes=limits.occludes & ~doors)
        occlusion = make_occlusion(scene, overlap.occludes, "embree", file_faces=file_faces,
                                   exact=occlusion.exact)
    shared = shared_faces_only(station_overlap)
    rows = [np.asarray(shared.indices[shared.indptr[n]:shared.indptr[n + 1]], np.int32)
            for n in range(shared.shape[0])]

    def qualify(positions: NDArray[np.float64], cut: FaceLimits) -> Iterator[QualifiedPairs]:
        # kept_faces reads them in any order: no sort. Nearly every shared face passes the
        # limits from every setup, so the setups go a few at a time (NETWORK_TESTS_PER_BLOCK)
        finder = PairFinder(scene, cut)
        for start, stop in finder.blocks(positions, most_tests=NETWORK_TESTS_PER_BLOCK):
            pairs, _ = finder.find(positions[start:stop], start, ordered=False)
            visible = visible_pairs(occlusion, pairs, positions, scene)
            yield QualifiedPairs(pairs.candidate[visible], pairs.face[visible],
                                 pairs.lpd_pts_m2[visible])

    def kept_rows(tested: list[NDArray[np.int32]]) -> list[NDArray[np.int32]]:
        """Per station, the faces of ``tested`` (ascending) kept from every setup."""
        return [faces[kept.all(axis=0)] for faces, kept in
                kept_faces(scene, displaced, tested.__getitem__, overlap, qualify,
                           threads=threads)]

    def components(tested: list[NDArray[np.int32]]) -> tuple[tuple[int, ...], ...]:
        kept = kept_rows(tested)
        indptr = np.zeros(len(kept) + 1, np.int64)
        np.cumsum([len(r) for r in kept], out=indptr[1:])
        indices = np.concatenate(kept) if kept else np.zeros(0, np.int32)
        worst = sp.csr_matrix((np.ones(len(indices), bool), indices, indptr),
                              shape=(len(kept), scene.n_faces))
        return station_registration(scene, worst, min_overlap_m2,
                                    overlap_density_pts_m2).components

    nominal = station_registration(scene, shared, min_overlap_m2, overlap_density_pts_m2)
    if forest_first and len(rows) > 1 and _apart_for_good(scene, nominal, rows, min_overlap_m2):
        forest = _strongest_forest(nominal, len(rows))

        def edge(pair: tuple[int, int]) -> tuple[NDArray[np.int32], NDArray[np.int32]]:
            faces = _common(rows[pair[0]], rows[pair[1]])
            return faces, _sample(scene, faces)

        edge_faces, samples = (list(column) for column in zip(
            *in_block_order(edge, forest, threads=threads), strict=True)) if forest else ([], [])
        tested: list[list[NDArray[np.int32]]] = [[] for _ in rows]
        for (a, b), sample in zip(forest, samples, strict=True):
            tested[a].append(sample)
            tested[b].append(sample)
        sampled = [np.unique(np.concatenate(t)) if t else np.zeros(0, np.int32)
                   for t in tested]
        kept = kept_rows(sampled)
        tried = sampled  # per station, the faces tested so far
        unproven = [i for i, ((a, b), faces, sample) in enumerate(
            zip(forest, edge_faces, samples, strict=True))
            if not _holds(scene, faces, sample, kept[a], kept[b], min_overlap_m2)]
        if unproven:  # their other faces too, then each such edge is judged on all of them
            kept, tried = _tested_more(
                scene.n_faces, kept_rows, kept, tried, [forest[i] for i in unproven],
                [edge_faces[i] for i in unproven])
        unproven_set = set(unproven)
        holding = [pair for i, pair in enumerate(forest) if i not in unproven_set
                   or _holds(scene, edge_faces[i], edge_faces[i], kept[pair[0]],
                             kept[pair[1]], min_overlap_m2)]
        if len(holding) == len(forest):
            return nominal.components
        return _grown_components(scene, nominal, rows, holding, kept, tried, kept_rows,
                                 min_overlap_m2, overlap_density_pts_m2)
    return components(rows)


def _tested_more(n_faces: int,
                 kept_rows: Callable[[list[NDArray[np.int32]]], list[NDArray[np.int32]]],
                 kept: list[NDArray[np.int32]], tested: list[NDArray[np.int32]],
                 edges: list[tuple[int, int]], edge_faces: list[NDArray[np.int32]]
                 ) -> tuple[list[NDArray[np.int32]], list[NDArray[np.int32]]]:
    """``kept`` and ``tested`` (per station, ascending: the faces it keeps from all its
    setups, of those tested) once both stations of each of ``edges`` are tested on every
    face of its ``edge_faces``."""
    wanted: list[list[NDArray[np.int32]]] = [[] for _ in kept]
    for pair, faces in zip(edges, edge_faces, strict=True):
        for n in pair:
            wanted[n].append(faces)
    new = [_ascending_union(n_faces, w, without=tested[n]) if w else np.zeros(0, np.int32)
           for n, w in enumerate(wanted)]
    more = kept_rows(new)
    return ([_ascending_union(n_faces, [k, m]) if len(m) else k
             for k, m in zip(kept, more, strict=True)],
            [_ascending_union(n_faces, [t, w]) if len(w) else t
             for t, w in zip(tested, new, strict=True)])


def _ascending_union(n_faces: int, arrays: list[NDArray[np.int32]],
                     without: NDArray[np.int32] | None = None) -> NDArray[np.int32]:
    """(k,) int32 ascending: the faces in any of ``arrays`` (face indices below
    ``n_faces``) and not in ``without``; ``np.union1d`` and ``np.setdiff1d`` give the
    same, through a sort of every face given (an edge's shared faces, once per edge of the
    station: millions on a sports hall), where an (F,) mark costs one pass."""
    mark = np.zeros(n_faces, bool)
    for faces in arrays:
        mark[faces] = True
    if without is not None:
        mark[without] = False
    return np.flatnonzero(mark).astype(np.int32)


def _grown_components(
    scene: Scene, nominal: Registration, rows: list[NDArray[np.int32]],
    holding: list[tuple[int, int]], kept: list[NDArray[np.int32]],
    tested: list[NDArray[np.int32]],
    kept_rows: Callable[[list[NDArray[np.int32]]], list[NDArray[np.int32]]],
    min_overlap_m2: float | None, overlap_density_pts_m2: float,
) -> tuple[tuple[int, ...], ...]:
    """The worst-case components when some edge of the strongest forest fails: those of
    testing every shared face (:func:`_worst_case_network`), found by testing only the
    edges that could still join two groups.

    The groups start as the stations the forest's ``holding`` edges (0-based pairs) join.
    An edge can join two groups only if the stations share faces in one nominal component
    (between components none ever passes: :func:`_apart_for_good`). Round by round, for
    each two groups still apart, their strongest untested such edge is tested on all its
    shared faces (all of them, once one has failed: groups that stay apart need every
    edge between them ruled out) and decided as the whole worst-case network decides it
    (:func:`station_registration` of the two stations' kept faces: both are tested on
    every face they share, so what they both keep is exact); one that holds merges its
    groups. When no such edge is left, no edge of the worst-case network joins two groups,
    and every group is joined by edges that hold: the groups are its components. A face is
    tested for a station at most once (``tested``), so this never casts more than testing
    every shared face, and far less when the groups left apart are a few small rooms."""
    groups = DisjointSet(range(len(rows)))
    for a, b in holding:
        groups.merge(a, b)
    component = {s - 1: k for k, members in enumerate(nominal.components) for s in members}
    # every edge that may pass in the worst case, strongest first (ties: station order)
    edges = sorted(((e.a - 1, e.b - 1, e.overlap_m2) for e in nominal.edges
                    if component[e.a - 1] == component[e.b - 1]),
                   key=lambda e: (-e[2], e[0], e[1]))
    decided: set[tuple[int, int]] = set()
    failed_between: set[tuple[int, int]] = set()  # groups whose strongest edge failed
    while True:
        batch: list[tuple[int, int]] = []
        taken: set[tuple[int, int]] = set()
        for a, b, _ in edges:
            ga, gb = groups[a], groups[b]
            between = (min(ga, gb), max(ga, gb))
            if ga == gb or (a, b) in decided or (
                    between in taken and between not in failed_between):
                continue
            taken.add(between)
            batch.append((a, b))
        if not batch:
            break
        kept, tested = _tested_more(scene.n_faces, kept_rows, kept, tested, batch,
                                    [_common(rows[a], rows[b]) for a, b in batch])
        for a, b in batch:
            decided.add((a, b))
            pair = sp.csr_matrix(
                (np.ones(len(kept[a]) + len(kept[b]), bool),
                 np.concatenate([kept[a], kept[b]]),
                 np.array([0, len(kept[a]), len(kept[a]) + len(kept[b])])),
                shape=(2, scene.n_faces))
            registration = station_registration(scene, pair, min_overlap_m2,
                                                overlap_density_pts_m2)
            if any(e.ok for e in registration.edges):
                groups.merge(a, b)
            else:
                ga, gb = groups[a], groups[b]
                failed_between.add((min(ga, gb), max(ga, gb)))
    return tuple(sorted(tuple(sorted(s + 1 for s in subset)) for subset in groups.subsets()))


# the share of an edge's normal scatter (its trace) a sample keeps in every direction: a
# forest edge is proven when its sample's kept faces alone give MIN_CONSTRAINT against the
# whole edge's area, so this leaves room for some of the sample to be lost
_SAMPLE_CONSTRAINT = 2.0 * MIN_CONSTRAINT


def _common(a: NDArray[np.int32], b: NDArray[np.int32]) -> NDArray[np.int32]:
    """The faces both ascending face lists hold, ascending (no sort: one binary search
    per face of ``a``)."""
    if not len(a) or not len(b):
        return np.zeros(0, np.int32)
    at = np.minimum(np.searchsorted(b, a), len(b) - 1)
    both: NDArray[np.int32] = a[b[at] == a]
    return both


def _scatter(scene: Scene, faces: NDArray[np.int32]) -> NDArray[np.float64]:
    """(3, 3) float64: the area-weighted normal scatter of ``faces``."""
    normals = scene.normals_of(faces)
    scatter: NDArray[np.float64] = (normals * scene.areas[faces][:, None]).T @ normals
    return scatter


def _sample(scene: Scene, faces: NDArray[np.int32]) -> NDArray[np.int32]:
    """(s,) ascending: some of an edge's shared ``faces`` whose normal scatter carries at
    least ``_SAMPLE_CONSTRAINT`` of the edge's whole area in every direction (every face
    when no smaller sample is found). Along each axis of the edge's own scatter, the faces
    facing it most are taken until they carry that share; among equals (the pieces of one
    wall) in a pseudo-random order, so a sample spreads over the surface."""
    if not len(faces):
        return faces
    area_m2 = scene.areas[faces]
    need_m2 = _SAMPLE_CONSTRAINT * float(area_m2.sum())
    axes = np.linalg.eigh(_scatter(scene, faces))[1]  # (3, 3) columns
    along_m2 = (scene.normals_of(faces) @ axes) ** 2 * area_m2[:, None]  # (n, 3)
    # the faces in a pseudo-random order, then stably by weight along each axis
    spread = np.argsort((faces.astype(np.uint64) * np.uint64(2654435761)) % np.uint64(1 << 32))
    picked = np.zeros(len(faces), bool)
    for axis in range(3):
        order = spread[np.argsort(-np.round(along_m2[spread, axis], 12), kind="stable")]
        enough = int(np.searchsorted(np.cumsum(along_m2[order, axis]), need_m2)) + 1
        picked[order[:enough]] = True
    sample = faces[picked]
    if np.linalg.eigvalsh(_scatter(scene, sample))[0] < need_m2:
        return faces
    return sample


def _holds(scene: Scene, faces: NDArray[np.int32], sample: NDArray[np.int32],
           kept_a: NDArray[np.int32], kept_b: NDArray[np.int32],
           min_overlap_m2: float | None) -> bool:
    """Whether the edge whose shared faces are ``faces`` surely holds in the worst case,
    from its ``sample`` tested only: ``kept_a`` and ``kept_b`` are the tested faces each
    station keeps from all its setups.

    The worst-case shared faces K hold the sample's faces both keep (K_s) and some of the
    untested ones U. Adding faces adds a positive semi-definite scatter, so K's smallest
    eigenvalue is at least K_s's; K's trace (its area) is at most K_s's plus U's. When
    ``MIN_CONSTRAINT`` times that bound is still below K_s's smallest eigenvalue, and K_s
    alone has the minimum overlap, the edge passes whatever U keeps (a relative margin of
    1e-9 covers rounding)."""
    both = _common(_common(sample, kept_a), kept_b)
    kept_m2 = float(scene.areas[both].sum())
    if not kept_m2 > 0 or (min_overlap_m2 is not None
                           and kept_m2 < min_overlap_m2 * (1 + 1e-9)):
        return False
    untested_m2 = float(scene.areas[faces].sum()) - float(scene.areas[sample].sum())
    smallest = float(np.linalg.eigvalsh(_scatter(scene, both))[0])
    return smallest >= MIN_CONSTRAINT * (kept_m2 + max(untested_m2, 0.0)) * (1 + 1e-9)


def _apart_for_good(scene: Scene, nominal: Registration, rows: list[NDArray[np.int32]],
                    min_overlap_m2: float | None) -> bool:
    """Whether no two stations of different nominal components can have an ok edge in the
    worst case, whatever faces the setups lose: only then do the components of the
    worst-case network follow from its nominal forest (see :func:`_worst_case_network`).

    The worst-case faces K two stations share are some of their nominal shared faces N.
    The area of K is at most N's. For any unit vector e, the smallest eigenvalue of K's
    normal scatter is at most e^T M_K e <= e^T M_N e, and K's trace (its area) is at least
    the smallest face of N: with e N's weakest direction, an edge whose N carries there
    less than half of ``MIN_CONSTRAINT`` times that face can never pass the constraint
    test (the half absorbs rounding). Such edges are the common ones between components:
    stations on two floors that share only a stair opening's coplanar faces.
    """
    label = {s: k for k, component in enumerate(nominal.components) for s in component}
    for edge in nominal.edges:
        if label[edge.a] == label[edge.b]:
            continue
        faces = _common(rows[edge.a - 1], rows[edge.b - 1])
        if not len(faces):
            continue
        area_m2 = scene.areas[faces]
        if min_overlap_m2 is not None and float(area_m2.sum()) < min_overlap_m2 * (1 - 1e-9):
            continue
        weakest = np.linalg.eigh(_scatter(scene, faces))[1][:, 0]
        along_m2 = float(((scene.normals_of(faces) @ weakest) ** 2) @ area_m2)
        if along_m2 >= 0.5 * MIN_CONSTRAINT * float(area_m2.min()):
            return False
    return True


def _strongest_forest(registration: Registration, n: int) -> list[tuple[int, int]]:
    """(a, b) 0-based station pairs, a < b: a spanning forest of the ok edges that keeps
    the largest overlaps (a minimum spanning forest of the reversed overlaps; one tree per
    component of the nominal network)."""
    ok = [e for e in registration.edges if e.ok]
    if not ok:
        return []
    top = max(e.overlap_m2 for e in ok)
    weights = sp.coo_matrix(([top + 1.0 - e.overlap_m2 for e in ok],
                             ([e.a - 1 for e in ok], [e.b - 1 for e in ok])), shape=(n, n))
    tree = minimum_spanning_tree(weights.tocsr()).tocoo()
    return sorted((min(a, b), max(a, b))
                  for a, b in zip(tree.row.tolist(), tree.col.tolist(), strict=True))


def plan_tolerance(sight: Sight, table: CoverageTable, chosen: Selection,
                   stations_xyz: NDArray[np.float64], station_overlap: sp.csr_matrix | None,
                   stats: Stats, *, threads: int | None = None,
                   fanout: RowsFanout | None = None, overlap: Sight | None = None
                   ) -> tuple[Tolerance, sp.csr_matrix]:
    """The tolerance report of the plan's ``chosen`` stations at (S, 3) ``stations_xyz``,
    and the stations' overlap rows it was judged with (``station_overlap`` when the
    selection made them; otherwise made here, cut to the faces two stations share as the
    survey cuts them, so the survey reuses them), over the pieces of ``overlap`` (default:
    the coverage's, ``sight``)."""
    scene, spec = sight.scene, sight.spec
    pieces = sight if overlap is None else overlap
    if station_overlap is None:  # the survey's rows, made once for both (its "overlap"),
        # cut to the faces two stations share as the survey cuts them (no whole matrix)
        t_rows = time.perf_counter()
        station_overlap = OverlapRows(
            pieces.scene, stations_xyz, pieces.limits, pieces.occlusion,
            spec.overlap_density_pts_m2, threads=threads,
            file_faces=pieces.file_faces, fanout=fanout
        ).shared_matrix(range(len(chosen.stations)))
        stats.seconds["overlap"] = time.perf_counter() - t_rows
    forget_bundles(pieces.scene)  # only the overlap rows reach far enough to use them
    # the overlap rows' scratch, still in their threads' heaps, and then the setups' (the
    # file's corners, the clearance test's faces), before the setups' rays make the peak
    release_freed_memory()
    t_tolerance, cpu_tolerance = time.perf_counter(), time.process_time()
    displaced = displaced_positions(
        scene, stations_xyz, spec.tolerance_radius_m, spec.clearance_m, sight.caster)
    release_freed_memory()
    stats.seconds["tolerance_setups"] = time.perf_counter() - t_tolerance
    tolerance = placement_tolerance(
        scene, table, chosen.stations, displaced, sight.limits,
        sight.qualifier(most_tests=STATION_TESTS_PER_BLOCK),
        tolerance_m=spec.tolerance_radius_m,
        covered_area_m2=chosen.covered_area_m2[-1] if chosen.stations else 0.0,
        goal_area_m2=spec.coverage_goal * table.max_achievable_area_m2,
        station_overlap=station_overlap, min_overlap_m2=spec.min_overlap_m2,
        overlap_density_pts_m2=spec.overlap_density_pts_m2, occlusion=sight.occlusion,
        file_faces=sight.file_faces, threads=threads, seconds=stats.seconds,
        overlap=overlap)
    stats.seconds["tolerance"] = time.perf_counter() - t_tolerance
    stats.cpu_seconds["tolerance"] = time.process_time() - cpu_tolerance
    return tolerance, station_overlap
