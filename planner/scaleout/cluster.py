"""The Dask side: a client of the cluster, one task out per worker thread, results read
in order (:class:`DaskFanout`).

Each task is a function of :mod:`planner.visibility.tiles` applied to one tile; the tile
travels in the task (client -> scheduler -> worker), never scattered: scattered data is lost
with its worker, a task's own arguments are not. One task per worker thread is out at a
time, the next submitted when any finishes, so a worker holds the tile it runs and no
other, and neither this process nor the scheduler holds more than those tiles.

A tile holds at most about :data:`TILE_FACES` target faces: a group of candidates with more
within reach (the overlap rows' 25 m take in much of a building of many storeys) is sent
in parts, each with all the group's candidates and some of its targets, and the parts'
pairs and rows are merged here into the group's, the same as one tile's. So a task's
memory, and a worker's, follows that budget, not the building.

The occluders every tile shares (the file's mesh of a split model,
:class:`~planner.visibility.tiles.Occluders`) are the result of one task of their own,
whose arguments they are: each tile task depends on it, so a worker fetches them once
and keeps them (with the one BVH its tiles build over them) until the plan releases the
future; a worker that dies with them is no loss, the scheduler computes them again.

Array letters: C candidates, F faces.
"""

from __future__ import annotations

import contextlib
import itertools
import math
import uuid
import weakref
from collections import deque
from collections.abc import Callable, Generator, Iterable, Iterator
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np
from numpy.typing import NDArray

from planner.errors import ClusterError, PlannerError, SchedulerUnreachableError
from planner.memory import release_freed_memory
from planner.progress import ProgressCallback, notify
from planner.rays.embree import EmbreeOcclusion
from planner.visibility.coverage import QualifiedPairs
from planner.visibility.overlap import OverlapRows
from planner.visibility.pairs import search_reach_m
from planner.visibility.qualify import Sight
from planner.visibility.tiles import (
    Occluders,
    Tile,
    TileCutter,
    contiguous_tiles,
    overlap_tile,
    qualify_tile,
)

if TYPE_CHECKING:
    from distributed import Client, Future

_Item = TypeVar("_Item")
_END = object()
_Result = TypeVar("_Result")

# tasks out per worker thread: one, so a worker holds the tile it runs and no queued one
# (a queued overlap tile is as big as the running one); the next is submitted as soon as
# any task finishes, so a worker waits for its next tile only the round trip
TASKS_PER_THREAD = 1
# items submitted and not yet yielded per worker thread at most: the results that finish
# before an earlier item's are kept here until it comes, so this bounds them (a result, a
# tile's pairs or rows, is far smaller than its tile)
RESULTS_BUFFERED_PER_THREAD = 4
# a tile's candidates: at least this many (a task's BVH and bundles are made once for them)
# and at most that many (its part of the model, and so the worker's memory, grows with them)
MIN_TILE_CANDIDATES = 8
MAX_TILE_CANDIDATES = 128
# tiles per worker thread at least, so a slow tile does not leave the others idle
TILES_PER_THREAD = 4
# a task's target faces at most (about: a file face's pieces stay together): a tile with
# more is sent in parts, each with all its candidates and some of its targets
# (:meth:`~planner.visibility.tiles.TileCutter.cut_parts`). A task's memory follows its
# faces (some 250 bytes a face of tile and scratch on the worker), so this bounds it
# whatever the building: the overlap rows' reach (25 m) takes in much of a building of
# many storeys around every candidate
TILE_FACES = 250_000
# runs of a task that raised before the plan fails (a worker that dies is another matter:
# the scheduler gives its tasks to the others, up to distributed.scheduler.allowed-failures)
TASK_RETRIES = 1
CONNECT_TIMEOUT_S = 10.0
# the overlap rows' tasks: a group's candidates stand in a cube of this side, so its tile
# (every piece within reach of one of them) spans the reach on either side and this, 58 m
# at the default 25 m reach, not the three reaches candidates within one reach of the
# group's first would span: a worker's memory follows the reach, not the building. Small
# against the reach, yet a few grid steps of a coarse grid (many of the default 0.5 m), so
# a group still has several candidates to share the cutting and sending of its tile
GROUP_SPREAD_M = 8.0


class DaskFanout:
    """A plan's visibility and overlap rows on the Dask cluster at ``address``.

    Connects at once: a scheduler that cannot be reached raises
    :class:`~planner.errors.SchedulerUnreachableError` naming the address. ``tile_candidates``:
    candidates per tile (default: from the candidates and the cluster's threads, between
    :data:`MIN_TILE_CANDIDATES` and :data:`MAX_TILE_CANDIDATES`); ``tile_faces``: a task's
    target faces at most (:data:`TILE_FACES`), what bounds a worker's memory. Close it (or
    use it as a context manager) when the plan is done.
    """

    def __init__(self, address: str, *, tile_candidates: int | None = None,
                 tile_faces: int | None = None,
                 connect_timeout_s: float = CONNECT_TIMEOUT_S) -> None:
        try:
            from distributed import Client
        except ImportError as exc:  # pragma: no cover - depends on the installation
            raise ClusterError(
                "a Dask scheduler was given but Dask is not installed: install "
                "scanplan[dask] (dask[distributed]) where the plan runs") from exc
        self.address = address
        self.tile_candidates = tile_candidates
        self.tile_faces = max(1, TILE_FACES if tile_faces is None else tile_faces)
        try:
            self._client: Client = Client(  # type: ignore[no-untyped-call]
                address, timeout=connect_timeout_s, set_as_default=False)
        except (OSError, TimeoutError, ValueError, TypeError) as exc:
            raise SchedulerUnreachableError(address, exc) from exc
        self._token = uuid.uuid4().hex[:12]
        self._cutters: weakref.WeakKeyDictionary[OverlapRows, TileCutter] = (
            weakref.WeakKeyDictionary())
        # the occluders of each occlusion test, computed once on the cluster (see the
        # module docstring); held while the test lives or until close
        self._occluders: weakref.WeakKeyDictionary[EmbreeOcclusion, Future[Occluders]] = (
            weakref.WeakKeyDictionary())
        self._keys = itertools.count()
        self.tasks = 0  # tasks submitted
        self.tile_bytes = 0  # the arrays of the tiles (and shared occluders) submitted

    def __enter__(self) -> DaskFanout:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        with contextlib.suppress(Exception):
            for future in list(self._occluders.values()):
                future.release()  # type: ignore[no-untyped-call]
            self._occluders.clear()
            self._client.close()  # type: ignore[no-untyped-call]

    @property
    def client(self) -> Client:
        return self._client

    @property
    def threads(self) -> int:
        """The cluster's worker threads now (at least 1)."""
        try:
            nthreads = self._client.nthreads()  # type: ignore[no-untyped-call]
            return max(1, int(sum(nthreads.values())))
        except Exception as exc:
            raise self._failed(exc) from exc

    def _failed(self, exc: BaseException) -> ClusterError:
        return ClusterError(f"the Dask cluster at {self.address} failed the plan: "
                            f"{type(exc).__name__}: {exc}")

    def _tile_size(self, n_candidates: int) -> int:
        if self.tile_candidates is not None:
            return max(1, self.tile_candidates)
        size = math.ceil(n_candidates / (TILES_PER_THREAD * self.threads))
        return min(max(size, MIN_TILE_CANDIDATES), MAX_TILE_CANDIDATES)

    def map(self, work: Callable[..., _Result], items: Iterable[_Item], *,
            count: int | None = None, on_read: Callable[[float], None] | None = None,
            shared: Future[Any] | None = None) -> Generator[_Result, None, None]:
        """``work(item)`` of every item as tasks on the cluster (``work(item, shared)``
        with ``shared``, a future every task depends on), yielded in the order of
        ``items``; ``on_read`` gets the fraction read (of ``count``) after each and may raise
        to stop (the tasks still out are cancelled).

        At most :data:`TASKS_PER_THREAD` tasks per worker thread are out, and the next item
        is submitted as soon as any of them finishes, whichever: a worker holds the tile it
        runs and no queued one, and none idles behind a slower one. Results that finish
        before an earlier item's wait here (at most :data:`RESULTS_BUFFERED_PER_THREAD`
        per thread are submitted and not yet yielded, so that many results at most)."""
        from distributed import as_completed

        client = self._client
        threads = self.threads
        window = max(1, TASKS_PER_THREAD * threads)
        ahead = max(window, RESULTS_BUFFERED_PER_THREAD * threads)
        pending = iter(items)
        running: dict[Any, tuple[int, Future[_Result]]] = {}  # by key: (item index, future)
        finished: dict[int, _Result] = {}  # by item index, not yet yielded
        done = as_completed(loop=client.loop)  # type: ignore[no-untyped-call]
        name = getattr(work, "__name__", "task")
        extra = () if shared is None else (shared,)
        submitted = read = 0

        def submit_more() -> None:
            nonlocal submitted
            while len(running) < window and submitted - read < ahead:
                item = next(pending, _END)
                if item is _END:
                    return
                if isinstance(item, Tile):
                    self.tile_bytes += item.nbytes
                # the tile is the task's argument on purpose (see the module docstring)
                future: Future[_Result] = self._submit(name, work, item, *extra,
                                                       retries=TASK_RETRIES)
                del item
                # the cut's scratch, freed into the heap where it stays resident until a
                # trim, before the next tile is cut beside the ones out
                release_freed_memory()
                running[future.key] = (submitted, future)
                done.add(future)  # type: ignore[no-untyped-call]
                submitted += 1

        try:
            submit_more()
            while running or read in finished:
                while read not in finished:
                    ready = next(done)
                    index, future = running.pop(ready.key)
                    del ready
                    try:
                        finished[index] = future.result()
                    except PlannerError:
                        raise
                    except Exception as exc:
                        raise self._failed(exc) from exc
                    future.release()  # type: ignore[no-untyped-call]
                    del future
                    submit_more()
                result = finished.pop(read)
                read += 1
                submit_more()
                yield result
                del result
                if on_read is not None and count:
                    on_read(read / count)
        finally:
            with contextlib.suppress(Exception):
                done.clear()  # type: ignore[no-untyped-call]
            out = [future for _, future in running.values()]
            if out:
                with contextlib.suppress(Exception):
                    client.cancel(out)  # type: ignore[no-untyped-call]

    def _submit(self, name: str, work: Callable[..., _Result], *args: Any,
                retries: int = 0) -> Future[_Result]:
        """``work(*args)`` as a task of this plan, named ``name``; its arguments (a tile,
        the occluders) travel in the task, so Dask's warning about large graphs is raised
        to what a building's tile can weigh."""
        import dask

        self.tasks += 1
        with dask.config.set({"distributed.admin.large-graph-warning-threshold": "4GiB"}):
            future: Future[_Result] = self._client.submit(
                work, *args, pure=False, retries=retries,
                key=f"scanplan-{name}-{self._token}-{next(self._keys)}")
        return future

    def _shared_occluders(self, occlusion: EmbreeOcclusion, cutter: TileCutter
                          ) -> Future[Occluders] | None:
        """The future of the occluders the cutter's tiles share (None: the tiles hold
        theirs), one per occlusion test: a task whose arguments are the occluders, so the
        scheduler can compute it again if every worker holding it dies."""
        future = self._occluders.get(occlusion)
        if future is None:
            occluders = cutter.occluders()
            if occluders is None:
                return None
            self.tile_bytes += occluders.nbytes
            future = self._submit("occluders", Occluders, occluders.vertices,
                                  occluders.faces, occluders.part)
            self._occluders[occlusion] = future
        return future

    def coverage_blocks(self, sight: Sight, positions: NDArray[np.float64],
                        progress: ProgressCallback | None
                        ) -> Iterator[tuple[QualifiedPairs, int, int]] | None:
        """The qualified pairs, one task per tile of contiguous candidates (see
        :class:`~planner.visibility.qualify.CoverageFanout`); None for the sampled model
        and the brute-force backend, which stay local."""
        if sight.spec.coverage_model != "centroid" or not isinstance(sight.occlusion,
                                                                     EmbreeOcclusion):
            return None
        limits = sight.limits
        cutter = TileCutter(sight.scene, limits, limits.occludes, sight.occlusion,
                            search_reach_m(limits))
        positions = np.asarray(positions, np.float64)
        size = self._tile_size(len(positions))
        count = math.ceil(len(positions) / size)
        shared = self._shared_occluders(sight.occlusion, cutter)
        lasts: deque[bool] = deque()
        tiles = _tiles(cutter, positions, contiguous_tiles(len(positions), size),
                       detached=shared is not None, most_faces=self.tile_faces, lasts=lasts)
        return _merged_pairs(self.map(qualify_tile, tiles, shared=shared), lasts,
                             lambda groups: notify(progress, "visibility", groups / count))

    def overlap_rows(self, rows: OverlapRows, candidates: list[int]
                     ) -> Iterator[tuple[NDArray[np.int32], int]] | None:
        """The overlap rows of ``candidates`` on the cluster, one task per group of
        candidates near one another (see :class:`~planner.visibility.overlap.RowsFanout`)."""
        occlusion = rows.occlusion
        if not isinstance(occlusion, EmbreeOcclusion):
            return None
        cutter = self._cutters.get(rows)
        if cutter is None:
            cutter = TileCutter(rows.scene, rows.limits, rows.occludes, occlusion,
                                rows.reach_m)
            self._cutters[rows] = cutter
        positions = rows.positions
        groups = _near_groups(np.array(sorted(candidates), np.int64), positions,
                              self._tile_size(len(positions)))
        shared = self._shared_occluders(occlusion, cutter)
        lasts: deque[bool] = deque()
        tiles = _tiles(cutter, positions, groups, detached=shared is not None,
                       most_faces=self.tile_faces, lasts=lasts)
        found: dict[int, tuple[NDArray[np.int32], int]] = {}
        for ids, (faces, rays) in zip(groups, _merged_rows(
                self.map(overlap_tile, tiles, shared=shared), lasts), strict=True):
            # the rays are counted once per group, with its first row
            for k, (c, row) in enumerate(zip(ids.tolist(), faces, strict=True)):
                found[c] = (row, rays if k == 0 else 0)
        return iter([found[c] for c in candidates])


def _tiles(cutter: TileCutter, positions: NDArray[np.float64],
           groups: Iterable[NDArray[np.int64]], *, detached: bool, most_faces: int,
           lasts: deque[bool]) -> Iterator[Tile]:
    """The tiles of each group of candidates (``positions``: (C, 3) float64, the plan's),
    in parts of about ``most_faces`` targets at most (:meth:`TileCutter.cut_parts`), cut
    as needed, without the occluders they share when ``detached``; ``lasts`` gets, as
    each part is yielded, whether it is its group's last."""
    for ids in groups:
        for tile, last in cutter.cut_parts(ids, positions[ids], most_faces,
                                           detached=detached):
            lasts.append(last)
            # yielded as cut: this frame keeps no tile while it waits
            yield tile
            del tile


def _by_group(results: Generator[_Result, None, None], lasts: deque[bool]
              ) -> Generator[list[_Result], None, None]:
    """The ``results`` of the parts (in order) gathered by group of candidates, ``lasts``
    saying which part ends a group (:func:`_tiles`). A caller clears each group's list
    once it has read it (this frame holds it until the next), and closing this closes
    ``results`` (the tasks still out are cancelled)."""
    parts: list[_Result] = []
    try:
        for result in results:
            parts.append(result)
            del result
            if lasts.popleft():
                group, parts = parts, []
                yield group
                del group
    finally:
        results.close()


def _merged_pairs(results: Generator[tuple[QualifiedPairs, int, int], None, None],
                  lasts: deque[bool], on_group: Callable[[int], None]
                  ) -> Iterator[tuple[QualifiedPairs, int, int]]:
    """The qualified pairs of each group of candidates, as one tile of the group gives
    them (sorted by (candidate, face)), from the ``results`` of its parts
    (:func:`_by_group`), with the pairs tested and the rays cast summed; ``on_group`` gets
    the groups read so far after each (it may raise to stop: the tasks still out are
    cancelled)."""
    with contextlib.closing(_by_group(results, lasts)) as groups:
        for count, parts in enumerate(groups, start=1):
            tested = sum(part_tested for _, part_tested, _ in parts)
            rays = sum(part_rays for _, _, part_rays in parts)
            pairs = [part_pairs for part_pairs, _, _ in parts]
            parts.clear()
            merged = pairs.pop() if len(pairs) == 1 else _by_candidate_and_face(pairs)
            del pairs
            yield merged, tested, rays
            del merged
            on_group(count)


def _by_candidate_and_face(parts: list[QualifiedPairs]) -> QualifiedPairs:
    """The pairs of ``parts`` (of one group of candidates, their faces apart) in one,
    sorted by (candidate, face); ``parts`` is emptied."""
    merged = QualifiedPairs.concatenate(parts)
    key = merged.candidate.astype(np.int64) << 32
    key |= merged.face.astype(np.int64)
    order = np.argsort(key, kind="stable")
    del key
    return QualifiedPairs(merged.candidate[order], merged.face[order],
                          merged.lpd_pts_m2[order])


def _merged_rows(results: Generator[tuple[list[NDArray[np.int32]], int], None, None],
                 lasts: deque[bool]) -> Iterator[tuple[list[NDArray[np.int32]], int]]:
    """The overlap rows of each group of candidates, as one tile of the group gives them
    (each row's faces ascending), from the ``results`` of its parts (:func:`_by_group`),
    with the rays cast summed."""
    with contextlib.closing(_by_group(results, lasts)) as groups:
        for parts in groups:
            rays = sum(part_rays for _, part_rays in parts)
            merged = parts[0][0] if len(parts) == 1 else [
                np.sort(np.concatenate(row))
                for row in zip(*(rows for rows, _ in parts), strict=True)]
            parts.clear()
            yield merged, rays
            del merged


def _near_groups(candidates: NDArray[np.int64], positions: NDArray[np.float64], size: int,
                 spread_m: float = GROUP_SPREAD_M) -> list[NDArray[np.int64]]:
    """``candidates`` (ascending) in groups of at most ``size`` that stand in one cube of
    side ``spread_m`` (cubes from the origin): a group's tile then holds what lies within
    reach of a box of ``spread_m``, not of candidates up to twice the reach apart. Groups
    come in the order of their first candidates, each ascending.

    ``positions``: (C, 3) float64, the plan's candidates."""
    if len(candidates) == 0:
        return []
    cells = np.floor(positions[candidates] / spread_m).astype(np.int64)  # (n, 3)
    _, cell = np.unique(cells, axis=0, return_inverse=True)
    cell = cell.reshape(-1)
    # a stable sort by cell keeps each cell's candidates ascending
    order = np.argsort(cell, kind="stable")
    bounds = np.flatnonzero(np.diff(cell[order])) + 1
    groups = [candidates[part[i:i + size]] for part in np.split(order, bounds)
              for i in range(0, len(part), size)]
    groups.sort(key=lambda group: int(group[0]))
    return groups


def fanout_over(address: str | None, **options: Any) -> contextlib.AbstractContextManager[
        DaskFanout | None]:
    """A :class:`DaskFanout` over the scheduler at ``address`` for the ``with`` block, or
    None without an address (the plan runs here)."""
    if not address:
        return contextlib.nullcontext()
    return DaskFanout(address, **options)
