"""Vector-env twins of the policy wrappers of `elastic_gym.policy.wrappers`.

The same logic ([`ActionMap`][elastic_gym.policy.actions.ActionMap],
[`ObservationBuilder`][elastic_gym.policy.observation.ObservationBuilder]) on all the arms
of a vector env (``gym.make_vec(id, N, vectorization_mode="vector_entry_point")``) at once.
Resets of some arms — autoresets, or ``reset(options={"reset_mask": ...})`` as training's
SB3 vec env does — restart their controllers, last actions and frame stacks only.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, cast

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.spaces import flatdim
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space

from elastic_gym.arms import reference_rows
from elastic_gym.controllers import public_info
from elastic_gym.controllers.vector import make_vector_controller
from elastic_gym.envs.arm_env import validated_actions
from elastic_gym.model import RobotModel
from elastic_gym.observers.vector import true_state_vector
from elastic_gym.policy.actions import (
    ActionConfig,
    ActionMap,
    check_link_mass_features,
    link_mass_residual,
)
from elastic_gym.policy.observation import (
    ErrorIntegral,
    ObservationBuilder,
    ObservationConfig,
    ObservationInputs,
    RestAtReset,
    TrueStateFeatures,
    base_state_error,
    check_base_error,
)
from elastic_gym.validation import checked_count


def elastic_batch(env: gym.vector.VectorEnv) -> Any:
    """The [`ArmBatch`][elastic_gym.envs.batch.ArmBatch] of an elastic_gym vector env (or of
    a single env seen as one arm)."""
    return cast(Any, env.unwrapped).batch


def wrapper_attribute(env: gym.vector.VectorEnv, name: str):
    """An attribute of the first wrapper down the stack that has it."""
    while True:
        if name in vars(env):
            return vars(env)[name]
        if not hasattr(env, "env"):
            raise AttributeError(f"no wrapper of {env} has {name!r}")
        env = env.env


class _ArmResets(gym.vector.VectorWrapper):
    """Tracks which arms the env restarts: at ``reset`` (mask) and by autoreset."""

    def __init__(self, env: gym.vector.VectorEnv) -> None:
        super().__init__(env)
        self._ended = np.zeros(self.num_envs, dtype=bool)

    def _reset_arms(self, options: dict | None) -> np.ndarray:
        mask = (options or {}).get("reset_mask")
        arms = np.arange(self.num_envs) if mask is None else np.flatnonzero(mask)
        self._ended[arms] = False
        return arms

    def _restarted(self, terminated: np.ndarray, truncated: np.ndarray) -> np.ndarray:
        """Arms the env reset during the step just taken (NEXT_STEP autoreset)."""
        mode = self.env.metadata.get("autoreset_mode")
        restarted = (
            np.flatnonzero(self._ended)
            if mode is AutoresetMode.NEXT_STEP
            else (np.zeros(0, dtype=np.int64))
        )
        self._ended = terminated | truncated
        return restarted


class PolicyAction(_ArmResets):
    """Actions in [-1, 1]^n of every arm -> motor torques at every control period.

    Args:
        env: a vector env below an observer wrapper (or raw sensors for the ``torque``
            and ``motor-offset`` kinds).
        action: an `ActionConfig` or its fields.
        model: the model the gravity compensation and a residual's base controller
            build on (default: the env's nominal model; e.g. an identified model).

    A residual's base controller is a vector controller of all arms
    ([`make_vector_controller`][elastic_gym.controllers.vector.make_vector_controller]).
    ``info["base_torque"]`` (N, n) holds the residual's base torque of the step just
    taken (zeros for other kinds and after a reset). The base is called on each
    observation as it arrives (its torque is applied at the next step); for a base with a
    desired state ``info["base_error"]`` (N, dim) is its state error x - x_d there.
    A residual on link masses keeps its arms' scales in ``link_mass``
    ([`LinkMassResidual`][elastic_gym.policy.actions.LinkMassResidual]) and gives its features as
    ``info["link_mass_fit"]`` (N, a), the scales its base's motor error showed at each
    arm's reset, and with ``residual_rate`` ``info["link_mass_estimate"]`` (N, a).
    """

    def __init__(
        self,
        env: gym.vector.VectorEnv,
        action: ActionConfig | dict | None = None,
        model: RobotModel | None = None,
    ) -> None:
        super().__init__(env)
        batch = elastic_batch(env)
        model = model or batch.model
        self.action_config = ActionConfig.from_config(action)
        self.map = ActionMap(self.action_config, model)
        self.n, self.dt = batch.n_joints, batch.control_dt
        self.sensors = "state" not in cast(spaces.Dict, env.single_observation_space).spaces
        self.controller = None
        self.link_mass = None
        if self.action_config.residual is not None:  # kind "residual"
            if self.sensors:
                raise ValueError("a residual policy needs a state source for its base controller")
            self.controller = make_vector_controller(
                self.action_config.residual,
                model,
                self.dt,
                self.num_envs,
                **self.action_config.residual_options,
            )
            self.link_mass = link_mass_residual(
                self.action_config, self.controller, self.num_envs, self.dt
            )
        self.single_action_space = spaces.Box(-1.0, 1.0, (self.map.size,), dtype=np.float32)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._obs: dict = {}
        self._info: dict = {}
        self._previous_motor = np.zeros((self.num_envs, self.n))
        self._base = np.zeros((self.num_envs, self.n))  # applied in the step just taken
        self._next_base = np.zeros((self.num_envs, self.n))  # for the current observation
        self._sensitivity: np.ndarray | None = None  # d tau_base / d s, step just taken
        self._next_sensitivity: np.ndarray | None = None  # ... for the current observation

    def _call_base(self, obs: Mapping, info: dict, restarted: np.ndarray) -> None:
        """The residual's base on the current observation: its torque for the next step
        and, for a base with a desired state, ``info["base_error"]`` (x - x_d). A second
        call at the same instant (the other arms of a masked reset) changes nothing."""
        if self.controller is None:
            return
        self._next_base = self.controller(obs, public_info(info))
        if self.link_mass is not None:
            self._next_sensitivity = self.link_mass.after_base(restarted)
            info.update(self.link_mass.features())
        error = base_state_error(self.controller)
        if error is not None:
            info["base_error"] = error.copy()

    def _restart(self, arms, obs: Mapping, info: Mapping) -> None:
        if self.controller is not None and len(arms):
            self.controller.reset_arms(obs, public_info(info), arms)
        if self.sensors:
            self._previous_motor[arms] = obs["motor_position"][arms]
        if self.link_mass is not None:
            self.link_mass.restart(arms)

    def reset(self, *, seed=None, options: dict | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        arms = self._reset_arms(options)
        self._restart(arms, obs, info)
        self._obs, self._info = obs, info
        self._base[arms] = 0.0
        info["base_torque"] = self._base.copy()
        self._call_base(obs, info, arms)
        return obs, info

    def step(self, actions):
        a = validated_actions(actions, self.num_envs, self.map.size)
        obs, info, n = self._obs, self._info, self.n
        self._base = self._next_base.copy()
        self._sensitivity = self._next_sensitivity
        theta = dtheta = None
        if self.map.needs_motor_state:
            if self.sensors:  # backward difference of the encoders
                theta = obs["motor_position"]
                dtheta = (theta - self._previous_motor) / self.dt
                self._previous_motor = theta.copy()
            else:
                theta, dtheta = obs["state"][:, :n], obs["state"][:, 2 * n : 3 * n]
        change = None if self.link_mass is None else self.link_mass.advance(a)
        torque = self.map.torque(
            a, theta, dtheta, reference_rows(info), self._base, self._sensitivity, change
        )
        obs, reward, terminated, truncated, info = self.env.step(torque)
        restarted = self._restarted(terminated, truncated)
        self._restart(restarted, obs, info)
        info["base_torque"] = self._base.copy()
        self._call_base(obs, info, restarted)
        self._obs, self._info = obs, info
        return obs, reward, terminated, truncated, info


class PolicyObservation(_ArmResets):
    """The policy's flat observation of every arm, (N, size) float32; ``frame_stack`` > 1
    concatenates each arm's last frames (oldest first, the first frame repeated after a
    reset), the vector twin of ``FrameStackObservation`` + ``FlattenObservation``."""

    def __init__(
        self,
        env: gym.vector.VectorEnv,
        observation: ObservationConfig | dict | None = None,
        frame_stack: int = 1,
    ) -> None:
        super().__init__(env)
        batch = elastic_batch(env)
        action_config = wrapper_attribute(env, "action_config")
        self.builder = ObservationBuilder.for_observations(
            observation,
            env.single_observation_space,
            batch.n_joints,
            batch.robot.elastic,
            action_config.kind == "residual",
            batch.torque_limit,
            action_config.action_size(batch.n_joints),
        )
        check_base_error(self.builder.features, wrapper_attribute(env, "controller"))
        check_link_mass_features(self.builder.features, action_config)
        self.frame_stack = checked_count(frame_stack, "frame_stack", 1)
        self.n = batch.n_joints
        self.action_size = action_config.action_size(self.n)
        size = self.builder.size * frame_stack
        self.single_observation_space = spaces.Box(-np.inf, np.inf, (size,), dtype=np.float32)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self._last_action = np.zeros((self.num_envs, self.action_size))
        self._frames = np.zeros((self.num_envs, frame_stack, self.builder.size), np.float32)
        self._integral = (
            ErrorIntegral(self.num_envs, self.n, batch.robot.elastic)
            if "error_integral" in self.builder.features
            else None
        )
        self._rest = (
            RestAtReset(self.num_envs, self.n) if "reset_rest" in self.builder.features else None
        )

    def _features(self, obs: Mapping, info: Mapping) -> np.ndarray:
        preview = None
        if "preview" in self.builder.features:
            preview = elastic_batch(self.env).reference_preview(self.builder.config.preview)[
                :, :, 0
            ]
        inputs = ObservationInputs(
            reference=reference_rows(info),
            last_action=self._last_action,
            state=obs.get("state"),
            motor_position=obs.get("motor_position"),
            acceleration=obs.get("acceleration"),
            preview=preview,
            base_torque=info["base_torque"],
            base_error=info.get("base_error"),
            error_integral=None if self._integral is None else self._integral.value,
            link_mass_estimate=info.get("link_mass_estimate"),
            link_mass_fit=info.get("link_mass_fit"),
            reset_rest=None if self._rest is None else self._rest.value,
        )
        return self.builder.build(inputs)

    def _latch(self, arms: np.ndarray, obs: Mapping, info: Mapping) -> None:
        if self._rest is not None and len(arms):
            self._rest.latch(arms, obs["motor_position"], reference_rows(info))

    def _integrate(self, obs: Mapping, info: Mapping, restarted: np.ndarray) -> None:
        """Advance the error integral of every arm, restart it for ``restarted``."""
        if self._integral is not None:
            every = np.arange(self.num_envs)
            self._integral.advance(every, obs["state"], reference_rows(info), info["time"])
            self._integral.restart(restarted, info["time"])

    def _observation(self, features: np.ndarray, restarted) -> np.ndarray:
        self._frames[:, :-1] = self._frames[:, 1:]
        self._frames[:, -1] = features
        self._frames[restarted] = features[restarted, None]
        return self._frames.reshape(self.num_envs, -1).copy()

    def reset(self, *, seed=None, options: dict | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        arms = self._reset_arms(options)  # a masked reset leaves the other arms' frames
        self._last_action[arms] = 0.0
        if self._integral is not None:
            self._integral.restart(arms, info["time"])
        self._latch(arms, obs, info)
        self._frames[arms] = self._features(obs, info)[arms, None]
        return self._frames.reshape(self.num_envs, -1).copy(), info

    def step(self, actions):
        a = validated_actions(actions, self.num_envs, self.action_size)
        obs, reward, terminated, truncated, info = self.env.step(a)
        self._last_action = np.clip(a, -1.0, 1.0)
        restarted = self._restarted(terminated, truncated)
        self._last_action[restarted] = 0.0
        self._integrate(obs, info, restarted)
        self._latch(restarted, obs, info)
        return (
            self._observation(self._features(obs, info), restarted),
            reward,
            terminated,
            truncated,
            info,
        )


class CriticState(gym.vector.VectorWrapper):
    """Every arm's flat policy observation with privileged entries appended for a critic
    in training: its true state's features
    ([`TrueStateFeatures`][elastic_gym.policy.observation.TrueStateFeatures] of
    ``info["true_state"]``, the current step only, not frame-stacked) if ``state``, then,
    if ``plant``, the plant parameters the arm drew at its last reset
    (``info["plant"]`` of every randomized path, in the order of
    `PATHS`; 0 for an arm that does not randomize
    a path). The first entries are the policy's observation, unchanged.

    Args:
        env: a flat policy stack (``PolicyObservation``, possibly frame-stacked).
        observation: the stack's `ObservationConfig` (its scales are used).
        state: append the true state's features.
        plant: append the drawn plant parameters (the env must randomize some).
    """

    def __init__(
        self,
        env: gym.vector.VectorEnv,
        observation: ObservationConfig | dict | None = None,
        state: bool = True,
        plant: bool = False,
    ) -> None:
        super().__init__(env)
        batch = elastic_batch(env)
        self.elastic = batch.robot.elastic
        self.features = (
            TrueStateFeatures(
                ObservationConfig.from_config(observation), batch.n_joints, self.elastic
            )
            if state
            else None
        )
        self.plant_paths = tuple(batch.plant_state.drawn) if plant else ()
        if plant and not self.plant_paths:
            raise ValueError(
                "critic_plant: the env randomizes no plant parameter (give the env kwarg randomize)"
            )
        if not (state or plant):
            raise ValueError("a critic state needs the true state, the plant or both")
        size = (
            flatdim(env.single_observation_space)
            + (self.features.size if self.features else 0)
            + len(self.plant_paths)
        )
        self.single_observation_space = spaces.Box(-np.inf, np.inf, (size,), dtype=np.float32)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)

    def _observation(self, obs: np.ndarray, info: Mapping) -> np.ndarray:
        parts = [obs]
        if self.features is not None:
            parts.append(self.features(true_state_vector(info, self.elastic), reference_rows(info)))
        if self.plant_paths:
            drawn = np.stack([info["plant"][path] for path in self.plant_paths], axis=1)
            parts.append(np.nan_to_num(drawn, nan=0.0))
        return np.concatenate(parts, axis=1)

    def reset(self, *, seed=None, options: dict | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        return self._observation(obs, info), info

    def step(self, actions):
        obs, reward, terminated, truncated, info = self.env.step(actions)
        return self._observation(obs, info), reward, terminated, truncated, info


class ActionRepeat(gym.vector.VectorWrapper):
    """Hold each action for ``repeat`` env steps and sum each arm's rewards (decimation).

    It sits above the observer wrapper, so the observer still sees every sample. The
    window ends early at the first step where an arm's episode ends: that arm must be
    reset (autoreset or ``reset_mask``) before its next action, and the others are handed
    back to the policy at the same time (a shorter hold, never a wrong one).
    """

    def __init__(self, env: gym.vector.VectorEnv, repeat: int) -> None:
        repeat = checked_count(repeat, "decimation (action repeat)", 1)
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
