"""``plan()``: the method's stages, one call into each stage's package.

scene → candidates (:mod:`planner.candidates`) → faces split where needed → visibility and
the coverage table (:mod:`planner.visibility`) → the choice of stations
(:mod:`planner.selection`) → placement tolerance, the stations' per-face results and the
survey: registration, route, field time (:mod:`planner.survey`). What it gives,
:class:`PlanResult`, the outputs write (:mod:`planner.outputs`).

The split happens here for a scene read with ``split_faces="as_needed"``: once the candidates
are known, only the long faces one of them can qualify part of are split
(:mod:`planner.visibility.splitting`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from planner.candidates.generate import plan_candidates
from planner.candidates.grid import CandidateSet
from planner.limits import FaceLimits
from planner.memory import bound_heap, release_freed_memory
from planner.parameters import PlanSpec
from planner.progress import ProgressCallback, Stats, new_stage
from planner.rays import Backend
from planner.scaleout import DaskFanout, fanout_over
from planner.scene import Scene, remesh
from planner.selection.choose import choose
from planner.selection.greedy import Selection, coverage_state
from planner.selection.optimal import OptimalResult
from planner.survey.fieldwork import FieldClock, Survey, places_of, survey, with_settings
from planner.survey.tolerance import Tolerance, plan_tolerance
from planner.visibility.bundles import forget_bundles
from planner.visibility.coverage import CoverageTable, StationRows
from planner.visibility.qualify import Sight, coverage_table, station_densities
from planner.walkgraph import walk_area

__all__ = ["PlanResult", "ProgressCallback", "Stats", "plan"]

# from this many faces on, the selection does not hold the pieces' bundles and the survey
# and the outputs keep their arrays out of the heap
# (planner.memory.bound_heap), where the plan's peak is: a fresh page costs a fault at first
# touch (over a whole 3.7 M-face plan some 10 % more CPU time, so not in the visibility),
# but freed scratch no longer piles up under the survey's peak (the 9.7 M-face office:
# some 250 MiB less); below it memory is not what limits a site server
BOUNDED_HEAP_FACES = 2_000_000


@dataclass(frozen=True, eq=False)
class PlanResult:
    """Everything a plan produced, before it is written out (see :mod:`planner.outputs.report`)."""

    scene: Scene
    spec: PlanSpec
    candidates: CandidateSet
    table: CoverageTable | StationRows  # the stations' rows unless plan(keep_table=True)
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


def plan(
    scene: Scene,
    spec: PlanSpec,
    *,
    progress: ProgressCallback | None = None,
    backend: Backend = "embree",
    threads: int | None = None,
    dask_scheduler: str | None = None,
    keep_table: bool = False,
) -> PlanResult:
    """Plan the stations for ``scene`` under ``spec``.

    Parameters
    ----------
    progress : called with (stage, fraction) between blocks of work; returning True
        cancels the plan with :class:`~planner.errors.CancelledError`
    backend : "embree" (default) or "bruteforce" (the slow reference)
    threads : worker threads for visibility (default: the machine's cores)
    dask_scheduler : address of a Dask scheduler (``tcp://host:8786``): the visibility and
        the overlap rows run on its workers (:mod:`planner.scaleout`), the plan's bytes are
        the same; raises :class:`~planner.errors.SchedulerUnreachableError` when it cannot
        be reached
    keep_table : keep the whole coverage table as ``table`` (every candidate's row, for
        analyses of the table itself); by default the plan keeps only its stations' rows
        and the table's totals (:class:`~planner.visibility.coverage.StationRows`), which
        is all its outputs read, and lets the table go before the survey
    """
    with fanout_over(dask_scheduler) as fanout:
        return _plan(scene, spec, progress=progress, backend=backend, threads=threads,
                     fanout=fanout, keep_table=keep_table)


def _plan(scene: Scene, spec: PlanSpec, *, progress: ProgressCallback | None,
          backend: Backend, threads: int | None, fanout: DaskFanout | None,
          keep_table: bool) -> PlanResult:
    stats = Stats()
    t0, cpu0 = time.perf_counter(), time.process_time()
    if scene.split_max_edge_m is not None and (spec.occluders != "file" or backend != "embree"):
        scene = remesh(scene, scene.split_max_edge_m)  # the pieces occlude: split them all now
    sight = Sight.of(scene, spec, backend)
    new_stage(progress, "candidates")
    candidates, fixed = plan_candidates(scene, spec, sight.caster)
    stats.seconds["candidates"] = time.perf_counter() - t0
    # the file's faces as the candidates saw them, for the overlap's coarser pieces
    whole = sight if spec.overlap_max_edge_m is not None else None
    if scene.split_max_edge_m is not None:
        t_split = time.perf_counter()
        release_freed_memory()  # the candidate stage's scratch, before the pieces are made
        sight = sight.split_as_needed(candidates.positions)
        stats.seconds["split"] = time.perf_counter() - t_split
    new_stage(progress, "visibility")
    table = coverage_table(sight, candidates.positions, stats, progress=progress,
                           threads=threads, fanout=fanout)
    if sight.scene.n_faces >= BOUNDED_HEAP_FACES:
        # the pieces' bundles (75 MB on the 9.7 M-piece office) are not held under the
        # selection's peak: the overlap rows make them again (there 0.7 - 1.2 s; on a
        # smaller model the time counts more than the memory: interior-1m's took 0.4 s)
        forget_bundles(sight.scene)
    new_stage(progress, "selection")
    overlap = sight  # the pieces the registration overlap is measured on
    if whole is not None:  # coarser pieces of the same faces (made after the visibility,
        # whose peak they would add to)
        t_split = time.perf_counter()
        overlap = whole.overlap_sight(candidates.positions) or sight
        del whole
        stats.seconds["overlap_split"] = time.perf_counter() - t_split
    # a budget of hours: the routes of the sets of stations it weighs are walked on one
    # graph, which the plan's survey walks too
    area_xy = walk_area(candidates.positions)
    clock = None if spec.max_field_time_h is None else FieldClock(
        sight.scene, spec, sight.limits, sight.caster, candidates.positions, area_xy,
        stats.seconds)
    choice = choose(sight, table, candidates.positions, fixed, stats, progress=progress,
                    threads=threads, fanout=fanout, overlap=overlap, clock=clock)
    chosen, station_overlap = choice.chosen, choice.station_overlap
    stations_xyz = candidates.positions[list(chosen.stations)]  # (S, 3)
    release_freed_memory()
    if sight.scene.n_faces >= BOUNDED_HEAP_FACES:
        bound_heap()  # from here on freed arrays leave the process at once, not at a trim
    tolerance = None
    if spec.tolerance_radius_m > 0:
        tolerance, station_overlap = plan_tolerance(
            sight, table, chosen, stations_xyz, station_overlap, stats, threads=threads,
            fanout=fanout, overlap=overlap)
    # what follows reads the stations' rows only: the table goes before the survey's peak
    # (the 9.7 M-piece office's 180 MB), unless the caller keeps it
    rows: CoverageTable | StationRows = table if keep_table \
        else table.station_rows(chosen.stations)
    del table
    # the threads' freed scratch (the overlap rows', the tolerance's: on the office 320 MB),
    # still in their arenas, before the survey makes the next peak
    release_freed_memory()
    plan_survey = survey(sight.scene, spec, stations_xyz, sight.limits, sight.occlusion,
                         sight.caster, stats.seconds, station_overlap=station_overlap,
                         threads=threads, fanout=fanout,
                         places=places_of(sight.scene, candidates, list(chosen.stations)),
                         walk_area_xy=area_xy, overlap=overlap,
                         network=None if clock is None else clock.hand_over())
    forget_bundles(sight.scene)
    release_freed_memory()  # the overlap rows' pair search, before the per-face results
    # the per-face results after the survey, which does not read them: on the 9.7 M-face
    # office they were 127 MB under the overlap rows' peak. With a scanner, each station's
    # least density margin over the faces it is credited with chooses its setting
    # (planner.scanners)
    faces = coverage_state(
        rows, chosen.stations,
        station_densities(sight, rows, chosen.stations, stations_xyz, stats, threads=threads),
        None if spec.scanner is None else sight.limits.min_density_pts_m2)
    margins = faces.pop("density_margin", None)
    if margins is not None:
        plan_survey = with_settings(plan_survey, spec, margins.tolist())
    new_stage(progress, "report")
    stats.cpu_seconds["plan"] = time.process_time() - cpu0
    outcome = choice.outcome
    return PlanResult(scene=sight.scene, spec=spec, candidates=candidates, table=rows,
                      limits=sight.limits, selections=outcome.selections, chosen=chosen,
                      optimal=outcome.optimal, faces=faces, stats=stats,
                      optimal_curve=outcome.curve, selection_report=outcome.report,
                      survey=plan_survey, tolerance=tolerance)
