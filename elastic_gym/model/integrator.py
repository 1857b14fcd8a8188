"""A compiled 4th-order Runge-Kutta integrator of N elastic (or rigid) arms, per-arm plants.

The state of arm k is x = (theta, q, theta', q') (De Luca et al. 2007, eq. (3)); its
derivative follows model (1), model (2) with constant S in the Schur-complement form,
or the rigid equations, with link friction d(q') = F_v q' + c tanh(q' / v_s), under the
motor torque and an external link torque held over a control period (events happen on
period boundaries); M and n come from the chain's Newton-Euler recursion
([`SerialChain`][elastic_gym.model.SerialChain]). One step is the classical RK4 (Hairer,
Norsett & Wanner, *Solving ODEs I*, Table II.1.2) with an embedded third-order error
estimate at no extra cost; the step size is controlled per arm and per control period
(`ArmIntegrator` gives the equations, the estimate and the control). Every arm is
integrated by itself, by the same operations in the same order whatever N: arm i of a
batch is bit-identical to the same arm alone.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from elastic_gym.model.chain import (
    NO_REFCOUNT,
    SerialChain,
    _arm_params,
    _cholesky_solve,
    _mass_and_bias_arm,
    _work_size,
    _workspace,
)
from elastic_gym.model.packed import Packed

MAX_SUBSTEPS = 256
"""The most substeps of one control period by default (the step-size control stops
halving the step there)."""

SHRINK_BELOW = 1.0 / 32.0
"""A period whose largest scaled error is below this lets the next one halve its substeps."""


@dataclass(frozen=True)
class Tolerance:
    """Local error tolerances of one substep: positions (rad) and rates (rad/s)."""

    position: float = 1e-9
    rate: float = 1e-6


@njit(cache=True, inline="always")
def _friction(k, j, v, plant):
    """d(q'_j) of arm k: F_v q' + c tanh(q' / v_s), c = c+ or c- by the sign."""
    viscous, c_pos, c_neg, smoothing, has_friction, has_coulomb = plant[3:9]
    if not has_friction:
        return 0.0
    d = viscous[k, j] * v
    if has_coulomb:
        s = np.tanh(v / smoothing[k])
        d += (c_pos[k, j] if s > 0.0 else c_neg[k, j]) * s
    return d


@njit(cache=True, inline="always")
def _derivative(k, x, tau, ext, plant, arm, ws, buf, out):
    """out = x' of arm k at x (4 n), motor torques ``tau`` (n), link torques ``ext`` (n,
    or an empty array: none). ``arm``: the arm's chain, bodies and -g_W (the chain's
    ``_arm_params``); ``buf``: (4, n) scratch.

    The operations and their order are those of the simulator's transmission kernel and
    the chain's forward dynamics (model (2): S B^-1 (tau - tau_J) summed as the
    simulator's row-wise products; the added inertia -S B^-1 S^T added to M(q), zero for
    model (1)), so that q'' at a state equals the simulator's own q'' there bit for bit.
    """
    n = tau.shape[0]
    K, D, B_inv = plant[0], plant[1], plant[2]
    elastic, coupled, SBinv, schur, ST = plant[9], plant[10], plant[11], plant[12], plant[13]
    chain, bodies_p, minus_gravity = arm
    small, links, bodies, dyn = ws
    M, h, rhs = dyn
    zero_n = bodies[8]
    q = x[n : 2 * n]
    dq = x[3 * n :]
    link, relative, coupled_link = buf[0], buf[1], buf[2]
    for j in range(n):
        out[j] = x[2 * n + j]
        out[n + j] = dq[j]
        friction = _friction(k, j, dq[j], plant)
        if elastic:
            torque = K[k, j] * (x[j] - q[j]) + D[k, j] * (x[2 * n + j] - dq[j])
            link[j] = torque - friction
            relative[j] = tau[j] - torque  # B theta'' (+ S^T q'' for model (2))
        else:
            link[j] = tau[j] - friction
        if ext.shape[0]:
            link[j] += ext[j]
    if coupled:  # tau_J - d + tau_e - S B^-1 (tau - tau_J)
        for a in range(n):
            total = relative[0] * SBinv[k, a, 0]
            for c in range(1, n):
                total = total + relative[c] * SBinv[k, a, c]
            coupled_link[a] = link[a] - total
        link = coupled_link
    _mass_and_bias_arm(
        q, dq, zero_n, minus_gravity, chain, bodies_p, M, h, links, small, bodies, True
    )
    for a in range(n):
        rhs[a] = link[a] - h[a]
        for c in range(n):
            M[a, c] += schur[k, a, c]
    ddq = out[3 * n :]
    _cholesky_solve(M, rhs, ddq)
    for j in range(n):
        if not elastic:
            out[2 * n + j] = ddq[j]
        elif coupled:
            total = ddq[0] * ST[k, j, 0]
            for c in range(1, n):
                total = total + ddq[c] * ST[k, j, c]
            out[2 * n + j] = B_inv[k, j] * (relative[j] - total)
        else:
            out[2 * n + j] = B_inv[k, j] * relative[j]


@njit(cache=True, **NO_REFCOUNT)
def _arm_period(k, x0, tau, ext, period, m, plant, inv_tol, arm, stages, buf, ws):
    """Integrate arm k over ``period`` in m RK4 substeps from x0 (4 n) into stages[5];
    stages[4] = f at the end. Returns the largest scaled error estimate of the substeps
    (stops early once it exceeds 1). m = 0: f(x0) into stages[0] only, returns 0 (the
    right-hand side `rk4_period_kernel` gives at a period of 0). One call site of
    `_derivative` (inlined), in a loop over the stages: five inlined copies of the
    Newton-Euler recursion cost more in instruction cache than the loop's branches, and
    each costs seconds of compile."""
    size = x0.shape[0]
    n = size // 4
    x, xs = stages[5], stages[6]
    h = period / max(m, 1)
    half = 0.5 * h
    sixth = h / 6.0
    for i in range(size):
        x[i] = x0[i]
        xs[i] = x0[i]
    worst = 0.0
    stage = 0
    done = 0
    while True:
        _derivative(k, xs, tau, ext, plant, arm, ws, buf, stages[stage])
        if m == 0:
            return 0.0
        if stage == 4:  # k5 = f(x+): the error of the substep, the next one's k1
            k1, k4, k5 = stages[0], stages[3], stages[4]
            for i in range(size):
                e = abs(sixth * (k4[i] - k5[i])) * (inv_tol[0] if i < 2 * n else inv_tol[1])
                if not e <= worst:  # NaN counts as too large
                    worst = e if e == e else np.inf
            done += 1
            if worst > 1.0 or done == m:
                return worst
            for i in range(size):
                k1[i] = k5[i]
            stage = 1
        else:
            stage += 1
        if stage == 4:  # x+ = x + h (k1 + 2 k2 + 2 k3 + k4) / 6
            k1, k2, k3, k4 = stages[0], stages[1], stages[2], stages[3]
            for i in range(size):
                x[i] = x[i] + sixth * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
                xs[i] = x[i]
        else:
            step = h if stage == 3 else half
            previous = stages[stage - 1]
            for i in range(size):
                xs[i] = x[i] + step * previous[i]


@njit(cache=True, inline="always")
def _arm_start(k, theta, dtheta, q, dq, ext, constants, x0):
    """x0 = (theta, q, theta', q') of arm k, in place; returns its link torques (``ext``'s
    row, empty for none) and its chain, bodies and -g_W (the chain's ``_arm_params``)."""
    n = q.shape[1]
    for j in range(n):
        x0[j] = theta[k, j]
        x0[n + j] = q[k, j]
        x0[2 * n + j] = dtheta[k, j]
        x0[3 * n + j] = dq[k, j]
    arm_ext = ext[k, :0] if ext.shape[1] == 0 else ext[k]
    stacked = constants[1].shape[0] > 1  # rot_p has one row per arm
    chain, bodies_p, _, _, minus_gravity = _arm_params(k if stacked else 0, constants)
    return arm_ext, (chain, bodies_p, minus_gravity)


@njit(cache=True, **NO_REFCOUNT)
def _rk4_arms(theta, dtheta, q, dq, tau, ext, period, substeps, ddq, arguments):
    """`rk4_period_kernel` on its unpacked arguments, compiled without numba's reference
    counting (the kernel allocates nothing: its scratch arrays are packed with the
    plant); the counting of the arrays unpacked at every stage (the workspace, the
    plant) cost half the time of a 2-link arm's right-hand side."""
    plant, constants, w, inv_tol, least, most, stages, buf, x0 = arguments
    N, n = q.shape
    ws = _workspace(n, w)
    work = 0
    for k in range(N):
        arm_ext, arm = _arm_start(k, theta, dtheta, q, dq, ext, constants, x0)
        if period == 0.0:  # the right-hand side: `_arm_period` with no substep
            no_substep = np.int64(0)  # int64 as m below: one signature of `_arm_period`
            _arm_period(
                k, x0, tau[k], arm_ext, period, no_substep, plant, inv_tol, arm, stages, buf, ws
            )
            for i in range(4 * n):
                ddq[k, i] = stages[0][i]
            continue
        m = min(max(substeps[k], least), most)
        while True:
            worst = _arm_period(
                k, x0, tau[k], arm_ext, period, m, plant, inv_tol, arm, stages, buf, ws
            )
            work += m
            if worst <= 1.0 or m >= most:
                break
            m = min(2 * m, most)
        if worst < SHRINK_BELOW and m // 2 >= least:
            m = m // 2
        substeps[k] = m
        x, end = stages[5], stages[4]
        for j in range(n):
            theta[k, j] = x[j]
            q[k, j] = x[n + j]
            dtheta[k, j] = x[2 * n + j]
            dq[k, j] = x[3 * n + j]
            ddq[k, j] = end[3 * n + j]
    return work


@njit(cache=True)
def rk4_period_kernel(theta, dtheta, q, dq, tau, ext, period, substeps, ddq, packed):
    """One control period of every arm (see `ArmIntegrator`), in place: the state
    (theta, theta', q, q' (N, n)) advanced under ``tau`` (N, n) and ``ext`` ((N, n) or
    (N, 0): none), the substep counts ``substeps`` (N,) updated, q'' at the end into
    ``ddq``. ``packed``: (plant, chain constants, the chain's scratch, 1 / tolerances,
    the fewest and the most substeps, scratch arrays). Returns the total number of
    substeps taken (rejected ones included). A ``period`` of 0 advances nothing: x' of
    every arm at its state goes into ``ddq`` (N, 4 n) instead (the right-hand side, in
    the same compiled code as the steps)."""
    return _rk4_arms(theta, dtheta, q, dq, tau, ext, period, substeps, ddq, packed.values)


class ArmIntegrator:
    """RK4 with step-size control of N arms.

    The derivative x' = (theta', q', theta'', q'') of arm k under the motor torque tau and
    an external link-side torque tau_e:

    * model (1): tau_J = K (theta - q) + D (theta' - q'),
      M(q) q'' + n(q, q') = tau_J - d(q') + tau_e,  theta'' = B^-1 (tau - tau_J);
    * model (2) with constant S, in the Schur-complement form:
      (M(q) - S B^-1 S^T) q'' = tau_J - d(q') + tau_e - S B^-1 (tau - tau_J) - n(q, q'),
      theta'' = B^-1 (tau - tau_J - S^T q'');
    * rigid arms: M(q) q'' + n(q, q') = tau - d(q') + tau_e, and theta = q;

    d(q') = F_v q' + c tanh(q' / v_s) (c = c+ or c- by the sign of q').

    One step of size h: k1 = f(x), k2 = f(x + h/2 k1), k3 = f(x + h/2 k2),
    k4 = f(x + h k3), x+ = x + h (k1 + 2 k2 + 2 k3 + k4) / 6, global error O(h^4). The
    derivative at the new state, k5 = f(x+), is needed anyway (it is the next step's k1
    and gives the period's final q'' and accelerometer readings); with it the weights
    (1/6, 1/3, 1/3, 0, 1/6) make a third-order solution (they satisfy the four order
    conditions of order 3), so e = x+ - x+^(3) = h (k4 - k5) / 6 estimates the local
    error of a third-order step, an upper bound of the RK4 step's own local error (as in
    the 'RK4(3)' pairs of Hairer et al., Sec. II.4).

    Step-size control, per arm and per control period T: the period is cut into m equal
    substeps; if the scaled error max_i |e_i| / tol_i of a substep exceeds 1, the period
    is integrated again from its start with 2 m (up to a maximum); after a period whose
    largest scaled error is below 1/32 (the error of a step twice as long, 16 times
    larger, is then below 1/2), the next period starts with m / 2. So each period ends
    exactly on the control boundary, with the held inputs' discontinuities there, and
    stiff stretches (the Coulomb tanh near q' = 0, a light wrist's torsion mode) get the
    substeps they need and no more. Positions are scaled by the position tolerance,
    rates by the rate tolerance. The substep counts are part of the state a caller must
    keep, reset and copy with it.

    Args:
        chain: the arms' chain (one parameter set, or stacked per arm: a payload, scaled
            links).
        transmission: (K, D, B^-1, F_v, c+, c-, v_s (N,), has friction, has Coulomb)
            with a leading arm axis (N, n), as ``PlantArray.transmission`` holds them.
        coupling: (S B^-1, -S B^-1 S^T, S^T) (N, n, n) for model (2), or None.
        elastic: elastic joints (model (1)/(2)) or rigid ones (theta = q).
        tolerance: the local error tolerances of a substep.
        substeps: (fewest, most) substeps of a control period; equal: a fixed step.

    ``substeps_now`` (N,) holds each arm's substep count for its next period (state of
    the arm: `reset` sets it, a copy of the arm copies it). The arrays are read at
    every call (changes made in place between periods are seen: a plant changed at a
    period boundary); after replacing one, call `repack`.
    """

    def __init__(
        self,
        chain: SerialChain,
        transmission: tuple,
        coupling: tuple[np.ndarray, np.ndarray, np.ndarray] | None,
        elastic: bool,
        tolerance: Tolerance | None = None,
        substeps: tuple[int, int] = (1, MAX_SUBSTEPS),
    ) -> None:
        tolerance = tolerance or Tolerance()
        if not (tolerance.position > 0.0 and tolerance.rate > 0.0):
            raise ValueError(f"integrator tolerances must be > 0, got {tolerance}")
        least, most = substeps
        if not 1 <= least <= most <= 2**20:
            raise ValueError(
                f"integrator substeps (fewest, most) must satisfy 1 <= fewest <= most <= "
                f"2^20, got {substeps}"
            )
        self.chain = chain
        self.transmission = transmission
        self.coupling = coupling
        self.elastic = bool(elastic)
        self.tolerance = tolerance
        self.substeps = (int(least), int(most))
        self.n_arms = len(transmission[0])
        self.substeps_now = np.full(self.n_arms, least, dtype=np.int64)
        self.repack()

    def repack(self) -> None:
        """Pack the kernels' arguments again (after an array was replaced)."""
        n, arms = self.chain.n, self.n_arms
        if self.coupling is None:
            empty = np.zeros((arms, n, n))
            coupling: tuple = (empty, empty, empty)
        else:
            coupling = tuple(np.ascontiguousarray(c, dtype=np.float64) for c in self.coupling)
        plant = (*self.transmission, self.elastic, self.coupling is not None, *coupling)
        tol = self.tolerance
        self._packed = Packed(
            (
                plant,
                self.chain._kernel_constants(),
                np.empty(_work_size(n)),  # the chain's scratch
                np.array([1.0 / tol.position, 1.0 / tol.rate]),
                np.int64(self.substeps[0]),
                np.int64(self.substeps[1]),
                np.empty((7, 4 * n)),  # the stages, the state and a stage's point
                np.empty((4, n)),  # the right-hand side's scratch
                np.empty(4 * n),  # the state at the period's start
            )
        )
        self._no_ext = np.zeros((arms, 0))

    @property
    def packed(self) -> Packed:
        """`rk4_period_kernel`'s `packed` (for compiled callers)."""
        return self._packed

    def reset(self, arms: np.ndarray | slice = slice(None)) -> None:
        """New episodes of ``arms``: their next period starts with the fewest substeps."""
        self.substeps_now[arms] = self.substeps[0]

    def _arrays(self, *arrays: np.ndarray) -> None:
        shape = (self.n_arms, self.chain.n)
        for a in arrays:
            if a.shape != shape or a.dtype != np.float64 or not a.flags.c_contiguous:
                raise ValueError(
                    f"the integrator takes C-contiguous float64 arrays of shape {shape}, "
                    f"got {a.dtype} {a.shape}"
                )

    def step(
        self,
        theta: np.ndarray,
        dtheta: np.ndarray,
        q: np.ndarray,
        dq: np.ndarray,
        tau: np.ndarray,
        period: float,
        link_torque: np.ndarray | None = None,
        ddq: np.ndarray | None = None,
    ) -> int:
        """Advance every arm by ``period`` (s) under the motor torques ``tau`` and the
        link torques ``link_torque`` (N, n; None: none), both held; the state arrays
        (N, n) in place, q'' at the end into ``ddq`` if given. Returns the number of
        substeps taken (rejected ones included)."""
        ext = self._no_ext if link_torque is None else link_torque
        out = np.empty(q.shape) if ddq is None else ddq
        self._arrays(theta, dtheta, q, dq, tau, ext if ext.shape[1] else tau, out)
        period = float(period)
        if not period > 0.0:
            raise ValueError(f"the integration period must be > 0 s, got {period}")
        now, packed = self.substeps_now, self._packed
        return int(rk4_period_kernel(theta, dtheta, q, dq, tau, ext, period, now, out, packed))

    def derivative(
        self,
        theta: np.ndarray,
        dtheta: np.ndarray,
        q: np.ndarray,
        dq: np.ndarray,
        tau: np.ndarray,
        link_torque: np.ndarray | None = None,
    ) -> np.ndarray:
        """x' = (theta', q', theta'', q'') (N, 4 n) at the given state."""
        ext = self._no_ext if link_torque is None else link_torque
        self._arrays(theta, dtheta, q, dq, tau, ext if ext.shape[1] else tau)
        out = np.empty((self.n_arms, 4 * self.chain.n))
        rk4_period_kernel(theta, dtheta, q, dq, tau, ext, 0.0, self.substeps_now, out, self._packed)
        return out
