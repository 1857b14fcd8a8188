"""Train stable-baselines3 policies on the estimated (or true, or raw-sensor) state.

Vectorized envs: with ``n_envs > 1`` the arms share one PyBullet world (the batched
env through :class:`~elastic_gym.training.sb3_vec_env.SB3VecEnv`), or ``batches`` such
worlds in worker processes (:class:`~elastic_gym.training.sb3_vec_env.ProcessBatches`,
one per core; or batches with different env kwargs, e.g. plants), all made by
`elastic_gym.training.run_envs`; ``VecNormalize`` whose statistics are saved beside
the model, a learning curve (:class:`~elastic_gym.training.learning_curve.LearningCurve`:
deterministic episodes on the comparison's loop at the start, every ``eval_freq`` policy
steps, default a twentieth of the run, and at the end) that keeps the best model,
TensorBoard logs and a progress bar. The run folder
(:class:`~elastic_gym.training.run_folder.RunFolder`) is refused if it holds an earlier
run (unless ``overwrite``) and removed if the run fails or is interrupted. Training runs
with single-threaded torch and BLAS (:func:`elastic_gym.runtime.parallel.single_threaded`).
A finished folder loads back with :func:`~elastic_gym.training.trained.load_run`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import time
from dataclasses import dataclass
from pathlib import Path

from gymnasium.spaces import flatdim

from elastic_gym.policy.builder import build_policy_env
from elastic_gym.runtime.parallel import DEFAULT_BACKEND
from elastic_gym.training.config import (
    Settings,
    TrainConfig,
    algorithm_class,
    default_policy,
    merged_hyperparams,
)
from elastic_gym.training.distill import check_distill
from elastic_gym.training.run_envs import training_vec_env
from elastic_gym.training.run_folder import RunFolder, missing_folders, remove_empty
from elastic_gym.training.trained import episode_duration


@dataclass(frozen=True)
class TrainResult:
    out_dir: str
    policy_steps: int
    env_steps: int
    wall_time: float
    mean_eval_return: float
    eval_tracking_rms: float


def zero_action_head(model) -> None:
    """Make the policy's mean action exactly zero at the start (Residual Policy Learning):
    the last layer of the actor's mean head gets zero weights and bias. PPO's
    ``log_std_init`` (hyper-parameter) sets the initial exploration around it."""
    import torch

    policy = model.policy
    if hasattr(policy, "action_net"):  # PPO / A2C
        heads = [policy.action_net]
    else:  # SAC: Linear; TD3: Sequential(..., Linear, Tanh) (TrainConfig.algo: no other)
        mu = policy.actor.mu
        heads = (
            [mu]
            if isinstance(mu, torch.nn.Linear)
            else [m for m in mu if isinstance(m, torch.nn.Linear)][-1:]
        )
        if hasattr(model, "actor_target"):
            target = model.actor_target.mu
            heads += [m for m in target if isinstance(m, torch.nn.Linear)][-1:]
    with torch.no_grad():
        for head in heads:
            head.weight.zero_()
            head.bias.zero_()


def train(
    config: TrainConfig,
    progress_bar: bool = True,
    verbose: int = 0,
    overwrite: bool = False,
    lock: bool = True,
) -> TrainResult:
    """Train one policy; write the run folder; return what happened.

    Raises before training if the folder holds an earlier run (unless ``overwrite``),
    is written by another process (:class:`~elastic_gym.runtime.folder_lock.FolderLockedError`;
    ``lock=False``: the caller holds the folder's lock) or the config is invalid;
    removes what it wrote if training fails or is interrupted (then
    :class:`~elastic_gym.runtime.parallel.Interrupted` says so).
    """
    from elastic_gym.runtime.parallel import single_threaded

    settings, algo_kwargs = config.settings()  # a bad config changes nothing
    check_distill(config, settings)
    episode_duration(config.env_id, config.training_env_kwargs(settings))  # bounded evaluations
    folder = RunFolder(config.out_dir)
    with folder.create(overwrite, lock), single_threaded():
        return _train(config, settings, algo_kwargs, folder, progress_bar, verbose)


def _train(
    config: TrainConfig,
    settings: Settings,
    algo_kwargs: dict,
    folder: RunFolder,
    progress_bar: bool,
    verbose: int,
) -> TrainResult:
    from stable_baselines3.common.vec_env import VecNormalize

    from elastic_gym.training.learning_curve import LearningCurve

    out = folder.path
    total = config.total_steps or settings.n_timesteps
    n_envs = settings.n_envs
    spec = config.policy_spec(settings)
    venv = training_vec_env(spec, settings, n_envs, config.seed)
    try:
        normalize = settings.normalize
        gamma = float(algo_kwargs.get("gamma", 0.99))
        venv = VecNormalize(venv, norm_obs=normalize, norm_reward=normalize, gamma=gamma)

        policy = algo_kwargs.pop("policy", default_policy(config.algo))
        if settings.critic_state or settings.critic_plant:
            from elastic_gym.training.critic import PrivilegedCriticPolicy

            deployed = build_policy_env(spec, spec.make_env())  # the actor's observation only
            try:
                privileged = flatdim(venv.observation_space) - flatdim(deployed.observation_space)
            finally:
                deployed.close()
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
        if spec.action.kind == "residual":
            zero_action_head(model)
        every = config.eval_freq or max(total // 20, 1)
        curve = LearningCurve(config, settings, venv, out, every, config.seed + 10_000)
        start = time.perf_counter()
        if settings.distill is None:
            model.learn(
                total_timesteps=total,
                callback=curve,
                progress_bar=progress_bar,
                tb_log_name=config.algo,
            )
        else:
            _distill(model, venv, settings, curve, config.seed, progress_bar, verbose)
        wall = time.perf_counter() - start

        model.save(out / "model.zip")
        venv.save(str(out / "vecnormalize.pkl"))
    finally:
        with contextlib.suppress(Exception):  # a failure to close must not hide what happened
            venv.close()
    # the run folder is self-contained: the hyper-parameters used, not a pointer to a file,
    # and every field of the action and observation configs (a later release's defaults
    # must not change what a saved policy's actions mean)
    folder.write_config(
        config.model_copy(
            update={
                "hyperparams_file": None,
                "action": spec.action.to_dict(),
                "observation": spec.observation.to_dict(),
                "hyperparams": merged_hyperparams(
                    config.algo, config.env_id, config.hyperparams, config.hyperparams_file
                ),
            }
        )
    )
    final = curve.evaluations[-1]
    result = TrainResult(
        str(out),
        model.num_timesteps,
        model.num_timesteps * spec.decimation,
        wall,
        final.mean_return,
        final.rms,
    )
    folder.write_summary(dataclasses.asdict(result))
    return result


def _distill(model, venv, settings: Settings, curve, seed: int, progress: bool, verbose: int):
    """Train ``model`` by distillation (:mod:`elastic_gym.training.distill`), the learning
    curve evaluated at the start and after every iteration."""
    from stable_baselines3.common.utils import configure_logger

    from elastic_gym.training.distill import distill

    assert settings.distill is not None
    model.set_logger(configure_logger(verbose, model.tensorboard_log, "distill"))
    curve.init_callback(model)
    curve.on_training_start({}, {})
    distill(
        model,
        venv,
        settings.distill,
        seed,
        after_iteration=curve.record,
        progress=progress,
    )


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
        RunFolder(config.out_dir).check(overwrite)
        settings, _ = config.settings()
        check_distill(config, settings)
        setting = config.model_copy(update={"seed": 0, "out_dir": ""}).to_dict()
        if repr(setting) not in built:
            built.add(repr(setting))
            spec = config.policy_spec(settings)
            build_policy_env(spec, spec.make_env()).close()


def train_many(
    configs: list[TrainConfig],
    workers: int | None = None,
    backend: str = DEFAULT_BACKEND,
    progress: bool = True,
    overwrite: bool = False,
) -> list[TrainResult]:
    """Several runs (e.g. seeds) in parallel on local processes or Ray; results in order.

    Checks every run before the first (:func:`check_configs`). If a run fails or the
    process is interrupted (SIGINT/SIGTERM), the other runs are stopped, the finished
    runs are kept, the unfinished ones removed, and the exception says which is which.
    """
    with contextlib.ExitStack() as locks:
        for out in dict.fromkeys(Path(c.out_dir) for c in configs):  # repeats: check_configs
            locks.enter_context(RunFolder(out).lock())
        return _train_many_locked(configs, workers, backend, progress, overwrite)


def _train_many_locked(
    configs: list[TrainConfig], workers: int | None, backend: str, progress: bool, overwrite: bool
) -> list[TrainResult]:
    from elastic_gym.runtime.parallel import for_each_result, with_detail

    check_configs(configs, overwrite)
    created = {folder for c in configs for folder in missing_folders(c.out_dir)}
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
        finished = [c.out_dir for c in configs if RunFolder(c.out_dir).finished]
        unfinished = [c.out_dir for c in configs if c.out_dir not in finished]
        for out in unfinished:
            RunFolder(out).clear(keep_folder=True)
        remove_empty(created)  # the folders this call made, if left empty
        detail = (
            f"kept the finished run(s) {finished or 'none'}; removed the unfinished "
            f"run(s) {unfinished}"
        )
        raise with_detail(exc, detail)  # noqa: B904 - with_detail sets the cause
    return [results[i] for i in range(len(configs))]
