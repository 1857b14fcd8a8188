"""The link side of the elastic-joint model, linear in its parameters.

De Luca et al. (2007), eq. (1): M(q) q'' + C(q, q') q' + g(q) + d(q') = tau_J, with link
friction d_j = F_v,j q'_j + F_c,j tanh(q'_j / v_s) (as the package's `LinkFriction`). The
left side is linear in the ten inertial parameters of every body (pinocchio's
`computeJointTorqueRegressor`) and in the friction coefficients. Two parametrizations:
one scale per link (`LinkColumns`: body i's parameters s_i times the nominal ones, the
`link_mass` of `ParameterScaling`; physically consistent, the model observers and
controllers get) and the base parameters (`BaseParameters`: the regressor's linearly
independent columns over generic motions by QR with column pivoting, Gautier & Khalil
1990, each a combination of the standard parameters; reported with standard errors).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin
from scipy.linalg import qr, solve_triangular

from elastic_gym.model import RobotModel, SerialChain

STANDARD_NAMES = ("m", "mx", "my", "mz", "Ixx", "Ixy", "Iyy", "Ixz", "Iyz", "Izz")


class LinkColumns:
    """Per-body torque columns of the link side: tau = sum_i s_i Y_i(q, q', q'')."""

    def __init__(self, model: RobotModel) -> None:
        self.n = model.n
        self.chains = []
        for body in range(1, model.n + 1):
            alone = model.pin_model.copy()
            for other in range(1, model.n + 1):
                if other != body:
                    alone.inertias[other] = pin.Inertia.Zero()
            self.chains.append(SerialChain(alone))

    def __call__(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
        """(N, n joints, n bodies): column i is body i's M q'' + C q' + g."""
        q, dq, ddq = (np.ascontiguousarray(x) for x in (q, dq, ddq))
        return np.stack([chain.rnea(q, dq, ddq) for chain in self.chains], axis=-1)

    def mass_and_bias(self, q: np.ndarray, dq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per body i: M_i(q) (N, n, n, bodies) and C_i(q, q') q' + g_i(q) (N, n, bodies),
        so that the columns are M_i q'' + (C_i q' + g_i) for any q''."""
        q, dq = np.ascontiguousarray(q), np.ascontiguousarray(dq)
        parts = [chain.mass_and_bias(q, dq) for chain in self.chains]
        return np.stack([M for M, _ in parts], axis=-1), np.stack([h for _, h in parts], axis=-1)


def coulomb_column(dq: np.ndarray, smoothing_velocity: float) -> np.ndarray:
    """tanh(q' / v_s), the smoothed sign of `LinkFriction`."""
    return np.tanh(dq / smoothing_velocity)


def body_names(model: RobotModel) -> tuple[str, ...]:
    """The URDF link moved by each joint (the first body frame of the joint)."""
    pm = model.pin_model
    names = []
    for j in range(1, model.n + 1):
        bodies = [f.name for f in pm.frames if f.type == pin.FrameType.BODY and f.parentJoint == j]
        names.append(bodies[0] if bodies else pm.names[j])
    return tuple(names)


def _regressor(model: RobotModel, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
    """Stacked joint torque regressors (N n, 10 n) at the samples (rows: sample-major)."""
    pm, data = model.pin_model, model.pin_model.createData()
    n = model.n
    out = np.empty((len(q) * n, 10 * n))
    for k in range(len(q)):
        out[k * n : (k + 1) * n] = pin.computeJointTorqueRegressor(pm, data, q[k], dq[k], ddq[k])
    return out


@dataclass(frozen=True)
class BaseParameters:
    """The identifiable combinations of the standard inertial parameters.

    ``independent``: indices of the standard parameters kept as base columns;
    ``combination``: (base, standard) matrix, base = combination @ standard;
    ``names``: one readable expression per base parameter.
    """

    independent: np.ndarray
    combination: np.ndarray
    names: tuple[str, ...]

    @classmethod
    def of(cls, model: RobotModel, samples: int = 40, seed: int = 0) -> BaseParameters:
        """The base parameters of ``model``'s chain, from its regressor at random motions
        (rank by QR with column pivoting, tolerance 1e-8 of the largest pivot)."""
        rng = np.random.default_rng(seed)
        n = model.n
        low = np.asarray(model.spec.workspace_low) - 0.5
        high = np.asarray(model.spec.workspace_high) + 0.5
        q = rng.uniform(low, high, (samples, n))
        dq, ddq = rng.normal(0, 2, (samples, n)), rng.normal(0, 5, (samples, n))
        W = _regressor(model, q, dq, ddq)
        scale = np.linalg.norm(W, axis=0)
        used = np.flatnonzero(scale > 1e-9 * max(scale.max(), 1.0))
        _, R, perm = qr(W[:, used] / scale[used], mode="economic", pivoting=True)
        diag = np.abs(np.diag(R))
        rank = int(np.sum(diag > 1e-8 * diag[0]))
        order = used[perm]
        kept, rest = order[:rank], order[rank:]
        combination = np.zeros((rank, 10 * n))
        combination[np.arange(rank), kept] = 1.0
        if len(rest):
            # W_rest = W_kept X (in scaled columns): base = pi_kept + X pi_rest
            X = solve_triangular(R[:rank, :rank], R[:rank, rank:])
            combination[:, rest] = X * scale[rest][None, :] / scale[kept][:, None]
        links = body_names(model)
        names = tuple(_expression(row, kept[i], links) for i, row in enumerate(combination))
        return cls(kept, combination, names)

    def nominal(self, model: RobotModel, mass_scale: np.ndarray | None = None) -> np.ndarray:
        """The base parameters of ``model``'s bodies (each scaled by ``mass_scale``)."""
        scale = np.ones(model.n) if mass_scale is None else np.asarray(mass_scale)
        standard = np.concatenate(
            [
                scale[j - 1] * model.pin_model.inertias[j].toDynamicParameters()
                for j in range(1, model.n + 1)
            ]
        )
        return self.combination @ standard

    def columns(self, model: RobotModel, q, dq, ddq) -> np.ndarray:
        """(N, n joints, n base) regressor of the base parameters at the samples."""
        W = _regressor(model, q, dq, ddq)[:, self.independent]
        return W.reshape(len(q), model.n, -1)


def _expression(row: np.ndarray, lead: int, links: tuple[str, ...], tolerance: float = 1e-9) -> str:
    """``link2.mx + 0.5 link3.m``: the standard parameters of a base parameter (first
    moments and inertias in the link's joint frame)."""
    terms = []
    order = [lead] + [k for k in np.flatnonzero(np.abs(row) > tolerance) if k != lead]
    for k in order:
        body, name = divmod(int(k), 10)
        coefficient = row[k]
        label = f"{links[body]}.{STANDARD_NAMES[name]}"
        if k == lead:
            terms.append(label)
        else:
            sign = "-" if coefficient < 0 else "+"
            terms.append(f"{sign} {abs(coefficient):.4g} {label}")
    return " ".join(terms)
