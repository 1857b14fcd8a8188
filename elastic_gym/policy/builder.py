"""The one builder of a policy's env: `build_policy_env(spec, env)`.

Stack, bottom to top, on one env or on the N arms of a vector env (the single-env
wrappers of `elastic_gym.policy.wrappers` are the N = 1 case of their vector twins in
`elastic_gym.policy.vector`):

    env                                   1 kHz loop, sensors only
    ObserverWrapper / TrueStateWrapper    state source (raw "sensors": none)
    PolicyAction                          a in [-1, 1]^n -> torque at every control period
    ActionRepeat(decimation)              policy rate = 1 / (decimation control_dt)
    PolicyObservation(frames)             flat features, the last frames stacked
    (CriticState)                         privileged critic inputs (training only)

The env comes from [`PolicySpec.make_env`][elastic_gym.policy.spec.PolicySpec.make_env]
or from the caller (RL Zoo's ``env_wrapper``: `wrap_policy_env`).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym

from elastic_gym.model import RobotModel
from elastic_gym.model.identified import identified_robot_model
from elastic_gym.observers import vector as vector_observers
from elastic_gym.observers import wrappers as single_observers
from elastic_gym.policy import vector as vector_policy
from elastic_gym.policy import wrappers as single_policy
from elastic_gym.policy.spec import PolicySpec


def build_policy_env(spec: PolicySpec, env: Any, critic: bool = False) -> Any:
    """The stack of the module docstring on ``env`` (a single env or a vector env of
    elastic_gym arms); ``critic``: the training stack, with the privileged inputs of the
    spec (``critic_state`` / ``critic_plant``) appended to the observation."""
    vector = isinstance(env, gym.vector.VectorEnv)
    observers = vector_observers if vector else single_observers
    policy: Any = vector_policy if vector else single_policy
    model = spec_model(spec, env)
    if not spec.sensors:
        env = observers.ObserverWrapper(env, spec.state, model=model, **spec.observer_options)
    env = policy.PolicyAction(env, spec.action, model=model)
    if spec.decimation > 1:
        env = policy.ActionRepeat(env, spec.decimation)
    env = policy.PolicyObservation(env, spec.observation, spec.frames)
    if critic and spec.critic:
        env = policy.CriticState(env, spec.observation, spec.critic_state, spec.critic_plant)
    return env


def spec_model(spec: PolicySpec, env: Any) -> RobotModel | None:
    """The model the spec's observer and action build on: the identified model of its
    ``model_file`` on ``env``'s nominal model, or None (the env's nominal model)."""
    if spec.model_file is None:
        return None
    return identified_robot_model(spec.model_file, env.unwrapped.model)


def wrap_policy_env(env: gym.Env, **fields: Any) -> gym.Env:
    """`build_policy_env` on an env made by the caller, the spec given by its fields
    besides the env id (taken from ``env.spec``): RL Zoo's ``env_wrapper`` hyper-parameter,
    e.g. ``elastic_gym.policy.wrap_policy_env: {state: "true", decimation: 10}``."""
    made = env.unwrapped.spec
    if made is None:
        raise ValueError("wrap_policy_env needs an env made by gym.make (its spec names the id)")
    return build_policy_env(PolicySpec(env_id=made.id, **fields), env)
