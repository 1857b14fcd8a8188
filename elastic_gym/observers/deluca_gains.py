"""Closed-form gains of the De Luca acceleration-based observer (De Luca et al. 2007).

The observation error of Theorems 1 and 2 obeys e' = A_obs e with
A_obs = [A; 0] - L C (proof of Theorem 1), which decouples into N fourth-order
systems, one per visco-elastic joint i (k_i = K_i / B_i, d_i = D_i / B_i):

    e_theta'  = -L1 e_theta + e_dtheta
    e_q'      = -L2 e_theta + e_dq
    e_dtheta' = -(k + L3) e_theta + k e_q - d e_dtheta + d e_dq
    e_dq'     = -L4 e_theta

with characteristic polynomial
lambda^4 + (L1 + d) lambda^3 + (L3 + d L1 + k) lambda^2 + (d L4 + k L2) lambda + k L4.
Matching it to p_i*(lambda) = lambda^4 + a3 lambda^3 + a2 lambda^2 + a1 lambda + a0
gives the expressions of Remark 3, evaluated here for all joints at once.
"""

from __future__ import annotations

import numpy as np

from elastic_gym.model.option_checks import stable_poles
from elastic_gym.validation import per_joint_values

POLES_PER_JOINT = 4
DEFAULT_BANDWIDTH = 250.0  # rad/s, the value found best on the KR15/2 (Sec. V-A)


def butterworth_poles(bandwidth: float | list[float] | np.ndarray, n_joints: int) -> np.ndarray:
    """(N, 4) poles of a 4th-order Butterworth pattern of radius ``bandwidth`` (rad/s).

    Poles bandwidth * exp(i (pi/2 + (2j + 1) pi / 8)), j = 0..3: two conjugate pairs with
    damping ratios cos(22.5 deg) = 0.92 and cos(67.5 deg) = 0.38 ("well damped
    eigenvalues with angular frequencies around 250 rad/s", Sec. V-A).
    ``bandwidth`` is a scalar or one value per joint.
    """
    radius = per_joint_values(bandwidth, n_joints, "bandwidth", 0.0, strict=True)
    j = np.arange(POLES_PER_JOINT)
    pattern = np.exp(1j * (np.pi / 2 + (2 * j + 1) * np.pi / (2 * POLES_PER_JOINT)))
    return radius[:, None] * pattern[None, :]


def validate_poles(poles, n_joints: int) -> np.ndarray:
    """(N, 4) complex poles from 4 common poles or one row of 4 per joint.

    Every pole must have a negative real part, and complex poles must come in
    conjugate pairs within each joint (so that the gains are real).
    """
    arr = stable_poles(poles, (POLES_PER_JOINT,), (n_joints, POLES_PER_JOINT))
    arr = np.broadcast_to(arr, (n_joints, POLES_PER_JOINT))
    coeffs = _polynomial(arr)
    degree = np.arange(1, POLES_PER_JOINT + 1)
    tolerance = 1e-9 * np.abs(arr).max(axis=1, keepdims=True) ** degree
    if np.any(np.abs(coeffs.imag) > tolerance):
        raise ValueError("complex poles must come in conjugate pairs (per joint)")
    return np.array(arr)


def _polynomial(poles: np.ndarray) -> np.ndarray:
    """(N, 4) complex coefficients of prod_j (lambda - lambda_ji), leading 1 dropped."""
    coeffs = np.zeros((poles.shape[0], POLES_PER_JOINT + 1), dtype=complex)
    coeffs[:, 0] = 1.0
    for j in range(POLES_PER_JOINT):  # multiply by (lambda - p_j), all joints at once
        coeffs[:, 1:] = coeffs[:, 1:] - poles[:, j : j + 1] * coeffs[:, :-1]
    return coeffs[:, 1:]


def characteristic_coefficients(poles: np.ndarray) -> np.ndarray:
    """(N, 4) real coefficients (a3, a2, a1, a0) of p_i*(lambda) (Remark 3), per joint row."""
    return _polynomial(poles).real.copy()


def deluca_gains(poles: np.ndarray, K: np.ndarray, B: np.ndarray, D: np.ndarray) -> np.ndarray:
    """(4, N) gains (L1, L2, L3, L4) of Remark 3 for the (N, 4) desired poles."""
    a3, a2, a1, a0 = characteristic_coefficients(poles).T
    L1 = a3 - D / B
    L2 = B / K * a1 - B * D / K**2 * a0
    L3 = a2 - D / B * a3 + (D**2 - K * B) / B**2
    L4 = B / K * a0
    return np.stack([L1, L2, L3, L4])


def error_matrix(gains: np.ndarray, K: np.ndarray, B: np.ndarray, D: np.ndarray) -> np.ndarray:
    """A_obs = [A; 0] - L C (4N x 4N), state order (theta, q, theta', q') of eq. (3)."""
    n = K.size
    L1, L2, L3, L4 = (np.diag(g) for g in gains)
    k, d = np.diag(K / B), np.diag(D / B)
    eye, zero = np.eye(n), np.zeros((n, n))
    return np.block(
        [
            [-L1, zero, eye, zero],
            [-L2, zero, zero, eye],
            [-k - L3, k, -d, d],
            [-L4, zero, zero, zero],
        ]
    )
