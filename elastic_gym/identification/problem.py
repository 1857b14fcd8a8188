"""The identification problem of one log: measurements, parameters, residuals.

Given (K, D, B), the motor side gives the deflection delta (`transmission`), hence
q = theta - delta, q' and q''. Residuals: the accelerometers, y - f_A(q, q', q'') - b
(De Luca et al. 2007, eq. (9); b a bias per axis), and the link side,
tau_J - Y(q, q', q'') pi (eq. (1); `link_side`: mass scales, viscous and Coulomb
friction). (K, D, B) enter nonlinearly; b and pi linearly and are solved for inside every
evaluation (variable projection, Golub & Pereyra 1973). The link side alone fixes K, D
and the masses only up to a common scale; the motor torque fixes the scale.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from elastic_gym.identification.link_side import LinkColumns, coulomb_column
from elastic_gym.identification.signals import SpectralGrid
from elastic_gym.identification.transmission import coupling_scaled, deflection_spectrum
from elastic_gym.model import RobotModel


def least_squares_solution(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """argmin |A p - b| for a tall A of full column rank: the normal equations of the
    columns scaled to unit norm, solved with the pseudo-inverse (a column of zeros, e.g.
    the Coulomb column of a joint that never moved, gets 0)."""
    norm = np.linalg.norm(A, axis=0)
    norm = np.where(norm > 0.0, norm, 1.0)
    As = A / norm
    return (np.linalg.pinv(As.T @ As) @ (As.T @ b)) / norm


@dataclass(frozen=True)
class Signals:
    """The log's signals as the fit needs them.

    ``time`` (T,), ``motor_position`` (T, n), ``torque`` (T, n), ``acceleration``
    (T, 3 s) with ``sensor_names`` (s).
    """

    time: np.ndarray
    motor_position: np.ndarray
    torque: np.ndarray
    acceleration: np.ndarray
    sensor_names: tuple[str, ...]

    @property
    def dt(self) -> float:
        return float((self.time[-1] - self.time[0]) / (len(self.time) - 1))


@dataclass(frozen=True)
class SamplingModel:
    """What the log's sampling did to its signals (modelled, not fitted).

    ``torque_hold``: each torque sample was held until the next one (zero-order hold);
    ``delay``: the torque acted this many seconds after its logged time relative to the
    measurements (e.g. the sensors' delay); ``accelerometer_cutoff_hz``: the
    accelerometers' first-order low-pass y_k = a y_{k-1} + (1 - a) x_k,
    a = exp(-2 pi f_c h), whose effect is undone on the measured readings (its inverse,
    (1 - a z^-1) / (1 - a), is a stable two-tap filter).
    """

    torque_hold: bool = True
    delay: float = 0.0
    accelerometer_cutoff_hz: float | None = None


@dataclass
class Measurements:
    """The filtered spectra and decimated samples of one log on one grid."""

    grid: SpectralGrid
    torque: np.ndarray  # spectrum (bins, n), hold and delay applied
    motor_acceleration: np.ndarray  # spectrum of theta'' (bins, n)
    theta: tuple[np.ndarray, np.ndarray, np.ndarray]  # theta, theta', theta'' decimated
    acceleration: np.ndarray  # decimated readings (N, 3 s)
    motor_velocity: np.ndarray  # theta' at every sample (T, n)
    motor_position: np.ndarray  # theta at every sample (T, n)
    readings: np.ndarray  # the accelerometers at every sample (T, 3 s), the wide band

    @classmethod
    def of(cls, signals: Signals, grid: SpectralGrid, sampling: SamplingModel) -> Measurements:
        bins = grid.bins
        theta = grid.spectrum(signals.motor_position)
        torque = grid.spectrum(signals.torque, hold=sampling.torque_hold, delay=sampling.delay)
        readings = grid.spectrum(signals.acceleration)
        wide = grid.spectrum(signals.acceleration, gain=grid.wide_gain)
        if sampling.accelerometer_cutoff_hz is not None:
            a = np.exp(-2.0 * np.pi * sampling.accelerometer_cutoff_hz * grid.dt)
            inverse = ((1.0 - a * np.exp(-grid.jw * grid.dt)) / (1.0 - a))[:, None]
            readings, wide = readings * inverse, wide * inverse
        return cls(
            grid=grid,
            torque=torque[:bins],
            motor_acceleration=grid.derivative(theta, 2)[:bins],
            theta=tuple(grid.decimated(theta, k) for k in range(3)),  # type: ignore[arg-type]
            acceleration=grid.decimated(readings),
            motor_velocity=grid.full(theta, 1),
            motor_position=grid.full(theta),
            readings=grid.full(wide),
        )


@dataclass
class Terms:
    """The model's terms on the decimated grid at one (K, D, B).

    ``predicted``: f_A(q, q', q'') (N, 3 s); ``rhs``: tau_J - S theta'' (N, n);
    ``columns``: link-side columns (N, n, p) for [mass scales, viscous, Coulomb].
    """

    q: np.ndarray
    dq: np.ndarray
    ddq: np.ndarray
    joint_torque: np.ndarray
    predicted: np.ndarray
    rhs: np.ndarray
    columns: np.ndarray


@dataclass(frozen=True)
class Frozen:
    """What the fit holds during one pass of the optimizer (refreshed between passes):
    the link's M_i(q), C_i q' + g_i of every body and the Coulomb columns, at the link
    motion of the pass's start. Within a pass (K, D, B) move q and q' by a fraction of the
    deflection (small against the motion), and q'' enters the columns exactly."""

    mass: np.ndarray  # (N, n, n, bodies)
    bias: np.ndarray  # (N, n, bodies)
    coulomb: np.ndarray  # (N, n)


@dataclass
class ElasticJointProblem:
    """Parameters, terms and residuals of the identification of one log.

    Nonlinear parameters: x = (log(K / K0), log(D / D0), log(B / B0)) relative to the
    nominal model's values. Linear parameters: accelerometer biases (3 s) and link
    parameters (n mass scales, n viscous, n Coulomb coefficients).
    """

    model: RobotModel
    measurements: Measurements
    coulomb_velocity: float = 0.01
    columns: LinkColumns = field(init=False)

    def __post_init__(self) -> None:
        self.n = n = self.model.n
        self.columns = LinkColumns(self.model)
        self.n_readings = self.measurements.acceleration.shape[1]
        self.free_link = np.ones(3 * n, dtype=bool)
        # the values of held link parameters: mass scale 1, no friction
        self.held_link = np.concatenate([np.ones(n), np.zeros(2 * n)])

    def hold_link(self, held: np.ndarray) -> None:
        """Hold the link parameters ``held`` (bool (3 n)) at their nominal values."""
        self.free_link = ~np.asarray(held, dtype=bool)

    # ------------------------------------------------------------------ layout
    @property
    def nonlinear_names(self) -> list[str]:
        names = self.model.spec.joint_names
        return [f"{p}[{j}]" for p in ("stiffness", "damping", "motor_inertia") for j in names]

    def link_names(self) -> list[str]:
        names = self.model.spec.joint_names
        return [f"{p}[{j}]" for p in ("link_mass", "viscous", "coulomb") for j in names]

    def transmission(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(K, D, B) of the nonlinear parameters x."""
        n, m = self.n, self.model
        return m.K * np.exp(x[:n]), m.D * np.exp(x[n : 2 * n]), m.B * np.exp(x[2 * n :])

    # ------------------------------------------------------------------ terms
    def deflection(self, x: np.ndarray) -> np.ndarray:
        """Spectrum (first bins, n) of the deflection delta at x."""
        meas, grid, model = self.measurements, self.measurements.grid, self.model
        K, D, B = self.transmission(x)
        S = coupling_scaled(model.S, B, model.B) if model.has_coupling else None
        return deflection_spectrum(
            grid.jw[: grid.bins], meas.torque, meas.motor_acceleration, K, D, B, S
        )

    def link_velocity(self, x: np.ndarray) -> np.ndarray:
        """q' at every sample (T, n), with the link's motion above the band: in the band
        theta' - delta'; above it (to `WIDE_BAND` of the Nyquist frequency) the integral
        of the accelerometers' q'' = T_A^+ (y - W_A) (De Luca et al. 2007, eq. (11); damped
        least squares near a singular T_A), which the encoders cannot give (delta' is
        the small difference of large terms there) and friction's sign responds to."""
        meas, grid = self.measurements, self.measurements.grid
        delta = self.deflection(x)
        q = np.ascontiguousarray(meas.motor_position - grid.full(delta))
        dq = np.ascontiguousarray(meas.motor_velocity - grid.full(delta, 1))
        ddq, _ = self.model.chain.acceleration_from_readings(
            q, dq, np.ascontiguousarray(meas.readings), 0.01, 0.01
        )
        above = grid.integral(grid.spectrum(np.nan_to_num(ddq), gain=grid.above_band))
        return dq + grid.full(above)

    def coulomb_columns(self, x: np.ndarray) -> np.ndarray:
        """The Coulomb columns tanh(q' / v_s) at x, computed at the full rate (`link_velocity`),
        filtered and decimated (N, n). They change little with (K, D, B): the fit holds
        them during one pass of the optimizer and refreshes them between passes."""
        grid = self.measurements.grid
        dq_full = self.link_velocity(x)
        return grid.decimated(grid.spectrum(coulomb_column(dq_full, self.coulomb_velocity)))

    def freeze(self, x: np.ndarray, terms: Terms | None = None) -> Frozen:
        """The `Frozen` link terms at x (``terms``: the exact terms at x, if known)."""
        terms = self.terms(x) if terms is None else terms
        mass, bias = self.columns.mass_and_bias(terms.q, terms.dq)
        n = self.n
        coulomb = terms.columns[:, np.arange(n), 2 * n + np.arange(n)]
        return Frozen(mass, bias, coulomb)

    def terms(self, x: np.ndarray, frozen: Frozen | None = None) -> Terms:
        """The terms at x (``frozen``: the link terms to hold; None: all at x)."""
        meas, grid, model = self.measurements, self.measurements.grid, self.model
        K, D, B = self.transmission(x)
        S = coupling_scaled(model.S, B, model.B) if model.has_coupling else None
        delta = self.deflection(x)
        stack = np.concatenate([delta, grid.derivative(delta, 1), grid.derivative(delta, 2)], 1)
        d0, d1, d2 = np.split(grid.decimated(stack), 3, axis=1)
        theta, dtheta, ddtheta = meas.theta
        q, dq, ddq = theta - d0, dtheta - d1, ddtheta - d2
        joint_torque = K * d0 + D * d1
        predicted = model.chain.specific_forces(q, dq, ddq)
        rhs = joint_torque - (ddtheta @ S.T if S is not None else 0.0)
        n, N = self.n, len(q)
        columns = np.zeros((N, n, 3 * n))
        joints = np.arange(n)
        columns[:, joints, n + joints] = dq
        if frozen is None:
            columns[:, :, :n] = self.columns(q, dq, ddq)
            columns[:, joints, 2 * n + joints] = self.coulomb_columns(x)
        else:
            columns[:, :, :n] = np.einsum("kjlb,kl->kjb", frozen.mass, ddq) + frozen.bias
            columns[:, joints, 2 * n + joints] = frozen.coulomb
        return Terms(q, dq, ddq, joint_torque, predicted, rhs, columns)

    # ------------------------------------------------------------------ residuals
    def solve_linear(
        self, terms: Terms, rows: np.ndarray, weights: tuple[np.ndarray, np.ndarray]
    ) -> tuple[np.ndarray, np.ndarray]:
        """(biases (3 s), link parameters (3 n)) minimizing the weighted residuals on
        ``rows`` at the given terms (``weights``: 1 / sigma per reading and per joint)."""
        bias = np.mean(self.measurements.acceleration[rows] - terms.predicted[rows], axis=0)
        w, free = weights[1], self.free_link
        columns = terms.columns[rows]
        rhs = terms.rhs[rows] - columns[:, :, ~free] @ self.held_link[~free]
        A = (columns[:, :, free] * w[None, :, None]).reshape(-1, int(free.sum()))
        b = (rhs * w[None, :]).reshape(-1)
        link = self.held_link.copy()
        link[free] = least_squares_solution(A, b)
        return bias, link

    def residuals(
        self,
        terms: Terms,
        bias: np.ndarray,
        link: np.ndarray,
        rows: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        """(accelerometer residuals (N, 3 s), link-side residuals (N, n)) on ``rows``."""
        readings = self.measurements.acceleration[rows] - terms.predicted[rows] - bias
        link_side = terms.rhs[rows] - terms.columns[rows] @ link
        return readings, link_side

    def weighted(
        self,
        x: np.ndarray,
        rows: np.ndarray,
        weights: tuple[np.ndarray, np.ndarray],
        linear: tuple[np.ndarray, np.ndarray] | None = None,
        frozen: Frozen | None = None,
    ) -> np.ndarray:
        """The stacked weighted residual at x; the linear parameters solved for (variable
        projection) unless given."""
        terms = self.terms(x, frozen)
        bias, link = self.solve_linear(terms, rows, weights) if linear is None else linear
        readings, link_side = self.residuals(terms, bias, link, rows)
        return np.concatenate([(readings * weights[0]).ravel(), (link_side * weights[1]).ravel()])
