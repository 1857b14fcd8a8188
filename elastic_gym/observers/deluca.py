"""De Luca, Schroeder & Thuemmel (ICRA 2007): acceleration-based observer for elastic joints.

Measurements: y1 = theta and the link acceleration, ideal (y2 = q'', Theorems 1 and 2) or
from accelerometers (eqs. (10)-(12)). Eqs. (6), (7) and (12) as one linear system,

    xi' = A_obs xi + G u + L y1 + H y2,    A_obs = [A; 0] - L C,
    G = [0; 0; B^-1; 0],   H = [0; 0; -B^-1 S^T; I]

(-B^-1 S^T: Theorem 2, model (2); ``use_coupling=False`` drops it), with the closed-form
gains of Remark 3 (`deluca_gains`). Discretized exactly with
the torque held and theta, q'' linear between samples (first-order hold); eq. (11),
q'' = T_A^+(xi_2) (y2' - W_A(xi_2, xi_4)), by a predictor-corrector with a damped
least-squares T_A^+ (``diagnostics``: cond(T_A), sigma_min, ``near_singular``).
``velocity_saturation`` clips the velocity entering W_A against peaking (None: the
paper's observer). Initial estimate at rest (Sec. IV); batched over N arms.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Annotated, Any, Literal

import numpy as np
from numba import njit
from pydantic import StrictBool, ValidationInfo, field_validator
from scipy.linalg import expm

from elastic_gym.model import RobotModel
from elastic_gym.model.chain import acceleration_from_readings_kernel
from elastic_gym.model.option_checks import Needs, PerSample
from elastic_gym.model.rows import rows_matmul
from elastic_gym.observers.base import BatchedObserver, arm_count
from elastic_gym.observers.deluca_gains import (
    DEFAULT_BANDWIDTH,
    butterworth_poles,
    deluca_gains,
    error_matrix,
    validate_poles,
)
from elastic_gym.validation import (
    PositiveFinite,
    StrictModel,
    at_most_one,
    entry,
    errors_at,
    validated_options,
)

DEFAULT_VELOCITY_SATURATION = 50.0  # rad/s, see "Peaking" above
DT_TOLERANCE = 1e-9  # relative mismatch of the update period tolerated
MAX_POLE_STEP = 10.0  # largest |lambda| dt: faster poles overflow the matrix exponential
PERIOD_KEYS = ("motor_position", "acceleration")  # what eq. (12) reads of an observation


def foh_discretization(
    F: np.ndarray, E: np.ndarray, T: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact sampled system of x' = F x + E w(t), w linear between samples (first-order hold).

    Returns (Phi, P0, P1) with x_{k+1} = Phi x_k + P0 w_k + P1 w_{k+1}, from one matrix
    exponential of [[F T, E T, 0], [0, 0, I], [0, 0, 0]]. A signal held constant over
    the period (zero-order hold) has the input matrix P0 + P1.
    """
    nx, nw = E.shape
    aug = np.zeros((nx + 2 * nw, nx + 2 * nw))
    aug[:nx, :nx] = F * T
    aug[:nx, nx : nx + nw] = E * T
    aug[nx : nx + nw, nx + nw :] = np.eye(nw)
    ex = expm(aug)
    phi, gamma0, gamma1 = ex[:nx, :nx], ex[:nx, nx : nx + nw], ex[:nx, nx + nw :]
    return phi, gamma0 - gamma1, gamma1


@njit(cache=True)
def _accelerometer_periods(
    xi,
    theta_prev,
    ddq_prev,
    torque,
    theta,
    readings,
    step_rows,
    ddq_rows,
    saturation,
    threshold,
    damping,
    work,
    constants,
    out,
    singular,
):
    """T periods of eq. (12) for N arms (predictor-corrector, `update_arms`' arithmetic):
    per period t, the prediction xi_p = [xi, u_t, m_t, (theta_{t+1}, q''_t)] @ step_rows,
    q''_{t+1} = T_A^+(xi_p,2) (y_{t+1} - W_A(xi_p,2, sat(xi_p,4))) (eq. (11)) and the
    correction xi = xi_p + (q''_{t+1} - q''_t) @ ddq_rows. `xi`, `theta_prev`, `ddq_prev`
    (N, .) are advanced in place; `out` (T, N, 4n) gets each period's estimate and
    `singular` (T, N, 3) eq. (11)'s (sigma_max, sigma_min, damping)."""
    T, N, n = theta.shape
    nx, width = 4 * n, step_rows.shape[0]
    stack = np.empty(width)
    predicted = np.empty((N, nx))
    q = np.empty((N, n))
    dq = np.empty((N, n))
    ddq = np.empty((N, n))
    diagnostics = np.empty((N, 3))
    for t in range(T):
        for k in range(N):
            for c in range(nx):
                stack[c] = xi[k, c]
            for c in range(n):
                stack[nx + c] = torque[t, k, c]
                stack[nx + n + c] = theta_prev[k, c]
                stack[nx + 2 * n + c] = ddq_prev[k, c]
                stack[nx + 3 * n + c] = theta[t, k, c]
                stack[nx + 4 * n + c] = ddq_prev[k, c]
            for c in range(nx):
                total = 0.0
                for j in range(width):
                    total += stack[j] * step_rows[j, c]
                predicted[k, c] = total
            for c in range(n):
                q[k, c] = predicted[k, n + c]
                v = predicted[k, 3 * n + c]
                if v < -saturation:
                    v = -saturation
                elif v > saturation:
                    v = saturation
                dq[k, c] = v
        acceleration_from_readings_kernel(
            q, dq, readings[t], threshold, damping, work, ddq, diagnostics, constants
        )
        for k in range(N):
            for c in range(nx):
                total = 0.0
                for j in range(n):
                    total += (ddq[k, j] - ddq_prev[k, j]) * ddq_rows[j, c]
                xi[k, c] = predicted[k, c] + total
                out[t, k, c] = xi[k, c]
            for c in range(n):
                theta_prev[k, c] = theta[t, k, c]
                ddq_prev[k, c] = ddq[k, c]
            for c in range(3):
                singular[t, k, c] = diagnostics[k, c]


def directions_per_joint(model: RobotModel) -> bool:
    """Whether the accelerometers measure at least one direction per joint (eq. (10))."""
    return 3 * model.n_sensors >= model.n


PoleRate = PerSample(MAX_POLE_STEP, " (faster poles overflow the matrix exponential)")
"""The bound |lambda| dt <= `MAX_POLE_STEP` of the poles (or of the bandwidth)."""


class DeLucaOptions(StrictModel):
    """The plain-data options of [`DeLucaObserver`][elastic_gym.observers.deluca.DeLucaObserver]
    (see its arguments); the poles
    and the per-joint bandwidth are checked against the robot by the observer, their
    magnitude against ``dt`` and the accelerometers against the robot by the validation
    context."""

    acceleration: Annotated[
        Literal["ideal", "accelerometer"],
        Needs(
            ("accelerometer",),
            "at least {n} measured directions (eq. (10), M >= N)",
            directions_per_joint,
        ),
    ] = "accelerometer"
    poles: Annotated[Any, PoleRate] = None
    bandwidth: Annotated[PositiveFinite | list[PositiveFinite] | None, PoleRate] = None
    use_coupling: StrictBool = True
    dls_threshold: PositiveFinite = 0.01
    dls_damping: PositiveFinite = 0.01
    velocity_saturation: PositiveFinite | None = DEFAULT_VELOCITY_SATURATION

    @field_validator("bandwidth")
    @classmethod
    def _poles_or_bandwidth(cls, bandwidth: Any, info: ValidationInfo) -> Any:
        at_most_one({"poles": info.data.get("poles"), "bandwidth": bandwidth})
        return bandwidth


class DeLucaObserver(BatchedObserver):
    """Acceleration-based observer of De Luca et al. (2007); see the module docstring.

    Args:
        model: nominal model; only K, B, D, S (and, for accelerometers, the kinematics
            and sensor mounts; for the default initial estimate, g(q)) are used.
        dt: sampling period (s).
        acceleration: ``"ideal"`` (Theorems 1/2, q'' from ``obs["link_acceleration"]``,
            privileged) or ``"accelerometer"`` (eq. (12), from ``obs["acceleration"]``).
        poles: desired error eigenvalues, 4 common ones or an (N, 4) array (conjugate
            pairs, negative real parts). Default: 4th-order Butterworth of radius
            ``bandwidth``.
        bandwidth: radius (rad/s) of the default Butterworth poles, scalar or per joint
            (default 250 rad/s, Sec. V-A); only when ``poles`` is None.
        use_coupling: include the -B^-1 S^T y2 term of Theorem 2 (model (2)).
        dls_threshold: smallest singular value of T_A (m) below which the damped
            least-squares inverse is damped and ``near_singular`` is set.
        dls_damping: damping lambda (m) at an exactly singular T_A.
        velocity_saturation: bound (rad/s) on the link velocity estimate used in
            W_A(xi_2, xi_4) of eq. (12) (default 50), or None (no saturation, as in the paper).
    """

    name = "deluca"
    applies_to = frozenset({"elastic"})
    options_model = DeLucaOptions

    def __init__(
        self,
        model: RobotModel,
        dt: float,
        acceleration: str = "accelerometer",
        poles=None,
        bandwidth: float | np.ndarray | None = None,
        use_coupling: bool = True,
        dls_threshold: float = 0.01,
        dls_damping: float = 0.01,
        velocity_saturation: float | None = DEFAULT_VELOCITY_SATURATION,
    ) -> None:
        super().__init__(model, dt)
        n = self.n
        if poles is None and bandwidth is None:  # checked against dt like a given one
            bandwidth = DEFAULT_BANDWIDTH
        options = validated_options(DeLucaOptions, locals(), {"model": model, "dt": self.dt})
        self.acceleration = options.acceleration
        self.use_coupling = options.use_coupling
        self.dls_threshold = options.dls_threshold
        self.dls_damping = options.dls_damping
        self.velocity_saturation = options.velocity_saturation
        # instance attribute: only the ideal variant needs the true q'' (Theorem 1)
        self.privileged = ("link_acceleration",) if acceleration == "ideal" else ()
        self._sensors = model.copy().chain  # own scratch buffer
        self._readings_width = 3 * model.n_sensors

        K, B, D = model.K, model.B, model.D
        with errors_at("options.poles" if poles is not None else "options.bandwidth"):
            given = options.bandwidth if poles is None else None
            self.poles = validate_poles(poles, n) if given is None else butterworth_poles(given, n)
        self.gains = deluca_gains(self.poles, K, B, D)
        self.A_obs = error_matrix(self.gains, K, B, D)

        phi, p0, p1 = foh_discretization(self.A_obs, self._input_matrix(), self.dt)
        self.phi = phi
        # one matrix for xi_{k+1} = [Phi, P_u, P_0^m, P_1^m] @ (xi_k, u_k, m_k, m_{k+1}),
        # stored transposed for row-stacked arms: xi_{k+1}^T = stack^T @ step^T
        self._step_rows = np.hstack([phi, p0[:, :n] + p1[:, :n], p0[:, n:], p1[:, n:]]).T.copy()
        self._ddq_rows = p1[:, 2 * n :].T.copy()
        self._allocate(1)

    def _allocate(self, n_arms: int) -> None:
        n = self.n
        self._stack = np.zeros((n_arms, self._step_rows.shape[0]))
        self._xi = np.zeros((n_arms, 4 * n))
        self._theta = np.zeros((n_arms, n))
        self._ddq = np.zeros((n_arms, n))
        self._period_out = np.empty((1, n_arms, 4 * n))  # one period of every arm
        self._period_singular = np.empty((1, n_arms, 3))
        self.arm_diagnostics = {}

    # ------------------------------------------------------------------ design
    def _input_matrix(self) -> np.ndarray:
        """E = [G, L, H] of xi' = A_obs xi + E (u, y1, y2), (4N x 3N)."""
        n, model = self.n, self.model
        E = np.zeros((4 * n, 3 * n))
        idx = np.arange(n)
        E[2 * n + idx, idx] = model.B_inv  # G u
        E[:, n : 2 * n] = np.vstack([np.diag(g) for g in self.gains])  # L y1
        if self.use_coupling:
            E[2 * n : 3 * n, 2 * n :] = -model.B_inv[:, None] * model.S.T  # -B^-1 S^T y2
        E[3 * n + idx, 2 * n + idx] = 1.0  # I y2
        return E

    # ------------------------------------------------------------------ measurements
    def _link_acceleration(self, obs: Mapping, xi: np.ndarray, arms) -> np.ndarray:
        """q'' samples of ``arms``: ideal (privileged), or eq. (11) at the estimates xi."""
        n = self.n
        if self.acceleration == "ideal":
            missing = (
                "acceleration='ideal' needs obs['link_acceleration'] (the true q''; "
                "ObserverWrapper adds it for observers with privileged link_acceleration)"
            )
            return entry(obs, "obs", "link_acceleration", (None, n), missing)[arms]
        missing = "acceleration='accelerometer' needs obs['acceleration']"
        shape = (None, 3 * self.model.n_sensors)
        reading = entry(obs, "obs", "acceleration", shape, missing)[arms]
        dq = xi[:, 3 * n :]
        if self.velocity_saturation is not None:
            dq = np.clip(dq, -self.velocity_saturation, self.velocity_saturation)
        ddq, singular = self._sensors.acceleration_from_readings(
            xi[:, n : 2 * n], dq, reading, self.dls_threshold, self.dls_damping
        )
        self._record_singular(arms, singular)
        return ddq

    def _record_singular(self, arms, singular: np.ndarray) -> None:
        """eq. (11)'s conditioning (`singular` (len(arms), 3): sigma_max, sigma_min, damping)
        as the arms' diagnostics."""
        sigma_max, sigma_min, damping = singular.T
        cond = np.divide(
            sigma_max, sigma_min, out=np.full(len(sigma_max), np.inf), where=sigma_min > 0.0
        )
        self._record(
            arms,
            cond_TA=cond,
            sigma_min_TA=sigma_min,
            dls_damping=damping,
            near_singular=sigma_min < self.dls_threshold,
        )

    def _record(self, arms, **values: np.ndarray) -> None:
        """Per-arm diagnostics (eq. (11)'s conditioning) of the arms just updated."""
        N = len(self._xi)
        for key, value in values.items():
            column = self.arm_diagnostics.get(key)
            if column is None or len(column) != N:
                column = np.zeros(N, dtype=value.dtype)
                self.arm_diagnostics[key] = column
            column[arms] = value

    # ------------------------------------------------------------------ Observer API
    def reset_arms(self, obs: Mapping, arms: np.ndarray, initial_estimate=None) -> np.ndarray:
        n_arms = arm_count(obs)
        if len(self._xi) != n_arms:
            self._allocate(n_arms)
        theta = self.measured_positions(obs, arms)
        xi = self.initial_rows(initial_estimate, len(arms))
        if xi is None:
            q = self.model.static_link_position(theta)
            xi = np.concatenate([theta, q, np.zeros((len(arms), 2 * self.n))], axis=1)
        self._xi[arms] = xi
        self._theta[arms] = theta
        self._ddq[arms] = self._link_acceleration(obs, xi, arms)
        return xi.copy()

    def update_arms(
        self, obs: Mapping, torque: np.ndarray, dt: float, arms: np.ndarray | slice | None = None
    ) -> np.ndarray:
        self._check_dt(dt)
        n = self.n
        tau = self.checked_torque(torque, len(self._xi))
        if self.acceleration == "accelerometer":  # one period of the compiled loop
            every = arms is None or (isinstance(arms, slice) and arms == slice(None))
            if not (every and self._every_arm(obs, tau)):
                period = {key: np.asarray(obs[key])[None] for key in PERIOD_KEYS if key in obs}
                self._periods(period, tau[None], arms)
            return self._xi.copy()
        arms = slice(None) if arms is None else arms
        theta = self.measured_positions(obs, arms)
        stack = self._stack[arms]
        stack[:, : 4 * n] = self._xi[arms]
        stack[:, 4 * n : 5 * n] = tau[arms]
        stack[:, 5 * n : 6 * n] = self._theta[arms]
        stack[:, 6 * n : 7 * n] = self._ddq[arms]
        stack[:, 7 * n : 8 * n] = theta
        ddq = self._link_acceleration(obs, self._xi[arms], arms)
        stack[:, 8 * n :] = ddq
        xi = rows_matmul(stack, self._step_rows)
        self._xi[arms], self._theta[arms], self._ddq[arms] = xi, theta, ddq
        return self._xi.copy()

    def update_sequence(self, obs: Mapping, torque: np.ndarray, dt: float) -> np.ndarray:
        """T periods of every arm in one compiled call (accelerometers; the ideal variant
        one `update_arms` per period): the numbers of T `update_arms` calls, bit for bit."""
        if self.acceleration != "accelerometer":
            return super().update_sequence(obs, torque, dt)
        self._check_dt(dt)
        tau = np.asarray(torque, dtype=float)
        if tau.ndim != 3 or tau.shape[1:] != (len(self._xi), self.n):
            raise ValueError(
                f"torque must have shape (T, {len(self._xi)}, {self.n}), got {tau.shape}"
            )
        return self._periods(obs, tau, None)

    def _check_dt(self, dt: float) -> None:
        if abs(dt - self.dt) > DT_TOLERANCE * self.dt:
            raise ValueError(
                f"DeLucaObserver was discretized for dt={self.dt}, update called with dt={dt}"
            )

    def _every_arm(self, obs: Mapping, tau: np.ndarray) -> bool:
        """One period of every arm by `_accelerometer_periods` on the observer's own state
        and buffers, when the measurements are float64 rows (N, .) as the envs give them
        (False: nothing done, `_periods` checks and copies them): the numbers of `_periods`,
        without its copies."""
        xi = self._xi
        rows = []
        for key, width in (("motor_position", self.n), ("acceleration", self._readings_width)):
            value = obs.get(key) if isinstance(obs, dict) else None
            if not (
                type(value) is np.ndarray
                and value.dtype == np.float64
                and value.shape == (len(xi), width)
                and value.flags.c_contiguous
            ):
                return False
            rows.append(value[None])
        self._run_periods(
            (xi, self._theta, self._ddq),
            np.ascontiguousarray(tau, dtype=float)[None],
            rows[0],
            rows[1],
            (self._period_out, self._period_singular),
        )
        self._record_singular(slice(None), self._period_singular[0])
        return True

    def _run_periods(
        self,
        state: tuple[np.ndarray, np.ndarray, np.ndarray],
        torque: np.ndarray,
        theta: np.ndarray,
        readings: np.ndarray,
        outputs: tuple[np.ndarray, np.ndarray],
    ) -> None:
        """`_accelerometer_periods` on ``state`` (xi, theta_prev, ddq_prev), advanced in
        place, with this observer's constants; ``outputs``: (estimates, diagnostics)."""
        saturation = np.inf if self.velocity_saturation is None else self.velocity_saturation
        work, constants = self._sensors.readings_arguments()
        _accelerometer_periods(
            *state,
            torque,
            theta,
            readings,
            self._step_rows,
            self._ddq_rows,
            float(saturation),
            float(self.dls_threshold),
            float(self.dls_damping),
            work,
            constants,
            *outputs,
        )

    def _periods(self, obs: Mapping, tau: np.ndarray, arms) -> np.ndarray:
        """Eq. (12) over the periods of `obs` (T, N, ...) and `tau` (T, N, n) for `arms`
        (None: all) by `_accelerometer_periods`; the diagnostics of the last period."""
        n, N = self.n, len(self._xi)
        every = arms is None or (isinstance(arms, slice) and arms == slice(None))
        rows = slice(None) if every else arms
        key = "motor_position"
        positions = entry(obs, "obs", key, (None, N, n), f"needs obs[{key!r}]")
        missing = "acceleration='accelerometer' needs obs['acceleration']"
        shape = (None, N, 3 * self.model.n_sensors)
        readings = entry(obs, "obs", "acceleration", shape, missing)
        theta = np.ascontiguousarray(positions[:, rows], dtype=float)
        readings = np.ascontiguousarray(readings[:, rows], dtype=float)
        torque = np.ascontiguousarray(tau[:, rows], dtype=float)
        xi = np.ascontiguousarray(self._xi[rows])
        theta_prev = np.ascontiguousarray(self._theta[rows])
        ddq_prev = np.ascontiguousarray(self._ddq[rows])
        T, count = theta.shape[:2]
        out = np.empty((T, count, 4 * n))
        singular = np.empty((T, count, 3))
        self._run_periods((xi, theta_prev, ddq_prev), torque, theta, readings, (out, singular))
        self._xi[rows], self._theta[rows], self._ddq[rows] = xi, theta_prev, ddq_prev
        if T:
            self._record_singular(rows if not every else slice(None), singular[-1])
        if every:
            return out
        full = np.empty((T, N, 4 * n))
        full[:] = self._xi  # the arms not advanced keep their estimates
        full[:, rows] = out
        return full
