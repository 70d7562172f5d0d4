"""What a crew needs to run a plan: scanner presets (``scanners``), registration overlap
(``registration``), where a person can walk (``walkgraph``), the visiting order
(``route``), and the three put together with the field time (``fieldwork``)."""
