"""Train stable-baselines3 policies on the estimated (or true, or raw-sensor) state.

Vectorized envs: with ``n_envs > 1`` the arms share one PyBullet world (`SB3VecEnv`), or
``batches`` such worlds in worker processes (`ProcessBatches`, one per core, or batches
with different env kwargs), all made by `elastic_gym.training.run_envs`; ``VecNormalize``
saved beside the model, a learning curve (`LearningCurve`: deterministic episodes on the
comparison's loop, every ``eval_freq`` policy steps) that keeps the best model, TensorBoard
logs and a progress bar. What only the envs would check is checked before any worker
starts (`check_policy_env`). The run folder (`RunFolder`) is refused if it holds an
earlier run unless ``overwrite`` (the new run is written beside it and takes its place
when finished); what a failed or interrupted run wrote is removed. The model, its
normalization, ``config.yaml`` and ``summary.json`` are in place before the envs' slow
shutdown, so a run whose model was saved always loads (`load_run`). Training runs with
single-threaded torch and BLAS.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import time
from dataclasses import dataclass
from pathlib import Path

from gymnasium.spaces import flatdim

from elastic_gym.controllers.registry import controller_class
from elastic_gym.evaluation.grid import check_options
from elastic_gym.observers.registry import OBSERVERS, observer_class
from elastic_gym.observers.sensors import SENSORS
from elastic_gym.policy.builder import build_policy_env
from elastic_gym.runtime.parallel import DEFAULT_BACKEND
from elastic_gym.training.config import Settings, TrainConfig, default_policy
from elastic_gym.training.plan import TrainPlan, plan_run
from elastic_gym.training.run_envs import training_vec_env
from elastic_gym.training.run_folder import NewRun, RunFolder, missing_folders, remove_empty
from elastic_gym.training.trained import episode_duration

# what a training run imports besides this module (its worker processes' server does it once)
TRAINING_IMPORTS = ("stable_baselines3", "elastic_gym.training.learning_curve")


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
    is written by another process (`FolderLockedError`; ``lock=False``: the caller holds
    the folder's lock) or the config is invalid; removes what it wrote if training fails
    or is interrupted, keeping an earlier run it was to replace (then `Interrupted` says
    so).
    """
    from elastic_gym.runtime.parallel import single_threaded

    plan = plan_run(config)  # a bad config changes nothing
    episode_duration(plan.spec.env_id, plan.spec.env_kwargs)  # bounded evaluations
    check_policy_env(plan)
    folder = RunFolder(config.out_dir)
    with folder.create(overwrite, lock) as run, single_threaded():
        return _train(plan, run, progress_bar, verbose)


def _train(plan: TrainPlan, run: NewRun, progress_bar: bool, verbose: int) -> TrainResult:
    from stable_baselines3.common.vec_env import VecNormalize

    from elastic_gym.training.learning_curve import LearningCurve

    config, settings, spec = plan.config, plan.settings, plan.spec
    out = run.target.path
    total = config.total_steps or settings.n_timesteps
    algo_kwargs = plan.algorithm_arguments()
    venv = training_vec_env(spec, settings, settings.n_envs, config.seed)
    try:
        normalize = settings.normalize
        gamma = float(algo_kwargs.get("gamma", 0.99))
        venv = VecNormalize(venv, norm_obs=normalize, norm_reward=normalize, gamma=gamma)

        policy = algo_kwargs.pop("policy", default_policy(config.algo))
        if spec.critic:
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
        model = plan.algorithm(
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
        curve = LearningCurve(plan, venv, out, every, config.seed + 10_000)
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
        run.target.write_config(plan.record)
        final = curve.evaluations[-1]
        result = TrainResult(
            str(run.folder.path),
            model.num_timesteps,
            model.num_timesteps * spec.decimation,
            wall,
            final.mean_return,
            final.rms,
        )
        run.target.write_summary(dataclasses.asdict(result))
        run.finish()  # in place before the envs' shutdown, which can take long
    finally:
        with contextlib.suppress(Exception):  # a failure to close must not hide what happened
            venv.close()
    return result


def _distill(model, venv, settings: Settings, curve, seed: int, progress: bool, verbose: int):
    """Train ``model`` by distillation
    ([`elastic_gym.training.distill`][elastic_gym.training.distill]), the learning
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
        plan = plan_run(config)
        setting = config.model_copy(update={"seed": 0, "out_dir": ""}).to_dict()
        if repr(setting) not in built:
            built.add(repr(setting))
            check_policy_env(plan)


def check_policy_env(plan: TrainPlan) -> None:
    """What only building a run's envs would check, checked in this process before any
    worker starts, as a ``ValueError`` naming the option: the observer's options and the
    residual's controller and options bound to their constructors, then the training
    stack built once per batch of env kwargs (their values, e.g. a task's options)."""
    config, spec = plan.config, plan.spec
    action = spec.action
    if config.state != SENSORS:
        fixed = OBSERVERS[config.state][2]
        cls = observer_class(config.state)
        check_options(cls, config.observer_options, "observer_options", fixed)
    if action.residual is not None:
        try:
            base = controller_class(action.residual)
        except ValueError as exc:
            raise ValueError(f"action.residual: {exc}") from None
        check_options(base, action.residual_options, "action.residual_options")
    for kwargs in {repr(k): k for k in plan.settings.batch_kwargs}.values():
        try:
            build_policy_env(spec, spec.make_env(env_kwargs=kwargs), critic=True).close()
        except Exception as exc:
            batch = f" with the batch's env kwargs {kwargs}" if kwargs else ""
            what = " ".join(str(exc).split())
            raise ValueError(
                f"the run's policy env cannot be built{batch}: {type(exc).__name__}: {what}"
            ) from None


def train_many(
    configs: list[TrainConfig],
    workers: int | None = None,
    backend: str = DEFAULT_BACKEND,
    progress: bool = True,
    overwrite: bool = False,
) -> list[TrainResult]:
    """Several runs (e.g. seeds) in parallel on local processes or Ray; results in order.

    Checks every run before the first ([`check_configs`][elastic_gym.training.train.check_configs]).
    If a run fails or the process is interrupted (SIGINT/SIGTERM), the other runs are
    stopped, the finished runs are kept, what the unfinished ones wrote is removed (an
    earlier run one of them was to replace is kept), and the exception says which is which.
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
    earlier = {c.out_dir: RunFolder(c.out_dir).summary_stamp() for c in configs}
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
            preload=TRAINING_IMPORTS,
        )
    except BaseException as exc:
        detail = _settle_runs(configs, results, earlier)
        remove_empty(created)  # the folders this call made, if left empty
        raise with_detail(exc, detail)  # noqa: B904 - with_detail sets the cause
    return [results[i] for i in range(len(configs))]


def _settle_runs(configs: list[TrainConfig], results: dict[int, TrainResult], earlier: dict) -> str:
    """After a failed or interrupted [`train_many`][elastic_gym.training.train.train_many]:
    keep the runs that finished (a result, or a new ``summary.json`` in place), remove what
    the others wrote (a worker that was killed could not), put back an earlier run one was
    replacing; returns what was done, for the message."""
    finished, removed, kept = [], [], []
    for i, config in enumerate(configs):
        folder = RunFolder(config.out_dir)
        stamp = folder.summary_stamp()
        if i in results or stamp not in (None, earlier[config.out_dir]):
            finished.append(config.out_dir)
            continue
        folder.recover()  # an unfinished replacement: removed, the earlier run put back
        if earlier[config.out_dir] is None:
            folder.clear(keep_folder=True)
            removed.append(config.out_dir)
        else:
            kept.append(config.out_dir)
    detail = f"kept the finished run(s) {finished or 'none'}; removed the unfinished run(s) "
    detail += f"{removed or 'none'}"
    if kept:
        detail += f"; kept the earlier run(s) {kept} that unfinished runs were to replace"
    return detail
