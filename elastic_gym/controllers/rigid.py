"""Tracking controllers of the rigid-arm observer papers, fed by a velocity estimate.

Both read q and the velocity estimate x_hat_2 from ``obs["state"]`` and q_d, q_d', q_d''
from ``info["reference"]``:

* [`CristofaroTrackingController`][elastic_gym.controllers.rigid.CristofaroTrackingController]:
  Cristofaro & De Luca (IEEE L-CSS 2022), Example 3,
  exactly as printed (Lambda = 0.5 I, K_P = diag(40, 60), K_D = diag(60, 90)):
  tau = M(q) (q_d'' + Lambda (q_d' - x_hat_2)) + C(q, x_hat_2) (q_d' + Lambda (q_d - q))
  + g(q) + K_P (q_d - q) + K_D (q_d' - x_hat_2);
* [`FeedbackLinearizingController`][elastic_gym.controllers.rigid.FeedbackLinearizingController]:
  computed torque with friction compensation, the
  controller of Solsona & Puleston's simulation (Sec. 4): tau = M(q) a + C(q, x_hat_2) x_hat_2
  + g(q) + f_r(v_f), a = q_d'' + K_D (q_d' - x_hat_2) + K_P (q_d - q), with the model's
  friction f_r at v_f = x_hat_2 or q_d'.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

import numpy as np

from elastic_gym.controllers.base import Controller
from elastic_gym.controllers.vector import OneArmLaw, StateLaw, arm_rows, twin_of
from elastic_gym.model import RobotModel
from elastic_gym.model.option_checks import square_matrix
from elastic_gym.validation import Matrix, PositiveFinite, StrictModel, validated_options

CRISTOFARO_LAMBDA = 0.5
CRISTOFARO_KP = (40.0, 60.0)
CRISTOFARO_KD = (60.0, 90.0)
Gain = Annotated[Any, Matrix()]
"""A gain option as given (finite entries); its form is checked by `_gain_matrix`."""


def _gain_matrix(value, n: int, name: str) -> np.ndarray:
    """A gain whose symmetric part is positive semi-definite, from a scalar, N numbers or
    an N x N matrix (`square_matrix`)."""
    return square_matrix(value, n, name, psd_tolerance=0.0)


class _RigidTracking(OneArmLaw, Controller):
    """Rigid-arm tracking laws; they run as their twins with one arm."""

    applies_to = frozenset({"rigid"})


def _signals(x: np.ndarray, ref: np.ndarray, n: int) -> tuple[np.ndarray, ...]:
    """(q, x_hat_2, q_d, q_d', q_d'') of N arms from states (N, 2n) and references."""
    return x[:, :n], x[:, n:], ref[:, 0], ref[:, 1], ref[:, 2]


class CristofaroOptions(StrictModel):
    """The options of
    [`CristofaroTrackingController`][elastic_gym.controllers.rigid.CristofaroTrackingController]
    (gain sizes checked by it)."""

    Lambda: Gain = CRISTOFARO_LAMBDA
    K_P: Gain | None = None
    K_D: Gain | None = None


class CristofaroTrackingController(_RigidTracking):
    """Example 3 of Cristofaro & De Luca (2022), see the module docstring.

    Args:
        model, dt: nominal rigid-arm model and control period.
        Lambda, K_P, K_D: gains (scalar, N numbers or N x N); the defaults are the
            paper's, for N = 2 (other arms need explicit K_P and K_D).
    """

    name = "cristofaro-tracking"
    options_model = CristofaroOptions

    def __init__(
        self,
        model: RobotModel,
        dt: float,
        Lambda=CRISTOFARO_LAMBDA,
        K_P=None,
        K_D=None,
    ) -> None:
        super().__init__(model, dt)
        validated_options(CristofaroOptions, locals())
        n = self.n
        if (K_P is None or K_D is None) and n != len(CRISTOFARO_KP):
            raise ValueError(
                f"the paper's K_P, K_D are for 2 joints; give K_P and K_D for {n} joints"
            )
        self.Lambda = _gain_matrix(Lambda, n, "Lambda")
        self.K_P = _gain_matrix(CRISTOFARO_KP if K_P is None else K_P, n, "K_P")
        self.K_D = _gain_matrix(CRISTOFARO_KD if K_D is None else K_D, n, "K_D")
        self.bind_law()


class FeedbackLinearizationOptions(StrictModel):
    """The options of
    [`FeedbackLinearizingController`][elastic_gym.controllers.rigid.FeedbackLinearizingController]
    (gain sizes checked by it)."""

    omega: PositiveFinite = 10.0
    damping_ratio: PositiveFinite = 1.0
    K_P: Gain | None = None
    K_D: Gain | None = None
    friction_velocity: Literal["estimate", "desired"] = "estimate"


class FeedbackLinearizingController(_RigidTracking):
    """Computed torque with friction compensation (Solsona & Puleston, Sec. 4).

    Args:
        model, dt: nominal rigid-arm model (its friction is compensated) and period.
        omega, damping_ratio: error dynamics K_P = omega^2, K_D = 2 zeta omega
            (default 10 rad/s, zeta = 1).
        K_P, K_D: explicit gains (scalar, N numbers or N x N) instead.
        friction_velocity: ``"estimate"`` or ``"desired"`` (see module docstring).
    """

    name = "feedback-linearization"
    options_model = FeedbackLinearizationOptions

    def __init__(
        self,
        model: RobotModel,
        dt: float,
        omega: float = 10.0,
        damping_ratio: float = 1.0,
        K_P=None,
        K_D=None,
        friction_velocity: str = "estimate",
    ) -> None:
        super().__init__(model, dt)
        n = self.n
        validated_options(FeedbackLinearizationOptions, locals())
        self.friction_velocity = friction_velocity
        self.K_P = _gain_matrix(omega**2 if K_P is None else K_P, n, "K_P")
        self.K_D = _gain_matrix(2.0 * damping_ratio * omega if K_D is None else K_D, n, "K_D")
        self.bind_law()


@twin_of(CristofaroTrackingController)
class VectorCristofaroTracking(StateLaw[CristofaroTrackingController]):
    """Example 3 of Cristofaro & De Luca (2022) on N arms (chain kernels).

    C(q, x_hat_2) w comes from the bias n(q, v) = C(q, v) v + g(q), a quadratic form in v
    with the Christoffel-symbol C (symmetric in its two velocity arguments), by
    polarization: C(q, v) w = (n(q, v + w) - n(q, v - w)) / 4.
    """

    def torques(self, t: np.ndarray, x: np.ndarray, ref: np.ndarray) -> np.ndarray:
        c, chain = self.controller, self.model.chain
        q, v, q_d, dq_d, ddq_d = _signals(x, ref, self.n)
        e, de = q_d - q, dq_d - v
        w = dq_d + arm_rows(c.Lambda, e)
        M, bias = chain.mass_and_bias(np.concatenate([q, q]), np.concatenate([v + w, v - w]))
        N = len(q)
        return (
            arm_rows(M[:N], ddq_d + arm_rows(c.Lambda, de))
            + (bias[:N] - bias[N:]) / 4.0
            + chain.gravity(q)
            + arm_rows(c.K_P, e)
            + arm_rows(c.K_D, de)
        )


@twin_of(FeedbackLinearizingController)
class VectorFeedbackLinearization(StateLaw[FeedbackLinearizingController]):
    """Computed torque with friction compensation (Solsona & Puleston) on N arms."""

    def torques(self, t: np.ndarray, x: np.ndarray, ref: np.ndarray) -> np.ndarray:
        c, model = self.controller, self.model
        q, v, q_d, dq_d, ddq_d = _signals(x, ref, self.n)
        a = ddq_d + arm_rows(c.K_D, dq_d - v) + arm_rows(c.K_P, q_d - q)
        v_friction = v if c.friction_velocity == "estimate" else dq_d
        return model.chain.rnea(q, v, a) + model.link_friction(v_friction)
