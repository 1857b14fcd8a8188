"""Learning curves of a training run: return and tracking RMS versus policy steps and
wall time, written to the run folder.

`LearningCurve` (an SB3 callback) evaluates the deterministic policy at the start,
every ``every`` policy steps and at the end, on the same episodes each time, with the
normalization of that moment: [`evaluate_run`][elastic_gym.training.trained.evaluate_run] of the
model being trained, the arms of one world of the comparison's loop (seeds ``seed``,
``seed + 1``, ...). Each
evaluation is a row of ``learning_curve.csv``: ``policy_steps``, ``env_steps``,
``wall_time`` (evaluations excluded), ``eval_return`` and ``eval_return_std``,
``tracking_rms`` and ``tracking_rms_max`` (rad), ``saturated`` (share of actions at their
bound), ``train_return`` (last 100 training episodes). It keeps the best model
(``best_model.zip``) and writes ``evaluations.npz`` as SB3's ``EvalCallback`` does.
"""

from __future__ import annotations

import csv
import time
from pathlib import Path

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

from elastic_gym.training.plan import TrainPlan
from elastic_gym.training.rollouts import Evaluation
from elastic_gym.training.run_folder import CURVE_FILE
from elastic_gym.training.trained import TrainedRun, evaluate_run

COLUMNS = (
    "policy_steps",
    "env_steps",
    "wall_time",
    "eval_return",
    "eval_return_std",
    "tracking_rms",
    "tracking_rms_max",
    "saturated",
    "train_return",
)


class LearningCurve(BaseCallback):
    """Evaluations during training -> ``learning_curve.csv``, ``evaluations.npz`` and
    ``best_model.zip`` in ``out_dir`` (module docstring);
    [`train`][elastic_gym.training.train.train]
    refuses a run whose evaluation episodes never end (``episode_time=None``) before it.

    Args:
        plan: the run ([`TrainPlan`][elastic_gym.training.plan.TrainPlan]).
        normalizer: the training ``VecNormalize`` (its current statistics), or None.
        out_dir: the run folder.
        every: policy steps between evaluations (>= 1: ``eval_freq`` is a positive
            integer, its default a twentieth of the run, at least 1).
        seed: seed of the first evaluation episode.
    """

    def __init__(
        self,
        plan: TrainPlan,
        normalizer,
        out_dir: str | Path,
        every: int,
        seed: int,
    ) -> None:
        super().__init__()
        self.plan, self.normalizer = plan, normalizer
        self.episodes = plan.config.eval_episodes
        self.out = Path(out_dir)
        self.every, self.seed, self.decimation = every, seed, plan.spec.decimation
        self.evaluations: list[Evaluation] = []
        self.timesteps: list[int] = []
        self._next = 0
        self._evaluating = 0.0
        self._start = 0.0
        self._best = -np.inf

    def _on_training_start(self) -> None:
        self._start = time.perf_counter()
        with open(self.out / CURVE_FILE, "w", newline="") as handle:
            csv.writer(handle).writerow(COLUMNS)
        self._evaluate()

    def _on_step(self) -> bool:
        if self.num_timesteps >= self._next:
            self._evaluate()
        return True

    def _on_training_end(self) -> None:
        if not self.timesteps or self.timesteps[-1] != self.num_timesteps:
            self._evaluate()

    def record(self, policy_steps: int) -> None:
        """Evaluate now, at ``policy_steps`` (training outside ``learn``: distillation)."""
        self.num_timesteps = policy_steps
        self._evaluate()

    def _evaluate(self) -> None:
        began = time.perf_counter()
        run = TrainedRun(self.model, self.normalizer, self.plan)
        result = evaluate_run(run, self.episodes, self.seed)
        self.evaluations.append(result)
        self.timesteps.append(self.num_timesteps)
        self._next = (self.num_timesteps // self.every + 1) * self.every
        if result.mean_return > self._best:
            self._best = result.mean_return
            self.model.save(self.out / "best_model.zip")
        buffer = getattr(self.model, "ep_info_buffer", None) or []
        train_return = float(np.mean([info["r"] for info in buffer])) if buffer else ""
        row = (
            self.num_timesteps,
            self.num_timesteps * self.decimation,
            began - self._start - self._evaluating,
            result.mean_return,
            float(np.std(result.returns)),
            result.rms,
            max(result.tracking_rms),
            float(np.mean(result.saturated_actions)),
            train_return,
        )
        with open(self.out / CURVE_FILE, "a", newline="") as handle:
            csv.writer(handle).writerow(row)
        np.savez(
            self.out / "evaluations.npz",
            timesteps=np.array(self.timesteps),
            results=np.array([e.returns for e in self.evaluations]),
            tracking_rms=np.array([e.tracking_rms for e in self.evaluations]),
            saturated=np.array([e.saturated_actions for e in self.evaluations]),
        )
        self._evaluating += time.perf_counter() - began
        if self.logger is not None:
            self.logger.record("eval/mean_return", result.mean_return)
            self.logger.record("eval/tracking_rms", result.rms)
