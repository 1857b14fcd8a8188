"""Smooth rest-to-rest reference trajectories with analytic derivatives.

A motion from q_a to q_b of duration T uses the 9th-order timing law
s(u) = 126 u^5 - 420 u^6 + 540 u^7 - 315 u^8 + 70 u^9, u = (t - t0) / T,
whose derivatives up to order 4 vanish at both ends, so q_d is C^4 and the
inverse dynamics of the elastic arm (which needs q_d^(4), De Luca et al. Sec. V)
starts and ends at rest with continuous torque.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.polynomial import polynomial

TIMING_LAW = np.array([0, 0, 0, 0, 0, 126, -420, 540, -315, 70], dtype=float)
MAX_ORDER = 8


def _timing_coefficients() -> np.ndarray:
    """Row k: polynomial coefficients (ascending powers) of d^k s / du^k."""
    rows = [TIMING_LAW]
    for _ in range(MAX_ORDER):
        rows.append(np.append(polynomial.polyder(rows[-1]), 0.0))
    return np.array(rows)


_COEFFICIENTS = _timing_coefficients()
_POWERS = np.arange(len(TIMING_LAW))


def timing_coefficients(order: int) -> np.ndarray:
    """Rows 0..order of the timing law's derivative coefficients (ascending powers of u),
    the ``coefficients`` of `_rest_to_rest_kernel` (a view: not to be written)."""
    if order > MAX_ORDER:
        raise ValueError(f"order must be <= {MAX_ORDER}")
    return _COEFFICIENTS[: order + 1]


def timing_law(u: np.ndarray | float, order: int = 4) -> np.ndarray:
    """s(u) and its derivatives d^k s / du^k for k = 0..order, shape (order + 1, *u.shape)."""
    x = np.clip(np.asarray(u, dtype=float), 0.0, 1.0)
    if x.ndim == 0:
        return _COEFFICIENTS[: order + 1] @ (float(x) ** _POWERS)
    return np.tensordot(_COEFFICIENTS[: order + 1], np.power.outer(x, _POWERS), axes=([1], [-1]))


@njit(cache=True)
def _rest_to_rest_kernel(t, waypoints, move_time, dwell_time, coefficients, out):
    """Per arm: the reference and its derivatives (see `rest_to_rest`)."""
    N, n_points, n = waypoints.shape
    n_rows = out.shape[1]
    segment = move_time + dwell_time
    n_segments = n_points - 1
    powers = np.empty(coefficients.shape[1])
    for k in range(N):
        out[k, :, :] = 0.0
        if n_segments == 0:
            for j in range(n):  # element loops: a slice copy compiles numba's broadcasting
                out[k, 0, j] = waypoints[k, 0, j]
            continue
        index = min(int(max(t[k], 0.0) // segment), n_segments - 1)
        u = (t[k] - index * segment - dwell_time) / move_time
        if u <= 0.0 or u >= 1.0:  # at rest (derivatives above 4 of the law do not vanish there)
            rest = index if u <= 0.0 else index + 1
            for j in range(n):
                out[k, 0, j] = waypoints[k, rest, j]
            continue
        powers[0] = 1.0
        for p in range(1, powers.shape[0]):
            powers[p] = powers[p - 1] * u
        scale = 1.0
        for r in range(n_rows):
            s = 0.0
            for p in range(powers.shape[0]):
                s += coefficients[r, p] * powers[p]
            s *= scale
            scale /= move_time
            for j in range(n):
                out[k, r, j] = s * (waypoints[k, index + 1, j] - waypoints[k, index, j])
        for j in range(n):
            out[k, 0, j] += waypoints[k, index, j]


def rest_to_rest(
    t: np.ndarray, waypoints: np.ndarray, move_time: float, dwell_time: float, order: int = 4
) -> np.ndarray:
    """Reference derivatives of N piecewise rest-to-rest motions, (N, order + 1, n).

    Arm k moves through ``waypoints[k]`` (n_points, n): segment i goes from waypoint i
    to i + 1 in ``move_time`` seconds after a ``dwell_time`` pause; after the last
    waypoint the reference stays there. Rows: q_d, q_d', ..., q_d^(order) at ``t[k]``.
    """
    coefficients = timing_coefficients(order)
    t = np.ascontiguousarray(t, dtype=np.float64).reshape(-1)
    waypoints = np.ascontiguousarray(waypoints, dtype=np.float64)
    if waypoints.ndim != 3 or len(t) != len(waypoints):  # the kernel does not check bounds
        raise ValueError(
            f"one time per arm: {len(t)} times for waypoints of shape "
            f"{waypoints.shape} (N, n_points, n)"
        )
    out = np.empty((len(t), order + 1, waypoints.shape[2]))
    _rest_to_rest_kernel(t, waypoints, float(move_time), float(dwell_time), coefficients, out)
    return out


@dataclass(frozen=True)
class RestToRestPath:
    """One piecewise rest-to-rest motion through ``waypoints`` (see `rest_to_rest`)."""

    waypoints: np.ndarray  # (n_points, N)
    move_time: float
    dwell_time: float

    @property
    def segment_time(self) -> float:
        return self.move_time + self.dwell_time

    @property
    def duration(self) -> float:
        return (len(self.waypoints) - 1) * self.segment_time

    def evaluate(self, t: float, order: int = 4) -> np.ndarray:
        """Reference derivatives (order + 1, N): rows q_d, q_d', ..., q_d^(order)."""
        return rest_to_rest(
            np.array([t]), np.asarray(self.waypoints)[None], self.move_time, self.dwell_time, order
        )[0]
