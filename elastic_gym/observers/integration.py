"""Fixed-step integration of observer dynamics over one sampling period."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np


def rk4(
    rhs: Callable[[float, np.ndarray], np.ndarray], x: np.ndarray, dt: float, substeps: int = 1
) -> np.ndarray:
    """Classical RK4 of x' = rhs(t, x) over [0, dt] in ``substeps`` equal steps."""
    h = dt / substeps
    for i in range(substeps):
        t = i * h
        k1 = rhs(t, x)
        k2 = rhs(t + 0.5 * h, x + 0.5 * h * k1)
        k3 = rhs(t + 0.5 * h, x + 0.5 * h * k2)
        k4 = rhs(t + h, x + h * k3)
        x = x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    return x
