"""Link-side torque pulses of N arms (the ``torque_pulses`` env kwarg).

Each arm has its own schedule: pulses k with start time t_k, duration d_k and amplitude
a_k (N m per joint), given or drawn at every reset from the arm's plant stream (see
[`elastic_gym.envs.config`][elastic_gym.envs.config]). During the control period that starts at time
t the
links receive the external torque sum_k a_k [t_k <= t < t_k + d_k], summed in pulse order;
it enters the link equation beside tau_J (PyBullet and the true q'').
"""

from __future__ import annotations

import numpy as np

from elastic_gym.envs.config import RandomPulses, TorquePulsesConfig
from elastic_gym.validation import per_joint_values


def given_pulses(
    config: TorquePulsesConfig, torque_limit: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(start times (P,), end times (P,), amplitudes (P, n)) of a given schedule."""
    n = len(torque_limit)
    times = np.asarray(config.times, dtype=float)
    amplitudes = [
        per_joint_values(a, n, f"torque_pulses.amplitudes[{k}]")
        for k, a in enumerate(config.amplitudes or ())
    ]
    return times, times + np.asarray(config.durations), np.array(amplitudes).reshape(-1, n)


def random_pulses(
    spec: RandomPulses, rng: np.random.Generator, torque_limit: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A random schedule as `given_pulses` gives one: times, then durations, then
    amplitudes, then signs drawn from ``rng`` (an arm's plant stream)."""
    n = len(torque_limit)
    times = rng.uniform(*spec.window, size=spec.count)
    durations = rng.uniform(spec.duration.low, spec.duration.high, size=spec.count)
    scale = rng.uniform(spec.amplitude.low, spec.amplitude.high, size=(spec.count, n))
    signs = np.where(rng.random((spec.count, n)) < 0.5, -1.0, 1.0)
    return times, times + durations, signs * scale * torque_limit


class TorquePulses:
    """The pulse schedules of N arms, padded to a common pulse count (zero pulses that
    never start), and the torque they apply."""

    def __init__(self, n_arms: int, n_joints: int) -> None:
        self.n_arms, self.n = n_arms, n_joints
        self.start = np.full((n_arms, 0), np.inf)
        self.end = np.full((n_arms, 0), np.inf)
        self.amplitude = np.zeros((n_arms, 0, n_joints))
        self.current = np.zeros((n_arms, n_joints))  # the torque of the last control period

    def set(self, arm: int, start: np.ndarray, end: np.ndarray, amplitude: np.ndarray) -> None:
        """Arm ``arm``'s schedule (P pulses; the others' are padded if P is the largest)."""
        count = len(start)
        if count > self.start.shape[1]:
            extra = count - self.start.shape[1]
            self.start = np.pad(self.start, ((0, 0), (0, extra)), constant_values=np.inf)
            self.end = np.pad(self.end, ((0, 0), (0, extra)), constant_values=np.inf)
            self.amplitude = np.pad(self.amplitude, ((0, 0), (0, extra), (0, 0)))
        self.start[arm], self.end[arm], self.amplitude[arm] = np.inf, np.inf, 0.0
        self.start[arm, :count], self.end[arm, :count] = start, end
        self.amplitude[arm, :count] = amplitude

    def torque(self, time: np.ndarray) -> np.ndarray | None:
        """The link torque (N, n) of the control period starting at ``time`` (N,), or None
        when no arm has an active pulse."""
        if not self.start.shape[1]:
            return None
        t = time[:, None]
        active = (self.start <= t) & (t < self.end)
        if not active.any():
            self.current[:] = 0.0
            return None
        out = np.zeros((self.n_arms, self.n))
        for k in range(self.start.shape[1]):
            out = out + np.where(active[:, k, None], self.amplitude[:, k], 0.0)
        self.current = out
        return out
