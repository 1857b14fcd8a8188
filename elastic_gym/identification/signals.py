"""Zero-phase low-pass filtering, exact derivatives and decimation of sampled signals.

Every term of the fit goes through one zero-phase filter applied in the frequency domain:
the log is padded (odd reflection about its end points, as `scipy.signal.filtfilt` pads)
to a fast FFT length, X(f) is multiplied by a real raised-cosine low-pass H(f) (no delay),
and the k-th derivative is (i 2 pi f)^k X(f), exact for the band-limited signal. A torque
held for one sample (zero-order hold) is the band-limited staircase: its spectrum is the
samples' times exp(-i pi f h) sinc(f h). The filtered signals have no content above the
stop band and are sampled exactly on a coarser grid (an inverse FFT of the first bins):
the residuals are evaluated there. The first and last `edge` seconds are left out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.fft as sfft

WIDE_BAND = 0.3  # of the Nyquist frequency: what the Coulomb column sees of the motion


def raised_cosine_lowpass(freqs: np.ndarray, pass_hz: float, stop_hz: float) -> np.ndarray:
    """H(f): 1 for f <= pass_hz, 0.5 (1 + cos(pi (f - pass_hz) / (stop_hz - pass_hz)))
    between, 0 for f >= stop_hz."""
    H = np.ones_like(freqs, dtype=float)
    between = (freqs > pass_hz) & (freqs < stop_hz)
    H[between] = 0.5 * (1.0 + np.cos(np.pi * (freqs[between] - pass_hz) / (stop_hz - pass_hz)))
    H[freqs >= stop_hz] = 0.0
    return H


@dataclass(frozen=True)
class Band:
    """The zero-phase filter's pass band edge and stop frequency (Hz)."""

    pass_hz: float
    stop_hz: float

    def __post_init__(self) -> None:
        if not 0.0 < self.pass_hz < self.stop_hz:
            raise ValueError(
                f"filter band: need 0 < pass_hz < stop_hz, got {self.pass_hz}, {self.stop_hz}"
            )


def _odd_extension(x: np.ndarray, front: int, back: int) -> np.ndarray:
    """x extended by ``front`` and ``back`` samples, odd reflections about its end points
    (held constant where the log is shorter than the padding), the outer half of each
    pad tapered (raised cosine) to the mean of the two outermost values, so that the FFT's
    periodic extension joins smoothly too."""
    T = len(x)
    head_index = np.minimum(np.arange(front, 0, -1), T - 1)
    tail_index = np.maximum(T - 2 - np.arange(back), 0)
    head = 2.0 * x[0] - x[head_index]
    tail = 2.0 * x[-1] - x[tail_index]
    out = np.concatenate([head, x, tail])
    centre = 0.5 * (out[0] + out[-1])
    window = np.ones(len(out))
    for start, size, rising in ((0, front // 2, True), (len(out) - back // 2, back // 2, False)):
        if size:
            ramp = 0.5 * (1.0 - np.cos(np.pi * (np.arange(size) + 0.5) / size))
            window[start : start + size] = ramp if rising else ramp[::-1]
    shape = (-1,) + (1,) * (out.ndim - 1)
    return centre + (out - centre) * window.reshape(shape)


class SpectralGrid:
    """The frequency grid of one log: filtering, derivatives and decimated samples.

    Args:
        n_samples: samples T of the log.
        dt: sample period h (s).
        band: the zero-phase low-pass.
        decimation: r; the residual grid has period r h (``band.stop_hz`` must lie below
            its Nyquist frequency 1 / (2 r h)).
        edge: seconds left out at each end of the log (the filter's transients).
    """

    def __init__(
        self, n_samples: int, dt: float, band: Band, decimation: int, edge: float = 0.5
    ) -> None:
        r = int(decimation)
        if r < 1:
            raise ValueError(f"decimation must be >= 1, got {decimation}")
        nyquist = 0.5 / (r * dt)
        if band.stop_hz >= nyquist:
            raise ValueError(
                f"the filter's stop frequency {band.stop_hz:g} Hz must lie below the "
                f"decimated grid's Nyquist frequency {nyquist:g} Hz (lower decimation)"
            )
        self.n_samples, self.dt, self.band, self.decimation = n_samples, dt, band, r
        pad = r * int(np.ceil(edge / dt / r))  # a multiple of r: decimated samples align
        coarse = sfft.next_fast_len(-(-(n_samples + 2 * pad) // r), real=True)
        self.pad, self.length = pad, r * coarse
        self.freqs = np.fft.rfftfreq(self.length, dt)
        self.omega = 2.0 * np.pi * self.freqs
        self.gain = raised_cosine_lowpass(self.freqs, band.pass_hz, band.stop_hz)
        wide = max(band.stop_hz, WIDE_BAND * 0.5 / dt)
        self.wide_gain = raised_cosine_lowpass(self.freqs, wide, 1.5 * wide)
        self.bins = coarse // 2 + 1  # the bins the decimated grid represents
        self._jw = 1j * self.omega
        edge_samples = max(round(edge / dt), 0)
        # decimated samples (original indices) and the interior ones
        self.indices = np.arange(0, n_samples, r)
        self.edge_samples = edge_samples
        self.interior_mask = (self.indices >= edge_samples) & (
            self.indices < n_samples - edge_samples
        )

    @property
    def jw(self) -> np.ndarray:
        """i omega on the grid's bins (rad/s)."""
        return self._jw

    def spectrum(
        self, x: np.ndarray, hold: bool = False, delay: float = 0.0, gain: np.ndarray | None = None
    ) -> np.ndarray:
        """Filtered spectrum (bins, channels) of the samples ``x`` (T, channels).

        ``hold``: the samples are a zero-order-hold command (each value held for one
        sample period); ``delay`` (s): the signal acts that much later than logged;
        ``gain``: another filter than the band's (e.g. `above_band`).
        """
        x = np.asarray(x, dtype=float)
        flat = x.reshape(len(x), -1)
        extended = _odd_extension(flat, self.pad, self.length - self.n_samples - self.pad)
        gain = self.gain if gain is None else gain
        X = sfft.rfft(extended, axis=0, workers=-1) * gain[:, None]
        shift = delay + (0.5 * self.dt if hold else 0.0)
        if shift:
            X *= np.exp(-self._jw * shift)[:, None]
        if hold:
            X *= np.sinc(self.freqs * self.dt)[:, None]
        return X

    @property
    def above_band(self) -> np.ndarray:
        """The band-pass from the band's stop frequency to `WIDE_BAND` of the Nyquist
        frequency: the complement of the band in the wide band."""
        return self.wide_gain - self.gain

    def integral(self, X: np.ndarray) -> np.ndarray:
        """The spectrum of the integral of a signal without content at 0 Hz."""
        jw = self._jw[: len(X)]
        return np.where(jw[:, None] != 0, X / np.where(jw == 0, 1.0, jw)[:, None], 0.0)

    def derivative(self, X: np.ndarray, order: int) -> np.ndarray:
        """The spectrum of the ``order``-th time derivative (``X``: the first bins of a
        spectrum, or all)."""
        return X * (self._jw[: len(X)] ** order)[:, None] if order else X

    def full(self, X: np.ndarray, order: int = 0) -> np.ndarray:
        """The filtered signal (or its derivative) at every sample of the log (T, channels);
        ``X`` may hold the first bins only (the others are zero)."""
        x = sfft.irfft(self.derivative(X, order), n=self.length, axis=0, workers=-1)
        return x[self.pad : self.pad + self.n_samples]

    def decimated(self, X: np.ndarray, order: int = 0) -> np.ndarray:
        """The filtered signal (or its derivative) at the decimated samples
        (``indices``), exact for the band-limited signal (an inverse FFT of the bins below
        the coarse Nyquist frequency)."""
        r = self.decimation
        coarse = self.length // r
        Y = self.derivative(X[: self.bins], order)
        x = sfft.irfft(Y, n=coarse, axis=0, workers=-1) / r
        start = self.pad // r
        return x[start : start + len(self.indices)]

    def filtered(self, x: np.ndarray) -> np.ndarray:
        """``x`` (T, channels) through the zero-phase filter, at every sample."""
        return self.full(self.spectrum(x))
