"""What a policy's action means: torque, motor-position offsets through a motor PD, or a
residual on a classical controller. Pure logic on arrays with a leading arm axis. The action
a in [-1, 1]^n, held for ``decimation`` control periods, becomes a torque at every period:

* ``torque``: tau = tau_max * a;
* ``motor-offset``: a motor PD tracks q_d + offset_scale * a, tau = kp (q_d + offset_scale
  * a - theta) + kd (q_d' - theta') [+ g(q_d) with ``gravity_compensation``];
* ``residual`` (Residual Policy Learning, Silver et al. 2018): tau = tau_base +
  residual_scale * tau_max * rho(a), rho(a) = sign(a) max(|a| - d, 0) / (1 - d) a deadzone
  (d = ``residual_deadzone``); with ``residual_space: link-mass`` the residual scales the
  link masses of the base's model instead, s_i = 1 + residual_scale * rho(a_i), and
  tau = tau_base + sum_i (s_i - 1) d tau_base / d s_i, the base's law on that model
  ([`LinkMassSensitivity`][elastic_gym.controllers.invdyn.LinkMassSensitivity]), one shared s with
  ``residual_shared``, the rate of s with ``residual_rate`` (`LinkMassResidual`).
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

import numpy as np
from pydantic import Field, StrictBool, StrictStr, model_validator

from elastic_gym.controllers.gain_design import (
    ON_ELASTIC,
    bandwidth_pd_gains,
    nominal_configuration,
)
from elastic_gym.controllers.invdyn import fit_link_masses
from elastic_gym.model import RobotModel
from elastic_gym.validation import (
    ConfigModel,
    Finite,
    PositiveFinite,
    all_or_none,
    option_value,
    per_joint_values,
)

KINDS = ("torque", "motor-offset", "residual")
RESIDUAL_DEADZONE = 0.2  # default |a| below which a residual adds exactly nothing
RESIDUAL_SPACES = ("torque", "link-mass")
Gains = Finite | list[Finite] | None  # one or n numbers; checked against n by ActionMap


def deadzone(action: np.ndarray, width: float = 0.0) -> np.ndarray:
    """rho(a) = sign(a) max(|a| - d, 0) / (1 - d) of the action clipped to [-1, 1], d the
    ``width`` in [0, 1): exactly zero while |a| <= d, continuous at d, 1 at |a| = 1 (d = 0:
    the clipped action). Works on one arm (n,) or on N arms (N, n)."""
    a = np.clip(np.asarray(action, dtype=float), -1.0, 1.0)
    if width:
        a = np.sign(a) * np.maximum(np.abs(a) - width, 0.0) / (1.0 - width)
    return a


def residual_torque(
    action: np.ndarray, torque_limit: np.ndarray, scale: float, deadzone_width: float = 0.0
) -> np.ndarray:
    """The residual correction added to a base controller's torque:
    ``scale * torque_limit * rho(a)``, rho the `deadzone` of width ``deadzone_width``."""
    return scale * torque_limit * deadzone(action, deadzone_width)


class ActionConfig(ConfigModel):
    """How actions in [-1, 1]^n become torques (module docstring).

    Attributes:
        kind: ``"torque"``, ``"motor-offset"`` or ``"residual"``.
        offset_scale: motor-offset range (rad) at |a| = 1.
        bandwidth, damping_ratio: motor PD gains by the bandwidth rule (rad/s, -).
        kp, kd: explicit motor PD gains (one or n numbers), replacing the rule.
        gravity_compensation: add g(q_d) of the nominal model (a model term).
        residual: name of the base controller (registry of ``elastic_gym.controllers``).
        residual_options: options of the base controller.
        residual_scale: bound of the residual torque as a fraction of tau_max (the
            ``torque`` space), or of the link-mass change as a fraction of the model's
            masses (``link-mass``).
        residual_deadzone: |a| below which the residual is exactly zero, in [0, 1).
        residual_space: ``"torque"`` (added to the base's torque) or ``"link-mass"``
            (scales the link masses of the base's model).
        residual_rate: on link masses, the action sets the rate of the scales instead,
            s' = residual_rate * rho(a) (1/s), from s = 1 at every reset, within
            1 +- residual_scale (an adaptation law with a deadzone: the scales hold
            while |a| <= d). The policy sees them as the feature ``link_mass_estimate``.
        residual_shared: on link masses, one scale for all links (s_i = s, the one
            entry of the action), as a payload or a uniformly heavier arm changes them.
    """

    section = "action"
    kind: Literal[KINDS] = "torque"  # type: ignore[valid-type]
    offset_scale: PositiveFinite = 0.05
    bandwidth: PositiveFinite = 60.0
    damping_ratio: PositiveFinite = 0.7
    kp: Gains = None
    kd: Gains = None
    gravity_compensation: StrictBool = False
    residual: StrictStr | None = None
    residual_options: dict[str, Any] = Field(default_factory=dict)
    residual_scale: PositiveFinite = Field(0.1, le=1)
    residual_deadzone: Finite = Field(RESIDUAL_DEADZONE, ge=0, lt=1)
    residual_space: Literal[RESIDUAL_SPACES] = "torque"  # type: ignore[valid-type]
    residual_rate: PositiveFinite | None = None
    residual_shared: StrictBool = False

    @model_validator(mode="after")
    def _consistent(self) -> ActionConfig:
        all_or_none({"kp": self.kp, "kd": self.kd})  # neither: the bandwidth rule
        residual_kind = True if self.kind == "residual" else None  # only it takes a base
        all_or_none(
            {"kind 'residual'": residual_kind, "residual (a controller name)": self.residual}
        )
        if self.residual_space == "link-mass" and self.kind != "residual":
            raise ValueError("residual_space 'link-mass' needs kind 'residual'")
        if self.residual_rate is not None and not self.on_link_masses:
            raise ValueError("residual_rate needs kind 'residual' with residual_space 'link-mass'")
        if self.residual_shared and not self.on_link_masses:
            raise ValueError(
                "residual_shared needs kind 'residual' with residual_space 'link-mass'"
            )
        return self

    @property
    def on_link_masses(self) -> bool:
        """True when the residual scales the link masses of its base's model."""
        return self.kind == "residual" and self.residual_space == "link-mass"

    def action_size(self, n: int) -> int:
        """Entries of an action for an arm of n joints: 1 for a shared link-mass scale."""
        return 1 if self.residual_shared else n

    @property
    def model_free(self) -> bool:
        """True when no model term is in the policy's path (pure RL)."""
        return self.kind != "residual" and not self.gravity_compensation


class ActionMap:
    """tau = map(a, state, reference[, base torque]) for N arms (module docstring).

    Args:
        config: the parameterization.
        model: nominal model (torque limits, PD gain rule, gravity compensation).
    """

    def __init__(self, config: ActionConfig, model: RobotModel) -> None:
        self.config = config
        self.model = model
        self.n = model.n
        self.size = config.action_size(model.n)  # entries of an action
        self.torque_limit = np.asarray(model.torque_limit, dtype=float)
        self.kp = self.kd = np.zeros(self.n)
        kind = Annotated[str, ON_ELASTIC]  # on rigid arms: 'torque' or 'residual'
        option_value("kind", config.kind, kind, prefix="action ", context={"model": model})
        if config.kind == "motor-offset":
            if config.kp is None:
                self.kp, self.kd = bandwidth_pd_gains(
                    model, nominal_configuration(model), config.bandwidth, config.damping_ratio
                )
            else:
                self.kp = per_joint_values(config.kp, self.n, "action 'kp'", 0.0, strict=True)
                self.kd = per_joint_values(config.kd, self.n, "action 'kd'", 0.0)

    def mass_change(self, action: np.ndarray) -> np.ndarray:
        """s - 1 (N, size) of the link-mass residual for actions (N, size) (module
        docstring)."""
        config = self.config
        return config.residual_scale * deadzone(action, config.residual_deadzone)

    @property
    def needs_motor_state(self) -> bool:
        return self.config.kind == "motor-offset"

    def torque(
        self,
        action: np.ndarray,
        motor_position: np.ndarray | None = None,
        motor_velocity: np.ndarray | None = None,
        reference: np.ndarray | None = None,
        base_torque: np.ndarray | None = None,
        base_sensitivity: np.ndarray | None = None,
        mass_change: np.ndarray | None = None,
    ) -> np.ndarray:
        """Motor torque (N, n) for actions (N, size) in [-1, 1] (clipped).

        ``motor_position``, ``motor_velocity`` (N, n) and ``reference`` (N, >= 2, n) rows
        q_d, q_d', ... are needed by ``motor-offset``; ``base_torque`` (N, n) by
        ``residual``, and on link masses also ``base_sensitivity`` (N, n, n), row i of an
        arm d tau_base / d s_i (the base's ``link_mass_sensitivity``), and with
        ``residual_rate`` ``mass_change`` (N, size), s - 1 of the `LinkMassEstimate`
        (size 1: one scale for all links).
        """
        a = np.clip(np.asarray(action, dtype=float), -1.0, 1.0)
        config = self.config
        if config.kind == "torque":
            return self.torque_limit * a
        if config.on_link_masses:
            assert base_torque is not None and base_sensitivity is not None
            change = self.mass_change(a) if mass_change is None else mass_change
            change = np.broadcast_to(change, (len(change), self.n))
            return base_torque + np.matmul(change[:, None, :], base_sensitivity)[:, 0]
        if config.kind == "residual":
            return base_torque + residual_torque(
                a, self.torque_limit, config.residual_scale, config.residual_deadzone
            )
        assert reference is not None and motor_position is not None and motor_velocity is not None
        q_d, dq_d = reference[:, 0], reference[:, 1]
        target = q_d + self.config.offset_scale * a
        tau = self.kp * (target - motor_position) + self.kd * (dq_d - motor_velocity)
        if self.config.gravity_compensation:
            tau = tau + np.array([self.model.gravity(q) for q in q_d])
        return tau

    def motor_offset_action(
        self,
        torque: np.ndarray,
        motor_position: np.ndarray,
        motor_velocity: np.ndarray,
        reference: np.ndarray,
    ) -> np.ndarray:
        """The ``motor-offset`` action (rows, n), unclipped, whose motor PD applies
        ``torque`` at this motor state and reference (rows q_d, q_d', ...): the inverse of
        `torque`, a = ((tau [- g(q_d)] - kd (q_d' - theta')) / kp + theta - q_d) /
        offset_scale."""
        q_d, dq_d = reference[:, 0], reference[:, 1]
        if self.config.gravity_compensation:
            torque = torque - np.array([self.model.gravity(q) for q in q_d])
        offset = (torque - self.kd * (dq_d - motor_velocity)) / self.kp + motor_position - q_d
        return offset / self.config.offset_scale


class LinkMassEstimate:
    """The link-mass scales s of a residual with ``residual_rate``, per arm: s - 1 = 0 at
    a (re)start, then at every control period s - 1 += dt * residual_rate * rho(a), kept
    within +- residual_scale (rho the `deadzone`).

    Args:
        config: the action parameterization (``residual_rate`` set).
        n_arms: arms. size: scales per arm (links, or 1 shared). dt: control period (s).
    """

    def __init__(self, config: ActionConfig, n_arms: int, size: int, dt: float) -> None:
        assert config.residual_rate is not None
        self.config, self.dt, self.rate = config, float(dt), float(config.residual_rate)
        self.change = np.zeros((n_arms, size))  # s - 1

    def restart(self, arms: np.ndarray) -> None:
        self.change[arms] = 0.0

    def advance(self, action: np.ndarray) -> np.ndarray:
        """One control period under the actions (N, size); returns s - 1 (N, size)."""
        c = self.config
        step = self.dt * self.rate * deadzone(action, c.residual_deadzone)
        self.change = np.clip(self.change + step, -c.residual_scale, c.residual_scale)
        return self.change

    @property
    def feature(self) -> np.ndarray:
        """(s - 1) / residual_scale (N, size), in [-1, 1]: the feature
        ``link_mass_estimate``."""
        return self.change / self.config.residual_scale


FIT_BOUND = 10.0  # |feature| bound of link_mass_fit (in units of residual_scale)


class LinkMassFit:
    """The feature ``link_mass_fit`` of each arm: (s_fit - 1) / residual_scale (N, size),
    within +-FIT_BOUND, the link-mass scales that explained its base's motor-position
    error at its last reset, held. Call `latch` with the arms just reset, after the
    base's call on their first observation.

    s_fit - 1 is [`fit_link_masses`][elastic_gym.controllers.invdyn.fit_link_masses] of
    that call: the load exactly at a reset at rest, before the base has acted (a static load
    identification). Once the base moves the motor, theta carries its action, so the
    value of each arm's reset is held.
    """

    def __init__(self, config: ActionConfig, n_arms: int, n: int) -> None:
        self.config = config
        self.value = np.zeros((n_arms, config.action_size(n)))

    def latch(self, base, arms: np.ndarray) -> None:
        if not len(arms):
            return
        config, n = self.config, base.n
        fit = fit_link_masses(
            base.link_mass_state_sensitivity[arms],
            base.state_error[arms, :n],
            config.residual_shared,
        )
        self.value[arms] = np.clip(fit / config.residual_scale, -FIT_BOUND, FIT_BOUND)


class LinkMassResidual:
    """What a residual on link masses keeps of each arm beside its vector base: the
    base's d tau / d s at its last call, the scales integrated from the action with
    ``residual_rate`` (`LinkMassEstimate`) and the load fitted at each reset
    (`LinkMassFit`). The training stack and the trained-policy controller each
    hold one and, per control period: `restart` the arms reset, call the base,
    `after_base`, read `features`, then `advance` under the action.

    Args:
        config: the action parameterization (on link masses).
        base: the residual's vector base, a law with INVDYN (a clear error otherwise).
        n_arms: arms. dt: control period (s).
    """

    def __init__(self, config: ActionConfig, base, n_arms: int, dt: float) -> None:
        track = getattr(base, "track_link_mass", None)
        if track is None:
            raise ValueError(
                "residual_space 'link-mass' needs a base with INVDYN (eq. (13), its integral "
                f"action or PD variants), not {base.name!r}"
            )
        track()
        self.base = base
        self.fit = LinkMassFit(config, n_arms, base.n)
        self.estimate = (
            None
            if config.residual_rate is None
            else LinkMassEstimate(config, n_arms, config.action_size(base.n), dt)
        )

    def restart(self, arms: np.ndarray) -> None:
        if self.estimate is not None:
            self.estimate.restart(arms)

    def after_base(self, reset_arms: np.ndarray) -> np.ndarray:
        """Latch the fit of the arms just reset; the base's d tau / d s (N, n, n) of the
        call just made, a copy."""
        self.fit.latch(self.base, reset_arms)
        return self.base.link_mass_sensitivity.copy()

    def features(self) -> dict[str, np.ndarray]:
        """The features ``link_mass_fit`` and, with ``residual_rate``,
        ``link_mass_estimate`` of every arm (N, size), copies."""
        values = {"link_mass_fit": self.fit.value.copy()}
        if self.estimate is not None:
            values["link_mass_estimate"] = self.estimate.feature.copy()
        return values

    def advance(self, action: np.ndarray) -> np.ndarray | None:
        """s - 1 (N, size) under the actions (N, size) when they set its rate (one control
        period of `LinkMassEstimate`); None when they set s itself."""
        return None if self.estimate is None else self.estimate.advance(action)


def link_mass_residual(config: ActionConfig, base, n_arms: int, dt: float):
    """The `LinkMassResidual` of a residual on link masses over its vector base,
    else None."""
    return LinkMassResidual(config, base, n_arms, dt) if config.on_link_masses else None


def check_link_mass_features(features: tuple[str, ...], config: ActionConfig) -> None:
    """Refuse the feature ``link_mass_estimate`` unless the residual integrates link-mass
    scales (``residual_rate``), and ``link_mass_fit`` unless it acts on link masses."""
    if "link_mass_estimate" in features and config.residual_rate is None:
        raise ValueError(
            "observation feature 'link_mass_estimate' needs a residual on link masses with "
            "residual_rate"
        )
    if "link_mass_fit" in features and not config.on_link_masses:
        raise ValueError(
            "observation feature 'link_mass_fit' needs a residual with residual_space 'link-mass'"
        )
