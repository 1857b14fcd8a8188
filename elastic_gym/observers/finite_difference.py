"""Baseline: low-pass filtered finite differences of the encoders.

Rigid arms: q from the link encoders, q' = LPF[(q_k - q_{k-1}) / T].
Elastic arms (what a motor-only controller assumes): theta from the motor encoders,
theta' = LPF[(theta_k - theta_{k-1}) / T]; the link is taken at its quasi-static
position q = theta - K^-1 g(q) (solved by fixed-point iteration, a contraction since
|K^-1 dg/dq| << 1) with q' = theta'. The filter is first order with cut-off
``cutoff_hz``, discretized exactly: v_k = a v_{k-1} + (1 - a) v_raw, a = exp(-2 pi f_c T).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from elastic_gym.model import RobotModel
from elastic_gym.observers.base import BatchedObserver, arm_count
from elastic_gym.validation import PositiveFinite, option_value


class FiniteDifferenceObserver(BatchedObserver):
    """Filtered finite differences; see the module docstring."""

    name = "finite-difference"

    def __init__(self, model: RobotModel, dt: float, cutoff_hz: float = 30.0) -> None:
        super().__init__(model, dt)
        self.cutoff_hz = option_value("cutoff_hz", cutoff_hz, PositiveFinite)
        self._allocate(1)

    def _allocate(self, n_arms: int) -> None:
        shape = (n_arms, self.n)
        self._previous, self._velocity, self._q_static = (np.zeros(shape) for _ in range(3))

    def _estimate(self, position: np.ndarray, arms) -> np.ndarray:
        velocity = self._velocity[arms]
        if not self.elastic:
            return np.concatenate([position, velocity], axis=1)
        q = self.model.static_link_position(position, initial=self._q_static[arms], tolerance=1e-10)
        self._q_static[arms] = q
        return np.concatenate([position, q, velocity, velocity], axis=1)

    def reset_arms(self, obs: Mapping, arms: np.ndarray, initial_estimate=None) -> np.ndarray:
        n_arms = arm_count(obs)
        if len(self._previous) != n_arms:
            self._allocate(n_arms)
        position = self.measured_positions(obs, arms)
        x0 = self.initial_rows(initial_estimate, len(arms))
        self._previous[arms] = position
        self._q_static[arms] = position
        self._velocity[arms] = 0.0 if x0 is None else x0[:, -self.n :]
        return self._estimate(position, arms)

    def update_arms(
        self, obs: Mapping, torque: np.ndarray, dt: float, arms: np.ndarray | slice | None = None
    ) -> np.ndarray:
        arms = slice(None) if arms is None else arms
        position = self.measured_positions(obs, arms)
        raw = (position - self._previous[arms]) / dt
        a = np.exp(-2.0 * np.pi * self.cutoff_hz * dt)
        self._velocity[arms] = a * self._velocity[arms] + (1.0 - a) * raw
        self._previous[arms] = position
        estimate = self._estimate(position, arms)
        out = np.zeros((len(self._previous), self.state_dim))
        out[arms] = estimate
        return out
