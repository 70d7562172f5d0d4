"""What a ray caster answers: the occlusion test of the coverage pairs and first hits.

Array letters: P rays (one per candidate-face pair), R arbitrary rays.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Literal, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

Backend = Literal["embree", "bruteforce"]


# Rays end this factor past the target's distance: far enough for float32 rounding at the
# target's surface (5 um at 5 m), near enough that nothing behind it is traversed.
FAR_LIMIT_FACTOR = 1.0 + 1e-3


# exact_rays(indices (K,) int64) -> (K, 3) float64 origins and (K, 3) float64 unit
# directions of those rays, computed from the model's float64 geometry (the rays handed to
# ``visible`` are often float32 copies); used where float32 cannot decide a ray
ExactRays = Callable[[NDArray[np.int64]], tuple[NDArray[np.float64], NDArray[np.float64]]]


class Occlusion(Protocol):
    """Answers, for P rays, whether each reaches its target face unblocked.

    ``exact``: every ray is decided as the float64 brute-force reference decides it (else
    by one float32 cast, the same on every machine with the pinned kernels).
    """

    exact: bool

    def visible(
        self,
        origins: NDArray[np.floating[Any]],
        directions: NDArray[np.floating[Any]],
        distances_m: NDArray[np.floating[Any]],
        target_faces: NDArray[np.integer[Any]],
        exact_rays: ExactRays | None = None,
    ) -> NDArray[np.bool_]:
        """(P,) bool for (P, 3) origins, (P, 3) unit directions, (P,) distances, (P,) faces.

        ``exact_rays`` gives the float64 rays of any subset (default: the given rays).
        """
        ...


@runtime_checkable
class RayCaster(Protocol):
    """Closest hits of arbitrary rays (candidate generation: floors, obstacles overhead)."""

    def first_hit(
        self, origins: NDArray[np.floating[Any]], directions: NDArray[np.floating[Any]]
    ) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        """The face each (R, 3) ray hits first and its distance; -1 and inf for a miss."""
        ...
