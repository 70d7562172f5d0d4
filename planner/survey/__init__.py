"""What a crew needs to run a plan: registration overlap (``registration``), where a
person can walk (``walkgraph``), the visiting order (``route``), and the three put together
with the field time (``fieldwork``; the instrument, its settings and its scan durations are
:mod:`planner.scanners`)."""
