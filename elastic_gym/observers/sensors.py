"""Raw sensors as a state source: no estimate at all.

A loop on raw sensors (a policy trained with ``state: sensors``) reads the encoder and
accelerometer observation itself; `RawSensors` is the state source of such a loop
in the observers' interface, an estimate of dimension 0 that reads no ground truth, and
[`SensorWrapper`][elastic_gym.observers.vector.SensorWrapper] keeps the sensor observation for it.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from elastic_gym.observers.base import BatchedObserver, arm_count

SENSORS = "sensors"


class RawSensors(BatchedObserver):
    """The empty estimate (state dimension 0) of a loop that reads the raw sensors."""

    name = SENSORS

    @property
    def state_names(self) -> tuple[str, ...]:
        return ()

    def reset_arms(
        self, obs: Mapping[str, np.ndarray], arms: np.ndarray, initial_estimate=None
    ) -> np.ndarray:
        if initial_estimate is not None:
            raise ValueError("initial_estimate: raw sensors have no state estimate to initialise")
        return np.zeros((len(arms), 0))

    def update_arms(
        self,
        obs: Mapping[str, np.ndarray],
        torque: np.ndarray,
        dt: float,
        arms: np.ndarray | None = None,
    ) -> np.ndarray:
        return np.zeros((arm_count(obs), 0))
