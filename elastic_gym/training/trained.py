"""A finished run folder loaded back (:func:`load_run`), and its deterministic policy on
fresh episodes (:func:`evaluate_run`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from gymnasium.vector import AutoresetMode

from elastic_gym.training.config import Settings, TrainConfig
from elastic_gym.training.rollouts import Evaluation, PolicyActor, evaluate_arms
from elastic_gym.training.run_envs import PolicyStack
from elastic_gym.training.run_folder import RunFolder


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


def evaluate_run(
    run: TrainedRun, n_episodes: int = 3, seed: int = 123, env_kwargs: dict | None = None
) -> Evaluation:
    """The deterministic policy of a run on ``n_episodes`` fresh episodes (seeds
    ``seed``, ``seed + 1``, ...), run as the arms of one batch; ``env_kwargs`` are merged
    into the run's (e.g. ``{"plant_scaling": {"link_mass": 1.3}}``)."""
    envs = run.stack.make_vec(n_episodes, env_kwargs, autoreset_mode=AutoresetMode.NEXT_STEP)
    try:
        return evaluate_arms(envs, run.act, seed, run.start)
    finally:
        envs.close()
