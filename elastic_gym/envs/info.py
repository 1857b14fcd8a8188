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

from collections.abc import Callable

import numpy as np
from numba import njit

from elastic_gym.arms import REFERENCE_KEYS
from elastic_gym.envs.episode import EpisodeState
from elastic_gym.envs.measurement import Sensors
from elastic_gym.envs.plant_state import PlantState
from elastic_gym.envs.simulator import ArmSimulator
from elastic_gym.model.chain import NO_REFCOUNT
from elastic_gym.model.packed import Packed, direct

ROWS = 7 + len(REFERENCE_KEYS)
"""n-vectors of one arm's info: theta, q, theta', q', q'', the reference's rows, tau, the
torque pulse (`_arm_values`)."""


@njit(cache=True, **NO_REFCOUNT)
def _arm_values(k, arrays, pulse, out):
    """One fresh copy of arm k's info and observation arrays, flat, into ``out``: theta, q,
    theta', q', q'', the reference's rows (q_d .. q_d^(4)), tau and the torque pulse, n
    numbers each, then the observed encoders, accelerometers and reference; returns
    whether one of its observed accelerometer readings is at the range (`_at_range`).
    ``arrays``: the batch's (theta, q, theta', q', q'', reference (N, 5, n), tau, the
    observed encoders, accelerometers (N, 0 without) and reference, the accelerometers'
    range (N,)); ``pulse``: the torque pulses (N, n)."""
    theta, q, dtheta, dq, ddq, reference, torque = arrays[:7]
    position, acceleration, observed_reference, limit = arrays[7:]
    n = q.shape[1]
    rows = reference.shape[1]
    for j in range(n):
        out[j] = theta[k, j]
        out[n + j] = q[k, j]
        out[2 * n + j] = dtheta[k, j]
        out[3 * n + j] = dq[k, j]
        out[4 * n + j] = ddq[k, j]
        for r in range(rows):
            out[(5 + r) * n + j] = reference[k, r, j]
        out[(5 + rows) * n + j] = torque[k, j]
        out[(6 + rows) * n + j] = pulse[k, j]
    start = (7 + rows) * n
    for values in (position, acceleration, observed_reference):
        for j in range(values.shape[1]):
            out[start + j] = values[k, j]
        start += values.shape[1]
    return _at_range(acceleration[k], limit[k])


@njit(cache=True)
def arm_values_kernel(k, packed, pulse, out):
    """`_arm_values` of a `Packed` of its arrays (a kernel without reference counting
    reads them: the counting of the eleven arrays would cost a fifth of the call)."""
    return _arm_values(k, packed.values, pulse, out)


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
        self._call: Callable[..., bool] | None = None  # `arm_values_kernel`, see `_pack`
        self._packed: Packed | None = None
        self._observed: list[tuple[str, slice]] = []  # observation key, its part of a copy
        self._shape = (ROWS, self.n_joints)

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
        the state, the reference and the torques)."""
        return self.arm_outputs(k)[1]

    def arm_outputs(self, k: int) -> tuple[dict[str, np.ndarray], dict]:
        """(observation, info) of the one arm ``k``: the observation as
        [`ArmBatch.observation`][elastic_gym.envs.batch.ArmBatch.observation] gives it, the
        info as `arm`, their arrays views of one fresh copy (one compiled call)."""
        call = self._call or self._pack()
        episode, plant_state, n = self.episode, self.plant_state, self.n_joints
        rows = np.empty(self._shape)  # (the rows of n past ROWS: the observation)
        out = rows.reshape(-1)
        at_range = call(k, self._packed, plant_state.pulses.current, out)
        theta, q, dtheta, dq, ddq = rows[0], rows[1], rows[2], rows[3], rows[4]
        q_d, dq_d, ddq_d, d3q_d, d4q_d = rows[5], rows[6], rows[7], rows[8], rows[9]
        torque, pulse = rows[10], rows[11]  # ROWS = 12
        observation = {key: out[part] for key, part in self._observed}
        plant = plant_state.arm_values(k)
        plant["torque_pulse"] = pulse
        plant_state.pulse_schedule(k, plant)
        return observation, {
            "time": episode.time.item(k),
            "true_state": {
                "q": q,
                "dq": dq,
                "theta": theta,
                "dtheta": dtheta,
                "ddq": ddq,
                "x": out[: 4 * n],
            },
            "torque": torque,
            "torque_saturated": episode.saturated.item(k),
            "acceleration_saturated": at_range,
            "reference": {  # REFERENCE_KEYS
                "q": q_d,
                "dq": dq_d,
                "ddq": ddq_d,
                "d3q": d3q_d,
                "d4q": d4q_d,
            },
            "termination_reason": episode.reasons[k],
            "plant": plant,
        }

    def _pack(self) -> Callable[..., bool]:
        """The arrays `arm_values_kernel` reads (the parts' own, never rebound), packed
        once, and the layout of its copy; returns its entry point (`direct`)."""
        sim, episode, sensors = self.sim, self.episode, self.sensors
        obs, n, position = episode.obs, self.n_joints, sensors.position_key
        acceleration = obs.get("acceleration", self._no_readings)
        observed = (obs[position], acceleration, obs["reference"])
        state = (sim.theta, sim.q, sim.dtheta, sim.dq, episode.ddq)
        limit = sensors.accelerometer_array.range
        self._packed = Packed((*state, episode.reference, episode.torque, *observed, limit))
        parts, start = {}, ROWS * n  # the copy's layout: encoders, accelerometers, reference
        for key, values in zip((position, "acceleration", "reference"), observed, strict=True):
            parts[key] = slice(start, start + values.shape[1])
            start += values.shape[1]
        self._observed = [(key, parts[key]) for key in obs]  # in the observation's order
        self._shape = (-(-start // n), n)  # whole rows of n
        pulse = self.plant_state.pulses.current
        self._call = direct(arm_values_kernel, 0, self._packed, pulse, np.empty(start))
        return self._call

    def _acceleration_saturated(self, arms) -> np.ndarray:
        """Whether an observed accelerometer reading is at the sensor's range (clipped)."""
        if not self.sensors.n_sensors:
            return np.zeros(len(self.episode.time[arms]), dtype=bool)
        readings = np.abs(self.episode.obs["acceleration"][arms])
        limit = self.sensors.accelerometer_array.range[arms]
        return (readings >= limit[:, None]).any(axis=-1)
