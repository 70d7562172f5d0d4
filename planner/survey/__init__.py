"""The survey: what a crew needs to run a plan.

Takes the chosen stations, the scene and the visibility (:mod:`planner.visibility`); gives
the registration network between the stations (``registration``, on their overlap rows),
the visiting order and its walk (``route``, on the walk graph of :mod:`planner.walkgraph`),
the three put together with the field time (``fieldwork``; the instrument, its settings and
its scan durations are :mod:`planner.scanners`) and what the plan keeps when each tripod
lands off its station (``tolerance``).
"""
