"""The choice of stations: the fewest candidates that cover the goal.

Takes the coverage table (and, for a registrable network, the overlap rows); gives the
stations in selection order with the area each adds (:class:`~planner.selection.greedy.Selection`).

The paper's greedy and weighted greedy (:mod:`planner.selection.greedy`); ``optimal``, a
local search and HiGHS's MILP with a proven bound (:mod:`planner.selection.optimal`,
programs in :mod:`planner.selection.program`, solved in a child process by
:mod:`planner.selection.highs_worker`); the registration constraint
(:mod:`planner.selection.connected`, the flow of :mod:`planner.selection.connectivity`);
the stations needed per goal (:mod:`planner.selection.curve`). The stage itself is
:mod:`planner.selection.choose`.
"""
