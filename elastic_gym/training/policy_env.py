"""The env a policy is trained on: state source, action parameterization, decimation,
observation features.

Stack (bottom to top; :func:`make_policy_vec_env` builds the same on N arms of one
PyBullet world with the vector twins)::

    gym.make(env_id)                      1 kHz loop, sensors only
    ObserverWrapper / TrueStateWrapper    state source ("sensors": the raw observation)
    PolicyAction                          a in [-1, 1]^n -> torque at 1 kHz
    (PlantTeacher)                        teacher: the teacher's action (distillation, N arms)
    ActionRepeat(decimation)              policy rate = 1 kHz / decimation
    PolicyObservation                     flat features
    (FrameStackObservation + Flatten)     raw sensors: the last frames
    (CriticState)                         critic_state / critic_plant (training only)
"""

from __future__ import annotations

from types import ModuleType
from typing import Any

import gymnasium as gym
from gymnasium.vector import AutoresetMode

import elastic_gym  # noqa: F401  (registers the env ids in worker processes)
from elastic_gym.observers import vector as vector_observers
from elastic_gym.observers import wrappers as observers
from elastic_gym.observers.registry import source_class
from elastic_gym.observers.sensors import SENSORS
from elastic_gym.training import vector as vector_policy
from elastic_gym.training import wrappers as policy
from elastic_gym.training.actions import ActionConfig
from elastic_gym.training.observation import ObservationConfig
from elastic_gym.validation import only_when


def check_state_source(state: str) -> None:
    """Refuse a name that is no state source (:func:`source_class`), listing the valid ones."""
    source_class(state)


def _stack(
    env: Any,
    observer_wrappers: ModuleType,
    policy_wrappers: ModuleType,
    state: str,
    observer_options: dict | None,
    decimation: int,
    action: ActionConfig | dict | None,
    observation: ObservationConfig | dict | None,
    frame_stack: int,
    critic_state: bool,
    critic_plant: bool = False,
    teacher: bool = False,
) -> Any:
    """The stack of the module docstring on ``env`` with the wrappers of the modules
    ``observer_wrappers`` and ``policy_wrappers``: the single-env ones, or their vector
    twins on a vector env. Raw sensors take no observer and no observer options."""
    check_state_source(state)
    only_when(state != SENSORS, {"observer_options": observer_options}, "state is an observer")
    if state != SENSORS:
        env = observer_wrappers.ObserverWrapper(env, state, **(observer_options or {}))
    env = policy_wrappers.PolicyAction(env, action)
    if teacher:  # only make_policy_vec_env asks for it
        from elastic_gym.training.teacher import PlantTeacher

        env = PlantTeacher(env, decimation)
    if decimation > 1:
        env = policy_wrappers.ActionRepeat(env, decimation)
    env = policy_wrappers.PolicyObservation(env, observation, frame_stack)
    if not (critic_state or critic_plant):
        return env
    return policy_wrappers.CriticState(env, observation, critic_state, critic_plant)


def make_policy_env(
    env_id: str,
    state: str = "true",
    env_kwargs: dict | None = None,
    observer_options: dict | None = None,
    decimation: int = 1,
    action: ActionConfig | dict | None = None,
    observation: ObservationConfig | dict | None = None,
    frame_stack: int = 1,
    critic_state: bool = False,
    critic_plant: bool = False,
) -> gym.Env:
    """Build the wrapper stack of the module docstring."""
    check_state_source(state)
    return wrap_policy_env(
        gym.make(env_id, **(env_kwargs or {})),
        state,
        observer_options,
        decimation,
        action,
        observation,
        frame_stack,
        critic_state,
        critic_plant,
    )


def wrap_policy_env(
    env: gym.Env,
    state: str = "true",
    observer_options: dict | None = None,
    decimation: int = 1,
    action: ActionConfig | dict | None = None,
    observation: ObservationConfig | dict | None = None,
    frame_stack: int = 1,
    critic_state: bool = False,
    critic_plant: bool = False,
) -> gym.Env:
    """The wrapper stack of the module docstring around an env made by the caller (e.g.
    RL Zoo's ``env_wrapper`` hyper-parameter)."""
    return _stack(
        env,
        observers,
        policy,
        state,
        observer_options,
        decimation,
        action,
        observation,
        frame_stack,
        critic_state,
        critic_plant,
    )


def make_policy_vec_env(
    env_id: str,
    n_arms: int,
    state: str = "true",
    env_kwargs: dict | None = None,
    observer_options: dict | None = None,
    decimation: int = 1,
    action: ActionConfig | dict | None = None,
    observation: ObservationConfig | dict | None = None,
    frame_stack: int = 1,
    autoreset_mode: AutoresetMode = AutoresetMode.DISABLED,
    critic_state: bool = False,
    critic_plant: bool = False,
    teacher: bool = False,
) -> gym.vector.VectorEnv:
    """The stack of :func:`make_policy_env` on ``n_arms`` arms in one PyBullet world;
    ``teacher``: with the plant teacher's action in ``info["teacher_action"]``
    (:class:`~elastic_gym.training.teacher.PlantTeacher`, distillation).

    Autoreset is ``DISABLED`` by default: :class:`~elastic_gym.training.sb3_vec_env.SB3VecEnv`
    resets the arms whose episode ended.
    """
    check_state_source(state)
    envs = gym.make_vec(
        env_id,
        num_envs=n_arms,
        vectorization_mode="vector_entry_point",
        autoreset_mode=autoreset_mode,
        **(env_kwargs or {}),
    )
    return _stack(
        envs,
        vector_observers,
        vector_policy,
        state,
        observer_options,
        decimation,
        action,
        observation,
        frame_stack,
        critic_state,
        critic_plant,
        teacher,
    )
