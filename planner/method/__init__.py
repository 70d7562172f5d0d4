"""The paper's method, stage by stage: ``candidates`` (grid, floors, clearance; ``rooms`` for
IFC spaces, ``winding`` for inside tests; ``walkgraph``, where a person can walk, which the
survey's route uses too) → ``pairs`` (analytic limits, ``density``) →
``visibility`` (Embree in ``_embree``, the reference in ``_bruteforce``; ``sampled`` for the
sampled coverage model) → ``coverage`` (the sparse table) → ``selection`` (greedy, weighted
greedy) and ``optimal`` (local search and HiGHS in ``highs_worker``) → ``curve``."""
