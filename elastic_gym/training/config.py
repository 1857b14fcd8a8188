"""Training configuration and RL-Zoo-style hyper-parameter files.

Hyper-parameters live in ``hyperparams/<algo>.yaml``, one entry per env id plus
``default``: the algorithm's constructor arguments and our keys (``n_timesteps``,
``n_envs``, ``batches``, ``decimation``, ``normalize``, ``critic_state``,
``critic_plant``, ``action``, ``observation``, ``env_kwargs``, ``distill``). Command-line overrides
(``key=value``) win over the file, which wins over the defaults; a run's own ``action`` /
``observation`` fields and env kwargs win key by key (a run naming its own ``task`` drops
the file's ``task_options``). ``learning_rate`` and ``clip_range`` may be
``lin_<value>``, a linear decay to 0.
"""

from __future__ import annotations

import contextlib
import copy
import functools
import inspect
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import (
    AfterValidator,
    ConfigDict,
    Field,
    GetPydanticSchema,
    RootModel,
    StrictBool,
    StrictFloat,
    StrictInt,
    StrictStr,
    TypeAdapter,
    WithJsonSchema,
    model_validator,
)

from elastic_gym.envs.config import MakeKwargsMapping
from elastic_gym.envs.ids import registered_env_id
from elastic_gym.model.identified import checked_model_file
from elastic_gym.observers.sensors import SENSORS
from elastic_gym.policy.actions import ActionConfig
from elastic_gym.policy.observation import ObservationConfig
from elastic_gym.policy.spec import (
    PolicySpec,
    check_model_robot,
    check_state_source,
)
from elastic_gym.training.distill import DistillConfig
from elastic_gym.validation import (
    ConfigModel,
    Finite,
    StrictModel,
    checked,
    known,
    lookup,
    numbers,
    only_when,
    plain,
    validated,
)
from elastic_gym.yaml_io import load_yaml

ALGORITHMS = ("ppo", "sac", "td3", "recurrentppo")
RECURRENT = {"recurrentppo"}  # sb3-contrib's RecurrentPPO: an LSTM in actor and critic
SCHEDULED = ("learning_rate", "clip_range")  # may be "lin_<value>" (RL Zoo)
ACTIVATIONS = {"tanh": "Tanh", "relu": "ReLU", "elu": "ELU", "leaky_relu": "LeakyReLU"}


def algorithm_class(algo: str):
    """The stable-baselines3 (or sb3-contrib, ``recurrentppo``) class of an algorithm name."""
    lookup(dict.fromkeys(ALGORITHMS), algo, "algorithm")
    if algo == "recurrentppo":
        from sb3_contrib import RecurrentPPO

        return RecurrentPPO
    import stable_baselines3

    return getattr(stable_baselines3, algo.upper())


def default_policy(algo: str) -> str:
    """SB3's policy name for flat observations: an MLP, with an LSTM for recurrent ones."""
    return "MlpLstmPolicy" if algo in RECURRENT else "MlpPolicy"


# an integer or an integral float (YAML's ``!!float 1e6`` is 1000000), not a bool or a string
_INTEGRAL = StrictInt | Annotated[StrictFloat, Field(multiple_of=1), AfterValidator(int)]
Integral = Annotated[int, GetPydanticSchema(lambda _, handler: handler.generate_schema(_INTEGRAL))]
Count = Annotated[Integral, Field(ge=1), WithJsonSchema({"type": "integer", "minimum": 1})]
PositiveInt = Annotated[StrictInt, Field(ge=1)]  # numpy integers count (StrictModel)


class Settings(StrictModel):
    """Our own keys of a hyper-parameter entry (module docstring), resolved once per run;
    the other keys are the algorithm's constructor arguments."""

    model_config = ConfigDict(frozen=True)
    n_timesteps: Count = 100_000
    n_envs: Count = 1
    batches: Count | Annotated[list[MakeKwargsMapping], Field(min_length=1)] = 1
    decimation: Count = 1
    normalize: StrictBool = True
    critic_state: StrictBool = False
    critic_plant: StrictBool = False
    action: dict[str, Any] = Field(default_factory=dict)
    observation: dict[str, Any] = Field(default_factory=dict)
    env_kwargs: MakeKwargsMapping = Field(default_factory=dict)
    distill: DistillConfig | None = None  # train by distillation instead of RL

    @property
    def batch_kwargs(self) -> list[dict]:
        """One env-kwargs update per batch: ``batches`` k gives k identical batches, a list
        of mappings (e.g. ``[{}, {plant_scaling: {link_mass: 1.3}}]``: half the arms on the
        nominal plant, half on links 30 % heavier) one batch each."""
        return [{}] * self.batches if isinstance(self.batches, int) else self.batches


class HyperparameterEntry(Settings):
    """One entry of a hyper-parameter file: our keys (typed) and the algorithm's
    constructor arguments (checked against its signature by
    [`resolve_settings`][elastic_gym.training.config.resolve_settings])."""

    model_config = ConfigDict(extra="allow")


class HyperparameterFile(RootModel[dict[str, HyperparameterEntry]]):
    """A hyper-parameter file: env ids (or ``default``) -> entry."""


def hyperparams_path(path: str | Path) -> Path:
    """The file ``path`` names: a path that exists, or else the bare name of a file shipped
    in ``elastic_gym/training/hyperparams`` (``ppo-robust.yaml``), so that the shipped
    recipes work from any directory and from an installed package. Anything else is
    returned as given (the reader then names it in its error)."""
    given = Path(path)
    if given.exists() or given.name != str(path):
        return given
    shipped = Path(str(resources.files("elastic_gym.training") / "hyperparams" / given.name))
    return shipped if shipped.is_file() else given


def load_hyperparams_file(path: str | Path) -> dict:
    """Parse a hyper-parameter YAML file
    ([`hyperparams_path`][elastic_gym.training.config.hyperparams_path]); errors name the file
    and the problem."""
    data = load_yaml(hyperparams_path(path))  # an empty file (None) is refused too
    checked(lambda: HyperparameterFile.model_validate(data), str(path), HyperparameterFile)
    return data


def shipped_hyperparams(algo: str) -> dict:
    algorithm_class(algo)  # validates the name
    path = resources.files("elastic_gym.training") / "hyperparams" / f"{algo}.yaml"
    return load_hyperparams_file(str(path))


def merged_hyperparams(
    algo: str, env_id: str, overrides: dict | None = None, file: str | Path | None = None
) -> dict:
    """Plain merged settings: file ``default`` < file[env_id] < overrides (YAML-serialisable)."""
    table = load_hyperparams_file(file) if file is not None else shipped_hyperparams(algo)
    return {**table.get("default", {}), **table.get(env_id, {}), **(overrides or {})}


EXCLUDED_ARGUMENTS = {"self", "env", "seed", "tensorboard_log", "verbose", "device"}


def resolve_settings(
    algo: str, env_id: str, overrides: dict | None = None, file: str | Path | None = None
) -> tuple[Settings, dict]:
    """(our settings, the algorithm's keyword arguments, ready for SB3) of one run, from
    `merged_hyperparams` (`settings_from`)."""
    return settings_from(algo, merged_hyperparams(algo, env_id, overrides, file))


def settings_from(algo: str, hyperparams: dict) -> tuple[Settings, dict]:
    """(our settings, the algorithm's keyword arguments, ready for SB3) from merged
    ``hyperparams`` (`merged_hyperparams`; left as they are), each key checked."""
    merged = copy.deepcopy(hyperparams)
    ours = {key: merged.pop(key) for key in Settings.model_fields if key in merged}
    settings = validated(Settings, ours)
    allowed = set(inspect.signature(algorithm_class(algo).__init__).parameters)
    allowed -= EXCLUDED_ARGUMENTS | {"_init_setup_model"}
    known(merged, allowed | set(Settings.model_fields), "hyper-parameter", of=algo)  # ours popped
    for key in SCHEDULED:
        if isinstance(merged.get(key), str):
            merged[key] = _schedule(key, merged[key])
    _check_values(algo, merged)
    _check_ranges(merged)
    if settings.critic_state or settings.critic_plant:
        _check_critic_state(
            algo, merged, "critic_state" if settings.critic_state else "critic_plant"
        )
    if "policy_kwargs" in merged:
        merged["policy_kwargs"] = _policy_kwargs(merged["policy_kwargs"])
    return settings, merged


def resolve_hyperparams(
    algo: str, env_id: str, overrides: dict | None = None, file: str | Path | None = None
) -> dict:
    """Merged settings for one run
    ([`resolve_settings`][elastic_gym.training.config.resolve_settings]) as one mapping: the keys
    given (ours validated) and the algorithm's arguments."""
    settings, algo_kwargs = resolve_settings(algo, env_id, overrides, file)
    return {**settings.model_dump(exclude_unset=True), **algo_kwargs}


ARGUMENT_KINDS = ((bool, StrictBool), (int, Integral), (float, Finite))  # by default's type


@dataclass(frozen=True)
class Interval:
    """The values an algorithm's argument means something for: ``low`` to ``high``
    (None: unbounded), each end included or not; ``also``: single values with a meaning
    of their own outside it (SB3's ``-1``)."""

    low: float | None
    high: float | None = None
    low_closed: bool = True
    high_closed: bool = True
    also: tuple[float, ...] = ()

    def __contains__(self, value: float) -> bool:
        if value in self.also:
            return True
        above = self.low is None or (value >= self.low if self.low_closed else value > self.low)
        below = self.high is None or (value <= self.high if self.high_closed else value < self.high)
        return above and below

    def __str__(self) -> str:
        low = "-inf" if self.low is None else f"{self.low:g}"
        high = "inf" if self.high is None else f"{self.high:g}"
        left = "[" if self.low_closed and self.low is not None else "("
        right = "]" if self.high_closed and self.high is not None else ")"
        extra = "".join(f" or {value:g}" for value in self.also)
        return f"in {left}{low}, {high}{right}{extra}"


POSITIVE = Interval(0.0, low_closed=False)
NON_NEGATIVE = Interval(0.0)
COUNT = Interval(1)
# SB3's arguments whose values outside these make no sense (Schulman et al. 2017 for PPO's,
# Haarnoja et al. 2018 for SAC's, Fujimoto et al. 2018 for TD3's): refused before any env
RANGES: dict[str, Interval] = {
    "learning_rate": POSITIVE,
    "gamma": Interval(0.0, 1.0, low_closed=False),  # a discount: 1 is undiscounted
    "gae_lambda": Interval(0.0, 1.0),
    "clip_range": POSITIVE,
    "clip_range_vf": POSITIVE,
    "ent_coef": NON_NEGATIVE,
    "vf_coef": NON_NEGATIVE,
    "max_grad_norm": POSITIVE,
    "target_kl": POSITIVE,
    "tau": Interval(0.0, 1.0, low_closed=False),  # the target networks' Polyak step
    "n_steps": COUNT,
    "batch_size": COUNT,
    "n_epochs": COUNT,
    "buffer_size": COUNT,
    "learning_starts": NON_NEGATIVE,
    "train_freq": COUNT,
    "gradient_steps": Interval(1, also=(-1,)),  # -1: as many as the env steps collected
    "target_update_interval": COUNT,
    "policy_delay": COUNT,
    "target_policy_noise": NON_NEGATIVE,
    "target_noise_clip": NON_NEGATIVE,
    "stats_window_size": COUNT,
}


def _check_ranges(merged: dict) -> None:
    """Refuse a number outside the range of its argument (`RANGES`): ``ValueError``
    naming the hyper-parameter, the range and the value. Schedules (``lin_<value>``,
    checked > 0 when parsed), strings (SAC's ``ent_coef: auto``), tuples and None are left
    to the algorithm."""
    for key, interval in RANGES.items():
        value = merged.get(key)
        if (
            isinstance(value, (int, float))
            and not isinstance(value, bool)
            and value not in interval
        ):
            raise ValueError(f"hyper-parameter {key}: must be {interval}, got {value!r}")


def _check_values(algo: str, merged: dict) -> None:
    """Bind the algorithm's arguments to its signature before any env is built: an
    argument whose default is a boolean needs a boolean, one whose default is a number a
    finite number (an integer where the default is one; integral floats such as
    ``!!float 1e6`` become integers) unless it is a schedule or a tuple (``train_freq``)."""
    params = inspect.signature(algorithm_class(algo).__init__).parameters
    for key, value in merged.items():
        default = getattr(params.get(key), "default", None)
        kind = next((kind for t, kind in ARGUMENT_KINDS if isinstance(default, t)), None)
        if kind is None or (
            kind is not StrictBool and (callable(value) or isinstance(value, (list, tuple)))
        ):
            continue
        check = functools.partial(TypeAdapter(kind).validate_python, plain(value))
        merged[key] = checked(check, f"hyper-parameter {key}")


def _check_critic_state(algo: str, merged: dict, key: str) -> None:
    """``critic_state`` / ``critic_plant`` need PPO with its MLP policy, whose features
    extractor they split
    ([`PrivilegedCriticPolicy`][elastic_gym.training.critic.PrivilegedCriticPolicy])."""
    privileged = {key: True}
    ppo = "algo is ppo (a critic with privileged inputs is implemented for ppo only)"
    only_when(algo == "ppo", privileged, f"{ppo}, not {algo}")
    policy = merged.get("policy", "MlpPolicy")
    only_when(policy == "MlpPolicy", privileged, f"policy is the MlpPolicy, got {policy!r}")
    kwargs = merged.get("policy_kwargs") or {}
    shared = isinstance(kwargs, dict) and bool(kwargs.get("share_features_extractor"))
    own = "the critic has its own features extractor: drop policy_kwargs.share_features_extractor"
    only_when(not shared, privileged, own)


def linear_schedule(initial: float, progress_remaining: float) -> float:
    """RL Zoo's ``lin_<value>``: the value decays linearly from ``initial`` to 0 over
    training (SB3 passes the remaining progress, 1 -> 0)."""
    return progress_remaining * initial


def _schedule(key: str, text: str):
    """``lin_<value>`` as [`linear_schedule`][elastic_gym.training.config.linear_schedule] of the
    value (a finite number > 0)."""
    prefix, _, value = text.partition("_")
    what = "must be a number or 'lin_<number > 0>' (linear decay)"
    given = value if prefix == "lin" else None  # None: refused
    initial = numbers(given, key, what, [()], minimum=0.0, strict=True, shown=text)
    return functools.partial(linear_schedule, float(initial))


def _policy_kwargs(value) -> dict:
    kwargs = dict(
        checked(lambda: TypeAdapter(dict[str, Any]).validate_python(value), "policy_kwargs")
    )
    if "activation_fn" in kwargs:
        import torch

        name = lookup(ACTIVATIONS, kwargs["activation_fn"], "policy_kwargs.activation_fn")
        kwargs["activation_fn"] = getattr(torch.nn, name)
    return kwargs


def parse_overrides(items: list[str]) -> dict:
    """``["learning_rate=1e-4", "n_envs=2"]`` -> dict, values parsed as YAML scalars."""
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise ValueError(f"hyper-parameter override must look like key=value, got {item!r}")
        parsed = load_yaml(value, f"override {item!r}")
        if isinstance(parsed, str):  # YAML 1.1 reads "1e-4" as a string
            with contextlib.suppress(ValueError):
                parsed = float(parsed)
        out[key] = parsed
    return out


def _state_source(state: str) -> str:
    check_state_source(state)
    return state


class TrainConfig(ConfigModel):
    """One training run.

    ``env_id``: a registered id; a bare name (``TwoLinkElastic-v0``) means
    ``elastic_gym/TwoLinkElastic-v0``. ``state``: ``"true"``, an observer name (the
    policy sees its estimate), or ``"sensors"`` (raw observation, ``frame_stack`` frames).
    ``action`` / ``observation``: fields of `ActionConfig` /
    `ObservationConfig` that override the hyper-parameter file's (e.g.
    ``{"kind": "residual", "residual": "feedforward-state-feedback"}`` for a residual
    policy). ``total_steps``: env interactions counted by SB3 (policy steps); None takes
    ``n_timesteps`` from the hyper-parameter file. ``model_file``: an identified model
    file (`elastic-gym identify`) the policy's observer, gravity compensation and residual
    base build on instead of the env's nominal model (the trained plant stays the env's).
    """

    env_id: Annotated[StrictStr, AfterValidator(registered_env_id)] = (
        "elastic_gym/TwoLinkElastic-v0"
    )
    algo: Literal[ALGORITHMS] = "ppo"  # type: ignore[valid-type]
    state: Annotated[StrictStr, AfterValidator(_state_source)] = "deluca"
    total_steps: PositiveInt | None = None
    seed: Annotated[StrictInt, Field(ge=0)] = 0
    out_dir: StrictStr = "runs/ppo-twolink"
    action: dict[str, Any] = Field(default_factory=dict)
    observation: dict[str, Any] = Field(default_factory=dict)
    frame_stack: PositiveInt = 4
    env_kwargs: MakeKwargsMapping = Field(default_factory=dict)
    observer_options: dict[str, Any] = Field(default_factory=dict)
    model_file: Annotated[StrictStr, AfterValidator(checked_model_file)] | None = None
    hyperparams: dict[str, Any] = Field(default_factory=dict)
    hyperparams_file: StrictStr | None = None
    eval_freq: PositiveInt | None = None  # None: a twentieth of the run's policy steps
    eval_episodes: PositiveInt = 3

    @model_validator(mode="after")
    def _policy_fields(self) -> TrainConfig:
        self.policy_configs(Settings())
        if self.model_file is not None:
            check_model_robot(self.model_file, self.env_id, self.env_kwargs)
        return self

    @classmethod
    def from_dict(cls, data: dict) -> TrainConfig:
        """A run's config from a mapping of its fields (``ValueError`` naming the field;
        anything else, ``None`` of an empty file too, is refused by the model)."""
        return checked(functools.partial(cls.model_validate, plain(data)), model=cls)

    def settings(self) -> tuple[Settings, dict]:
        """(our settings, the algorithm's arguments) of this run
        ([`resolve_settings`][elastic_gym.training.config.resolve_settings])."""
        return resolve_settings(self.algo, self.env_id, self.hyperparams, self.hyperparams_file)

    def policy_configs(self, settings: Settings) -> tuple[ActionConfig, ObservationConfig]:
        """The action and observation configs: the hyper-parameter ``settings``'
        overridden field by field by the run's own."""
        action = {**settings.action, **self.action}
        observation = ObservationConfig.from_config({**settings.observation, **self.observation})
        frames = {"observation.frames": observation.frames > 1}
        only_when(self.state != SENSORS, frames, "the state is an observer or the truth")
        return ActionConfig.from_config(action), observation

    def policy_spec(self, settings: Settings) -> PolicySpec:
        """The spec of the policy this run trains: its config with its resolved
        hyper-parameters ``settings`` (`settings`): env and kwargs
        (`training_env_kwargs`), state source, action and observation configs
        (`policy_configs`), decimation, the frames of raw sensors, the critic's
        privileged inputs."""
        action, observation = self.policy_configs(settings)
        return PolicySpec(
            env_id=self.env_id,
            env_kwargs=self.training_env_kwargs(settings),
            state=self.state,
            observer_options=dict(self.observer_options),
            action=action,
            observation=observation,
            decimation=settings.decimation,
            frame_stack=self.frame_stack if self.state == SENSORS else None,
            critic_state=settings.critic_state,
            critic_plant=settings.critic_plant,
            model_file=self.model_file,
        )

    def training_env_kwargs(self, settings: Settings) -> dict:
        """The env kwargs of the run: the hyper-parameter file's ``env_kwargs`` (in
        ``settings``) updated key by key with the run's own; the file's ``task_options``
        are dropped when the run names its own ``task``."""
        shipped = dict(settings.env_kwargs)
        if "task" in self.env_kwargs:
            shipped.pop("task_options", None)
        return {**shipped, **self.env_kwargs}
