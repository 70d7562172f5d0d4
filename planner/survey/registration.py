"""The registration network of a plan's stations: which two stations overlap enough, and
with surfaces that fix a rigid registration in all three directions, to be registered
cloud to cloud (the test: :mod:`planner.selection.connected`).

Takes the stations' overlap rows (:mod:`planner.visibility.overlap`); gives the
:class:`Registration`: its edges and connected components.

Array letters: F faces, S stations.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numba
import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.sparse.csgraph import connected_components

from planner.scene import Scene
from planner.selection.connected import MIN_CONSTRAINT, SCATTER_TERMS, constraint_of


@dataclass(frozen=True)
class Edge:
    a: int  # station ids (1-based, selection order)
    b: int
    overlap_m2: float
    constraint: float
    ok: bool


@dataclass(frozen=True)
class Registration:
    """The overlap graph of a plan's stations."""

    min_overlap_m2: float | None
    overlap_density_pts_m2: float
    edges: tuple[Edge, ...]
    components: tuple[tuple[int, ...], ...]  # station ids per connected component

    @property
    def connected(self) -> bool:
        return len(self.components) <= 1

    def to_dict(self) -> dict[str, Any]:
        return {
            "min_overlap_m2": self.min_overlap_m2,
            "overlap_density_pts_m2": self.overlap_density_pts_m2,
            "connected": self.connected,
            "components": [list(c) for c in self.components],
            "edges": [{"a": e.a, "b": e.b, "overlap_m2": round(e.overlap_m2, 6),
                       "constraint": round(e.constraint, 6), "ok": e.ok} for e in self.edges],
        }


@numba.njit(nogil=True, cache=True)
def _shared_sums(indptr: NDArray[np.int32], faces: NDArray[np.int32], n_faces: int,
                 areas: NDArray[np.float64], normals: NDArray[np.float64],
                 source: NDArray[np.int32], terms: NDArray[np.int64]
                 ) -> NDArray[np.float64]:  # compiled; see test_survey
    """(N, N, 1 + T) float64: for every two of the N rows (``indptr``, ascending ``faces``:
    a CSR pattern over ``n_faces`` faces), the area of the faces both hold and the T
    area-weighted normal products n_i n_j area of the (T, 2) ``terms`` (``SCATTER_TERMS``,
    as :func:`scatter_weights`), each summed over those faces
    in ascending order. That is the order of the sparse product ``rows @ rows.T`` with the
    weights on the left (and of :func:`overlap_with`), so the sums are the same bits,
    without the transposed copy and (nnz,) weights a product needs: only the rows holding
    each face, 4 bytes an entry and a face. A face's normal is its file face's, row
    ``source[face]`` of ``normals``.
    """
    n = len(indptr) - 1
    # the rows holding each face, by a counting sort of the entries (rows stay ascending)
    first = np.zeros(n_faces + 1, np.int32)  # first[f] .. first[f + 1] - 1: f's holders
    for entry in range(len(faces)):
        first[faces[entry] + 1] += 1
    for face in range(n_faces):
        first[face + 1] += first[face]
    holder = np.empty(len(faces), np.int32)
    for row in range(n):
        for entry in range(indptr[row], indptr[row + 1]):
            face = faces[entry]
            holder[first[face]] = row
            first[face] += 1
    for face in range(n_faces, 0, -1):  # the filling moved every start to the next one
        first[face] = first[face - 1]
    first[0] = 0
    width = 1 + len(terms)
    sums = np.zeros((n, n, width))
    weight = np.empty(width)
    for row in range(n):
        for entry in range(indptr[row], indptr[row + 1]):
            face = faces[entry]
            area = areas[face]
            weight[0] = area
            normal = source[face]
            for k in range(len(terms)):
                weight[1 + k] = (normals[normal, terms[k, 0]] * normals[normal, terms[k, 1]]
                                 * area)
            for at in range(first[face], first[face + 1]):
                other = holder[at]
                for k in range(width):
                    sums[row, other, k] += weight[k]
    flat = sums.reshape(-1)
    for at in range(len(flat)):  # a zero sum is +0.0, as in a dense or sparse product
        if flat[at] == 0.0:
            flat[at] = 0.0
    return sums


def station_registration(scene: Scene, station_overlap: sp.csr_matrix,
                         min_overlap_m2: float | None,
                         overlap_density_pts_m2: float) -> Registration:
    """Edges between every two stations that share area, from their (S, F) overlap rows.

    ``ok`` needs the overlap (``min_overlap_m2``; any shared area when it is null) and the
    constraint test; components are taken over the ok edges. The rows may be cut to the
    faces two stations share (:func:`shared_faces_only`): the result is the same.
    """
    n = station_overlap.shape[0]
    shared = station_overlap.tocsr()  # rows the survey may have cut to shared faces already
    shared.sort_indices()
    # (S, S) the shared area, (S, S, 6) the shared faces' area-weighted normal scatter
    sums = _shared_sums(np.asarray(shared.indptr, np.int32),
                        np.asarray(shared.indices, np.int32), scene.n_faces, scene.areas,
                        scene.file_normals, scene.source_face, np.array(SCATTER_TERMS))
    overlap_m2, scatter6 = sums[:, :, 0], sums[:, :, 1:]
    edges: list[Edge] = []
    rows: list[int] = []
    cols: list[int] = []
    for a in range(n):
        constraint = constraint_of(scatter6[a])
        for b in range(a + 1, n):
            if overlap_m2[a, b] <= 0:
                continue
            ok = bool(overlap_m2[a, b] >= (min_overlap_m2 or 0.0)
                      and constraint[b] >= MIN_CONSTRAINT)
            edges.append(Edge(a + 1, b + 1, float(overlap_m2[a, b]), float(constraint[b]), ok))
            if ok:
                rows.append(a)
                cols.append(b)
    graph = sp.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n))
    count, labels = connected_components(graph, directed=False)
    components = tuple(tuple(int(i) + 1 for i in np.flatnonzero(labels == c))
                       for c in range(count))
    # components in order of their first station
    return Registration(min_overlap_m2, overlap_density_pts_m2, tuple(edges),
                        tuple(sorted(components)) if n else ())
