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
from typing import Annotated, Any

import numpy as np
from pydantic import Field, StrictBool, model_validator

from elastic_gym.arms import arm_view, as_batch
from elastic_gym.controllers.base import Controller
from elastic_gym.controllers.registry import make_controller
from elastic_gym.controllers.vector import (
    ARM0,
    ControllerTwin,
    make_vector_controller,
    twin_of,
)
from elastic_gym.model import RobotModel
from elastic_gym.validation import (
    StrictModel,
    all_or_none,
    lookup,
    only_when,
    per_joint_values,
    validated_options,
)

RESIDUAL_DEADZONE = 0.2  # default |a| below which a residual adds exactly nothing


def deadzone(action: np.ndarray, width: float = 0.0) -> np.ndarray:
    """rho(a) = sign(a) max(|a| - d, 0) / (1 - d) of the action clipped to [-1, 1], d the
    ``width`` in [0, 1): exactly zero while |a| <= d, continuous at d, 1 at |a| = 1 (d = 0:
    the clipped action). Works on one arm (n,) or on N arms (N, n)."""
    a = np.clip(np.asarray(action, dtype=float), -1.0, 1.0)
    if width:
        a = np.sign(a) * np.maximum(np.abs(a) - width, 0.0) / (1.0 - width)
    return a


def residual_torque(
    action: np.ndarray, torque_limit: np.ndarray, scale: float, deadzone_width: float = 0.0
) -> np.ndarray:
    """The residual correction added to a base controller's torque:
    ``scale * torque_limit * rho(a)``, rho the :func:`deadzone` of width
    ``deadzone_width``."""
    return scale * torque_limit * deadzone(action, deadzone_width)


def load_sb3_model(path: str | os.PathLike, algorithm: str | type):
    """Load a saved stable-baselines3 model (``algorithm`` a class or its name)."""
    if isinstance(algorithm, str):
        try:
            sb3 = importlib.import_module("stable_baselines3")
        except ImportError as exc:  # pragma: no cover - optional dependency
            raise ImportError("loading a policy file needs stable-baselines3 (extra 'rl')") from exc
        base = importlib.import_module("stable_baselines3.common.base_class").BaseAlgorithm
        algorithms = {
            name: cls
            for name, cls in vars(sb3).items()
            if isinstance(cls, type) and issubclass(cls, base)
        }
        algorithm = lookup(algorithms, algorithm, "stable-baselines3 algorithm")
    cls: Any = algorithm
    return cls.load(os.fspath(path), device="cpu")


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


class PolicyOptions(StrictModel):
    """The options of :class:`PolicyController` (the policy and its normalization are
    checked by the controller as they are loaded)."""

    policy: Any
    algorithm: str | type | None = None
    preprocess: Callable | None = None
    scale_actions: StrictBool = True
    residual: Controller | str | None = None
    residual_options: dict[str, Any] | None = None
    residual_scale: Annotated[float, Field(strict=True, gt=0.0, le=1.0)] = 0.1
    residual_deadzone: Annotated[float, Field(strict=True, ge=0.0, lt=1.0)] = RESIDUAL_DEADZONE
    deterministic: StrictBool = True
    decimation: Annotated[int, Field(strict=True, ge=1)] = 1

    @model_validator(mode="after")
    def _paired(self) -> PolicyOptions:
        path = self.policy if isinstance(self.policy, (str, os.PathLike)) else None
        all_or_none({"policy (a path)": path, "algorithm": self.algorithm})
        only_when(
            isinstance(self.residual, str),
            {"residual_options": self.residual_options},
            "residual is a controller's registry name",
            loc=("residual_options",),
        )
        return self


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
        residual, residual_options, residual_scale, residual_deadzone: residual mode
            (:func:`residual_torque`).
        deterministic: passed to ``predict``.
        decimation: the policy acts every ``decimation`` calls and its action is held in
            between (the residual base controller still runs at every call).
    """

    name = "policy"
    options_model = PolicyOptions
    takes_sensors = True  # the policy gets the observation as it is

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
        residual_deadzone: float = RESIDUAL_DEADZONE,
        deterministic: bool = True,
        decimation: int = 1,
    ) -> None:
        super().__init__(model, dt)
        validated_options(PolicyOptions, locals())
        self.decimation = decimation
        if algorithm is not None:  # with a policy path (PolicyOptions)
            policy = load_sb3_model(policy, algorithm)
        self._predict = callable(getattr(policy, "predict", None))
        if not (self._predict or callable(policy)):
            raise TypeError(
                f"policy must be callable or have predict(), got {type(policy).__name__}"
            )
        self.policy = policy
        self.normalization = load_normalization(normalization)
        self.preprocess = preprocess
        self.scale_actions = scale_actions
        self.deterministic = deterministic
        self.torque_limit = self._limit(torque_limit)
        self.residual = self._base_controller(residual, residual_options)
        self.residual_scale = float(residual_scale)
        self.residual_deadzone = float(residual_deadzone)
        self._law = VectorPolicyController.of(self, 1)

    def _limit(self, torque_limit) -> np.ndarray:
        if torque_limit is None:
            return self.model.torque_limit.copy()
        return per_joint_values(torque_limit, self.n, "torque_limit", 0.0, strict=True)

    def _base_controller(self, residual, options) -> Controller | None:
        if isinstance(residual, str):
            return make_controller(residual, self.model, self.dt, **dict(options or {}))
        return residual  # a Controller or None (PolicyOptions)

    def reset(self, obs: Mapping, info: Mapping) -> None:
        self._law.reset_arms(as_batch(obs), as_batch(info), ARM0)

    def action(self, obs: Mapping, info: Mapping) -> np.ndarray:
        """The raw policy output for this observation (after preprocessing/normalization)."""
        return self._law.act(0, obs, info)

    def __call__(self, obs: Mapping, info: Mapping) -> np.ndarray:
        return self._law(as_batch(obs), as_batch(info))[0]


@twin_of(PolicyController)
class VectorPolicyController(ControllerTwin[PolicyController]):
    """:class:`PolicyController` on N arms: each arm has its own recurrent state, call
    count and held action, and the policy is called once per acting arm with that arm's
    observation (a batched call would round differently from the single controller's);
    the residual base runs as one vector controller for all arms."""

    def _bind(self, controller: PolicyController, n_arms: int) -> None:
        super()._bind(controller, n_arms)
        N, residual = self.n_arms, controller.residual
        self.base = (
            None if residual is None else make_vector_controller(residual, self.model, self.dt, N)
        )
        self._states: list = [None] * N
        self._episode_start = np.ones(N, dtype=bool)
        self._calls = np.zeros(N, dtype=np.int64)
        self._held = np.zeros((N, self.n))

    def reset_arms(self, obs: Mapping, info: Mapping, arms: np.ndarray) -> None:
        for i in arms:
            self._states[i] = None
        self._episode_start[arms] = True
        self._calls[arms] = 0
        if self.base is not None:
            self.base.reset_arms(obs, info, arms)

    def act(self, i: int, obs: Mapping, info: Mapping) -> np.ndarray:
        """The raw policy output (n,) of arm i for its own observation and info."""
        c = self.controller
        policy_obs = c.preprocess(obs, info) if c.preprocess is not None else obs
        if c.normalization is not None:
            policy_obs = c.normalization.normalize_obs(policy_obs)
        if c._predict:
            action, self._states[i] = c.policy.predict(
                policy_obs,
                state=self._states[i],
                episode_start=self._episode_start[i : i + 1].copy(),
                deterministic=c.deterministic,
            )
            self._episode_start[i] = False
        else:
            action = c.policy(policy_obs)
        action = np.asarray(action, dtype=float)
        if action.size != self.n or not np.all(np.isfinite(action)):
            raise ValueError(f"policy must return {self.n} finite numbers, got {action!r}")
        return action.reshape(self.n)

    def __call__(self, obs: Mapping, info: Mapping) -> np.ndarray:
        c = self.controller
        for arm in np.flatnonzero(self._calls % c.decimation == 0):  # acts at 1/(decimation dt)
            i = int(arm)
            self._held[i] = self.act(i, arm_view(obs, i), arm_view(info, i))
        self._calls += 1
        action = np.clip(self._held, -1.0, 1.0)
        if self.base is not None:
            correction = residual_torque(
                self._held, c.torque_limit, c.residual_scale, c.residual_deadzone
            )
            return self.base(obs, info) + correction
        if c.scale_actions:
            return c.torque_limit * action
        return self._held.copy()
