"""Eq. (13) with integral action: the classical remedy for static offsets under model error.

De Luca, Schroeder & Thuemmel (ICRA 2007), eq. (13), has no integral term: with a wrong
model behind INVDYN the loop settles at a static link offset. With the integral of the
link position error,

    z' = q_hat - q_d,        tau = K_P (x_d - xi) - K_I z + tau_d,

the offset goes whenever the estimate q_hat is unbiased at rest (the true state, or the
De Luca observer, Theorem 1); with a biased estimate the integrator drives q_hat, not q,
to q_d. Gains: LQR on the linearization augmented with z
(:func:`~elastic_gym.controllers.gain_design.lqr_integral_gain`, integral pole near
omega / 3). Anti-windup: z frozen while the last torque exceeded the limit, and the
integral torque K_I z kept within ``integral_limit`` times the torque limit.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from elastic_gym.controllers.gain_design import (
    closed_loop_poles,
    integral_linearization,
    link_position_rows,
    lqr_integral_gain,
)
from elastic_gym.controllers.invdyn import (
    DEFAULT_FD_STEP,
    TIME_TOLERANCE,
    info_time,
    state_vector,
)
from elastic_gym.controllers.state_feedback import FeedforwardStateFeedback
from elastic_gym.model import RobotModel
from elastic_gym.validation import is_real

DEFAULT_INTEGRAL_WEIGHT = 0.1
DEFAULT_INTEGRAL_LIMIT = 0.5  # fraction of the torque limit


class IntegralStateFeedback(FeedforwardStateFeedback):
    """Eq. (13) plus an integrator on the link position error, with anti-windup.

    Args:
        model: nominal model (INVDYN and the gain design use it).
        dt: control period (s).
        omega: slowest closed-loop pole (rad/s) of the underlying eq. (13) design.
        integral_weight: LQR weight of z relative to J^2 w^6 (see module docstring).
        integral_limit: bound of |K_I z| as a fraction of the model's torque limit.
        feedforward, design_configuration, fd_step: as for eq. (13).

    ``design`` holds the configuration, the method and the poles of the augmented
    nominal closed loop (dimension N + dim(x)); ``integral`` is the state z.
    """

    name = "integral-state-feedback"

    def __init__(
        self,
        model: RobotModel,
        dt: float,
        omega: float = 30.0,
        integral_weight: float = DEFAULT_INTEGRAL_WEIGHT,
        integral_limit: float = DEFAULT_INTEGRAL_LIMIT,
        feedforward: bool = True,
        design_configuration=None,
        fd_step: float = DEFAULT_FD_STEP,
    ) -> None:
        if not (is_real(integral_limit) and np.isfinite(integral_limit) and integral_limit > 0):
            raise ValueError(f"integral_limit must be a positive number, got {integral_limit!r}")
        self.integral_weight = integral_weight
        super().__init__(
            model,
            dt,
            omega=omega,
            feedforward=feedforward,
            design_configuration=design_configuration,
            fd_step=fd_step,
        )
        q0 = self.design["configuration"]
        self.integral_bound = float(integral_limit) * np.asarray(model.spec.torque_limit, float)
        self.torque_limit = np.asarray(model.spec.torque_limit, dtype=float)
        self._rows = link_position_rows(model)
        A, Bu = integral_linearization(model, q0)
        self.design["poles"] = closed_loop_poles(A, Bu, np.hstack([self.integral_gain, self.gain]))
        self.integral = np.zeros(self.n)
        self._time: float | None = None
        self._saturated = False

    def _design(self, A, Bu, q0, omega, gain, weights, poles) -> tuple[np.ndarray, str]:
        K_x, self.integral_gain = lqr_integral_gain(self.model, q0, omega, self.integral_weight)
        return K_x, f"LQR with integral action, slowest pole of eq. (13) {omega} rad/s"

    def reset(self, obs: Mapping, info: Mapping) -> None:
        super().reset(obs, info)
        self.integral = np.zeros(self.n)
        self._time = None
        self._saturated = False

    def _integrate(self, error: np.ndarray, elapsed: float) -> None:
        z = self.integral + elapsed * error
        torque = np.clip(self.integral_gain @ z, -self.integral_bound, self.integral_bound)
        self.integral = np.linalg.solve(self.integral_gain, torque)

    def __call__(self, obs: Mapping, info: Mapping) -> np.ndarray:
        t = info_time(info)
        x = state_vector(obs, self.dim)
        x_d, tau_d = self.desired(info)
        if self._time is None:
            self._time = t
        elif t > self._time + TIME_TOLERANCE:
            if not self._saturated:
                self._integrate(x[self._rows] - x_d[self._rows], t - self._time)
            self._time = t
        tau = self.gain @ (x_d - x) - self.integral_gain @ self.integral + tau_d
        self._saturated = bool(np.any(np.abs(tau) > self.torque_limit))
        return tau
