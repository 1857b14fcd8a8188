"""stable-baselines3's ``VecEnv`` interface over a Gymnasium vector env of elastic_gym arms.

SB3 expects, in the step that ends an episode, the first observation of the next one,
with the last observation in ``infos[i]["terminal_observation"]`` and
``infos[i]["TimeLimit.truncated"]`` telling a time-out (bootstrapped by the algorithms)
from a termination. :class:`SB3VecEnv` gets there from a vector env with autoreset
``DISABLED``: after each step it resets the arms whose episode ended
(``reset(options={"reset_mask": ended})``), the other arms go on untouched. Put
``VecNormalize`` / ``VecMonitor`` on top as with any SB3 ``VecEnv``.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode
from stable_baselines3.common.vec_env import VecEnv


def _row(obs: Any, i: int) -> Any:
    if isinstance(obs, dict):
        return {key: value[i].copy() for key, value in obs.items()}
    return obs[i].copy()


def _merge(obs: Any, new: Any, rows: np.ndarray) -> Any:
    """``obs`` with the given rows taken from ``new``."""
    if isinstance(obs, dict):
        return {key: _merge(obs[key], new[key], rows) for key in obs}
    out = obs.copy()
    out[rows] = new[rows]
    return out


class SB3VecEnv(VecEnv):
    """An SB3 ``VecEnv`` of the N arms of a Gymnasium vector env (autoreset DISABLED).

    Args:
        env: the vector env (possibly wrapped), created with
            ``autoreset_mode=AutoresetMode.DISABLED``.
        info_keys: per-arm info entries copied into SB3's ``infos`` at every step
            (e.g. for callbacks); nothing else is copied (speed).
    """

    def __init__(self, env: gym.vector.VectorEnv, info_keys: Iterable[str] = ()) -> None:
        mode = env.metadata.get("autoreset_mode")
        if mode is not AutoresetMode.DISABLED:
            raise ValueError(f"SB3VecEnv needs a vector env with autoreset_mode=DISABLED "
                             f"(it resets ended arms itself), got {mode}")
        self.env = env
        self.info_keys = tuple(info_keys)
        self.render_mode = None
        super().__init__(env.num_envs, env.single_observation_space, env.single_action_space)
        self._actions: np.ndarray | None = None

    # ------------------------------------------------------------------ stepping
    def reset(self):
        seeds = None if all(s is None for s in self._seeds) else list(self._seeds)
        obs, info = self.env.reset(seed=seeds)
        self._reset_seeds()
        self.reset_infos = [self._arm_info(info, i) for i in range(self.num_envs)]
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self):
        obs, reward, terminated, truncated, info = self.env.step(self._actions)
        ended = terminated | truncated
        infos = [self._arm_info(info, i) for i in range(self.num_envs)]
        if ended.any():
            rows = np.flatnonzero(ended)
            for i in rows:
                infos[i]["terminal_observation"] = _row(obs, i)
                infos[i]["TimeLimit.truncated"] = bool(truncated[i] and not terminated[i])
            restarted, reset_info = self.env.reset(options={"reset_mask": ended})
            obs = _merge(obs, restarted, rows)
            for i in rows:
                self.reset_infos[i] = self._arm_info(reset_info, i)
        return obs, np.asarray(reward, dtype=np.float32), ended, infos

    def _arm_info(self, info: dict, i: int) -> dict:
        return {key: info[key][i] for key in self.info_keys if key in info}

    def close(self) -> None:
        self.env.close()

    # ------------------------------------------------------------------ attributes
    def _indices(self, indices: int | Iterable[int] | None) -> Sequence[int]:
        if indices is None:
            return range(self.num_envs)
        return [indices] if isinstance(indices, int) else list(indices)

    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        """The vector env's attribute (shared by every arm), once per requested arm."""
        value = getattr(self.env, attr_name)
        return [value for _ in self._indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        setattr(self.env.unwrapped, attr_name, value)

    def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs):
        result = getattr(self.env, method_name)(*method_args, **method_kwargs)
        return [result for _ in self._indices(indices)]

    def env_is_wrapped(self, wrapper_class: type, indices=None) -> list[bool]:
        return [False for _ in self._indices(indices)]

    def get_images(self) -> Sequence[np.ndarray | None]:
        return [None for _ in range(self.num_envs)]
