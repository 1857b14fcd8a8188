"""INVDYN: the inverse dynamics of the elastic arm along a desired link trajectory.

De Luca, Schroeder & Thuemmel (ICRA 2007), Sec. V-B: the controller (13) needs ``(x_d, tau_d) =
INVDYN(q_d, q_d', q_d'', q_d''', q_d'''')``, the state x_d = (theta_d, q_d, theta_d', q_d') and the
motor torque tau_d under which the nominal model (1) or (2) moves its links exactly along q_d(t).
With the torsion delta = theta - q the link equation reads K delta + D delta' = tau_J, tau_J = tau_r
+ S theta_d'', tau_r = M(q_d) q_d'' + C(q_d, q_d') q_d' + g(q_d) + d(q_d'), and the motor equation
gives tau_d = B theta_d'' + S^T q_d'' + tau_J. For D = 0, delta = K^-1 tau_J is algebraic (q_d^(4)
needed); for D > 0 [`TorsionFilter`][elastic_gym.controllers.invdyn.TorsionFilter] integrates the
internal dynamics exactly for a cubic Hermite tau_J over each period. tau_r' is exact, by the
complex step of the compiled RNEA
([`rnea_tangent`][elastic_gym.model.chain.SerialChain.rnea_tangent]), tau_r'' a central difference
of it (O(h^2)). The S terms are exact when S^2 = 0 (the KR15). For rigid arms INVDYN is the computed
torque. Every class runs N arms at once (the single arm: N = 1).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Annotated

import numpy as np
from numba import njit
from pydantic import Field
from scipy.special import factorial

from elastic_gym import arms
from elastic_gym.arms import REFERENCE_KEYS
from elastic_gym.model import RobotModel
from elastic_gym.validation import entry, option_value, shaped

DEFAULT_FD_STEP = 1e-4
FdStep = Annotated[float, Field(strict=True, gt=0.0, lt=0.1, allow_inf_nan=False)]
"""The central-difference step (s) of tau_r'' inside INVDYN."""
PUBLIC_INFO = "(pass public_info(info) of the env step)"
TIME_TOLERANCE = 1e-9  # s; calls closer in time than this count as the same instant
REFERENCE_SET = frozenset(REFERENCE_KEYS)


def reference_derivatives(info: Mapping, n: int) -> np.ndarray:
    """The desired trajectory q_d .. q_d^(4) of ``info["reference"]`` as a (5, N) array."""
    return checked_reference_rows(info, n, None)


def checked_reference_rows(info: Mapping, n: int, n_arms: int | None) -> np.ndarray:
    """``info["reference"]`` as (n_arms, 5, n) (batched info) or (5, n) (``n_arms`` None)
    (`elastic_gym.arms.reference_rows`), checked: a clear error for a missing key,
    a wrong shape or a non-finite entry."""
    reference = info.get("reference") if isinstance(info, Mapping) else None
    if not isinstance(reference, Mapping) or not reference.keys() >= REFERENCE_SET:
        raise ValueError(
            f"controller needs info['reference'] with keys {REFERENCE_KEYS} {PUBLIC_INFO}"
        )
    shape = (len(REFERENCE_KEYS), n) if n_arms is None else (n_arms, len(REFERENCE_KEYS), n)
    return shaped(arms.reference_rows(info), shape, "info['reference'] rows", finite=True)


def state_vector(obs: Mapping, dim: int, n_arms: int | None = None) -> np.ndarray:
    """``obs["state"]`` (from an ObserverWrapper / TrueStateWrapper) checked: (dim,), or
    (n_arms, dim) for a batch."""
    shape = (dim,) if n_arms is None else (n_arms, dim)
    missing = "controller needs obs['state']: wrap the env in ObserverWrapper or TrueStateWrapper"
    return entry(obs, "obs", "state", shape, missing)


def info_time(info: Mapping, n_arms: int | None = None) -> float | np.ndarray:
    """``info["time"]``: a float, or (n_arms,) finite times for a batch."""
    shape = None if n_arms is None else (n_arms,)
    t = entry(info, "info", "time", shape, f"controller needs info['time'] {PUBLIC_INFO}", True)
    return float(t) if n_arms is None else t


def taylor_matrix(h: float, order: int = len(REFERENCE_KEYS)) -> np.ndarray:
    """T with (T @ ref)[k] = sum_j ref[j] h^(j-k) / (j-k)!: derivatives at t + h from those at t."""
    k = np.arange(order)
    power = np.clip(k[None, :] - k[:, None], 0, None)
    return np.triu(h**power / factorial(power))


def _arms_first(ref: np.ndarray) -> tuple[np.ndarray, bool]:
    """A reference (5, n) or (N, 5, n) as (N, 5, n), and whether it was a single arm."""
    ref = np.asarray(ref, dtype=float)
    return (ref[None], True) if ref.ndim == 2 else (ref, False)


class RigidTorque:
    """tau_r = M q'' + C q' + g + d(q') along a trajectory, with its time derivatives.

    Every method takes the reference q_d .. q_d^(4) of one arm (5, n) or of N arms
    (N, 5, n) and evaluates all arms in one call of the model's
    [`SerialChain`][elastic_gym.model.SerialChain] kernels.
    """

    def __init__(self, model: RobotModel, fd_step: float = DEFAULT_FD_STEP) -> None:
        self.model = model
        self.fd_step = option_value("fd_step", fd_step, FdStep, prefix="")
        self._ahead = taylor_matrix(self.fd_step)
        self._behind = taylor_matrix(-self.fd_step)

    def _with_derivative(self, ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(tau_r, tau_r') of (N, 5, n) references; tau_r' exact (complex-step RNEA
        tangent along (q_d', q_d'', q_d''') plus the friction slope)."""
        q, dq, ddq, d3q = ref[:, 0], ref[:, 1], ref[:, 2], ref[:, 3]
        tau, dtau = self.model.chain.rnea_tangent((q, dq, ddq), (dq, ddq, d3q))
        friction = self.model.friction
        if friction is not None:
            tau = tau + friction.torque(dq)
            dtau = dtau + friction.derivative(dq) * ddq
        return tau, dtau

    def derivatives(self, ref: np.ndarray, second: bool = True) -> tuple[np.ndarray, ...]:
        """(tau_r, tau_r', tau_r'') of (N, 5, n) references in one kernel call; tau_r'' is
        the central difference (tau_r'(t + h) - tau_r'(t - h)) / 2h of the exact tau_r'
        along the Taylor expansion of the reference (zero when ``second`` is False)."""
        N = len(ref)
        if not second:
            return (*self._with_derivative(ref), np.zeros((N, self.model.n)))
        points = np.concatenate([ref, self._ahead @ ref, self._behind @ ref])
        tau, dtau = self._with_derivative(points)
        ddtau = (dtau[N : 2 * N] - dtau[2 * N :]) / (2.0 * self.fd_step)
        return tau[:N], dtau[:N], ddtau

    def torque(self, ref: np.ndarray) -> np.ndarray:
        arms, single = _arms_first(ref)
        q, dq, ddq = arms[:, 0], arms[:, 1], arms[:, 2]
        tau = self.model.chain.rnea(q, dq, ddq) + self.model.link_friction(dq)
        return tau[0] if single else tau

    def first_derivative(self, ref: np.ndarray) -> np.ndarray:
        """Exact tau_r'."""
        arms, single = _arms_first(ref)
        dtau = self._with_derivative(arms)[1]
        return dtau[0] if single else dtau

    def second_derivative(self, ref: np.ndarray) -> np.ndarray:
        """tau_r'' by a central difference of the exact tau_r' (error O(fd_step^2))."""
        arms, single = _arms_first(ref)
        ddtau = self.derivatives(arms)[2]
        return ddtau[0] if single else ddtau


@njit(cache=True)
def _torsion_kernel(t, u, du, ddu, K, D, viscous, rate, c, clock, v0, dv0, delta, out):
    """One `TorsionFilter.update` of N arms (rows), joint by joint (see there)."""
    N, n = u.shape
    for i in range(N):
        first = np.isnan(clock[i])
        ahead = t[i] > clock[i] + TIME_TOLERANCE  # False when not started (NaN)
        h = t[i] - clock[i]
        for j in range(n):
            k, cj = K[j], c[j]
            v, dv, ddv = u[i, j] / k, du[i, j] / k, ddu[i, j] / k  # static torsion, derivatives
            if first:  # quasi-static start, exact at rest
                d = v - cj * (dv - cj * (ddv - cj * 0.0))
            elif ahead:  # exact solution for the cubic Hermite interpolant of u over h
                a0, m0 = v0[i, j], dv0[i, j]
                slope = (v - a0) / h
                dd0 = (6.0 * slope - 4.0 * m0 - 2.0 * dv) / h
                dd1 = (-6.0 * slope + 2.0 * m0 + 4.0 * dv) / h
                d3 = (6.0 * (m0 + dv) - 12.0 * slope) / h**2
                start = a0 - cj * (m0 - cj * (dd0 - cj * d3))
                end = v - cj * (dv - cj * (dd1 - cj * d3))
                d = end + np.exp(-rate[j] * h) * (delta[i, j] - start)
            else:  # same instant (up to rounding): no time to integrate over
                d = delta[i, j]
            v0[i, j], dv0[i, j] = v, dv
            if viscous[j]:
                d1 = (u[i, j] - k * d) / D[j]
                d2 = (du[i, j] - k * d1) / D[j]
                d3o = (ddu[i, j] - k * d2) / D[j]
            else:
                d, d1, d2, d3o = v, dv, ddv, 0.0
            delta[i, j] = d
            out[0, i, j], out[1, i, j], out[2, i, j], out[3, i, j] = d, d1, d2, d3o
        if first or ahead:
            clock[i] = t[i]


@njit(cache=True)
def _torsion_trajectory_kernel(t, u, du, ddu, K, D, viscous, rate, c, clock, v0, dv0, delta, out):
    """T successive `TorsionFilter.update` of one arm, row k at time t[k] (each into a
    C-contiguous row, then copied: `update`'s signature of the kernel, not a second one for
    a strided slice of ``out``)."""
    row = np.empty((out.shape[0], 1, out.shape[2]))
    for k in range(len(t)):
        _torsion_kernel(
            t[k : k + 1],
            u[k : k + 1],
            du[k : k + 1],
            ddu[k : k + 1],
            K,
            D,
            viscous,
            rate,
            c,
            clock,
            v0,
            dv0,
            delta,
            row,
        )
        for order in range(out.shape[0]):
            for j in range(out.shape[2]):
                out[order, k, j] = row[order, 0, j]


class TorsionFilter:
    """Exact integration of K delta + D delta' = u(t), per joint (D = 0 joints: algebraic).

    ``update(t, u, du, ddu)`` advances from the previous call with u the cubic
    Hermite interpolant of (u, u') at both ends, for which the ODE has a closed-form
    solution (the polynomial particular solution sum_k (-1/a)^k v^(k), v = u / K, a = K / D,
    plus a decaying exponential), and returns delta and its first three derivatives (the
    third is exact for D > 0 joints and zero (neglected) for D = 0). With ``n_arms`` the
    state holds N arms: u and its derivatives are (N, n), t is one time per arm (N,) and
    ``reset(arms)`` restarts some of them; without it, u is (n,) and t a number. The update
    of all arms is one compiled loop.
    """

    def __init__(self, stiffness: np.ndarray, damping: np.ndarray, n_arms: int | None = None):
        self.K = np.asarray(stiffness, dtype=float)
        D = np.asarray(damping, dtype=float)
        self.viscous = D > 0.0
        self.D = np.where(self.viscous, D, 1.0)  # safe divisor; D = 0 joints are masked
        self.rate = np.where(self.viscous, self.K / self.D, 0.0)  # a = K / D
        self.time_constant = np.where(self.viscous, self.D / self.K, 0.0)  # 1 / a
        self.single = n_arms is None
        shape = (1 if n_arms is None else n_arms, len(self.K))
        self._time = np.full(shape[0], np.nan)  # NaN: not started
        self._v = np.zeros(shape)
        self._dv = np.zeros(shape)
        self._delta = np.zeros(shape)

    @property
    def delta(self) -> np.ndarray:
        """The torsion: (n,) without ``n_arms``, else (N, n)."""
        return self._delta[0] if self.single else self._delta

    @delta.setter
    def delta(self, value: np.ndarray) -> None:
        self._delta[:] = value

    def reset(self, arms: np.ndarray | None = None) -> None:
        """Restart every arm (or ``arms``): the next update starts at the quasi-static torsion."""
        index = ... if arms is None else arms
        self._time[index] = np.nan
        self._v[index] = 0.0
        self._dv[index] = 0.0
        self._delta[index] = 0.0

    def update(
        self, t, u: np.ndarray, du: np.ndarray, ddu: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        shape = self._delta.shape
        t = self._checked_times(np.ascontiguousarray(t, dtype=np.float64).reshape(shape[0]))
        out = np.empty((4, *shape))
        rows, state = self._rows(shape, u, du, ddu), self._kernel_state()
        _torsion_kernel(t, *rows, *state, out)  # type: ignore[call-arg]  # stub: no star-args
        d0, d1, d2, d3 = out[:, 0] if self.single else out
        return d0, d1, d2, d3

    def trajectory(
        self, times, u: np.ndarray, du: np.ndarray, ddu: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """T successive `update` of a one-arm filter at increasing ``times`` (T,),
        u and its derivatives (T, n), in one compiled loop: the (T, n) torsions and
        derivatives, exactly those of the T updates."""
        if len(self._delta) != 1:
            raise ValueError("trajectory() filters one arm, not a batch of them")
        times = np.ascontiguousarray(times, dtype=np.float64).reshape(-1)
        self._checked_times(times[:1])
        if np.any(np.diff(times) < -TIME_TOLERANCE):
            raise ValueError("trajectory() needs increasing times")
        shape = (len(times), len(self.K))
        out = np.empty((4, *shape))
        rows, state = self._rows(shape, u, du, ddu), self._kernel_state()
        _torsion_trajectory_kernel(times, *rows, *state, out)  # type: ignore[call-arg]  # stub
        d0, d1, d2, d3 = out
        return d0, d1, d2, d3

    def _checked_times(self, t: np.ndarray) -> np.ndarray:
        back = t < self._time - TIME_TOLERANCE  # False where not started (NaN)
        if back.any():
            raise ValueError(
                f"controller time went back from {self._time[back]} to {t[back]}; call reset()"
            )
        return t

    @staticmethod
    def _rows(shape, *arrays) -> tuple[np.ndarray, ...]:
        return tuple(np.ascontiguousarray(a, dtype=np.float64).reshape(shape) for a in arrays)

    def _kernel_state(self) -> tuple[np.ndarray, ...]:
        """The constants and the memory the kernels read and update in place."""
        return (
            self.K,
            self.D,
            self.viscous,
            self.rate,
            self.time_constant,
            self._time,
            self._v,
            self._dv,
            self._delta,
        )


class InverseDynamics:
    """INVDYN of De Luca et al. (Sec. V-B) for model (1), model (2) and rigid arms.

    Call ``invdyn(t, ref)`` with ``ref`` the (5, n) array q_d .. q_d^(4) at time t,
    once per control period in increasing time (the torsion filter has memory);
    ``reset()`` at the start of every episode. Returns (x_d, tau_d).
    With ``n_arms`` it runs N arms at once: ``ref`` (N, 5, n), ``t`` (N,), returns
    (N, dim) and (N, n), ``reset(arms)`` restarts some arms; each arm's result is the
    single-arm one. See the module docstring for how D and S are handled.
    """

    def __init__(
        self, model: RobotModel, fd_step: float = DEFAULT_FD_STEP, n_arms: int | None = None
    ) -> None:
        self.model = model
        self.n = model.n
        self.single = n_arms is None
        arms = 1 if n_arms is None else n_arms
        self.rigid_torque = RigidTorque(model, fd_step)
        if model.elastic:
            self.filter = TorsionFilter(model.K, model.D, arms)
            # torsion of the uncoupled model (1), used inside the S theta_d'' term
            self.uncoupled_filter = (
                TorsionFilter(model.K, model.D, arms) if model.has_coupling else None
            )
            self.needs_second = model.has_coupling or bool(np.any(model.D == 0.0))

    def reset(self, arms: np.ndarray | None = None) -> None:
        if self.model.elastic:
            self.filter.reset(arms)
            if self.uncoupled_filter is not None:
                self.uncoupled_filter.reset(arms)

    def __call__(self, t, ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ref = np.asarray(ref, dtype=float)
        x_d, tau_d = self._arms(t, ref[None] if self.single else ref)
        return (x_d[0], tau_d[0]) if self.single else (x_d, tau_d)

    def trajectory(self, times: np.ndarray, refs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """INVDYN at each of one arm's increasing ``times`` (T,) with ``refs`` (T, 5, n):
        exactly the rows of T successive calls, with the rigid torques of all T periods in
        one kernel call (only the torsion filter steps period by period). Returns (T, dim)
        and (T, n). For a single-arm instance (no ``n_arms``)."""
        if not self.single:
            raise ValueError("trajectory() plans one arm: build InverseDynamics without n_arms")
        refs = np.asarray(refs, dtype=float)
        if not self.model.elastic:
            return self._arms(None, refs)
        rigid = self.rigid_torque.derivatives(refs, self.needs_second)
        times = np.asarray(times, dtype=float)
        return self._state_and_torque(refs, *self._torsion(times, refs, *rigid, trajectory=True))

    def _arms(self, t, ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if not self.model.elastic:
            return np.concatenate([ref[:, 0], ref[:, 1]], axis=1), self.rigid_torque.torque(ref)
        rigid = self.rigid_torque.derivatives(ref, self.needs_second)
        return self._state_and_torque(ref, *self._torsion(t, ref, *rigid))

    def _torsion(self, t, ref, tau_r, dtau_r, ddtau_r, *, trajectory=False) -> tuple:
        """The torsion delta, delta', delta'' and tau_J at time ``t`` from the rigid
        torques: one update of the torsion filter(s), or T of them along a
        ``trajectory`` (``t`` (T,), one arm's rows)."""

        def update(f: TorsionFilter, *rows):
            return f.trajectory(*rows) if trajectory else f.update(*rows)

        if self.uncoupled_filter is None:
            delta, d1, d2, _ = update(self.filter, t, tau_r, dtau_r, ddtau_r)
            return delta, d1, d2, tau_r
        S_T = self.model.S.T
        _, _, c2, c3 = update(self.uncoupled_filter, t, tau_r, dtau_r, ddtau_r)
        tau_j = tau_r + (ref[:, 2] + c2) @ S_T
        dtau_j = dtau_r + (ref[:, 3] + c3) @ S_T
        ddtau_j = ddtau_r + ref[:, 4] @ S_T  # S delta0 neglected (used only if D = 0)
        delta, d1, d2, _ = update(self.filter, t, tau_j, dtau_j, ddtau_j)
        return delta, d1, d2, tau_j

    def _state_and_torque(self, ref, delta, d1, d2, tau_j) -> tuple[np.ndarray, np.ndarray]:
        """x_d = (q_d + delta, q_d, q_d' + delta', q_d') and tau_d = B theta_d'' + S^T q_d''
        + tau_J (module docstring)."""
        q, dq, ddq = ref[:, 0], ref[:, 1], ref[:, 2]
        x_d = np.concatenate([q + delta, q, dq + d1, dq], axis=1)
        return x_d, self.model.B * (ddq + d2) + ddq @ self.model.S + tau_j


class LinkMassSensitivity:
    """How INVDYN's (x_d, tau_d) change with the link masses of the model, for N arms.

    ``link_mass`` scaling ([`ParameterScaling`][elastic_gym.model.ParameterScaling]) multiplies all
    inertial parameters of a link (mass, first moment, rotational inertia) by s_i. The
    RNEA torque tau_r is linear in them, and INVDYN (Sec. V-B) is linear in tau_r: the
    torsion equation K delta + D delta' = tau_J is linear, theta_d = q_d + delta and
    tau_d = B theta_d'' + S^T q_d'' + tau_J. So INVDYN of a model with scales s is exactly

        (x_d, tau_d)(s) = (x_d, tau_d)(1) + sum_i (s_i - 1) (d x_d / d s_i, d tau_d / d s_i),

    the derivative of link i being INVDYN of the model with link i twice as heavy minus
    the nominal one. Call ``sensitivity(t, ref, x_d, tau_d)`` with the nominal INVDYN's
    (x_d, tau_d) of the same call (same times, increasing, as for `InverseDynamics`).
    Without ``feedforward`` the reference is the static one (`static_reference`),
    also linear in the masses.
    """

    def __init__(
        self, model: RobotModel, fd_step: float, n_arms: int, feedforward: bool = True
    ) -> None:
        heavier = np.eye(model.n) + 1.0  # row i: link i twice as heavy
        self.models = [model.perturbed(link_mass=tuple(row)) for row in heavier]
        self.invdyn = (
            [InverseDynamics(m, fd_step, n_arms) for m in self.models] if feedforward else []
        )

    def reset(self, arms: np.ndarray | None = None) -> None:
        for invdyn in self.invdyn:
            invdyn.reset(arms)

    def __call__(
        self, t, ref: np.ndarray, x_d: np.ndarray, tau_d: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """(d x_d / d s (N, n, dim), d tau_d / d s (N, n, n)), row i of each arm: link i."""
        if self.invdyn:
            rows = [invdyn(t, ref) for invdyn in self.invdyn]
        else:
            rows = [static_reference(model, ref) for model in self.models]
        dx = np.stack([x - x_d for x, _ in rows], axis=1)
        dtau = np.stack([tau - tau_d for _, tau in rows], axis=1)
        return dx, dtau


def fit_link_masses(state_sensitivity: np.ndarray, motor_error: np.ndarray, shared: bool):
    """The link-mass scales s - 1 (N, n, or N, 1 if ``shared``) that explain a motor
    position error at standstill: a static load identification from the encoders.

    theta_d of INVDYN is linear in the scales (`LinkMassSensitivity`): at rest in
    the static equilibrium of links s times the model's, q = q_d and theta - theta_d(1) =
    J (s - 1), J (n, n) the columns d theta_d / d s_i (the motor rows of
    ``state_sensitivity`` (N, n, dim)), summed into one for a shared scale. The answer is
    the damped least-squares solution (damping 1e-6 of the mean eigenvalue of J^T J).
    ``motor_error`` (N, n): theta - theta_d(1) of the same call.
    """
    n = motor_error.shape[1]
    columns = state_sensitivity[:, :, :n]  # (N, n links, n joints)
    if shared:
        columns = columns.sum(axis=1, keepdims=True)
    normal = np.matmul(columns, columns.transpose(0, 2, 1))  # J^T J (N, size, size)
    size = normal.shape[-1]
    damping = 1e-6 * np.trace(normal, axis1=1, axis2=2) / size + 1e-300
    normal = normal + damping[:, None, None] * np.eye(size)
    right = np.matmul(columns, motor_error[:, :, None])  # J^T (theta - theta_d)
    return np.linalg.solve(normal, right)[:, :, 0]


def static_reference(model: RobotModel, ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Reference without INVDYN: the gravity-compensated static state at q_d.

    Elastic: x_d = (q_d + K^-1 g(q_d), q_d, q_d', q_d'), tau_d = g(q_d);
    rigid: x_d = (q_d, q_d'), tau_d = g(q_d). ``ref`` (5, n) or (N, 5, n).
    """
    arms, single = _arms_first(ref)
    q, dq = arms[:, 0], arms[:, 1]
    g = model.chain.gravity(q)
    blocks = [q, dq] if not model.elastic else [q + g / model.K, q, dq, dq]
    x_d = np.concatenate(blocks, axis=1)
    return (x_d[0], g[0]) if single else (x_d, g)
