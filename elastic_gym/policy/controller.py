"""The one controller that runs a policy in ``compare`` and ``benchmark``:
`PolicyController`, registered as ``"policy"`` and ``"trained-policy"``.

It runs a **deployed policy** — an exported policy folder (`elastic-gym export`: an ONNX
graph and its manifest, run by onnxruntime, nothing unpickled), a training run folder (SB3
pickles: only with ``trust_pickle``) or a loaded
[`Policy`][elastic_gym.policy.loading.Policy] — on the features of its spec and the state
source it was trained on (`elastic_gym.policy.deployed_law`); or a **callable**
``obs -> action`` (or an object with SB3's ``predict``) on the env's own observation, its
actions scaled to the torque limits or added as a bounded residual to a base controller
(`elastic_gym.policy.callable_law`). Both run batched, each arm with its own memory
(recurrent state, frame stack, held action): the single controller is the N = 1 case of
its vector twin `VectorPolicy`.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping
from typing import Annotated, Any

import gymnasium as gym
import numpy as np
from pydantic import Field, StrictBool, model_validator

from elastic_gym.arms import as_batch
from elastic_gym.controllers.base import Controller
from elastic_gym.controllers.registry import make_controller
from elastic_gym.controllers.vector import ARM0, ControllerTwin, twin_of
from elastic_gym.model import RobotModel
from elastic_gym.policy.actions import RESIDUAL_DEADZONE, ActionMap
from elastic_gym.policy.callable_law import CallableLaw
from elastic_gym.policy.deployed_law import DeployedLaw
from elastic_gym.policy.loading import Policy, load_normalization, load_policy, load_sb3_model
from elastic_gym.policy.observation import ObservationBuilder
from elastic_gym.validation import (
    StrictModel,
    all_or_none,
    at_most_one,
    only_when,
    per_joint_values,
    validated_options,
)

CALLABLE_OPTIONS = {  # option -> its default; given only with a callable policy
    "algorithm": None,
    "normalization": None,
    "preprocess": None,
    "scale_actions": True,
    "torque_limit": None,
    "residual": None,
    "residual_options": None,
    "residual_scale": 0.1,
    "residual_deadzone": RESIDUAL_DEADZONE,
    "deterministic": True,
    "decimation": 1,
}


def is_folder(value: Any) -> bool:
    """True for the path of a policy folder (an exported policy or a run folder)."""
    return isinstance(value, (str, os.PathLike))


class PolicyOptions(StrictModel):
    """The options of `PolicyController`: ``policy`` (or ``run``, the same: the option name
    of ``trained-policy``) is a policy folder, a loaded `Policy`, a callable or an SB3-like
    model; the other options of a callable are refused with a folder."""

    policy: Any = None
    run: Any = None
    trust_pickle: StrictBool = False
    best: StrictBool = False
    algorithm: str | type | None = None
    normalization: Any = None
    preprocess: Callable | None = None
    scale_actions: StrictBool = True
    torque_limit: Any = None
    residual: Controller | str | None = None
    residual_options: dict[str, Any] | None = None
    residual_scale: Annotated[float, Field(strict=True, gt=0.0, le=1.0)] = 0.1
    residual_deadzone: Annotated[float, Field(strict=True, ge=0.0, lt=1.0)] = RESIDUAL_DEADZONE
    deterministic: StrictBool = True
    decimation: Annotated[int, Field(strict=True, ge=1)] = 1

    @model_validator(mode="after")
    def _one_kind(self) -> PolicyOptions:
        at_most_one({"policy": self.policy, "run": self.run}, required=True)
        given = self.run if self.policy is None else self.policy
        zip_file = is_folder(given) and self.algorithm is not None  # an SB3 model file
        deployed = isinstance(given, Policy) or (is_folder(given) and not zip_file)
        if deployed:
            callable_options = {  # True: given (only_when reads False as not given)
                key: True
                for key, default in CALLABLE_OPTIONS.items()
                if getattr(self, key) != default
            }
            only_when(False, callable_options, "the policy is a callable or an SB3 model")
        only_when(is_folder(given) and not zip_file, {"best": self.best}, "the policy is a folder")
        path = given if zip_file else None
        all_or_none({"policy (a model file)": path, "algorithm": self.algorithm})
        only_when(
            isinstance(self.residual, str),
            {"residual_options": self.residual_options},
            "residual is a controller's registry name",
            loc=("residual_options",),
        )
        return self


class PolicyController(Controller):
    """A policy as a controller (module docstring).

    Args:
        model, dt: the comparison's nominal model and control period.
        policy: an exported policy folder, a training run folder (with ``trust_pickle``),
            a loaded `Policy`, a callable ``obs -> action``, an object with SB3's
            ``predict``, or the path of a saved SB3 model (with ``algorithm`` and
            ``trust_pickle``).
        run: the same as ``policy`` (the option name of ``trained-policy``).
        trust_pickle: load pickles (an SB3 run folder, model file or ``VecNormalize``
            pickle): unpickling runs code stored in the files; only for files you made
            or trust.
        best: a run folder's best model of its learning curve.

    Options of a callable or SB3 model on the env's own observation:
        algorithm: SB3 algorithm (name or class) when ``policy`` is a model file.
        normalization: a ``VecNormalize`` or the path of its pickle.
        preprocess: ``f(obs, info) -> policy observation``.
        scale_actions: actions in [-1, 1] scaled to ``torque_limit``.
        torque_limit: N limits (default: the model's).
        residual, residual_options, residual_scale, residual_deadzone: a residual on a
            base controller (an instance or a registry name).
        deterministic: passed to ``predict``.
        decimation: the policy acts every ``decimation`` calls, its action held between.

    A deployed policy must be fed the state source it was trained on (``state_source``):
    an estimate (``obs["state"]``) or, for a policy trained on raw ``sensors``, the sensor
    observation itself. A policy that sees a preview of the reference (the task's future,
    not in a controller's ``info``) is refused.
    """

    name = "policy"
    options_model = PolicyOptions
    policy: Any  # a deployed Policy, or the callable / SB3-like model
    takes_sensors = True  # a policy trained on them, or a callable given them

    def __init__(
        self,
        model: RobotModel,
        dt: float,
        policy: Any = None,
        run: Any = None,
        trust_pickle: bool = False,
        best: bool = False,
        algorithm: str | type | None = None,
        normalization: Any = None,
        preprocess: Callable | None = None,
        scale_actions: bool = True,
        torque_limit: Any = None,
        residual: Controller | str | None = None,
        residual_options: Mapping | None = None,
        residual_scale: float = 0.1,
        residual_deadzone: float = RESIDUAL_DEADZONE,
        deterministic: bool = True,
        decimation: int = 1,
    ) -> None:
        options = {key: value for key, value in locals().items() if key in CALLABLE_OPTIONS}
        super().__init__(model, dt)
        validated_options(PolicyOptions, locals())
        given = run if policy is None else policy
        self.deployed = isinstance(given, Policy) or (is_folder(given) and algorithm is None)
        if self.deployed:
            loaded = given if isinstance(given, Policy) else load_policy(given, trust_pickle, best)
            self._deploy(loaded)
        else:
            self._callable(given, trust_pickle, **options)
        self._law = VectorPolicy.of(self, 1)

    # ------------------------------------------------------------------ deployed policy
    def _deploy(self, policy: Policy) -> None:
        model, spec = self.model, policy.spec
        self.policy = policy
        self.source = policy.source
        self.sensors = spec.sensors
        self.map = ActionMap(spec.action, model)
        self.builder = ObservationBuilder(
            spec.observation,
            self.n,
            model.elastic,
            self.sensors,
            spec.action.kind == "residual",
            model.torque_limit,
            3 * model.n_sensors,
            self.map.size,
        )
        if "preview" in self.builder.features:
            raise ValueError(
                f"the policy in {policy.source} sees a preview of the reference, which a "
                "comparison controller cannot read"
            )
        self.frames = spec.frames
        check_robot(policy, model)
        check_sizes(policy, self.builder.size * self.frames, self.map.size)
        self.base = None
        if spec.action.residual is not None:  # kind "residual"
            options = spec.action.residual_options
            self.base = make_controller(spec.action.residual, model, self.dt, **options)
        self.decimation = spec.decimation
        self.state_source = spec.state

    # ------------------------------------------------------------------ callable policy
    def _callable(self, policy: Any, trust_pickle: bool, **options: Any) -> None:
        algorithm = options["algorithm"]
        if algorithm is not None:  # with a model file (PolicyOptions)
            policy = load_sb3_model(policy, algorithm, trust_pickle)
        self.predicts = callable(getattr(policy, "predict", None))
        if not (self.predicts or callable(policy)):
            raise TypeError(
                f"policy must be callable or have predict(), got {type(policy).__name__}"
            )
        self.policy = policy
        self.source = getattr(policy, "__qualname__", type(policy).__name__)
        self.normalization = load_normalization(options["normalization"], trust_pickle)
        self.preprocess = options["preprocess"]
        self.scale_actions = options["scale_actions"]
        self.deterministic = options["deterministic"]
        self.decimation = options["decimation"]
        limit = options["torque_limit"]
        self.torque_limit = (
            self.model.torque_limit.copy()
            if limit is None
            else per_joint_values(limit, self.n, "torque_limit", 0.0, strict=True)
        )
        residual = options["residual"]
        if isinstance(residual, str):
            residual = make_controller(
                residual, self.model, self.dt, **dict(options["residual_options"] or {})
            )
        self.residual = residual
        self.residual_scale = float(options["residual_scale"])
        self.residual_deadzone = float(options["residual_deadzone"])

    # ------------------------------------------------------------------ the loop
    def reset(self, obs: Mapping, info: Mapping) -> None:
        self._law.reset_arms(as_batch(obs), as_batch(info), ARM0)

    def action(self, obs: Mapping, info: Mapping) -> np.ndarray:
        """A callable policy's raw output for this observation (after preprocessing and
        normalization)."""
        law = self._law.law
        if not isinstance(law, CallableLaw):
            raise TypeError("action() is the raw output of a callable policy")
        return law.act(0, obs, info)

    def __call__(self, obs: Mapping, info: Mapping) -> np.ndarray:
        return self._law(as_batch(obs), as_batch(info))[0]


def check_robot(policy: Policy, model: RobotModel) -> None:
    """Refuse a policy trained (by its spec) on another robot than ``model``'s."""
    spec = policy.spec
    robot = spec.env_kwargs.get("robot", gym.spec(spec.env_id).kwargs.get("robot"))
    name = getattr(robot, "name", robot)
    if name != model.spec.name:
        raise ValueError(
            f"{policy.source}: {policy.spec_file} says the policy was trained on "
            f"{spec.env_id} (robot {name!r}); the comparison runs it on the robot "
            f"{model.spec.name!r}"
        )


def check_sizes(policy: Policy, features: int, actions: int) -> None:
    """Refuse a policy whose actor does not take the observations its spec builds
    (``features`` entries) or does not give the ``actions`` entries of its action: e.g. a
    ``config.yaml`` edited or copied from another run."""
    spec, actor = policy.spec, policy.actor
    entries = f"{policy.spec_file} ({spec.env_id}, state {spec.state!r}) gives {features} entries"
    joints = f"its action on the comparison's robot has {actions} entries"
    checks = [
        (f"{policy.actor_file} takes observations", actor.observation_size, features, entries),
        (f"{policy.actor_file} gives actions", actor.action_size, actions, joints),
    ]
    for what, size, wanted, why in checks:
        if size != wanted:
            raise ValueError(
                f"{policy.source}: {what} of shape ({size},), but {why}: the folder's "
                f"{policy.spec_file} does not match its {policy.actor_file}"
            )


@twin_of(PolicyController)
class VectorPolicy(ControllerTwin[PolicyController]):
    """`PolicyController` on N arms: a deployed policy's loop
    ([`DeployedLaw`][elastic_gym.policy.deployed_law.DeployedLaw]) or a callable's
    ([`CallableLaw`][elastic_gym.policy.callable_law.CallableLaw]), each arm with its
    own memory."""

    def _bind(self, controller: PolicyController, n_arms: int) -> None:
        super()._bind(controller, n_arms)
        self.law: DeployedLaw | CallableLaw = (
            DeployedLaw(self) if controller.deployed else CallableLaw(self)
        )

    @property
    def arm_diagnostics(self) -> dict[str, np.ndarray]:
        """``saturated_actions`` of a deployed policy (each arm's share of policy steps
        with an action at its bound)."""
        return self.law.diagnostics

    def reset_arms(self, obs: Mapping, info: Mapping, arms: np.ndarray) -> None:
        self.law.reset_arms(obs, info, arms)

    def __call__(self, obs: Mapping, info: Mapping) -> np.ndarray:
        return self.law(obs, info)
