"""The oracle: the true state, for "true state" rows of a comparison (not implementable)."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from elastic_gym.observers.base import Observer


class OracleObserver(Observer):
    """Returns the ground truth the env puts in ``info["true_state"]``."""

    name = "true"
    privileged = ("true_state",)

    def _truth(self, obs: Mapping) -> np.ndarray:
        truth = obs["true_state"]
        if self.elastic:
            return np.array(truth["x"], dtype=float)
        return np.concatenate([truth["q"], truth["dq"]])

    def reset(self, obs: Mapping, initial_estimate: np.ndarray | None = None) -> np.ndarray:
        return self._truth(obs)

    def update(self, obs: Mapping, torque: np.ndarray, dt: float) -> np.ndarray:
        return self._truth(obs)
