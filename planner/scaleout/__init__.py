"""One plan fanned out over a Dask cluster, with the same bytes as on one machine.

``plan(scene, spec, dask_scheduler="tcp://host:8786")`` (``scanplan plan
--dask-scheduler``, the service's ``SCANPLAN_DASK_SCHEDULER``) connects to a running
Dask scheduler (:class:`~planner.scaleout.cluster.DaskFanout`) and computes there:

- the coverage table's qualified pairs: one task per tile of contiguous candidates, each
  with the part of the model within its reach (:mod:`planner.visibility.tiles`), in parts
  of at most about 250,000 target faces where more lie within reach;
- the overlap rows (the registration density's, about 25 m of reach): every candidate's for
  the ``optimal`` method, the few the connected greedy asks for, the stations' for the
  survey.

The rest of the plan runs where ``plan`` was called: candidates, the split, the selection
on the merged table, the placement tolerance, the survey, the outputs. Left there too
(where a tile would not decide as the model does, or has not been made to): the sampled
coverage model, the robust table's cut and the brute-force backend.

Tasks carry their tile in the task itself, through the scheduler, so a task whose worker
dies runs again on another worker (Dask reschedules it; nothing was scattered that could be
lost). The file's mesh, the same for every tile, is one task's result that the tiles depend
on: each worker fetches it once and builds one BVH over it for the plan. Dask is imported
only here and only when a scheduler is given: the embedded default needs none (``pip
install scanplan[dask]`` adds it).
"""

from planner.scaleout.cluster import DaskFanout, fanout_over

__all__ = ["DaskFanout", "fanout_over"]
