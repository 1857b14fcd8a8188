"""One training run resolved once (`plan_run`): the run's config, its hyper-parameters
merged and checked, the algorithm's arguments and the spec of the policy it trains.

[`train`][elastic_gym.training.train.train] plans, checks what only the envs would check,
then learns from the plan alone; a loaded run folder is the plan of its ``config.yaml``.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from typing import Any

from elastic_gym.policy.spec import PolicySpec
from elastic_gym.training.config import (
    Settings,
    TrainConfig,
    algorithm_class,
    merged_hyperparams,
    settings_from,
)
from elastic_gym.training.distill import check_distill


@dataclass(frozen=True)
class TrainPlan:
    """A run's config with everything resolved from it (`plan_run`).

    ``settings``: our keys of the merged hyper-parameters; ``spec``: the policy the run
    trains ([`TrainConfig.policy_spec`][elastic_gym.training.config.TrainConfig.policy_spec]);
    ``algorithm``: the stable-baselines3 (or sb3-contrib) class it trains with;
    ``record``: the config its run folder keeps (`recorded_config`).
    """

    config: TrainConfig
    settings: Settings
    spec: PolicySpec
    algorithm: Any
    record: TrainConfig = field(repr=False)
    _algo_kwargs: dict[str, Any] = field(repr=False)

    def algorithm_arguments(self) -> dict[str, Any]:
        """The algorithm's keyword arguments, a fresh copy (the constructor may keep and
        change them)."""
        return copy.deepcopy(self._algo_kwargs)


def plan_run(config: TrainConfig) -> TrainPlan:
    """Resolve ``config`` (``ValueError`` naming the problem; nothing is built): its
    hyper-parameters ([`TrainConfig.settings`][elastic_gym.training.config.TrainConfig.settings]),
    its policy spec, and a ``distill`` entry the run cannot use
    ([`check_distill`][elastic_gym.training.distill.check_distill])."""
    hyperparams = merged_hyperparams(
        config.algo, config.env_id, config.hyperparams, config.hyperparams_file
    )
    settings, algo_kwargs = settings_from(config.algo, hyperparams)
    spec = config.policy_spec(settings)
    check_distill(config, settings, spec.action.kind)
    record = recorded_config(config, spec, hyperparams)
    return TrainPlan(config, settings, spec, algorithm_class(config.algo), record, algo_kwargs)


def recorded_config(config: TrainConfig, spec: PolicySpec, hyperparams: dict) -> TrainConfig:
    """The config a run folder keeps: self-contained, the merged ``hyperparams`` used
    (`merged_hyperparams`) instead of a pointer to their file, and every field of the
    action and observation configs of the run's ``spec`` (a later release's defaults must
    not change what a saved policy's actions mean)."""
    return config.model_copy(
        update={
            "hyperparams_file": None,
            "action": spec.action.to_dict(),
            "observation": spec.observation.to_dict(),
            "hyperparams": hyperparams,
        }
    )
