"""Property: the coverage table's runs hold exactly the pairs they were made from, whether
made from pairs or from a sparse pattern (the face classes' table is made from one)."""

from __future__ import annotations

import itertools

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


@settings(max_examples=60, deadline=None)
@given(instance=sets_st, cuts=st.lists(st.integers(min_value=0, max_value=320), max_size=6))
def test_runs_made_block_by_block_hold_the_same_faces(
        instance: tuple[int, list[set[int]]], cuts: list[int]) -> None:
    """The visibility hands the pairs over in blocks, a candidate's pairs sometimes cut
    between two: the table holds the same faces, a run cut by a block boundary kept as two."""
    n_faces, sets = instance
    candidate = np.array([c for c, faces in enumerate(sets) for _ in faces], np.int32)
    face = np.array([f for faces in sets for f in sorted(faces)], np.int32)
    area = np.linspace(1.0, 2.0, n_faces)
    whole = CoverageTable.from_pairs(
        QualifiedPairs(candidate, face, np.ones(len(face), np.float32)), len(sets), area)
    bounds = sorted({0, len(face), *(c for c in cuts if c < len(face))})
    blocks = [QualifiedPairs(candidate[a:b], face[a:b], np.ones(b - a, np.float32))
              for a, b in itertools.pairwise(bounds)]
    table = CoverageTable.from_blocks(blocks, len(sets), area)
    assert np.array_equal(table.pair_ptr, whole.pair_ptr)
    for c, faces in enumerate(sets):
        assert table.faces_of(c).tolist() == sorted(faces)
    cut_inside = sum(1 for b in bounds[1:-1] if candidate[b] == candidate[b - 1]
                     and face[b] == face[b - 1] + 1)
    assert table.run_ptr[-1] == whole.run_ptr[-1] + cut_inside
