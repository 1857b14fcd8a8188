"""The ``elastic-gym`` console script (argparse subcommands).

``elastic-gym compare`` runs a comparison grid (the built-in default, a shipped
``--preset`` or a ``--config`` YAML file) and prints its table. A subcommand is a
function ``add_<name>_parser(subcommands)`` that adds its parser and sets
``handler`` (a function ``args -> exit code``); :func:`build_parser` lists them.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from elastic_gym.evaluation.scenario import DEFAULT_PRESET, list_presets
from elastic_gym.parallel import BACKENDS


def add_compare_parser(subcommands: argparse._SubParsersAction) -> None:
    parser = subcommands.add_parser(
        "compare",
        help="compare controllers x state sources (true state, observers) on envs",
        description="Run a comparison grid in parallel and write a metrics table (CSV, "
        "markdown) and plots. Without arguments: the built-in default grid on "
        "TwoLinkElastic (about two minutes on 2 cores).",
    )
    source = parser.add_mutually_exclusive_group()
    source.add_argument("--preset", default=DEFAULT_PRESET,
                        help=f"shipped preset name (default: {DEFAULT_PRESET}); see --list-presets")
    source.add_argument("--config", metavar="YAML", help="scenario YAML file")
    source.add_argument("--list-presets", action="store_true", help="list presets and exit")
    parser.add_argument("--output", metavar="DIR",
                        help="output folder (default: ./compare_out/<scenario name>)")
    parser.add_argument("--workers", type=int, help="parallel workers (default: one per CPU)")
    parser.add_argument("--backend", choices=BACKENDS, default="process",
                        help="local processes (default) or Ray")
    parser.add_argument("--seeds", type=int, nargs="+", metavar="SEED",
                        help="override the scenario's seeds")
    parser.add_argument("--duration", type=float, metavar="SECONDS",
                        help="override the simulated time per run")
    parser.add_argument("--no-plots", action="store_true", help="do not write PNG figures")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.set_defaults(handler=run_compare)


def run_compare(args: argparse.Namespace) -> int:
    from elastic_gym.evaluation import compare, load_preset, load_scenario

    if args.list_presets:
        print("\n".join(list_presets()))
        return 0
    scenario = load_scenario(args.config) if args.config else load_preset(args.preset)
    scenario = scenario.with_overrides(seeds=args.seeds, duration=args.duration)
    compare(
        scenario, output_dir=args.output, workers=args.workers, backend=args.backend,
        progress=not args.no_progress, plots=not args.no_plots,
    )
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="elastic-gym",
        description="Elastic-joint robot arms: compare observers and controllers.",
    )
    subcommands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    add_compare_parser(subcommands)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the console script; returns the exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.handler(args)
    except (ValueError, FileNotFoundError) as exc:
        parser.exit(2, f"elastic-gym {args.command}: error: {exc}\n")


if __name__ == "__main__":
    sys.exit(main())
