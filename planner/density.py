"""Local point density (LPD) of a terrestrial laser scanner on a face, after the paper's
equations 2-4.

With SPS the angular step (rad), d the distance (m) and alpha the incidence angle between
the ray and the face plane::

    LPS90 = SPS * d            point spacing on a face seen head-on
    LPSa  = LPS90 / sin(alpha) point spacing along the slope
    LPD   = 1 / (LPS90 * LPSa) = sin(alpha) / (SPS * d)**2     points per m^2

A face 5 m away head-on at SPS 0.001 gets 1 / 0.005**2 = 40 000 pts/m^2.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray


def local_point_density(
    sin_incidence: NDArray[np.float64], distance_m: NDArray[np.float64], angular_step_rad: float
) -> NDArray[np.float64]:
    """LPD in pts/m^2 for (P,) incidence sines and (P,) distances in metres."""
    spacing_m = angular_step_rad * distance_m
    return sin_incidence / (spacing_m * spacing_m)


def density_range_m(min_density_pts_m2: float, angular_step_rad: float) -> float:
    """The farthest distance at which a face seen head-on still meets the density.

    ``inf`` when no density is required. With the defaults, 1 / (0.001 * sqrt(45000)) = 4.71 m.
    """
    if min_density_pts_m2 <= 0:
        return math.inf
    return 1.0 / (angular_step_rad * math.sqrt(min_density_pts_m2))
