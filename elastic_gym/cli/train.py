"""``elastic-gym train``: a stable-baselines3 policy on the estimated (or true, or raw-sensor)
state, one run or one per seed."""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING

from elastic_gym.cli.common import default, require_rl_extra, yaml_mapping
from elastic_gym.runtime.parallel import BACKENDS, DEFAULT_BACKEND
from elastic_gym.validation import distinct

if TYPE_CHECKING:
    from elastic_gym.training import TrainConfig


def add_parser(subcommands: argparse._SubParsersAction) -> None:
    from elastic_gym.observers.registry import state_sources
    from elastic_gym.policy.actions import KINDS
    from elastic_gym.training.config import ALGORITHMS, TrainConfig

    parser = subcommands.add_parser(
        "train",
        help="train an RL policy (stable-baselines3) on the estimated or true state",
        description="Train PPO/SAC/TD3 with RL-Zoo-style hyper-parameters (shipped per env id, "
        "overridable), VecNormalize, evaluation callback, TensorBoard logs. The run folder "
        "plugs into 'elastic-gym compare --policy RUN'.",
    )
    parser.add_argument(
        "--env",
        default=default(TrainConfig, "env_id"),
        help="env id (the elastic_gym/ prefix is optional; default: %(default)s)",
    )
    parser.add_argument("--algo", default=default(TrainConfig, "algo"), choices=ALGORITHMS)
    parser.add_argument(
        "--state",
        default=default(TrainConfig, "state"),
        choices=state_sources(),
        help="what the policy sees: an observer's estimate, 'true', or raw "
        "'sensors' (frame-stacked)",
    )
    parser.add_argument(
        "--steps", type=int, help="policy steps (default: n_timesteps of the hyper-parameter file)"
    )
    parser.add_argument(
        "--seeds", type=int, nargs="+", default=[default(TrainConfig, "seed")], metavar="SEED"
    )
    parser.add_argument(
        "--out",
        metavar="DIR",
        help="run folder (default: runs/<algo>-<env>-"
        "<state>; one sub-folder per seed when several)",
    )
    parser.add_argument(
        "--overwrite", action="store_true", help="replace an earlier run in the run folder"
    )
    parser.add_argument(
        "--action",
        choices=KINDS,
        help="action parameterization (default: the hyper-parameter file's)",
    )
    parser.add_argument(
        "--action-options",
        default="{}",
        metavar="YAML",
        help="ActionConfig fields, e.g. '{offset_scale: 0.05, bandwidth: 60}'",
    )
    parser.add_argument(
        "--observation",
        default="{}",
        metavar="YAML",
        help="ObservationConfig fields, e.g. '{preview: [0.02, 0.05]}'",
    )
    parser.add_argument(
        "--residual",
        metavar="CONTROLLER",
        help="residual policy on top of this controller (e.g. "
        "feedforward-state-feedback); same as --action residual",
    )
    parser.add_argument(
        "--residual-scale",
        type=float,
        help="bound of the residual torque as a fraction of the torque limit",
    )
    parser.add_argument(
        "--frame-stack",
        type=int,
        default=default(TrainConfig, "frame_stack"),
        help="frames for 'sensors' (default: %(default)s)",
    )
    parser.add_argument(
        "--env-kwargs",
        default="{}",
        metavar="YAML",
        help="env kwargs as a YAML mapping, e.g. '{task: regulation}'",
    )
    parser.add_argument("--observer-options", default="{}", metavar="YAML")
    parser.add_argument(
        "--model",
        metavar="FILE",
        help="identified model file (elastic-gym identify): the policy's observer, gravity "
        "compensation and residual base build on it instead of the nominal model (the "
        "simulated plant stays what --env-kwargs make it)",
    )
    parser.add_argument(
        "--hyperparams",
        nargs="+",
        default=[],
        metavar="KEY=VALUE",
        help="override hyper-parameters, e.g. learning_rate=1e-4 n_envs=2",
    )
    parser.add_argument(
        "--hyperparams-file",
        metavar="YAML",
        help="hyper-parameter file: a path, or the name of a shipped one (ppo-robust.yaml,"
        " recurrentppo-deluca-robust.yaml, recurrentppo-robust.yaml, ppo-residual-robust.yaml)",
    )
    parser.add_argument(
        "--eval-freq",
        type=int,
        default=default(TrainConfig, "eval_freq"),
        help="policy steps between evals (default: a twentieth of the run's policy steps)",
    )
    parser.add_argument("--eval-episodes", type=int, default=default(TrainConfig, "eval_episodes"))
    parser.add_argument(
        "--backend",
        choices=BACKENDS,
        default=DEFAULT_BACKEND,
        help="for several seeds: local processes (default) or Ray",
    )
    parser.add_argument("--workers", type=int, help="parallel runs (default: one per CPU)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument(
        "--print-config",
        action="store_true",
        help="print the configuration of each run this command would train (a YAML list of "
        "TrainConfig mappings) and exit without training or writing anything",
    )
    parser.set_defaults(handler=run_train)


def _action_fields(args: argparse.Namespace) -> dict:
    """ActionConfig fields from --action, --action-options, --residual, --residual-scale."""
    fields = yaml_mapping(args.action_options, "--action-options")
    if args.action is not None:
        fields["kind"] = args.action
    if args.residual is not None:
        fields.update(kind="residual", residual=args.residual)
    if args.residual_scale is not None:
        fields["residual_scale"] = args.residual_scale
    return fields


def train_run_base(args: argparse.Namespace) -> str:
    """The run folder of ``elastic-gym train`` (``--out`` or its default): the run's, or
    the parent of one ``seed<k>`` folder per seed when several."""
    name = args.env.split("/")[-1]
    return args.out or f"runs/{args.algo}-{name}-{args.state}" + (
        f"-residual-{args.residual}" if args.residual else ""
    )


def train_configs(args: argparse.Namespace) -> list[TrainConfig]:
    """The [`TrainConfig`][elastic_gym.training.TrainConfig] of each seed of parsed
    ``elastic-gym train`` arguments: what the command trains."""
    from elastic_gym.training import TrainConfig, parse_overrides

    distinct(args.seeds, "seed(s)", where="--seeds")
    base = train_run_base(args)
    return [
        TrainConfig(
            env_id=args.env,
            algo=args.algo,
            state=args.state,
            total_steps=args.steps,
            seed=seed,
            out_dir=base if len(args.seeds) == 1 else f"{base}/seed{seed}",
            action=_action_fields(args),
            observation=yaml_mapping(args.observation, "--observation"),
            frame_stack=args.frame_stack,
            env_kwargs=yaml_mapping(args.env_kwargs, "--env-kwargs"),
            observer_options=yaml_mapping(args.observer_options, "--observer-options"),
            model_file=args.model,
            hyperparams=parse_overrides(args.hyperparams),
            hyperparams_file=args.hyperparams_file,
            eval_freq=args.eval_freq,
            eval_episodes=args.eval_episodes,
        )
        for seed in args.seeds
    ]


def run_train(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.table import Table

    if args.print_config:
        import yaml

        resolved = [config.to_dict() for config in train_configs(args)]
        sys.stdout.write(yaml.safe_dump(resolved, sort_keys=False))
        return 0
    require_rl_extra("elastic-gym train")
    from elastic_gym.training import RunFolder, train, train_many

    base = RunFolder(train_run_base(args))
    base.undo_killed_writer()  # a killed overwrite's leftovers: the earlier run put back
    base.check(args.overwrite)
    configs = train_configs(args)
    if len(configs) == 1:
        results = [train(configs[0], progress_bar=not args.no_progress, overwrite=args.overwrite)]
    else:
        results = train_many(
            configs,
            workers=args.workers,
            backend=args.backend,
            progress=not args.no_progress,
            overwrite=args.overwrite,
        )
    table = Table(title=f"{args.algo} on {configs[0].env_id} ({args.state} state)")
    table.add_column("run", overflow="fold")
    for column in ("seed", "policy steps", "env steps", "wall time [s]", "eval return"):
        table.add_column(column)
    for config, result in zip(configs, results, strict=True):
        table.add_row(
            result.out_dir,
            str(config.seed),
            str(result.policy_steps),
            str(result.env_steps),
            f"{result.wall_time:.0f}",
            f"{result.mean_eval_return:.4g}",
        )
    Console().print(table)
    print(f"compare with: elastic-gym compare --policy {' '.join(r.out_dir for r in results)}")
    return 0
