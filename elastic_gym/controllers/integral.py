"""Eq. (13) with integral action: the classical remedy for static offsets under model error.

De Luca, Schroeder & Thuemmel (ICRA 2007), eq. (13), has no integral term: with a wrong
model behind INVDYN the loop settles at a static link offset. With the integral of the
link position error,

    z' = q_hat - q_d,        tau = K_P (x_d - xi) - K_I z + tau_d,

the offset goes whenever the estimate q_hat is unbiased at rest (the true state, or the
De Luca observer, Theorem 1); with a biased estimate the integrator drives q_hat, not q,
to q_d. Gains: LQR on the linearization augmented with z
([`lqr_integral_gain`][elastic_gym.controllers.gain_design.lqr_integral_gain], integral pole near
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
from elastic_gym.controllers.invdyn import DEFAULT_FD_STEP, TIME_TOLERANCE
from elastic_gym.controllers.state_feedback import (
    FeedforwardOptions,
    FeedforwardStateFeedback,
    VectorStateFeedback,
)
from elastic_gym.controllers.vector import arm_rows, twin_of
from elastic_gym.model import RobotModel
from elastic_gym.validation import PositiveFinite, validated_options

DEFAULT_INTEGRAL_WEIGHT = 0.1
DEFAULT_INTEGRAL_LIMIT = 0.5  # fraction of the torque limit


class IntegralOptions(FeedforwardOptions):
    """The options of
    [`IntegralStateFeedback`][elastic_gym.controllers.integral.IntegralStateFeedback]."""

    omega: PositiveFinite = 30.0
    integral_weight: PositiveFinite = DEFAULT_INTEGRAL_WEIGHT
    integral_limit: PositiveFinite = DEFAULT_INTEGRAL_LIMIT


class IntegralStateFeedback(FeedforwardStateFeedback):
    """Eq. (13) plus an integrator on the link position error, with anti-windup.

    Args:
        model: nominal model (INVDYN and the gain design use it).
        dt: control period (s).
        omega: slowest closed-loop pole (rad/s) of the underlying eq. (13) design.
        integral_weight: LQR weight of z relative to J^2 w^6 (see module docstring).
        integral_limit: bound of |K_I z| as a fraction of the model's torque limit.
        feedforward, design_configuration, fd_step, load_identification: as for eq. (13).

    ``design`` holds the configuration, the method and the poles of the augmented
    nominal closed loop (dimension N + dim(x)); ``integral`` is the state z. The law runs
    as [`VectorIntegralStateFeedback`][elastic_gym.controllers.integral.VectorIntegralStateFeedback]
    with one arm.
    """

    name = "integral-state-feedback"
    options_model = IntegralOptions

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
        load_identification: str = "none",
    ) -> None:
        validated_options(IntegralOptions, locals())
        self.integral_weight = integral_weight
        self.integral_bound = float(integral_limit) * np.asarray(model.spec.torque_limit, float)
        self.torque_limit = np.asarray(model.spec.torque_limit, dtype=float)
        super().__init__(
            model,
            dt,
            omega=omega,
            feedforward=feedforward,
            design_configuration=design_configuration,
            fd_step=fd_step,
            load_identification=load_identification,
        )
        q0 = np.asarray(self.design["configuration"])
        A, Bu = integral_linearization(model, q0)
        self.design["poles"] = closed_loop_poles(A, Bu, np.hstack([self.integral_gain, self.gain]))

    def _design(self, A, Bu, q0, omega, gain, weights, poles) -> tuple[np.ndarray, str]:
        K_x, self.integral_gain = lqr_integral_gain(self.model, q0, omega, self.integral_weight)
        return K_x, f"LQR with integral action, slowest pole of eq. (13) {omega} rad/s"

    @property
    def integral(self) -> np.ndarray:
        """The integrator state z (n,)."""
        return self._law.integral[0]


@twin_of(IntegralStateFeedback)
class VectorIntegralStateFeedback(VectorStateFeedback):
    """Eq. (13) with integral action on N arms: one integrator z_i per arm."""

    def _bind(self, controller: IntegralStateFeedback, n_arms: int) -> None:  # type: ignore[override]  # the twin of this class only
        super()._bind(controller, n_arms)
        self.integral_gain = controller.integral_gain
        self.integral_bound = controller.integral_bound
        self.torque_limit = controller.torque_limit
        self._rows = link_position_rows(controller.model)
        self.integral = np.zeros((self.n_arms, self.n))
        self._time = np.full(self.n_arms, np.nan)  # NaN: no call since the reset
        self._saturated = np.zeros(self.n_arms, dtype=bool)

    def reset_arms(self, obs: Mapping, info: Mapping, arms: np.ndarray) -> None:
        super().reset_arms(obs, info, arms)
        self.integral[arms] = 0.0
        self._time[arms] = np.nan
        self._saturated[arms] = False

    def _integrate(self, arms: np.ndarray, error: np.ndarray, elapsed: np.ndarray) -> None:
        z = self.integral[arms] + elapsed[:, None] * error
        K_I, bound = self.integral_gain, self.integral_bound
        torque = np.clip(arm_rows(K_I, z), -bound, bound)
        self.integral[arms] = np.linalg.solve(K_I, torque[..., None])[..., 0]

    def torques(self, t: np.ndarray, x: np.ndarray, ref: np.ndarray) -> np.ndarray:
        x_d, tau_d = self.tracked(t, x, ref)
        previous = self._time
        ahead = t > previous + TIME_TOLERANCE  # False right after a reset (NaN)
        arms = np.flatnonzero(ahead & ~self._saturated)
        if len(arms):
            rows = self._rows
            self._integrate(arms, x[arms][:, rows] - x_d[arms][:, rows], (t - previous)[arms])
        self._time = np.where(ahead | np.isnan(previous), t, previous)
        tau = arm_rows(self.gain, x_d - x) - arm_rows(self.integral_gain, self.integral) + tau_d
        self._saturated = np.any(np.abs(tau) > self.torque_limit, axis=1)
        return tau
