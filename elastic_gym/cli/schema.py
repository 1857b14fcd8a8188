"""``elastic-gym schema``: the JSON Schema of a kind of YAML file."""

from __future__ import annotations

import argparse
import sys


def add_parser(subcommands: argparse._SubParsersAction) -> None:
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
