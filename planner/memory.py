"""Keeping a plan's peak memory down: arrays grown in place, freed memory given back.

:class:`GrowingArray` builds an array of unknown final length without a second copy at
the end. :func:`release_freed_memory` runs between the stages of a plan: glibc keeps
freed blocks below its (growing, up to 32 MB) mmap threshold in the heap for reuse, so
the many mid-sized arrays a stage frees (a block of pairs, a station's overlap row) would
stay in the worker's RSS under the next stage's peak. ``malloc_trim`` hands back every
whole free page, and :func:`released_every` calls it within a stage, every so many
results its threads hand over. :func:`bound_heap` keeps such arrays out of the heap in the
first place. Elsewhere (musl, macOS) both do nothing.
"""

from __future__ import annotations

import ctypes
import functools
from collections.abc import Callable, Iterable, Iterator
from typing import Any, TypeVar

import numpy as np
from numpy.typing import NDArray

_Item = TypeVar("_Item")


@functools.cache
def _malloc_trim() -> Callable[[int], int] | None:
    """glibc's ``malloc_trim``, or None on another C library (musl, macOS)."""
    try:
        trim: Callable[[int], int] = ctypes.CDLL("libc.so.6").malloc_trim
    except (OSError, AttributeError):
        return None
    return trim


# glibc's mallopt parameter number of M_MMAP_THRESHOLD (malloc.h)
_M_MMAP_THRESHOLD = -3
# allocations from this size on get pages of their own, unmapped when freed
MMAP_THRESHOLD_BYTES = 256 * 1024


@functools.cache
def bound_heap() -> bool:
    """Serve every allocation of :data:`MMAP_THRESHOLD_BYTES` or more (numpy arrays of
    some 30,000 values and up) with pages of its own, returned to the system when freed.

    glibc raises its mmap threshold each time such a block is freed, up to 32 MB, and then
    serves the blocks of that size from the heap, where a freed block stays resident
    until the heap's top is free. A plan's stages free thousands of such blocks (blocks of
    pairs, overlap rows, scratch of the threads), so on a 9.7 M-face office the heap held
    some 400 MB that no array used when the survey's peak came. A fixed threshold keeps
    the peak to what is in use; the cost is a fresh zeroed page at first touch.
    Process-wide, set once; True when set (glibc only).
    """
    try:
        mallopt = ctypes.CDLL("libc.so.6").mallopt
    except (OSError, AttributeError):
        return False
    return bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES))


def release_freed_memory() -> None:
    """Hand the heap's free pages back to the system (glibc ``malloc_trim``)."""
    trim = _malloc_trim()
    if trim is not None:
        trim(0)


def released_every(items: Iterable[_Item], every: int) -> Iterator[_Item]:
    """``items`` as they come, the heap's free pages handed back
    (:func:`release_freed_memory`) after every ``every`` items, and once more at the end
    when more than ``every`` came. For results made on worker threads: each thread frees
    its scratch into a heap of its own, where it stays resident until a trim."""
    count = 0
    for count, item in enumerate(items, start=1):
        yield item
        del item  # let go before the trim: the reader has it, or has dropped it
        if count % every == 0:
            release_freed_memory()
    if count > every and count % every:
        release_freed_memory()


class GrowingArray:
    """A 1-D array appended to in place (``ndarray.resize``, a ``realloc``: large arrays
    are remapped, not copied), so building it needs no second copy."""

    def __init__(self, dtype: type[np.generic]) -> None:
        self.array = np.empty(1 << 16, dtype)
        self.n = 0

    def append(self, values: NDArray[Any]) -> None:
        self.extend(len(values))[:] = values

    def extend(self, count: int) -> NDArray[Any]:
        """Append ``count`` places and return them, not yet filled, for the caller to write
        (a view: fill it before the next ``append`` or ``extend``, which may move it)."""
        if self.n + count > len(self.array):
            self.array.resize(max(self.n + count, len(self.array) * 3 // 2), refcheck=False)
        self.n += count
        return self.array[self.n - count:self.n]

    def done(self) -> NDArray[Any]:
        """The array of what was appended (the object is used up)."""
        self.array.resize(self.n, refcheck=False)
        return self.array
