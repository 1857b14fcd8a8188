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
from elastic_gym.observers.base import Observer


class FiniteDifferenceObserver(Observer):
    """Filtered finite differences; see the module docstring."""

    name = "finite-difference"

    def __init__(self, model: RobotModel, dt: float, cutoff_hz: float = 30.0) -> None:
        super().__init__(model, dt)
        if not (isinstance(cutoff_hz, (int, float)) and cutoff_hz > 0):
            raise ValueError(f"cutoff_hz must be > 0, got {cutoff_hz!r}")
        self.cutoff_hz = float(cutoff_hz)
        self._previous = np.zeros(self.n)
        self._velocity = np.zeros(self.n)
        self._q_static = np.zeros(self.n)

    def _static_link_position(self, theta: np.ndarray) -> np.ndarray:
        self._q_static = self.model.static_link_position(
            theta, initial=self._q_static, tolerance=1e-10
        )
        return self._q_static

    def _estimate(self, position: np.ndarray) -> np.ndarray:
        if not self.elastic:
            return np.concatenate([position, self._velocity])
        q = self._static_link_position(position)
        return np.concatenate([position, q, self._velocity, self._velocity])

    def reset(self, obs: Mapping, initial_estimate: np.ndarray | None = None) -> np.ndarray:
        position = self.measured_position(obs)
        x0 = self.check_initial_estimate(initial_estimate)
        self._previous = position.copy()
        self._q_static = position.copy()
        self._velocity = np.zeros(self.n) if x0 is None else x0[-self.n :].copy()
        return self._estimate(position)

    def update(self, obs: Mapping, torque: np.ndarray, dt: float) -> np.ndarray:
        position = self.measured_position(obs)
        raw = (position - self._previous) / dt
        a = np.exp(-2.0 * np.pi * self.cutoff_hz * dt)
        self._velocity = a * self._velocity + (1.0 - a) * raw
        self._previous = position
        return self._estimate(position)
