"""INVDYN: the inverse dynamics of the elastic arm along a desired link trajectory.

De Luca, Schroeder & Thuemmel (ICRA 2007), Sec. V-B: the controller (13) needs
``(x_d, tau_d) = INVDYN(q_d, q_d', q_d'', q_d''', q_d'''')``, the state x_d =
(theta_d, q_d, theta_d', q_d') and the motor torque tau_d under which the nominal model
(1) or (2) moves its links exactly along q_d(t). With the torsion delta = theta - q the
link equation reads K delta + D delta' = tau_J, tau_J = tau_r + S theta_d'',
tau_r = M(q_d) q_d'' + C(q_d, q_d') q_d' + g(q_d) + d(q_d'), and the motor equation gives
tau_d = B theta_d'' + S^T q_d'' + tau_J. For D = 0, delta = K^-1 tau_J is algebraic (q_d^(4)
needed); for D > 0 :class:`TorsionFilter` integrates the internal dynamics exactly for a
cubic Hermite tau_J over each period. tau_r' comes from pinocchio's RNEA derivatives,
tau_r'' by a central difference of it (O(h^2)). The S terms are exact when S^2 = 0 (the
KR15). For rigid arms INVDYN is the computed torque: x_d = (q_d, q_d'), tau_d = tau_r.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from scipy.special import factorial

from elastic_gym.model import RobotModel
from elastic_gym.validation import is_real

REFERENCE_KEYS = ("q", "dq", "ddq", "d3q", "d4q")
DEFAULT_FD_STEP = 1e-4
TIME_TOLERANCE = 1e-9  # s; calls closer in time than this count as the same instant


def reference_derivatives(info: Mapping, n: int) -> np.ndarray:
    """The desired trajectory q_d .. q_d^(4) of ``info["reference"]`` as a (5, N) array."""
    reference = info.get("reference") if isinstance(info, Mapping) else None
    if not isinstance(reference, Mapping) or any(k not in reference for k in REFERENCE_KEYS):
        raise ValueError(
            f"controller needs info['reference'] with keys {REFERENCE_KEYS} "
            "(pass public_info(info) of the env step)"
        )
    ref = np.array([np.asarray(reference[k], dtype=float) for k in REFERENCE_KEYS])
    if ref.shape != (len(REFERENCE_KEYS), n) or not np.all(np.isfinite(ref)):
        raise ValueError(f"info['reference'] must hold 5 finite {n}-vectors, got shape {ref.shape}")
    return ref


def state_vector(obs: Mapping, dim: int) -> np.ndarray:
    """``obs["state"]`` (from an ObserverWrapper / TrueStateWrapper) as a checked vector."""
    if not isinstance(obs, Mapping) or "state" not in obs:
        raise ValueError(
            "controller needs obs['state']: wrap the env in ObserverWrapper or TrueStateWrapper"
        )
    x = np.asarray(obs["state"], dtype=float)
    if x.shape != (dim,):
        raise ValueError(f"obs['state'] must have {dim} entries, got shape {x.shape}")
    return x


def info_time(info: Mapping) -> float:
    """``info["time"]`` as a float, with a clear error when missing."""
    if not isinstance(info, Mapping) or "time" not in info:
        raise ValueError("controller needs info['time'] (pass public_info(info) of the env step)")
    return float(info["time"])


def taylor_matrix(h: float, order: int = len(REFERENCE_KEYS)) -> np.ndarray:
    """T with (T @ ref)[k] = sum_j ref[j] h^(j-k) / (j-k)!: derivatives at t + h from those at t."""
    k = np.arange(order)
    power = np.clip(k[None, :] - k[:, None], 0, None)
    return np.triu(h**power / factorial(power))


class RigidTorque:
    """tau_r = M q'' + C q' + g + d(q') along a trajectory, with its time derivatives."""

    def __init__(self, model: RobotModel, fd_step: float = DEFAULT_FD_STEP) -> None:
        if not (is_real(fd_step) and 0.0 < fd_step < 0.1):
            raise ValueError(f"fd_step must be a number in (0, 0.1) s, got {fd_step!r}")
        self.model = model
        self.fd_step = float(fd_step)
        self._ahead = taylor_matrix(self.fd_step)
        self._behind = taylor_matrix(-self.fd_step)

    def torque(self, ref: np.ndarray) -> np.ndarray:
        model = self.model
        return model.rnea(ref[0], ref[1], ref[2]) + model.link_friction(ref[1])

    def first_derivative(self, ref: np.ndarray) -> np.ndarray:
        """Exact tau_r' from the analytic RNEA derivatives."""
        model = self.model
        dtau_dq, dtau_dv, M = model.rnea_derivatives(ref[0], ref[1], ref[2])
        dtau = dtau_dq @ ref[1] + dtau_dv @ ref[2] + M @ ref[3]
        if model.friction is not None:
            dtau = dtau + model.friction.derivative(ref[1]) * ref[2]
        return dtau

    def second_derivative(self, ref: np.ndarray) -> np.ndarray:
        """tau_r'' by a central difference of the exact tau_r' (error O(fd_step^2))."""
        ahead = self.first_derivative(self._ahead @ ref)
        behind = self.first_derivative(self._behind @ ref)
        return (ahead - behind) / (2.0 * self.fd_step)


class TorsionFilter:
    """Exact integration of K delta + D delta' = u(t), per joint (D = 0 joints: algebraic).

    ``update(t, u, du, ddu)`` advances from the previous call with u the cubic
    Hermite interpolant of (u, u') at both ends, and returns delta and its first three
    derivatives (the third is exact for D > 0 joints and zero (neglected) for D = 0).
    """

    def __init__(self, stiffness: np.ndarray, damping: np.ndarray) -> None:
        self.K = np.asarray(stiffness, dtype=float)
        D = np.asarray(damping, dtype=float)
        self.viscous = D > 0.0
        self.D = np.where(self.viscous, D, 1.0)  # safe divisor; D = 0 joints are masked
        self.rate = np.where(self.viscous, self.K / self.D, 0.0)  # a = K / D
        self.time_constant = np.where(self.viscous, self.D / self.K, 0.0)  # 1 / a
        self.reset()

    def reset(self) -> None:
        self._time: float | None = None
        self._v = np.zeros_like(self.K)
        self._dv = np.zeros_like(self.K)
        self.delta = np.zeros_like(self.K)

    def _particular(self, v: np.ndarray, dv: np.ndarray, ddv: np.ndarray, d3v) -> np.ndarray:
        """Polynomial particular solution sum_k (-1/a)^k v^(k) of delta' = a (v - delta)."""
        c = self.time_constant
        return v - c * (dv - c * (ddv - c * d3v))

    def _advance(self, h: float, v: np.ndarray, dv: np.ndarray) -> None:
        v0, m0 = self._v, self._dv
        slope = (v - v0) / h
        dd0 = (6.0 * slope - 4.0 * m0 - 2.0 * dv) / h
        dd1 = (-6.0 * slope + 2.0 * m0 + 4.0 * dv) / h
        d3 = (6.0 * (m0 + dv) - 12.0 * slope) / h**2
        start = self._particular(v0, m0, dd0, d3)
        end = self._particular(v, dv, dd1, d3)
        self.delta = end + np.exp(-self.rate * h) * (self.delta - start)

    def update(
        self, t: float, u: np.ndarray, du: np.ndarray, ddu: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        K, D = self.K, self.D
        v, dv, ddv = u / K, du / K, ddu / K  # the static torsion and its derivatives
        if self._time is None:
            self.delta = self._particular(v, dv, ddv, 0.0)  # quasi-static start, exact at rest
        elif t < self._time - TIME_TOLERANCE:
            raise ValueError(f"controller time went back from {self._time} to {t}; call reset()")
        elif t > self._time + TIME_TOLERANCE:
            self._advance(t - self._time, v, dv)
        else:  # same instant (up to rounding): no time to integrate over
            t = self._time
        self._time, self._v, self._dv = t, v, dv
        viscous = self.viscous
        self.delta = delta = np.where(viscous, self.delta, v)
        d1 = np.where(viscous, (u - K * delta) / D, dv)
        d2 = np.where(viscous, (du - K * d1) / D, ddv)
        d3 = np.where(viscous, (ddu - K * d2) / D, 0.0)
        return delta, d1, d2, d3


class InverseDynamics:
    """INVDYN of De Luca et al. (Sec. V-B) for model (1), model (2) and rigid arms.

    Call ``invdyn(t, ref)`` with ``ref`` the (5, N) array q_d .. q_d^(4) at time t,
    once per control period in increasing time (the torsion filter has memory);
    ``reset()`` at the start of every episode. Returns (x_d, tau_d).
    See the module docstring for how D and S are handled.
    """

    def __init__(self, model: RobotModel, fd_step: float = DEFAULT_FD_STEP) -> None:
        self.model = model
        self.n = model.n
        self.rigid_torque = RigidTorque(model, fd_step)
        if model.elastic:
            self.filter = TorsionFilter(model.K, model.D)
            # torsion of the uncoupled model (1), used inside the S theta_d'' term
            self.uncoupled_filter = TorsionFilter(model.K, model.D) if model.has_coupling else None
            self.needs_second = model.has_coupling or bool(np.any(model.D == 0.0))

    def reset(self) -> None:
        if self.model.elastic:
            self.filter.reset()
            if self.uncoupled_filter is not None:
                self.uncoupled_filter.reset()

    def __call__(self, t: float, ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        model, rt = self.model, self.rigid_torque
        tau_r = rt.torque(ref)
        if not model.elastic:
            return np.concatenate([ref[0], ref[1]]), tau_r
        dtau_r = rt.first_derivative(ref)
        ddtau_r = rt.second_derivative(ref) if self.needs_second else np.zeros(self.n)
        if self.uncoupled_filter is None:
            tau_j = tau_r
            delta, d1, d2, _ = self.filter.update(t, tau_r, dtau_r, ddtau_r)
        else:
            S = model.S
            _, _, c2, c3 = self.uncoupled_filter.update(t, tau_r, dtau_r, ddtau_r)
            tau_j = tau_r + S @ (ref[2] + c2)
            dtau_j = dtau_r + S @ (ref[3] + c3)
            ddtau_j = ddtau_r + S @ ref[4]  # S delta0 neglected (used only if D = 0)
            delta, d1, d2, _ = self.filter.update(t, tau_j, dtau_j, ddtau_j)
        ddtheta = ref[2] + d2
        x_d = np.concatenate([ref[0] + delta, ref[0], ref[1] + d1, ref[1]])
        tau_d = model.B * ddtheta + model.S.T @ ref[2] + tau_j
        return x_d, tau_d


def static_reference(model: RobotModel, ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Reference without INVDYN: the gravity-compensated static state at q_d.

    Elastic: x_d = (q_d + K^-1 g(q_d), q_d, q_d', q_d'), tau_d = g(q_d);
    rigid: x_d = (q_d, q_d'), tau_d = g(q_d).
    """
    g = model.gravity(ref[0])
    if not model.elastic:
        return np.concatenate([ref[0], ref[1]]), g
    return np.concatenate([ref[0] + g / model.K, ref[0], ref[1], ref[1]]), g
