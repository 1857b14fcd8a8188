"""Sensor models: position encoders and 3-axis MEMS accelerometers.

Only these reach the observation. Noise is drawn from the environment's
``np_random`` (arm i of a batch: its own generator) so that a seed fixes every sample.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from elastic_gym.validation import config_from

GRAVITY = 9.81


def _check_range(
    owner: str,
    key: str,
    value,
    low: float,
    high: float,
    zero: bool = True,
    none: bool = True,
    why: str = "",
) -> None:
    """``value`` in [low, high] (or 0 / None where allowed): limits beyond which a sensor
    setting would overflow the observation or mean nothing physical (``why`` is said)."""
    if value is None and none:
        return
    number = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(
        value, bool
    )
    if number and ((value == 0 and zero) or low <= value <= high):
        return
    allowed = f"{'0 or ' if zero else ''}a number in [{low:g}, {high:g}]"
    raise ValueError(f"{owner}.{key} must be {allowed}{why}, got {value!r}")


@dataclass(frozen=True)
class EncoderConfig:
    """Position encoder: quantization ``resolution`` (rad, 0 = ideal) and Gaussian noise.

    ``None`` fields take the robot's defaults (``RobotSpec.encoder_resolution`` and
    ``encoder_noise_std``).
    """

    resolution: float | None = None
    noise_std: float | None = None

    def __post_init__(self) -> None:
        _check_range("encoder", "resolution", self.resolution, 1e-12, 1.0)
        _check_range("encoder", "noise_std", self.noise_std, 1e-12, 1.0)

    @classmethod
    def from_config(cls, config) -> EncoderConfig:
        return config_from(cls, config, "encoder")


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

    def restart(self, arms: np.ndarray) -> None:
        self.next[arms] = self.BLOCK

    def draw(self, arms: np.ndarray, rngs: list[np.random.Generator]) -> np.ndarray:
        """One sample per arm of ``arms`` (``rngs[k]`` is the generator of ``arms[k]``)."""
        for k in np.flatnonzero(self.next[arms] == self.BLOCK):
            arm = arms[k]
            self.block[arm] = rngs[k].standard_normal(self.block.shape[1:])
            self.next[arm] = 0
        sample = self.block[arms, self.next[arms]]
        self.next[arms] += 1
        return sample


class Encoder:
    """Quantized, optionally noisy position measurement: round((x + n) / r) * r.

    Positions have a leading arm axis (N, n); arm i draws its noise from ``rngs[i]``.
    """

    def __init__(self, resolution: float, noise_std: float, n_joints: int, n_arms: int = 1) -> None:
        self.resolution = float(resolution)
        self.noise_std = float(noise_std)
        self.noise = GaussianNoise(n_arms if self.noise_std > 0.0 else 0, n_joints)

    def measure(
        self, position: np.ndarray, rngs: list[np.random.Generator], arms: np.ndarray
    ) -> np.ndarray:
        """Readings of the arms ``arms`` (rows of ``position``; ``rngs`` are theirs)."""
        y = position
        if self.noise_std > 0.0:
            y = y + self.noise_std * self.noise.draw(arms, rngs)
        if self.resolution > 0.0:
            return np.round(y / self.resolution) * self.resolution
        return np.array(y, dtype=float)


@dataclass(frozen=True)
class AccelerometerConfig:
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

    noise_density: float = 1.5e-3
    bias_std: float = 0.02
    range: float = 16.0 * GRAVITY
    cutoff_hz: float | None = None
    resolution: float | None = None

    def __post_init__(self) -> None:
        _check_range("accelerometer", "noise_density", self.noise_density, 1e-12, 10.0, none=False)
        _check_range("accelerometer", "bias_std", self.bias_std, 1e-12, 100.0, none=False)
        _check_range("accelerometer", "resolution", self.resolution, 1e-9, 100.0)
        _check_range(
            "accelerometer",
            "range",
            self.range,
            GRAVITY,
            1e9,
            zero=False,
            none=False,
            why=f" (at least g = {GRAVITY} m/s^2: a sensor at rest reads g)",
        )
        _check_range("accelerometer", "cutoff_hz", self.cutoff_hz, 1e-3, 1e6, zero=False)

    @classmethod
    def from_config(cls, config) -> AccelerometerConfig:
        return config_from(cls, config, "accelerometer")

    @classmethod
    def ideal(cls) -> AccelerometerConfig:
        """Noise-free, unbiased, unfiltered, practically unbounded."""
        return cls(noise_density=0.0, bias_std=0.0, range=1e9)


class AccelerometerArray:
    """Applies the error model of :class:`AccelerometerConfig` to true specific forces.

    Readings have a leading arm axis (N, 3 n_sensors); each arm has its own bias and
    filter state and draws from its own generator.
    """

    def __init__(
        self, config: AccelerometerConfig, n_sensors: int, sample_time: float, n_arms: int = 1
    ) -> None:
        self.config = config
        self.size = 3 * n_sensors
        self.sample_std = config.noise_density * np.sqrt(0.5 / sample_time)
        self.alpha = (
            float(np.exp(-2.0 * np.pi * config.cutoff_hz * sample_time))
            if config.cutoff_hz is not None
            else 0.0
        )
        self.bias = np.zeros((n_arms, self.size))
        self.noise = GaussianNoise(n_arms if self.sample_std > 0.0 else 0, self.size)
        self.filtered = np.zeros((n_arms, self.size))
        self.fresh = np.ones(n_arms, dtype=bool)  # the filter starts at the first reading

    def reset(self, arms: np.ndarray, rngs: list[np.random.Generator]) -> None:
        """New bias for the given arms (drawn from their generators), filters restarted."""
        for i in arms:
            self.bias[i] = self.config.bias_std * rngs[i].standard_normal(self.size)
        self.fresh[arms] = True
        if self.sample_std > 0.0:
            self.noise.restart(arms)

    def measure(
        self, specific_force: np.ndarray, rngs: list[np.random.Generator], arms: np.ndarray
    ) -> np.ndarray:
        """Readings of the arms ``arms`` (rows of ``specific_force``; ``rngs`` are theirs)."""
        y = specific_force + self.bias[arms]
        if self.sample_std > 0.0:
            y = y + self.sample_std * self.noise.draw(arms, rngs)
        if self.alpha > 0.0:
            fresh = self.fresh[arms][:, None]
            y = np.where(fresh, y, self.alpha * self.filtered[arms] + (1.0 - self.alpha) * y)
            self.filtered[arms] = y
            self.fresh[arms] = False
        limit = self.config.range
        y = np.minimum(np.maximum(y, -limit), limit)
        if self.config.resolution:
            y = np.round(y / self.config.resolution) * self.config.resolution
        return np.array(y, dtype=float)
