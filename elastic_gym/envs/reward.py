"""The tracking reward of the arm envs, on arrays with a leading arm axis.

Inputs have shape (N, n): the link tracking error e = q - q_d, its rate e', the applied
torque tau and the previous one, the torque limits and the torsion theta - q. Per arm
and control period dt,

    r = dt * ( w_track    * mean_{joints, sigmas} exp(-(e / sigma)^2)
             + w_velocity * mean_{joints, sigmas} exp(-(e' / sigma_v)^2)
             - w_torque   * mean_joints (tau / tau_max)^2
             - w_rate     * mean_joints min(1, (tau' / tau'_max)^2)
             - w_torsion  * mean_joints min(1, ((theta - q) / torsion_scale)^2)
             + (w_torque + w_rate + w_torsion) )

with tau' = (tau - tau_prev) / dt, tau'_max = tau_max / rate_time: every penalty bounded,
so r >= 0; a broken episode pays ``-termination * (sum of the weights)``.
"""

from __future__ import annotations

from functools import cached_property
from typing import Annotated

import numpy as np
from numba import njit
from pydantic import Field

from elastic_gym.validation import ConfigModel, NonNegativeFinite, PositiveFinite, numbers

DEFAULT_SIGMAS = (1e-5, 1e-4, 1e-3, 1e-2, 1e-1, 1.0)  # rad, one kernel per decade
DEFAULT_VELOCITY_SIGMAS = (1e-3, 1e-2, 1e-1, 1.0, 10.0)  # rad/s
TERM_NAMES = ("track", "velocity", "torque", "rate", "torsion", "offset")
Widths = Annotated[tuple[PositiveFinite, ...], Field(min_length=1)]


class RewardConfig(ConfigModel):
    """Weights and scales of the tracking reward (module docstring).

    Attributes:
        track: weight of the tracking kernels (reward per second of perfect tracking).
        sigmas: kernel widths of the link error (rad), each > 0.
        velocity: weight of the velocity-error kernels.
        velocity_sigmas: kernel widths of the velocity error (rad/s).
        torque: weight of the normalized squared torque.
        rate: weight of the torque-rate (action-rate) penalty.
        rate_time: the rate penalty saturates at tau' = tau_max / rate_time (s).
        torsion: weight of the torsion penalty (0 by default: a loaded elastic joint
            must twist).
        torsion_scale: torsion (rad) at which that penalty saturates.
        termination: seconds of the best reward lost when the physics breaks.
    """

    section = "reward"
    track: NonNegativeFinite = 1.0
    sigmas: Widths = DEFAULT_SIGMAS
    velocity: NonNegativeFinite = 0.0
    velocity_sigmas: Widths = DEFAULT_VELOCITY_SIGMAS
    torque: NonNegativeFinite = 0.01
    rate: NonNegativeFinite = 0.05
    rate_time: PositiveFinite = 0.002
    torsion: NonNegativeFinite = 0.0
    torsion_scale: PositiveFinite = 0.05
    termination: NonNegativeFinite = 1.0

    @cached_property
    def _inverse_sigmas(self) -> np.ndarray:
        return 1.0 / np.array(self.sigmas)

    @cached_property
    def _inverse_velocity_sigmas(self) -> np.ndarray:
        return 1.0 / np.array(self.velocity_sigmas)

    @cached_property
    def _weights(self) -> np.ndarray:
        """track, velocity, torque, rate, torsion, penalty bound (the kernel's order)."""
        c = self
        return np.array([c.track, c.velocity, c.torque, c.rate, c.torsion, c.penalty_bound])

    def kernel_constants(self, dt: float) -> tuple:
        """The arguments of `_reward_kernel` after the torque limit and the torsion
        (the configuration at the control period ``dt``), in the kernel's order."""
        return (
            self._inverse_sigmas,
            self._inverse_velocity_sigmas,
            self._weights,
            self.rate_time / dt,
            self.torsion_scale,
            dt,
        )

    @property
    def penalty_bound(self) -> float:
        """Largest penalty per second (added back as a constant so that r >= 0)."""
        return self.torque + self.rate + self.torsion

    @property
    def max_rate(self) -> float:
        """Largest reward per second (perfect tracking, no torque, no torsion)."""
        return self.track + self.velocity + self.penalty_bound

    @property
    def termination_reward(self) -> float:
        """Reward of the step that ends an episode on broken physics (< 0)."""
        return -self.termination * self.max_rate


def _kernel_mean(x: np.ndarray, inverse_sigmas: np.ndarray) -> np.ndarray:
    """mean over joints and widths of exp(-(x / sigma)^2); x (N, n) -> (N,)."""
    scaled = x[..., None] * inverse_sigmas
    return np.exp(-scaled * scaled).sum(axis=(1, 2)) * (1.0 / (x.shape[1] * len(inverse_sigmas)))


def _saturated_mean(x: np.ndarray) -> np.ndarray:
    """mean over joints of min(1, x^2); x (N, n) -> (N,)."""
    return np.minimum(x * x, 1.0).sum(axis=1) * (1.0 / x.shape[1])


def _checked(error, error_rate, torque, previous_torque, torque_limit, torsion):
    shape = np.shape(error)
    arrays = {
        "error": error,
        "error_rate": error_rate,
        "torque": torque,
        "previous_torque": previous_torque,
        "torsion": torsion,
        "torque_limit": torque_limit,
    }
    out = {}
    rows = [shape] if len(shape) == 2 else []  # (arms, joints)
    for name, value in arrays.items():
        limit = name == "torque_limit"  # one row for every arm allowed
        what = f"must have shape (arms, joints){' or (joints,)' * limit} (error has {shape})"
        shapes = [*rows, shape[1:]] if limit and rows else rows
        where = f"reward input {name!r}"
        out[name] = numbers(value, where, what, shapes, finite=False, show_shape=True)
    return (
        out["error"],
        out["error_rate"],
        out["torque"],
        out["previous_torque"],
        out["torque_limit"],
        out["torsion"],
    )


def reward_terms(
    config: RewardConfig,
    dt: float,
    error,
    error_rate,
    torque,
    previous_torque,
    torque_limit,
    torsion,
) -> dict[str, np.ndarray]:
    """Each term of the reward (already multiplied by ``dt``), every entry of shape (N,).

    Args:
        config: weights and scales.
        dt: control period (s).
        error, error_rate: e = q - q_d and e' = q' - q_d', shape (N, n).
        torque, previous_torque: applied motor torque now and one period earlier (N, n).
        torque_limit: tau_max, shape (n,) or (N, n), > 0.
        torsion: theta - q, shape (N, n) (zeros for rigid arms).

    The keys are `TERM_NAMES`; their sum is [`total_reward`][elastic_gym.envs.reward.total_reward].
    """
    e, de, tau, previous, limit, torsion = _checked(
        error, error_rate, torque, previous_torque, torque_limit, torsion
    )
    c = config
    return {
        "track": dt * c.track * _kernel_mean(e, c._inverse_sigmas),
        "velocity": dt * c.velocity * _kernel_mean(de, c._inverse_velocity_sigmas),
        "torque": -dt * c.torque * _saturated_mean(tau / limit),
        "rate": -dt * c.rate * _saturated_mean((tau - previous) * (c.rate_time / dt) / limit),
        "torsion": -dt * c.torsion * _saturated_mean(torsion / c.torsion_scale),
        "offset": np.full(len(e), dt * c.penalty_bound),  # keeps r >= 0
    }


def total_reward(
    config: RewardConfig,
    dt: float,
    error,
    error_rate,
    torque,
    previous_torque,
    torque_limit,
    torsion,
) -> np.ndarray:
    """The reward of one control period per arm, shape (N,), each value in [0, dt * max_rate].

    Equal to the sum of [`reward_terms`][elastic_gym.envs.reward.reward_terms] (to rounding); terms
    of weight zero are not
    computed. Inputs as in [`reward_terms`][elastic_gym.envs.reward.reward_terms].
    """
    arrays = _checked(error, error_rate, torque, previous_torque, torque_limit, torsion)
    return batch_reward(config, dt, *arrays)


def batch_reward(
    config: RewardConfig,
    dt: float,
    error: np.ndarray,
    error_rate: np.ndarray,
    torque: np.ndarray,
    previous_torque: np.ndarray,
    torque_limit: np.ndarray,
    torsion: np.ndarray,
) -> np.ndarray:
    """[`total_reward`][elastic_gym.envs.reward.total_reward] without the input checks
    (float64 arrays of the right shapes):
    one compiled loop over the arms, the hot path of the envs."""
    limit = torque_limit if torque_limit.ndim == 2 else torque_limit[None]
    out = np.empty(len(error))
    _reward_kernel(  # type: ignore[call-arg]  # numba's Dispatcher stub takes no star-args
        error,
        error_rate,
        torque,
        previous_torque,
        limit,
        torsion,
        *config.kernel_constants(dt),
        out,
    )
    return out


@njit(cache=True)
def _kernel_sum(x, inverse_sigmas):
    """sum over joints and widths of exp(-(x / sigma)^2) for one arm."""
    total = 0.0
    for j in range(x.shape[0]):
        for s in range(inverse_sigmas.shape[0]):
            scaled = x[j] * inverse_sigmas[s]
            total += np.exp(-scaled * scaled)
    return total


@njit(cache=True)
def _saturated_sum(x, y, scale, divisor):
    """sum over joints of min(1, ((x - y) scale / divisor)^2) for one arm."""
    total = 0.0
    for j in range(x.shape[0]):
        value = (x[j] - y[j]) * scale / divisor[j]
        total += min(value * value, 1.0)
    return total


@njit(cache=True)
def _reward_kernel(
    e,
    de,
    tau,
    previous,
    limit,
    torsion,
    inverse_sigmas,
    inverse_velocity_sigmas,
    weights,
    rate_factor,
    torsion_scale,
    dt,
    out,
):
    """The module docstring's reward for each arm (weights: track, velocity, torque, rate,
    torsion, penalty bound)."""
    N, n = e.shape
    zero = np.zeros(n)
    ones = np.ones(n) * torsion_scale
    shared_limit = limit.shape[0] == 1  # one limit row for every arm
    for k in range(N):
        tau_max = limit[0] if shared_limit else limit[k]
        bracket = (
            weights[0] * _kernel_sum(e[k], inverse_sigmas) / (n * inverse_sigmas.shape[0])
            + weights[5]
        )
        if weights[1] != 0.0:
            bracket += (
                weights[1]
                * _kernel_sum(de[k], inverse_velocity_sigmas)
                / (n * inverse_velocity_sigmas.shape[0])
            )
        if weights[2] != 0.0:
            bracket -= weights[2] * _saturated_sum(tau[k], zero, 1.0, tau_max) / n
        if weights[3] != 0.0:
            bracket -= weights[3] * _saturated_sum(tau[k], previous[k], rate_factor, tau_max) / n
        if weights[4] != 0.0:
            bracket -= weights[4] * _saturated_sum(torsion[k], zero, 1.0, ones) / n
        out[k] = dt * bracket
