"""Single-env wrapper shells around the policy-side logic (``actions``, ``observation``).

Stack, bottom to top ([`build_policy_env`][elastic_gym.policy.builder.build_policy_env])::

    env -> ObserverWrapper -> PolicyAction -> ActionRepeat -> PolicyObservation

* `PolicyAction`: the action in [-1, 1]^n becomes a torque at every control period
  ([`ActionMap`][elastic_gym.policy.actions.ActionMap]);
* `ActionRepeat`: the action is held for ``k`` periods and the rewards summed,
  above the observer, which still sees every sample;
* `PolicyObservation`: the features of
  [`ObservationBuilder`][elastic_gym.policy.observation.ObservationBuilder];
* `CriticState` (training only): the true state's features and/or the drawn plant
  parameters appended for a privileged critic.
"""

from __future__ import annotations

import functools
from typing import TypeVar

import gymnasium as gym
import numpy as np
from gymnasium.spaces import flatdim
from gymnasium.vector import VectorWrapper

from elastic_gym.envs.arm_env import validated_actions
from elastic_gym.model import RobotModel
from elastic_gym.policy import vector
from elastic_gym.policy.actions import ActionConfig
from elastic_gym.policy.observation import ObservationConfig
from elastic_gym.single_env import SingleArmWrapper

W = TypeVar("W", bound=VectorWrapper)


class _CheckedActions(SingleArmWrapper[W]):
    """A single-arm policy wrapper: the action is checked with its single-arm shape."""

    def batched_action(self, action) -> np.ndarray:
        return validated_actions(action, 0, flatdim(self.action_space))


class PolicyAction(_CheckedActions[vector.PolicyAction], gym.utils.RecordConstructorArgs):
    """Actions in [-1, 1]^n -> motor torque at every control period.

    Args:
        env: an elastic_gym env below an ``ObserverWrapper`` (or raw sensors for the
            ``torque`` and ``motor-offset`` kinds).
        action: an `ActionConfig` or its fields.
        model: the model the gravity compensation and a residual's base controller
            build on (default: the env's nominal model; e.g. an identified model).

    ``info["base_torque"]`` holds the residual's base torque (zeros for other kinds),
    ``info["base_error"]`` its base's state error x - x_d (a base with a desired state).
    """

    def __init__(
        self,
        env: gym.Env,
        action: ActionConfig | dict | None = None,
        model: RobotModel | None = None,
    ) -> None:
        gym.utils.RecordConstructorArgs.__init__(self, action=action, model=model)
        _CheckedActions.__init__(
            self, env, functools.partial(vector.PolicyAction, action=action, model=model)
        )
        self.action_config = self.vector.action_config
        self.map = self.vector.map
        self.controller = self.vector.controller  # the residual's base (vector, N = 1)

    @property
    def _info(self) -> dict:
        """The info of the last reset or step of the env below (the state source's)."""
        return self.arm.last_info


class ActionRepeat(SingleArmWrapper[vector.ActionRepeat], gym.utils.RecordConstructorArgs):
    """Hold each action for ``repeat`` env steps and sum the rewards."""

    def __init__(self, env: gym.Env, repeat: int) -> None:
        gym.utils.RecordConstructorArgs.__init__(self, repeat=repeat)
        SingleArmWrapper.__init__(self, env, functools.partial(vector.ActionRepeat, repeat=repeat))
        self.repeat = repeat


class PolicyObservation(_CheckedActions[vector.PolicyObservation], gym.utils.RecordConstructorArgs):
    """The policy's flat observation (module docstring of ``observation``).

    Args:
        env: a stack with a `PolicyAction` below (its action kind decides whether
            the base torque is available).
        observation: an `ObservationConfig` or its fields.
        frame_stack: the last ``frame_stack`` feature vectors, oldest first (the first
            repeated after a reset).
    """

    def __init__(
        self,
        env: gym.Env,
        observation: ObservationConfig | dict | None = None,
        frame_stack: int = 1,
    ) -> None:
        gym.utils.RecordConstructorArgs.__init__(
            self, observation=observation, frame_stack=frame_stack
        )
        _CheckedActions.__init__(
            self,
            env,
            functools.partial(
                vector.PolicyObservation, observation=observation, frame_stack=frame_stack
            ),
        )
        self.builder = self.vector.builder


class CriticState(SingleArmWrapper[vector.CriticState], gym.utils.RecordConstructorArgs):
    """The flat policy observation with privileged entries appended (training only): the
    true state's features (``state``) and/or the drawn plant parameters (``plant``), as
    [`CriticState`][elastic_gym.policy.vector.CriticState].

    Args:
        env: a flat policy stack (``PolicyObservation``).
        observation: the stack's `ObservationConfig` (its scales are used).
        state: append the true state's features.
        plant: append the drawn plant parameters (the env must randomize some).
    """

    def __init__(
        self,
        env: gym.Env,
        observation: ObservationConfig | dict | None = None,
        state: bool = True,
        plant: bool = False,
    ) -> None:
        gym.utils.RecordConstructorArgs.__init__(
            self, observation=observation, state=state, plant=plant
        )
        SingleArmWrapper.__init__(
            self,
            env,
            functools.partial(
                vector.CriticState, observation=observation, state=state, plant=plant
            ),
        )
