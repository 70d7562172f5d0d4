"""Sums in compiled code with numpy's bits.

A search that runs compiled (the lower bound's volume algorithm, greedy) decides its steps
on sums; summed in numpy's order they are the bits numpy's ``sum`` gives, so moving a loop
from numpy into one compiled call changes no result.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

# numpy's summation order for a float64 vector (pairwise: blocks of at most this many
# summed by eight running sums, numpy/_core/src/umath/loops_utils.h.src)
PAIRWISE_BLOCK = 128


@numba.njit(nogil=True, cache=True)
def numpy_sum(values: NDArray[np.float64]) -> float:  # compiled
    """``values.sum()`` with numpy's bits: its pairwise summation, from 0.

    numpy halves a vector longer than :data:`PAIRWISE_BLOCK` (the first half a multiple of
    eight long) and adds the halves' sums; this walks the same tree with a stack (a
    recursive function loaded from numba's cache crashed the process)."""
    n = len(values)
    if n <= PAIRWISE_BLOCK:
        return 0.0 + _block_sum(values, 0, n)
    # pending halves: start, length, whether the left half is summed, and its sum
    starts = np.empty(128, np.int64)
    lengths = np.empty(128, np.int64)
    left_done = np.empty(128, np.bool_)
    lefts = np.empty(128)
    depth = 0
    start, length = 0, n
    while True:
        while length > PAIRWISE_BLOCK:  # descend to the leftmost block
            half = length // 2
            half -= half % 8
            starts[depth], lengths[depth], left_done[depth] = start, length, False
            depth += 1
            length = half
        total = _block_sum(values, start, length)
        while depth > 0:  # a finished half: add it to its left half, or sum the right one
            depth -= 1
            half = lengths[depth] // 2
            half -= half % 8
            if not left_done[depth]:
                left_done[depth], lefts[depth] = True, total
                depth += 1
                start, length = starts[depth - 1] + half, lengths[depth - 1] - half
                break
            total = lefts[depth] + total
        else:
            return 0.0 + total


@numba.njit(nogil=True, cache=True)
def _block_sum(values: NDArray[np.float64], start: int, n: int) -> float:  # compiled
    """numpy's sum of ``values[start:start + n]``, ``n`` at most :data:`PAIRWISE_BLOCK`:
    one running sum under eight, else eight running sums added as a tree, then the rest."""
    if n < 8:
        total = 0.0
        for i in range(start, start + n):
            total += values[i]
        return total
    r0, r1, r2, r3 = values[start], values[start + 1], values[start + 2], values[start + 3]
    r4, r5, r6, r7 = values[start + 4], values[start + 5], values[start + 6], values[start + 7]
    i = 8
    whole = n - n % 8
    while i < whole:
        j = start + i
        r0 += values[j]
        r1 += values[j + 1]
        r2 += values[j + 2]
        r3 += values[j + 3]
        r4 += values[j + 4]
        r5 += values[j + 5]
        r6 += values[j + 6]
        r7 += values[j + 7]
        i += 8
    total = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        total += values[start + i]
        i += 1
    return float(total)
