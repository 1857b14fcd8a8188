"""Single-env wrapper shells around the policy-side logic (``actions``, ``observation``).

Stack, bottom to top (``make_policy_env``)::

    env -> ObserverWrapper -> PolicyAction -> ActionRepeat -> PolicyObservation

* :class:`PolicyAction`: the action in [-1, 1]^n becomes a torque at every control period
  (:class:`~elastic_gym.training.actions.ActionMap`);
* :class:`ActionRepeat`: the action is held for ``k`` periods and the rewards summed,
  above the observer, which still sees every sample;
* :class:`PolicyObservation`: the features of
  :class:`~elastic_gym.training.observation.ObservationBuilder`;
* :class:`CriticState` (training only): the true state's features appended for a
  privileged critic.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from elastic_gym.controllers import make_controller, public_info
from elastic_gym.observers.wrappers import true_state_vector
from elastic_gym.training.actions import ActionConfig, ActionMap
from elastic_gym.training.observation import (
    ObservationBuilder,
    ObservationConfig,
    ObservationInputs,
    TrueStateFeatures,
)

REFERENCE_KEYS = ("q", "dq", "ddq", "d3q", "d4q")


def reference_rows(info: dict) -> np.ndarray:
    """``info["reference"]`` as a (5, n) array: q_d .. q_d^(4)."""
    reference = info["reference"]
    return np.array([reference[key] for key in REFERENCE_KEYS], dtype=float)


def reference_preview(env: gym.Env, horizons: tuple[float, ...]) -> np.ndarray:
    """q_d at the env's time + h for each horizon, (H, n): the reference is known ahead."""
    return env.unwrapped.reference_preview(horizons)[:, 0]


def check_action(action, n: int) -> np.ndarray:
    """A finite (n,) array, or a clear error (nothing is stepped)."""
    arr = np.asarray(action)
    if arr.dtype.kind not in "fiu":
        raise TypeError(f"action must be a real numeric array, got dtype {arr.dtype}")
    if arr.shape != (n,):
        raise ValueError(f"action must have shape ({n},), got {arr.shape}")
    arr = arr.astype(np.float64)
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"action must be finite, got {arr}")
    return arr


class PolicyAction(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Actions in [-1, 1]^n -> motor torque at every control period (module docstring).

    Args:
        env: an elastic_gym env below an ``ObserverWrapper`` (or raw sensors for the
            ``torque`` and ``motor-offset`` kinds).
        action: an :class:`ActionConfig` or its fields.

    ``info["base_torque"]`` holds the residual's base torque (zeros for other kinds).
    """

    def __init__(self, env: gym.Env, action: ActionConfig | dict | None = None) -> None:
        gym.utils.RecordConstructorArgs.__init__(self, action=action)
        gym.Wrapper.__init__(self, env)
        base = env.unwrapped
        self.action_config = ActionConfig.from_config(action)
        self.map = ActionMap(self.action_config, base.model)
        self.n = base.n_joints
        self.dt = base.control_dt
        self.sensors = "state" not in env.observation_space.spaces
        self.controller = None
        if self.action_config.kind == "residual":
            if self.sensors:
                raise ValueError("a residual policy needs a state source for its base controller")
            self.controller = make_controller(
                self.action_config.residual,
                base.model,
                self.dt,
                **self.action_config.residual_options,
            )
        self.action_space = spaces.Box(-1.0, 1.0, (self.n,), dtype=np.float32)
        self._obs = self._info = None
        self._previous_motor = None

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        if self.controller is not None:
            self.controller.reset(obs, public_info(info))
        self._obs, self._info = obs, info
        self._previous_motor = None
        info["base_torque"] = np.zeros(self.n)
        return obs, info

    def _motor_state(self) -> tuple[np.ndarray, np.ndarray]:
        n, obs = self.n, self._obs
        if not self.sensors:
            state = obs["state"]
            return state[:n], state[2 * n : 3 * n]
        theta = obs["motor_position"]  # backward difference of the encoder
        previous = theta if self._previous_motor is None else self._previous_motor
        return theta, (theta - previous) / self.dt

    def step(self, action):
        a = check_action(action, self.n)
        base = np.zeros(self.n)
        if self.controller is not None:
            base = self.controller(self._obs, public_info(self._info))
        theta = dtheta = None
        if self.map.needs_motor_state:
            theta, dtheta = self._motor_state()
        torque = self.map.torque(
            a[None],
            None if theta is None else theta[None],
            None if dtheta is None else dtheta[None],
            reference_rows(self._info)[None],
            base[None],
        )[0]
        if self.sensors:
            self._previous_motor = self._obs["motor_position"]
        obs, reward, terminated, truncated, info = self.env.step(torque)
        info["base_torque"] = base
        self._obs, self._info = obs, info
        return obs, reward, terminated, truncated, info


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


class PolicyObservation(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """The policy's flat observation (module docstring of ``observation``).

    Args:
        env: a stack with a :class:`PolicyAction` below (its action kind decides whether
            the base torque is available).
        observation: an :class:`ObservationConfig` or its fields.
    """

    def __init__(self, env: gym.Env, observation: ObservationConfig | dict | None = None) -> None:
        gym.utils.RecordConstructorArgs.__init__(self, observation=observation)
        gym.Wrapper.__init__(self, env)
        base = env.unwrapped
        action_config = env.get_wrapper_attr("action_config")
        self.builder = ObservationBuilder.for_observations(
            observation,
            env.observation_space,
            base.n_joints,
            base.robot.elastic,
            action_config.kind == "residual",
            base.torque_limit,
        )
        self.n = base.n_joints
        self.observation_space = spaces.Box(-np.inf, np.inf, (self.builder.size,), dtype=np.float32)
        self._last_action = np.zeros(self.n)
        self._vector = np.zeros(self.builder.size, dtype=np.float32)

    def _observation(self, obs: dict, info: dict) -> np.ndarray:
        if "reference" not in info:  # the step that ended the episode on broken physics
            return self._vector.copy()
        config = self.builder.config
        preview = None
        if "preview" in self.builder.features:
            preview = reference_preview(self.env, config.preview)[None]
        inputs = ObservationInputs(
            reference=reference_rows(info)[None],
            last_action=self._last_action[None],
            state=obs["state"][None] if "state" in obs else None,
            motor_position=obs["motor_position"][None] if "motor_position" in obs else None,
            acceleration=obs["acceleration"][None] if "acceleration" in obs else None,
            preview=preview,
            base_torque=info["base_torque"][None],
        )
        self._vector = self.builder.build(inputs)[0]
        return self._vector.copy()

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        self._last_action = np.zeros(self.n)
        return self._observation(obs, info), info

    def step(self, action):
        a = check_action(action, self.n)
        obs, reward, terminated, truncated, info = self.env.step(a)
        self._last_action = np.clip(a, -1.0, 1.0)
        return self._observation(obs, info), reward, terminated, truncated, info


class CriticState(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """The flat policy observation with the true state's features appended
    (:class:`~elastic_gym.training.observation.TrueStateFeatures` of
    ``info["true_state"]``, the current step only, not frame-stacked): the privileged
    input of a critic in training. The first entries are the policy's observation,
    unchanged.

    Args:
        env: a flat policy stack (``PolicyObservation``, possibly frame-stacked).
        observation: the stack's :class:`ObservationConfig` (its scales are used).
    """

    def __init__(self, env: gym.Env, observation: ObservationConfig | dict | None = None) -> None:
        gym.utils.RecordConstructorArgs.__init__(self, observation=observation)
        gym.Wrapper.__init__(self, env)
        base = env.unwrapped
        self.elastic = base.robot.elastic
        self.features = TrueStateFeatures(
            ObservationConfig.from_config(observation), base.n_joints, self.elastic
        )
        size = env.observation_space.shape[0] + self.features.size
        self.observation_space = spaces.Box(-np.inf, np.inf, (size,), dtype=np.float32)

    def _observation(self, obs: np.ndarray, info: dict) -> np.ndarray:
        privileged = self.features(
            true_state_vector(info, self.elastic)[None], reference_rows(info)[None]
        )[0]
        return np.concatenate([obs, privileged])

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        return self._observation(obs, info), info

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        return self._observation(obs, info), reward, terminated, truncated, info
