"""Property: the coverage table's runs hold exactly the pairs they were made from, whether
made from pairs or from a sparse pattern (the face classes' table is made from one)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from planner.visibility.coverage import CoverageTable, QualifiedPairs

sets_st = st.integers(min_value=1, max_value=40).flatmap(lambda n_faces: st.tuples(
    st.just(n_faces),
    st.lists(st.sets(st.integers(min_value=0, max_value=n_faces - 1)), min_size=1,
             max_size=8)))


@settings(max_examples=60, deadline=None)
@given(instance=sets_st)
def test_runs_from_pairs_and_from_a_pattern_hold_the_same_faces(
        instance: tuple[int, list[set[int]]]) -> None:
    n_faces, sets = instance
    candidate = np.array([c for c, faces in enumerate(sets) for _ in faces], np.int32)
    face = np.array([f for faces in sets for f in sorted(faces)], np.int32)
    pairs = QualifiedPairs(candidate, face, np.ones(len(face), np.float32))
    area = np.linspace(1.0, 2.0, n_faces)
    table = CoverageTable.from_pairs(pairs, len(sets), area)
    again = CoverageTable.from_csr(table.pattern(np.bool_), area)
    for made in (table, again):
        assert made.n_pairs == len(face)
        for c, faces in enumerate(sets):
            assert made.faces_of(c).tolist() == sorted(faces)
    # the same runs: consecutive faces of a candidate in one run, nothing else merged
    for name in ("run_ptr", "run_start", "run_length", "pair_ptr"):
        assert np.array_equal(getattr(table, name), getattr(again, name)), name
    assert table.pattern(np.bool_).toarray().tolist() == [
        [f in faces for f in range(n_faces)] for faces in sets]
