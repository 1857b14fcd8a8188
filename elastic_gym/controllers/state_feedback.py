"""Feedforward + full-state feedback, eq. (13) of De Luca, Schroeder & Thuemmel (ICRA 2007).

    tau = K_P (x_d - xi) + tau_d,    (x_d, tau_d) = INVDYN(q_d, ..., q_d^(4))

xi is the state estimate (``obs["state"]``, or the truth behind a ``TrueStateWrapper``),
x_d and tau_d come from [`InverseDynamics`][elastic_gym.controllers.invdyn.InverseDynamics], and
K_P is a full N x 4N gain designed on the coupled linearization of the arm
([`gain_design`][elastic_gym.controllers.gain_design]). By default an LQR design places the
slowest closed-loop poles at ``omega`` = 30 rad/s, the value of the paper's KR15
experiment ("close to the robot natural frequency"). The same law runs on rigid arms
(x = (q, q'), INVDYN = computed torque).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Annotated, Any, ClassVar, Literal

import numpy as np
from pydantic import StrictBool, ValidationInfo, field_validator

from elastic_gym.controllers.base import Controller
from elastic_gym.controllers.gain_design import (
    closed_loop_poles,
    linearize,
    lqr_bandwidth_gain,
    lqr_gain,
    nominal_configuration,
    pole_placement_gain,
)
from elastic_gym.controllers.invdyn import (
    DEFAULT_FD_STEP,
    FdStep,
    InverseDynamics,
    LinkMassSensitivity,
    fit_link_masses,
    info_time,
    reference_derivatives,
    static_reference,
)
from elastic_gym.controllers.vector import OneArmLaw, StateLaw, arm_rows, twin_of
from elastic_gym.model import RobotModel
from elastic_gym.model.option_checks import square_matrix
from elastic_gym.validation import (
    Finite,
    Matrix,
    PositiveFinite,
    StrictModel,
    at_most_one,
    errors_at,
    only_when,
    shaped,
    validated_options,
)


class LQRWeights(StrictModel):
    """LQR weights: matrices, diagonals or scalars (checked against the state size)."""

    Q: Annotated[Any, Matrix()]
    R: Annotated[Any, Matrix()]


LOAD_IDENTIFICATION = ("none", "per-link", "shared")


class FeedforwardOptions(StrictModel):
    """The INVDYN and linearization options shared by eq. (13) and its variants."""

    feedforward: StrictBool = True
    design_configuration: list[Finite] | None = None
    fd_step: FdStep = DEFAULT_FD_STEP
    load_identification: Literal[LOAD_IDENTIFICATION] = "none"  # type: ignore[valid-type]


class StateFeedbackOptions(FeedforwardOptions):
    """The options of
    [`FeedforwardStateFeedback`][elastic_gym.controllers.state_feedback.FeedforwardStateFeedback]
    (gain shapes checked by its design)."""

    omega: PositiveFinite = 30.0
    gain: Annotated[Any, Matrix()] | None = None
    weights: LQRWeights | None = None
    poles: Any = None
    feedback: StrictBool = True

    @field_validator("poles")
    @classmethod
    def _one_design(cls, poles: Any, info: ValidationInfo) -> Any:
        at_most_one(
            {"gain": info.data.get("gain"), "weights": info.data.get("weights"), "poles": poles}
        )
        return poles

    @field_validator("feedback")
    @classmethod
    def _pure_feedforward(cls, feedback: bool, info: ValidationInfo) -> bool:
        designs = {k: info.data.get(k) for k in ("gain", "weights", "poles")}
        only_when(feedback, designs, "feedback is true (False: pure feedforward)")
        return feedback


class FeedforwardStateFeedback(OneArmLaw, Controller):
    """Eq. (13): tau = K_P (x_d - xi) + tau_d.

    Args:
        model: nominal model (INVDYN and the gain design use it).
        dt: control period (s).
        omega: slowest closed-loop pole magnitude (rad/s) of the default LQR design (None:
            a subclass's own default design).
        gain: explicit K_P (N x dim(x)); overrides the design.
        weights: ``{"Q": ..., "R": ...}`` LQR weights (matrices or diagonals).
        poles: all dim(x) closed-loop poles for MIMO pole placement.
        feedback: ``False`` gives pure feedforward (K_P = 0).
        feedforward: ``False`` replaces INVDYN by the static gravity-compensated reference
            (x_d at rest at q_d with q_d', tau_d = g(q_d)).
        design_configuration: configuration q0 of the linearization (default: the middle
            of the robot's workspace).
        fd_step: step (s) of the central difference giving tau_r'' inside INVDYN.
        load_identification: ``"per-link"`` or ``"shared"`` (one scale for all links)
            identifies the link masses at each reset from the encoders and runs the law
            on that model from then on
            ([`VectorStateFeedback`][elastic_gym.controllers.state_feedback.VectorStateFeedback];
            elastic arms).

    At most one of ``gain``, ``weights``, ``poles`` may be given.
    ``design`` holds the configuration, method and closed-loop poles of the nominal
    linearization. The law runs as
    [`VectorStateFeedback`][elastic_gym.controllers.state_feedback.VectorStateFeedback] with one
    arm.
    """

    name = "feedforward-state-feedback"
    options_model: ClassVar[type | None] = StateFeedbackOptions

    def __init__(
        self,
        model: RobotModel,
        dt: float,
        omega: float | None = 30.0,
        gain=None,
        weights: Mapping | None = None,
        poles=None,
        feedback: bool = True,
        feedforward: bool = True,
        design_configuration=None,
        fd_step: float = DEFAULT_FD_STEP,
        load_identification: str = "none",
    ) -> None:
        super().__init__(model, dt)
        options = validated_options(StateFeedbackOptions, locals())
        self.dim = (4 if self.elastic else 2) * self.n
        self.feedforward = feedforward
        self.fd_step = fd_step
        if load_identification != "none" and not self.elastic:
            raise ValueError(
                "options.load_identification: the load shows in the joint torsion at rest, "
                "which a rigid arm does not have (use 'none')"
            )
        self.load_identification = load_identification
        q0 = self._configuration(design_configuration)
        A, Bu = linearize(model, q0)
        if feedback:
            lqr = options.weights
            self.gain, method = self._design(A, Bu, q0, omega, gain, lqr, poles)
        else:
            self.gain, method = np.zeros((self.n, self.dim)), "none (pure feedforward)"
        self.design = {
            "configuration": q0,
            "method": method,
            "poles": closed_loop_poles(A, Bu, self.gain),
        }
        self.bind_law()

    # ------------------------------------------------------------ design
    def _configuration(self, q0) -> np.ndarray:
        if q0 is None:
            return nominal_configuration(self.model)
        return shaped(q0, (self.n,), "options.design_configuration")

    def _design(self, A, Bu, q0, omega, gain, weights, poles) -> tuple[np.ndarray, str]:
        if gain is not None:
            return shaped(gain, (self.n, self.dim), "options.gain"), "explicit gain"
        if weights is not None:
            Q = square_matrix(weights.Q, self.dim, "weights.Q", (self.dim,))
            R = square_matrix(weights.R, self.n, "weights.R", (self.n,))
            return lqr_gain(A, Bu, Q, R), "LQR (given weights)"
        if poles is not None:
            with errors_at("options.poles"):
                return pole_placement_gain(A, Bu, poles), "pole placement"
        return lqr_bandwidth_gain(self.model, q0, omega), f"LQR, slowest pole {omega} rad/s"

    # ------------------------------------------------------------ control
    def desired(self, info: Mapping) -> tuple[np.ndarray, np.ndarray]:
        """(x_d, tau_d) at the time of ``info``: INVDYN, or the static reference."""
        ref = reference_derivatives(info, self.n)
        x_d, tau_d = self._law.desired(np.array([info_time(info)]), ref[None])
        return x_d[0], tau_d[0]

    @property
    def link_mass_change(self) -> np.ndarray:
        """s - 1 (n,): the link-mass scales identified at the last reset
        (``load_identification``; zeros without)."""
        return self._law.link_mass_change[0]


@twin_of(FeedforwardStateFeedback)
class VectorStateFeedback(StateLaw[FeedforwardStateFeedback]):
    """Eq. (13) on N arms: tau_i = K_P (x_d,i - xi_i) + tau_d,i, INVDYN batched.

    Also the law of the decentralized PD controllers (eq. (13) with a block gain).
    ``state_error`` (N, dim): x - x_d of every arm at the last call
    ([`tracked`][elastic_gym.controllers.state_feedback.VectorStateFeedback.tracked]).
    After
    [`track_link_mass`][elastic_gym.controllers.state_feedback.VectorStateFeedback.track_link_mass],
    ``link_mass_sensitivity`` (N, n, n) holds at every call
    the change of the torque per unit change of each link's mass scale in the model, and
    ``link_mass_state_sensitivity`` (N, n, dim) that of the desired state x_d.

    With ``load_identification``, the first call after an arm's reset identifies the
    link masses from its motor error, s - 1 =
    [`fit_link_masses`][elastic_gym.controllers.invdyn.fit_link_masses] (exact for an arm at rest in
    its static equilibrium, as the envs reset), kept in ``link_mass_change`` (N, n), and
    every call runs the law on that model: (x_d, tau_d)(s) = (x_d, tau_d)(1) +
    sum_i (s_i - 1) d (x_d, tau_d) / d s_i, INVDYN being linear in the masses.
    """

    def _bind(self, controller: FeedforwardStateFeedback, n_arms: int) -> None:
        super()._bind(controller, n_arms)
        self.gain = controller.gain
        self.feedforward = controller.feedforward
        self.invdyn = InverseDynamics(controller.model, controller.fd_step, self.n_arms)
        self.state_error = np.zeros((self.n_arms, self.state_dim))
        self._mass_sensitivity: LinkMassSensitivity | None = None
        self.link_mass_sensitivity: np.ndarray | None = None
        self.link_mass_state_sensitivity: np.ndarray | None = None
        self.identification = controller.load_identification
        self.link_mass_change = np.zeros((self.n_arms, self.n))
        self._unidentified = np.ones(self.n_arms, dtype=bool)
        if self.identification != "none":
            self.track_link_mass()

    def track_link_mass(self) -> None:
        """From the next call on, keep ``link_mass_sensitivity`` (N, n, n): row i of an
        arm is d tau / d s_i = K_P d x_d / d s_i + d tau_d / d s_i, the torque of this law
        with the model's link i mass scaled by 1 + c minus its torque, divided by c (exact
        for every c: [`LinkMassSensitivity`][elastic_gym.controllers.invdyn.LinkMassSensitivity]).
        The
        feedback on x - x_d and any integral of the link error do not depend on the
        masses. Costs n more INVDYN evaluations per call."""
        c = self.controller
        self._mass_sensitivity = LinkMassSensitivity(
            c.model, c.fd_step, self.n_arms, self.feedforward
        )
        self.link_mass_sensitivity = np.zeros((self.n_arms, self.n, self.n))
        self.link_mass_state_sensitivity = np.zeros((self.n_arms, self.n, self.state_dim))

    def reset_arms(self, obs: Mapping, info: Mapping, arms: np.ndarray) -> None:
        self.invdyn.reset(arms)
        self.state_error[arms] = 0.0
        self.link_mass_change[arms] = 0.0
        self._unidentified[arms] = True
        if self._mass_sensitivity is not None:
            self._mass_sensitivity.reset(arms)

    def desired(self, t: np.ndarray, ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(x_d (N, dim), tau_d (N, n)): INVDYN, or the static reference."""
        if self.feedforward:
            return self.invdyn(t, ref)
        return static_reference(self.model, ref)

    def tracked(
        self, t: np.ndarray, x: np.ndarray, ref: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """(x_d, tau_d) of `desired` (on the identified model with
        ``load_identification``); keeps x - x_d as `state_error`, the error the
        feedback of eq. (13) acts on at this call."""
        x_d, tau_d = self.desired(t, ref)
        if self._mass_sensitivity is not None:
            dx_d, dtau_d = self._mass_sensitivity(t, ref, x_d, tau_d)
            if self.identification != "none":
                x_d, tau_d = self._identified(x, x_d, tau_d, dx_d, dtau_d)
            self.link_mass_state_sensitivity = dx_d
            self.link_mass_sensitivity = np.matmul(dx_d, self.gain.T) + dtau_d
        self.state_error = x - x_d
        return x_d, tau_d

    def _identified(self, x, x_d, tau_d, dx_d, dtau_d) -> tuple[np.ndarray, np.ndarray]:
        """Identify the link masses of the arms just reset; (x_d, tau_d) on each arm's
        identified model."""
        arms = np.flatnonzero(self._unidentified)
        if len(arms):
            n = self.n
            error = x[arms, :n] - x_d[arms, :n]
            shared = self.identification == "shared"
            self.link_mass_change[arms] = fit_link_masses(dx_d[arms], error, shared)
            self._unidentified[arms] = False
        change = self.link_mass_change[:, None, :]
        return x_d + np.matmul(change, dx_d)[:, 0], tau_d + np.matmul(change, dtau_d)[:, 0]

    def torques(self, t: np.ndarray, x: np.ndarray, ref: np.ndarray) -> np.ndarray:
        x_d, tau_d = self.tracked(t, x, ref)
        return arm_rows(self.gain, x_d - x) + tau_d
