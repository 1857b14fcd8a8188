"""``elastic-gym benchmark``: one entry's scorecard on the versioned suite, or the
leaderboard rebuilt from scorecards."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from elastic_gym.cli.common import require_rl_extra, yaml_mapping
from elastic_gym.runtime.parallel import BACKENDS, DEFAULT_BACKEND
from elastic_gym.validation import validated

if TYPE_CHECKING:
    from elastic_gym.benchmark.entry import EntryArguments


def add_parser(subcommands: argparse._SubParsersAction) -> None:
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
        key: yaml_mapping(getattr(args, key), f"--{key.replace('_', '-')}")
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
