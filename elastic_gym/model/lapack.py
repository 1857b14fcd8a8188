"""The thin SVD of small matrices in compiled loops, with a workspace reused across calls.

``np.linalg.svd`` in numba asks LAPACK's ``dgesdd`` for its optimal workspace, allocates
it and frees it at every call: for the 6 x 2 maps of eq. (10) that is about 60 % of the
call. `thin_svd` calls the same routine (SciPy's ``cython_lapack.dgesdd``, which
numba calls too) with the same arguments and the workspace of `svd_workspace`,
queried once per shape: its results are bit for bit those of ``np.linalg.svd(T,
full_matrices=False)``. For two columns (the maps of a two-joint arm) it runs the
routines dgesdd runs on that path itself, without dgesdd's ten workspace queries and the
steps that are identities for two columns (`_two_columns`): the same numbers, half the time.
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


def _external(module: str, name: str, n_args: int) -> types.ExternalFunction:
    """A LAPACK / BLAS routine of SciPy's Cython API, by a symbol of this module's own."""
    symbol = f"elastic_gym_{name}"
    llvm.add_symbol(symbol, get_cython_function_address(f"scipy.linalg.cython_{module}", name))
    return types.ExternalFunction(symbol, types.void(*([types.voidptr] * n_args)))


_dgeqr2 = _external("lapack", "dgeqr2", 7)
_dorg2r = _external("lapack", "dorg2r", 8)
_dbdsdc = _external("lapack", "dbdsdc", 14)
_dgemm = _external("blas", "dgemm", 13)
_CHARS = np.array([ord(c) for c in "SUIN"], dtype=np.uint8)  # jobz, uplo, compq, trans
_SCALE_FREE = (1e-130, 1e130)  # max |T_ij| inside which dgesdd does not scale T
# (it scales outside [sqrt(tiny) / eps, eps / sqrt(tiny)] = [6.7e-139, 1.5e138])


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
    # m n lda ldu ldvt lwork info, then n again (ldwrkr) for `_two_columns`
    ints = np.array([m, n, m, m, k, -1, 0, n], dtype=np.int32)
    jobz = np.empty(4, dtype=np.uint8)  # "S", and the characters `_two_columns` passes
    for i in range(4):
        jobz[i] = _CHARS[i]
    query = (np.zeros((n, m)), np.empty(k), np.empty((k, m)), np.empty((n, k)))
    iwork = np.empty(8 * k, dtype=np.int32)
    optimal = np.empty(1)
    _call(np.zeros((m, n)), (*query, ints, optimal, iwork, jobz))
    ints[5] = int(optimal[0])
    return (*query, ints, np.empty(max(int(optimal[0]), 4 * n * n + 8 * n + 8)), iwork, jobz)


@njit(cache=True)
def _two_columns(space):
    """dgesdd's path of a thin SVD (jobz "S") of a copied m x 2 matrix (m >= 3, no
    scaling), the routines it runs there called directly: QR of A (dgeqr2, what dgeqrf
    runs for two columns), Q (dorg2r, what dorgqr runs), the SVD of R (dbdsdc), U = Q U_R
    (dgemm). The bidiagonalization of the 2 x 2 R (dgebrd) and the back-transforms
    (dormbr) are identities for two columns (every Householder reflection of a 2 x 2 upper
    triangular matrix has tau = 0), so s = diag(R), e = R_12 are what dgebrd hands on."""
    a, s, u, vt, ints, work, iwork, chars = space
    n = 2
    itau = n * n  # work: R (n x n, column-major), tau, e, then scratch
    ie = itau + n
    scratch = ie + 3 * n
    _dgeqr2(
        ints[0:].ctypes,
        ints[1:].ctypes,
        a.ctypes,
        ints[2:].ctypes,
        work[itau:].ctypes,
        work[scratch:].ctypes,
        ints[6:].ctypes,
    )
    for c in range(n):  # R, zero below the diagonal
        for r in range(n):
            work[r + c * n] = a[c, r] if r <= c else 0.0
    _dorg2r(
        ints[0:].ctypes,
        ints[1:].ctypes,
        ints[1:].ctypes,
        a.ctypes,
        ints[2:].ctypes,
        work[itau:].ctypes,
        work[scratch:].ctypes,
        ints[6:].ctypes,
    )
    s[0], s[1], work[ie] = work[0], work[3], work[2]
    _dbdsdc(
        chars[1:].ctypes,  # "U"
        chars[2:].ctypes,  # "I"
        ints[1:].ctypes,
        s.ctypes,
        work[ie:].ctypes,
        u.ctypes,
        ints[3:].ctypes,
        vt.ctypes,
        ints[4:].ctypes,
        work.ctypes,  # q, iq: not referenced for compq "I"
        iwork.ctypes,
        work[scratch:].ctypes,
        iwork.ctypes,
        ints[6:].ctypes,
    )
    if ints[6] != 0:
        raise ValueError("Internal algorithm failed to converge.")  # numba's own message
    for c in range(n):  # U_R, before U = Q U_R overwrites it
        for r in range(n):
            work[r + c * n] = u[c, r]
    work[itau], work[itau + 1] = 1.0, 0.0  # alpha, beta
    _dgemm(
        chars[3:].ctypes,  # "N"
        chars[3:].ctypes,
        ints[0:].ctypes,
        ints[1:].ctypes,
        ints[1:].ctypes,
        work[itau:].ctypes,
        a.ctypes,
        ints[2:].ctypes,
        work.ctypes,
        ints[7:].ctypes,
        work[itau + 1 :].ctypes,
        u.ctypes,
        ints[3:].ctypes,
    )


@njit(cache=True)
def lapack_svd(T, space):
    """`thin_svd` by one dgesdd call (every shape; what `thin_svd` is checked against)."""
    _call(T, space)
    return space[2], space[1], space[3]


@njit(cache=True)
def thin_svd(T, space):
    """U (m, k) as ``u.T``, s (k,) and V^T (k, n) as ``vt.T`` of the thin SVD of T (m, n):
    returns the views ``(u, s, vt)`` of ``space`` (overwritten by the next call). Two
    columns and m >= 3 (dgesdd's QR path): `_two_columns`, bit for bit dgesdd's numbers."""
    m, n = T.shape
    largest = 0.0  # max |T_ij|, NaN if one is: dgesdd scales T outside `_SCALE_FREE`
    for r in range(m):
        for c in range(n):
            v = abs(T[r, c])
            if not v <= largest:
                largest = v
    scale_free = largest == 0.0 or _SCALE_FREE[0] <= largest <= _SCALE_FREE[1]
    if n != 2 or m < 3 or not scale_free:
        _call(T, space)
    else:
        a = space[0]
        for c in range(n):  # column-major copy, as LAPACK reads it
            for r in range(m):
                a[c, r] = T[r, c]
        _two_columns(space)
    return space[2], space[1], space[3]
