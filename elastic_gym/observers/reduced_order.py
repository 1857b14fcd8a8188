"""Reduced-order velocity observer of Cristofaro & De Luca (IEEE L-CSS 2022), rigid arms.

Eq. (6) with the linear gain k(y) = k y of eq. (9):

    M(y) z' = -C(y, x_hat_2) x_hat_2 - F x_hat_2 - g(y) - k M(y) x_hat_2 + tau,
    x_hat_2 = z + k y,

integrated by RK4 over each control period. Constant gain: k0 of eq. (12) from the
model's bounds (`RigidArmBounds`), or given.
Hybrid gain (Sec. IV, ``hybrid=True``): k_r of eq. (16) with the logic state r of eq.
(17). The paper's jump sets (15) leave no flow set for v_bar <= 2 eta and jump every
sample (``jump_sets="literal"``); the default ``"hysteresis"`` lowers the gain only when
|x_hat_2| + eta is ``tolerance`` below the lower level's bound, and resets z at each jump
(z+ = z + (k_r - k_r+) y) so that x_hat_2 is continuous.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Literal, get_args

import numpy as np

from elastic_gym.model import RobotModel
from elastic_gym.observers.rigid_common import (
    RigidArmBounds,
    ScalarGainReducedObserver,
    boolean_option,
    positive_integer,
    positive_number,
)
from elastic_gym.validation import at_most_one, errors_at, option_value

JumpSets = Literal["hysteresis", "literal"]
JUMP_SETS = get_args(JumpSets)


class ReducedOrderObserver(ScalarGainReducedObserver):
    """Cristofaro & De Luca reduced-order observer, eq. (6), constant or hybrid gain.

    Args:
        model: nominal rigid-arm model.
        dt: sampling period (s).
        eta: radius of the error ball of Theorem 1 (rad/s), eqs. (12)-(13), (15)-(16).
        v_max: velocity bound of Assumption 2 (rad/s) for the constant gain, eq. (12).
        k0: explicit constant gain (1/s) instead of eq. (12).
        hybrid: use the scheduled gain k_r, eqs. (15)-(17), instead of k0.
        v_bar: level width of the velocity partition (rad/s), eq. (15).
        r0: initial logic state r(0) (>= 1 with the hysteresis layer).
        jump_sets: ``"hysteresis"`` (tolerance layer, default) or ``"literal"`` (eq. (15)).
        tolerance: width of the hysteresis band (rad/s).
        points_per_joint, max_samples: configuration sampling of the bounds.
        model_friction: include F x_hat_2 (``model.link_friction``) in the observer.
        substeps: RK4 steps per sampling period.

    Diagnostics: ``gain`` (current k), ``r`` (logic state, hybrid) and ``jumps``
    (number of jumps of r since reset).
    """

    name = "reduced-order"

    def __init__(
        self,
        model: RobotModel,
        dt: float,
        eta: float = 1.0,
        v_max: float = 2.0,
        k0: float | None = None,
        hybrid: bool = False,
        v_bar: float = 2.0,
        r0: int = 1,
        jump_sets: str = "hysteresis",
        tolerance: float = 0.1,
        points_per_joint: int = 181,
        max_samples: int = 4096,
        model_friction: bool = True,
        substeps: int = 1,
    ) -> None:
        self.hybrid = boolean_option("hybrid", hybrid)
        option_value("jump_sets", jump_sets, JumpSets)
        with errors_at("options.k0"):  # k0: a constant gain, hybrid: the switched one
            at_most_one({"k0": k0, "hybrid": hybrid or None})
        self.eta = positive_number("eta", eta)
        self.v_max = positive_number("v_max", v_max)
        self.v_bar = positive_number("v_bar", v_bar)
        self.tolerance = positive_number("tolerance", tolerance)
        self.hysteresis = jump_sets == "hysteresis"
        self.r0 = positive_integer("r0", r0, minimum=1 if self.hysteresis else 0)
        self.bounds = RigidArmBounds.from_model(model, points_per_joint, max_samples)
        if k0 is None:
            k0 = self.bounds.injection_gain(self.v_max + self.eta)
            if k0 <= 0.0:
                raise ValueError(
                    f"eq. (12) gives k0 = {k0:.3g} <= 0 for robot {model.spec.name!r} "
                    "(no Coriolis coupling to dominate); pass option 'k0' > 0"
                )
        self.k0 = positive_number("k0", k0)
        self.r = self.r0
        self.jumps = 0
        super().__init__(
            model, dt, self.level_gain(self.r0) if hybrid else self.k0, model_friction, substeps
        )
        self._update_diagnostics()

    def level_gain(self, r: int) -> float:
        """k_r of eq. (16)."""
        return self.bounds.injection_gain(self.eta + r * self.v_bar)

    def _jump(self, speed: float) -> int:
        """+1, -1 or 0: the jump of r (17) triggered by |x_hat_2| = ``speed``."""
        r, v_bar, eta = self.r, self.v_bar, self.eta
        if speed >= r * v_bar - eta:
            return 1
        down = (r - 1) * v_bar - eta - self.tolerance if self.hysteresis else (r - 1) * v_bar + eta
        return -1 if r > 0 and speed <= down else 0

    def _update_diagnostics(self) -> None:
        self.diagnostics = {"gain": self.gain, "r": float(self.r), "jumps": float(self.jumps)}

    def reset(self, obs: Mapping, initial_estimate: np.ndarray | None = None) -> np.ndarray:
        self.r, self.jumps = self.r0, 0
        self.gain = self.level_gain(self.r0) if self.hybrid else self.k0
        estimate = super().reset(obs, initial_estimate)
        self._update_diagnostics()
        return estimate

    def update(self, obs: Mapping, torque: np.ndarray, dt: float) -> np.ndarray:
        estimate = super().update(obs, torque, dt)
        if self.hybrid:
            step = self._jump(float(np.linalg.norm(estimate[self.n :])))
            if step:
                self.r += step
                self.jumps += 1
                self.set_gain(self.level_gain(self.r))
            self._update_diagnostics()
        return estimate
