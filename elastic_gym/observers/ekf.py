"""Extended Kalman filter for elastic-joint arms with exponential data weighting.

After Abdeetedal (report on Lightcap & Banks, IEEE TCST 2010), eqs. (1)-(18), on the
models (1)/(2) of De Luca et al. State x = (theta, q, theta', q'), input tau held over
the period T.

* Dynamics x' = f(x, u) + G(x) w, eq. (4): w a torque noise (density Q) on the motor and
  link equations, through the inverse of the complete inertia [[B, S^T], [S, M(q)]].
* Jacobian F = df/dx, eq. (8), from pinocchio's RNEA derivatives (implicit in q'').
* Prediction: the mean by RK4 (``substeps``), the covariance by the discrete eq. (15),
  P^- = e^{2 alpha T} Phi P Phi^T + Q_d (Van Loan), alpha the data weighting.
* Measurement, eqs. (9)-(13): motor encoders (variance resolution^2 / 12 + noise^2) and,
  with ``use_accelerometers=True``, eq. (10) of De Luca et al.; gain eq. (18), update
  eq. (16), covariance eq. (17) in Joseph form.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import NamedTuple

import numpy as np
import pinocchio as pin
from scipy.linalg import cho_factor, cho_solve, expm

from elastic_gym.model import RobotModel
from elastic_gym.observers.base import Observer
from elastic_gym.observers.integration import rk4
from elastic_gym.validation import is_real

DEFAULT_ALPHA = 1.0
"""Exponential data weighting alpha of eq. (15), 1/s."""
DEFAULT_ACCELERATION_NOISE = (0.5, 2.0)
"""Per-sample acceleration uncertainty (rad/s^2) of the (motor, link) equations that the
default torque-noise density Q stands for, see :func:`default_process_noise`."""
DEFAULT_INITIAL_STD = (1e-3, 0.05, 0.5, 1.0)
"""Standard deviations (rad, rad, rad/s, rad/s) of (theta, q, theta', q') in the default P0."""
DEFAULT_ACCELEROMETER_STD = 0.05
"""Accelerometer standard deviation (m/s^2) per axis and sample: white noise of the env's
default MEMS part (1.5e-3 m/s^2/sqrt(Hz) at 1 kHz, 0.034 m/s^2) plus its 0.02 m/s^2 bias."""
MAX_VARIANCE = 1e6
"""Largest entry of Q, R and P0 in their SI units (standard deviations of 1000 rad, rad/s
or m/s^2; torque noise sqrt(Q / T) of 3e4 N m at 1 ms), far above anything physical for
these arms. Measured on the 2-link arm at T = 1 ms: P0 = 1e10 lost positive definiteness
in the update within 5 samples, Q = 1e60 overflowed at the first."""
MAX_STD = float(np.sqrt(MAX_VARIANCE))
"""Largest standard deviation (or encoder quantum) option, from :data:`MAX_VARIANCE`."""
MAX_SUBSTEPS = 100
"""Most RK4 steps per period: at T = 1 ms one step already keeps h * omega <= 0.6 for the
stiffest elastic mode of the package (596 rad/s); more only multiply the cost."""


# ----------------------------------------------------------------------------- helpers
def _check_number(
    name: str,
    value,
    minimum: float = 0.0,
    strict: bool = False,
    maximum: float = np.inf,
    why: str = "",
) -> float:
    if isinstance(value, bool) or not is_real(value) or not np.isfinite(value):
        raise TypeError(f"EKF option {name!r} must be a finite number, got {value!r}")
    if value < minimum or (strict and value == minimum):
        relation = ">" if strict else ">="
        raise ValueError(f"EKF option {name!r} must be {relation} {minimum}, got {value!r}")
    if value > maximum:
        raise ValueError(f"EKF option {name!r} must be <= {maximum:g}{why}, got {value!r}")
    return float(value)


def covariance_option(value, name: str, block_sizes: tuple[int, ...]) -> np.ndarray:
    """A symmetric positive semi-definite covariance from a compact option value.

    Accepted forms: a scalar (the same variance everywhere), one variance per block
    (``len(block_sizes)`` values, each repeated over its block), the full diagonal,
    or the full symmetric matrix.
    """
    dim = sum(block_sizes)
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise TypeError(f"EKF option {name!r} must be numeric, got {value!r}") from None
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"EKF option {name!r} must be finite, got {value!r}")
    if np.any(np.abs(arr) > MAX_VARIANCE):
        raise ValueError(
            f"EKF option {name!r}: entries must be <= {MAX_VARIANCE:g} in SI units "
            f"(larger ones overflow the filter's arithmetic), got {value!r}"
        )
    if arr.ndim == 0:
        arr = np.full(dim, float(arr))
    elif arr.ndim == 1 and arr.size == len(block_sizes):
        arr = np.repeat(arr, block_sizes)
    if arr.ndim == 1 and arr.size == dim:
        if np.any(arr < 0.0):
            raise ValueError(f"EKF option {name!r}: variances must be >= 0, got {value!r}")
        return np.diag(arr)
    if arr.shape != (dim, dim):
        raise ValueError(
            f"EKF option {name!r} must be a scalar, {len(block_sizes)} block variances, "
            f"{dim} diagonal entries or a {dim}x{dim} matrix, got shape {arr.shape}"
        )
    symmetric = 0.5 * (arr + arr.T)
    scale = max(1.0, float(np.abs(arr).max()))
    if not np.allclose(arr, arr.T) or np.linalg.eigvalsh(symmetric).min() < -1e-12 * scale:
        raise ValueError(f"EKF option {name!r} must be symmetric positive semi-definite")
    return symmetric


def default_process_noise(model: RobotModel, dt: float) -> np.ndarray:
    """Diagonal torque-noise density Q (2N x 2N, motor block first), N^2 m^2 s.

    A white torque of density Q held over one period T has standard deviation
    sqrt(Q / T). The default makes it the torque that produces the accelerations
    :data:`DEFAULT_ACCELERATION_NOISE` through B on the motors and through the diagonal
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
    """Accelerations a = (theta'', q'') of model (1)/(2) and their derivatives.

    ``dx`` (2N x 4N) is da/dx, the lower half of F = df/dx in eq. (8); ``dw`` (2N x 2N)
    is da/d(w_motor, w_link) for torques added to the motor and link equations: the
    inverse of the complete inertia [[B, S^T], [S, M(q)]], i.e. the noise matrix G of
    eq. (5) (blockdiag(B^-1, M^-1) for S = 0). Its first N columns are da/dtau.
    """

    ddtheta: np.ndarray
    ddq: np.ndarray
    dx: np.ndarray
    dw: np.ndarray


class ElasticLinearization:
    """Derivatives of the elastic-arm accelerations from pinocchio's RNEA derivatives.

    The link acceleration solves r(x, q'') = 0 with (eliminating theta'' from model (2))
    r = rnea(q, q', q'') - S B^-1 S^T q'' - (I + S B^-1) tau_J + S B^-1 (tau + w_m) - w_l + d(q'),
    so by the implicit-function theorem dq''/dx = -Ms^-1 dr/dx with the Schur complement
    Ms = M - S B^-1 S^T (for S = 0 this is the ABA derivative), dq''/dw_m = -Ms^-1 S B^-1,
    dq''/dw_l = Ms^-1; then theta'' = B^-1 (tau + w_m - tau_J - S^T q''). Constant
    blocks are computed once.
    """

    def __init__(self, model: RobotModel) -> None:
        n = model.n
        self.model = model
        K, D = np.diag(model.K), np.diag(model.D)
        self._dtau_j = np.hstack([K, -K, D, -D])  # d tau_J / dx
        SBinv = model.S * model.B_inv
        self._SBinv_ST = SBinv @ model.S.T
        self._dr_spring = -(np.eye(n) + SBinv) @ self._dtau_j
        self._dr_noise = np.hstack([SBinv, -np.eye(n)])  # dr / d(w_m, w_l)
        self._dtheta_dw = np.hstack([np.diag(model.B_inv), np.zeros((n, n))])

    def __call__(self, x: np.ndarray, tau: np.ndarray) -> AccelerationDerivatives:
        model, n = self.model, self.model.n
        q, dq = x[n : 2 * n], x[3 * n :]
        ddtheta, ddq = model.elastic_accelerations(x, tau)
        drnea_dq, drnea_dv, M = model.rnea_derivatives(q, dq, ddq)
        dr = self._dr_spring.copy()
        dr[:, n : 2 * n] += drnea_dq
        dr[:, 3 * n :] += drnea_dv
        if model.friction is not None:
            dr[:, 3 * n :] += np.diag(model.friction.derivative(dq))
        solved = -np.linalg.solve(M - self._SBinv_ST, np.hstack([dr, self._dr_noise]))
        dq_dx, dq_dw = solved[:, : 4 * n], solved[:, 4 * n :]
        dtheta_dx = -model.B_inv[:, None] * (self._dtau_j + model.S.T @ dq_dx)
        dtheta_dw = self._dtheta_dw - model.B_inv[:, None] * (model.S.T @ dq_dw)
        return AccelerationDerivatives(
            ddtheta, ddq, np.vstack([dtheta_dx, dq_dx]), np.vstack([dtheta_dw, dq_dw])
        )


def accelerometer_jacobians(
    model: RobotModel, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Readings y_2 = T_A(q) q'' + W_A(q, q') (De Luca et al. eq. (10)) and derivatives.

    Returns ``(y2, dy2_dq, dy2_dq', dy2_dq'' = T_A)`` at fixed q''. The sensor reads
    f = a_S - R^T g_W (a_S the classical acceleration of the sensor point in its own
    frame); pinocchio gives d a_S (``getPointClassicAccelerationDerivatives``, LOCAL)
    and d(-R^T g_W)/dq = -[R^T g_W]_x J_w with J_w the sensor's angular Jacobian (LOCAL).
    """
    pm, data = model.pin_model, model.data
    readings = model.accelerometer_readings(q, dq, ddq)
    pin.computeForwardKinematicsDerivatives(pm, data, q, dq, ddq)
    pin.computeJointJacobians(pm, data, q)
    pin.updateFramePlacements(pm, data)
    rows = 3 * model.n_sensors
    d_dq, d_dv, d_da = (np.empty((rows, model.n)) for _ in range(3))
    for i, fid in enumerate(model.sensor_frame_ids):
        frame = pm.frames[fid]
        _, a_dq, a_dv, a_da = pin.getPointClassicAccelerationDerivatives(
            pm, data, frame.parentJoint, frame.placement, pin.ReferenceFrame.LOCAL
        )
        j_w = pin.getFrameJacobian(pm, data, fid, pin.ReferenceFrame.LOCAL)[3:]
        gravity_local = data.oMf[fid].rotation.T @ model.gravity_vector
        block = slice(3 * i, 3 * i + 3)
        d_dq[block] = a_dq - pin.skew(gravity_local) @ j_w
        d_dv[block] = a_dv
        d_da[block] = a_da
    return readings, d_dq, d_dv, d_da


# ------------------------------------------------------------------------- the filter
class ExtendedKalmanFilter(Observer):
    """EKF with exponential data weighting for elastic arms; see the module docstring.

    Args:
        model: nominal model (possibly with parameter errors).
        dt: sampling period T (s).
        alpha: exponential data weighting of eq. (15), 1/s (0 <= alpha <= 1/dt; 0 is the
            plain EKF).
            Default :data:`DEFAULT_ALPHA`.
        Q: torque-noise spectral density (N^2 m^2 s) of the (motor, link) equations, 2N x 2N
            (scalar, 2 block values, 2N diagonal entries or the matrix). Default
            :func:`default_process_noise`.
        R: measurement covariance (encoders rad^2, then accelerometers (m/s^2)^2); same
            compact forms with blocks (encoders, accelerometers). Default from
            ``encoder_resolution``, ``encoder_noise_std`` and ``accelerometer_std``.
        P0: initial covariance, 4N x 4N (scalar, 4 block variances, diagonal or matrix).
            Default: standard deviations :data:`DEFAULT_INITIAL_STD` per block.
        use_accelerometers: also fuse the accelerometer readings (eq. (10)).
        encoder_resolution: motor encoder quantum (rad); default the robot's.
        encoder_noise_std: motor encoder noise (rad); default the robot's.
        accelerometer_std: accelerometer noise per axis (m/s^2);
            default :data:`DEFAULT_ACCELEROMETER_STD`.
        substeps: RK4 steps per period for the predicted mean (1 to :data:`MAX_SUBSTEPS`).

    Every option is checked when the filter is built (finite, in range, shapes, Q and P0
    symmetric positive semi-definite, R positive definite, entries at most
    :data:`MAX_VARIANCE`): ``TypeError`` / ``ValueError`` naming it.
    """

    name = "ekf"
    applies_to = frozenset({"elastic"})

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
        self.alpha = _check_number(
            "alpha",
            alpha,
            maximum=1.0 / self.dt,
            why=" = 1/dt (it would discount the past by more than e^2 per sample; measured at "
            "1/dt: estimation errors of 0.6 - 1.4 rad, at 10/dt: a broken covariance)",
        )
        if not isinstance(use_accelerometers, bool):
            raise TypeError(
                f"EKF option 'use_accelerometers' must be a bool, got {use_accelerometers!r}"
            )
        if use_accelerometers and model.n_sensors == 0:
            raise ValueError(
                f"EKF option 'use_accelerometers': robot {model.spec.name!r} has no accelerometers"
            )
        self.use_accelerometers = use_accelerometers
        accelerometer_std = _check_number(
            "accelerometer_std", accelerometer_std, strict=True, maximum=MAX_STD
        )
        if (
            isinstance(substeps, bool)
            or not isinstance(substeps, int)
            or not 1 <= substeps <= MAX_SUBSTEPS
        ):
            raise ValueError(
                f"EKF option 'substeps' must be an integer in [1, {MAX_SUBSTEPS}], got {substeps!r}"
            )
        self.substeps = substeps

        self.Q = (
            default_process_noise(model, self.dt)
            if Q is None
            else covariance_option(Q, "Q", (n, n))
        )
        sensor_options = {
            "encoder_resolution": encoder_resolution,
            "encoder_noise_std": encoder_noise_std,
        }
        if R is not None:
            given = [key for key, value in sensor_options.items() if value is not None]
            if given or accelerometer_std != DEFAULT_ACCELEROMETER_STD:
                raise ValueError(
                    f"EKF option 'R' replaces the sensor options {given or ['accelerometer_std']}; "
                    "give one or the other"
                )
        blocks = (n, 3 * model.n_sensors) if use_accelerometers else (n,)
        self.R = (
            self._sensor_covariance(encoder_resolution, encoder_noise_std, accelerometer_std)
            if R is None
            else covariance_option(R, "R", blocks)
        )
        if np.linalg.eigvalsh(self.R).min() <= 0.0:
            raise ValueError(
                "EKF option 'R' (or the encoder/accelerometer noise it is built from) must be "
                "positive definite"
            )
        self.P0 = (
            np.diag(np.repeat(np.asarray(DEFAULT_INITIAL_STD) ** 2, n))
            if P0 is None
            else covariance_option(P0, "P0", (n, n, n, n))
        )
        self.x = np.zeros(4 * n)
        self.P = self.P0.copy()
        self._selector = np.hstack([np.eye(n), np.zeros((n, 3 * n))])  # theta = C x
        self._derivatives = ElasticLinearization(model)

    def _sensor_covariance(
        self, resolution: float | None, noise_std: float | None, accelerometer_std: float
    ) -> np.ndarray:
        spec = self.model.spec
        resolution = spec.encoder_resolution if resolution is None else resolution
        noise_std = spec.encoder_noise_std if noise_std is None else noise_std
        resolution = _check_number("encoder_resolution", resolution, maximum=MAX_STD)
        noise_std = _check_number("encoder_noise_std", noise_std, maximum=MAX_STD)
        variances = [np.full(self.n, resolution**2 / 12.0 + noise_std**2)]
        if self.use_accelerometers:
            variances.append(np.full(3 * self.model.n_sensors, accelerometer_std**2))
        return np.diag(np.concatenate(variances))

    # ----------------------------------------------------------------- interface
    def reset(self, obs: Mapping, initial_estimate: np.ndarray | None = None) -> np.ndarray:
        """Initial estimate: the given one, or the arm at rest with theta from the
        encoders and q the static link position theta = q + K^-1 g(q)."""
        x0 = self.check_initial_estimate(initial_estimate)
        if x0 is None:
            theta = self.measured_position(obs)
            q = self.model.static_link_position(theta)
            x0 = np.concatenate([theta, q, np.zeros(2 * self.n)])
        self.x = x0
        self.P = self.P0.copy()
        self.diagnostics = {}
        return self.x.copy()

    def update(self, obs: Mapping, torque: np.ndarray, dt: float) -> np.ndarray:
        """One predict (eqs. (4)-(8), (15)) and correct (eqs. (9)-(18)) cycle."""
        tau = np.asarray(torque, dtype=float)
        if tau.shape != (self.n,):
            raise ValueError(f"torque must have shape ({self.n},), got {tau.shape}")
        if not (is_real(dt) and np.isfinite(dt) and dt > 0):
            raise ValueError(f"dt must be a positive number, got {dt!r}")
        y = self._measurement_vector(obs)
        self.predict(tau, dt)
        self.correct(y, tau)
        return self.x.copy()

    # ------------------------------------------------------------------- steps
    def _measurement_vector(self, obs: Mapping) -> np.ndarray:
        parts = [self.measured_position(obs)]
        if self.use_accelerometers:
            if "acceleration" not in obs:
                raise ValueError("use_accelerometers=True needs obs['acceleration']")
            parts.append(np.asarray(obs["acceleration"], dtype=float))
        y = np.concatenate(parts)
        if y.shape != (self.R.shape[0],):
            raise ValueError(f"measurement has {y.size} entries, the EKF expects {self.R.shape[0]}")
        return y

    def _rk4(self, x: np.ndarray, tau: np.ndarray, dt: float) -> np.ndarray:
        dynamics = self.model.elastic_dynamics
        return rk4(lambda t, z: dynamics(z, tau), x, dt, self.substeps)

    def linearization(self, x: np.ndarray, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(F, G) of eqs. (4)-(8) at x: F = df/dx (4N x 4N), G the torque-noise input (4N x 2N)."""
        n = self.n
        derivatives = self._derivatives(x, tau)
        F = np.zeros((4 * n, 4 * n))
        F[: 2 * n, 2 * n :] = np.eye(2 * n)
        F[2 * n :] = derivatives.dx
        G = np.zeros((4 * n, 2 * n))
        G[2 * n :] = derivatives.dw
        return F, G

    def predict(self, tau: np.ndarray, dt: float) -> None:
        """Mean by RK4 with tau held; P^- = e^{2 alpha T} Phi P Phi^T + Q_d (Van Loan)."""
        F, G = self.linearization(self.x, tau)
        dim = F.shape[0]
        van_loan = np.zeros((2 * dim, 2 * dim))
        van_loan[:dim, :dim] = -F
        van_loan[:dim, dim:] = G @ self.Q @ G.T
        van_loan[dim:, dim:] = F.T
        E = expm(van_loan * dt)
        Phi = E[dim:, dim:].T
        Qd = Phi @ E[:dim, dim:]
        P = np.exp(2.0 * self.alpha * dt) * (Phi @ self.P @ Phi.T) + Qd
        self.P = 0.5 * (P + P.T)
        self.x = self._rk4(self.x, tau, dt)

    def measurement_model(self, x: np.ndarray, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """h(x, u) and H = dh/dx, eqs. (9)-(13): encoders, then accelerometers."""
        n = self.n
        if not self.use_accelerometers:
            return x[:n].copy(), self._selector
        derivatives = self._derivatives(x, tau)
        q, dq = x[n : 2 * n], x[3 * n :]
        readings, d_dq, d_dv, d_da = accelerometer_jacobians(self.model, q, dq, derivatives.ddq)
        H_acc = d_da @ derivatives.dx[n:]
        H_acc[:, n : 2 * n] += d_dq
        H_acc[:, 3 * n :] += d_dv
        return np.concatenate([x[:n], readings]), np.vstack([self._selector, H_acc])

    def correct(self, y: np.ndarray, tau: np.ndarray) -> None:
        """Gain eq. (18), update eq. (16) with the nonlinear h, Joseph-form eq. (17)."""
        h, H = self.measurement_model(self.x, tau)
        innovation = y - h
        PHt = self.P @ H.T
        S = H @ PHt + self.R
        if not np.all(np.isfinite(S)):  # diverged: a NaN estimate (the wrapper ends the episode)
            self.x = np.full_like(self.x, np.nan)
            return
        factor = cho_factor(S)
        gain = cho_solve(factor, PHt.T).T
        self.x = self.x + gain @ innovation
        I_KH = np.eye(self.P.shape[0]) - gain @ H
        P = I_KH @ self.P @ I_KH.T + gain @ self.R @ gain.T
        self.P = 0.5 * (P + P.T)
        self.diagnostics = {
            "nis": float(innovation @ cho_solve(factor, innovation)),
            "link_position_std": float(np.sqrt(np.max(np.diag(self.P)[self.n : 2 * self.n]))),
        }
