"""The visibility stage: which candidate-face pairs qualify, block by block, into the table.

Takes the scene as the visibility sees it (:class:`Sight`: the analytic limits, the
occlusion test, the first-hit caster) and the (C, 3) candidate positions; gives the
qualified pairs in candidate order (:func:`qualify_pairs`, :func:`qualified_blocks`), the
coverage table made from them (:func:`coverage_table`, :func:`robust_table`) and the chosen
stations' densities (:func:`station_densities`).

Candidates are processed in blocks by a small thread pool: the analytic limits are numpy
work and Embree releases the GIL, so both cores stay busy. Blocks are merged in candidate
order, which keeps the result independent of the number of threads.

Array letters: C candidates, F faces, S stations.
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from planner.candidates.placement import displaced_positions
from planner.errors import NothingVisibleError
from planner.limits import FaceLimits
from planner.memory import released_every
from planner.parameters import PlanSpec
from planner.progress import ProgressCallback, Stats, notify
from planner.rays import Backend, Occlusion, RayCaster, make_occlusion, make_ray_caster
from planner.scene import Scene, remesh
from planner.threads import in_block_order
from planner.visibility.bundles import bundle_culler
from planner.visibility.coverage import CoverageTable, QualifiedPairs, StationRows
from planner.visibility.pairs import (
    TESTS_PER_BLOCK,
    PairFinder,
    lpd_of_faces,
    search_reach_m,
    sorted_by_face,
    visible_pairs,
)
from planner.visibility.robust import robust_blocks, within_table
from planner.visibility.solids import closed_shells
from planner.visibility.splitting import faces_to_split

# blocks of qualified pairs read between two trims of the heap in the visibility stage.
# Its threads free mid-sized scratch (a block's visible pairs, its sort order: 1 to 32 MB)
# into their own arenas, where it stays resident among the blocks still in use. Measured
# on the 9.7 M-face office, the stage alone: a peak of 1,910 and 1,962 MiB without trims,
# 1,796 with one every 64 blocks (1,793 every 16), CPU time the same within the runs'
# spread (122.6-126.8 s without, 125.7 s with). Keeping such arrays out of the heap
# altogether (planner.memory.bound_heap, from the selection on) costs a fresh page at
# every first touch instead. A plan of few candidates with many pairs each (the 1.06 M-face
# cluttered interior of benchmarks/cluttered_interior.py: 105 candidates) gets few blocks,
# and a trim every 64 came at most once: the stage's largest sample was 1,131 - 1,327 MiB
# in three runs with one every 64, 1,052 - 1,055 in two with one every 16 (resident memory
# sampled every 30 ms, the shared machine; the stage's own peak varies from run to run).
TRIM_EVERY_BLOCKS = 16


@dataclass(frozen=True, eq=False)
class Sight:
    """The scene as the visibility sees it.

    Attributes
    ----------
    scene : the scene (split or not)
    spec : the plan's parameters
    limits : the analytic limits of every face
    occlusion : the occlusion test over the faces that occlude
    backend : "embree" or "bruteforce" (the slow reference)
    """

    scene: Scene
    spec: PlanSpec
    limits: FaceLimits
    occlusion: Occlusion
    backend: Backend

    @classmethod
    def of(cls, scene: Scene, spec: PlanSpec, backend: Backend) -> Sight:
        """The limits and the occlusion test of ``scene`` under ``spec``."""
        limits = FaceLimits.from_spec(spec, scene)
        return cls(scene, spec, limits,
                   make_occlusion(scene, limits.occludes, backend,
                                  file_faces=spec.occluders == "file",
                                  exact=spec.exact_rays),
                   backend)

    @functools.cached_property
    def caster(self) -> RayCaster:
        """First hits: the Embree occlusion object casts the floor rays too; the brute force
        needs one."""
        if isinstance(self.occlusion, RayCaster):
            return self.occlusion
        return make_ray_caster(self.scene, self.limits.occludes, file_faces=self.file_faces)

    @property
    def file_faces(self) -> bool:
        """Rays are tested against the file's faces, not the split pieces."""
        return self.spec.occluders == "file"

    def split_as_needed(self, positions: np.ndarray, max_edge_m: float | None = None
                        ) -> Sight:
        """The sight of the scene with the long faces split that some of the (C, 3)
        candidate ``positions`` can qualify part of (:mod:`planner.visibility.splitting`),
        into pieces of at most ``max_edge_m`` (default: the scene's ``split_max_edge_m``)."""
        scene = self.scene
        edge_m = scene.split_max_edge_m if max_edge_m is None else max_edge_m
        assert edge_m is not None
        split = faces_to_split(scene, positions, self.limits, edge_m,
                               self.spec.overlap_density_pts_m2)
        scene = remesh(scene, edge_m, split=split)
        limits = FaceLimits.from_spec(self.spec, scene)
        return Sight(scene, self.spec, limits,
                     make_occlusion(scene, limits.occludes, self.backend, file_faces=True,
                                    like=self.occlusion, exact=self.spec.exact_rays),
                     self.backend)

    def overlap_sight(self, positions: np.ndarray) -> Sight | None:
        """The sight the registration overlap is measured on: the file's faces split into
        pieces of at most ``overlap_max_edge_m`` where the (C, 3) ``positions`` can qualify
        part of them, coarser than the coverage's (on the 9.7 M-piece office, 1 m pieces
        take the survey's overlap from 22.7 to 3.3 s; faces between the two edges are
        then judged whole, which moves the constraint of some edges across its
        threshold). None when the overlap is measured on the coverage's pieces: no
        ``overlap_max_edge_m``, the scene is not split as needed (already remeshed, or the
        mesh as given), or its pieces are as coarse already."""
        edge_m = self.spec.overlap_max_edge_m
        own_m = self.scene.split_max_edge_m
        if edge_m is None or own_m is None or edge_m <= own_m:
            return None
        return self.split_as_needed(positions, edge_m)

    def qualifier(self, most_tests: int = TESTS_PER_BLOCK
                  ) -> Callable[[np.ndarray, FaceLimits], Iterator[QualifiedPairs]]:
        """The plan's coverage model for a few displaced setups at a time (one thread each:
        the caller runs positions in parallel), at most ``most_tests`` pair tests a block
        (the same pairs qualify whatever the blocks)."""
        def qualify(positions: np.ndarray, limits: FaceLimits) -> Iterator[QualifiedPairs]:
            # a station's own faces only: bundles would cast rays for every face in reach
            return qualified_blocks(self, positions, Stats(), threads=1, bundles=False,
                                    limits=limits, most_tests=most_tests)
        return qualify


class CoverageFanout(Protocol):
    """Computes the qualified pairs elsewhere (a cluster: :mod:`planner.scaleout`)."""

    def coverage_blocks(self, sight: Sight, positions: np.ndarray,
                        progress: ProgressCallback | None
                        ) -> Iterator[tuple[QualifiedPairs, int, int]] | None:
        """The qualified pairs of the (C, 3) candidate ``positions`` as
        :func:`qualify_pairs` gives them (blocks in candidate order, with the pairs tested
        and rays cast); None when this sight's pairs cannot be computed there (they are
        then computed here)."""
        ...


def coverage_table(sight: Sight, positions: np.ndarray, stats: Stats, *,
                   progress: ProgressCallback | None = None,
                   threads: int | None = None,
                   fanout: CoverageFanout | None = None) -> CoverageTable:
    """The coverage table of the (C, 3) candidate ``positions``: the qualified pairs under
    the plan's coverage model, robust when ``spec.robust``. With a ``fanout`` the
    qualified pairs are computed there where it can (the robust cut stays here).

    Raises :class:`NothingVisibleError` when no face qualifies from any candidate.
    """
    scene, spec = sight.scene, sight.spec
    started = time.perf_counter()
    remote = None if fanout is None else fanout.coverage_blocks(sight, positions, progress)
    blocks = (qualified_blocks(sight, positions, stats, progress=progress, threads=threads)
              if remote is None else _counted(remote, stats))
    table = CoverageTable.from_blocks(released_every(blocks, TRIM_EVERY_BLOCKS),
                                      len(positions), scene.areas)
    stats.qualified_pairs = table.n_pairs
    stats.seconds["visibility"] = time.perf_counter() - started
    if spec.robust:  # a face counts only when it qualifies from every displaced setup too
        table = robust_table(sight, table, positions, stats, progress=progress,
                             threads=threads)
    if table.n_pairs == 0:
        raise NothingVisibleError(
            f"no face qualifies from any of the {len(positions)} candidates: check that "
            "the model is in metres (unit_scale), that candidates stand inside it, and the "
            f"limits (dof_min_m {spec.dof_min_m}, min_density_pts_m2 "
            f"{spec.min_density_pts_m2}, min_incidence_deg {spec.min_incidence_deg})"
        )
    return table


def _counted(blocks: Iterable[tuple[QualifiedPairs, int, int]], stats: Stats
             ) -> Iterator[QualifiedPairs]:
    """The pairs of ``blocks``, what was tested and cast counted in ``stats``."""
    for qualified, tested, rays in blocks:
        stats.pairs_tested += tested
        stats.rays_cast += rays
        yield qualified


def robust_table(sight: Sight, table: CoverageTable, positions: np.ndarray, stats: Stats, *,
                 progress: ProgressCallback | None = None,
                 threads: int | None = None) -> CoverageTable:
    """``table`` cut to the faces that qualify from every displaced setup of each
    candidate too (:mod:`planner.visibility.robust`)."""
    scene, spec = sight.scene, sight.spec
    t_robust = time.perf_counter()
    robust = CoverageTable.from_blocks(robust_blocks(
        scene, table, displaced_positions(
            scene, positions, spec.tolerance_radius_m, spec.clearance_m, sight.caster),
        sight.limits, sight.qualifier(), threads=threads,
        disc_radius_m=spec.tolerance_radius_m if spec.coverage_model == "centroid"
        else None,
        # part of the coverage table: a cancel is heard, the percentage stays put
        notify=lambda _: notify(progress, "visibility", 1.0)),
        len(positions), scene.areas)
    stats.seconds["robust"] = time.perf_counter() - t_robust
    return robust


def station_densities(sight: Sight, table: CoverageTable | StationRows, stations: tuple[int, ...],
                      stations_xyz: np.ndarray, stats: Stats, *,
                      threads: int | None = None) -> Iterator[QualifiedPairs]:
    """The chosen stations' qualified pairs with their LPDs, numbered by their place in
    ``stations`` ((S, 3) ``stations_xyz``), as :func:`~planner.selection.greedy.coverage_state`
    reads them.

    The table keeps no densities: the chosen stations' are computed again, a station or a
    block at a time. Under the centroid model a station's faces are its row of the table
    (robust or not): only their LPDs, without the pair search and the rays again (the
    office's 218 stations: 20 M rays). The sampled model's pairs are qualified again, alone:
    a few stations, not worth making the bundles again; small blocks, as the per-face
    results they fill are made beside them where the plan's memory peaks.
    """
    if sight.spec.coverage_model == "centroid":
        return _table_densities(sight.scene, sight.limits, table, stations, stations_xyz)
    densities = qualified_blocks(sight, stations_xyz, stats, threads=threads, bundles=False,
                                 most_tests=TESTS_PER_BLOCK // 4)
    if sight.spec.robust:
        densities = within_table(densities, table, stations)
    return densities


def _table_densities(scene: Scene, limits: FaceLimits, table: CoverageTable | StationRows,
                     stations: tuple[int, ...], stations_xyz: np.ndarray
                     ) -> Iterator[QualifiedPairs]:
    """The chosen stations' rows of the table with their LPDs, a station at a time and
    numbered by their place in ``stations``: the values the visibility computed for these
    pairs (:func:`lpd_of_faces`)."""
    for order, candidate in enumerate(stations):
        faces = table.faces_of(candidate)
        yield QualifiedPairs(np.full(len(faces), order, np.int32), faces,
                             lpd_of_faces(scene, limits, stations_xyz[order], faces))


def qualified_blocks(
    sight: Sight,
    positions: np.ndarray,
    stats: Stats,
    *,
    progress: ProgressCallback | None = None,
    threads: int | None = None,
    bundles: bool | None = None,
    most_tests: int = TESTS_PER_BLOCK,
    limits: FaceLimits | None = None,
) -> Iterator[QualifiedPairs]:
    """The qualified pairs of (C, 3) candidate positions under the plan's coverage model,
    block by block in candidate order (``bundles``, ``most_tests``: as
    :func:`qualify_pairs`; ``limits``: other limits than the sight's); counts what was
    tested in ``stats``."""
    spec = sight.spec
    limits = sight.limits if limits is None else limits
    if spec.coverage_model == "sampled":
        from planner.visibility.sampled import qualify_sampled_pairs

        blocks = qualify_sampled_pairs(
            sight.scene, positions, limits, sight.occlusion, spec.samples_per_face,
            spec.min_sampled_fraction, progress=progress, threads=threads)
    else:
        blocks = qualify_pairs(sight.scene, positions, limits, sight.occlusion,
                               progress=progress, threads=threads, bundles=bundles,
                               most_tests=most_tests)
    yield from _counted(blocks, stats)


def qualify_pairs(
    scene: Scene,
    positions: np.ndarray,
    limits: FaceLimits,
    occlusion: Occlusion,
    *,
    progress: ProgressCallback | None = None,
    threads: int | None = None,
    bundles: bool | None = None,
    most_tests: int = TESTS_PER_BLOCK,
    reach_m: float | None = None,
) -> Iterator[tuple[QualifiedPairs, int, int]]:
    """The qualified pairs of (C, 3) candidate positions, block by block in candidate order
    (each sorted by (candidate, face)), with the pairs tested and rays cast for it.

    ``bundles``: rule out bundles of pieces hidden behind one occluder with four rays
    each (:mod:`planner.visibility.bundles`): None where it pays (a long reach), True always,
    False never; the same pairs qualify either way. ``most_tests``: the pair tests a block
    of candidates makes at most (:meth:`PairFinder.blocks`), which bounds its scratch.
    ``reach_m``: the search's reach (default: the limits'; a tile passes its model's).

    Blocks of candidates run on a thread pool (the compiled limits loop and Embree both
    release the GIL); they come out in block order, so they do not depend on timing.
    """
    reach_m = search_reach_m(limits) if reach_m is None else reach_m
    culler = None if bundles is False else bundle_culler(scene, reach_m, occlusion,
                                                         always=bool(bundles))
    finder = PairFinder(scene, limits, reach_m=reach_m, shells=closed_shells(scene, occlusion),
                        bundle_of=None if culler is None else culler.bundles.bundle_of)
    # neighbouring candidates in a block share the pair search of their cells
    stop_of = dict(finder.blocks(positions, most_tests=most_tests))

    def block(start: int) -> tuple[QualifiedPairs, int, int]:
        points = positions[start:stop_of[start]]
        hidden, bundle_rays = (None, 0) if culler is None else culler.hidden(points)
        # unordered: sorting the visible pairs afterwards costs a fraction of sorting all
        pairs, tested = finder.find(points, start, hidden, ordered=False)
        visible = np.flatnonzero(visible_pairs(occlusion, pairs, positions, scene))
        candidate, face = pairs.candidate[visible], pairs.face[visible]
        order = sorted_by_face(candidate, face)
        qualified = QualifiedPairs(candidate[order], face[order],
                                   pairs.lpd_pts_m2[visible[order]])
        return qualified, tested, len(pairs) + bundle_rays

    return in_block_order(block, list(stop_of), threads=threads,
                          notify=lambda fraction: notify(progress, "visibility", fraction))
