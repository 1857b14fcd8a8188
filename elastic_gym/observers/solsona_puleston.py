"""Reduced-order velocity observer of Solsona & Puleston for N-link arms, rigid arms.

Eqs. (6)-(7) with G = g0 I (Sec. 3):

    x_hat_2 = v + G x_1,
    v'      = beta(x_1, x_hat_2) + u(x_1, tau) - G x_hat_2,

beta = H^-1 [-C(x_1, x_hat_2) x_hat_2 - f_r(x_hat_2)], u = H^-1 [tau - tau_g(x_1)], with
the friction f_r of their arm (viscous + asymmetric Coulomb, smoothed as in
``model.link_friction``) in the model. The same ODE as Cristofaro & De Luca eq. (6) with
k = g0 (`ScalarGainReducedObserver`). Their
sufficient design criterion, eqs. (15)-(17), g0 > M:
[`sufficient_gain_bound`][elastic_gym.observers.solsona_puleston.sufficient_gain_bound].
"""

from __future__ import annotations

import numpy as np

from elastic_gym.model import RobotModel
from elastic_gym.observers.rigid_common import (
    RigidArmBounds,
    ScalarGainReducedObserver,
    boolean_option,
    positive_integer,
    positive_number,
)


class SolsonaPulestonObserver(ScalarGainReducedObserver):
    """Solsona & Puleston reduced-order observer, eqs. (6)-(7) with G = g0 I.

    Args:
        model: nominal rigid-arm model (its link friction enters the observer).
        dt: sampling period (s).
        g0: observer gain (1/s), default 3 as in their Sec. 4.
        model_friction: include the model's friction f_r(x_hat_2) in beta.
        substeps: RK4 steps per sampling period.

    Diagnostics: ``gain`` (g0).
    """

    name = "solsona-puleston"

    def __init__(
        self,
        model: RobotModel,
        dt: float,
        g0: float = 3.0,
        model_friction: bool = True,
        substeps: int = 1,
    ) -> None:
        super().__init__(model, dt, positive_number("g0", g0), model_friction, substeps)
        self.diagnostics = {"gain": self.gain}


def sufficient_gain_bound(
    model: RobotModel,
    radius: float,
    include_viscous: bool = False,
    points_per_joint: int = 181,
    directions: int = 720,
) -> float:
    """M of eq. (15): sup over configurations and |xi| <= ``radius`` of |d beta/d xi|.

    With beta = -H^-1 C(x_1, xi) xi (their eq. (3)), d beta/d xi = -H^-1 2 C(x_1, xi)
    (identity C(q, u) w = C(q, w) u of the Christoffel factorization); with
    ``include_viscous`` the viscous friction adds -H^-1 F. Coulomb friction has no
    derivative at xi = 0 (its smoothed version a derivative of order f_c / 0.01), so
    it is left out, as in their Sec. 3 where beta has no friction at all. The norm is
    convex in xi, so the sup over the ball is on the sphere |xi| = ``radius``:
    ``directions`` unit vectors, evenly spaced on the circle for N = 2, deterministic
    pseudo-random (plus the basis vectors) for N > 2; configurations as in
    `RigidArmBounds`. ``radius`` is r2 of eq. (14) or (21).
    """
    radius = positive_number("radius", radius)
    include_viscous = boolean_option("include_viscous", include_viscous)
    directions = positive_integer("directions", directions)
    bounds = RigidArmBounds.from_model(model, points_per_joint)
    n = model.n
    if n == 2:
        angle = np.linspace(0.0, 2.0 * np.pi, directions, endpoint=False)
        unit = np.stack([np.cos(angle), np.sin(angle)], axis=1)
    else:
        sample = np.random.default_rng(0).normal(size=(directions, n))
        unit = np.concatenate([np.eye(n), sample / np.linalg.norm(sample, axis=1, keepdims=True)])
    coriolis = np.einsum("kabc,sc->ksab", bounds.tensors, radius * unit)
    viscous = include_viscous and model.friction is not None
    damping = np.diag(model.friction.viscous) if model.friction and viscous else np.zeros((n, n))
    jacobian = np.linalg.solve(bounds.inertia[:, None], 2.0 * coriolis + damping)
    return float(np.linalg.norm(jacobian, ord=2, axis=(-2, -1)).max())
