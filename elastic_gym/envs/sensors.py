"""Sensor models: position encoders and 3-axis MEMS accelerometers.

Only these reach the observation. Noise is drawn from the environment's
``np_random`` (arm i of a batch: its own generator) so that a seed fixes every sample.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from typing import Annotated

import numpy as np
from numba import njit
from pydantic import AfterValidator, ConfigDict, StrictFloat

from elastic_gym.validation import StrictModel, validated

GRAVITY = 9.81


@functools.cache
def every_arm(n_arms: int) -> np.ndarray:
    """The indices 0 .. N - 1 (read-only, one array per N): given as ``arms``, the sensors
    measure every arm with whole-array operations instead of indexing with ``arms``."""
    arms = np.arange(n_arms)
    arms.flags.writeable = False
    return arms


def _within(low: float, high: float, zero: bool = True, why: str = "") -> AfterValidator:
    """A value in [low, high] (or 0 where allowed): limits beyond which a sensor setting
    would overflow the observation or mean nothing physical (``why`` is said)."""

    def check(value: float) -> float:
        if (value == 0 and zero) or low <= value <= high:
            return value
        allowed = f"{'0 or ' if zero else ''}a number in [{low:g}, {high:g}]"
        raise ValueError(f"must be {allowed}{why}, got {value!r}")

    return AfterValidator(check)


class EncoderConfig(StrictModel):
    """Position encoder: quantization ``resolution`` (rad, 0 = ideal) and Gaussian noise.

    ``None`` fields take the robot's defaults (``RobotSpec.encoder_resolution`` and
    ``encoder_noise_std``).
    """

    model_config = ConfigDict(frozen=True)

    resolution: Annotated[StrictFloat, _within(1e-12, 1.0)] | None = None
    noise_std: Annotated[StrictFloat, _within(1e-12, 1.0)] | None = None

    @classmethod
    def from_config(cls, config) -> EncoderConfig:
        return validated(cls, config, "encoder")


@njit(cache=True)
def _any_equal(values, value):
    """Whether any entry of ``values`` (1-D) equals ``value``."""
    for k in range(values.shape[0]):  # noqa: SIM110 - a loop numba compiles
        if values[k] == value:
            return True
    return False


class GaussianNoise:
    """Standard normal samples of ``size`` per arm and reading, each arm from its own
    generator, drawn ``BLOCK`` readings at a time.

    One generator call per arm every ``BLOCK`` readings instead of one per reading: the
    per-arm calls were a fifth of a 64-arm batch step. The samples of an arm depend only
    on its generator and on the readings it takes, as for an arm alone in its env; a
    reset starts a fresh block (the generator may have been reseeded).
    """

    BLOCK = 256

    def __init__(self, n_arms: int, size: int) -> None:
        self.block = np.zeros((n_arms, self.BLOCK, size))
        self.next = np.full(n_arms, self.BLOCK)  # index of the next sample; BLOCK: draw
        self.room = 0  # samples every arm has left in its block at least (0: look)

    def restart(self, arms: np.ndarray) -> None:
        self.next[arms] = self.BLOCK
        self.room = 0

    def snapshot(self) -> tuple[np.ndarray, np.ndarray]:
        """Copies of the drawn blocks and the next sample's index of every arm."""
        return self.block.copy(), self.next.copy()

    def restore(self, snapshot: tuple[np.ndarray, np.ndarray]) -> None:
        """The blocks and indices of a `snapshot`, copied in place."""
        self.block[...], self.next[...] = snapshot
        self.room = 0

    def refill(self, rngs: list[np.random.Generator]) -> None:
        """A fresh block for every arm whose block is used up (before a sample of each:
        `room` counts the samples down to the next look at the arms' blocks)."""
        if self.room > 0:
            self.room -= 1
            return
        if _any_equal(self.next, self.BLOCK):  # rare: once every BLOCK readings
            for arm in np.flatnonzero(self.next == self.BLOCK):
                self.block[arm] = rngs[arm].standard_normal(self.block.shape[1:])
                self.next[arm] = 0
        self.room = self.BLOCK - 1 - int(self.next.max())  # after this sample

    def draw(self, arms: np.ndarray, rngs: list[np.random.Generator]) -> np.ndarray:
        """One sample per arm of ``arms`` (``rngs[k]`` is the generator of ``arms[k]``)."""
        if arms is every_arm(len(self.next)):
            self.refill(rngs)
            sample = self.block[arms, self.next]
            self.next += 1
            return sample
        self.room = 0  # the arms' blocks no longer advance together
        following = self.next[arms]
        empty = following == self.BLOCK
        if empty.any():
            for k in np.flatnonzero(empty):
                arm = arms[k]
                self.block[arm] = rngs[k].standard_normal(self.block.shape[1:])
                self.next[arm] = 0
            following = self.next[arms]
        sample = self.block[arms, following]
        self.next[arms] = following + 1
        return sample


@njit(cache=True)
def _shared_readings(y, offset, std, block, following, bound, resolution, out):
    """Every arm's readings with one error model for all, as the numpy path gives them:
    out = quantize(clip(y + offset + std n, -bound, bound)) with n = block[k, following[k]]
    (``following`` advanced when std > 0), quantize(v) = rint(v / r) r for r > 0 (NaN kept
    by the clip, like numpy's maximum and minimum); ``offset`` None: no offset."""
    for k in range(y.shape[0]):
        for j in range(y.shape[1]):
            v = y[k, j]
            if offset is not None:
                v = v + offset[k, j]
            if std > 0.0:
                v = v + std * block[k, following[k], j]
            v = -bound if v < -bound else v
            v = bound if v > bound else v
            if resolution > 0.0:
                v = np.rint(v / resolution) * resolution
            out[k, j] = v
        if std > 0.0:
            following[k] += 1


def common(values: np.ndarray) -> float | None:
    """The value every arm shares (the fast path of a measurement), or None."""
    return float(values[0]) if len(values) and np.all(values == values[0]) else None


def _quantized(y: np.ndarray, resolution: np.ndarray, shared: float | None, arms) -> np.ndarray:
    """round(y / r) * r per row with arm k's resolution r_k (r = 0: unchanged)."""
    if shared is not None:
        return np.rint(y / shared) * shared if shared > 0.0 else np.array(y, dtype=float)
    r = resolution[arms, None]
    safe = np.where(r > 0.0, r, 1.0)
    return np.where(r > 0.0, np.rint(y / safe) * safe, y)  # rint: np.round to 0 decimals


def _add_noise(
    y: np.ndarray,
    std: np.ndarray,
    shared: float | None,
    noise: GaussianNoise,
    arms: np.ndarray,
    rngs: list,
) -> np.ndarray:
    """y + std_k n_k for the rows whose arm has std_k > 0 (only they draw); ``std`` (N,)."""
    if shared is not None:
        return y + shared * noise.draw(arms, rngs) if shared > 0.0 else y
    rows = np.flatnonzero(std[arms] > 0.0)
    if not len(rows):
        return y
    which = arms[rows]
    y = np.array(y, dtype=float)
    y[rows] = y[rows] + std[which, None] * noise.draw(which, [rngs[r] for r in rows])
    return y


def _compiled(y, offset, std: float, noise: GaussianNoise, rngs, bound: float, resolution: float):
    """Every arm's readings by `_shared_readings` (one error model, no filter)."""
    if std > 0.0:
        noise.refill(rngs)
    y = np.ascontiguousarray(y, dtype=np.float64)
    out = np.empty(y.shape)
    _shared_readings(y, offset, std, noise.block, noise.next, bound, resolution, out)
    return out


class Encoder:
    """Quantized, optionally noisy position measurement: round((x + n) / r) * r.

    Positions have a leading arm axis (N, n); arm i draws its noise from ``rngs[i]``.
    ``resolution`` and ``noise_std`` are one value for every arm or one per arm (N,); an
    arm without noise draws nothing.
    """

    def __init__(self, resolution, noise_std, n_joints: int, n_arms: int = 1) -> None:
        self.resolution = np.broadcast_to(np.asarray(resolution, dtype=float), (n_arms,)).copy()
        self.noise_std = np.broadcast_to(np.asarray(noise_std, dtype=float), (n_arms,)).copy()
        self.noise = GaussianNoise(n_arms, n_joints)
        self._shared = common(self.resolution), common(self.noise_std)

    def set(self, arm: int, resolution: float, noise_std: float) -> None:
        """Arm ``arm``'s own resolution and noise (e.g. drawn at a reset)."""
        self.resolution[arm], self.noise_std[arm] = resolution, noise_std
        self._shared = common(self.resolution), common(self.noise_std)

    @property
    def shared(self) -> tuple[float | None, float | None]:
        """(resolution, noise_std) when every arm has the same one (None where the arms
        differ): the compiled path of a measurement."""
        return self._shared

    def restart(self, arms: np.ndarray) -> None:
        """Fresh noise blocks for the arms (at a reset: their generators may be new)."""
        self.noise.restart(arms)

    def measure(
        self, position: np.ndarray, rngs: list[np.random.Generator], arms: np.ndarray
    ) -> np.ndarray:
        """Readings of the arms ``arms`` (rows of ``position``; ``rngs`` are theirs)."""
        resolution, noise_std = self._shared
        every = arms is every_arm(len(self.noise_std))
        if every and resolution is not None and noise_std is not None:
            return _compiled(position, None, noise_std, self.noise, rngs, np.inf, resolution)
        y = _add_noise(position, self.noise_std, noise_std, self.noise, arms, rngs)
        return _quantized(y, self.resolution, resolution, arms)


class AccelerometerConfig(StrictModel):
    """Error model of every 3-axis accelerometer of the arm.

    Defaults are those of a good industrial MEMS part sampled at the control rate:

    * ``noise_density`` 1.5e-3 m/s^2/sqrt(Hz) (~150 ug/sqrt(Hz)); the per-sample standard
      deviation is noise_density * sqrt(f_s / 2);
    * ``bias_std`` 0.02 m/s^2 (~2 mg): a constant bias per axis drawn at each reset;
    * ``range`` 16 g: readings saturate there (``info["acceleration_saturated"]``); at
      least g, which a sensor at rest reads;
    * ``cutoff_hz`` None: optional first-order low-pass (anti-aliasing) filter;
    * ``resolution`` None: optional output quantization (m/s^2).
    """

    model_config = ConfigDict(frozen=True)

    noise_density: Annotated[StrictFloat, _within(1e-12, 10.0)] = 1.5e-3
    bias_std: Annotated[StrictFloat, _within(1e-12, 100.0)] = 0.02
    range: Annotated[
        StrictFloat,
        _within(
            GRAVITY,
            1e9,
            zero=False,
            why=f" (at least g = {GRAVITY} m/s^2: a sensor at rest reads g)",
        ),
    ] = 16.0 * GRAVITY
    cutoff_hz: Annotated[StrictFloat, _within(1e-3, 1e6, zero=False)] | None = None
    resolution: Annotated[StrictFloat, _within(1e-9, 100.0)] | None = None

    @classmethod
    def from_config(cls, config) -> AccelerometerConfig:
        return validated(cls, config, "accelerometer")

    @classmethod
    def ideal(cls) -> AccelerometerConfig:
        """Noise-free, unbiased, unfiltered, practically unbounded (every field given, so
        that merged into another error model, e.g. by `per_arm`, it replaces it whole)."""
        return cls(noise_density=0.0, bias_std=0.0, range=1e9, cutoff_hz=None, resolution=None)


class AccelerometerArray:
    """Applies the error model of `AccelerometerConfig` to true specific forces.

    Readings have a leading arm axis (N, 3 n_sensors); each arm has its own bias and
    filter state and draws from its own generator. ``config``: one error model for every
    arm or a sequence of N (arm i's own); ``range`` of the whole array is the largest.
    """

    def __init__(
        self,
        config: AccelerometerConfig | Sequence[AccelerometerConfig],
        n_sensors: int,
        sample_time: float,
        n_arms: int = 1,
    ) -> None:
        configs = [config] * n_arms if isinstance(config, AccelerometerConfig) else list(config)
        self.config = max(configs, key=lambda c: c.range)
        self.size = 3 * n_sensors
        self.sample_time = sample_time
        self.sample_std, self.alpha = np.zeros(n_arms), np.zeros(n_arms)
        self.bias_std, self.range = np.zeros(n_arms), np.zeros(n_arms)
        self.resolution = np.zeros(n_arms)
        for arm, arm_config in enumerate(configs):
            self.set(arm, arm_config)
        self.bias = np.zeros((n_arms, self.size))
        self.noise = GaussianNoise(n_arms, self.size)
        self.filtered = np.zeros((n_arms, self.size))
        self.fresh = np.ones(n_arms, dtype=bool)  # the filter starts at the first reading

    def set(self, arm: int, config: AccelerometerConfig) -> None:
        """Arm ``arm``'s own error model (e.g. drawn at a reset)."""
        dt = self.sample_time
        self.sample_std[arm] = config.noise_density * np.sqrt(0.5 / dt)
        self.alpha[arm] = (
            float(np.exp(-2.0 * np.pi * config.cutoff_hz * dt))
            if config.cutoff_hz is not None
            else 0.0
        )
        self.bias_std[arm], self.range[arm] = config.bias_std, config.range
        self.resolution[arm] = config.resolution or 0.0
        self._shared = [
            common(x) for x in (self.sample_std, self.alpha, self.range, self.resolution)
        ]

    @property
    def shared(self) -> list[float | None]:
        """(per-sample noise std, filter coefficient, range, resolution) when every arm has
        the same one (None where the arms differ): the compiled path of a measurement."""
        return self._shared

    def snapshot(self) -> dict:
        """Copies of the arms' biases, filter states and noise blocks."""
        return {
            "bias": self.bias.copy(),
            "filtered": self.filtered.copy(),
            "fresh": self.fresh.copy(),
            "noise": self.noise.snapshot(),
        }

    def restore(self, snapshot: dict) -> None:
        """The biases, filter states and noise blocks of a `snapshot`, copied in place."""
        self.bias[...], self.filtered[...] = snapshot["bias"], snapshot["filtered"]
        self.fresh[...] = snapshot["fresh"]
        self.noise.restore(snapshot["noise"])

    def reset(self, arms: np.ndarray, rngs: list[np.random.Generator]) -> None:
        """New bias for the given arms (drawn from their generators), filters restarted."""
        for i in arms:
            self.bias[i] = self.bias_std[i] * rngs[i].standard_normal(self.size)
        self.fresh[arms] = True
        self.noise.restart(arms)

    def measure(
        self, specific_force: np.ndarray, rngs: list[np.random.Generator], arms: np.ndarray
    ) -> np.ndarray:
        """Readings of the arms ``arms`` (rows of ``specific_force``; ``rngs`` are theirs)."""
        every = arms is every_arm(len(self.bias))
        sample_std, alpha, limit, resolution = self._shared
        if (
            every
            and alpha == 0.0
            and sample_std is not None
            and limit is not None
            and resolution is not None
        ):
            return _compiled(
                specific_force, self.bias, sample_std, self.noise, rngs, limit, resolution
            )
        y = specific_force + (self.bias if every else self.bias[arms])
        y = _add_noise(y, self.sample_std, sample_std, self.noise, arms, rngs)
        if alpha is None or alpha > 0.0:
            a = self.alpha[arms, None] if alpha is None else alpha
            hold = (self.fresh[arms] | (self.alpha[arms] == 0.0))[:, None]
            y = np.where(hold, y, a * self.filtered[arms] + (1.0 - a) * y)
            self.filtered[arms] = y
            self.fresh[arms] = False
        bound = self.range[arms, None] if limit is None else limit
        y = np.minimum(np.maximum(y, -bound), bound)
        return _quantized(y, self.resolution, resolution, arms)
