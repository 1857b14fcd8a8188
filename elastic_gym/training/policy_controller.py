"""A trained run folder as a controller of the comparison runner (``"trained-policy"``).

The policy sees what it saw in training and acts the same way: every ``decimation``
calls it gets the features of :class:`~elastic_gym.training.observation.ObservationBuilder`
(from the state source, the reference in ``info``, its last action and the residual's
last base torque), normalized with the saved ``VecNormalize`` statistics; at every call
its held action becomes a torque through the same
:class:`~elastic_gym.training.actions.ActionMap` (motor PD, residual base, ...).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np
from pydantic import StrictBool

from elastic_gym.arms import as_batch
from elastic_gym.controllers import Controller, make_controller
from elastic_gym.controllers.invdyn import reference_derivatives, state_vector
from elastic_gym.controllers.vector import ARM0, ControllerTwin, make_vector_controller, twin_of
from elastic_gym.model import RobotModel
from elastic_gym.training.actions import ActionMap
from elastic_gym.training.observation import ErrorIntegral, ObservationBuilder, ObservationInputs
from elastic_gym.training.policy_env import SENSORS
from elastic_gym.training.rollouts import PolicyActor
from elastic_gym.training.trained import TrainedRun, load_run
from elastic_gym.validation import StrictModel, validated_options


class TrainedPolicyOptions(StrictModel):
    """The options of :class:`TrainedPolicyController`."""

    run: Path
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


def check_spaces(trained: TrainedRun, features: int, n_joints: int, run: str | Path) -> None:
    """Refuse a run folder whose ``model.zip`` (or ``vecnormalize.pkl``) does not take the
    observations its ``config.yaml`` rebuilds (``features`` entries, plus the critic's
    privileged ones) or does not give ``n_joints`` actions: e.g. a ``config.yaml`` edited
    or copied from another run."""
    model = trained.model
    expected = features + getattr(model.policy, "privileged_size", 0)
    shapes = {"model.zip": tuple(model.observation_space.shape)}
    statistics = getattr(getattr(trained.normalizer, "obs_rms", None), "mean", None)
    if statistics is not None:
        shapes["vecnormalize.pkl"] = tuple(np.shape(statistics))
    for name, shape in shapes.items():
        if shape != (expected,):
            raise ValueError(
                f"{run}: {name} takes observations of shape {shape}, but config.yaml "
                f"({trained.config.env_id}, state {trained.config.state!r}) gives {expected} "
                "entries: the folder's config.yaml does not match its model"
            )
    actions = tuple(model.action_space.shape)
    if actions != (n_joints,):
        raise ValueError(
            f"{run}: model.zip gives actions of shape {actions}, the comparison's robot has "
            f"{n_joints} joints: the folder's config.yaml does not match its model"
        )


class TrainedPolicyController(Controller):
    """Controller built from a folder written by ``elastic-gym train``.

    Args:
        model, dt: nominal model and control period of the comparison.
        run: the run folder. ``best``: use the best model of the learning curve.

    The comparison must feed it the state source it was trained on (``state_source``);
    policies trained on raw ``sensors`` or with a reference preview (which needs the
    task's future reference, not in a controller's ``info``) are refused.
    """

    name = "trained-policy"
    options_model = TrainedPolicyOptions

    def __init__(self, model: RobotModel, dt: float, run: str | Path, best: bool = False) -> None:
        super().__init__(model, dt)
        validated_options(TrainedPolicyOptions, locals())
        trained = load_run(run, best=best)
        config = trained.config
        if config.state == SENSORS:
            raise ValueError(
                f"the policy in {run} was trained on raw sensors; only policies trained on a "
                "state source ('true' or an observer) can run in a comparison"
            )
        action, observation = config.policy_configs(trained.settings)
        self.map = ActionMap(action, model)
        self.builder = ObservationBuilder(
            observation, self.n, model.elastic, False, action.kind == "residual", model.torque_limit
        )
        if "preview" in self.builder.features:
            raise ValueError(
                f"the policy in {run} sees a preview of the reference, which a "
                "comparison controller cannot read"
            )
        check_robot(config, model, run)
        check_spaces(trained, self.builder.size, self.n, run)
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
        x = state_vector(obs, self._law.state_dim)
        reference = reference_derivatives(info, self.n)
        return self._law.torques(x[None], reference[None], as_batch(obs), as_batch(info))[0]


@twin_of(TrainedPolicyController)
class VectorTrainedPolicy(ControllerTwin[TrainedPolicyController]):
    """:class:`TrainedPolicyController` on N arms: features and torques of all arms at
    once; the policy acts per arm (its own recurrent memory, and a per-arm call rounds as
    the single controller's does); the residual base is one vector controller."""

    def _bind(self, controller: TrainedPolicyController, n_arms: int) -> None:
        super()._bind(controller, n_arms)
        N, n, trained = self.n_arms, self.n, controller.trained
        self.base = (
            None
            if controller.base is None
            else make_vector_controller(controller.base, self.model, self.dt, N)
        )
        self.actors = [PolicyActor(trained.model, trained.normalizer) for _ in range(N)]
        self._calls = np.zeros(N, dtype=np.int64)
        self._action = np.zeros((N, n))
        self._last_action = np.zeros((N, n))
        self._last_base = np.zeros((N, n))
        self._integral = ErrorIntegral(N, n, controller.elastic)

    def reset_arms(self, obs: Mapping, info: Mapping, arms: np.ndarray) -> None:
        if self.base is not None:
            self.base.reset_arms(obs, info, arms)
        for i in arms:
            self.actors[i].start()
        self._calls[arms] = 0
        for held in (self._action, self._last_action, self._last_base):
            held[arms] = 0.0
        self._integral.restart(arms, np.broadcast_to(info["time"], (self.n_arms,)))

    def torques(
        self, x: np.ndarray, reference: np.ndarray, obs: Mapping, info: Mapping
    ) -> np.ndarray:
        """Torques (N, n) for states (N, dim) and references (N, 5, n); the batched ``obs``
        and ``info`` feed the residual base controller."""
        c, n = self.controller, self.n
        acting = np.flatnonzero(self._calls % c.decimation == 0)  # at 1 / (decimation dt)
        if len(acting):
            later = acting[self._calls[acting] > 0]  # the first call is the reset's step
            time = np.broadcast_to(info["time"], (self.n_arms,))
            self._integral.advance(later, x[later], reference[later], time)
            features = c.builder.build(
                ObservationInputs(
                    reference=reference[acting],
                    last_action=self._last_action[acting],
                    state=x[acting],
                    base_torque=self._last_base[acting],
                    error_integral=self._integral.value[acting],
                )
            )
            for k, i in enumerate(acting):
                self._action[i] = self.actors[i](features[k])
            self._last_action[acting] = np.clip(self._action[acting], -1.0, 1.0)
        self._calls += 1
        base = np.zeros((len(x), n)) if self.base is None else self.base(obs, info)
        self._last_base = base
        theta, dtheta = (x[:, :n], x[:, 2 * n : 3 * n]) if c.elastic else (None, None)
        return c.map.torque(self._action, theta, dtheta, reference, base)

    def __call__(self, obs: Mapping, info: Mapping) -> np.ndarray:
        return self.torques(self.states(obs), self.references(info), obs, info)
