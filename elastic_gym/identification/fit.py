"""The fit: nonlinear least squares over (K, D, B), the rest solved linearly inside.

`fit_log` runs `scipy.optimize.least_squares` (trust region reflective, bounds a factor
`FitSettings.bound` around the nominal values) on the weighted residuals of
`ElasticJointProblem`, from the nominal model, in `passes` rounds: after each round the
weight of every accelerometer axis and every joint's link equation is set to 1 / its
residual standard deviation (so that every channel counts by its own noise), and the
fit repeats from the last estimate. It then computes, at the estimate:

* the Jacobian J of the weighted residual with respect to every parameter (the
  nonlinear ones by central differences, the linear ones exactly);
* the covariance s^2 c (J^T J)^-1, s^2 the residual variance per degree of freedom and c
  the long-run variance factor 1 + 2 sum_k rho_k of the residuals' autocorrelation (the
  decimated residuals are not quite independent), and from it the standard errors;
* the condition number of J with its columns scaled to unit norm;
* the residuals on the held-out part of the log (the last `holdout` fraction), which
  the fit did not see.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from elastic_gym.identification.problem import (
    ElasticJointProblem,
    Measurements,
    SamplingModel,
    Signals,
    Terms,
)
from elastic_gym.identification.signals import Band, SpectralGrid
from elastic_gym.model import RobotModel


@dataclass(frozen=True)
class FitSettings:
    """Options of the fit (None: chosen from the log, see `choose_band`)."""

    band: Band | None = None
    decimation: int | None = None
    edge: float = 0.5
    holdout: float = 0.2
    coulomb_velocity: float = 0.01
    sampling: SamplingModel = field(default_factory=SamplingModel)
    bound: float = 4.0
    passes: int = 2
    max_lag: int = 20


@dataclass
class FitResult:
    """What `fit_log` found (values in SI units, per joint unless said otherwise)."""

    names: list[str]  # every parameter, in the order of ``values``
    values: np.ndarray
    standard_errors: np.ndarray
    nominal: np.ndarray
    correlation: np.ndarray
    condition_number: float
    sigma_readings: np.ndarray  # residual std per accelerometer axis (m/s^2)
    sigma_link: np.ndarray  # residual std per joint's link equation (N m)
    holdout: dict[str, np.ndarray]  # rms and fit (%) per channel on the held-out part
    terms: Terms  # at the estimate, on the decimated grid
    rows: np.ndarray
    holdout_rows: np.ndarray
    problem: ElasticJointProblem
    band: Band
    decimation: int
    seconds: float
    iterations: int
    variance_factor: float

    def value(self, name: str) -> float:
        return float(self.values[self.names.index(name)])

    def group(self, prefix: str) -> tuple[np.ndarray, np.ndarray]:
        """(values, standard errors) of the parameters named ``prefix[...]``."""
        index = [i for i, name in enumerate(self.names) if name.startswith(prefix + "[")]
        return self.values[index], self.standard_errors[index]


def choose_band(signals: Signals, model: RobotModel, dither_hz: float = 25.0) -> Band:
    """The filter band from the log: up to the highest frequency at which the
    accelerometers see more than noise (their power spectral density 30 times the floor
    measured between 0.6 and 0.9 of the Nyquist frequency), at least `dither_hz`,
    at most 0.3 of the sampling rate; the stop band starts 1.5 times higher."""
    from scipy.signal import welch

    fs = 1.0 / signals.dt
    y = signals.acceleration - signals.acceleration.mean(axis=0)
    f, psd = welch(y, fs=fs, nperseg=min(len(y), round(fs)), axis=0)
    total = psd.sum(axis=1)
    floor = np.median(total[(f > 0.3 * fs) & (f < 0.45 * fs)])
    above = np.flatnonzero((total > 30.0 * floor) & (f < 0.3 * fs))
    highest = f[above[-1]] if len(above) else dither_hz
    pass_hz = float(np.clip(highest, dither_hz, 0.3 * fs / 1.5))
    return Band(pass_hz, 1.5 * pass_hz)


def _decimation(band: Band, dt: float) -> int:
    """The largest r whose Nyquist frequency 1 / (2 r h) lies 10 % above the stop band."""
    return max(1, int(np.floor(0.5 / (dt * band.stop_hz * 1.1))))


def _long_run_factor(residuals: np.ndarray, max_lag: int) -> float:
    """1 + 2 sum_k rho_k (k = 1 .. max_lag, Bartlett weights) averaged over channels:
    the variance of a mean of correlated residuals relative to independent ones."""
    r = residuals - residuals.mean(axis=0)
    var = np.sum(r**2, axis=0)
    factor = np.ones(r.shape[1])
    for k in range(1, min(max_lag, len(r) - 1) + 1):
        rho = np.sum(r[k:] * r[:-k], axis=0) / var
        factor += 2.0 * (1.0 - k / (max_lag + 1)) * rho
    return max(float(np.mean(factor)), 1.0)


def _fit_percent(measured: np.ndarray, residual: np.ndarray) -> np.ndarray:
    """100 (1 - |residual| / |measured - mean|) per channel (NRMSE fit)."""
    spread = np.linalg.norm(measured - measured.mean(axis=0), axis=0)
    return 100.0 * (1.0 - np.linalg.norm(residual, axis=0) / np.where(spread > 0, spread, 1.0))


def fit_log(signals: Signals, model: RobotModel, settings: FitSettings | None = None) -> FitResult:
    """Identify K, D, B, the link mass scales, friction and accelerometer biases of the
    arm that wrote ``signals``, starting from ``model`` (the nominal model: kinematics,
    sensor mounts and the nominal inertial parameters the mass scales refer to)."""
    start = time.perf_counter()
    settings = settings or FitSettings()
    T = len(signals.time)
    band = settings.band or choose_band(signals, model)
    r = settings.decimation or _decimation(band, signals.dt)
    grid = SpectralGrid(T, signals.dt, band, r, settings.edge)
    measurements = Measurements.of(signals, grid, settings.sampling)
    problem = ElasticJointProblem(model, measurements, settings.coulomb_velocity)
    split = round(T * (1.0 - settings.holdout))
    rows = np.flatnonzero(grid.interior_mask & (grid.indices < split))
    holdout_rows = np.flatnonzero(grid.interior_mask & (grid.indices >= split))
    if len(rows) < 10 * (3 * model.n):
        raise ValueError(
            f"the log is too short to identify: {len(rows)} samples on the "
            f"{1 / (r * signals.dt):g} Hz grid after leaving out {settings.edge} s at each "
            "end and the held-out part"
        )
    n = model.n
    x = np.zeros(3 * n)
    weights = _weights(problem, x, rows)
    iterations = 0
    bound = np.log(settings.bound)
    for _ in range(settings.passes):
        coulomb = problem.coulomb_columns(x)
        solution = least_squares(
            problem.weighted,
            x,
            args=(rows, weights, None, coulomb),
            bounds=(-bound, bound),
            method="trf",
            x_scale=1.0,
            diff_step=1e-7,
            xtol=1e-10,
            ftol=1e-10,
        )
        x, iterations = solution.x, iterations + solution.nfev
        weights = _weights(problem, x, rows)
    terms = problem.terms(x)
    bias, link = problem.solve_linear(terms, rows, weights)
    readings, link_side = problem.residuals(terms, bias, link, rows)
    jacobian = _jacobian(problem, x, (bias, link), rows, weights, terms)
    weighted = np.concatenate([readings * weights[0], link_side * weights[1]], axis=1)
    dof = max(weighted.size - jacobian.shape[1], 1)
    s2 = float(np.sum(weighted**2) / dof)
    factor = _long_run_factor(weighted, settings.max_lag)
    column_norm = np.linalg.norm(jacobian, axis=0)
    column_norm = np.where(column_norm > 0, column_norm, 1.0)
    scaled = jacobian / column_norm
    singular = np.linalg.svd(scaled, compute_uv=False)
    condition = float(singular[0] / singular[-1]) if singular[-1] > 0 else float("inf")
    inverse = np.linalg.pinv(scaled.T @ scaled)
    cov = s2 * factor * inverse / np.outer(column_norm, column_norm)
    se_all = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    d = np.where(se_all > 0, se_all, 1.0)
    correlation = cov / np.outer(d, d)

    K, D, B = problem.transmission(x)
    values = np.concatenate([K, D, B, link, bias])
    se = np.concatenate([np.concatenate([K, D, B]) * se_all[: 3 * n], se_all[3 * n :]])
    nominal = np.concatenate(
        [model.K, model.D, model.B, np.ones(n), np.zeros(2 * n), np.zeros(len(bias))]
    )
    names = [
        *problem.nonlinear_names,
        *problem.link_names(),
        *(f"bias[{name}_{axis}]" for name in signals.sensor_names for axis in "xyz"),
    ]
    held_readings, held_link = problem.residuals(terms, bias, link, holdout_rows)
    holdout = {
        "readings_rms": np.sqrt(np.mean(held_readings**2, axis=0)),
        "readings_fit": _fit_percent(measurements.acceleration[holdout_rows], held_readings),
        "link_rms": np.sqrt(np.mean(held_link**2, axis=0)),
        "link_fit": _fit_percent(terms.rhs[holdout_rows], held_link),
    }
    return FitResult(
        names=names,
        values=values,
        standard_errors=se,
        nominal=nominal,
        correlation=correlation,
        condition_number=condition,
        sigma_readings=1.0 / weights[0],
        sigma_link=1.0 / weights[1],
        holdout=holdout,
        terms=terms,
        rows=rows,
        holdout_rows=holdout_rows,
        problem=problem,
        band=band,
        decimation=r,
        seconds=time.perf_counter() - start,
        iterations=iterations,
        variance_factor=factor,
    )


def _weights(
    problem: ElasticJointProblem, x: np.ndarray, rows: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """1 / residual std per accelerometer axis and per joint at x (unweighted solve of the
    linear parameters first)."""
    terms = problem.terms(x)
    ones = (np.ones(problem.n_readings), np.ones(problem.n))
    bias, link = problem.solve_linear(terms, rows, ones)
    readings, link_side = problem.residuals(terms, bias, link, rows)
    floor = 1e-12
    return (
        1.0 / np.maximum(readings.std(axis=0), floor),
        1.0 / np.maximum(link_side.std(axis=0), floor),
    )


def _jacobian(
    problem: ElasticJointProblem,
    x: np.ndarray,
    linear: tuple[np.ndarray, np.ndarray],
    rows: np.ndarray,
    weights: tuple[np.ndarray, np.ndarray],
    terms: Terms,
) -> np.ndarray:
    """(residuals, parameters): nonlinear columns by central differences (linear
    parameters held), the linear ones exactly (a bias shifts its axis, a link parameter
    adds its column)."""
    bias, link = linear
    N, s3, n = len(rows), problem.n_readings, problem.n
    coulomb = terms.columns[:, np.arange(n), 2 * n + np.arange(n)]
    step = 1e-5
    columns = []
    for i in range(len(x)):
        e = np.zeros_like(x)
        e[i] = step
        plus = problem.weighted(x + e, rows, weights, linear, coulomb)
        minus = problem.weighted(x - e, rows, weights, linear, coulomb)
        columns.append((plus - minus) / (2.0 * step))
    J_nl = np.stack(columns, axis=1)
    J_bias = np.zeros((N * s3 + N * n, s3))
    for c in range(s3):
        block = np.zeros((N, s3))
        block[:, c] = -weights[0][c]
        J_bias[: N * s3, c] = block.ravel()
    link_block = -(terms.columns[rows] * weights[1][None, :, None]).reshape(N * n, -1)
    J_link = np.vstack([np.zeros((N * s3, link_block.shape[1])), link_block])
    return np.hstack([J_nl, J_link, J_bias])
