"""Vector-env twins of the policy wrappers of :mod:`elastic_gym.training.wrappers`."""

from __future__ import annotations

import gymnasium as gym
import numpy as np


class ActionRepeat(gym.vector.VectorWrapper):
    """Hold each action for ``repeat`` env steps and sum each arm's rewards (decimation).

    It sits above the observer wrapper, so the observer still sees every sample. The
    window ends early at the first step where an arm's episode ends: that arm must be
    reset (autoreset or ``reset_mask``) before its next action, and the others are handed
    back to the policy at the same time (a shorter hold, never a wrong one).
    """

    def __init__(self, env: gym.vector.VectorEnv, repeat: int) -> None:
        if isinstance(repeat, bool) or not isinstance(repeat, int) or repeat < 1:
            raise ValueError(f"decimation (action repeat) must be an integer >= 1, got {repeat!r}")
        super().__init__(env)
        self.repeat = repeat

    def step(self, actions):
        total = np.zeros(self.num_envs)
        for _ in range(self.repeat):
            obs, reward, terminated, truncated, info = self.env.step(actions)
            total += reward
            if np.any(terminated | truncated):
                break
        return obs, total, terminated, truncated, info
