"""``plan()``: scene -> candidates -> split -> pairs -> visibility -> coverage -> selection ->
report.

The split happens here for a scene read with ``split_faces="as_needed"``: once the candidates
are known, only the long faces one of them can qualify part of are split
(:mod:`planner.method.splitting`).

Candidates are processed in blocks by a small thread pool: the analytic limits are numpy
work and Embree releases the GIL, so both cores stay busy. Blocks are merged in candidate
order, which keeps the result independent of the number of threads.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from planner.errors import CancelledError, NoCandidatesError, NothingVisibleError
from planner.io.orientation import scene_rotation, to_plan
from planner.memory import bound_heap, release_freed_memory, released_every
from planner.method.bundles import bundle_culler, forget_bundles
from planner.method.candidates import CandidateSet, explicit_candidates, generate_grid
from planner.method.connectivity import Connectivity
from planner.method.coverage import CoverageTable, QualifiedPairs
from planner.method.optimal import OptimalResult, choose_stations
from planner.method.pairs import (
    TESTS_PER_BLOCK,
    FaceLimits,
    PairFinder,
    lpd_of_faces,
    sorted_by_face,
)
from planner.method.placement import (
    at_heights,
    displaced_positions,
    robust_blocks,
    within_table,
)
from planner.method.selection import Selection, coverage_state, fixed_candidates
from planner.method.splitting import faces_to_split
from planner.method.visibility import (
    Backend,
    Occlusion,
    RayCaster,
    make_occlusion,
    make_ray_caster,
)
from planner.parameters import PlanSpec
from planner.scene import Scene, remesh
from planner.survey.fieldwork import Survey, survey
from planner.survey.registration import OverlapRows, connected_greedy, overlap_graph
from planner.survey.tolerance import Tolerance, placement_tolerance
from planner.threads import in_block_order

# from this many faces on, the survey and the outputs keep their arrays out of the heap
# (planner.memory.bound_heap), where the plan's peak is: a fresh page costs a fault at first
# touch (over a whole 3.7 M-face plan some 10 % more CPU time, so not in the visibility),
# but freed scratch no longer piles up under the survey's peak (the 9.7 M-face office:
# some 250 MiB less); below it memory is not what limits a site server
BOUNDED_HEAP_FACES = 2_000_000

# progress(stage, fraction 0..1) -> True to cancel
ProgressCallback = Callable[[str, float], bool | None]


@dataclass
class Stats:
    """What the run did, for benchmarks and the job record (never in the result bytes)."""

    seconds: dict[str, float] = field(default_factory=dict)
    cpu_seconds: dict[str, float] = field(default_factory=dict)  # process CPU, all threads
    pairs_tested: int = 0
    rays_cast: int = 0
    qualified_pairs: int = 0
    overlap_rows: int = 0  # candidates whose overlap row the connected greedy computed


@dataclass(frozen=True, eq=False)
class PlanResult:
    """Everything a plan produced, before it is written out (see :mod:`planner.outputs.report`)."""

    scene: Scene
    spec: PlanSpec
    candidates: CandidateSet
    table: CoverageTable
    limits: FaceLimits
    selections: dict[str, Selection]  # full orders, per method
    chosen: Selection  # the plan: the chosen method up to the goal
    optimal: OptimalResult | None
    faces: dict[str, np.ndarray]
    stats: Stats
    optimal_curve: tuple[OptimalResult, ...] = ()  # per goal of curve_goals
    selection_report: dict[str, Any] = field(default_factory=dict)  # plan.json "selection"
    survey: Survey | None = None  # registration, route, field time (planner.survey.fieldwork)
    tolerance: Tolerance | None = None  # placement tolerance (planner.survey.tolerance)


def _notify(progress: ProgressCallback | None, stage: str, fraction: float) -> None:
    if progress is not None and progress(stage, min(max(fraction, 0.0), 1.0)):
        raise CancelledError(f"the plan was cancelled during {stage}")


def _new_stage(progress: ProgressCallback | None, stage: str) -> None:
    """Start ``stage``: release what the last one freed, then tell ``progress``."""
    release_freed_memory()
    _notify(progress, stage, 0.0)


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


def plan(
    scene: Scene,
    spec: PlanSpec,
    *,
    progress: ProgressCallback | None = None,
    backend: Backend = "embree",
    threads: int | None = None,
) -> PlanResult:
    """Plan the stations for ``scene`` under ``spec``.

    Parameters
    ----------
    progress : called with (stage, fraction) between blocks of work; returning True
        cancels the plan with :class:`CancelledError`
    backend : "embree" (default) or "bruteforce" (the slow reference)
    threads : worker threads for visibility (default: the machine's cores)
    """
    stats = Stats()
    t0, cpu0 = time.perf_counter(), time.process_time()
    if scene.split_max_edge_m is not None and (spec.occluders != "file" or backend != "embree"):
        scene = remesh(scene, scene.split_max_edge_m)  # the pieces occlude: split them all now
    limits = FaceLimits.from_spec(spec, scene)
    occlusion = make_occlusion(scene, limits.occludes, backend,
                               file_faces=spec.occluders == "file")
    _new_stage(progress, "candidates")
    if spec.candidates is not None:
        # given in model coordinates; the planner works Z-up (up_axis, planner.io.orientation)
        candidates = explicit_candidates(
            to_plan(scene_rotation(scene.metadata), np.asarray(spec.candidates)))
    elif scene.metadata.get("spaces"):
        from planner.io import ifc

        with _file_blamed(scene):
            candidates = at_heights(spec, lambda at: ifc.room_candidates(
                scene, at, _caster(scene, spec, limits, occlusion)))
    else:
        with _file_blamed(scene):
            candidates = at_heights(spec, lambda at: generate_grid(
                scene, at, _caster(scene, spec, limits, occlusion)))
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
                heights_m=None if candidates.heights_m is None
                else np.r_[candidates.heights_m, np.full(added, np.nan)])
    stats.seconds["candidates"] = time.perf_counter() - t0
    if scene.split_max_edge_m is not None:
        t_split = time.perf_counter()
        release_freed_memory()  # the candidate stage's scratch, before the pieces are made
        scene, limits, occlusion = _split_as_needed(scene, spec, candidates.positions, limits,
                                                    backend)
        stats.seconds["split"] = time.perf_counter() - t_split

    t1 = time.perf_counter()
    _new_stage(progress, "visibility")
    table = CoverageTable.from_blocks(
        released_every(_qualified_blocks(scene, spec, candidates.positions, limits, occlusion,
                                         stats, progress=progress, threads=threads),
                       TRIM_EVERY_BLOCKS),
        len(candidates), scene.areas)
    stats.qualified_pairs = table.n_pairs
    stats.seconds["visibility"] = time.perf_counter() - t1
    if spec.robust:  # a face counts only when it qualifies from every displaced setup too
        t_robust = time.perf_counter()
        table = CoverageTable.from_blocks(robust_blocks(
            scene, table, displaced_positions(
                scene, candidates.positions, spec.placement_tolerance_m, spec.clearance_m,
                _caster(scene, spec, limits, occlusion)),
            limits, _qualifier(scene, spec, occlusion), threads=threads,
            disc_radius_m=spec.placement_tolerance_m if spec.coverage_model == "centroid"
            else None,
            # part of the coverage table: a cancel is heard, the percentage stays put
            notify=lambda _: _notify(progress, "visibility", 1.0)),
            len(candidates), scene.areas)
        stats.seconds["robust"] = time.perf_counter() - t_robust
    if table.n_pairs == 0:
        raise NothingVisibleError(
            f"no face qualifies from any of the {len(candidates)} candidates: check that "
            "the model is in metres (unit_scale), that candidates stand inside it, and the "
            f"limits (dof_min_m {spec.dof_min_m}, min_density_pts_m2 "
            f"{spec.min_density_pts_m2}, min_incidence_deg {spec.min_incidence_deg})"
        )

    t2 = time.perf_counter()
    _new_stage(progress, "selection")
    rows = None
    connectivity = None
    min_overlap_m2 = spec.min_overlap_m2
    if min_overlap_m2 is not None:
        # the overlap rows (faces each candidate qualifies for at the overlap density) are
        # computed when a method first needs them: the connected greedy asks for a few
        rows = OverlapRows(scene, candidates.positions, limits, occlusion,
                           spec.overlap_density_pts_m2, threads=threads,
                           file_faces=spec.occluders == "file")
        if spec.method == "optimal" and not fixed:
            # optimal keeps the overlap graph connected: a flow MILP from connected greedy,
            # on the graph of every candidate's row
            t_graph = time.perf_counter()
            top_goal = max((spec.coverage_goal, *(spec.curve_goals or ())))
            connectivity = Connectivity(
                overlap_graph(rows.matrix(range(len(rows))), scene, min_overlap_m2),
                *(connected_greedy(table, rows, scene, candidates.positions,
                                   min_overlap_m2, weighted=w, goal=top_goal)
                  for w in (False, True)))
            stats.seconds["overlap_graph"] = time.perf_counter() - t_graph - rows.seconds
    outcome = choose_stations(
        table, method=spec.method, goal=spec.coverage_goal,
        time_limit_s=spec.optimal_time_limit_s, centroids=scene.centroids, fixed=fixed,
        curve_goals=spec.curve_goals,
        progress=lambda fraction: _notify(progress, "selection", fraction),
        connectivity=connectivity)
    selections, chosen, optimal = outcome.selections, outcome.chosen, outcome.optimal
    station_overlap = None
    if rows is not None and min_overlap_m2 is not None:
        if spec.method != "optimal":
            # registration constraint: every station after the first overlaps a chosen one
            chosen = connected_greedy(
                table, rows, scene, candidates.positions, min_overlap_m2,
                weighted=spec.method == "weighted_greedy", goal=spec.coverage_goal,
            ).truncated(spec.coverage_goal)
        station_overlap = rows.matrix(list(chosen.stations))
        stats.seconds["overlap"] = rows.seconds
        stats.overlap_rows = rows.n_computed
        rows = None  # its cached rows (and bundles) are not needed any more
    # selection without the overlap rows computed in it
    stats.seconds["selection"] = time.perf_counter() - t2 - stats.seconds.get("overlap", 0.0)
    for step, seconds in outcome.seconds.items():
        stats.seconds[f"selection_{step}"] = seconds
    stations_xyz = candidates.positions[list(chosen.stations)]  # (S, 3)
    release_freed_memory()
    if scene.n_faces >= BOUNDED_HEAP_FACES:
        bound_heap()  # from here on freed arrays leave the process at once, not at a trim
    tolerance = None
    if spec.placement_tolerance_m > 0:
        if station_overlap is None:  # the survey's rows, made once for both (its "overlap"),
            # cut to the faces two stations share as the survey cuts them (no whole matrix)
            t_rows = time.perf_counter()
            station_overlap = OverlapRows(
                scene, stations_xyz, limits, occlusion,
                spec.overlap_density_pts_m2, threads=threads,
                file_faces=spec.occluders == "file").shared_matrix(range(len(chosen.stations)))
            stats.seconds["overlap"] = time.perf_counter() - t_rows
        forget_bundles(scene)  # only the overlap rows reach far enough to use them
        t_tolerance, cpu_tolerance = time.perf_counter(), time.process_time()
        displaced = displaced_positions(
            scene, stations_xyz, spec.placement_tolerance_m,
            spec.clearance_m, _caster(scene, spec, limits, occlusion))
        stats.seconds["tolerance_setups"] = time.perf_counter() - t_tolerance
        tolerance = placement_tolerance(
            scene, table, chosen.stations, displaced, limits, _qualifier(scene, spec, occlusion),
            tolerance_m=spec.placement_tolerance_m,
            covered_area_m2=chosen.covered_area_m2[-1] if chosen.stations else 0.0,
            goal_area_m2=spec.coverage_goal * table.max_achievable_area_m2,
            station_overlap=station_overlap, min_overlap_m2=min_overlap_m2,
            overlap_density_pts_m2=spec.overlap_density_pts_m2, occlusion=occlusion,
            file_faces=spec.occluders == "file", threads=threads, seconds=stats.seconds)
        stats.seconds["tolerance"] = time.perf_counter() - t_tolerance
        stats.cpu_seconds["tolerance"] = time.process_time() - cpu_tolerance
        # its threads' freed scratch, still in their arenas (the office: 320 MB), before the
        # densities and the per-face results make the next peak
        release_freed_memory()
    # the table keeps no densities: the chosen stations' are computed again for the
    # per-face results, a station or a block at a time; with a scanner, each station's
    # least density margin over the faces it is credited with chooses its setting
    # (planner.scanners)
    if spec.coverage_model == "centroid":
        # a station's faces are its row of the table (robust or not): only their LPDs,
        # without the pair search and the rays again (the office's 218 stations: 20 M rays)
        densities: Iterator[QualifiedPairs] = _table_densities(
            scene, limits, table, chosen.stations, stations_xyz)
    else:
        # the sampled model's pairs qualified again, alone: a few stations, not worth
        # making the bundles again; small blocks, as the per-face results they fill are
        # made beside them where the plan's memory peaks
        densities = _qualified_blocks(
            scene, spec, stations_xyz, limits, occlusion, stats,
            threads=threads, bundles=False, most_tests=TESTS_PER_BLOCK // 4)
        if spec.robust:
            densities = within_table(densities, table, chosen.stations)
    faces = coverage_state(table, chosen.stations, densities,
                           None if spec.scanner is None else limits.min_density_pts_m2)
    margins = faces.pop("density_margin", None)
    plan_survey = survey(scene, spec, stations_xyz, limits,
                         occlusion, _caster(scene, spec, limits, occlusion), stats.seconds,
                         station_overlap=station_overlap, threads=threads,
                         density_margins=None if margins is None else margins.tolist())
    forget_bundles(scene)
    _new_stage(progress, "report")
    stats.cpu_seconds["plan"] = time.process_time() - cpu0
    return PlanResult(scene=scene, spec=spec, candidates=candidates, table=table,
                      limits=limits, selections=selections, chosen=chosen, optimal=optimal,
                      faces=faces, stats=stats, optimal_curve=outcome.curve,
                      selection_report=outcome.report, survey=plan_survey,
                      tolerance=tolerance)


def _table_densities(scene: Scene, limits: FaceLimits, table: CoverageTable,
                     stations: tuple[int, ...], stations_xyz: np.ndarray
                     ) -> Iterator[QualifiedPairs]:
    """The chosen stations' rows of the table with their LPDs, a station at a time and
    numbered by their place in ``stations`` (as :func:`coverage_state` reads them): the
    values the visibility computed for these pairs (:func:`lpd_of_faces`)."""
    for order, candidate in enumerate(stations):
        faces = table.faces_of(candidate)
        yield QualifiedPairs(np.full(len(faces), order, np.int32), faces,
                             lpd_of_faces(scene, limits, stations_xyz[order], faces))


# blocks of qualified pairs read between two trims of the heap in the visibility stage.
# Its threads free mid-sized scratch (a block's visible pairs, its sort order: 1 to 32 MB)
# into their own arenas, where it stays resident among the blocks still in use. Measured
# on the 9.7 M-face office, the stage alone: a peak of 1,910 and 1,962 MiB without trims,
# 1,796 with one every 64 blocks (1,793 every 16), CPU time the same within the runs'
# spread (122.6-126.8 s without, 125.7 s with). Keeping such arrays out of the heap
# altogether (planner.memory.bound_heap, from the selection on) costs a fresh page at
# every first touch instead.
TRIM_EVERY_BLOCKS = 64


def _split_as_needed(scene: Scene, spec: PlanSpec, positions: np.ndarray, limits: FaceLimits,
                     backend: Backend) -> tuple[Scene, FaceLimits, Occlusion]:
    """Split the long faces that some of the (C, 3) candidate ``positions`` can qualify part
    of (:mod:`planner.method.splitting`); the limits and the occlusion of the split scene."""
    assert scene.split_max_edge_m is not None
    split = faces_to_split(scene, positions, limits, scene.split_max_edge_m,
                           spec.overlap_density_pts_m2)
    scene = remesh(scene, scene.split_max_edge_m, split=split)
    limits = FaceLimits.from_spec(spec, scene)
    return scene, limits, make_occlusion(scene, limits.occludes, backend, file_faces=True)


def _caster(scene: Scene, spec: PlanSpec, limits: FaceLimits, occlusion: Occlusion
            ) -> RayCaster:
    """The Embree occlusion object casts the floor rays too; the brute force needs one."""
    if isinstance(occlusion, RayCaster):
        return occlusion
    return make_ray_caster(scene, limits.occludes, file_faces=spec.occluders == "file")


def _qualifier(scene: Scene, spec: PlanSpec, occlusion: Occlusion
               ) -> Callable[[np.ndarray, FaceLimits], Iterator[QualifiedPairs]]:
    """The plan's coverage model for a few displaced setups at a time (one thread each:
    the caller runs positions in parallel)."""
    def qualify(positions: np.ndarray, limits: FaceLimits) -> Iterator[QualifiedPairs]:
        # a station's own faces only: bundles would cast rays for every face in reach
        return _qualified_blocks(scene, spec, positions, limits, occlusion, Stats(), threads=1,
                                 bundles=False)
    return qualify


def _qualified_blocks(
    scene: Scene,
    spec: PlanSpec,
    positions: np.ndarray,
    limits: FaceLimits,
    occlusion: Occlusion,
    stats: Stats,
    *,
    progress: ProgressCallback | None = None,
    threads: int | None = None,
    bundles: bool | None = None,
    most_tests: int = TESTS_PER_BLOCK,
) -> Iterator[QualifiedPairs]:
    """The qualified pairs of (C, 3) candidate positions under the plan's coverage model,
    block by block in candidate order (``bundles``, ``most_tests``: as
    :func:`qualify_pairs`); counts what was tested in ``stats``."""
    if spec.coverage_model == "sampled":
        from planner.method.sampled import qualify_sampled_pairs

        blocks = qualify_sampled_pairs(
            scene, positions, limits, occlusion, spec.samples_per_face,
            spec.min_sampled_fraction, progress=progress, threads=threads)
    else:
        blocks = qualify_pairs(scene, positions, limits, occlusion, progress=progress,
                               threads=threads, bundles=bundles, most_tests=most_tests)
    for qualified, tested, rays in blocks:
        stats.pairs_tested += tested
        stats.rays_cast += rays
        yield qualified


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
) -> Iterator[tuple[QualifiedPairs, int, int]]:
    """The qualified pairs of (C, 3) candidate positions, block by block in candidate order
    (each sorted by (candidate, face)), with the pairs tested and rays cast for it.

    ``bundles``: rule out bundles of pieces hidden behind one occluder with four rays
    each (:mod:`planner.method.bundles`): None where it pays (a long reach), True always,
    False never; the same pairs qualify either way. ``most_tests``: the pair tests a block
    of candidates makes at most (:meth:`PairFinder.blocks`), which bounds its scratch.

    Blocks of candidates run on a thread pool (the compiled limits loop and Embree both
    release the GIL); they come out in block order, so they do not depend on timing.
    """
    finder = PairFinder(scene, limits)
    culler = None if bundles is False else bundle_culler(scene, finder.reach_m, occlusion,
                                                         always=bool(bundles))
    # neighbouring candidates in a block share the pair search of their cells
    stop_of = dict(finder.blocks(positions, most_tests=most_tests))

    def block(start: int) -> tuple[QualifiedPairs, int, int]:
        points = positions[start:stop_of[start]]
        hidden, bundle_rays = (None, 0) if culler is None else culler.hidden(points)
        # unordered: sorting the visible pairs afterwards costs a fraction of sorting all
        pairs, tested = finder.find(points, start, hidden, ordered=False)
        visible = np.flatnonzero(occlusion.visible(
            pairs.origin, pairs.direction, pairs.distance_m, pairs.face,
            exact_rays=pairs.exact_rays(positions, scene.centroids),
        ))
        candidate, face = pairs.candidate[visible], pairs.face[visible]
        order = sorted_by_face(candidate, face)
        qualified = QualifiedPairs(candidate[order], face[order],
                                   pairs.lpd_pts_m2[visible[order]])
        return qualified, tested, len(pairs) + bundle_rays

    return in_block_order(block, list(stop_of), threads=threads,
                          notify=lambda fraction: _notify(progress, "visibility", fraction))
