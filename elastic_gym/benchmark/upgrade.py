"""Format 1 scorecards (every episode a mapping with its keys repeated) to format 2.

`upgrade_card` keeps what format 2 holds: the episodes of each cell in columns (the
metrics of `elastic_gym.benchmark.card.METRICS`; wall-clock ones such as
``sim_wall_ratio`` and the observers' diagnostics are dropped), the stated scores, the
entry (a run folder named by an absolute path is recorded relative to the current folder,
see `relative_run`), the command that reproduces it, and the provenance. The new card is
checked against the suite like any other (`elastic_gym.benchmark.audit.check_card`):
scores its episodes do not give are refused, not carried over.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from elastic_gym.benchmark.audit import check_card
from elastic_gym.benchmark.card import FORMAT, METRICS, Scorecard, parse_scorecard
from elastic_gym.benchmark.command import entry_command
from elastic_gym.benchmark.entry import Entry
from elastic_gym.benchmark.suite import SuiteConfig, list_suites, load_suite


def relative_run(path: str) -> str:
    """A run folder's path as a command from the current folder names it: relative when it
    lies in the current folder, or when its last parts name a folder there (the same
    checkout moved); else as given."""
    given = Path(path)
    if not given.is_absolute():
        return path
    try:
        return str(given.relative_to(Path.cwd()))
    except ValueError:
        pass
    for start in range(1, len(given.parts)):
        tail = Path(*given.parts[start:])
        if tail.is_dir():
            return str(tail)
    return path


def _command(entry: dict[str, Any], suite: str, robots: list[str], subset: bool) -> str | None:
    fields: dict[str, Any] = {"label": entry["label"]}
    if entry["kind"] == "run":
        options = entry["controller_options"]
        fields |= {"run": options["run"], "best": options.get("best", False)}
        return entry_command(Entry.model_construct(**_defaults(fields)), suite)
    fields |= {
        "controller": entry["controller"],
        "options": entry["controller_options"],
        "source": entry["source"],
        "source_options": entry["source_options"],
    }
    return entry_command(
        Entry.model_construct(**_defaults(fields)), suite, robots if subset else None
    )


def _defaults(fields: dict[str, Any]) -> dict[str, Any]:
    base: dict[str, Any] = {"controller": None, "options": {}, "source": "true"}
    return {**base, "source_options": {}, "run": None, "best": False, **fields}


def upgrade_card(data: dict[str, Any], suite: SuiteConfig, where: str = "scorecard") -> Scorecard:
    """The format-2 card of a format-1 card's JSON ``data`` (module docstring)."""
    if data.get("format") != 1:
        raise ValueError(f"{where}: format: {data.get('format')!r}, not a format 1 card")
    entry = dict(data["entry"])
    if entry.get("kind") == "run":
        options = dict(entry["controller_options"])
        options["run"] = relative_run(str(options["run"]))
        entry["controller_options"] = options
    seeds = list(suite.seeds)
    cells = {}
    for cell in data["cells"]:
        by_seed = {e["seed"]: e for e in cell["episodes"]}
        rows = [by_seed[s] for s in seeds if s in by_seed]
        cells[cell["id"]] = {
            "status": [e["status"] for e in rows],
            **{m: [e["metrics"].get(m) for e in rows] for m in METRICS},
        }
    shipped = suite.name in list_suites() and load_suite(suite.name).hash == suite.hash
    subset = set(data["robots"]) != set(suite.robots)
    package = data.get("package", {})
    card = {
        "format": FORMAT,
        "suite": data["suite"],
        "entry": entry,
        "command": _command(entry, suite.name, data["robots"], subset) if shipped else None,
        "robots": data["robots"],
        "seeds": seeds,
        "scores": data["scores"],
        "cells": cells,
        "provenance": {
            "package": package.get("version") or "unknown",
            "commit": package.get("commit"),
            "created": data["created"],
            "wall_time": data["wall_time"],
            "cpu_time": data.get("cpu_time"),
        },
    }
    upgraded = parse_scorecard(card, where)
    check_card(upgraded, suite, where)
    return upgraded


def upgrade_file(path: str | Path, suite: SuiteConfig | str | Path | None = None) -> Scorecard:
    """`upgrade_card` of a format-1 card file (its suite: ``suite`` or the shipped suite
    it names)."""
    path = Path(path)
    try:
        data = json.loads(path.read_bytes())
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path}: not a scorecard JSON file: {exc}") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path}: not a scorecard (a JSON object)")
    if not isinstance(suite, SuiteConfig):
        suite = load_suite(suite or data.get("suite", {}).get("name", ""))
    return upgrade_card(data, suite, str(path))
