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

from elastic_gym.controllers import Controller, make_controller
from elastic_gym.controllers.invdyn import reference_derivatives, state_vector
from elastic_gym.model import RobotModel
from elastic_gym.training.actions import ActionMap
from elastic_gym.training.observation import ObservationBuilder, ObservationInputs
from elastic_gym.training.policy_env import SENSORS
from elastic_gym.training.train import TrainedRun, load_run


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

    def __init__(self, model: RobotModel, dt: float, run: str | Path, best: bool = False) -> None:
        super().__init__(model, dt)
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
        if action.kind == "residual":
            self.base = make_controller(action.residual, model, dt, **action.residual_options)
        self.trained = trained
        self.decimation = trained.decimation
        self.state_source = config.state
        self.run = str(run)
        self._clear()

    def _clear(self) -> None:
        self._calls = 0
        self._action = np.zeros(self.n)
        self._last_action = np.zeros(self.n)
        self._last_base = np.zeros(self.n)

    def reset(self, obs: Mapping, info: Mapping) -> None:
        if self.base is not None:
            self.base.reset(obs, info)
        self.trained.start()
        self._clear()

    def __call__(self, obs: Mapping, info: Mapping) -> np.ndarray:
        n = self.n
        x = state_vector(obs, 4 * n if self.elastic else 2 * n)
        reference = reference_derivatives(info, n)
        if self._calls % self.decimation == 0:  # the policy acts at 1 / (decimation dt)
            features = self.builder.build(
                ObservationInputs(
                    reference=reference[None],
                    last_action=self._last_action[None],
                    state=x[None],
                    base_torque=self._last_base[None],
                )
            )
            self._action = self.trained.act(features[0])
            self._last_action = np.clip(self._action, -1.0, 1.0)
        self._calls += 1
        base = np.zeros(n) if self.base is None else self.base(obs, info)
        self._last_base = base
        motor = (x[None, :n], x[None, 2 * n : 3 * n]) if self.elastic else (None, None)
        return self.map.torque(self._action[None], *motor, reference[None], base[None])[0]
