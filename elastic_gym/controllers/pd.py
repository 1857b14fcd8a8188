"""Decentralized PD laws with the INVDYN feedforward: the comparisons of eq. (13).

Both are eq. (13) with a structured (diagonal-block) gain, so they share INVDYN with
[`FeedforwardStateFeedback`][elastic_gym.controllers.state_feedback.FeedforwardStateFeedback]:

* [`MotorPD`][elastic_gym.controllers.pd.MotorPD], the "motion control law using only motor states"
  of De Luca et al.,
  Sec. V-B: tau = Kp (theta_d - theta) + Kd (theta_d' - theta') + tau_d (with
  ``feedforward=False``: PD + gravity compensation);
* [`LinkPD`][elastic_gym.controllers.pd.LinkPD]: the same on the (estimated) link state (q, q').

Gains: per joint as if the arm moved rigidly, kp = J w^2, kd = 2 zeta J w, J = B + M_ii(q0),
w = ``omega``, zeta = 0.7. Link PD on elastic arms is non-collocated: by default it uses
the bandwidth <= omega with the largest stability margin
([`most_stable_bandwidth`][elastic_gym.controllers.gain_design.most_stable_bandwidth]).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from pydantic import ValidationInfo, field_validator

from elastic_gym.controllers.gain_design import (
    Block,
    bandwidth_pd_gains,
    most_stable_bandwidth,
    pd_gain,
)
from elastic_gym.controllers.invdyn import DEFAULT_FD_STEP
from elastic_gym.controllers.state_feedback import (
    FeedforwardOptions,
    FeedforwardStateFeedback,
    VectorStateFeedback,
)
from elastic_gym.controllers.vector import twin_of
from elastic_gym.model import RobotModel
from elastic_gym.validation import (
    NonNegativeFinite,
    PositiveFinite,
    all_or_none,
    errors_at,
    per_joint_values,
    validated_options,
)

DEFAULT_BANDWIDTH = 30.0  # rad/s, as the slowest poles of the eq. (13) design


PerJointGain = NonNegativeFinite | list[NonNegativeFinite] | None


class PDOptions(FeedforwardOptions):
    """The options of [`MotorPD`][elastic_gym.controllers.pd.MotorPD] and
    [`LinkPD`][elastic_gym.controllers.pd.LinkPD] (per-joint sizes checked by the
    design)."""

    omega: PositiveFinite | None = DEFAULT_BANDWIDTH
    damping_ratio: PositiveFinite = 0.7
    kp: PerJointGain = None
    kd: PerJointGain = None

    @field_validator("kd")
    @classmethod
    def _both_gains(cls, kd: Any, info: ValidationInfo) -> Any:
        all_or_none({"kp": info.data.get("kp"), "kd": kd})  # neither: the bandwidth design
        return kd


class _BlockPD(FeedforwardStateFeedback):
    """PD on one block of the state (``block``) with the eq. (13) feedforward."""

    block: Block = "motor"
    options_model = PDOptions

    def __init__(
        self,
        model: RobotModel,
        dt: float,
        omega: float | None = DEFAULT_BANDWIDTH,
        damping_ratio: float = 0.7,
        kp=None,
        kd=None,
        feedforward: bool = True,
        design_configuration=None,
        fd_step: float = DEFAULT_FD_STEP,
        load_identification: str = "none",
    ) -> None:
        validated_options(PDOptions, locals())
        self.damping_ratio = damping_ratio
        self._kp, self._kd = kp, kd
        self.bandwidth = omega  # None: default_bandwidth() at the design configuration
        super().__init__(
            model,
            dt,
            omega=DEFAULT_BANDWIDTH if omega is None else omega,
            feedforward=feedforward,
            design_configuration=design_configuration,
            fd_step=fd_step,
            load_identification=load_identification,
        )

    def _design(self, A, Bu, q0, omega, gain, weights, poles) -> tuple[np.ndarray, str]:
        model, n = self.model, self.n
        kp, kd = self._kp, self._kd
        if kp is None:
            if self.bandwidth is None:
                self.bandwidth = self.default_bandwidth(q0)
            kp, kd = bandwidth_pd_gains(model, q0, self.bandwidth, self.damping_ratio)
        with errors_at("options.kp" if self._kp is not None else "options.omega"):
            kp, kd = per_joint_values(kp, n, "kp", 0.0), per_joint_values(kd, n, "kd", 0.0)
        gain = pd_gain(model, kp, kd, self.block)
        return gain, f"{self.block} PD"

    def default_bandwidth(self, q0: np.ndarray) -> float:
        """Bandwidth used when ``omega`` is None."""
        return DEFAULT_BANDWIDTH


class MotorPD(_BlockPD):
    """PD on the motor position and velocity + INVDYN feedforward (elastic arms).

    Args: ``omega`` (rad/s) and ``damping_ratio`` of the per-joint bandwidth rule, or
    explicit ``kp``, ``kd`` (one or N numbers); ``feedforward``, ``design_configuration``,
    ``fd_step``, ``load_identification`` as in
    [`FeedforwardStateFeedback`][elastic_gym.controllers.state_feedback.FeedforwardStateFeedback].
    """

    name = "motor-pd"
    applies_to = frozenset({"elastic"})
    block = "motor"


class LinkPD(_BlockPD):
    """PD on the (estimated) link position and velocity + INVDYN feedforward.

    ``omega=None`` (default) gives 30 rad/s on rigid arms and, on elastic arms, the
    bandwidth <= 30 rad/s with the largest stability margin.
    """

    name = "link-pd"
    block = "link"

    def __init__(self, model: RobotModel, dt: float, omega: float | None = None, **options):
        super().__init__(model, dt, omega=omega, **options)

    def default_bandwidth(self, q0: np.ndarray) -> float:
        if not self.elastic:
            return DEFAULT_BANDWIDTH
        return most_stable_bandwidth(
            self.model, q0, DEFAULT_BANDWIDTH, self.damping_ratio, self.block
        )


@twin_of(MotorPD)
class VectorMotorPD(VectorStateFeedback):
    """[`MotorPD`][elastic_gym.controllers.pd.MotorPD] on N arms
    (the eq. (13) law with its block gain)."""


@twin_of(LinkPD)
class VectorLinkPD(VectorStateFeedback):
    """[`LinkPD`][elastic_gym.controllers.pd.LinkPD] on N arms
    (the eq. (13) law with its block gain)."""
