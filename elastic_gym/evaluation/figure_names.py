"""File names of a comparison's figures, checked before the first run.

Part of the report stage. Each scenario (env x axis values x model error) gets a figure
named after its labels ([`plot_file_name`][elastic_gym.evaluation.figure_names.plot_file_name]);
[`check_plot_names`][elastic_gym.evaluation.figure_names.check_plot_names] refuses, naming
the field, labels whose file names would be longer than a file system allows or would
coincide (one figure would overwrite another).
"""

from __future__ import annotations

import re
from collections.abc import Sequence

from elastic_gym.evaluation.grid import RunSpec
from elastic_gym.evaluation.output import MAX_NAME_BYTES
from elastic_gym.evaluation.scenario import IDENTITY_COLUMNS, Scenario, ScenarioError


def plot_file_name(group: Sequence) -> str:
    """File name of the figure of a group of runs: its labels joined by ``__``, every
    run of characters other than letters, digits, ``.``, ``+`` and ``-`` replaced by
    ``_``, and ``.png``."""
    stem = re.sub(r"[^A-Za-z0-9.+-]+", "_", "__".join(str(g) for g in group)).strip("_")
    return f"{stem}.png"


def check_plot_names(scenario: Scenario, runs: Sequence[RunSpec]) -> None:
    """Refuse labels whose figure file names are too long or coincide (module docstring)."""
    columns = [IDENTITY_COLUMNS[0], *scenario.axis_names, IDENTITY_COLUMNS[1]]
    fields = ["envs", *(f"axes.{name}" for name in scenario.axis_names), "model_errors"]
    seen: dict[str, tuple] = {}
    for group in dict.fromkeys(spec.group for spec in runs):
        name = plot_file_name(group)
        if len(name.encode()) > MAX_NAME_BYTES:
            longest = max(range(len(group)), key=lambda k: len(str(group[k])))
            raise ScenarioError(
                fields[longest],
                f"the labels {list(group)} give a figure file name of "
                f"{len(name.encode())} bytes (the limit is {MAX_NAME_BYTES}): shorten the "
                f"{columns[longest]} label {group[longest]!r}",
            )
        other = seen.setdefault(name, group)
        if other != group:
            differ = next(k for k in range(len(group)) if group[k] != other[k])
            raise ScenarioError(
                fields[differ],
                f"the {columns[differ]} labels {other[differ]!r} and "
                f"{group[differ]!r} give the same figure file name {name!r} (only letters, "
                "digits, '.', '+' and '-' are kept): make them differ in those",
            )
