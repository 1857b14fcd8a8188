"""Wrappers that adapt the control stack to an RL policy.

* :class:`ActionRepeat` (decimation): the policy acts at a lower rate than the 1 kHz
  loop; the action is held for ``k`` env steps and the rewards are summed. It sits
  *above* the observer wrapper, so the observer still sees every sample (DESIGN.md).
* :class:`ResidualAction`: the policy adds a bounded correction to a classical
  controller's torque, tau = controller(obs, info) + scale * tau_max * a, a in [-1, 1]^N —
  the usual way RL is made to work on stiff arms. The controller runs at every env step.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from elastic_gym.controllers import Controller, make_controller, public_info


class ActionRepeat(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Hold each action for ``repeat`` env steps and sum the rewards."""

    def __init__(self, env: gym.Env, repeat: int) -> None:
        if not isinstance(repeat, int) or repeat < 1:
            raise ValueError(f"decimation (action repeat) must be an integer >= 1, got {repeat!r}")
        gym.utils.RecordConstructorArgs.__init__(self, repeat=repeat)
        gym.Wrapper.__init__(self, env)
        self.repeat = repeat

    def step(self, action):
        total = 0.0
        for _ in range(self.repeat):
            obs, reward, terminated, truncated, info = self.env.step(action)
            total += float(reward)
            if terminated or truncated:
                break
        return obs, total, terminated, truncated, info


class ResidualAction(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """tau = controller(obs, public_info) + scale * tau_max * action, action in [-1, 1]^N.

    Args:
        env: an env whose observation the controller understands (an ``ObserverWrapper``
            or ``TrueStateWrapper`` for the state-feedback controllers).
        controller: a :class:`Controller` or a registry name (built on the env's nominal
            model at the env's control period).
        scale: bound of the correction as a fraction of the torque limit.
    """

    def __init__(self, env: gym.Env, controller: Controller | str, scale: float = 0.1,
                 **controller_options) -> None:
        gym.utils.RecordConstructorArgs.__init__(
            self, controller=controller, scale=scale, _disable_deepcopy=True, **controller_options
        )
        gym.Wrapper.__init__(self, env)
        if not (isinstance(scale, (int, float)) and 0.0 < scale <= 1.0):
            raise ValueError(f"residual scale must be in (0, 1], got {scale!r}")
        base = env.unwrapped
        if isinstance(controller, str):
            controller = make_controller(controller, base.model, base.control_dt,
                                         **controller_options)
        self.controller = controller
        self.bound = scale * base.torque_limit
        n = base.n_joints
        self.action_space = spaces.Box(-np.ones(n), np.ones(n), dtype=np.float64)
        self._obs = None
        self._info = None

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        self.controller.reset(obs, public_info(info))
        self._obs, self._info = obs, info
        return obs, info

    def step(self, action):
        correction = np.clip(np.asarray(action, dtype=float), -1.0, 1.0) * self.bound
        torque = self.controller(self._obs, public_info(self._info)) + correction
        obs, reward, terminated, truncated, info = self.env.step(torque)
        self._obs, self._info = obs, info
        return obs, reward, terminated, truncated, info
