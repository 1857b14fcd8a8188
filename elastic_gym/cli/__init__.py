"""The ``elastic-gym`` console script (argparse subcommands).

Each subcommand is a module of this package with a function ``add_parser(subcommands)``
that adds its parser and sets ``handler`` (a function ``args -> exit code``);
`SUBCOMMANDS` lists them in the order ``--help`` shows. Defaults come from the
config models (``TrainConfig``, ``Scenario``), not from here.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from elastic_gym import __version__
from elastic_gym.cli import (
    benchmark,
    compare,
    export,
    identify,
    observe,
    precompile,
    record,
    schema,
    train,
)
from elastic_gym.runtime.parallel import Interrupted, interrupts_raised

SUBCOMMANDS = (compare, train, export, benchmark, record, identify, observe, schema, precompile)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="elastic-gym",
        description="Elastic-joint robot arms: compare observers, controllers and RL policies.",
    )
    parser.add_argument("--version", action="version", version=f"elastic-gym {__version__}")
    subcommands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for command in SUBCOMMANDS:
        command.add_parser(subcommands)
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
