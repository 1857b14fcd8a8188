"""A trained run folder as a controller of the comparison runner (``"trained-policy"``).

The policy sees what it saw in training and acts the same way: every ``decimation``
calls it gets the features of :class:`~elastic_gym.training.observation.ObservationBuilder`
(from the state source, the reference in ``info``, its last action, the residual's last
base torque and its base's state error now), normalized with the saved ``VecNormalize``
statistics; at every call its held action becomes a torque through the same
:class:`~elastic_gym.training.actions.ActionMap` (motor PD, residual base, ...).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np
from pydantic import InstanceOf, StrictBool

from elastic_gym.arms import as_batch
from elastic_gym.controllers import Controller, make_controller
from elastic_gym.controllers.vector import ARM0, ControllerTwin, make_vector_controller, twin_of
from elastic_gym.model import RobotModel
from elastic_gym.training.actions import (
    ActionMap,
    check_link_mass_features,
    link_mass_residual,
)
from elastic_gym.training.observation import (
    ErrorIntegral,
    ObservationBuilder,
    ObservationInputs,
    RestAtReset,
    base_state_error,
    check_base_error,
)
from elastic_gym.training.policy_env import SENSORS
from elastic_gym.training.rollouts import PolicyActor, at_bound
from elastic_gym.training.trained import TrainedRun, load_run
from elastic_gym.validation import StrictModel, only_when, validated_options


class TrainedPolicyOptions(StrictModel):
    """The options of :class:`TrainedPolicyController`."""

    run: InstanceOf[TrainedRun] | Path
    best: StrictBool = False


def check_robot(config, model: RobotModel, run: str | Path) -> None:
    """Refuse a policy trained (by its ``config.yaml``) on another robot than ``model``'s."""
    import gymnasium as gym

    robot = config.env_kwargs.get("robot", gym.spec(config.env_id).kwargs.get("robot"))
    name = getattr(robot, "name", robot)
    if name != model.spec.name:
        raise ValueError(
            f"{run}: config.yaml says the policy was trained on {config.env_id} (robot "
            f"{name!r}); the comparison runs it on the robot {model.spec.name!r}"
        )


def check_spaces(trained: TrainedRun, features: int, actions: int, run: str | Path) -> None:
    """Refuse a run folder whose ``model.zip`` (or ``vecnormalize.pkl``) does not take the
    observations its ``config.yaml`` rebuilds (``features`` entries, plus the critic's
    privileged ones) or does not give the ``actions`` entries of its action: e.g. a
    ``config.yaml`` edited or copied from another run."""
    model = trained.model
    expected = features + getattr(model.policy, "privileged_size", 0)
    entries = f"config.yaml ({trained.config.env_id}, state {trained.config.state!r}) gives "
    entries += f"{expected} entries"
    checks = [("model.zip takes observations", model.observation_space.shape, expected, entries)]
    # vars(): an unpickled VecNormalize without observation statistics (normalize: false)
    # recurses in SB3's __getattr__ instead of raising AttributeError
    obs_rms = None if trained.normalizer is None else vars(trained.normalizer).get("obs_rms")
    statistics = getattr(obs_rms, "mean", None)
    if statistics is not None:
        checks.append(
            ("vecnormalize.pkl takes observations", np.shape(statistics), expected, entries)
        )
    joints = f"its action on the comparison's robot has {actions} entries"
    checks.append(("model.zip gives actions", model.action_space.shape, actions, joints))
    for what, shape, size, why in checks:
        if tuple(shape) != (size,):
            raise ValueError(
                f"{run}: {what} of shape {tuple(shape)}, but {why}: the folder's config.yaml "
                "does not match its model"
            )


class TrainedPolicyController(Controller):
    """Controller built from a folder written by ``elastic-gym train``.

    Args:
        model, dt: nominal model and control period of the comparison.
        run: the run folder, or a run already loaded (:class:`TrainedRun`, e.g. the
            model being trained). ``best``: use the best model of the learning curve.

    The comparison must feed it the state source it was trained on (``state_source``):
    an estimate (``obs["state"]``) or, for a policy trained on raw ``sensors``, the
    sensor observation itself (encoders and accelerometers, each arm's last
    ``frame_stack`` policy frames stacked as in training, the motor velocity of a
    motor-offset action the backward difference of the encoders). A policy that sees a
    preview of the reference (the task's future, not in a controller's ``info``) is
    refused.
    """

    name = "trained-policy"
    options_model = TrainedPolicyOptions
    takes_sensors = True  # a policy trained on them

    def __init__(
        self, model: RobotModel, dt: float, run: str | Path | TrainedRun, best: bool = False
    ) -> None:
        super().__init__(model, dt)
        validated_options(TrainedPolicyOptions, locals())
        only_when(
            not isinstance(run, TrainedRun), {"best": best}, "run is a run folder, not a loaded run"
        )
        if isinstance(run, TrainedRun):
            trained, run = run, run.config.out_dir
        else:
            trained = load_run(run, best=best)
        config = trained.config
        self.sensors = config.state == SENSORS
        action, observation = config.policy_configs(trained.settings)
        self.map = ActionMap(action, model)
        self.builder = ObservationBuilder(
            observation,
            self.n,
            model.elastic,
            self.sensors,
            action.kind == "residual",
            model.torque_limit,
            3 * model.n_sensors,
            self.map.size,
        )
        if "preview" in self.builder.features:
            raise ValueError(
                f"the policy in {run} sees a preview of the reference, which a "
                "comparison controller cannot read"
            )
        self.frame_stack = trained.stack.frame_stack
        check_robot(config, model, run)
        check_spaces(trained, self.builder.size * self.frame_stack, self.map.size, run)
        self.base = None
        if action.residual is not None:  # kind "residual"
            self.base = make_controller(action.residual, model, dt, **action.residual_options)
        self.trained = trained
        self.decimation = trained.decimation
        self.state_source = config.state
        self.run = str(run)
        self._law = VectorTrainedPolicy.of(self, 1)

    def reset(self, obs: Mapping, info: Mapping) -> None:
        self._law.reset_arms(as_batch(obs), as_batch(info), ARM0)

    def __call__(self, obs: Mapping, info: Mapping) -> np.ndarray:
        return self._law(as_batch(obs), as_batch(info))[0]


@twin_of(TrainedPolicyController)
class VectorTrainedPolicy(ControllerTwin[TrainedPolicyController]):
    """:class:`TrainedPolicyController` on N arms: features and torques of all arms at
    once; the policy acts per arm (its own recurrent memory and frame stack, and a
    per-arm call rounds as the single controller's does); the residual base is one
    vector controller."""

    def _bind(self, controller: TrainedPolicyController, n_arms: int) -> None:
        super()._bind(controller, n_arms)
        N, n, trained = self.n_arms, self.n, controller.trained
        self.base = (
            None
            if controller.base is None
            else make_vector_controller(controller.base, self.model, self.dt, N)
        )
        if self.base is not None:
            check_base_error(controller.builder.features, self.base)
        self.actors = [PolicyActor(trained.model, trained.normalizer) for _ in range(N)]
        self._calls = np.zeros(N, dtype=np.int64)
        self._action = np.zeros((N, controller.map.size))
        self._last_action = np.zeros((N, controller.map.size))
        self._last_base = np.zeros((N, n))
        self._base_error = np.zeros((N, self.state_dim))  # x - x_d of this call's base
        size = controller.builder.size
        self._frames = np.zeros((N, controller.frame_stack, size), dtype=np.float32)
        self._previous_motor = np.zeros((N, n))  # encoders at the last call (raw sensors)
        self._acts = np.zeros(N)
        self._at_bound = np.zeros(N)
        self._integral = ErrorIntegral(N, n, controller.elastic)
        self._rest = RestAtReset(N, n)
        check_link_mass_features(controller.builder.features, controller.map.config)
        self._link_mass = link_mass_residual(controller.map.config, self.base, N, self.dt)

    @property
    def arm_diagnostics(self) -> dict[str, np.ndarray]:
        """``saturated_actions``: each arm's share of policy steps since its reset with an
        action at its bound on some joint (:func:`~elastic_gym.training.rollouts.at_bound`)."""
        return {"saturated_actions": self._at_bound / np.maximum(self._acts, 1)}

    def _check_source(self, obs: Mapping) -> None:
        c = self.controller
        if c.sensors != ("state" not in obs):
            given = "a state estimate" if c.sensors else "raw sensors"
            raise ValueError(
                f"the policy in {c.run} was trained on {c.state_source!r} but the loop gives "
                f"it {given}: pair it with the state source {c.state_source!r}"
            )

    def reset_arms(self, obs: Mapping, info: Mapping, arms: np.ndarray) -> None:
        self._check_source(obs)
        if self.base is not None:
            self.base.reset_arms(obs, info, arms)
        for i in arms:
            self.actors[i].start()
        self._calls[arms] = 0
        for held in (self._action, self._last_action, self._last_base, self._acts, self._at_bound):
            held[arms] = 0.0
        if self.controller.sensors:
            motor = np.asarray(obs["motor_position"], dtype=float)
            self._previous_motor[arms] = motor[arms]
            if self.controller.elastic:
                self._rest.latch(arms, motor, self.references(info))
        self._integral.restart(arms, np.broadcast_to(info["time"], (self.n_arms,)))
        if self._link_mass is not None:
            self._link_mass.restart(arms)

    def _inputs(
        self, obs: Mapping, info: Mapping, x: np.ndarray | None, reference: np.ndarray, arms
    ) -> ObservationInputs:
        """The policy's feature inputs of the acting ``arms``: the state (and the error
        integral, advanced to this policy step), or the raw sensors."""
        link_mass = {} if self._link_mass is None else self._link_mass.features()
        inputs = ObservationInputs(
            reference=reference[arms],
            last_action=self._last_action[arms],
            base_torque=self._last_base[arms],
            base_error=self._base_error[arms],
            reset_rest=self._rest.value[arms],
            **{name: value[arms] for name, value in link_mass.items()},
        )
        if x is None:  # raw sensors
            inputs.motor_position = np.asarray(obs["motor_position"], dtype=float)[arms]
            if "acceleration" in obs:
                inputs.acceleration = np.asarray(obs["acceleration"], dtype=float)[arms]
            return inputs
        later = arms[self._calls[arms] > 0]  # the first call is the reset's step
        time = np.broadcast_to(info["time"], (self.n_arms,))
        self._integral.advance(later, x[later], reference[later], time)
        inputs.state = x[arms]
        inputs.error_integral = self._integral.value[arms]
        return inputs

    def _policy_observations(self, features: np.ndarray, arms: np.ndarray) -> np.ndarray:
        """Each acting arm's last ``frame_stack`` frames, flat, oldest first; an arm's
        first frame after its reset fills its whole stack (as in training)."""
        first = self._calls[arms] == 0
        frames = self._frames
        frames[arms[~first], :-1] = frames[arms[~first], 1:]
        frames[arms, -1] = features
        frames[arms[first]] = features[first, None]
        return frames[arms].reshape(len(arms), -1)

    def _motor_state(self, obs: Mapping, x: np.ndarray | None):
        """(theta, theta') of the action map: from the state, or the encoders and their
        backward difference over the control period (raw sensors)."""
        c, n = self.controller, self.n
        if not c.elastic:
            return None, None
        if x is not None:
            return x[:, :n], x[:, 2 * n : 3 * n]
        theta = np.asarray(obs["motor_position"], dtype=float)
        dtheta = (theta - self._previous_motor) / self.dt
        return theta, dtheta

    def __call__(self, obs: Mapping, info: Mapping) -> np.ndarray:
        c, n = self.controller, self.n
        reference = self.references(info)
        x = None if c.sensors else self.states(obs)
        base = np.zeros((self.n_arms, n)) if self.base is None else self.base(obs, info)
        sensitivity = None
        if self._link_mass is not None:  # the fit of each arm's first call after its reset
            sensitivity = self._link_mass.after_base(np.flatnonzero(self._calls == 0))
        error = base_state_error(self.base)
        if error is not None:
            self._base_error = error
        acting = np.flatnonzero(self._calls % c.decimation == 0)  # at 1 / (decimation dt)
        if len(acting):
            features = c.builder.build(self._inputs(obs, info, x, reference, acting))
            policy_obs = self._policy_observations(features, acting)
            for k, i in enumerate(acting):
                self._action[i] = self.actors[i](policy_obs[k])
            self._last_action[acting] = np.clip(self._action[acting], -1.0, 1.0)
            self._acts[acting] += 1
            self._at_bound[acting] += at_bound(self._action[acting])
        self._calls += 1
        self._last_base = base
        theta, dtheta = self._motor_state(obs, x)
        if c.sensors:
            self._previous_motor = np.asarray(obs["motor_position"], dtype=float).copy()
        change = None if self._link_mass is None else self._link_mass.advance(self._action)
        return c.map.torque(self._action, theta, dtheta, reference, base, sensitivity, change)
