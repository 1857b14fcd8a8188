"""Single-env wrappers as the N = 1 case of their vector twins.

A wrapper's logic is written once, for N arms with a leading arm axis (a
``gym.vector.VectorWrapper`` over an elastic_gym vector env); `SingleArmWrapper` runs
that same code on one env (the reverse of Gymnasium, which derives its vector wrappers
from the single-env ones). The wrapped env is seen as a vector env of one arm
(`OneArm`, autoreset disabled): observations and info get a leading axis of length
1 on the way in and lose it on the way out (Gymnasium's ``_key`` masks dropped; numpy
scalars of one arm become Python scalars, as a single env gives them). Info items the
vector logic leaves alone are handed back as the wrapped env made them.

An episode that has ended (terminated, truncated, or ended by the vector logic through
``end_episodes``) must be reset before the next ``step``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, Generic, TypeVar

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv, VectorWrapper
from gymnasium.vector.utils import batch_space

from elastic_gym.arms import as_batch, elastic_base, single_arm


class OneArm(VectorEnv):
    """One elastic_gym env (possibly wrapped) as a vector env of one arm.

    Autoreset is ``DISABLED``: stepping an arm whose episode has ended raises
    ``RuntimeError`` until ``reset``. ``batch`` is the env's
    [`ArmBatch`][elastic_gym.envs.batch.ArmBatch] (what vector wrappers read: model, control
    period, reference preview).
    """

    def __init__(self, env: gym.Env) -> None:
        batch = elastic_base(env, "this wrapper", vector=False).batch
        self.env, self.batch = env, batch
        self.num_envs = 1
        self.metadata = {**env.metadata, "autoreset_mode": AutoresetMode.DISABLED}
        self.render_mode = env.render_mode
        self.single_observation_space = env.observation_space
        self.single_action_space = env.action_space
        self.observation_space = batch_space(env.observation_space, 1)
        self.action_space = batch_space(env.action_space, 1)
        self.last_info: dict = {}  # the env's info of the last reset or step
        self._sent: dict = {}
        self._ended = True

    @property
    def control_dt(self) -> float:
        return self.batch.control_dt

    def _as_batch(self, obs: Any, info: dict) -> tuple[Any, dict]:
        self.last_info = info
        self._sent = {key: as_batch(value) for key, value in info.items()}
        return as_batch(obs), dict(self._sent)

    def single_info(self, info: Mapping) -> dict:
        """The single env's info of the last reset or step, with the items the vector
        logic added or replaced in ``info`` (its batched form) taken from it."""
        out = dict(self.last_info)
        for key, value in info.items():
            if not key.startswith("_") and self._sent.get(key) is not value:
                out[key] = single_arm(value)
        return out

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        self._ended = False
        return self._as_batch(obs, info)

    def step(self, actions):
        if self._ended:
            raise RuntimeError("call reset() before step() (and after an episode has ended)")
        obs, reward, terminated, truncated, info = self.env.step(actions[0])
        self._ended = bool(terminated or truncated)
        obs, info = self._as_batch(obs, info)
        return (
            obs,
            np.array([reward], dtype=float),
            np.array([terminated]),
            np.array([truncated]),
            info,
        )

    def end_episodes(self, arms: np.ndarray) -> None:
        """End the episode now (the vector logic terminated it): the next step needs a reset."""
        if len(arms):
            self._ended = True

    def render(self):
        return self.env.render()


W = TypeVar("W", bound=VectorWrapper)


class SingleArmWrapper(gym.Wrapper, Generic[W]):
    """A vector wrapper's logic on one env (module docstring).

    Args:
        env: an elastic_gym env, possibly wrapped.
        vector: builds the vector wrapper on the env seen as one arm (`OneArm`).

    ``vector`` is the vector wrapper doing the work; ``observation_space`` and
    ``action_space`` are its single-arm spaces.
    """

    def __init__(self, env: gym.Env, vector: Callable[[OneArm], W]) -> None:
        gym.Wrapper.__init__(self, env)
        self.arm = OneArm(env)
        self.vector: W = vector(self.arm)
        self.observation_space = self.vector.single_observation_space
        self.action_space = self.vector.single_action_space

    def batched_action(self, action: Any) -> np.ndarray:
        """The action with the arm axis the vector logic expects (checks: subclasses)."""
        return np.asarray(action)[None]

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        obs, info = self.vector.reset(seed=seed, options=options)
        return single_arm(obs), self.arm.single_info(info)

    def step(self, action):
        obs, reward, terminated, truncated, info = self.vector.step(self.batched_action(action))
        return (
            single_arm(obs),
            float(reward[0]),
            bool(terminated[0]),
            bool(truncated[0]),
            self.arm.single_info(info),
        )
