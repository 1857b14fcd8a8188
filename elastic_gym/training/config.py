"""Training configuration and RL-Zoo-style hyper-parameter files.

Hyper-parameters live in ``hyperparams/<algo>.yaml``, one entry per env id plus a
``default`` entry, each a mapping of the algorithm's constructor arguments and these
keys of ours: ``n_timesteps`` (default budget, policy steps), ``n_envs`` (arms; more
than one share a PyBullet world), ``batches`` (worker processes the arms are split
over, one PyBullet world each: a number, or a list of env-kwargs updates, one per
batch, e.g. ``[{}, {plant_scaling: {link_mass: 1.3}}]`` for two plants),
``decimation`` (env steps per policy step), ``normalize`` (VecNormalize on/off),
``critic_state`` (PPO only: a critic that also sees the true state, the actor never
does; :mod:`elastic_gym.training.critic`),
``action`` (fields of :class:`~elastic_gym.training.actions.ActionConfig`),
``observation`` (fields of
:class:`~elastic_gym.training.observation.ObservationConfig`) and ``env_kwargs`` (the
training env's kwargs, e.g. the task's options). Command-line overrides (``key=value``)
win over the file, which wins over the defaults; a run's own ``action`` /
``observation`` fields win over the file's, and its own env kwargs over the file's key
by key (a run that names its own ``task`` drops the file's ``task_options``, which
belong to the file's task). ``learning_rate`` and ``clip_range`` may be
``lin_<value>`` (RL Zoo's linear decay to 0).
"""

from __future__ import annotations

import contextlib
import functools
import inspect
import math
from dataclasses import asdict, dataclass, field, fields
from importlib import resources
from pathlib import Path

import numpy as np
import yaml

from elastic_gym.training.actions import ActionConfig
from elastic_gym.training.observation import ObservationConfig
from elastic_gym.training.policy_env import check_state_source
from elastic_gym.validation import is_real, registered_env_id
from elastic_gym.yaml_io import load_yaml

ALGORITHMS = ("ppo", "sac", "td3", "recurrentppo")
RECURRENT = {"recurrentppo"}  # sb3-contrib's RecurrentPPO: an LSTM in actor and critic
OWN_KEYS = {
    "n_timesteps",
    "n_envs",
    "batches",
    "decimation",
    "normalize",
    "critic_state",
    "action",
    "observation",
    "env_kwargs",
}
OWN_BOOLEANS = ("normalize", "critic_state")
SCHEDULED = ("learning_rate", "clip_range")  # may be "lin_<value>" (RL Zoo)
ACTIVATIONS = {"tanh": "Tanh", "relu": "ReLU", "elu": "ELU", "leaky_relu": "LeakyReLU"}


def algorithm_class(algo: str):
    """The stable-baselines3 (or sb3-contrib, ``recurrentppo``) class of an algorithm name."""
    if algo not in ALGORITHMS:
        raise ValueError(f"unknown algorithm {algo!r}; valid: {list(ALGORITHMS)}")
    if algo == "recurrentppo":
        from sb3_contrib import RecurrentPPO

        return RecurrentPPO
    import stable_baselines3

    return getattr(stable_baselines3, algo.upper())


def default_policy(algo: str) -> str:
    """SB3's policy name for flat observations: an MLP, with an LSTM for recurrent ones."""
    return "MlpLstmPolicy" if algo in RECURRENT else "MlpPolicy"


def load_hyperparams_file(path: str | Path) -> dict:
    """Parse a hyper-parameter YAML file; errors name the file and the problem."""
    data = load_yaml(Path(path))
    if not isinstance(data, dict):
        raise ValueError(f"{path}: top level must map env ids (or 'default') to settings")
    for key, entry in data.items():
        if not isinstance(entry, dict):
            raise ValueError(f"{path}: entry {key!r} must be a mapping, got {type(entry).__name__}")
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


def resolve_hyperparams(
    algo: str, env_id: str, overrides: dict | None = None, file: str | Path | None = None
) -> dict:
    """Merged settings for one run (:func:`merged_hyperparams`), validated, ready for SB3."""
    merged = merged_hyperparams(algo, env_id, overrides, file)
    allowed = set(inspect.signature(algorithm_class(algo).__init__).parameters) - {
        "self",
        "env",
        "policy_kwargs",
        "seed",
        "tensorboard_log",
        "verbose",
        "device",
        "_init_setup_model",
    }
    allowed |= OWN_KEYS | {"policy_kwargs"}
    unknown = set(merged) - allowed
    if unknown:
        raise ValueError(
            f"unknown hyper-parameter(s) {sorted(unknown)} for {algo}; valid: {sorted(allowed)}"
        )
    for key in SCHEDULED:
        if isinstance(merged.get(key), str):
            merged[key] = _schedule(key, merged[key])
    _check_values(algo, merged)
    if merged.get("critic_state"):
        _check_critic_state(algo, merged)
    if "policy_kwargs" in merged:
        merged["policy_kwargs"] = _policy_kwargs(merged["policy_kwargs"])
    for key in ("env_kwargs", "action", "observation"):
        if not isinstance(merged.get(key, {}), dict):
            raise ValueError(f"hyper-parameter {key} must be a mapping, got {merged[key]!r}")
    batch_kwargs(merged.get("batches", 1))
    return merged


POSITIVE_INTEGERS = ("n_timesteps", "n_envs", "decimation")  # our own count settings


def _check_values(algo: str, merged: dict) -> None:
    """Refuse a value of the wrong kind before any env is built: our own counts must be
    positive integers and ``normalize`` a boolean; an algorithm argument whose default is
    a number must be a finite number (an integer where the default is one) unless it is
    a schedule or a tuple (``train_freq``), and a boolean default needs a boolean.
    Integral floats (``!!float 1e6``) become integers where one is needed."""
    params = inspect.signature(algorithm_class(algo).__init__).parameters
    for key, value in merged.items():
        default = getattr(params.get(key), "default", None)
        if key in OWN_BOOLEANS or isinstance(default, bool):
            if not isinstance(value, bool):
                raise ValueError(f"hyper-parameter {key} must be true or false, got {value!r}")
        elif key in POSITIVE_INTEGERS or (
            key in params
            and _is_number(default)
            and not (callable(value) or isinstance(value, (list, tuple)))
        ):
            if not _is_number(value) or not math.isfinite(value):
                raise ValueError(f"hyper-parameter {key} must be a finite number, got {value!r}")
            if key in POSITIVE_INTEGERS or isinstance(default, int):
                if value != int(value) or (key in POSITIVE_INTEGERS and value < 1):
                    kind = "a positive integer" if key in POSITIVE_INTEGERS else "an integer"
                    raise ValueError(f"hyper-parameter {key} must be {kind}, got {value!r}")
                merged[key] = int(value)


def _check_critic_state(algo: str, merged: dict) -> None:
    """``critic_state: true`` needs PPO with its MLP policy, whose features extractor it
    splits (:class:`~elastic_gym.training.critic.PrivilegedCriticPolicy`)."""
    if algo != "ppo":
        raise ValueError(
            f"critic_state (a critic that sees the true state) is implemented "
            f"for ppo only, not {algo}"
        )
    if merged.get("policy", "MlpPolicy") != "MlpPolicy":
        raise ValueError(f"critic_state needs the MlpPolicy, got policy {merged['policy']!r}")
    kwargs = merged.get("policy_kwargs") or {}
    if isinstance(kwargs, dict) and kwargs.get("share_features_extractor"):
        raise ValueError(
            "critic_state gives the critic its own features extractor: drop "
            "policy_kwargs.share_features_extractor"
        )


def _is_number(value) -> bool:
    return is_real(value) and not isinstance(value, bool)


def batch_kwargs(batches) -> list[dict]:
    """The ``batches`` hyper-parameter as one env-kwargs update per batch: an integer k
    (k identical batches) or a list of mappings (e.g. ``[{}, {plant_scaling: {link_mass:
    1.3}}]``: half the arms on the nominal plant, half on links 30 % heavier)."""
    if isinstance(batches, int) and not isinstance(batches, bool) and batches >= 1:
        return [{}] * batches
    if isinstance(batches, list) and batches and all(isinstance(entry, dict) for entry in batches):
        return batches
    raise ValueError(
        f"batches must be an integer >= 1 or a non-empty list of env-kwargs "
        f"mappings, got {batches!r}"
    )


def linear_schedule(initial: float, progress_remaining: float) -> float:
    """RL Zoo's ``lin_<value>``: the value decays linearly from ``initial`` to 0 over
    training (SB3 passes the remaining progress, 1 -> 0)."""
    return progress_remaining * initial


def _schedule(key: str, text: str):
    prefix, _, value = text.partition("_")
    try:
        initial = float(value)
    except ValueError:
        initial = math.nan
    if prefix != "lin" or not math.isfinite(initial) or initial <= 0:
        raise ValueError(f"{key} {text!r}: give a number or 'lin_<number > 0>' (linear decay)")
    return functools.partial(linear_schedule, initial)


def _policy_kwargs(value) -> dict:
    if not isinstance(value, dict):
        raise ValueError(f"policy_kwargs must be a mapping, got {value!r}")
    kwargs = dict(value)
    if "activation_fn" in kwargs:
        name = kwargs["activation_fn"]
        if name not in ACTIVATIONS:
            raise ValueError(f"policy_kwargs.activation_fn {name!r}; valid: {sorted(ACTIVATIONS)}")
        import torch

        kwargs["activation_fn"] = getattr(torch.nn, ACTIVATIONS[name])
    return kwargs


def parse_overrides(items: list[str]) -> dict:
    """``["learning_rate=1e-4", "n_envs=2"]`` -> dict, values parsed as YAML scalars."""
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise ValueError(f"hyper-parameter override must look like key=value, got {item!r}")
        try:
            parsed = yaml.safe_load(value)
        except yaml.YAMLError:
            raise ValueError(f"cannot parse the value of override {item!r}") from None
        if isinstance(parsed, str):  # YAML 1.1 reads "1e-4" as a string
            with contextlib.suppress(ValueError):
                parsed = float(parsed)
        out[key] = parsed
    return out


@dataclass
class TrainConfig:
    """One training run.

    ``env_id``: a registered id; a bare name (``TwoLinkElastic-v0``) means
    ``elastic_gym/TwoLinkElastic-v0``. ``state``: ``"true"``, an observer name (the
    policy sees its estimate), or ``"sensors"`` (raw observation, ``frame_stack`` frames).
    ``action`` / ``observation``: fields of :class:`ActionConfig` /
    :class:`ObservationConfig` that override the hyper-parameter file's (e.g.
    ``{"kind": "residual", "residual": "feedforward-state-feedback"}`` for a residual
    policy). ``total_steps``: env interactions counted by SB3 (policy steps); None takes
    ``n_timesteps`` from the hyper-parameter file.
    """

    env_id: str = "elastic_gym/TwoLinkElastic-v0"
    algo: str = "ppo"
    state: str = "deluca"
    total_steps: int | None = None
    seed: int = 0
    out_dir: str = "runs/ppo-twolink"
    action: dict = field(default_factory=dict)
    observation: dict = field(default_factory=dict)
    frame_stack: int = 4
    env_kwargs: dict = field(default_factory=dict)
    observer_options: dict = field(default_factory=dict)
    hyperparams: dict = field(default_factory=dict)
    hyperparams_file: str | None = None
    eval_freq: int = 20000
    eval_episodes: int = 3

    def __post_init__(self) -> None:
        self.env_id = registered_env_id(self.env_id)
        algorithm_class(self.algo)
        check_state_source(self.state)
        for key in ("seed", "eval_freq", "eval_episodes", "frame_stack"):
            value, least = getattr(self, key), 0 if key == "seed" else 1
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < least:
                raise ValueError(f"{key} must be an integer >= {least}, got {value!r}")
        for key in ("action", "observation"):
            if not isinstance(getattr(self, key), dict):
                raise ValueError(
                    f"{key} must be a mapping of its fields, got {getattr(self, key)!r}"
                )
        self.policy_configs({})
        if self.total_steps is not None and (
            isinstance(self.total_steps, bool)
            or not isinstance(self.total_steps, (int, np.integer))
            or self.total_steps < 1
        ):
            raise ValueError(f"total_steps must be a positive integer, got {self.total_steps!r}")

    @classmethod
    def from_dict(cls, data: dict) -> TrainConfig:
        allowed = {f.name for f in fields(cls)}
        unknown = set(data) - allowed
        if unknown:
            raise ValueError(
                f"unknown training config field(s) {sorted(unknown)}; valid: {sorted(allowed)}"
            )
        return cls(**data)

    def policy_configs(self, settings: dict) -> tuple[ActionConfig, ObservationConfig]:
        """The action and observation configs: ``settings`` (resolved hyper-parameters)
        overridden field by field by the run's own."""
        action = {**settings.get("action", {}), **self.action}
        observation = {**settings.get("observation", {}), **self.observation}
        return ActionConfig.from_config(action), ObservationConfig.from_config(observation)

    def training_env_kwargs(self, settings: dict) -> dict:
        """The env kwargs of the run: the hyper-parameter file's ``env_kwargs`` (in
        ``settings``) updated key by key with the run's own; the file's ``task_options``
        are dropped when the run names its own ``task``."""
        shipped = dict(settings.get("env_kwargs") or {})
        if "task" in self.env_kwargs:
            shipped.pop("task_options", None)
        return {**shipped, **self.env_kwargs}

    def to_dict(self) -> dict:
        return asdict(self)
