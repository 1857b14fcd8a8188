"""The `fourier` task: a periodic Fourier-series reference and a torque dither, the
identification excitation of Swevers et al. (1997).

q_d(t) = q0 + w(t) Σ_l [a_l sin(l ω t) + b_l cos(l ω t)], ω = 2π / period, per joint, with
every derivative up to the fourth analytic (INVDYN needs q_d⁽⁴⁾); w(t) fades the motion in
over `ramp` seconds with the C⁴ timing law of the tracking task, so that the arm starts at
rest at q0. The open-loop torque added to the action is the dither w(t) Σ_m A_j sin(2π ν_m t
+ φ_mj): `sines` frequencies ν_m log-uniform in `band` (Hz), random phases (both drawn from
the dither's own `seed`), amplitudes A_j = rms_j √(2/M) for an RMS of `rms` times each
joint's torque limit: it excites the torsion modes the slow reference cannot reach.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from math import comb
from typing import Annotated

import numpy as np
from numba import njit
from pydantic import Field, StrictInt

from elastic_gym.envs.task_base import REFERENCE_ORDER, Task, per_joint_option
from elastic_gym.envs.trajectories import timing_coefficients
from elastic_gym.validation import (
    Finite,
    FiniteNumbers,
    NonNegativeFinite,
    PositiveFinite,
    PositiveNumbers,
    StrictModel,
    ordered,
    shaped,
)

DEFAULT_HARMONICS = 5
DEFAULT_FILL = 0.6  # of the workspace box's half-width


class DitherOptions(StrictModel):
    """The torque dither (module docstring): `band` (Hz), `rms` (fraction of each joint's
    torque limit, one or one per joint), `sines` (M), `seed`."""

    band: tuple[PositiveFinite, PositiveFinite] = (2.0, 25.0)
    rms: PositiveNumbers = 0.03
    sines: Annotated[StrictInt, Field(ge=1, le=1000)] = 40
    seed: Annotated[StrictInt, Field(ge=0)] = 0

    def model_post_init(self, context: object) -> None:
        ordered(*self.band, names=("band[0]", "band[1]"))


class FourierOptions(StrictModel):
    """Options of `FourierTask` (module docstring): `period` (s), `offset` (q0, rad;
    default the workspace box's centre), `sine` and `cosine` (rad, one row of n per
    harmonic; default equal amplitudes filling 60 % of the box), `ramp` (s), `dither`."""

    period: PositiveFinite = 10.0
    offset: FiniteNumbers | None = None
    sine: list[list[Finite]] | None = None
    cosine: list[list[Finite]] | None = None
    ramp: NonNegativeFinite = 1.0
    dither: DitherOptions | None = None


def dither_parameters(
    options: DitherOptions, torque_limit: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(frequencies (M,) in Hz, phases (M, n), amplitudes (n,) in N m) of a dither."""
    rng = np.random.default_rng(options.seed)
    low, high = options.band
    M, n = options.sines, len(torque_limit)
    frequencies = np.exp(rng.uniform(np.log(low), np.log(high), M))
    phases = rng.uniform(0.0, 2.0 * np.pi, (M, n))
    rms = np.broadcast_to(np.asarray(options.rms, dtype=float), (n,)) * torque_limit
    return frequencies, phases, rms * np.sqrt(2.0 / M)


def fourier_series(
    t: np.ndarray, sine: np.ndarray, cosine: np.ndarray, period: float, order: int
) -> np.ndarray:
    """Σ_l a_l sin(l ω t) + b_l cos(l ω t) and its derivatives: (len(t), order + 1, n)."""
    t = np.asarray(t, dtype=float)
    omega = 2.0 * np.pi / period * np.arange(1, len(sine) + 1)  # (L,)
    phase = np.multiply.outer(t, omega)  # (T, L)
    out = np.empty((len(t), order + 1, sine.shape[1]))
    for k in range(order + 1):
        shift = k * np.pi / 2.0  # d/dt sin(x) = sin(x + π/2) ω
        scale = omega**k
        sin, cos = np.sin(phase + shift) * scale, np.cos(phase + shift) * scale
        out[:, k] = sin @ sine + cos @ cosine
    return out


_LAW = timing_coefficients(REFERENCE_ORDER)  # rows: d^k s / du^k, ascending powers of u
_BINOMIAL = np.array([[comb(k, i) for i in range(REFERENCE_ORDER + 1)] for k in range(5)], float)


@njit(cache=True)
def _window(t, ramp, law, w):
    """w(t) and its derivatives into `w`: the timing law over [0, ramp], 1 after."""
    w[:] = 0.0
    if ramp <= 0.0:
        w[0] = 1.0
        return
    u = min(max(t / ramp, 0.0), 1.0)
    scale = 1.0
    for d in range(w.shape[0]):
        value = 0.0
        for p in range(law.shape[1] - 1, -1, -1):  # Horner
            value = value * u + law[d, p]
        w[d] = value * scale
        scale /= ramp


@njit(cache=True)
def _reference_kernel(t, sine, cosine, omega, ramp, law, offset, out):
    """q_d^(d) = Σ_i C(d, i) w^(i) f^(d-i) (Leibniz) at each time, f^(d) = Σ_l (l ω)^d
    (a_l sin(l ω t + d π/2) + b_l cos(l ω t + d π/2))."""
    K, n = out.shape[1], out.shape[2]
    f = np.empty((K, n))
    w = np.empty(K)
    for k in range(t.shape[0]):
        f[:] = 0.0
        for l in range(sine.shape[0]):
            x = omega[l] * t[k]
            s, c = np.sin(x), np.cos(x)
            power = 1.0
            for d in range(K):
                m = d % 4  # sin(x + d π/2), cos(x + d π/2)
                S = s if m == 0 else (c if m == 1 else (-s if m == 2 else -c))
                C = c if m == 0 else (-s if m == 1 else (-c if m == 2 else s))
                for j in range(n):
                    f[d, j] += power * (sine[l, j] * S + cosine[l, j] * C)
                power *= omega[l]
        _window(t[k], ramp, law, w)
        for d in range(K):
            for j in range(n):
                total = 0.0
                for i in range(d + 1):
                    total += _BINOMIAL[d, i] * w[i] * f[d - i, j]
                out[k, d, j] = total
        for j in range(n):
            out[k, 0, j] += offset[j]


@njit(cache=True)
def _dither_kernel(t, frequencies, phases, amplitudes, ramp, law, out):
    """w(t) A_j Σ_m sin(2π ν_m t + φ_mj) at each time."""
    w = np.empty(1)
    for k in range(t.shape[0]):
        _window(t[k], ramp, law[:1], w)
        for j in range(out.shape[1]):
            total = 0.0
            for m in range(frequencies.shape[0]):
                total += np.sin(2.0 * np.pi * frequencies[m] * t[k] + phases[m, j])
            out[k, j] = w[0] * amplitudes[j] * total


@dataclass
class FourierTask(Task):
    """Follow a Fourier-series reference with a torque dither (module docstring)."""

    options: FourierOptions = field(default_factory=FourierOptions)
    options_model = FourierOptions

    def __post_init__(self) -> None:
        self.name = "fourier"
        n, o = self.spec.n_joints, self.options
        half = 0.5 * (self.high - self.low)
        centre = 0.5 * (self.low + self.high)
        self.offset = centre if o.offset is None else per_joint_option(o.offset, n, "offset")
        if (o.sine is None) != (o.cosine is None):
            raise ValueError("task_options: give both sine and cosine, or neither")
        if o.sine is None:
            amplitude = DEFAULT_FILL * half / DEFAULT_HARMONICS
            self.sine = np.tile(amplitude, (DEFAULT_HARMONICS, 1))
            self.cosine = np.zeros_like(self.sine)
        else:
            self.sine = shaped(o.sine, (None, n), "task_options.sine")
            self.cosine = shaped(o.cosine, (len(self.sine), n), "task_options.cosine")
        self.period, self.ramp = o.period, o.ramp
        bound = np.sqrt(self.sine**2 + self.cosine**2).sum(axis=0)  # max |Σ_l ...| per joint
        if np.any(self.offset - bound < self.low) or np.any(self.offset + bound > self.high):
            raise ValueError(
                f"task_options: the reference offset ± its amplitude bound {bound.round(4)} "
                f"leaves the workspace box [{self.low}, {self.high}]"
            )
        limit = np.asarray(self.spec.torque_limit, dtype=float)
        self.dither = None
        if o.dither is not None:
            self.dither = dither_parameters(o.dither, limit)

    def reset_arm(self, arm: int, rng: np.random.Generator) -> np.ndarray:
        return self.offset.copy()

    def configured_points(self) -> dict[str, np.ndarray]:
        return {"offset": np.atleast_2d(self.offset)}

    def reference_at(self, t: np.ndarray) -> np.ndarray:
        """q_d .. q_d⁽⁴⁾ at the times `t`: (len(t), 5, n)."""
        t = np.array(t, dtype=float, ndmin=1)  # a copy: writeable, as the kernel's signature
        out = np.empty((len(t), REFERENCE_ORDER + 1, self.spec.n_joints))
        omega = 2.0 * np.pi / self.period * np.arange(1.0, len(self.sine) + 1.0)
        _reference_kernel(t, self.sine, self.cosine, omega, self.ramp, _LAW, self.offset, out)
        return out

    def reference(self, t: np.ndarray, arms: slice | np.ndarray = slice(None)) -> np.ndarray:
        times = np.broadcast_to(np.asarray(t, dtype=float), (self.n_arms,))[arms]
        return self.reference_at(times)

    def dither_at(self, t: np.ndarray) -> np.ndarray:
        """The dither torque at the times `t`: (len(t), n) (zeros without a dither)."""
        t = np.array(t, dtype=float, ndmin=1)  # a copy: writeable, as the kernel's signature
        out = np.zeros((len(t), self.spec.n_joints))
        if self.dither is not None:
            _dither_kernel(t, *self.dither, self.ramp, _LAW, out)
        return out

    def external_torque(self, t: np.ndarray, q: np.ndarray) -> np.ndarray | None:
        if self.dither is None:
            return None
        return self.dither_at(np.broadcast_to(np.asarray(t, dtype=float), (len(q),)))
