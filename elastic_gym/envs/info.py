"""The info of a batch's arms: the ground truth and the bookkeeping, never observed.

`BatchInfo` reads the simulator's state, the episode's arrays, the sensors and the plant
state and gives, for a group of arms (arrays with a leading arm axis) or for one arm
(plain values):

* `time` (s), `true_state` (q, q', theta, theta', q'' and x = (theta, q, theta', q')),
  `torque` (the applied, clipped motor torque), `torque_saturated`,
  `acceleration_saturated` (an observed accelerometer reading at the sensor's range),
  `reference` (q_d .. q_d^(4)), `termination_reason` (None while the physics holds);
* `plant`: the simulated plant's own parameters
  ([`PlantState.info`][elastic_gym.envs.plant_state.PlantState.info]).

Every array handed out is new (views of one fresh copy per group: the state, the
reference), so no later step changes an info already handed out.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from elastic_gym.arms import REFERENCE_KEYS
from elastic_gym.envs.episode import EpisodeState
from elastic_gym.envs.measurement import Sensors
from elastic_gym.envs.plant_state import PlantState
from elastic_gym.envs.simulator import ArmSimulator


@njit(cache=True)
def _arm_values(k, theta, q, dtheta, dq, ddq, reference, torque, readings, limit, out):
    """One fresh copy of arm k's info arrays, flat: theta, q, theta', q', q'', the
    reference's rows (q_d .. q_d^(4)) and tau, n numbers each; returns whether one of its
    accelerometer `readings` (N, 3 n_sensors) is at the range `limit` (N,)
    (`_at_range`)."""
    n = q.shape[1]
    for j in range(n):
        out[j] = theta[k, j]
        out[n + j] = q[k, j]
        out[2 * n + j] = dtheta[k, j]
        out[3 * n + j] = dq[k, j]
        out[4 * n + j] = ddq[k, j]
        for r in range(reference.shape[1]):
            out[(5 + r) * n + j] = reference[k, r, j]
        out[(5 + reference.shape[1]) * n + j] = torque[k, j]
    return _at_range(readings[k], limit[k])


@njit(cache=True)
def _at_range(readings, limit):
    """Whether any |reading| >= limit (a NaN reading is not), as numpy's
    `np.fmax.reduce(np.abs(readings)) >= limit` gives it."""
    for j in range(readings.shape[0]):  # noqa: SIM110 - a loop numba compiles
        if abs(readings[j]) >= limit:
            return True
    return False


class BatchInfo:
    """The info of the arms of a batch made of these parts (read only).

    Args:
        sim: the simulator (the state q, q', theta, theta').
        episode: the episode arrays (time, q'', reference, torques, flags, reasons, the
            observed accelerometer readings).
        sensors: the sensors (the accelerometers' ranges).
        plant_state: the plant state (`info["plant"]`).
    """

    def __init__(
        self, sim: ArmSimulator, episode: EpisodeState, sensors: Sensors, plant_state: PlantState
    ) -> None:
        self.sim, self.episode, self.sensors, self.plant_state = sim, episode, sensors, plant_state
        self.n_joints = episode.ddq.shape[1]
        self._no_readings = np.zeros((episode.n_arms, 0))  # the accelerometers of none

    def arms(self, arms: slice | np.ndarray = slice(None)) -> dict:
        """The info of ``arms``: arrays with a leading arm axis."""
        sim, episode, n = self.sim, self.episode, self.n_joints
        # one fresh copy of the state and the reference (5 n each: the derivatives)
        x = np.concatenate(
            (
                sim.theta[arms],
                sim.q[arms],
                sim.dtheta[arms],
                sim.dq[arms],
                episode.ddq[arms],
                episode.reference[arms].reshape(-1, len(REFERENCE_KEYS) * n),
            ),
            axis=1,
        )
        state = {
            "q": x[:, n : 2 * n],
            "dq": x[:, 3 * n : 4 * n],
            "theta": x[:, :n],
            "dtheta": x[:, 2 * n : 3 * n],
            "ddq": x[:, 4 * n : 5 * n],
            "x": x[:, : 4 * n],
        }
        start = 5 * n
        return {
            "time": episode.time[arms].copy(),
            "true_state": state,
            "torque": episode.torque[arms].copy(),
            "torque_saturated": episode.saturated[arms].copy(),
            "acceleration_saturated": self._acceleration_saturated(arms),
            "reference": {
                key: x[:, start + k * n : start + (k + 1) * n]
                for k, key in enumerate(REFERENCE_KEYS)
            },
            "termination_reason": episode.reasons[arms].copy(),
            "plant": self.plant_state.info(arms),
        }

    def arm(self, k: int) -> dict:
        """The info of the one arm ``k`` (plain values; the same items, one compiled copy of
        the state, the reference and the torque)."""
        sim, episode, n = self.sim, self.episode, self.n_joints
        x = np.empty((6 + len(REFERENCE_KEYS)) * n)
        at_range = _arm_values(
            k,
            sim.theta,
            sim.q,
            sim.dtheta,
            sim.dq,
            episode.ddq,
            episode.reference,
            episode.torque,
            episode.obs.get("acceleration", self._no_readings),
            self.sensors.accelerometer_array.range,
            x,
        )
        return {
            "time": float(episode.time[k]),
            "true_state": {
                "q": x[n : 2 * n],
                "dq": x[3 * n : 4 * n],
                "theta": x[:n],
                "dtheta": x[2 * n : 3 * n],
                "ddq": x[4 * n : 5 * n],
                "x": x[: 4 * n],
            },
            "torque": x[10 * n :],
            "torque_saturated": bool(episode.saturated[k]),
            "acceleration_saturated": at_range,
            "reference": {  # REFERENCE_KEYS
                "q": x[5 * n : 6 * n],
                "dq": x[6 * n : 7 * n],
                "ddq": x[7 * n : 8 * n],
                "d3q": x[8 * n : 9 * n],
                "d4q": x[9 * n : 10 * n],
            },
            "termination_reason": episode.reasons[k],
            "plant": self.plant_state.info(k),
        }

    def _acceleration_saturated(self, arms) -> np.ndarray:
        """Whether an observed accelerometer reading is at the sensor's range (clipped)."""
        if not self.sensors.n_sensors:
            return np.zeros(len(self.episode.time[arms]), dtype=bool)
        readings = np.abs(self.episode.obs["acceleration"][arms])
        limit = self.sensors.accelerometer_array.range[arms]
        return (readings >= limit[:, None]).any(axis=-1)
