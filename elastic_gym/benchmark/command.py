"""The command line of an entry: the `elastic-gym benchmark` options that say what is
scored and on which suite, the line a card records, and the entry read back from a line.

`add_entry_options` defines the options once, for the console script and for
`parse_command`; `entry_command` writes the line that reproduces an entry (``None`` when
no line can: a Python callable or other object among the options). Options are written in
YAML flow style, which reads back to the same values (checked).
"""

from __future__ import annotations

import argparse
import math
import shlex
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml
from pydantic import RootModel

from elastic_gym.benchmark.entry import Entry, EntryArguments, described
from elastic_gym.benchmark.suite import DEFAULT_SUITE
from elastic_gym.validation import validated
from elastic_gym.yaml_io import load_yaml

if TYPE_CHECKING:
    from elastic_gym.benchmark.card import Scorecard

PROGRAM = ("elastic-gym", "benchmark")


def add_entry_options(parser: argparse.ArgumentParser) -> None:
    """The options naming an entry, its label, the suite and the robots (``--suite`` has
    no default here: `DEFAULT_SUITE` where none is given)."""
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
    from elastic_gym.policy.loading import TRUST_HELP

    parser.add_argument(
        "--run",
        metavar="POLICY",
        help="an exported policy folder (elastic-gym export), or a run folder written by "
        "elastic-gym train with --trust-pickle",
    )
    parser.add_argument("--trust-pickle", action="store_true", help=TRUST_HELP)
    parser.add_argument(
        "--options", default="{}", metavar="YAML", help="controller options (YAML mapping)"
    )
    parser.add_argument(
        "--source-options", default="{}", metavar="YAML", help="observer options (YAML mapping)"
    )
    parser.add_argument(
        "--label", help="the entry's name on the leaderboard (at most 100 characters)"
    )
    parser.add_argument(
        "--suite",
        help=f"shipped suite name or suite YAML file (default: {DEFAULT_SUITE}; with "
        "--verify: the suite the card's command names)",
    )
    parser.add_argument(
        "--robot", nargs="+", metavar="ROBOT", help="only these robots of the suite"
    )
    parser.add_argument(
        "--model",
        nargs="+",
        metavar="FILE",
        help="identified model file(s) (elastic-gym identify), one per robot: the model the "
        "entry's controller and observer build on for that robot's cells instead of the "
        "nominal one (the simulated plants stay what they are)",
    )


class _Mapping(RootModel[dict[str, Any]]):
    """A YAML mapping given as an option's value (empty: ``{}``)."""


def yaml_option(text: str, option: str) -> dict:
    """A YAML mapping given as an option's value (``ValueError`` naming the option)."""
    return validated(_Mapping, load_yaml(text, option), prefix=option).root


def entry_arguments(args: argparse.Namespace, **modes: Any) -> EntryArguments:
    """The entry options of parsed ``args`` (and the console script's other modes, e.g.
    ``leaderboard=True``), validated together."""
    keys = ("controller", "source", "run", "trust_pickle", "label", "model")
    fields = {key: getattr(args, key) for key in keys}
    fields |= {"class": args.cls, **modes}
    fields |= {
        key: yaml_option(getattr(args, key), f"--{key.replace('_', '-')}")
        for key in ("options", "source_options")
    }
    return validated(EntryArguments, fields, prefix="entry")


def _flow(options: dict) -> str | None:
    """``options`` as a YAML flow mapping that reads back equal, else ``None``."""
    if not _plain(options):
        return None
    text = yaml.safe_dump(options, default_flow_style=True, width=math.inf).strip()
    try:
        return text if load_yaml(text, "options") == options else None
    except ValueError:
        return None


def _plain(value: Any) -> bool:
    if isinstance(value, dict):
        return all(isinstance(k, str) and _plain(v) for k, v in value.items())
    if isinstance(value, list):
        return all(_plain(v) for v in value)
    return value is None or isinstance(value, (bool, int, float, str))


def entry_command(entry: Entry, suite: str, robots: list[str] | None = None) -> str | None:
    """The `elastic-gym benchmark` line that scores ``entry`` on ``suite`` (a shipped
    suite's name or a file) and ``robots`` (default: all), or ``None`` if none can."""
    words = [*PROGRAM]
    if entry.run is not None:
        if entry.best:
            return None  # the console script scores a run's final model
        words += ["--run", entry.run, *(["--trust-pickle"] if entry.trust_pickle else [])]
    else:
        controller, source = described(entry.controller), described(entry.source)
        options, source_options = _flow(entry.options), _flow(entry.source_options)
        if controller is None or source is None or options is None or source_options is None:
            return None
        words += ["--controller", controller, "--source", source]
        words += ["--options", options] if entry.options else []
        words += ["--source-options", source_options] if entry.source_options else []
    words += ["--label", entry.name, "--suite", suite]
    words += ["--robot", *robots] if robots else []
    words += ["--model", *entry.models] if entry.models else []
    return shlex.join(words)


@dataclass(frozen=True)
class Command:
    """An entry read back from its command line, with the suite and robots it names."""

    entry: dict[str, Any]
    suite: str
    robots: list[str] | None


class _Parser(argparse.ArgumentParser):
    def error(self, message: str):
        raise ValueError(message)


def parse_command(command: str, where: str = "command") -> Command:
    """The entry of an `entry_command` line (``ValueError`` starting with ``where`` for
    anything else: another program, options that do not name an entry)."""
    try:
        words = shlex.split(command)
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None
    if tuple(words[:2]) != PROGRAM:
        raise ValueError(f"{where}: not an `{' '.join(PROGRAM)}` command: {command!r}")
    parser = _Parser(prog=" ".join(PROGRAM), add_help=False)
    add_entry_options(parser)
    try:
        args = parser.parse_args(words[2:])
        arguments = entry_arguments(args)
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None
    if args.suite is None:
        raise ValueError(f"{where}: names no --suite")
    return Command(arguments.entry(), args.suite, args.robot)


def command_mismatches(card: Scorecard) -> list[str]:
    """Where the card's own command scores another entry than the card's ``entry`` says
    (controller, source, their options and model files; a trained policy's run as given) or
    names another shipped suite (a suite file is not compared): ``field: value, but the
    card's command names --option value`` per difference. The label is not compared (a card
    may be shown under another name). ``ValueError`` for a command that is not an entry's
    line."""
    if card.command is None:
        return []
    command = parse_command(card.command)
    said, entry = command.entry, card.entry
    pairs: list[tuple[str, Any, str, Any]] = []
    if "run" in said:  # a policy folder, as given (the entry's source is the policy's)
        for key in ("policy", "run"):  # the controller's option (`run` in older cards)
            if key in entry.controller_options:
                given = entry.controller_options[key]
                pairs.append(("--run", said["run"], f"controller_options.{key}", given))
                break
    else:
        pairs += [
            ("--controller", said.get("controller"), "controller", entry.controller),
            ("--options", said.get("options", {}), "controller_options", entry.controller_options),
            ("--source", said.get("source"), "source", entry.source),
            (
                "--source-options",
                said.get("source_options", {}),
                "source_options",
                entry.source_options,
            ),
        ]
    pairs.append(("--model", list(said.get("models", ())), "models", entry.models))
    problems = [
        f"entry.{field}: {value!r}, but the card's command names {option} {wanted!r}"
        for option, wanted, field, value in pairs
        if value != wanted
    ]
    named = command.suite
    if (
        "/" not in named
        and Path(named).suffix not in (".yaml", ".yml")
        and named != card.suite.name
    ):
        problems.append(f"suite: {card.suite.name}, but the card's command names --suite {named!r}")
    return problems
