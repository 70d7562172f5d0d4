"""What a crew needs to run a plan: registration overlap (``registration``), the visiting
order and its walk (``route``, on the walk graph of :mod:`planner.walkgraph`), and
the three put together with the field time (``fieldwork``; the instrument, its settings and
its scan durations are :mod:`planner.scanners`)."""
