"""The fit: nonlinear least squares over (K, D, B), the rest solved linearly inside.

`fit_log` runs `scipy.optimize.least_squares` (trust region reflective, bounds a factor
`FitSettings.bound` around the nominal values) from the nominal model in `passes` rounds,
reweighting every accelerometer axis and joint equation by 1 / its residual standard
deviation between rounds. At the estimate: the Jacobian of every free parameter, the
covariance s^2 c (J^T J)^-1 (c: the residuals' long-run variance factor), the standard
errors, the condition number of the column-scaled Jacobian and the residuals on the
held-out end of the log. Parameters the log did not excite (`excitation`) are held at
their nominal values and the fit is repeated without them.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares
from threadpoolctl import threadpool_limits

from elastic_gym.identification.excitation import (
    Thresholds,
    TorsionBand,
    poorly_excited,
    torsion_band,
)
from elastic_gym.identification.link_side import BaseParameters
from elastic_gym.identification.problem import (
    ElasticJointProblem,
    Frozen,
    Measurements,
    SamplingModel,
    Signals,
    Terms,
    least_squares_solution,
)
from elastic_gym.identification.signals import Band, SpectralGrid
from elastic_gym.model import RobotModel


@dataclass(frozen=True)
class FitSettings:
    """Options of the fit (``band`` None: chosen from the log, see `choose_band`;
    ``decimation`` None: the coarsest grid the band allows; ``sampling`` None: the log's,
    `identify` reads it from the sidecar)."""

    band: Band | None = None
    decimation: int | None = None
    edge: float = 0.5
    holdout: float = 0.2
    coulomb_velocity: float = 0.01
    sampling: SamplingModel | None = None
    bound: float = 4.0
    passes: int = 2
    max_lag: int = 20
    thresholds: Thresholds = field(default_factory=Thresholds)
    base_parameters: bool = True


@dataclass(frozen=True)
class BaseParameterFit:
    """The base inertial parameters fitted to the log's link side."""

    names: tuple[str, ...]
    values: np.ndarray
    standard_errors: np.ndarray
    nominal: np.ndarray  # of the nominal model
    scaled: np.ndarray  # of the nominal model with the fitted mass scales
    condition_number: float


@dataclass
class FitResult:
    """What `fit_log` found (values in SI units).

    ``names``/``values``/``standard_errors``/``nominal``: every parameter (K, D, B per
    joint, then mass scales, viscous and Coulomb friction per joint, then the biases per
    accelerometer axis); a held parameter has its nominal value and a NaN standard error.
    """

    names: list[str]
    values: np.ndarray
    standard_errors: np.ndarray
    nominal: np.ndarray
    held: dict[str, str]  # name -> why it was held at its nominal value
    warnings: list[str]
    correlation: np.ndarray  # of the free parameters
    free_names: list[str]
    condition_number: float
    sigma_readings: np.ndarray  # residual std per accelerometer axis (m/s^2)
    sigma_link: np.ndarray  # residual std per joint's link equation (N m)
    holdout: dict[str, np.ndarray]  # rms and fit (%) per channel on the held-out part
    terms: Terms  # at the estimate, on the decimated grid
    bias: np.ndarray
    link: np.ndarray
    rows: np.ndarray
    holdout_rows: np.ndarray
    problem: ElasticJointProblem
    torsion: TorsionBand
    base: BaseParameterFit | None
    band: Band
    decimation: int
    seconds: float
    evaluations: int
    variance_factor: float

    def value(self, name: str) -> float:
        return float(self.values[self.names.index(name)])

    def group(self, prefix: str) -> tuple[np.ndarray, np.ndarray]:
        """(values, standard errors) of the parameters named ``prefix[...]``."""
        index = [i for i, name in enumerate(self.names) if name.startswith(prefix + "[")]
        return self.values[index], self.standard_errors[index]

    @property
    def time(self) -> np.ndarray:
        """Times (s from the log's start) of the decimated grid's samples."""
        grid = self.problem.measurements.grid
        return grid.indices * grid.dt


def noise_floor(x: np.ndarray, fs: float) -> np.ndarray:
    """Per column, the median power spectral density (unit^2/Hz) between 0.3 and 0.45 of
    the sampling rate (Welch, 1 s segments): the sensor's noise, where an arm has no
    motion left."""
    from scipy.signal import welch

    f, psd = welch(x - x.mean(axis=0), fs=fs, nperseg=min(len(x), round(fs)), axis=0)
    return np.median(psd[(f > 0.3 * fs) & (f < 0.45 * fs)], axis=0)


def choose_band(signals: Signals, model: RobotModel, margin: float = 1.25) -> Band:
    """The filter band where the log's information is: up to ``margin`` times the
    frequency at which the encoders' noise, through the motor side, starts to exceed the
    accelerometers' own noise.

    The deflection is (tau - B theta'') / (K + i w D), so white encoder noise of density
    S_theta enters the predicted link acceleration q'' = theta'' - delta'' with the gain
    B w^4 / K above the motor-side resonance (w^2 from theta'', w^2 from delta''), and a
    reading at lever L (m: the column norm of T_A) with L times that. It equals the
    accelerometer noise density S_a at w_j^4 = K_j sqrt(S_a) / (L_j B_j sqrt(S_theta_j));
    above the smallest w_j / 2 pi the fit would chase encoder noise (an errors-in-variables
    bias that grows fast with the band). At least 1.2 times the lowest torsion mode (and
    10 Hz), at most 0.2 f_s (noiseless sensors); the stop band starts 1.5 times higher."""
    fs = 1.0 / signals.dt
    s_a = float(np.mean(noise_floor(signals.acceleration, fs)))
    s_theta = noise_floor(signals.motor_position, fs)
    q = np.median(signals.motor_position, axis=0)
    T, _ = model.accelerometer_maps(q, np.zeros(model.n))
    lever = np.maximum(np.linalg.norm(T, axis=0), 1e-3)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = model.K * np.sqrt(s_a) / (lever * model.B * np.sqrt(s_theta))
    ratio = np.where(np.isnan(ratio), np.inf, ratio)  # noiseless sensors: no limit
    crossover = np.min(ratio**0.25) / (2.0 * np.pi)
    free, _ = model.natural_frequencies(q)
    lowest = max(10.0, 1.2 * float(np.min(free)) / (2.0 * np.pi))  # the first torsion mode
    pass_hz = float(np.clip(margin * crossover, min(lowest, 0.2 * fs), 0.2 * fs))
    return Band(pass_hz, 1.5 * pass_hz)


def _decimation(band: Band, dt: float) -> int:
    """The largest r whose Nyquist frequency 1 / (2 r h) lies 10 % above the stop band."""
    return max(1, int(np.floor(0.5 / (dt * band.stop_hz * 1.1))))


def _long_run_factor(residuals: np.ndarray, max_lag: int) -> float:
    """1 + 2 sum_k (1 - k / (L + 1)) rho_k (k = 1 .. L, Bartlett weights) averaged over
    channels: the variance of a mean of correlated residuals relative to independent
    ones (at least 1)."""
    r = residuals - residuals.mean(axis=0)
    var = np.sum(r**2, axis=0)
    var = np.where(var > 0, var, 1.0)
    factor = np.ones(r.shape[1])
    for k in range(1, min(max_lag, len(r) - 1) + 1):
        rho = np.sum(r[k:] * r[:-k], axis=0) / var
        factor += 2.0 * (1.0 - k / (max_lag + 1)) * rho
    return max(float(np.mean(factor)), 1.0)


def _fit_percent(measured: np.ndarray, residual: np.ndarray) -> np.ndarray:
    """100 (1 - |residual| / |measured - mean|) per channel (NRMSE fit)."""
    spread = np.linalg.norm(measured - measured.mean(axis=0), axis=0)
    return 100.0 * (1.0 - np.linalg.norm(residual, axis=0) / np.where(spread > 0, spread, 1.0))


def _covariance(
    jacobian: np.ndarray, weighted: np.ndarray, max_lag: int
) -> tuple[np.ndarray, float, float]:
    """(covariance, condition number of the column-scaled J, long-run factor)."""
    dof = max(weighted.size - jacobian.shape[1], 1)
    s2 = float(np.sum(weighted**2) / dof)
    factor = _long_run_factor(weighted, max_lag)
    norm = np.linalg.norm(jacobian, axis=0)
    norm = np.where(norm > 0, norm, 1.0)
    scaled = jacobian / norm
    singular = np.linalg.svd(scaled, compute_uv=False)
    condition = float(singular[0] / singular[-1]) if singular[-1] > 0 else float("inf")
    cov = s2 * factor * np.linalg.pinv(scaled.T @ scaled) / np.outer(norm, norm)
    return cov, condition, factor


class _Fit:
    """One fit of ``problem`` with the nonlinear parameters ``free`` (bool (3 n))."""

    def __init__(
        self, problem: ElasticJointProblem, rows: np.ndarray, settings: FitSettings
    ) -> None:
        self.problem, self.rows, self.settings = problem, rows, settings
        self.evaluations = 0

    def run(self, free: np.ndarray, start: np.ndarray) -> tuple:
        """(x, weights, indices of x at the bound, the exact terms at x) after
        ``settings.passes`` rounds."""
        problem, rows = self.problem, self.rows
        x = start.copy()
        x[~free] = 0.0
        terms = problem.terms(x)
        weights = _weights(problem, terms, rows)
        bound = np.log(self.settings.bound)

        def residual(z: np.ndarray, weights: tuple, frozen: Frozen) -> np.ndarray:
            full = x.copy()
            full[free] = z
            return problem.weighted(full, rows, weights, None, frozen)

        for _ in range(self.settings.passes):
            if not free.any():
                break
            frozen = problem.freeze(x, terms)
            solution = least_squares(
                residual,
                np.clip(x[free], -0.999 * bound, 0.999 * bound),
                args=(weights, frozen),
                bounds=(-bound, bound),
                method="trf",
                x_scale=1.0,
                diff_step=1e-7,
                xtol=1e-10,
                ftol=1e-10,
            )
            x[free] = solution.x
            self.evaluations += solution.nfev
            terms = problem.terms(x)
            weights = _weights(problem, terms, rows)
        at_bound = {int(i) for i in np.flatnonzero(free & (np.abs(x) > 0.99 * bound))}
        return x, weights, at_bound, terms


def fit_log(signals: Signals, model: RobotModel, settings: FitSettings | None = None) -> FitResult:
    """Identify K, D, B, the link mass scales, friction and accelerometer biases of the
    arm that wrote ``signals``, starting from ``model`` (the nominal model: kinematics,
    sensor mounts and the nominal inertial parameters the mass scales refer to).

    Linear algebra runs on one BLAS thread: the matrices are small, and threads fighting
    over busy cores cost more than they give."""
    with threadpool_limits(limits=1, user_api="blas"):
        return _fit_log(signals, model, settings or FitSettings())


def _fit_log(signals: Signals, model: RobotModel, settings: FitSettings) -> FitResult:
    start = time.perf_counter()
    T, n = len(signals.time), model.n
    band = settings.band or choose_band(signals, model)
    r = settings.decimation or _decimation(band, signals.dt)
    grid = SpectralGrid(T, signals.dt, band, r, settings.edge)
    measurements = Measurements.of(signals, grid, settings.sampling or SamplingModel())
    problem = ElasticJointProblem(model, measurements, settings.coulomb_velocity)
    split = round(T * (1.0 - settings.holdout))
    rows = np.flatnonzero(grid.interior_mask & (grid.indices < split))
    holdout_rows = np.flatnonzero(grid.interior_mask & (grid.indices >= split))
    if len(rows) < 10 * (6 * n + problem.n_readings):
        raise ValueError(
            f"the log is too short to identify: {len(rows)} samples on the "
            f"{1 / (r * signals.dt):g} Hz grid after leaving out {settings.edge} s at each "
            "end and the held-out part"
        )
    torsion = torsion_band(
        signals.acceleration, signals.motor_position, signals.dt, model, band.pass_hz
    )
    names = _names(problem, signals.sensor_names)
    held: dict[str, str] = {}
    warnings: list[str] = []
    if not torsion.excited:
        warnings.append(torsion.warning())
        for name in names[: 2 * n]:
            held[name] = "the log does not excite the joint torsion"
    fitter = _Fit(problem, rows, settings)
    x = np.zeros(3 * n)
    for _attempt in range(3):
        free = np.array([name not in held for name in names[: 3 * n]])
        problem.hold_link(np.array([name in held for name in names[3 * n : 6 * n]]))
        x, weights, at_bound, terms = fitter.run(free, x)
        estimate = _estimate(problem, x, rows, weights, settings, free, terms)
        values, se = _values(problem, x, estimate)
        bounded = {names[i] for i in at_bound}
        scale_torque = np.sqrt(np.mean(estimate["terms"].rhs[rows] ** 2, axis=0))
        scale_velocity = np.sqrt(np.mean(estimate["terms"].dq[rows] ** 2, axis=0))
        weak = poorly_excited(
            names,
            values,
            se,
            scale_torque,
            scale_velocity,
            model.spec.joint_names,
            bounded,
            settings.thresholds,
        )
        transmission = set(names[: 3 * n])
        new = {
            k: why
            for k, (why, hold) in weak.items()
            if hold and k in transmission and k not in held
        }
        if not new:
            break
        held.update(new)
    for name, (why, _) in weak.items():
        if name not in held:
            warnings.append(f"{name} is poorly identified: {why}")
    for name, why in held.items():
        if not why.startswith("the log does not excite"):
            warnings.append(f"{name} is not identifiable from this log ({why}): held at nominal")
    terms = estimate["terms"]
    bias, link = estimate["bias"], estimate["link"]
    held_readings, held_link = problem.residuals(terms, bias, link, holdout_rows)
    holdout = {
        "readings_rms": np.sqrt(np.mean(held_readings**2, axis=0)),
        "readings_fit": _fit_percent(measurements.acceleration[holdout_rows], held_readings),
        "link_rms": np.sqrt(np.mean(held_link**2, axis=0)),
        "link_fit": _fit_percent(terms.rhs[holdout_rows], held_link),
    }
    base = (
        _base_parameters(problem, terms, rows, weights, link, settings)
        if settings.base_parameters
        else None
    )
    return FitResult(
        names=names,
        values=values,
        standard_errors=se,
        nominal=_nominal(model, problem.n_readings),
        held=held,
        warnings=warnings,
        correlation=estimate["correlation"],
        free_names=[name for name, keep in zip(names, estimate["free"], strict=True) if keep],
        condition_number=estimate["condition"],
        sigma_readings=1.0 / weights[0],
        sigma_link=1.0 / weights[1],
        holdout=holdout,
        terms=terms,
        bias=bias,
        link=link,
        rows=rows,
        holdout_rows=holdout_rows,
        problem=problem,
        torsion=torsion,
        base=base,
        band=band,
        decimation=r,
        seconds=time.perf_counter() - start,
        evaluations=fitter.evaluations,
        variance_factor=estimate["factor"],
    )


def _names(problem: ElasticJointProblem, sensors: tuple[str, ...]) -> list[str]:
    return [
        *problem.nonlinear_names,
        *problem.link_names(),
        *(f"bias[{name}_{axis}]" for name in sensors for axis in "xyz"),
    ]


def _nominal(model: RobotModel, readings: int) -> np.ndarray:
    n = model.n
    return np.concatenate(
        [model.K, model.D, model.B, np.ones(n), np.zeros(2 * n), np.zeros(readings)]
    )


def _estimate(
    problem: ElasticJointProblem,
    x: np.ndarray,
    rows: np.ndarray,
    weights: tuple[np.ndarray, np.ndarray],
    settings: FitSettings,
    free_nonlinear: np.ndarray,
    terms: Terms,
) -> dict:
    """Linear parameters, covariance of the free parameters at x (``terms``: at x)."""
    bias, link = problem.solve_linear(terms, rows, weights)
    readings, link_side = problem.residuals(terms, bias, link, rows)
    jacobian = _jacobian(problem, x, (bias, link), rows, weights, terms)
    free = np.concatenate([free_nonlinear, problem.free_link, np.ones(len(bias), dtype=bool)])
    weighted = np.concatenate([readings * weights[0], link_side * weights[1]], axis=1)
    cov, condition, factor = _covariance(jacobian[:, free], weighted, settings.max_lag)
    se = np.full(len(free), np.nan)
    se[free] = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    d = np.where(se[free] > 0, se[free], 1.0)
    return {
        "terms": terms,
        "bias": bias,
        "link": link,
        "se": se,
        "free": free,
        "correlation": cov / np.outer(d, d),
        "condition": condition,
        "factor": factor,
    }


def _values(problem: ElasticJointProblem, x: np.ndarray, estimate: dict) -> tuple:
    """(values, standard errors) of every parameter in SI units."""
    n, se = problem.n, estimate["se"]
    K, D, B = problem.transmission(x)
    transmission = np.concatenate([K, D, B])
    values = np.concatenate([transmission, estimate["link"], estimate["bias"]])
    errors = np.concatenate([transmission * se[: 3 * n], se[3 * n :]])
    return values, errors


def _weights(
    problem: ElasticJointProblem, terms: Terms, rows: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """1 / residual std per accelerometer axis and per joint at the terms (unweighted
    solve of the linear parameters first)."""
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
    """(residuals, every parameter): nonlinear columns by central differences (linear
    parameters and Coulomb columns held), the linear ones exactly (a bias shifts its axis,
    a link parameter adds its column)."""
    N, s3, n = len(rows), problem.n_readings, problem.n
    frozen = problem.freeze(x, terms)
    step = 1e-5
    columns = []
    for i in range(len(x)):
        e = np.zeros_like(x)
        e[i] = step
        plus = problem.weighted(x + e, rows, weights, linear, frozen)
        minus = problem.weighted(x - e, rows, weights, linear, frozen)
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


def _base_parameters(
    problem: ElasticJointProblem,
    terms: Terms,
    rows: np.ndarray,
    weights: tuple[np.ndarray, np.ndarray],
    link: np.ndarray,
    settings: FitSettings,
) -> BaseParameterFit:
    """The base inertial parameters fitted to tau_J with the friction columns (one
    weighted linear least squares on the fit's rows)."""
    model, n = problem.model, problem.n
    base = BaseParameters.of(model)
    q, dq, ddq = (np.ascontiguousarray(a[rows]) for a in (terms.q, terms.dq, terms.ddq))
    Y = base.columns(model, q, dq, ddq)
    friction = terms.columns[rows][:, :, n:]
    A = np.concatenate([Y, friction], axis=2)
    w = weights[1]
    Aw = (A * w[None, :, None]).reshape(-1, A.shape[2])
    bw = (terms.rhs[rows] * w[None, :]).reshape(-1)
    solution = least_squares_solution(Aw, bw)
    residual = (bw - Aw @ solution).reshape(len(rows), n)
    cov, condition, _ = _covariance(Aw, residual, settings.max_lag)
    k = Y.shape[2]
    return BaseParameterFit(
        names=base.names,
        values=solution[:k],
        standard_errors=np.sqrt(np.clip(np.diag(cov)[:k], 0.0, None)),
        nominal=base.nominal(model),
        scaled=base.nominal(model, link[:n]),
        condition_number=condition,
    )
