"""Visibility: which candidate-face pairs qualify, gathered in the sparse coverage table.

Takes the scene, the (C, 3) candidate positions and the plan's limits; gives the
:class:`~planner.visibility.coverage.CoverageTable` (the faces each candidate qualifies
for) and, for the survey, the overlap rows at the registration density.

A pair qualifies when the face's centroid passes the analytic limits from the candidate
(range, field of view, incidence, local point density LPD = sin(alpha) / (SPS d)^2:
:mod:`planner.visibility.pairs`, found cell by cell in :mod:`planner.visibility.cells`) and
one occlusion ray reaches it (:mod:`planner.rays`), unless a whole bundle of pieces is
hidden behind one occluder (:mod:`planner.visibility.bundles`). The stage itself is
:mod:`planner.visibility.qualify`; long faces are split where a candidate can qualify part
of them (:mod:`planner.visibility.splitting`); the sampled coverage model is
:mod:`planner.visibility.sampled`; the robust table :mod:`planner.visibility.robust`; the
overlap rows :mod:`planner.visibility.overlap`.
"""
