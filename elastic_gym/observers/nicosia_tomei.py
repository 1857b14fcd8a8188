"""Full-order observer of Nicosia & Tomei (IEEE TAC 1990), the baseline of Cristofaro & De Luca.

With q_tilde = q - q_hat:

    q_hat' = z + kD q_tilde,
    z'     = M(q)^-1 [tau - C(q, z) z - F z - g(q) + kP q_tilde],

with the measured q in M, C and g and F z the model's link friction, integrated by RK4
over each control period (`rigid_common`). The velocity
estimate is z (filtered twice), not q_hat' (which feeds the measurement noise through).
Gains: kD = k0 of Cristofaro & De Luca eq. (12), so both observers are compared at equal
output-injection gain; kP = kD^2 lambda_max(M) / 4 makes the heaviest mode of the
linearized error critically damped.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from elastic_gym.model import RobotModel
from elastic_gym.observers.base import Observer
from elastic_gym.observers.rigid_common import (
    RigidArmBounds,
    boolean_option,
    observer_acceleration,
    positive_integer,
    positive_number,
    rk4_period,
)


class NicosiaTomeiObserver(Observer):
    """Nicosia-Tomei full-order observer (module docstring).

    Args:
        model: nominal rigid-arm model.
        dt: sampling period (s).
        kD: output injection gain on q_hat' (1/s); default k0 of eq. (12).
        kP: output injection gain on z (N m / rad); default kD^2 lambda_max(M) / 4.
        eta, v_max: parameters of eq. (12) for the default kD (rad/s).
        points_per_joint, max_samples: configuration sampling of the bounds.
        model_friction: include the model's link friction in the observer.
        substeps: RK4 steps per sampling period.

    Diagnostics: ``kD``, ``kP`` and ``position_residual`` = |q - q_hat|.
    """

    name = "nicosia-tomei"
    applies_to = frozenset({"rigid"})

    def __init__(
        self,
        model: RobotModel,
        dt: float,
        kD: float | None = None,
        kP: float | None = None,
        eta: float = 1.0,
        v_max: float = 2.0,
        points_per_joint: int = 181,
        max_samples: int = 4096,
        model_friction: bool = True,
        substeps: int = 1,
    ) -> None:
        super().__init__(model, dt)
        bounds = RigidArmBounds.from_model(model, points_per_joint, max_samples)
        if kD is None:
            velocity = positive_number("v_max", v_max) + positive_number("eta", eta)
            kD = bounds.injection_gain(velocity)
        self.kD = positive_number("kD", kD)
        if kP is None:
            kP = 0.25 * self.kD**2 * float(bounds.lambda_max.max())
        self.kP = positive_number("kP", kP)
        self.model_friction = boolean_option("model_friction", model_friction)
        self.substeps = positive_integer("substeps", substeps)
        self._x = np.zeros(2 * self.n)
        self._y = np.zeros(self.n)
        self.diagnostics = {"kD": self.kD, "kP": self.kP, "position_residual": 0.0}

    def _rhs(self, x: np.ndarray, y: np.ndarray, torque: np.ndarray) -> np.ndarray:
        n = self.n
        q_hat, z = x[:n], x[n:]
        q_tilde = y - q_hat
        tau = torque + self.kP * q_tilde
        acceleration = observer_acceleration(self.model, y, z, tau, self.model_friction)
        return np.concatenate([z + self.kD * q_tilde, acceleration])

    def reset(self, obs: Mapping, initial_estimate: np.ndarray | None = None) -> np.ndarray:
        x0 = self.check_initial_estimate(initial_estimate)
        self._y = self.measured_position(obs).copy()
        self._x = np.concatenate([self._y, np.zeros(self.n)]) if x0 is None else x0
        self.diagnostics["position_residual"] = float(np.linalg.norm(self._y - self._x[: self.n]))
        return self._x.copy()

    def update(self, obs: Mapping, torque: np.ndarray, dt: float) -> np.ndarray:
        y = self.measured_position(obs)
        tau = np.asarray(torque, dtype=float)
        self._x = rk4_period(self._rhs, self._x, self._y, y, tau, dt, self.substeps)
        self._y = y.copy()
        self.diagnostics["position_residual"] = float(np.linalg.norm(y - self._x[: self.n]))
        return self._x.copy()
