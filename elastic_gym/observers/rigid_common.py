"""What the rigid-arm velocity observers have in common.

* `rk4_period`: one control period of an observer ODE by RK4, the measured position
  interpolated linearly and the torque held.
* `RigidArmBounds`: the bounds of Cristofaro & De Luca (2022), c0(q) =
  max_{|u|=1} ||C(q, u)|| of eq. (4), lambda_min(M(q)) of eqs. (2)/(8) and the injection
  gain of eqs. (12)/(16), maximised over sampled configurations of joints 2..N (M and C do
  not depend on the first joint): a full grid or a deterministic Sobol sequence.
* `ScalarGainReducedObserver`: x_hat_2 = z + k y,
  z' = M(y)^-1 [tau - C(y, x_hat_2) x_hat_2 - d(x_hat_2) - g(y)] - k x_hat_2, shared by
  Cristofaro & De Luca eq. (6) and Solsona & Puleston eqs. (6)-(7) (d the model's link
  friction).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Annotated

import numpy as np
from pydantic import Field, StrictBool, StrictInt

from elastic_gym.model import RobotModel
from elastic_gym.observers.base import Observer
from elastic_gym.observers.integration import rk4
from elastic_gym.validation import PositiveFinite, option_value

ASCENT_TOLERANCE = 1e-10
SAMPLING_SEED = 0


# ---------------------------------------------------------------- validation
def positive_number(name: str, value: object) -> float:
    """``value`` as a float > 0 (`option_value`)."""
    return option_value(name, value, PositiveFinite)


def boolean_option(name: str, value: object) -> bool:
    """``value`` if it is a bool (`option_value`)."""
    return option_value(name, value, StrictBool)


def positive_integer(name: str, value: object, minimum: int = 1) -> int:
    """``value`` as an int >= ``minimum`` (`option_value`)."""
    return option_value(name, value, Annotated[StrictInt, Field(ge=minimum)])


# ---------------------------------------------------------------- dynamics
def observer_acceleration(
    model: RobotModel, q: np.ndarray, dq: np.ndarray, torque: np.ndarray, friction: bool
) -> np.ndarray:
    """M(q)^-1 [tau - C(q, dq) dq - g(q) - d(dq)], d the model's link friction or 0."""
    if friction:
        return model.rigid_acceleration(q, dq, torque)
    return model.aba(q, dq, torque)


def rk4_period(
    rhs: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray],
    x: np.ndarray,
    y_start: np.ndarray,
    y_end: np.ndarray,
    torque: np.ndarray,
    dt: float,
    substeps: int = 1,
) -> np.ndarray:
    """Integrate x' = rhs(x, y(t), torque) over one period by RK4.

    y(t) is the linear interpolation between the samples ``y_start`` (t = 0) and
    ``y_end`` (t = dt), a first-order hold of the measurement; the torque is held
    (it is constant over the period in the plant too).
    """
    slope = (y_end - y_start) / dt
    return rk4(lambda t, z: rhs(z, y_start + slope * t, torque), x, dt, substeps)


# ---------------------------------------------------------------- model bounds
def configuration_samples(
    model: RobotModel, points_per_joint: int = 181, max_samples: int = 4096
) -> np.ndarray:
    """Configurations (K, N) covering joints 2..N (joint 1 held at 0); see module doc."""
    n = model.n
    lower = np.asarray(model.pin_model.lowerPositionLimit, dtype=float)[1:]
    upper = np.asarray(model.pin_model.upperPositionLimit, dtype=float)[1:]
    unbounded = ~np.isfinite(lower) | ~np.isfinite(upper) | (upper - lower >= 2.0 * np.pi)
    lower = np.where(unbounded, -np.pi, lower)
    upper = np.where(unbounded, np.pi, upper)
    d = n - 1
    if d == 0:
        return np.zeros((1, n))
    if points_per_joint**d <= max_samples:
        axes = [np.linspace(lo, hi, points_per_joint) for lo, hi in zip(lower, upper, strict=True)]
        tail = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, d)
    else:
        from scipy.stats import qmc  # imported here: scipy.stats costs a second to import

        unit = qmc.Sobol(d, scramble=True, seed=SAMPLING_SEED).random(max_samples)
        tail = qmc.scale(unit, lower, upper)
    return np.hstack([np.zeros((len(tail), 1)), tail])


def christoffel_tensor(model: RobotModel, q: np.ndarray) -> np.ndarray:
    """T (N, N, N) with C(q, u) = T @ u, C from the Christoffel symbols.

    This is the factorization that satisfies both M' - 2C skew-symmetric and the
    identity (3) C(q, u) w = C(q, w) u used in the proofs. Since C(q, v) v is
    quadratic in v with a symmetric coefficient tensor, its velocity Jacobian is
    2 C(q, v): T[:, :, k] = 1/2 d(rnea)/d(q') at q' = e_k (exact, rnea is quadratic).
    """
    n = model.n
    zero = np.zeros(n)
    slices = [0.5 * model.rnea_derivatives(q, e, zero)[1] for e in np.eye(n)]
    return np.stack(slices, axis=-1)


def coriolis_bound(
    tensors: np.ndarray, directions_per_joint: int = 16, starts: int = 4, iterations: int = 30
) -> np.ndarray:
    """c0 = max_{|u|=1} ||C(q, u)||_2 of eq. (4) for a batch of tensors (K, N, N, N).

    C(q, u) v = B(u, v) is a symmetric vector-valued bilinear form (identity (3)), so
    by Banach's theorem on symmetric forms the maximum over unit u, v, w of
    w^T B(u, v) is reached at u = v: c0 = max_{|u|=1} ||C(q, u) u||, the largest
    Coriolis/centrifugal torque at unit speed. That is maximised by an alternating
    ascent on f(w, u) = w^T C(q, u) u = u^T S(w) u (S(w) = sum_a w_a T[a], symmetric):
    w = h(u)/|h(u)|, then u = the eigenvector of S(w) of largest |eigenvalue|; f never
    decreases. Starts: the ``starts`` best of N * ``directions_per_joint`` fixed
    pseudo-random unit directions (plus the basis vectors). For N = 2 this is exact to
    1e-9 (checked against dense sampling of the circle); for larger N it is a local
    ascent from the best samples.
    """
    K, n = tensors.shape[:2]
    rng = np.random.default_rng(SAMPLING_SEED)
    directions = _unit(np.concatenate([np.eye(n), rng.normal(size=(directions_per_joint * n, n))]))
    candidates = np.broadcast_to(directions, (K, *directions.shape))
    norms = np.linalg.norm(_centrifugal(tensors, candidates), axis=-1)
    best = np.argsort(-norms, axis=1)[:, :starts]
    u = directions[best]
    value = np.take_along_axis(norms, best, axis=1)
    flat = tensors.reshape(K, 1, n, n * n)
    for _ in range(iterations):
        w = _unit(_centrifugal(tensors, u))
        S = (w[..., None, :] @ flat)[..., 0, :].reshape(K, -1, n, n)
        eigenvalues, eigenvectors = np.linalg.eigh(S)
        largest = np.argmax(np.abs(eigenvalues), axis=-1)
        u = np.take_along_axis(eigenvectors, largest[..., None, None], axis=-1)[..., 0]
        new_value = np.linalg.norm(_centrifugal(tensors, u), axis=-1)
        converged = np.max(new_value - value) <= ASCENT_TOLERANCE * max(1.0, new_value.max())
        value = np.maximum(value, new_value)
        if converged:
            break
    return value.max(axis=1)


def _centrifugal(tensors: np.ndarray, u: np.ndarray) -> np.ndarray:
    """h = C(q, u) u for tensors (K, N, N, N) and directions u (K, S, N) -> (K, S, N)."""
    K, n = tensors.shape[:2]
    outer = (u[..., :, None] * u[..., None, :]).reshape(K, -1, n * n, 1)
    return (tensors.reshape(K, 1, n, n * n) @ outer)[..., 0]


def _unit(x: np.ndarray) -> np.ndarray:
    norm = np.linalg.norm(x, axis=-1, keepdims=True)
    return x / np.where(norm > 0.0, norm, 1.0)


def viscous_lower_bound(model: RobotModel) -> float:
    """lambda_min(F) of the (diagonal) viscous link friction, 0 without friction."""
    if model.friction is None:
        return 0.0
    return float(np.min(model.friction.viscous))


@dataclass(frozen=True)
class RigidArmBounds:
    """Model quantities on sampled configurations q_k (rows of ``configurations``).

    ``tensors`` (K, N, N, N): C(q_k, u) = tensors[k] @ u (`christoffel_tensor`);
    ``inertia`` (K, N, N): M(q_k); ``c0``, ``lambda_min``, ``lambda_max`` (K,): c0(q_k) of
    eq. (4) and the extreme eigenvalues of M(q_k); ``friction_min``: lambda_min(F).
    Build with `from_model`; `injection_gain` evaluates eqs. (12)/(16).
    """

    configurations: np.ndarray
    tensors: np.ndarray
    inertia: np.ndarray
    c0: np.ndarray
    lambda_min: np.ndarray
    lambda_max: np.ndarray
    friction_min: float

    @classmethod
    def from_model(
        cls, model: RobotModel, points_per_joint: int = 181, max_samples: int = 4096
    ) -> RigidArmBounds:
        points_per_joint = positive_integer("points_per_joint", points_per_joint, 2)
        max_samples = positive_integer("max_samples", max_samples)
        configurations = configuration_samples(model, points_per_joint, max_samples)
        tensors = np.stack([christoffel_tensor(model, q) for q in configurations])
        inertia = np.stack([model.mass_matrix(q) for q in configurations])
        eig = np.linalg.eigvalsh(inertia)
        return cls(
            configurations,
            tensors,
            inertia,
            coriolis_bound(tensors),
            eig[:, 0],
            eig[:, -1],
            viscous_lower_bound(model),
        )

    def injection_gain(self, velocity_bound: float) -> float:
        """max_q [c0(q) V - lambda_min(F)] / lambda_min(M(q)).

        V = v_max + eta gives k0 of eq. (12); V = eta + r v_bar gives k_r of eq. (16).
        """
        return float(np.max((self.c0 * velocity_bound - self.friction_min) / self.lambda_min))


# ---------------------------------------------------------------- shared observer
class ScalarGainReducedObserver(Observer):
    """Reduced-order velocity observer with a scalar injection gain k (module docstring).

    The estimate is x = (y, x_hat_2): the measured position and the velocity estimate.
    Subclasses choose the gain; `set_gain` changes it with the reset of z that
    keeps x_hat_2 = z + k y continuous.

    Args:
        model: nominal model (M, C, g and the link friction d).
        dt: sampling period (s).
        gain: initial injection gain k > 0 (1/s).
        model_friction: include the model's link friction d(x_hat_2) in the observer.
        substeps: RK4 steps per sampling period.
    """

    applies_to = frozenset({"rigid"})

    def __init__(
        self,
        model: RobotModel,
        dt: float,
        gain: float,
        model_friction: bool = True,
        substeps: int = 1,
    ) -> None:
        super().__init__(model, dt)
        self.gain = positive_number("gain", gain)
        self.model_friction = boolean_option("model_friction", model_friction)
        self.substeps = positive_integer("substeps", substeps)
        self._z = np.zeros(self.n)
        self._y = np.zeros(self.n)

    @property
    def velocity(self) -> np.ndarray:
        """x_hat_2 = z + k y at the last sample."""
        return self._z + self.gain * self._y

    def _rhs(self, z: np.ndarray, y: np.ndarray, torque: np.ndarray) -> np.ndarray:
        velocity = z + self.gain * y
        acceleration = observer_acceleration(self.model, y, velocity, torque, self.model_friction)
        return acceleration - self.gain * velocity

    def set_gain(self, gain: float) -> None:
        """New gain with z reset so that x_hat_2 is unchanged by the switch."""
        self._z = self._z + (self.gain - gain) * self._y
        self.gain = gain

    def reset(self, obs: Mapping, initial_estimate: np.ndarray | None = None) -> np.ndarray:
        x0 = self.check_initial_estimate(initial_estimate)
        self._y = self.measured_position(obs).copy()
        velocity = np.zeros(self.n) if x0 is None else x0[self.n :]
        self._z = velocity - self.gain * self._y
        return np.concatenate([self._y, velocity])

    def update(self, obs: Mapping, torque: np.ndarray, dt: float) -> np.ndarray:
        y = self.measured_position(obs)
        tau = np.asarray(torque, dtype=float)
        self._z = rk4_period(self._rhs, self._z, self._y, y, tau, dt, self.substeps)
        self._y = y.copy()
        return np.concatenate([self._y, self.velocity])
