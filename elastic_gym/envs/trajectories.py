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


def timing_law(u: np.ndarray | float, order: int = 4) -> np.ndarray:
    """s(u) and its derivatives d^k s / du^k for k = 0..order, shape (order + 1, *u.shape)."""
    u = np.clip(np.asarray(u, dtype=float), 0.0, 1.0)
    if u.ndim == 0:
        return _COEFFICIENTS[: order + 1] @ (float(u) ** _POWERS)
    return np.tensordot(_COEFFICIENTS[: order + 1], np.power.outer(u, _POWERS), axes=([1], [-1]))


@dataclass(frozen=True)
class RestToRestPath:
    """Piecewise rest-to-rest motion through ``waypoints``.

    Segment i moves from waypoint i to i + 1 in ``move_time`` seconds after a
    ``dwell_time`` pause; after the last waypoint the reference stays there.
    """

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
        if order > MAX_ORDER:
            raise ValueError(f"order must be <= {MAX_ORDER}")
        n_segments = len(self.waypoints) - 1
        if n_segments == 0:
            out = np.zeros((order + 1, self.waypoints.shape[1]))
            out[0] = self.waypoints[0]
            return out
        index = min(int(max(t, 0.0) // self.segment_time), n_segments - 1)
        start = self.waypoints[index]
        u = (t - index * self.segment_time - self.dwell_time) / self.move_time
        if u <= 0.0 or u >= 1.0:  # at rest (derivatives above 4 of the law do not vanish there)
            out = np.zeros((order + 1, self.waypoints.shape[1]))
            out[0] = start if u <= 0.0 else self.waypoints[index + 1]
            return out
        s = (_COEFFICIENTS[: order + 1] @ (u**_POWERS)) * self.move_time ** -_POWERS[: order + 1]
        out = s[:, None] * (self.waypoints[index + 1] - start)
        out[0] += start
        return out
