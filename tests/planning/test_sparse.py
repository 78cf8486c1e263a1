"""The CSC matrix handed to Clarabel, against scipy's (the oracle) and a hand-worked program."""

from __future__ import annotations

import clarabel
import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import given
from hypothesis import strategies as st

from catanc.planning.stage2.sparse import CscMatrix


@st.composite
def entries(draw: st.DrawFn) -> tuple[tuple[int, int], list[int], list[int], list[float]]:
    height = draw(st.integers(1, 7))
    width = draw(st.integers(1, 7))
    count = draw(st.integers(0, 25))  # more entries than places: duplicates
    rows = draw(st.lists(st.integers(0, height - 1), min_size=count, max_size=count))
    columns = draw(st.lists(st.integers(0, width - 1), min_size=count, max_size=count))
    values = draw(st.lists(st.floats(-1e3, 1e3, allow_nan=False), min_size=count, max_size=count))
    return (height, width), rows, columns, values


@given(entries())
def test_from_entries_matches_scipy(case: tuple[tuple[int, int], list[int], list[int], list[float]]) -> None:
    shape, rows, columns, values = case
    mine = CscMatrix.from_entries(shape, rows, columns, values)
    theirs = sp.csc_matrix((values, (rows, columns)), shape=shape)
    theirs.sum_duplicates()
    assert mine.shape == theirs.shape
    assert mine.nnz == theirs.nnz
    assert mine.indptr.tolist() == theirs.indptr.tolist()
    assert mine.indices.tolist() == theirs.indices.tolist()
    np.testing.assert_allclose(mine.data, theirs.data, rtol=1e-12, atol=1e-9)


def test_zeros_has_an_empty_column_pointer_per_column() -> None:
    zeros = CscMatrix.zeros((3, 2))
    assert zeros.indptr.tolist() == [0, 0, 0]
    assert zeros.nnz == 0


@pytest.mark.parametrize(
    ("rows", "columns", "values", "why"),
    [([0, 3], [0, 0], [1.0, 1.0], "outside"), ([0], [0, 1], [1.0], "length"), ([0], [-1], [1.0], "outside")],
)
def test_bad_entries_are_refused(rows: list[int], columns: list[int], values: list[float], why: str) -> None:
    with pytest.raises(ValueError, match=why):
        CscMatrix.from_entries((3, 2), rows, columns, values)


def test_clarabel_solves_a_hand_worked_program_from_it() -> None:
    """min x + y subject to x >= 1, y >= 2, x + y >= 4 (Clarabel: b - A z in the cone): 4, on the
    segment x + y = 4 with x >= 1, y >= 2; the x >= 1 row is written as two halves to be summed."""
    A = CscMatrix.from_entries((3, 2), [0, 0, 1, 2, 2], [0, 0, 1, 0, 1], [-0.5, -0.5, -1.0, -1.0, -1.0])
    settings = clarabel.DefaultSettings()
    settings.verbose = False
    solver = clarabel.DefaultSolver(
        CscMatrix.zeros((2, 2)),
        np.array([1.0, 1.0]),
        A,
        np.array([-1.0, -2.0, -4.0]),
        [clarabel.NonnegativeConeT(3)],
        settings,
    )
    solution = solver.solve()
    assert str(solution.status) == "Solved"
    x, y = solution.x
    assert x + y == pytest.approx(4.0, abs=1e-6)
    assert x >= 1.0 - 1e-6
    assert y >= 2.0 - 1e-6
