"""Extended Kalman filter for elastic-joint arms with exponential data weighting.

After Abdeetedal (report on Lightcap & Banks, IEEE TCST 2010), eqs. (1)-(18), on the
models (1)/(2) of De Luca et al. State x = (theta, q, theta', q'), input tau held over
the period T.

* Dynamics x' = f(x, u) + G(x) w, eq. (4), by the compiled forward dynamics of the model's
  [`SerialChain`][elastic_gym.model.SerialChain]; w a torque noise (density Q) on the motor and
  link equations, through the inverse of the complete inertia [[B, S^T], [S, M(q)]].
* Jacobian F = df/dx, eq. (8), from complex-step tangents of the compiled RNEA.
* Prediction: the mean by RK4 (``substeps``), the covariance by the discrete eq. (15),
  P^- = e^{2 alpha T} Phi P Phi^T + Q_d (Van Loan), alpha the data weighting.
* Measurement, eqs. (9)-(13): motor encoders and, with ``use_accelerometers=True``,
  eq. (10) of De Luca et al.; gain eq. (18), update eq. (16), eq. (17) in Joseph form.
* N arms at once (stacked Jacobians, exponentials, updates), each equal to its lone filter.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Annotated, Any, NamedTuple

import numpy as np
from pydantic import Field, StrictBool, ValidationInfo, field_validator
from scipy.linalg import expm

from elastic_gym.model import RobotModel
from elastic_gym.model.option_checks import Needs, PerSample, square_matrix
from elastic_gym.observers.base import BatchedObserver, arm_count
from elastic_gym.observers.integration import rk4
from elastic_gym.validation import (
    Matrix,
    NonNegativeFinite,
    StrictModel,
    at_most_one,
    entry,
    numbers,
    validated_options,
)

DEFAULT_ALPHA = 1.0
"""Exponential data weighting alpha of eq. (15), 1/s."""
DEFAULT_ACCELERATION_NOISE = (0.5, 2.0)
"""Per-sample acceleration uncertainty (rad/s^2) of the (motor, link) equations that the
default torque-noise density Q stands for, see
[`default_process_noise`][elastic_gym.observers.ekf.default_process_noise]."""
DEFAULT_INITIAL_STD = (1e-3, 0.05, 0.5, 1.0)
"""Standard deviations (rad, rad, rad/s, rad/s) of (theta, q, theta', q') in the default P0."""
DEFAULT_ACCELEROMETER_STD = 0.05
"""Accelerometer standard deviation (m/s^2) per axis and sample: white noise of the env's
default MEMS part (1.5e-3 m/s^2/sqrt(Hz) at 1 kHz, 0.034 m/s^2) plus its 0.02 m/s^2 bias."""
MAX_VARIANCE = 1e6
"""Largest entry of Q, R and P0 in their SI units (standard deviations of 1000 rad, rad/s
or m/s^2; torque noise sqrt(Q / T) of 3e4 N m at 1 ms), far above anything physical for
these arms, and well below the magnitudes at which the covariance update loses positive
definiteness or overflows."""
MAX_STD = float(np.sqrt(MAX_VARIANCE))
"""Largest standard deviation (or encoder quantum) option, from `MAX_VARIANCE`."""
MAX_SUBSTEPS = 100
"""Most RK4 steps per period: at T = 1 ms one step already keeps h * omega <= 0.6 for the
stiffest elastic mode of the package (596 rad/s); more only multiply the cost."""
PSD_TOLERANCE = 1e-12
"""Relative rounding a given full covariance may have below zero in its eigenvalues."""
DISCOUNT = " (alpha above 1/dt discounts the past by more than e^2 per sample, eq. (15))"
"""Why alpha is bounded by 1/dt (`PerSample`)."""


def has_sensors(model: RobotModel) -> bool:
    """Whether the robot carries accelerometers (for ``use_accelerometers``)."""
    return model.n_sensors > 0


# ----------------------------------------------------------------------------- options
CovarianceValue = Annotated[Any, Matrix(MAX_VARIANCE)]
"""A covariance option as given: finite entries of magnitude <= `MAX_VARIANCE`
(larger ones overflow the filter's arithmetic); its form is checked by
[`covariance_option`][elastic_gym.observers.ekf.covariance_option]."""


def covariance_option(
    value: CovarianceValue, name: str, block_sizes: tuple[int, ...], definite: bool = False
) -> np.ndarray:
    """A symmetric positive semi-definite covariance from a compact option value (its
    entries validated by `CovarianceValue`): a scalar (the same variance everywhere),
    one variance per block (``len(block_sizes)`` values, each repeated over its block),
    the full diagonal, or the full symmetric matrix (`square_matrix`); positive
    definite if ``definite``."""
    size = sum(block_sizes)
    return square_matrix(value, size, name, block_sizes, True, PSD_TOLERANCE, definite)


def default_process_noise(model: RobotModel, dt: float) -> np.ndarray:
    """Diagonal torque-noise density Q (2N x 2N, motor block first), N^2 m^2 s.

    A white torque of density Q held over one period T has standard deviation
    sqrt(Q / T). The default makes it the torque that produces the accelerations
    `DEFAULT_ACCELERATION_NOISE` through B on the motors and through the diagonal
    of M(q) at the middle of the robot's workspace on the links, so that light distal
    links are not swamped by a noise sized for the heavy proximal ones.
    """
    spec = model.spec
    q_mid = 0.5 * (np.asarray(spec.workspace_low) + np.asarray(spec.workspace_high))
    inertia = np.concatenate([model.B, np.diag(model.mass_matrix(q_mid))])
    accelerations = np.repeat(np.asarray(DEFAULT_ACCELERATION_NOISE), model.n)
    return np.diag((inertia * accelerations) ** 2 * dt)


# ----------------------------------------------------------------- model derivatives
class AccelerationDerivatives(NamedTuple):
    """Accelerations a = (theta'', q'') of model (1)/(2) of N arms and their derivatives.

    ``dx`` (N, 2n, 4n) is da/dx, the lower half of F = df/dx in eq. (8); ``dw``
    (N, 2n, 2n) is da/d(w_motor, w_link) for torques added to the motor and link
    equations: the inverse of the complete inertia [[B, S^T], [S, M(q)]], i.e. the noise
    matrix G of eq. (5) (blockdiag(B^-1, M^-1) for S = 0). Its first n columns are da/dtau.
    """

    ddtheta: np.ndarray
    ddq: np.ndarray
    dx: np.ndarray
    dw: np.ndarray


def _unit_directions(m: int, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Tangent directions (e_k, 0) then (0, e_k), k < n, repeated for m arms: (2 n m, n) each
    of (t_q, t_dq, t_ddq), row 2 n i + j for arm i and direction j."""
    eye, zero = np.eye(n), np.zeros((n, n))
    t_q = np.tile(np.vstack([eye, zero]), (m, 1))
    t_dq = np.tile(np.vstack([zero, eye]), (m, 1))
    return t_q, t_dq, np.zeros_like(t_q)


def _per_direction(values: np.ndarray, m: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(d/dq, d/dq') as (m, rows, n) Jacobians from tangents along `_unit_directions`."""
    d = values.reshape(m, 2 * n, -1).transpose(0, 2, 1)
    return d[:, :, :n], d[:, :, n:]


class ElasticLinearization:
    """Accelerations of the elastic arm and their derivatives for N arms (chain kernels).

    The link acceleration solves r(x, q'') = 0 with (eliminating theta'' from model (2))
    r = rnea(q, q', q'') - S B^-1 S^T q'' - (I + S B^-1) tau_J + S B^-1 (tau + w_m) - w_l + d(q'),
    so by the implicit-function theorem dq''/dx = -Ms^-1 dr/dx with the Schur complement
    Ms = M - S B^-1 S^T (for S = 0 this is the ABA derivative), dq''/dw_m = -Ms^-1 S B^-1,
    dq''/dw_l = Ms^-1; then theta'' = B^-1 (tau + w_m - tau_J - S^T q''). q'' itself is the
    chain's Cholesky forward dynamics of Ms; d rnea/dq and d rnea/dq' are complex-step
    tangents of the compiled RNEA along the unit directions
    ([`rnea_tangent`][elastic_gym.model.chain.SerialChain.rnea_tangent]). Constant blocks are
    computed once.
    """

    def __init__(self, model: RobotModel) -> None:
        n = model.n
        self.model = model
        self.chain = model.copy().chain  # own scratch buffers
        K, D = np.diag(model.K), np.diag(model.D)
        self._dtau_j = np.hstack([K, -K, D, -D])  # d tau_J / dx
        SBinv = model.S * model.B_inv
        self._SBinv = SBinv
        self._SBinv_ST = SBinv @ model.S.T
        self._dr_spring = -(np.eye(n) + SBinv) @ self._dtau_j
        self._dr_noise = np.hstack([SBinv, -np.eye(n)])  # dr / d(w_m, w_l)
        self._dtheta_dw = np.hstack([np.diag(model.B_inv), np.zeros((n, n))])

    def accelerations(self, x: np.ndarray, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(theta'', q'') (N, n) each of model (1)/(2) at states x (N, 4n), torques (N, n)."""
        model, n = self.model, self.model.n
        theta, q, dtheta, dq = x[:, :n], x[:, n : 2 * n], x[:, 2 * n : 3 * n], x[:, 3 * n :]
        tau_j = model.K * (theta - q) + model.D * (dtheta - dq)
        rhs = tau_j - model.link_friction(dq) - (tau - tau_j) @ self._SBinv.T
        ddq = self.chain.forward_dynamics(q, dq, rhs, -self._SBinv_ST)
        return model.B_inv * (tau - tau_j - ddq @ model.S), ddq

    def dynamics(self, x: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """x' = f(x, tau) of eq. (4) (model (2) when S != 0), (N, 4n)."""
        n = self.model.n
        ddtheta, ddq = self.accelerations(x, tau)
        return np.concatenate([x[:, 2 * n :], ddtheta, ddq], axis=1)

    def __call__(self, x: np.ndarray, tau: np.ndarray) -> AccelerationDerivatives:
        model, n, m = self.model, self.model.n, len(x)
        q, dq = x[:, n : 2 * n], x[:, 3 * n :]
        ddtheta, ddq = self.accelerations(x, tau)
        rows = np.repeat(np.arange(m), 2 * n)
        point = (q[rows], dq[rows], ddq[rows])
        _, tangent = self.chain.rnea_tangent(point, _unit_directions(m, n))
        drnea_dq, drnea_dv = _per_direction(tangent, m, n)
        M = self.chain.mass_and_bias(q, dq)[0]
        dr = np.broadcast_to(self._dr_spring, (m, n, 4 * n)).copy()
        dr[:, :, n : 2 * n] += drnea_dq
        dr[:, :, 3 * n :] += drnea_dv
        if model.friction is not None:
            dr[:, :, 3 * n :] += model.friction.derivative(dq)[:, :, None] * np.eye(n)
        noise = np.broadcast_to(self._dr_noise, (m, n, 2 * n))
        solved = -np.linalg.solve(M - self._SBinv_ST, np.concatenate([dr, noise], axis=2))
        dq_dx, dq_dw = solved[:, :, : 4 * n], solved[:, :, 4 * n :]
        B_inv = model.B_inv[:, None]
        dtheta_dx = -B_inv * (self._dtau_j + model.S.T @ dq_dx)
        dtheta_dw = self._dtheta_dw - B_inv * (model.S.T @ dq_dw)
        return AccelerationDerivatives(
            ddtheta,
            ddq,
            np.concatenate([dtheta_dx, dq_dx], axis=1),
            np.concatenate([dtheta_dw, dq_dw], axis=1),
        )

    def accelerometer_jacobians(
        self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Readings y_2 = T_A(q) q'' + W_A(q, q') (De Luca et al. eq. (10)) of N arms and
        their derivatives ``(y2, dy2/dq, dy2/dq', dy2/dq'' = T_A)`` at fixed q'': complex-step
        tangents of the compiled specific forces (the rotation of gravity into the sensor
        frame included)."""
        n, m = self.model.n, len(q)
        rows = np.repeat(np.arange(m), 2 * n)
        point = (q[rows], dq[rows], ddq[rows])
        readings, tangent = self.chain.specific_forces_tangent(point, _unit_directions(m, n))
        d_dq, d_dv = _per_direction(tangent, m, n)
        T_A = self.chain.accelerometer_maps(q, dq)[0]
        return readings[:: 2 * n], d_dq, d_dv, T_A


def _cholesky_solve(L: np.ndarray, B: np.ndarray) -> np.ndarray:
    return np.linalg.solve(np.swapaxes(L, -1, -2), np.linalg.solve(L, B))


def solve_spd(S: np.ndarray, B: np.ndarray) -> np.ndarray:
    """X with S_i X_i = B_i for each arm's symmetric positive definite S_i (Cholesky).

    The one linear-algebra solve of the filter's correction: an arm whose S_i is not
    finite or not positive definite gets NaN (its estimate becomes non-finite and the
    wrapper ends its episode), the other arms are solved as usual.
    """
    X = np.full(B.shape, np.nan)
    arms = np.flatnonzero(np.isfinite(S).all(axis=(1, 2)) & np.isfinite(B).all(axis=(1, 2)))
    try:
        X[arms] = _cholesky_solve(np.linalg.cholesky(S[arms]), B[arms])
    except np.linalg.LinAlgError:  # some S_i is not positive definite: one arm at a time
        for i in arms:
            try:
                X[i] = _cholesky_solve(np.linalg.cholesky(S[i]), B[i])
            except np.linalg.LinAlgError:
                continue  # this arm keeps NaN
    return X


# ------------------------------------------------------------------------- the filter
Deviation = Annotated[float, Field(strict=True, ge=0, le=MAX_STD, allow_inf_nan=False)]


class EKFOptions(StrictModel):
    """The plain-data options of
    [`ExtendedKalmanFilter`][elastic_gym.observers.ekf.ExtendedKalmanFilter] (see its
    arguments); the forms of the covariances Q, R, P0 are checked against the robot's
    dimensions by [`covariance_option`][elastic_gym.observers.ekf.covariance_option]; alpha
    (<= 1/dt) and ``use_accelerometers`` against the validation context (the robot
    ``model`` and ``dt``)."""

    alpha: Annotated[NonNegativeFinite, PerSample(1.0, DISCOUNT)] = DEFAULT_ALPHA
    Q: CovarianceValue | None = None
    P0: CovarianceValue | None = None
    use_accelerometers: Annotated[StrictBool, Needs((True,), "accelerometers", has_sensors)] = False
    encoder_resolution: Deviation | None = None
    encoder_noise_std: Deviation | None = None
    accelerometer_std: Annotated[Deviation, Field(gt=0)] = DEFAULT_ACCELEROMETER_STD
    R: CovarianceValue | None = None  # after the sensor options it replaces
    substeps: Annotated[int, Field(strict=True, ge=1, le=MAX_SUBSTEPS)] = 1

    @field_validator("R")
    @classmethod
    def _R_or_sensor_options(cls, R: Any, info: ValidationInfo) -> Any:
        given = [k for k in ("encoder_resolution", "encoder_noise_std") if info.data.get(k)]
        if info.data.get("accelerometer_std") != DEFAULT_ACCELEROMETER_STD:
            given.append("accelerometer_std")
        at_most_one({"R": R, ", ".join(given): given or None})  # R replaces the sensor options
        return R


class ExtendedKalmanFilter(BatchedObserver):
    """EKF with exponential data weighting for elastic arms; see the module docstring.

    Args:
        model: nominal model (possibly with parameter errors).
        dt: sampling period T (s).
        alpha: exponential data weighting of eq. (15), 1/s (0 <= alpha <= 1/dt; 0 is the
            plain EKF).
            Default `DEFAULT_ALPHA`.
        Q: torque-noise spectral density (N^2 m^2 s) of the (motor, link) equations, 2N x 2N
            (scalar, 2 block values, 2N diagonal entries or the matrix). Default
            [`default_process_noise`][elastic_gym.observers.ekf.default_process_noise].
        R: measurement covariance (encoders rad^2, then accelerometers (m/s^2)^2); same
            compact forms with blocks (encoders, accelerometers). Default from
            ``encoder_resolution``, ``encoder_noise_std`` and ``accelerometer_std``.
        P0: initial covariance, 4N x 4N (scalar, 4 block variances, diagonal or matrix).
            Default: standard deviations `DEFAULT_INITIAL_STD` per block.
        use_accelerometers: also fuse the accelerometer readings (eq. (10)).
        encoder_resolution: motor encoder quantum (rad); default the robot's.
        encoder_noise_std: motor encoder noise (rad); default the robot's.
        accelerometer_std: accelerometer noise per axis (m/s^2);
            default `DEFAULT_ACCELEROMETER_STD`.
        substeps: RK4 steps per period for the predicted mean (1 to `MAX_SUBSTEPS`).

    Every option is checked when the filter is built (finite, in range, shapes, Q and P0
    symmetric positive semi-definite, R positive definite, entries at most
    `MAX_VARIANCE`): ``TypeError`` / ``ValueError`` naming it.

    The filter holds N arms (``reset_arms`` / ``update_arms``): every step is stacked
    linear algebra over the arms (batched Jacobians, one batched matrix exponential, one
    batched Cholesky solve); the single-arm ``reset`` / ``update`` are N = 1. ``x`` and
    ``P`` are the estimate and covariance (of the one arm, or (N, ...) for N arms).
    """

    name = "ekf"
    applies_to = frozenset({"elastic"})
    options_model = EKFOptions

    def __init__(
        self,
        model: RobotModel,
        dt: float,
        alpha: float = DEFAULT_ALPHA,
        Q=None,
        R=None,
        P0=None,
        use_accelerometers: bool = False,
        encoder_resolution: float | None = None,
        encoder_noise_std: float | None = None,
        accelerometer_std: float = DEFAULT_ACCELEROMETER_STD,
        substeps: int = 1,
    ) -> None:
        super().__init__(model, dt)
        n = self.n
        options = validated_options(EKFOptions, locals(), {"model": model, "dt": self.dt})
        self.alpha, self.use_accelerometers = options.alpha, use_accelerometers
        self.substeps = substeps
        self.Q = (
            default_process_noise(model, self.dt)
            if Q is None
            else covariance_option(options.Q, "Q", (n, n))
        )
        blocks = (n, 3 * model.n_sensors) if use_accelerometers else (n,)
        R, name = options.R, "R"
        if R is None:  # from the sensor options
            R, name = self._sensor_covariance(options).tolist(), "R (from the sensor noise)"
        self.R = covariance_option(R, name, blocks, definite=True)
        self.P0 = (
            np.diag(np.repeat(np.asarray(DEFAULT_INITIAL_STD) ** 2, n))
            if P0 is None
            else covariance_option(options.P0, "P0", (n, n, n, n))
        )
        self._selector = np.hstack([np.eye(n), np.zeros((n, 3 * n))])  # theta = C x
        self._derivatives = ElasticLinearization(model)
        self._allocate(1)

    def _sensor_covariance(self, options: EKFOptions) -> np.ndarray:
        spec = self.model.spec
        resolution = options.encoder_resolution
        resolution = spec.encoder_resolution if resolution is None else resolution
        noise_std = options.encoder_noise_std
        noise_std = spec.encoder_noise_std if noise_std is None else noise_std
        variances = [np.full(self.n, resolution**2 / 12.0 + noise_std**2)]
        if self.use_accelerometers:
            variances.append(np.full(3 * self.model.n_sensors, options.accelerometer_std**2))
        return np.diag(np.concatenate(variances))

    def _allocate(self, n_arms: int) -> None:
        dim = 4 * self.n
        self._x = np.zeros((n_arms, dim))
        self._P = np.broadcast_to(self.P0, (n_arms, dim, dim)).copy()
        self.arm_diagnostics = {}

    @property
    def x(self) -> np.ndarray:
        """The state estimate: (4n,) for one arm, (N, 4n) for N arms."""
        return self._x[0] if len(self._x) == 1 else self._x

    @property
    def P(self) -> np.ndarray:
        """The covariance: (4n, 4n) for one arm, (N, 4n, 4n) for N arms."""
        return self._P[0] if len(self._P) == 1 else self._P

    # ----------------------------------------------------------------- interface
    def reset_arms(self, obs: Mapping, arms: np.ndarray, initial_estimate=None) -> np.ndarray:
        """Initial estimates: the given ones, or the arms at rest with theta from the
        encoders and q the static link position theta = q + K^-1 g(q)."""
        n_arms = arm_count(obs) if obs else max(len(self._x), int(np.max(arms)) + 1)
        if len(self._x) != n_arms:
            self._allocate(n_arms)
        x0 = self.initial_rows(initial_estimate, len(arms))
        if x0 is None:
            theta = self.measured_positions(obs, arms)
            q = self.model.static_link_position(theta)
            x0 = np.concatenate([theta, q, np.zeros((len(arms), 2 * self.n))], axis=1)
        self._x[arms] = x0
        self._P[arms] = self.P0
        for column in self.arm_diagnostics.values():
            column[arms] = np.nan
        return x0.copy()

    def update_arms(
        self, obs: Mapping, torque: np.ndarray, dt: float, arms: np.ndarray | None = None
    ) -> np.ndarray:
        """One predict (eqs. (4)-(8), (15)) and correct (eqs. (9)-(18)) cycle of ``arms``."""
        numbers(dt, "dt", "must be a positive number", [()], minimum=0.0, strict=True, exact=True)
        arms = np.arange(len(self._x)) if arms is None else np.asarray(arms)
        tau = self.checked_torque(torque, len(self._x))[arms]
        y = self._measurements(obs, arms)
        self.predict(tau, dt, arms)
        self.correct(y, tau, arms)
        return self._x.copy()

    # ------------------------------------------------------------------- steps
    def _measurements(self, obs: Mapping, arms: np.ndarray) -> np.ndarray:
        parts = [self.measured_positions(obs, arms)]
        if self.use_accelerometers:
            missing = "use_accelerometers=True needs obs['acceleration']"
            reading = entry(obs, "obs", "acceleration", None, missing)
            parts.append(np.asarray(reading, dtype=float)[arms])
        y = np.concatenate([np.reshape(p, (len(arms), -1)) for p in parts], axis=1)
        if y.shape[1] != self.R.shape[0]:
            raise ValueError(
                f"measurement has {y.shape[1]} entries, the EKF expects {self.R.shape[0]}"
            )
        return y

    def linearization(self, x: np.ndarray, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(F, G) of eqs. (4)-(8) at x: F = df/dx (4n x 4n), G the torque-noise input
        (4n x 2n); with a leading arm axis for states (N, 4n) and torques (N, n)."""
        rows, single = _arm_rows(x, tau)
        F, G = self._linearization(*rows)
        return (F[0], G[0]) if single else (F, G)

    def _linearization(self, x: np.ndarray, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        n, m = self.n, len(x)
        derivatives = self._derivatives(x, tau)
        F = np.zeros((m, 4 * n, 4 * n))
        F[:, : 2 * n, 2 * n :] = np.eye(2 * n)
        F[:, 2 * n :] = derivatives.dx
        G = np.zeros((m, 4 * n, 2 * n))
        G[:, 2 * n :] = derivatives.dw
        return F, G

    def predict(self, tau: np.ndarray, dt: float, arms: np.ndarray | None = None) -> None:
        """Mean by RK4 with tau held; P^- = e^{2 alpha T} Phi P Phi^T + Q_d (Van Loan), for
        ``arms`` (default all) with their torques ``tau`` (len(arms), n) (or (n,))."""
        arms = np.arange(len(self._x)) if arms is None else arms
        x = self._x[arms]
        tau = np.broadcast_to(tau, (len(arms), self.n))
        F, G = self._linearization(x, tau)
        dim = F.shape[1]
        van_loan = np.zeros((len(arms), 2 * dim, 2 * dim))
        van_loan[:, :dim, :dim] = -F
        van_loan[:, :dim, dim:] = G @ self.Q @ np.swapaxes(G, 1, 2)
        van_loan[:, dim:, dim:] = np.swapaxes(F, 1, 2)
        E = expm(van_loan * dt)
        Phi = np.swapaxes(E[:, dim:, dim:], 1, 2)
        Qd = Phi @ E[:, :dim, dim:]
        P = np.exp(2.0 * self.alpha * dt) * (Phi @ self._P[arms] @ np.swapaxes(Phi, 1, 2)) + Qd
        self._P[arms] = 0.5 * (P + np.swapaxes(P, 1, 2))
        dynamics = self._derivatives.dynamics
        self._x[arms] = rk4(lambda t, z: dynamics(z, tau), x, dt, self.substeps)

    def measurement_model(self, x: np.ndarray, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """h(x, u) and H = dh/dx, eqs. (9)-(13): encoders, then accelerometers; with a
        leading arm axis for states (N, 4n) and torques (N, n)."""
        rows, single = _arm_rows(x, tau)
        h, H = self._measurement_model(*rows)
        return (h[0], H[0]) if single else (h, H)

    def _measurement_model(self, x: np.ndarray, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        n, m = self.n, len(x)
        selector = np.broadcast_to(self._selector, (m, n, 4 * n))
        if not self.use_accelerometers:
            return x[:, :n].copy(), selector
        derivatives = self._derivatives(x, tau)
        q, dq = x[:, n : 2 * n], x[:, 3 * n :]
        readings, d_dq, d_dv, d_da = self._derivatives.accelerometer_jacobians(
            q, dq, derivatives.ddq
        )
        H_acc = d_da @ derivatives.dx[:, n:]
        H_acc[:, :, n : 2 * n] += d_dq
        H_acc[:, :, 3 * n :] += d_dv
        return (
            np.concatenate([x[:, :n], readings], axis=1),
            np.concatenate([selector, H_acc], axis=1),
        )

    def correct(self, y: np.ndarray, tau: np.ndarray, arms: np.ndarray | None = None) -> None:
        """Gain eq. (18), update eq. (16) with the nonlinear h, Joseph-form eq. (17), for
        ``arms`` (default all) with measurements y and torques tau (one row per arm)."""
        arms = np.arange(len(self._x)) if arms is None else arms
        m = len(arms)
        y, tau = np.reshape(y, (m, -1)), np.broadcast_to(tau, (m, self.n))
        x, P = self._x[arms], self._P[arms]
        h, H = self._measurement_model(x, tau)
        innovation = y - h
        Ht = np.swapaxes(H, 1, 2)
        PHt = P @ Ht
        S = H @ PHt + self.R
        solved = solve_spd(S, np.concatenate([np.swapaxes(PHt, 1, 2), innovation[..., None]], 2))
        gain = np.swapaxes(solved[..., :-1], 1, 2)
        x = x + (gain @ innovation[..., None])[..., 0]
        I_KH = np.eye(P.shape[1]) - gain @ H
        P = I_KH @ P @ np.swapaxes(I_KH, 1, 2) + gain @ self.R @ np.swapaxes(gain, 1, 2)
        self._x[arms] = x
        self._P[arms] = 0.5 * (P + np.swapaxes(P, 1, 2))
        link_variance = np.diagonal(self._P[arms], axis1=1, axis2=2)[:, self.n : 2 * self.n]
        self._record(
            arms,
            nis=np.einsum("ij,ij->i", innovation, solved[..., -1]),
            link_position_std=np.sqrt(np.max(link_variance, axis=1)),
        )

    def _record(self, arms: np.ndarray, **values: np.ndarray) -> None:
        N = len(self._x)
        for key, value in values.items():
            column = self.arm_diagnostics.get(key)
            if column is None or len(column) != N:
                column = self.arm_diagnostics[key] = np.full(N, np.nan)
            column[arms] = value


def _arm_rows(x: np.ndarray, tau: np.ndarray) -> tuple[tuple[np.ndarray, np.ndarray], bool]:
    """States and torques of one arm (vectors) or of N arms (rows) as rows, and whether
    they were one arm's."""
    x = np.asarray(x, dtype=float)
    single = x.ndim == 1
    x = x[None] if single else x
    return (x, np.broadcast_to(np.asarray(tau, dtype=float), (len(x), x.shape[1] // 4))), single
