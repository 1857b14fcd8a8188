"""Train stable-baselines3 policies on the estimated (or true, or raw-sensor) state.

Vectorized envs (``SubprocVecEnv`` when ``n_envs > 1``), ``VecNormalize`` whose
statistics are saved beside the model, an ``EvalCallback`` saving the best model,
TensorBoard logs and a progress bar. A run folder holds::

    model.zip  vecnormalize.pkl  best_model.zip  config.yaml  summary.json  tb/  evaluations.npz
"""

from __future__ import annotations

import dataclasses
import functools
import json
import pickle
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from elastic_gym.training.config import (
    TrainConfig,
    algorithm_class,
    merged_hyperparams,
    resolve_hyperparams,
)
from elastic_gym.training.policy_env import SENSORS, make_policy_env

RUN_FILES = ("model.zip", "vecnormalize.pkl", "config.yaml")


@dataclass(frozen=True)
class TrainResult:
    out_dir: str
    policy_steps: int
    env_steps: int
    wall_time: float
    mean_eval_return: float


def env_factory(config: TrainConfig, settings: dict):
    """A picklable constructor of the policy env of a config (for vec envs and workers)."""
    return functools.partial(
        make_policy_env,
        config.env_id,
        state=config.state,
        env_kwargs=config.env_kwargs,
        observer_options=config.observer_options,
        decimation=int(settings.get("decimation", 1)),
        residual=config.residual,
        residual_scale=config.residual_scale,
        frame_stack=config.frame_stack if config.state == SENSORS else 1,
    )


def _vec_env(config: TrainConfig, settings: dict, n_envs: int, seed: int):
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    return make_vec_env(
        env_factory(config, settings), n_envs=n_envs, seed=seed,
        vec_env_cls=SubprocVecEnv if n_envs > 1 else DummyVecEnv,
    )


def split_settings(config: TrainConfig) -> tuple[dict, dict]:
    """(our settings, algorithm kwargs) resolved from the hyper-parameter file + overrides."""
    merged = resolve_hyperparams(config.algo, config.env_id, config.hyperparams,
                                 config.hyperparams_file)
    ours = {k: merged.pop(k) for k in ("n_timesteps", "n_envs", "decimation", "normalize")
            if k in merged}
    return ours, merged


def train(config: TrainConfig, progress_bar: bool = True, verbose: int = 0) -> TrainResult:
    """Train one policy; write the run folder; return what happened."""
    from stable_baselines3.common.callbacks import EvalCallback
    from stable_baselines3.common.vec_env import VecNormalize

    settings, algo_kwargs = split_settings(config)
    total = config.total_steps or int(settings.get("n_timesteps", 100_000))
    n_envs = int(settings.get("n_envs", 1))
    out = Path(config.out_dir)
    out.mkdir(parents=True, exist_ok=True)

    venv = _vec_env(config, settings, n_envs, config.seed)
    eval_env = _vec_env(config, settings, 1, config.seed + 10_000)
    normalize = bool(settings.get("normalize", True))
    gamma = float(algo_kwargs.get("gamma", 0.99))
    venv = VecNormalize(venv, norm_obs=normalize, norm_reward=normalize, gamma=gamma)
    eval_env = VecNormalize(eval_env, training=False, norm_obs=normalize, norm_reward=False)

    policy = algo_kwargs.pop("policy", "MlpPolicy")
    model = algorithm_class(config.algo)(
        policy, venv, seed=config.seed, tensorboard_log=str(out / "tb"), verbose=verbose,
        device="cpu", **algo_kwargs,
    )
    callback = EvalCallback(
        eval_env, n_eval_episodes=config.eval_episodes,
        eval_freq=max(config.eval_freq // n_envs, 1), best_model_save_path=str(out),
        log_path=str(out), deterministic=True, verbose=verbose,
    )
    start = time.perf_counter()
    model.learn(total_timesteps=total, callback=callback, progress_bar=progress_bar,
                tb_log_name=config.algo)
    wall = time.perf_counter() - start

    model.save(out / "model.zip")
    venv.save(str(out / "vecnormalize.pkl"))
    # the run folder is self-contained: the hyper-parameters used, not a pointer to a file
    frozen = dataclasses.replace(config, hyperparams_file=None, hyperparams=merged_hyperparams(
        config.algo, config.env_id, config.hyperparams, config.hyperparams_file))
    (out / "config.yaml").write_text(yaml.safe_dump(frozen.to_dict(), sort_keys=False))
    decimation = int(settings.get("decimation", 1))
    mean_eval = float(np.mean(callback.evaluations_results[-1])) if callback.evaluations_results \
        else float("nan")
    result = TrainResult(str(out), model.num_timesteps, model.num_timesteps * decimation, wall,
                         mean_eval)
    (out / "summary.json").write_text(json.dumps(result.__dict__, indent=2))
    venv.close()
    eval_env.close()
    return result


@dataclass
class TrainedRun:
    """A run folder loaded back: the SB3 model, its normalization statistics and config."""

    model: object
    normalizer: object | None
    config: TrainConfig
    settings: dict

    @property
    def decimation(self) -> int:
        return int(self.settings.get("decimation", 1))

    def act(self, flat_obs: np.ndarray) -> np.ndarray:
        """Deterministic action in [-1, 1]^N for one flattened observation."""
        obs = np.asarray(flat_obs, dtype=np.float32)
        if self.normalizer is not None and self.normalizer.norm_obs:
            obs = self.normalizer.normalize_obs(obs)
        action, _ = self.model.predict(obs, deterministic=True)
        return np.asarray(action, dtype=float)


def read_run_config(run_dir: str | Path) -> TrainConfig:
    """The configuration of a run folder written by :func:`train` (checks the folder)."""
    folder = Path(run_dir)
    missing = [name for name in RUN_FILES if not (folder / name).exists()]
    if missing:
        raise ValueError(f"{folder} is not a training run folder: missing {missing}")
    return TrainConfig.from_dict(yaml.safe_load((folder / "config.yaml").read_text()))


def load_run(run_dir: str | Path, best: bool = False) -> TrainedRun:
    """Load a run folder written by :func:`train` (``best=True``: the EvalCallback's best model)."""
    folder = Path(run_dir)
    config = read_run_config(folder)
    settings, _ = split_settings(config)
    model_path = folder / ("best_model.zip" if best and (folder / "best_model.zip").exists()
                           else "model.zip")
    model = algorithm_class(config.algo).load(str(model_path), device="cpu")
    with open(folder / "vecnormalize.pkl", "rb") as handle:
        normalizer = pickle.load(handle)
    normalizer.training = False
    return TrainedRun(model, normalizer, config, settings)


def evaluate_run(run: TrainedRun, n_episodes: int = 3, seed: int = 123) -> float:
    """Mean undiscounted return of the deterministic policy on fresh episodes."""
    env = env_factory(run.config, run.settings)()
    returns = []
    for episode in range(n_episodes):
        obs, _ = env.reset(seed=seed + episode)
        done, total = False, 0.0
        while not done:
            obs, reward, terminated, truncated, _ = env.step(run.act(obs))
            total += float(reward)
            done = terminated or truncated
        returns.append(total)
    env.close()
    return float(np.mean(returns))


def _train_job(config: TrainConfig) -> TrainResult:
    return train(config, progress_bar=False)


def train_many(configs: list[TrainConfig], workers: int | None = None, backend: str = "process",
               progress: bool = True) -> list[TrainResult]:
    """Several runs (e.g. seeds) in parallel on local processes or Ray; results in order."""
    from elastic_gym.parallel import run_jobs

    return run_jobs(_train_job, configs, workers=workers, backend=backend, progress=progress,
                    label="training runs",
                    describe=lambda c: f"training run {c.out_dir} (seed {c.seed})")
