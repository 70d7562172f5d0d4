"""Stations already scanned (``fixed_stations``, a re-scan) as candidates of the plan.

Takes the (C, 3) candidate positions and the fixed stations; gives the positions with the
stations that match no candidate appended, and each fixed station's candidate index.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from planner.errors import ParameterError

# a fixed station this close to a candidate (metres, per axis) is that candidate: plan.json
# rounds positions to 1e-6 m, and no tripod is set up more precisely than a millimetre
FIXED_MATCH_M = 1e-3


def fixed_candidates(
    positions: NDArray[np.float64], fixed_stations: tuple[tuple[float, float, float], ...]
) -> tuple[NDArray[np.float64], tuple[int, ...]]:
    """Candidate indices of the stations already scanned, appending those that are new.

    ``positions`` is (C, 3); returns the (C + new, 3) positions (the given ones first, in
    their order, then each fixed station that matches none, in the order given) and the
    candidate index of every fixed station. Deterministic: a station matches the
    lowest-index candidate within FIXED_MATCH_M on every axis.
    """
    extra: list[tuple[float, float, float]] = []
    indices: list[int] = []
    for i, point in enumerate(fixed_stations):
        near = np.flatnonzero(np.all(np.abs(positions - np.asarray(point)) <= FIXED_MATCH_M,
                                     axis=1))
        if len(near):
            index = int(near[0])
        else:
            index = len(positions) + len(extra)
            extra.append(point)
        if index in indices:
            raise ParameterError(
                f"fixed_stations[{i}]",
                f"{list(point)} is the station of fixed_stations[{indices.index(index)}] "
                f"again (within {FIXED_MATCH_M} m); list each station once")
        indices.append(index)
    if extra:
        positions = np.concatenate([positions, np.asarray(extra, np.float64)])
    return positions, tuple(indices)
