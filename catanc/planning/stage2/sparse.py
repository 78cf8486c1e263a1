"""A compressed sparse column matrix, just what Clarabel's Python binding reads.

Clarabel takes any object with ``shape``, ``indptr``, ``indices``, ``data`` and ``nnz`` (its
binding reads those attributes, and ``has_canonical_format``: rows sorted within each column,
no duplicates).  Building one here keeps scipy out of the re-optimiser process: importing
``scipy.sparse`` (scipy 1.17) costs ~0.15 s of CPU, most of it scipy's array-API layer walking
numpy's lazily imported submodules, in every ``catanc run`` for a ~20-row matrix.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt


@dataclass(frozen=True, eq=False)
class CscMatrix:
    shape: tuple[int, int]
    indptr: npt.NDArray[np.int64]  # column j's entries are data[indptr[j]:indptr[j + 1]]
    indices: npt.NDArray[np.int64]  # their rows, increasing within a column
    data: npt.NDArray[np.float64]
    has_canonical_format: bool = True  # sorted rows, no duplicates (Clarabel checks it)

    @property
    def nnz(self) -> int:
        return len(self.data)

    @classmethod
    def from_entries(
        cls, shape: tuple[int, int], rows: Sequence[int], columns: Sequence[int], values: Sequence[float]
    ) -> CscMatrix:
        """The matrix with ``values`` at ``(rows, columns)``; entries at one place are summed."""
        height, width = shape
        row = np.asarray(rows, dtype=np.int64)
        column = np.asarray(columns, dtype=np.int64)
        value = np.asarray(values, dtype=np.float64)
        if not len(row) == len(column) == len(value):
            raise ValueError("rows, columns and values differ in length")
        if len(row) and (row.min() < 0 or row.max() >= height or column.min() < 0 or column.max() >= width):
            raise ValueError(f"an entry lies outside the {height}x{width} matrix")
        order = np.lexsort((row, column))  # by column, then row
        place = column[order] * height + row[order]
        unique, first = np.unique(place, return_index=True)
        summed = np.add.reduceat(value[order], first) if len(first) else value[:0]
        counts = np.bincount(unique // height, minlength=width)
        indptr = np.concatenate(([0], np.cumsum(counts))).astype(np.int64)
        return cls(shape, indptr, (unique % height).astype(np.int64), summed.astype(np.float64))

    @classmethod
    def zeros(cls, shape: tuple[int, int]) -> CscMatrix:
        return cls.from_entries(shape, (), (), ())
