"""The world of a group of runs: one vector env of its arms, a vector observer, a vector
controller.

Part of the execute stage. The controller and the observer are built on the env's nominal
model (or the scenario's identified model of the robot; ``.perturbed(**model_error)`` with
the run's model error), never on the simulated plant; the controller sees only
``{"state", "reference"}`` (on the source ``sensors``: the sensor observation) and the
public info, never the truth.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass
from typing import cast

import gymnasium as gym
import numpy as np

from elastic_gym.controllers.registry import CONTROLLERS
from elastic_gym.controllers.vector import VectorController, make_vector_controller
from elastic_gym.envs.arm_env import ArmEnv
from elastic_gym.envs.vector_env import ArmVectorEnv
from elastic_gym.evaluation.grid import RunSpec
from elastic_gym.evaluation.groups import RunGroup
from elastic_gym.model.identified import identified_robot_model
from elastic_gym.observers.base import Observer
from elastic_gym.observers.registry import make_observer
from elastic_gym.observers.sensors import RawSensors
from elastic_gym.observers.vector import ObserverWrapper as VectorObserverWrapper
from elastic_gym.observers.vector import SensorWrapper


def arm_env(env: gym.Env) -> ArmEnv:
    """The elastic_gym env under the wrappers of ``env``."""
    return cast(ArmEnv, env.unwrapped)


def arm_vector_env(envs: gym.vector.VectorEnv) -> ArmVectorEnv:
    """The elastic_gym vector env under the wrappers of ``envs``."""
    return cast(ArmVectorEnv, envs.unwrapped)


def run_model(env, spec: RunSpec):
    """The model of the run's controller and observer: the env's nominal model, or the
    run's identified model file on it, with its model error; ``env``: a single or vector
    env."""
    model = env.unwrapped.model
    if spec.model_file is not None:
        model = identified_robot_model(spec.model_file, model)
    return model.perturbed(**spec.model_error) if spec.model_error else model


def make_observer_of(spec: RunSpec, model, dt: float) -> Observer:
    """The run's state source on ``model`` (one arm's observer)."""
    source = spec.source
    if source.cls is None:
        return make_observer(source.name, model.copy(), dt, **source.options)
    return spec.observer_cls(model.copy(), dt, **source.options)


def initial_estimate(spec: RunSpec) -> np.ndarray | None:
    """The source's initial estimate (None: the observer's own start)."""
    estimate = spec.source.initial_estimate
    return None if estimate is None else np.asarray(estimate, dtype=float)


def build_vector_controller(spec: RunSpec, model, dt: float, n_arms: int) -> VectorController:
    """The run's controller for ``n_arms`` arms: a built-in's batched twin by its registry
    name, one copy per arm of any other class (`make_vector_controller`)."""
    named = spec.controller.cls is None and spec.controller.name in CONTROLLERS
    kind = spec.controller.name if named else spec.controller_cls
    return make_vector_controller(kind, model.copy(), dt, n_arms, **spec.controller.options)


@dataclass
class World:
    """The vector env of a group's arms with its vector observer and vector controller."""

    envs: gym.vector.VectorEnv
    wrapped: VectorObserverWrapper
    controller: VectorController

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self.envs.close()


def make_group_env(group: RunGroup) -> gym.vector.VectorEnv:
    """The vector env of the group's arms (no episode limit: the runs set the duration)."""
    kwargs = {**group.env_kwargs(), "episode_time": None}
    return gym.make_vec(
        group.first.env_id, len(group), vectorization_mode="vector_entry_point", **kwargs
    )


def build_observer_wrapper(
    envs: gym.vector.VectorEnv, spec: RunSpec, model
) -> VectorObserverWrapper:
    """The run's state source on ``model`` for every arm of ``envs`` (raw sensors: the
    sensor observation itself, `SensorWrapper`)."""
    if issubclass(spec.observer_cls, RawSensors):
        return SensorWrapper(envs)
    observer = make_observer_of(spec, model, arm_vector_env(envs).control_dt)
    return VectorObserverWrapper(envs, observer, initial_estimate=initial_estimate(spec))


def build_world(group: RunGroup) -> World:
    """Build the world of ``group`` (exceptions propagate; nothing is left open)."""
    spec = group.first
    envs = make_group_env(group)
    try:
        model = run_model(envs, spec)
        wrapped = build_observer_wrapper(envs, spec, model)
        controller = build_vector_controller(
            spec, model, arm_vector_env(envs).control_dt, len(group)
        )
    except BaseException:
        envs.close()
        raise
    return World(envs, wrapped, controller)
