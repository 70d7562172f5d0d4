"""A mixed-integer linear program under construction, handed to HiGHS as a
:class:`~planner.selection.highs_worker.Program`.

The set-cover programs of :mod:`planner.selection.optimal` and the registration flow of
:mod:`planner.selection.connectivity` add their variables and rows to one builder.

Array letters: C candidates, V variables.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from planner.selection.highs_worker import Program


class ProgramBuilder:
    """A MILP under construction. Variables 0..C-1 are the candidates' ``x`` (1: chosen).

    ``add_variables`` returns the index of the first new variable; ``add_rows`` takes rows
    over the variables that exist so far (fewer columns are padded with zeros).
    """

    def __init__(self, n_candidates: int) -> None:
        self.n_candidates = n_candidates
        self._cost: list[NDArray[np.float64]] = []
        self._integrality: list[NDArray[np.float64]] = []
        self._lower: list[NDArray[np.float64]] = []
        self._upper: list[NDArray[np.float64]] = []
        self._rows: list[tuple[sp.csr_matrix, NDArray[np.float64], NDArray[np.float64]]] = []
        self.n_variables = 0
        # (V,) a feasible solution HiGHS starts from (dropped if hooks add variables later)
        self.start: NDArray[np.float64] | None = None
        self.add_variables(np.zeros(n_candidates), integer=True, lower=0.0, upper=1.0)

    def add_variables(self, cost: NDArray[np.float64], *, integer: bool,
                      lower: float | NDArray[np.float64],
                      upper: float | NDArray[np.float64]) -> int:
        n = len(cost)
        first = self.n_variables
        self._cost.append(np.asarray(cost, np.float64))
        self._integrality.append(np.full(n, 1.0 if integer else 0.0))
        self._lower.append(np.broadcast_to(np.asarray(lower, np.float64), (n,)).copy())
        self._upper.append(np.broadcast_to(np.asarray(upper, np.float64), (n,)).copy())
        self.n_variables += n
        return first

    def set_cost(self, first: int, cost: NDArray[np.float64]) -> None:
        """Replace the cost of variables ``first``, ``first + 1``, ..."""
        full = np.concatenate(self._cost)
        full[first:first + len(cost)] = cost
        self._cost = [full]

    def add_rows(self, rows: sp.spmatrix, lower: float | NDArray[np.float64],
                 upper: float | NDArray[np.float64]) -> None:
        rows = sp.csr_matrix(rows)
        n = rows.shape[0]
        self._rows.append((rows, np.broadcast_to(np.asarray(lower, np.float64), (n,)).copy(),
                           np.broadcast_to(np.asarray(upper, np.float64), (n,)).copy()))

    def add_partial_cover(self, cover: sp.spmatrix, area_m2: NDArray[np.float64],
                          need_m2: float, *, y_cost: NDArray[np.float64] | None = None,
                          x_start: NDArray[np.float64] | None = None) -> None:
        """The partial cover over the candidates' ``x``: a ``y_k`` in [0, 1] for each class
        of ``cover`` (C, K) 0/1, ``y_k <= sum_{c covers k} x_c`` and ``area_m2 . y >=
        need_m2`` (continuous ``y`` is exact with integer ``x``: a covered class may take
        y = 1). ``y_cost`` (K,): the cost of ``y`` (default 0); ``x_start`` (C,): a plan to
        start from (its ``y``: the classes it covers). The ``y`` come right after ``x``.
        """
        n_cand, n_class = cover.shape
        if self.n_variables != n_cand:
            raise ValueError("the partial cover's y must follow the candidates' x")
        self.add_variables(np.zeros(n_class) if y_cost is None else y_cost, integer=False,
                           lower=0.0, upper=1.0)
        # y_k - sum_c cover[c, k] x_c <= 0
        self.add_rows(_cover_rows(sp.csc_matrix(cover)), -np.inf, 0.0)
        self.add_rows(sp.hstack([sp.csr_matrix((1, n_cand)), sp.csr_matrix(area_m2[None, :])]),
                      need_m2, np.inf)
        if x_start is not None:
            self.start = np.concatenate([x_start, np.minimum(1.0, cover.T @ x_start)])

    def build(self) -> Program:
        width = self.n_variables
        blocks = [sp.csr_matrix((r.data, r.indices, r.indptr), shape=(r.shape[0], width))
                  for r, _, _ in self._rows]
        rows = sp.vstack(blocks, format="csr") if blocks else sp.csr_matrix((0, width))
        return Program(
            cost=np.concatenate(self._cost), integrality=np.concatenate(self._integrality),
            lower=np.concatenate(self._lower), upper=np.concatenate(self._upper), rows=rows,
            row_lower=np.concatenate([lo for _, lo, _ in self._rows]) if blocks else np.zeros(0),
            row_upper=np.concatenate([hi for _, _, hi in self._rows]) if blocks else np.zeros(0),
            start=self.start if self.start is not None and len(self.start) == width else None,
        )


def _cover_rows(cover: sp.csc_matrix) -> sp.csr_matrix:
    """(K, C + K) CSR: row k is ``-cover[:, k]`` followed by a 1 for ``y_k`` (the rows
    ``y_k - sum_c cover[c, k] x_c <= 0``), each row's indices ascending.

    Written straight from the columns of ``cover`` (C, K): a stack of ``-cover.T`` and an
    identity went through two coordinate copies of every entry (making the rows of Lantern
    Hollow's relaxed program, 1.2 M entries, peaked at 68 MiB; now at 40)."""
    if not cover.has_sorted_indices:
        cover = cover.sorted_indices()  # a copy: the caller's matrix stays as it is
    n_cand, n_class = cover.shape
    per_row = np.diff(cover.indptr)  # (K,)
    indptr = np.zeros(n_class + 1, np.int64)
    np.cumsum(per_row + 1, out=indptr[1:])
    identity_at = indptr[1:] - 1  # (K,) the last entry of each row: y_k's
    is_cover = np.ones(int(indptr[-1]), bool)
    is_cover[identity_at] = False
    indices = np.empty(int(indptr[-1]), np.int32)
    indices[is_cover] = cover.indices
    indices[identity_at] = n_cand + np.arange(n_class, dtype=np.int32)
    data = np.ones(int(indptr[-1]))
    data[is_cover] = -np.asarray(cover.data, np.float64)
    return sp.csr_matrix((data, indices, indptr), shape=(n_class, n_cand + n_class))
