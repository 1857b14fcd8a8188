"""The ``elastic-gym`` console script (argparse subcommands).

``elastic-gym compare`` runs a comparison grid (the built-in default, a shipped
``--preset`` or a ``--config`` YAML file) and prints its table; ``--policy RUN`` adds
trained policies as controllers. ``elastic-gym train`` trains a stable-baselines3
policy on the estimated (or true, or raw-sensor) state. ``elastic-gym schema NAME``
prints the JSON Schema of a kind of YAML file. Defaults come from the config models
(:class:`~elastic_gym.training.TrainConfig`, :class:`~elastic_gym.evaluation.Scenario`),
not from this module. A subcommand is a
function ``add_<name>_parser(subcommands)`` that adds its parser and sets
``handler`` (a function ``args -> exit code``); :func:`build_parser` lists them.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from pydantic import BaseModel, RootModel

from elastic_gym.evaluation.groups import DEFAULT_BATCH_SIZE
from elastic_gym.evaluation.presets import DEFAULT_PRESET, list_presets
from elastic_gym.evaluation.scenario import COMPARISON_PHYSICS_DT, QUICK_DURATION
from elastic_gym.parallel import BACKENDS, DEFAULT_BACKEND, Interrupted, interrupts_raised
from elastic_gym.validation import distinct, validated

if TYPE_CHECKING:
    from elastic_gym.benchmark.entry import EntryArguments
    from elastic_gym.training import TrainConfig


def default(model: type[BaseModel], field: str):
    """The default of a config model's field (the one place it is written)."""
    return model.model_fields[field].get_default(call_default_factory=True)


def add_compare_parser(subcommands: argparse._SubParsersAction) -> None:
    parser = subcommands.add_parser(
        "compare",
        help="compare controllers x state sources (true state, observers) on envs",
        description="Run a comparison grid in parallel and write a metrics table (CSV, "
        "markdown) and plots. Without arguments: the built-in default grid on "
        "TwoLinkElastic (about 300 s of CPU: 2.5 to 3 minutes on 2 free cores).",
    )
    source = parser.add_mutually_exclusive_group()
    source.add_argument(
        "--preset",
        default=DEFAULT_PRESET,
        help=f"shipped preset name (default: {DEFAULT_PRESET}); see --list-presets",
    )
    source.add_argument("--config", metavar="YAML", help="scenario YAML file")
    source.add_argument("--list-presets", action="store_true", help="list presets and exit")
    parser.add_argument(
        "--output", metavar="DIR", help="output folder (default: ./compare_out/<scenario name>)"
    )
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="replace the files of an earlier comparison in the output folder",
    )
    parser.add_argument("--workers", type=int, help="parallel workers (default: one per CPU)")
    parser.add_argument(
        "--batch-size",
        type=int,
        default=DEFAULT_BATCH_SIZE,
        metavar="N",
        help="most runs simulated together in one world (vector env, observer, controller; "
        f"default {DEFAULT_BATCH_SIZE}); 1: every run in a world of its own (the same rows)",
    )
    parser.add_argument(
        "--backend",
        choices=BACKENDS,
        default=DEFAULT_BACKEND,
        help="local processes (default) or Ray",
    )
    parser.add_argument(
        "--seeds", type=int, nargs="+", metavar="SEED", help="override the scenario's seeds"
    )
    parser.add_argument(
        "--duration", type=float, metavar="SECONDS", help="override the simulated time per run"
    )
    parser.add_argument(
        "--quick",
        action="store_true",
        help=f"a fast look at the grid: first seed only, at most {QUICK_DURATION:g} s per run, "
        "each sweep thinned to its farthest magnitude on each side of the nominal "
        "(--seeds/--duration apply after it)",
    )
    parser.add_argument(
        "--physics-dt",
        type=float,
        metavar="SECONDS",
        help=f"override the scenario's physics step (default {COMPARISON_PHYSICS_DT:g} s)",
    )
    parser.add_argument(
        "--policy",
        nargs="+",
        metavar="RUN",
        default=[],
        help="training run folder(s) (elastic-gym train) to compare as controllers",
    )
    parser.add_argument("--no-plots", action="store_true", help="do not write PNG figures")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.set_defaults(handler=run_compare)


def run_compare(args: argparse.Namespace) -> int:
    from elastic_gym.evaluation import compare, load_preset, load_scenario

    if args.list_presets:
        print("\n".join(list_presets()))
        return 0
    scenario = load_scenario(args.config) if args.config else load_preset(args.preset)
    if args.quick:
        scenario = scenario.quick()
    scenario = scenario.with_overrides(
        seeds=args.seeds, duration=args.duration, physics_dt=args.physics_dt
    )
    if args.policy:
        require_rl_extra("compare --policy")
    for run in args.policy:
        scenario = with_trained_policy(scenario, run)
    result = compare(
        scenario,
        output_dir=args.output,
        workers=args.workers,
        backend=args.backend,
        progress=not args.no_progress,
        plots=not args.no_plots,
        overwrite=args.overwrite,
        batch_size=args.batch_size,
    )
    if result.failed:
        sys.stderr.write(
            f"elastic-gym compare: {result.failed} of {len(result.runs)} runs failed "
            f"(status column of {result.output_dir / 'runs.csv'})\n"
        )
        return 1
    return 0


def with_trained_policy(scenario, run_dir: str):
    """The scenario with a ``trained-policy`` controller for a run folder, paired with the
    state source it was trained on (an observer, ``true`` or raw ``sensors``; added to the
    scenario if missing)."""
    from pathlib import Path

    from elastic_gym.evaluation.scenario import ControllerEntry, SourceEntry
    from elastic_gym.training.run_folder import RunFolder

    config = RunFolder(run_dir).read_config()
    other_envs = sorted({e.id for e in scenario.envs} - {config.env_id})
    if other_envs:
        raise ValueError(
            f"--policy {run_dir}: trained on {config.env_id}, but the scenario "
            f"also has {other_envs}"
        )
    sources = list(scenario.state_sources)
    source = next(
        (s for s in sources if s.name == config.state and s.options == config.observer_options),
        None,
    )
    if source is None:
        source = SourceEntry.model_validate(
            {
                "name": config.state,
                "label": f"{config.state}-policy",
                "options": config.observer_options,
            }
        )
        sources.append(source)
    controller = ControllerEntry.model_validate(
        {
            "name": "trained-policy",
            "label": f"policy:{Path(run_dir).name}",
            "options": {"run": str(Path(run_dir).resolve())},
            "sources": [source.label],
        }
    )
    return scenario.with_overrides(
        controllers=(*scenario.controllers, controller), state_sources=tuple(sources)
    )


def add_train_parser(subcommands: argparse._SubParsersAction) -> None:
    from elastic_gym.observers.registry import state_sources
    from elastic_gym.training.actions import KINDS
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
    parser.set_defaults(handler=run_train)


class _Mapping(RootModel[dict[str, Any]]):
    """A YAML mapping given on the command line (empty: ``{}``)."""


def _yaml_mapping(text: str, option: str) -> dict:
    from elastic_gym.yaml_io import load_yaml

    return validated(_Mapping, load_yaml(text, option), prefix=option).root


def _action_fields(args: argparse.Namespace) -> dict:
    """ActionConfig fields from --action, --action-options, --residual, --residual-scale."""
    fields = _yaml_mapping(args.action_options, "--action-options")
    if args.action is not None:
        fields["kind"] = args.action
    if args.residual is not None:
        fields.update(kind="residual", residual=args.residual)
    if args.residual_scale is not None:
        fields["residual_scale"] = args.residual_scale
    return fields


def require_rl_extra(command: str) -> None:
    """Refuse an RL command clearly where stable-baselines3 / torch are not installed
    (``pip install .`` leaves them out; they come with the ``rl`` extra)."""
    try:
        import stable_baselines3  # noqa: F401
        import torch  # noqa: F401
    except ImportError as exc:
        raise RuntimeError(
            f"{command} needs the 'rl' extra ({exc}): pip install "
            "'elastic-gym[rl]' (CPU torch first: pip install torch --index-url "
            "https://download.pytorch.org/whl/cpu)"
        ) from None


def train_run_base(args: argparse.Namespace) -> str:
    """The run folder of ``elastic-gym train`` (``--out`` or its default): the run's, or
    the parent of one ``seed<k>`` folder per seed when several."""
    name = args.env.split("/")[-1]
    return args.out or f"runs/{args.algo}-{name}-{args.state}" + (
        f"-residual-{args.residual}" if args.residual else ""
    )


def train_configs(args: argparse.Namespace) -> list[TrainConfig]:
    """The :class:`~elastic_gym.training.TrainConfig` of each seed of parsed
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
            observation=_yaml_mapping(args.observation, "--observation"),
            frame_stack=args.frame_stack,
            env_kwargs=_yaml_mapping(args.env_kwargs, "--env-kwargs"),
            observer_options=_yaml_mapping(args.observer_options, "--observer-options"),
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

    require_rl_extra("elastic-gym train")
    from elastic_gym.training import RunFolder, train, train_many

    RunFolder(train_run_base(args)).check(args.overwrite)
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


def add_benchmark_parser(subcommands: argparse._SubParsersAction) -> None:
    parser = subcommands.add_parser(
        "benchmark",
        help="score a controller + state source, a user's class or a trained policy on the "
        "elastic-gym benchmark suite; rebuild the leaderboard",
        description="Run the versioned benchmark suite (elastic-gym-v1: tasks x perturbation "
        "categories x robots x 10 published seeds) with one entry and write its scorecard "
        "(JSON, markdown, PNG); or rebuild docs/leaderboard.md from scorecard files.",
    )
    parser.add_argument("--controller", metavar="NAME", help="controller registry name")
    parser.add_argument(
        "--class",
        dest="cls",
        metavar="MODULE:CLASS",
        help="a user's Controller subclass (with --source, default true) or Observer "
        "subclass (with --controller, default feedforward-state-feedback)",
    )
    parser.add_argument(
        "--source",
        metavar="SOURCE",
        help="state source: 'true' (oracle), an observer name, 'sensors' (raw sensors, for "
        "a policy) or an Observer 'module:Class'",
    )
    parser.add_argument("--run", metavar="RUN", help="a run folder written by elastic-gym train")
    parser.add_argument(
        "--leaderboard",
        action="store_true",
        help="rebuild docs/leaderboard.md (+ CSV, PNG) from docs/leaderboard/scorecards/*.json",
    )
    parser.add_argument(
        "--options", default="{}", metavar="YAML", help="controller options (YAML mapping)"
    )
    parser.add_argument(
        "--source-options", default="{}", metavar="YAML", help="observer options (YAML mapping)"
    )
    parser.add_argument("--label", help="the entry's name on the leaderboard")
    parser.add_argument(
        "--suite", default="elastic-gym-v1", help="shipped suite name or suite YAML file"
    )
    parser.add_argument(
        "--robot", nargs="+", metavar="ROBOT", help="only these robots of the suite"
    )
    parser.add_argument("--output", metavar="DIR", help="default: ./benchmark_out/<label>")
    parser.add_argument("--overwrite", action="store_true", help="replace an earlier scorecard")
    parser.add_argument("--workers", type=int, help="parallel workers (default: one per CPU)")
    parser.add_argument("--backend", choices=BACKENDS, default=DEFAULT_BACKEND)
    parser.add_argument(
        "--scorecards",
        metavar="DIR",
        default="docs/leaderboard/scorecards",
        help="with --leaderboard: the scorecard folder",
    )
    parser.add_argument(
        "--page", metavar="MD", default="docs/leaderboard.md", help="with --leaderboard"
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.set_defaults(handler=run_benchmark_command)


def benchmark_arguments(args: argparse.Namespace) -> EntryArguments:
    """The entry options of ``elastic-gym benchmark``, validated together."""
    from elastic_gym.benchmark.entry import EntryArguments

    fields = {key: getattr(args, key) for key in ("controller", "source", "run", "label")}
    fields |= {"class": args.cls, "leaderboard": args.leaderboard}
    fields |= {
        key: _yaml_mapping(getattr(args, key), f"--{key.replace('_', '-')}")
        for key in ("options", "source_options")
    }
    return validated(EntryArguments, fields, prefix="entry")


def run_benchmark_command(args: argparse.Namespace) -> int:
    from elastic_gym.benchmark import rebuild_leaderboard, run_benchmark

    arguments = benchmark_arguments(args)
    if arguments.leaderboard:
        files = rebuild_leaderboard(args.scorecards, args.page, args.suite)
        print("written: " + ", ".join(str(f) for f in files))
        return 0
    if args.run:
        require_rl_extra("benchmark --run")
    run_benchmark(
        arguments.entry(),
        suite=args.suite,
        robots=args.robot,
        output_dir=args.output,
        workers=args.workers,
        backend=args.backend,
        progress=not args.no_progress,
        overwrite=args.overwrite,
    )
    return 0


def add_schema_parser(subcommands: argparse._SubParsersAction) -> None:
    from elastic_gym.schemas import SCHEMA_DIR, schema_models

    parser = subcommands.add_parser(
        "schema",
        help="print the JSON Schema of a YAML file kind (scenario, train, ...)",
        description="Print the JSON Schema of a kind of YAML file: 'scenario' (presets, "
        "compare --config), 'train' (hyper-parameter files). YAML editors complete and "
        "check a file whose first line is '# yaml-language-server: $schema=<schema.json>'.",
    )
    which = parser.add_mutually_exclusive_group(required=True)
    which.add_argument("name", nargs="?", choices=sorted(schema_models()))
    which.add_argument(
        "--write",
        action="store_true",
        help=f"regenerate the shipped schema files in {SCHEMA_DIR} instead",
    )
    parser.set_defaults(handler=run_schema)


def run_schema(args: argparse.Namespace) -> int:
    from elastic_gym.schemas import schema_text, write_schemas

    if args.write:
        print("\n".join(str(path) for path in write_schemas()))
    else:
        sys.stdout.write(schema_text(args.name))
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="elastic-gym",
        description="Elastic-joint robot arms: compare observers, controllers and RL policies.",
    )
    subcommands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    add_compare_parser(subcommands)
    add_train_parser(subcommands)
    add_benchmark_parser(subcommands)
    add_schema_parser(subcommands)
    return parser


USAGE_ERRORS = (ValueError, FileNotFoundError, FileExistsError, NotADirectoryError, PermissionError)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the console script; returns the exit code.

    2: invalid input (nothing was run); 1: a job could not run, a comparison's run failed
    (its row says why; the others were run), or results could not be written (a full
    disk: the message says what was kept); 130 / 143: interrupted by SIGINT / SIGTERM
    (the message says what was kept on disk).
    """
    parser = build_parser()
    args = parser.parse_args(argv)
    prefix = f"elastic-gym {args.command}"
    try:
        with interrupts_raised():
            return args.handler(args)
    except KeyboardInterrupt as exc:
        interrupted = exc if isinstance(exc, Interrupted) else Interrupted.of(exc, "")
        sys.stderr.write(f"{prefix}: {interrupted}\n")
        return interrupted.exit_code
    except USAGE_ERRORS as exc:
        parser.exit(2, f"{prefix}: error: {exc}\n")
    except (RuntimeError, OSError) as exc:  # OSError: e.g. a disk that filled while running
        sys.stderr.write(f"{prefix}: error: {exc}\n")
        return 1


if __name__ == "__main__":
    sys.exit(main())
