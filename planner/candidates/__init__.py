"""Candidates: the scanner positions the plan chooses its stations from.

Takes the scene, the plan's parameters and a first-hit ray caster (floors, head room);
gives a :class:`~planner.candidates.grid.CandidateSet` (the (C, 3) positions, their storeys
and rooms, and why grid points were dropped) and the candidate index of each station
already scanned (``fixed_stations``).

Where they come from, in order: the ``candidates`` parameter, given in model coordinates;
the rooms of an IFC model (:mod:`planner.candidates.rooms`); otherwise a grid on every
floor a person can stand on (:mod:`planner.candidates.grid`, inside tests in
:mod:`planner.candidates.winding`), at each of the scanner heights
(:mod:`planner.candidates.placement`). Stations already scanned are matched to a candidate
or appended (:mod:`planner.candidates.fixed`). The stage itself is
:mod:`planner.candidates.generate`; what its steps derive from the scene alone (winding
cells, the building's samples) is made once per stage (:mod:`planner.candidates.scratch`).
"""
