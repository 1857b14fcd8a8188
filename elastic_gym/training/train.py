"""Train stable-baselines3 policies on the estimated (or true, or raw-sensor) state.

With ``n_envs > 1`` the arms share one PyBullet world
(:class:`~elastic_gym.training.sb3_vec_env.SB3VecEnv`), or ``batches`` worlds in worker
processes (:class:`~elastic_gym.training.sb3_vec_env.ProcessBatches`); ``VecNormalize``,
a learning curve that keeps the best model, TensorBoard logs. A run folder holds
``model.zip``, ``vecnormalize.pkl``, ``best_model.zip``, ``config.yaml``,
``summary.json`` (written last: a folder with it holds a finished run),
``learning_curve.csv``, ``evaluations.npz`` and ``tb/``. A folder holding a run is refused
unless ``overwrite`` (which removes that run's files only); a failed or interrupted run
removes what it wrote. Training is single-threaded. ``model.zip`` and
``vecnormalize.pkl`` are pickles: load only run folders from trusted sources.
"""

from __future__ import annotations

import contextlib
import functools
import json
import pickle
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml
from gymnasium.vector import AutoresetMode

from elastic_gym.folder_lock import check_writable, folder_lock
from elastic_gym.training.config import (
    Settings,
    TrainConfig,
    algorithm_class,
    default_policy,
    merged_hyperparams,
)
from elastic_gym.training.evaluation import CURVE_FILE, Evaluation, PolicyActor, evaluate_arms
from elastic_gym.training.policy_env import SENSORS, make_policy_env
from elastic_gym.yaml_io import load_yaml

RUN_FILES = ("model.zip", "vecnormalize.pkl", "config.yaml")  # needed to load a run
RUN_OUTPUTS = (*RUN_FILES, "best_model.zip", "summary.json", "evaluations.npz", CURVE_FILE, "tb")
FINISHED = "summary.json"


@dataclass(frozen=True)
class TrainResult:
    out_dir: str
    policy_steps: int
    env_steps: int
    wall_time: float
    mean_eval_return: float
    eval_tracking_rms: float


def env_factory(config: TrainConfig, settings: Settings, critic_state: bool = False):
    """A picklable constructor of the policy env of a config (for vec envs and workers);
    ``critic_state``: the training stack with the true state appended for the critic."""
    action, observation = config.policy_configs(settings)
    return functools.partial(
        make_policy_env,
        config.env_id,
        state=config.state,
        env_kwargs=config.training_env_kwargs(settings),
        observer_options=config.observer_options,
        decimation=settings.decimation,
        action=action,
        observation=observation,
        frame_stack=config.frame_stack if config.state == SENSORS else 1,
        critic_state=critic_state,
    )


def policy_vec_env(
    config: TrainConfig,
    settings: Settings,
    n_arms: int,
    autoreset_mode: AutoresetMode = AutoresetMode.DISABLED,
    env_kwargs: dict | None = None,
    critic_state: bool = False,
):
    """The policy stack of a config on ``n_arms`` arms of one PyBullet world (a Gymnasium
    vector env); ``env_kwargs`` update the run's (:meth:`TrainConfig.training_env_kwargs`)
    key by key; ``critic_state``: the training stack with the true state appended."""
    from elastic_gym.training.policy_env import make_policy_vec_env

    action, observation = config.policy_configs(settings)
    return make_policy_vec_env(
        config.env_id,
        n_arms,
        state=config.state,
        env_kwargs={**config.training_env_kwargs(settings), **(env_kwargs or {})},
        observer_options=config.observer_options,
        decimation=settings.decimation,
        action=action,
        observation=observation,
        frame_stack=config.frame_stack if config.state == SENSORS else 1,
        autoreset_mode=autoreset_mode,
        critic_state=critic_state,
    )


def vec_env_factory(
    config: TrainConfig,
    settings: Settings,
    n_arms: int,
    env_kwargs: dict | None = None,
    critic_state: bool = False,
):
    """A picklable constructor of ``n_arms`` arms of the policy env in one PyBullet world,
    as an SB3 ``VecEnv`` (``env_kwargs`` update the run's)."""
    from elastic_gym.training.sb3_vec_env import SB3VecEnv

    return lambda: SB3VecEnv(
        policy_vec_env(config, settings, n_arms, env_kwargs=env_kwargs, critic_state=critic_state)
    )


def _vec_env(config: TrainConfig, settings: Settings, n_envs: int, seed: int):
    """One env (n_envs = 1), a batch of n_envs arms, or several batches (hyper-parameter
    ``batches``, :attr:`Settings.batch_kwargs`) in worker processes; with the true state appended
    for the critic if the hyper-parameter ``critic_state`` is set."""
    from stable_baselines3.common.vec_env import DummyVecEnv, VecMonitor

    from elastic_gym.training.sb3_vec_env import ProcessBatches

    batches = settings.batch_kwargs
    if n_envs % len(batches):
        raise ValueError(f"the number of batches ({len(batches)}) must divide n_envs ({n_envs})")
    critic_state = settings.critic_state
    if n_envs == 1:
        venv = DummyVecEnv([env_factory(config, settings, critic_state)])
        venv.action_space.seed(seed)
    else:
        factories = [
            vec_env_factory(config, settings, n_envs // len(batches), kwargs, critic_state)
            for kwargs in batches
        ]
        venv = factories[0]() if len(factories) == 1 else ProcessBatches(factories)
    venv.seed(seed)
    # Episode returns and lengths, one wrapping whatever the arms' layout (VecNormalize's
    # statistics sync walks wrapper stacks in parallel).
    return VecMonitor(venv)


def zero_action_head(model) -> None:
    """Make the policy's mean action exactly zero at the start (Residual Policy Learning):
    the last layer of the actor's mean head gets zero weights and bias. PPO's
    ``log_std_init`` (hyper-parameter) sets the initial exploration around it."""
    import torch

    policy = model.policy
    if hasattr(policy, "action_net"):  # PPO / A2C
        heads = [policy.action_net]
    elif hasattr(policy.actor, "mu"):  # SAC: Linear; TD3: Sequential(..., Linear, Tanh)
        mu = policy.actor.mu
        heads = (
            [mu]
            if isinstance(mu, torch.nn.Linear)
            else [m for m in mu if isinstance(m, torch.nn.Linear)][-1:]
        )
        if hasattr(model, "actor_target"):
            target = model.actor_target.mu
            heads += [m for m in target if isinstance(m, torch.nn.Linear)][-1:]
    else:  # pragma: no cover - every algorithm of ALGORITHMS is handled above
        raise TypeError(f"cannot find the action head of {type(policy).__name__}")
    with torch.no_grad():
        for head in heads:
            head.weight.zero_()
            head.bias.zero_()


def earlier_run(folder: Path) -> list[str]:
    """Files of an earlier training run in ``folder`` or in its ``seed*`` sub-folders."""
    found = []
    for directory in (folder, *sorted(folder.glob("seed*"))):
        found += [
            str((directory / name).relative_to(folder))
            for name in RUN_OUTPUTS
            if (directory / name).exists()
        ]
    return found


def check_run_folder(folder: str | Path, overwrite: bool = False) -> None:
    """Raise if ``folder`` cannot receive a run (changes nothing): ``NotADirectoryError``
    if it is a file, ``PermissionError`` if it cannot be written (a read-only file
    system), ``FileExistsError`` if it holds an earlier run and not ``overwrite``."""
    folder = Path(folder)
    check_writable(folder)
    earlier = earlier_run(folder) if folder.is_dir() else []
    if earlier and not overwrite:
        shown = ", ".join(earlier[:4]) + (", ..." if len(earlier) > 4 else "")
        raise FileExistsError(
            f"run folder {str(folder)!r} holds an earlier run ({shown}); choose another "
            "--out, or replace it with --overwrite (overwrite=True)"
        )


def clear_run(folder: str | Path, keep_folder: bool = False) -> None:
    """Remove the files of a run (and of ``seed*`` sub-runs) from ``folder``, and the
    folders left empty (``folder`` itself too unless ``keep_folder``); nothing else."""
    folder = Path(folder)
    if not folder.is_dir():
        return
    for directory in (*sorted(folder.glob("seed*")), folder):
        if not directory.is_dir():
            continue
        for name in RUN_OUTPUTS:
            path = directory / name
            if path.is_dir():
                shutil.rmtree(path)
            elif path.exists():
                path.unlink()
        if not any(directory.iterdir()) and not (keep_folder and directory == folder):
            with contextlib.suppress(OSError):  # e.g. the current directory
                directory.rmdir()


def train(
    config: TrainConfig,
    progress_bar: bool = True,
    verbose: int = 0,
    overwrite: bool = False,
    lock: bool = True,
) -> TrainResult:
    """Train one policy; write the run folder; return what happened.

    Raises before training if the folder holds an earlier run (unless ``overwrite``),
    is written by another process (:class:`~elastic_gym.folder_lock.FolderLockedError`;
    ``lock=False``: the caller holds the folder's lock) or the config is invalid;
    removes what it wrote if training fails or is interrupted (then
    :class:`~elastic_gym.parallel.Interrupted` says so).
    """
    check_writable(config.out_dir)
    with folder_lock(config.out_dir) if lock else contextlib.nullcontext():
        return _train_locked(config, progress_bar, verbose, overwrite)


def _train_locked(
    config: TrainConfig, progress_bar: bool, verbose: int, overwrite: bool
) -> TrainResult:
    from elastic_gym.parallel import Interrupted, single_threaded

    out = Path(config.out_dir)
    check_run_folder(out, overwrite)
    settings, algo_kwargs = config.settings()
    created = [folder for folder in (out, *out.parents) if not folder.exists()]
    if overwrite:
        clear_run(out, keep_folder=True)
    out.mkdir(parents=True, exist_ok=True)
    try:
        with single_threaded():
            return _train(config, settings, algo_kwargs, out, progress_bar, verbose)
    except BaseException as exc:
        clear_run(out, keep_folder=True)
        for folder in created:  # deepest first; only the folders this call made, if empty
            with contextlib.suppress(OSError):
                folder.rmdir()
        if isinstance(exc, KeyboardInterrupt):
            raise Interrupted.of(exc, f"removed the unfinished run {out}") from None
        raise


def _train(
    config: TrainConfig,
    settings: Settings,
    algo_kwargs: dict,
    out: Path,
    progress_bar: bool,
    verbose: int,
) -> TrainResult:
    from stable_baselines3.common.vec_env import VecNormalize

    from elastic_gym.training.learning_curve import LearningCurve

    total = config.total_steps or settings.n_timesteps
    n_envs, decimation = settings.n_envs, settings.decimation
    action, observation = config.policy_configs(settings)
    venv = _vec_env(config, settings, n_envs, config.seed)
    try:
        eval_envs = policy_vec_env(config, settings, config.eval_episodes, AutoresetMode.NEXT_STEP)
    except BaseException:
        venv.close()
        raise
    try:
        normalize = settings.normalize
        gamma = float(algo_kwargs.get("gamma", 0.99))
        venv = VecNormalize(venv, norm_obs=normalize, norm_reward=normalize, gamma=gamma)

        policy = algo_kwargs.pop("policy", default_policy(config.algo))
        if settings.critic_state:
            from elastic_gym.training.critic import PrivilegedCriticPolicy

            # the evaluation envs are the deployment stack: the actor's observation only
            privileged = (
                venv.observation_space.shape[0] - eval_envs.single_observation_space.shape[0]
            )
            policy = PrivilegedCriticPolicy
            algo_kwargs["policy_kwargs"] = {
                **algo_kwargs.get("policy_kwargs", {}),
                "privileged_size": privileged,
            }
        model = algorithm_class(config.algo)(
            policy,
            venv,
            seed=config.seed,
            tensorboard_log=str(out / "tb"),
            verbose=verbose,
            device="cpu",
            **algo_kwargs,
        )
        if action.kind == "residual":
            zero_action_head(model)
        curve = LearningCurve(
            eval_envs, venv, out, config.eval_freq, config.seed + 10_000, decimation
        )
        start = time.perf_counter()
        model.learn(
            total_timesteps=total,
            callback=curve,
            progress_bar=progress_bar,
            tb_log_name=config.algo,
        )
        wall = time.perf_counter() - start

        model.save(out / "model.zip")
        venv.save(str(out / "vecnormalize.pkl"))
    finally:
        for env in (venv, eval_envs):  # a failure to close must not hide what happened
            with contextlib.suppress(Exception):
                env.close()
    # the run folder is self-contained: the hyper-parameters used, not a pointer to a file,
    # and every field of the action and observation configs (a later release's defaults
    # must not change what a saved policy's actions mean)
    frozen = config.model_copy(
        update={
            "hyperparams_file": None,
            "action": action.to_dict(),
            "observation": observation.to_dict(),
            "hyperparams": merged_hyperparams(
                config.algo, config.env_id, config.hyperparams, config.hyperparams_file
            ),
        }
    )
    (out / "config.yaml").write_text(yaml.safe_dump(frozen.to_dict(), sort_keys=False))
    final = curve.evaluations[-1]
    result = TrainResult(
        str(out),
        model.num_timesteps,
        model.num_timesteps * decimation,
        wall,
        final.mean_return,
        final.rms,
    )
    (out / FINISHED).write_text(json.dumps(result.__dict__, indent=2))
    return result


@dataclass
class TrainedRun:
    """A run folder loaded back: the SB3 model, its normalization statistics and config."""

    model: object
    normalizer: object | None
    config: TrainConfig
    settings: Settings

    def __post_init__(self) -> None:
        self._actor = PolicyActor(self.model, self.normalizer)

    @property
    def decimation(self) -> int:
        return self.settings.decimation

    def start(self) -> None:
        """A new episode: a recurrent policy forgets its memory."""
        self._actor.start()

    def act(self, flat_obs: np.ndarray) -> np.ndarray:
        """Deterministic action in [-1, 1]^n for one flattened observation, or (N, n) for
        a batch of N."""
        return self._actor(flat_obs)


def read_run_config(run_dir: str | Path) -> TrainConfig:
    """The configuration of a run folder written by :func:`train` (checks the folder)."""
    folder = Path(run_dir)
    if not folder.is_dir():
        raise ValueError(f"{folder} is not a training run folder: no such folder")
    missing = [name for name in RUN_FILES if not (folder / name).is_file()]
    if missing:
        raise ValueError(f"{folder} is not a training run folder: missing {missing}")
    path = folder / "config.yaml"
    try:
        data = load_yaml(path)
        if not isinstance(data, dict):
            raise ValueError(f"must hold a mapping, got {type(data).__name__}")
        return TrainConfig.from_dict(_before_the_deadzone(data))
    except (TypeError, ValueError) as exc:
        raise ValueError(
            f"{path} is not a valid run configuration: {' '.join(str(exc).split())}"
        ) from None


def _before_the_deadzone(data: dict) -> dict:
    """A run saved before actions had ``residual_deadzone`` applied its residual without
    one: say so explicitly, so that today's default (0.2) does not change its actions."""
    action = data.get("action", {})
    hyperparams = data.get("hyperparams")
    shipped = hyperparams.get("action") if isinstance(hyperparams, dict) else None
    if not isinstance(action, dict) or any(
        isinstance(part, dict) and "residual_deadzone" in part for part in (action, shipped)
    ):
        return data
    return {**data, "action": {**action, "residual_deadzone": 0.0}}


def load_run(run_dir: str | Path, best: bool = False) -> TrainedRun:
    """Load a run folder written by :func:`train` (``best=True``: the best model of the
    learning curve).

    Unpickles ``model.zip`` and ``vecnormalize.pkl``: load only trusted run folders. A
    missing or corrupted file raises ``ValueError`` naming it.
    """
    folder = Path(run_dir)
    config = read_run_config(folder)
    settings, _ = config.settings()
    model_path = folder / (
        "best_model.zip" if best and (folder / "best_model.zip").exists() else "model.zip"
    )
    try:
        model = algorithm_class(config.algo).load(str(model_path), device="cpu")
    except Exception as exc:
        raise ValueError(
            f"{model_path} cannot be loaded as a {config.algo} model: {type(exc).__name__}: {exc}"
        ) from None
    normalizer_path = folder / "vecnormalize.pkl"
    try:
        with open(normalizer_path, "rb") as handle:
            normalizer = pickle.load(handle)
        normalizer.training = False
    except Exception as exc:
        raise ValueError(
            f"{normalizer_path} cannot be loaded: {type(exc).__name__}: {exc}"
        ) from None
    return TrainedRun(model, normalizer, config, settings)


def evaluate_run(
    run: TrainedRun, n_episodes: int = 3, seed: int = 123, env_kwargs: dict | None = None
) -> Evaluation:
    """The deterministic policy of a run on ``n_episodes`` fresh episodes (seeds
    ``seed``, ``seed + 1``, ...), run as the arms of one batch; ``env_kwargs`` are merged
    into the run's (e.g. ``{"plant_scaling": {"link_mass": 1.3}}``)."""
    envs = policy_vec_env(run.config, run.settings, n_episodes, AutoresetMode.NEXT_STEP, env_kwargs)
    try:
        return evaluate_arms(envs, run.act, seed, run.start)
    finally:
        envs.close()


def check_configs(configs: list[TrainConfig], overwrite: bool = False) -> None:
    """Everything that can be checked before the first training run: distinct run
    folders (``--seeds 0 0``), free run folders, valid hyper-parameters, and the policy
    env of each distinct setting built once (bad env kwargs or observer options)."""
    folders = [str(Path(c.out_dir)) for c in configs]
    repeated = sorted({f for f in folders if folders.count(f) > 1})
    if repeated:
        seeds = sorted({c.seed for c in configs if str(Path(c.out_dir)) in repeated})
        raise ValueError(
            f"several runs would write to {repeated} (seeds {seeds}): give each "
            "run its own seed and folder"
        )
    built = set()
    for config in configs:
        check_run_folder(config.out_dir, overwrite)
        settings, _ = config.settings()
        setting = config.model_copy(update={"seed": 0, "out_dir": ""}).to_dict()
        if repr(setting) not in built:
            built.add(repr(setting))
            env_factory(config, settings)().close()


def train_many(
    configs: list[TrainConfig],
    workers: int | None = None,
    backend: str = "process",
    progress: bool = True,
    overwrite: bool = False,
) -> list[TrainResult]:
    """Several runs (e.g. seeds) in parallel on local processes or Ray; results in order.

    Checks every run before the first (:func:`check_configs`). If a run fails or the
    process is interrupted (SIGINT/SIGTERM), the other runs are stopped, the finished
    runs are kept, the unfinished ones removed, and the exception says which is which.
    """
    folders = dict.fromkeys(Path(c.out_dir) for c in configs)  # repeats: check_configs
    for folder in folders:
        check_writable(folder)
    with contextlib.ExitStack() as locks:
        for folder in folders:
            locks.enter_context(folder_lock(folder))
        return _train_many_locked(configs, workers, backend, progress, overwrite)


def _train_many_locked(
    configs: list[TrainConfig], workers: int | None, backend: str, progress: bool, overwrite: bool
) -> list[TrainResult]:
    from elastic_gym.parallel import for_each_result, with_detail

    check_configs(configs, overwrite)
    created = {
        folder
        for c in configs
        for folder in (Path(c.out_dir), *Path(c.out_dir).parents)
        if not folder.exists()
    }
    results: dict[int, TrainResult] = {}
    try:
        for_each_result(
            functools.partial(train, progress_bar=False, overwrite=overwrite, lock=False),
            configs,
            results.__setitem__,
            workers=workers,
            backend=backend,
            progress=progress,
            label="training runs",
            describe=lambda c: f"training run {c.out_dir} (seed {c.seed})",
        )
    except BaseException as exc:
        finished = [c.out_dir for c in configs if (Path(c.out_dir) / FINISHED).exists()]
        unfinished = [c.out_dir for c in configs if c.out_dir not in finished]
        for folder in unfinished:
            clear_run(folder, keep_folder=True)
        for folder in sorted(created, key=lambda f: len(f.parts), reverse=True):
            with contextlib.suppress(OSError):  # the folders this call made, if left empty
                folder.rmdir()
        detail = (
            f"kept the finished run(s) {finished or 'none'}; removed the unfinished "
            f"run(s) {unfinished}"
        )
        raise with_detail(exc, detail)  # noqa: B904 - with_detail sets the cause
    return [results[i] for i in range(len(configs))]
