"""A finished run folder loaded back (`load_run`), and its deterministic policy on
fresh episodes (`evaluate_run`), run on the comparison's batched closed loop.

`evaluate_run` is the comparison itself: the ``trained-policy`` controller of the run
on its state source, one run per episode seed, all of them the arms of one world of
[`run_group`][elastic_gym.evaluation.episodes.run_group]. An episode's tracking RMS is therefore
the ``track_rms`` of the comparison row of the same run, seed and plant (every control
period, from the reset on); its return the sum of the env's rewards over the episode.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from elastic_gym.envs.config import EPISODE_TIME
from elastic_gym.evaluation.episodes import RunResult, run_group
from elastic_gym.evaluation.grid import RunSpec
from elastic_gym.evaluation.groups import RunGroup
from elastic_gym.evaluation.scenario import ControllerEntry, SourceEntry
from elastic_gym.observers.registry import source_class
from elastic_gym.policy.actors import PolicyActor, SB3Actor
from elastic_gym.policy.controller import PolicyController
from elastic_gym.policy.loading import Policy, untrusted
from elastic_gym.policy.spec import PolicySpec
from elastic_gym.runtime.parallel import single_threaded
from elastic_gym.training.config import Settings, TrainConfig
from elastic_gym.training.plan import TrainPlan, plan_run
from elastic_gym.training.rollouts import Evaluation
from elastic_gym.training.run_folder import RunFolder
from elastic_gym.validation import checked_count

TRAINED_POLICY = "trained-policy"  # the controller name of a run's policy


@dataclass
class TrainedRun:
    """A run folder loaded back (or the run being trained): the SB3 model, its
    normalization statistics and the run's [`TrainPlan`][elastic_gym.training.plan.TrainPlan]
    (its ``config``, ``settings`` and ``spec``, the policy it trains); `policy` is the
    deployed policy the comparison runs."""

    model: Any  # an SB3 algorithm (duck-typed: no SB3 import here)
    normalizer: Any  # its VecNormalize, or None
    plan: TrainPlan

    def __post_init__(self) -> None:
        self._actor = PolicyActor(self.model, self.normalizer)

    @property
    def config(self) -> TrainConfig:
        return self.plan.config

    @property
    def settings(self) -> Settings:
        return self.plan.settings

    @property
    def spec(self) -> PolicySpec:
        return self.plan.spec

    @property
    def decimation(self) -> int:
        return self.spec.decimation

    @property
    def policy(self) -> Policy:
        """The run's deployed policy: its spec and the SB3 model's deterministic act."""
        return Policy(
            spec=self.spec,
            actor=SB3Actor(self.model, self.normalizer),
            source=str(self.config.out_dir),
            spec_file="config.yaml",
            actor_file="model.zip",
        )

    def start(self) -> None:
        """A new episode: a recurrent policy forgets its memory."""
        self._actor.start()

    def act(self, flat_obs: np.ndarray) -> np.ndarray:
        """Deterministic action in [-1, 1]^n for one flattened observation, or (N, n) for
        a batch of N."""
        return self._actor(flat_obs)


def load_run(run_dir: str | Path, best: bool = False, trust_pickle: bool = False) -> TrainedRun:
    """Load a run folder written by [`train`][elastic_gym.training.train.train]
    (``best=True``: the best model of the learning curve).

    Unpickles ``model.zip`` and ``vecnormalize.pkl``, which runs code stored in the files:
    only with ``trust_pickle=True``, for run folders you made or trust (else
    [`UntrustedPickleError`][elastic_gym.policy.loading.UntrustedPickleError] before any
    pickle is opened; `elastic-gym export` makes a policy without pickles). A missing or
    corrupted file raises ``ValueError`` naming it.
    """
    folder = RunFolder(run_dir)
    config = folder.read_config()
    if not trust_pickle:
        raise untrusted(run_dir)
    plan = plan_run(config)
    model = folder.load_model(config.algo, best)
    normalizer = folder.load_normalizer()
    _check_normalizer(model, normalizer, folder.path)
    return TrainedRun(model, normalizer, plan)


def _check_normalizer(model: Any, normalizer: Any, path: Path) -> None:
    """Refuse ``vecnormalize.pkl`` statistics of another size than the model's input."""
    # vars(): an unpickled VecNormalize without observation statistics (normalize: false)
    # recurses in SB3's __getattr__ instead of raising AttributeError
    obs_rms = None if normalizer is None else vars(normalizer).get("obs_rms")
    statistics = getattr(obs_rms, "mean", None)
    if statistics is not None and np.shape(statistics) != model.observation_space.shape:
        raise ValueError(
            f"{path}: vecnormalize.pkl takes observations of shape {np.shape(statistics)}, "
            f"but model.zip of shape {model.observation_space.shape}: the files are of "
            "different runs"
        )


def run_policy(run_dir: str | Path, best: bool = False) -> Policy:
    """The deployed policy of a run folder the user trusts (its pickles are loaded): what
    [`load_policy`][elastic_gym.policy.loading.load_policy] calls with
    ``trust_pickle``."""
    run = load_run(run_dir, best, trust_pickle=True)
    return Policy(
        spec=run.spec,
        actor=SB3Actor(run.model, run.normalizer),
        source=str(run_dir),
        spec_file="config.yaml",
        actor_file="model.zip",
    )


def run_spec(run_dir: str | Path) -> PolicySpec:
    """The policy spec of a run folder from its ``config.yaml`` alone (no pickle)."""
    return plan_run(RunFolder(run_dir).read_config()).spec


def episode_duration(env_id: str, env_kwargs: dict) -> float:
    """The simulated time of an episode of ``env_id`` with ``env_kwargs`` (``ValueError``
    for episodes that never end)."""
    default = gym.spec(env_id).kwargs.get("episode_time", EPISODE_TIME)
    duration = env_kwargs.get("episode_time", default)
    if duration is None:
        raise ValueError(
            "env_kwargs.episode_time: None (episodes that never end) leaves the evaluation "
            "episodes unbounded; give a finite episode_time"
        )
    return float(duration)


def evaluation_runs(
    run: TrainedRun | Policy, n_episodes: int, seed: int, env_kwargs: dict | None = None
) -> RunGroup:
    """The comparison's runs of `evaluate_run`: the ``trained-policy`` controller of
    ``run`` (a loaded run, or a deployed policy such as an exported one) on its state
    source, one run per seed ``seed``, ``seed + 1``, ..., in the policy's env with
    ``env_kwargs`` merged into its own, the policy and its observer on the spec's
    identified model, if any."""
    checked_count(n_episodes, "n_episodes", 1)
    policy = run if isinstance(run, Policy) else run.policy
    spec = policy.spec
    kwargs = {**spec.env_kwargs, **(env_kwargs or {})}
    duration = episode_duration(spec.env_id, kwargs)
    controller = ControllerEntry.model_validate(
        {"name": TRAINED_POLICY, "options": {"policy": policy}}
    )
    source = SourceEntry.model_validate(
        {"name": spec.state, "options": dict(spec.observer_options)}
    )
    return RunGroup(
        tuple(
            RunSpec(
                index=i,
                labels={"seed": int(seed) + i},
                env_id=spec.env_id,
                env_kwargs=kwargs,
                reset_options={},
                duration=duration,
                seed=int(seed) + i,
                controller=controller,
                controller_cls=PolicyController,
                source=source,
                observer_cls=source_class(spec.state),
                model_error={},
                model_file=_resolved(spec.model_file),
            )
            for i in range(n_episodes)
        )
    )


def _resolved(path: str | None) -> str | None:
    return None if path is None else str(Path(path).resolve())


def evaluation_of(results: list[RunResult]) -> Evaluation:
    """The `Evaluation` of the comparison results of
    [`evaluation_runs`][elastic_gym.training.trained.evaluation_runs]
    (``RuntimeError`` naming the episode for a run that failed)."""
    for result in results:
        if "track_rms" not in result.metrics:
            raise RuntimeError(f"evaluation episode seed {result.spec.seed}: {result.status}")
    return Evaluation(
        tuple(r.spec.seed for r in results),
        tuple(r.episode_return for r in results),
        tuple(r.metrics["track_rms"] for r in results),
        tuple(r.controller_diagnostics["saturated_actions"] for r in results),
    )


def evaluate_run(
    run: TrainedRun | Policy,
    n_episodes: int = 3,
    seed: int = 123,
    env_kwargs: dict | None = None,
) -> Evaluation:
    """The deterministic policy of a run (or a deployed policy, e.g.
    ``load_policy("policies/ppo")`` of an exported one) on ``n_episodes`` fresh episodes (seeds
    ``seed``, ``seed + 1``, ...), run as the arms of one world of the comparison's loop
    (module docstring); ``env_kwargs`` are merged into the run's (e.g.
    ``{"plant_scaling": {"link_mass": 1.3}}``).

    Runs single-threaded (torch and BLAS), as training does, so that the numbers do not
    depend on the caller's thread settings.
    """
    group = evaluation_runs(run, n_episodes, seed, env_kwargs)
    with single_threaded():
        return evaluation_of(run_group(group))
