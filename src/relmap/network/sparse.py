"""Sparse symmetric normal matrices: a pattern fixed once, refactorized every iteration."""

from __future__ import annotations

import numpy as np

from relmap.typing import FloatArray, IntArray

__all__ = ["SymmetricFactor", "SymmetricPattern"]


class SymmetricPattern:
    """The sparsity pattern of a symmetric ``size × size`` matrix, in CSC, fixed once.

    Built from the (row, col) of every contribution (duplicates allowed, both triangles);
    :meth:`assemble` then sums contributions into the CSC data array with one ``bincount``.
    """

    def __init__(self, size: int, rows: IntArray, cols: IntArray) -> None:
        self.size = size
        keys = cols.astype(np.int64) * size + rows  # column-major order = CSC order
        unique, self.position = np.unique(keys, return_inverse=True)
        self.indices = (unique % size).astype(np.int32)
        col_of = unique // size
        self.indptr = np.searchsorted(col_of, np.arange(size + 1)).astype(np.int32)
        self.nnz = len(unique)
        diag_keys = np.arange(size, dtype=np.int64) * (size + 1)
        self.diagonal_position = np.searchsorted(unique, diag_keys)
        present = self.diagonal_position < len(unique)
        present[present] = unique[self.diagonal_position[present]] == diag_keys[present]
        if not present.all():
            self.diagonal_position = None  # some parameter appears in no contribution at all

    def assemble(self, values: FloatArray) -> FloatArray:
        """CSC data from the contributions' values (in the order the pattern was built)."""
        return np.bincount(self.position, weights=values, minlength=self.nnz)

    def diagonal(self, data: FloatArray) -> FloatArray:
        """The matrix diagonal (zeros where the pattern has no diagonal entry)."""
        if self.diagonal_position is None:
            out = np.zeros(self.size)
            keys = self.indices.astype(np.int64)
            cols = np.repeat(np.arange(self.size), np.diff(self.indptr))
            on = keys == cols
            out[cols[on]] = data[on]
            return out
        return data[self.diagonal_position]

    def with_diagonal(self, data: FloatArray, extra: FloatArray) -> FloatArray:
        """A copy of ``data`` with ``extra`` added to the diagonal."""
        out = data.copy()
        out[self.diagonal_position] += extra
        return out

    def matrix(self, data: FloatArray):  # type: ignore[no-untyped-def]
        """The matrix as ``scipy.sparse.csc_matrix``."""
        import scipy.sparse as sp

        return sp.csc_matrix((data, self.indices, self.indptr), shape=(self.size, self.size))


class SymmetricFactor:
    """Factorization of a symmetric positive-definite matrix with a fixed pattern."""

    def __init__(self, pattern: SymmetricPattern) -> None:
        self.pattern = pattern
        self._lu = None

    def factorize(self, data: FloatArray) -> None:
        """Factorize the matrix with the given CSC data."""
        from scipy.sparse.linalg import splu

        self._lu = splu(self.pattern.matrix(data), permc_spec="MMD_AT_PLUS_A")

    def solve(self, b: FloatArray) -> FloatArray:
        """``A⁻¹ b`` for a vector or a matrix of columns."""
        assert self._lu is not None, "factorize first"
        return self._lu.solve(b)
