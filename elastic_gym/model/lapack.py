"""The thin SVD of small matrices in compiled loops, with a workspace reused across calls.

``np.linalg.svd`` in numba asks LAPACK's ``dgesdd`` for its optimal workspace, allocates
it and frees it at every call: for the 6 x 2 maps of eq. (10) that is about 60 % of the
call. `thin_svd` calls the same routine (SciPy's ``cython_lapack.dgesdd``, which
numba calls too) with the same arguments and the workspace of `svd_workspace`,
queried once per shape: its results are bit for bit those of ``np.linalg.svd(T,
full_matrices=False)``.
"""

from __future__ import annotations

import llvmlite.binding as llvm
import numpy as np
from numba import njit, types
from numba.extending import get_cython_function_address

_SYMBOL = "elastic_gym_dgesdd"  # by name, so that numba's cache holds no address
llvm.add_symbol(_SYMBOL, get_cython_function_address("scipy.linalg.cython_lapack", "dgesdd"))
_dgesdd = types.ExternalFunction(_SYMBOL, types.void(*([types.voidptr] * 14)))
_JOBZ_S = ord("S")  # the thin SVD: min(m, n) columns of U and rows of V^T


@njit(cache=True)
def _call(T, space):
    a, s, u, vt, ints, work, iwork, jobz = space
    m, n = T.shape
    for c in range(n):  # column-major copy, as LAPACK reads it
        for r in range(m):
            a[c, r] = T[r, c]
    _dgesdd(
        jobz.ctypes,
        ints[0:].ctypes,  # m
        ints[1:].ctypes,  # n
        a.ctypes,
        ints[2:].ctypes,  # lda
        s.ctypes,
        u.ctypes,
        ints[3:].ctypes,  # ldu
        vt.ctypes,
        ints[4:].ctypes,  # ldvt
        work.ctypes,
        ints[5:].ctypes,  # lwork
        iwork.ctypes,
        ints[6:].ctypes,  # info
    )
    if ints[6] != 0:
        raise ValueError("Internal algorithm failed to converge.")  # numba's own message


@njit(cache=True)
def svd_workspace(m, n):
    """Buffers of the thin SVD of (m, n) matrices (LAPACK's optimal workspace)."""
    k = min(m, n)
    ints = np.array([m, n, m, m, k, -1, 0], dtype=np.int32)  # m n lda ldu ldvt lwork info
    jobz = np.array([_JOBZ_S], dtype=np.uint8)
    query = (np.zeros((n, m)), np.empty(k), np.empty((k, m)), np.empty((n, k)))
    iwork = np.empty(8 * k, dtype=np.int32)
    optimal = np.empty(1)
    _call(np.zeros((m, n)), (*query, ints, optimal, iwork, jobz))
    ints[5] = int(optimal[0])
    return (*query, ints, np.empty(int(optimal[0])), iwork, jobz)


@njit(cache=True)
def thin_svd(T, space):
    """U (m, k) as ``u.T``, s (k,) and V^T (k, n) as ``vt.T`` of the thin SVD of T (m, n):
    returns the views ``(u, s, vt)`` of ``space`` (overwritten by the next call)."""
    _call(T, space)
    return space[2], space[1], space[3]
