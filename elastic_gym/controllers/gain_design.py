"""Full-state feedback gains on the *coupled* linearization of the arm.

The gain K_P of eq. (13) (De Luca et al., ICRA 2007) is an N x 4N matrix on the state
error x_d - x, x = (theta, q, theta', q'). It is designed on the linearization of the
complete model (1)/(2) at rest at a nominal configuration q0 (theta0 = q0 + K^-1 g(q0)),
not per joint on M_ii, which is unstable on strongly coupled arms:

    [B  S^T] [theta'']   [ D  -D] [theta']   [ K   -K     ] [theta]   [I]
    [S  M  ] [q''    ] + [-D   D] [q'    ] + [-K   K + G  ] [q    ] = [0] tau,

G = dg/dq(q0); rigid arms: M q'' + G q = tau. Designs: `lqr_bandwidth_gain`
(slowest closed-loop pole at ``omega``), `lqr_integral_gain` (augmented with the
integral of the link error), `lqr_gain`, `pole_placement_gain` and
`pd_gain` (decentralized PD as a structured N x 4N matrix).
"""

from __future__ import annotations

from typing import Annotated, Literal

import numpy as np
import pinocchio as pin
import scipy.linalg as sla
from scipy.optimize import brentq

from elastic_gym.model import RobotModel
from elastic_gym.model.option_checks import Needs, stable_poles
from elastic_gym.validation import PositiveFinite, option_value

Block = Literal["motor", "link"]
"""The state block of a decentralized PD (`pd_gain`)."""
ON_ELASTIC = Needs(
    ("motor", "motor-offset"), "elastic joints (motor positions)", lambda model: model.elastic
)
"""A motor-side law needs an elastic arm (checked against the robot of the validation
context): a `Needs` shared by the PD blocks and the
motor-offset action of the training package."""

BANDWIDTH_SEARCH = (0.1, 20.0)  # bracket of w / omega for the bisection


def nominal_configuration(model: RobotModel) -> np.ndarray:
    """Default design configuration: the middle of the robot's task workspace."""
    spec = model.spec
    return 0.5 * (np.asarray(spec.workspace_low) + np.asarray(spec.workspace_high))


def rigid_inertia(model: RobotModel, q0: np.ndarray) -> np.ndarray:
    """Inertia matrix of the arm moving rigidly (theta = q): B + S + S^T + M(q0)."""
    return np.diag(model.B) + model.S + model.S.T + model.mass_matrix(q0)


def linearize(model: RobotModel, q0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(A, B_u) of the arm linearized at rest at q0, state order (positions, velocities)."""
    n = model.n
    M = model.mass_matrix(q0)
    G = pin.computeGeneralizedGravityDerivatives(model.pin_model, model.data, q0)
    if model.elastic:
        K, D = np.diag(model.K), np.diag(model.D)
        inertia = np.block([[np.diag(model.B), model.S.T], [model.S, M]])
        stiffness = np.block([[K, -K], [-K, K + G]])
        damping = np.block([[D, -D], [-D, D]])
        inputs = np.vstack([np.eye(n), np.zeros((n, n))])
    else:
        inertia, stiffness, damping, inputs = M, G, np.zeros((n, n)), np.eye(n)
    m = inertia.shape[0]
    A = np.block(
        [
            [np.zeros((m, m)), np.eye(m)],
            [-np.linalg.solve(inertia, stiffness), -np.linalg.solve(inertia, damping)],
        ]
    )
    Bu = np.vstack([np.zeros((m, n)), np.linalg.solve(inertia, inputs)])
    return A, Bu


def closed_loop_poles(A: np.ndarray, Bu: np.ndarray, gain: np.ndarray) -> np.ndarray:
    """Eigenvalues of A - B_u K, sorted by magnitude."""
    poles = np.linalg.eigvals(A - Bu @ gain)
    return poles[np.argsort(np.abs(poles), kind="stable")]


def lqr_gain(A: np.ndarray, Bu: np.ndarray, Q: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Continuous LQR gain K = R^-1 B^T P (``scipy.linalg.solve_continuous_are``)."""
    P = sla.solve_continuous_are(A, Bu, Q, R)
    return np.linalg.solve(R, Bu.T @ P)


def _bandwidth_weights(model: RobotModel, J: np.ndarray, w: float) -> np.ndarray:
    """Q = diag(0, J^2 w^4, 0, J^2 w^2) on (theta, q, theta', q') (rigid: (q, q'))."""
    n = model.n
    blocks = 4 if model.elastic else 2
    Q = np.zeros((blocks * n, blocks * n))
    J2 = J @ J
    position, velocity = (blocks // 2 - 1) * n, (blocks - 1) * n
    Q[position : position + n, position : position + n] = J2 * w**4
    Q[velocity:, velocity:] = J2 * w**2
    return Q


def _positive(value: float, name: str = "omega") -> float:
    """A design argument that must be a finite number > 0 (``ValueError`` naming it)."""
    return option_value(name, value, PositiveFinite, prefix="")


def bandwidth_weight(model: RobotModel, q0: np.ndarray, omega: float) -> float:
    """The w of the LQR bandwidth design whose slowest closed-loop pole has magnitude
    ``omega`` (see module doc)."""
    _positive(omega)
    A, Bu = linearize(model, q0)
    J = rigid_inertia(model, q0)
    R = np.eye(model.n)

    def mismatch(log_w: float) -> float:
        gain = lqr_gain(A, Bu, _bandwidth_weights(model, J, float(np.exp(log_w))), R)
        return float(np.log(np.abs(closed_loop_poles(A, Bu, gain)[0]) / omega))

    low, high = (np.log(omega * f) for f in BANDWIDTH_SEARCH)
    if mismatch(low) * mismatch(high) > 0:
        raise ValueError(
            f"omega={omega} rad/s cannot be reached by the LQR bandwidth design of "
            f"{model.spec.name!r}; give explicit weights, poles or gain"
        )
    return float(np.exp(brentq(mismatch, low, high, xtol=1e-6)))


def lqr_bandwidth_gain(model: RobotModel, q0: np.ndarray, omega: float) -> np.ndarray:
    """LQR gain whose slowest closed-loop pole has magnitude ``omega`` (see module doc)."""
    w = bandwidth_weight(model, q0, omega)
    A, Bu = linearize(model, q0)
    J = rigid_inertia(model, q0)
    return lqr_gain(A, Bu, _bandwidth_weights(model, J, w), np.eye(model.n))


def link_position_rows(model: RobotModel) -> slice:
    """Where the link position q sits in the state: (theta, q, theta', q') or (q, q')."""
    start = model.n if model.elastic else 0
    return slice(start, start + model.n)


def integral_linearization(model: RobotModel, q0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(A, B_u) of the linearization augmented with z' = q - q_d, state (z, x)."""
    A, Bu = linearize(model, q0)
    n, dim = model.n, A.shape[0]
    A_aug = np.zeros((n + dim, n + dim))
    A_aug[n:, n:] = A
    A_aug[np.arange(n), n + np.arange(dim)[link_position_rows(model)]] = 1.0
    return A_aug, np.vstack([np.zeros((n, model.n)), Bu])


def lqr_integral_gain(
    model: RobotModel, q0: np.ndarray, omega: float, integral_weight: float
) -> tuple[np.ndarray, np.ndarray]:
    """(K_x, K_z): LQR on the linearization augmented with the integral z of the link
    position error, u = -K_z z - K_x (x - x_d).

    Weights: the bandwidth weights of `lqr_bandwidth_gain` (same w, so the
    same ``omega`` design) on x, and ``integral_weight`` J^2 w^6 on z. For a rigid
    joint J q'' = u these weights (c w^6, w^4, w^2) give closed-loop poles w times the
    roots of a fixed polynomial: ``integral_weight`` = 0.1 puts the integral pole at
    0.33 w and leaves the other two within 4 % of the design without integral
    (0.84 +- 0.50j vs 0.87 +- 0.50j).
    """
    _positive(integral_weight, "integral_weight")
    w = bandwidth_weight(model, q0, omega)
    J = rigid_inertia(model, q0)
    n = model.n
    A, Bu = integral_linearization(model, q0)
    Q = np.zeros_like(A)
    Q[:n, :n] = integral_weight * (J @ J) * w**6
    Q[n:, n:] = _bandwidth_weights(model, J, w)
    gain = lqr_gain(A, Bu, Q, np.eye(n))
    return gain[:, n:], gain[:, :n]


def pole_placement_gain(A: np.ndarray, Bu: np.ndarray, poles) -> np.ndarray:
    """MIMO pole placement (``scipy.signal.place_poles``) of all 2 * (positions) poles."""
    from scipy.signal import place_poles  # imported here: scipy.signal costs a second to import

    return place_poles(A, Bu, stable_poles(poles, (A.shape[0],))).gain_matrix


def pd_gain(model: RobotModel, kp: np.ndarray, kd: np.ndarray, block: Block) -> np.ndarray:
    """Decentralized PD as an N x dim(x) gain acting on the ``"motor"`` or ``"link"`` block."""
    n = model.n
    blocks = 4 if model.elastic else 2
    option_value("block", block, Annotated[Block, ON_ELASTIC], prefix="", context={"model": model})
    position = 0 if block == "motor" or not model.elastic else 1
    gain = np.zeros((n, blocks * n))
    gain[:, position * n : (position + 1) * n] = np.diag(kp)
    velocity = position + blocks // 2
    gain[:, velocity * n : (velocity + 1) * n] = np.diag(kd)
    return gain


def bandwidth_pd_gains(
    model: RobotModel, q0: np.ndarray, omega: float, damping_ratio: float
) -> tuple[np.ndarray, np.ndarray]:
    """Per-joint PD gains kp = J w^2, kd = 2 zeta J w, J the diagonal of the rigid inertia.

    This is the gain of each joint moving rigidly with bandwidth w; the actual poles of
    the elastic closed loop differ (see `closed_loop_poles`).
    """
    _positive(omega)
    _positive(damping_ratio, "damping_ratio")
    J = np.diag(rigid_inertia(model, q0))
    return J * omega**2, 2.0 * damping_ratio * J * omega


def most_stable_bandwidth(
    model: RobotModel, q0: np.ndarray, omega: float, damping_ratio: float, block: Block
) -> float:
    """The PD bandwidth w <= omega (log grid down to omega / 30) with the largest stability
    margin -max Re(pole) of the nominal linearized closed loop.

    Used for link-side PD on elastic arms: derivative feedback of the link velocity
    through a visco-elastic joint is destabilizing above kd ~ (B + J)^2 D / (B J) (Routh
    criterion of the single joint), so the rigid-arm rule w = omega is unstable there.
    """
    _positive(omega)
    A, Bu = linearize(model, q0)
    candidates = omega * np.geomspace(1.0, 1.0 / 30.0, 61)

    def margin(w: float) -> float:
        kp, kd = bandwidth_pd_gains(model, q0, w, damping_ratio)
        return -float(closed_loop_poles(A, Bu, pd_gain(model, kp, kd, block)).real.max())

    margins = np.array([margin(w) for w in candidates])
    if margins.max() <= 0.0:
        raise ValueError(
            f"no stable {block}-side PD with damping_ratio={damping_ratio} below "
            f"omega={omega} rad/s for {model.spec.name!r}; give kp and kd"
        )
    return float(candidates[int(np.argmax(margins))])
