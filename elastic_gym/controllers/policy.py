"""Run a learned policy (or any callable) as a controller.

``PolicyController`` turns ``obs -> action`` into ``(obs, info) -> torque`` so that RL
policies enter the same comparisons as the classical laws. The policy is a callable, an
object with the stable-baselines3 ``predict`` interface (recurrent state handled), or the
path of a saved SB3 model with its ``algorithm``; ``normalization`` applies the training's
observation statistics (a ``VecNormalize`` or its pickle: unpickling runs code, load only
trusted files); ``preprocess(obs, info)`` maps the env observation to the policy input.
With ``scale_actions`` the policy acts in [-1, 1], mapped to the torque limits; with
``residual`` (a controller or a registry name) the policy adds a bounded correction
``residual_scale * torque_limit * clip(action, -1, 1)`` to the base torque.
"""

from __future__ import annotations

import importlib
import os
import pickle
from collections.abc import Callable, Mapping

import numpy as np

from elastic_gym.controllers.base import Controller
from elastic_gym.controllers.registry import make_controller
from elastic_gym.model import RobotModel
from elastic_gym.validation import is_real, per_joint_values


def load_sb3_model(path: str | os.PathLike, algorithm: str | type):
    """Load a saved stable-baselines3 model (``algorithm`` a class or its name)."""
    if isinstance(algorithm, str):
        try:
            sb3 = importlib.import_module("stable_baselines3")
        except ImportError as exc:  # pragma: no cover - optional dependency
            raise ImportError("loading a policy file needs stable-baselines3 (extra 'rl')") from exc
        if not hasattr(sb3, algorithm):
            raise ValueError(f"unknown stable-baselines3 algorithm {algorithm!r}")
        algorithm = getattr(sb3, algorithm)
    return algorithm.load(os.fspath(path), device="cpu")


def load_normalization(normalization):
    """A ``VecNormalize``-like object (with ``normalize_obs``) from an object or a pickle path."""
    if normalization is None:
        return None
    if isinstance(normalization, (str, os.PathLike)):
        with open(normalization, "rb") as handle:
            normalization = pickle.load(handle)  # a user-provided training artefact
    if not callable(getattr(normalization, "normalize_obs", None)):
        raise TypeError(
            "normalization must be a VecNormalize (with normalize_obs) or the path of its pickle, "
            f"got {type(normalization).__name__}"
        )
    normalization.training = False
    return normalization


class PolicyController(Controller):
    """A policy ``obs -> action`` as a controller; see the module docstring.

    Args:
        model, dt: the robot's nominal model (torque limits, residual base) and period.
        policy: callable, SB3-like model, or path of a saved SB3 model.
        algorithm: SB3 algorithm (name or class) when ``policy`` is a path.
        normalization: ``VecNormalize`` or the path of its pickle.
        preprocess: ``f(obs, info) -> policy observation``.
        scale_actions: actions in [-1, 1] scaled to ``torque_limit``.
        torque_limit: N limits (default: the model's).
        residual, residual_options, residual_scale: residual mode.
        deterministic: passed to ``predict``.
        decimation: the policy acts every ``decimation`` calls and its action is held in
            between (the residual base controller still runs at every call).
    """

    name = "policy"

    def __init__(
        self,
        model: RobotModel,
        dt: float,
        policy,
        algorithm: str | type | None = None,
        normalization=None,
        preprocess: Callable | None = None,
        scale_actions: bool = True,
        torque_limit=None,
        residual: Controller | str | None = None,
        residual_options: Mapping | None = None,
        residual_scale: float = 0.1,
        deterministic: bool = True,
        decimation: int = 1,
    ) -> None:
        super().__init__(model, dt)
        if not isinstance(decimation, int) or decimation < 1:
            raise ValueError(f"decimation must be an integer >= 1, got {decimation!r}")
        self.decimation = decimation
        if isinstance(policy, (str, os.PathLike)):
            if algorithm is None:
                raise ValueError("a policy path needs 'algorithm' (e.g. 'PPO' or 'SAC')")
            policy = load_sb3_model(policy, algorithm)
        elif algorithm is not None:
            raise ValueError("'algorithm' applies only when policy is a path")
        self._predict = callable(getattr(policy, "predict", None))
        if not (self._predict or callable(policy)):
            raise TypeError(
                f"policy must be callable or have predict(), got {type(policy).__name__}"
            )
        if preprocess is not None and not callable(preprocess):
            raise TypeError("preprocess must be callable f(obs, info)")
        for key, value in (("scale_actions", scale_actions), ("deterministic", deterministic)):
            if not isinstance(value, bool):
                raise TypeError(f"{key} must be True or False, got {value!r}")
        self.policy = policy
        self.normalization = load_normalization(normalization)
        self.preprocess = preprocess
        self.scale_actions = scale_actions
        self.deterministic = deterministic
        self.torque_limit = self._limit(torque_limit)
        self.residual = self._base_controller(residual, residual_options)
        if not (is_real(residual_scale) and 0.0 < residual_scale <= 1.0):
            raise ValueError(f"residual_scale must be in (0, 1], got {residual_scale!r}")
        self.residual_scale = float(residual_scale)
        self._state = None
        self._episode_start = np.ones(1, dtype=bool)
        self._calls = 0
        self._held = np.zeros(self.n)

    def _limit(self, torque_limit) -> np.ndarray:
        if torque_limit is None:
            return self.model.torque_limit.copy()
        return per_joint_values(torque_limit, self.n, "torque_limit", 0.0, strict=True)

    def _base_controller(self, residual, options) -> Controller | None:
        if residual is None:
            if options:
                raise ValueError("residual_options need a residual controller")
            return None
        if isinstance(residual, str):
            return make_controller(residual, self.model, self.dt, **dict(options or {}))
        if not isinstance(residual, Controller):
            raise TypeError(f"residual must be a Controller or a registry name, got {residual!r}")
        if options:
            raise ValueError("residual_options apply only when residual is a registry name")
        return residual

    def reset(self, obs: Mapping, info: Mapping) -> None:
        self._state = None
        self._episode_start = np.ones(1, dtype=bool)
        self._calls = 0
        if self.residual is not None:
            self.residual.reset(obs, info)

    def action(self, obs: Mapping, info: Mapping) -> np.ndarray:
        """The raw policy output for this observation (after preprocessing/normalization)."""
        policy_obs = self.preprocess(obs, info) if self.preprocess is not None else obs
        if self.normalization is not None:
            policy_obs = self.normalization.normalize_obs(policy_obs)
        if self._predict:
            action, self._state = self.policy.predict(
                policy_obs,
                state=self._state,
                episode_start=self._episode_start,
                deterministic=self.deterministic,
            )
            self._episode_start = np.zeros(1, dtype=bool)
        else:
            action = self.policy(policy_obs)
        action = np.asarray(action, dtype=float)
        if action.size != self.n or not np.all(np.isfinite(action)):
            raise ValueError(f"policy must return {self.n} finite numbers, got {action!r}")
        return action.reshape(self.n)

    def __call__(self, obs: Mapping, info: Mapping) -> np.ndarray:
        if self._calls % self.decimation == 0:  # the policy acts at 1 / (decimation dt)
            self._held = self.action(obs, info)
        self._calls += 1
        action = self._held
        if self.residual is not None:
            correction = self.residual_scale * self.torque_limit * np.clip(action, -1.0, 1.0)
            return self.residual(obs, info) + correction
        if self.scale_actions:
            return self.torque_limit * np.clip(action, -1.0, 1.0)
        return action
