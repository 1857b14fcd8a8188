"""Tracking controllers of the rigid-arm observer papers, fed by a velocity estimate.

Both read q and the velocity estimate x_hat_2 from ``obs["state"]`` and q_d, q_d', q_d''
from ``info["reference"]``:

* :class:`CristofaroTrackingController`: Cristofaro & De Luca (IEEE L-CSS 2022), Example 3,
  exactly as printed (Lambda = 0.5 I, K_P = diag(40, 60), K_D = diag(60, 90)):
  tau = M(q) (q_d'' + Lambda (q_d' - x_hat_2)) + C(q, x_hat_2) (q_d' + Lambda (q_d - q))
  + g(q) + K_P (q_d - q) + K_D (q_d' - x_hat_2);
* :class:`FeedbackLinearizingController`: computed torque with friction compensation, the
  controller of Solsona & Puleston's simulation (Sec. 4): tau = M(q) a + C(q, x_hat_2) x_hat_2
  + g(q) + f_r(v_f), a = q_d'' + K_D (q_d' - x_hat_2) + K_P (q_d - q), with the model's
  friction f_r at v_f = x_hat_2 or q_d'.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from elastic_gym.controllers.base import Controller
from elastic_gym.controllers.invdyn import reference_derivatives, state_vector
from elastic_gym.model import RobotModel
from elastic_gym.validation import is_real

CRISTOFARO_LAMBDA = 0.5
CRISTOFARO_KP = (40.0, 60.0)
CRISTOFARO_KD = (60.0, 90.0)
FRICTION_VELOCITIES = ("estimate", "desired")


def _gain_matrix(value, n: int, name: str) -> np.ndarray:
    """A positive semi-definite diagonal gain from a scalar, N numbers or an N x N matrix."""
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 0:
        arr = np.full(n, float(arr))
    if arr.ndim == 1 and arr.shape == (n,):
        arr = np.diag(arr)
    if arr.shape != (n, n) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be a scalar, {n} numbers or a {n}x{n} matrix, got {value!r}")
    if np.any(np.linalg.eigvalsh(0.5 * (arr + arr.T)) < 0.0):
        raise ValueError(f"{name} must be positive semi-definite, got {value!r}")
    return arr


class _RigidTracking(Controller):
    """Shared reading of (q, x_hat_2) and of the reference."""

    applies_to = frozenset({"rigid"})

    def signals(self, obs: Mapping, info: Mapping) -> tuple[np.ndarray, ...]:
        x = state_vector(obs, 2 * self.n)
        ref = reference_derivatives(info, self.n)
        return x[: self.n], x[self.n :], ref[0], ref[1], ref[2]


class CristofaroTrackingController(_RigidTracking):
    """Example 3 of Cristofaro & De Luca (2022), see the module docstring.

    Args:
        model, dt: nominal rigid-arm model and control period.
        Lambda, K_P, K_D: gains (scalar, N numbers or N x N); the defaults are the
            paper's, for N = 2 (other arms need explicit K_P and K_D).
    """

    name = "cristofaro-tracking"

    def __init__(
        self,
        model: RobotModel,
        dt: float,
        Lambda=CRISTOFARO_LAMBDA,
        K_P=None,
        K_D=None,
    ) -> None:
        super().__init__(model, dt)
        n = self.n
        if (K_P is None or K_D is None) and n != len(CRISTOFARO_KP):
            raise ValueError(
                f"the paper's K_P, K_D are for 2 joints; give K_P and K_D for {n} joints"
            )
        self.Lambda = _gain_matrix(Lambda, n, "Lambda")
        self.K_P = _gain_matrix(CRISTOFARO_KP if K_P is None else K_P, n, "K_P")
        self.K_D = _gain_matrix(CRISTOFARO_KD if K_D is None else K_D, n, "K_D")

    def __call__(self, obs: Mapping, info: Mapping) -> np.ndarray:
        q, v, q_d, dq_d, ddq_d = self.signals(obs, info)
        model, L = self.model, self.Lambda
        e, de = q_d - q, dq_d - v
        return (
            model.mass_matrix(q) @ (ddq_d + L @ de)
            + model.coriolis_matrix(q, v) @ (dq_d + L @ e)
            + model.gravity(q)
            + self.K_P @ e
            + self.K_D @ de
        )


class FeedbackLinearizingController(_RigidTracking):
    """Computed torque with friction compensation (Solsona & Puleston, Sec. 4).

    Args:
        model, dt: nominal rigid-arm model (its friction is compensated) and period.
        omega, damping_ratio: error dynamics K_P = omega^2, K_D = 2 zeta omega
            (default 10 rad/s, zeta = 1).
        K_P, K_D: explicit gains (scalar, N numbers or N x N) instead.
        friction_velocity: ``"estimate"`` or ``"desired"`` (see module docstring).
    """

    name = "feedback-linearization"

    def __init__(
        self,
        model: RobotModel,
        dt: float,
        omega: float = 10.0,
        damping_ratio: float = 1.0,
        K_P=None,
        K_D=None,
        friction_velocity: str = "estimate",
    ) -> None:
        super().__init__(model, dt)
        n = self.n
        for key, value in (("omega", omega), ("damping_ratio", damping_ratio)):
            if not (is_real(value) and np.isfinite(value) and value > 0):
                raise ValueError(f"{key} must be a positive number, got {value!r}")
        if friction_velocity not in FRICTION_VELOCITIES:
            raise ValueError(
                f"friction_velocity must be one of {FRICTION_VELOCITIES}, got {friction_velocity!r}"
            )
        self.friction_velocity = friction_velocity
        self.K_P = _gain_matrix(omega**2 if K_P is None else K_P, n, "K_P")
        self.K_D = _gain_matrix(2.0 * damping_ratio * omega if K_D is None else K_D, n, "K_D")

    def __call__(self, obs: Mapping, info: Mapping) -> np.ndarray:
        q, v, q_d, dq_d, ddq_d = self.signals(obs, info)
        a = ddq_d + self.K_D @ (dq_d - v) + self.K_P @ (q_d - q)
        v_friction = v if self.friction_velocity == "estimate" else dq_d
        return self.model.rnea(q, v, a) + self.model.link_friction(v_friction)
