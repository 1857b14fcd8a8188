"""Row-stacked products whose rows do not depend on the batch: arm i's result is the same,
bit for bit, whatever the number of arms stacked with it.

BLAS (``numpy.matmul``) blocks a matrix product differently for different numbers of
rows, so row i of ``A @ B`` differs in its last bits between a stack of 1 and of 64
rows; a stiff closed loop amplifies such differences into different runs. The compiled
loop here sums each entry over the inner index in order, for every row alike.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def _rows_matmul(A, B, out):
    for i in range(A.shape[0]):
        for k in range(B.shape[1]):
            total = 0.0
            for j in range(A.shape[1]):
                total += A[i, j] * B[j, k]
            out[i, k] = total


def rows_matmul(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``A @ B`` for row-stacked arms A (N, m) and a shared matrix B (m, p): each row is
    computed alone (module docstring)."""
    A = np.ascontiguousarray(A, dtype=float)
    B = np.ascontiguousarray(B, dtype=float)
    out = np.empty((A.shape[0], B.shape[1]))
    _rows_matmul(A, B, out)
    return out
