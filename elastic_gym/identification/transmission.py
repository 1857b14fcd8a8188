"""The joint deflection from the motor side of the elastic-joint model.

De Luca et al. (2007), eq. (1), motor side: B theta'' + tau_J = tau, with the joint torque
tau_J = K (theta - q) + D (theta' - q'). With the deflection delta = theta - q this is, per
joint j and in the frequency domain,

    (K_j + i omega D_j) delta_j = tau_j - B_j theta_j'',

so delta is a known linear function of the logged torque and motor positions once
(K, D, B) are given: the link position q = theta - delta, its velocity and acceleration
follow without simulating the link side. The complete model (2) adds S^T q'' to the motor
side; S is strictly upper triangular, so joint j's equation holds q''_i of joints i < j
only and the deflections are solved in joint order, q''_i = theta''_i - delta''_i.
"""

from __future__ import annotations

import numpy as np


def deflection_spectrum(
    jw: np.ndarray,
    torque: np.ndarray,
    motor_acceleration: np.ndarray,
    K: np.ndarray,
    D: np.ndarray,
    B: np.ndarray,
    S: np.ndarray | None = None,
) -> np.ndarray:
    """Spectrum (bins, n) of the deflection delta = theta - q.

    Args:
        jw: i omega of the bins (bins,).
        torque: spectrum of the motor torque tau (bins, n).
        motor_acceleration: spectrum of theta'' (bins, n).
        K, D, B: stiffness, spring damping, motor inertia (n,).
        S: the constant motor/link inertial coupling of model (2), strictly upper
            triangular (n, n); None or zeros: model (1).
    """
    stiffness = K[None, :] + jw[:, None] * D[None, :]
    drive = torque - B[None, :] * motor_acceleration
    if S is None or not np.any(S):
        return drive / stiffness
    n = len(K)
    delta = np.zeros_like(drive)
    jw2 = jw**2
    for j in range(n):
        u = drive[:, j]
        for i in range(j):
            if S[i, j] != 0.0:
                u = u - S[i, j] * (motor_acceleration[:, i] - jw2 * delta[:, i])
        delta[:, j] = u / stiffness[:, j]
    return delta


def coupling_scaled(S_nominal: np.ndarray, B: np.ndarray, B_nominal: np.ndarray) -> np.ndarray:
    """S with each column j scaled by B_j / B_j(nominal): the rotor of motor j carries both
    its reflected inertia B_j = r_j^2 I_Rj and its coupling terms r_j I_Rj (De Luca et al.
    2007, Sec. V: S_23 = r_3 I_R3zz), so a fitted B_j scales them together (the gear
    ratios are known)."""
    return S_nominal * (B / B_nominal)[None, :]
