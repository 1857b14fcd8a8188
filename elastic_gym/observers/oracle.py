"""The oracle: the true state, for "true state" rows of a comparison (not implementable)."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from elastic_gym.observers.base import BatchedObserver


class OracleObserver(BatchedObserver):
    """Returns the ground truth the env puts in ``info["true_state"]``."""

    name = "true"
    privileged = ("true_state",)

    def _truth(self, obs: Mapping, arms) -> np.ndarray:
        truth = obs["true_state"]
        if self.elastic:
            return np.array(truth["x"], dtype=float)[arms]
        return np.concatenate([truth["q"], truth["dq"]], axis=-1)[arms]

    def reset_arms(self, obs: Mapping, arms: np.ndarray, initial_estimate=None) -> np.ndarray:
        return self._truth(obs, arms)

    def update_arms(
        self, obs: Mapping, torque: np.ndarray, dt: float, arms: np.ndarray | None = None
    ) -> np.ndarray:
        return self._truth(obs, slice(None))
