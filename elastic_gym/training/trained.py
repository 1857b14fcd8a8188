"""A finished run folder loaded back (:func:`load_run`), and its deterministic policy on
fresh episodes (:func:`evaluate_run`), run on the comparison's batched closed loop.

:func:`evaluate_run` is the comparison itself: the ``trained-policy`` controller of the run
on its state source, one run per episode seed, all of them the arms of one world of
:func:`~elastic_gym.evaluation.episodes.run_group`. An episode's tracking RMS is therefore
the ``track_rms`` of the comparison row of the same run, seed and plant (every control
period, from the reset on); its return the sum of the env's rewards over the episode.
"""

from __future__ import annotations

from dataclasses import dataclass, field
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
from elastic_gym.runtime.parallel import single_threaded
from elastic_gym.training.config import Settings, TrainConfig
from elastic_gym.training.rollouts import Evaluation, PolicyActor
from elastic_gym.training.run_envs import PolicyStack
from elastic_gym.training.run_folder import RunFolder
from elastic_gym.validation import checked_count


@dataclass
class TrainedRun:
    """A run folder loaded back: the SB3 model, its normalization statistics and config;
    ``stack`` is the policy env it was trained on (:class:`PolicyStack`)."""

    model: Any  # an SB3 algorithm (duck-typed: no SB3 import here)
    normalizer: Any  # its VecNormalize, or None
    config: TrainConfig
    settings: Settings
    stack: PolicyStack = field(init=False)

    def __post_init__(self) -> None:
        self.stack = PolicyStack.of(self.config, self.settings)
        self._actor = PolicyActor(self.model, self.normalizer)

    @property
    def decimation(self) -> int:
        return self.stack.decimation

    def start(self) -> None:
        """A new episode: a recurrent policy forgets its memory."""
        self._actor.start()

    def act(self, flat_obs: np.ndarray) -> np.ndarray:
        """Deterministic action in [-1, 1]^n for one flattened observation, or (N, n) for
        a batch of N."""
        return self._actor(flat_obs)


def load_run(run_dir: str | Path, best: bool = False) -> TrainedRun:
    """Load a run folder written by :func:`~elastic_gym.training.train.train` (``best=True``:
    the best model of the learning curve).

    Unpickles ``model.zip`` and ``vecnormalize.pkl``: load only trusted run folders. A
    missing or corrupted file raises ``ValueError`` naming it.
    """
    folder = RunFolder(run_dir)
    config = folder.read_config()
    settings, _ = config.settings()
    model = folder.load_model(config.algo, best)
    return TrainedRun(model, folder.load_normalizer(), config, settings)


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
    run: TrainedRun, n_episodes: int, seed: int, env_kwargs: dict | None = None
) -> RunGroup:
    """The comparison's runs of :func:`evaluate_run`: the ``trained-policy`` controller of
    ``run`` (the loaded object, not its folder) on its state source, one run per seed
    ``seed``, ``seed + 1``, ..., in the run's env with ``env_kwargs`` merged into its own."""
    checked_count(n_episodes, "n_episodes", 1)
    from elastic_gym.training.policy_controller import TrainedPolicyController

    stack = run.stack
    kwargs = {**stack.env_kwargs, **(env_kwargs or {})}
    duration = episode_duration(stack.env_id, kwargs)
    controller = ControllerEntry.model_validate(
        {"name": TrainedPolicyController.name, "options": {"run": run}}
    )
    source = SourceEntry.model_validate(
        {"name": stack.state, "options": dict(stack.observer_options)}
    )
    return RunGroup(
        tuple(
            RunSpec(
                index=i,
                labels={"seed": int(seed) + i},
                env_id=stack.env_id,
                env_kwargs=kwargs,
                reset_options={},
                duration=duration,
                seed=int(seed) + i,
                controller=controller,
                controller_cls=TrainedPolicyController,
                source=source,
                observer_cls=source_class(stack.state),
                model_error={},
            )
            for i in range(n_episodes)
        )
    )


def evaluation_of(results: list[RunResult]) -> Evaluation:
    """The :class:`Evaluation` of the comparison results of :func:`evaluation_runs`
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
    run: TrainedRun, n_episodes: int = 3, seed: int = 123, env_kwargs: dict | None = None
) -> Evaluation:
    """The deterministic policy of a run on ``n_episodes`` fresh episodes (seeds
    ``seed``, ``seed + 1``, ...), run as the arms of one world of the comparison's loop
    (module docstring); ``env_kwargs`` are merged into the run's (e.g.
    ``{"plant_scaling": {"link_mass": 1.3}}``).

    Runs single-threaded (torch and BLAS), as training does, so that the numbers do not
    depend on the caller's thread settings.
    """
    group = evaluation_runs(run, n_episodes, seed, env_kwargs)
    with single_threaded():
        return evaluation_of(run_group(group))
