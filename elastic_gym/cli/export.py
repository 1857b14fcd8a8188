"""``elastic-gym export``: a training run folder as an exported policy (an ONNX graph and
its manifest), loadable without unpickling anything."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_parser(subcommands: argparse._SubParsersAction) -> None:
    parser = subcommands.add_parser(
        "export",
        help="export a trained policy as an ONNX graph and a manifest (no pickle)",
        description="Export the deterministic actor of a training run folder (PPO or "
        "RecurrentPPO) as an ONNX graph with the observation normalization and the action "
        "clipping inside it, and a manifest (policy.json) of its observation layout, action "
        "meaning, policy rate, env, state source and provenance. The run's pickles are "
        "read as data (weights only; statistics through a restricted unpickler): exporting "
        "runs no code from the folder. compare --policy and benchmark --run load the "
        "exported folder through onnxruntime.",
    )
    parser.add_argument("run", metavar="RUN", help="a run folder written by elastic-gym train")
    parser.add_argument(
        "--output", metavar="DIR", help="the exported policy's folder (default: RUN-export)"
    )
    parser.add_argument(
        "--best", action="store_true", help="the learning curve's best model (best_model.zip)"
    )
    parser.add_argument(
        "--overwrite", action="store_true", help="replace an earlier export in the folder"
    )
    parser.set_defaults(handler=run_export)


def run_export(args: argparse.Namespace) -> int:
    from elastic_gym.cli.common import require_rl_extra

    require_rl_extra("export")
    from elastic_gym.training.export_run import export_run

    run = Path(args.run)
    output = Path(args.output) if args.output else run.with_name(f"{run.name}-export")
    manifest = export_run(run, output, best=args.best, overwrite=args.overwrite)
    print(
        f"exported {run} -> {output}/ ({manifest.env_id}, state {manifest.state!r}, "
        f"{manifest.observation.size} observation entries, {manifest.action.size} actions, "
        f"{manifest.policy_rate:g} Hz)"
    )
    return 0
