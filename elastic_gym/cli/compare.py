"""``elastic-gym compare``: a comparison grid (the built-in default, a shipped ``--preset``
or a ``--config`` YAML file) run in parallel; ``--policy RUN`` adds trained policies as
controllers."""

from __future__ import annotations

import argparse
import sys

from elastic_gym.cli.common import require_rl_extra
from elastic_gym.envs.config import INTEGRATORS
from elastic_gym.evaluation.groups import DEFAULT_BATCH_SIZE
from elastic_gym.evaluation.presets import DEFAULT_PRESET, list_presets
from elastic_gym.evaluation.scenario import (
    COMPARISON_INTEGRATOR,
    COMPARISON_PHYSICS_DT,
    QUICK_DURATION,
)
from elastic_gym.runtime.parallel import BACKENDS, DEFAULT_BACKEND


def add_parser(subcommands: argparse._SubParsersAction) -> None:
    from elastic_gym.policy.loading import TRUST_HELP

    parser = subcommands.add_parser(
        "compare",
        help="compare controllers x state sources (true state, observers) on envs",
        description="Run a comparison grid in parallel and write a metrics table (CSV, "
        "markdown) and plots. Without arguments: the built-in default grid on "
        "TwoLinkElastic (about 35 s of CPU on the RK4: some 20 s on 2 free cores).",
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
        help=(
            "override the scenario's physics step (default: the control period for the RK4, "
            f"{COMPARISON_PHYSICS_DT:g} s for PyBullet's integrator)"
        ),
    )
    parser.add_argument(
        "--integrator",
        choices=INTEGRATORS,
        help=f"override the scenario's integrator (default {COMPARISON_INTEGRATOR})",
    )
    parser.add_argument(
        "--policy",
        nargs="+",
        metavar="POLICY",
        default=[],
        help="exported policy folder(s) (elastic-gym export) to compare as controllers, or "
        "training run folder(s) with --trust-pickle",
    )
    parser.add_argument(
        "--model",
        nargs="+",
        metavar="FILE",
        default=[],
        help="identified model file(s) (elastic-gym identify), one per robot: the model the "
        "controllers and observers build on instead of the nominal one (model errors apply "
        "on top; the simulated plant stays what it is)",
    )
    parser.add_argument("--trust-pickle", action="store_true", help=TRUST_HELP)
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
        seeds=args.seeds,
        duration=args.duration,
        physics_dt=args.physics_dt,
        integrator=args.integrator,
    )
    if args.model:
        scenario = scenario.with_overrides(models=tuple(args.model))
    for folder in args.policy:
        scenario = with_trained_policy(scenario, folder, args.trust_pickle)
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


def with_trained_policy(scenario, folder: str, trust_pickle: bool = False):
    """The scenario with a ``trained-policy`` controller for a policy folder (exported, or
    a training run folder with ``trust_pickle``), paired with the state source it was
    trained on (an observer, ``true`` or raw ``sensors``; added to the scenario if
    missing)."""
    from pathlib import Path

    from elastic_gym.evaluation.scenario import ControllerEntry, SourceEntry
    from elastic_gym.policy.loading import is_exported, is_run_folder, read_spec, untrusted

    if not is_exported(folder) and is_run_folder(folder):
        if not trust_pickle:
            raise untrusted(folder)
        require_rl_extra("compare --policy RUN")
    spec = read_spec(folder)
    other_envs = sorted({e.id for e in scenario.envs} - {spec.env_id})
    if other_envs:
        raise ValueError(
            f"--policy {folder}: trained on {spec.env_id}, but the scenario also has {other_envs}"
        )
    sources = list(scenario.state_sources)
    source = next(
        (s for s in sources if s.name == spec.state and s.options == spec.observer_options),
        None,
    )
    if source is None:
        source = SourceEntry.model_validate(
            {
                "name": spec.state,
                "label": f"{spec.state}-policy",
                "options": spec.observer_options,
            }
        )
        sources.append(source)
    options: dict[str, object] = {"policy": str(Path(folder).resolve())}
    options |= {"trust_pickle": True} if trust_pickle else {}
    controller = ControllerEntry.model_validate(
        {
            "name": "trained-policy",
            "label": f"policy:{Path(folder).name}",
            "options": options,
            "sources": [source.label],
        }
    )
    return scenario.with_overrides(
        controllers=(*scenario.controllers, controller), state_sources=tuple(sources)
    )
