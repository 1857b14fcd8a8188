"""A scorecard verified by running its command again: `verify_card`.

The card's ``command`` (`elastic_gym.benchmark.command`) is read back into an entry, a
suite and robots, scored again by `elastic_gym.benchmark.run.run_benchmark`, and the new
card compared with the old one bit for bit in everything but ``provenance`` (when, where
and how long) and the command it ran: the suite, the entry's record, robots and seeds, every
episode's status and metric, every score. Floats are equal when their bits are (``0.0``
and ``-0.0`` differ). The old card is first checked against the suite like any leaderboard
card (`elastic_gym.benchmark.audit.check_card`).

Bit for bit holds on a machine like the card's. Elsewhere the floats' last bits differ (the
math library's and BLAS's kernels per CPU) and the closed loops carry them on: the card is
then reproduced when only episodes' metrics (one may be null on one side) and scores
differ, every status is the card's and every score within `SCORE_TOLERANCE` of it.
"""

from __future__ import annotations

import math
import struct
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from elastic_gym.benchmark.audit import check_card
from elastic_gym.benchmark.card import METRICS, Scorecard, read_scorecard
from elastic_gym.benchmark.command import parse_command
from elastic_gym.benchmark.suite import load_suite
from elastic_gym.runtime.parallel import DEFAULT_BACKEND

SHOWN = 5  # differences listed in the report
SCORE_TOLERANCE = 1e-3
"""Largest difference of a score (each in [0, 1]) from the card's on another machine: a
tenth of the last digit the leaderboard shows."""


@dataclass
class Differences:
    """What `card_differences` found: how many values were compared, and each that
    differs (``field: card X, re-run Y``)."""

    compared: int = 0
    differences: list[str] = field(default_factory=list)
    only_metrics: bool = True
    """Whether every difference is an episode's metric or a score (a float), no status,
    count or record among them."""
    score_difference: float = 0.0
    """The largest absolute difference of a score (inf: a count of episodes differs)."""


@dataclass(kw_only=True)
class Verification(Differences):
    """The outcome: the differences of the re-run ``rerun`` from the card at ``card``."""

    card: Path
    rerun: Scorecard

    @property
    def exact(self) -> bool:
        """Reproduced bit for bit."""
        return not self.differences

    @property
    def reproduced(self) -> bool:
        """Bit for bit, or within `SCORE_TOLERANCE` with only metrics and scores differing
        (the module docstring)."""
        return self.exact or (self.only_metrics and self.score_difference <= SCORE_TOLERANCE)

    def text(self) -> str:
        """What a user reads: reproduced or not, and the first differences."""
        episodes = len(self.rerun.cells) * len(self.rerun.seeds)
        if self.exact:
            return (
                f"{self.card}: reproduced bit for bit: {episodes} episodes (status and "
                f"{len(METRICS)} metrics each), every score and the entry "
                f"({self.compared} values; wall-clock provenance not compared)"
            )
        listed = "; ".join(self.differences[:SHOWN])
        more = (
            f" (and {len(self.differences) - SHOWN} more)" if len(self.differences) > SHOWN else ""
        )
        counted = f"{len(self.differences)} of {self.compared} values differ: {listed}{more}"
        if self.reproduced:
            return (
                f"{self.card}: reproduced within {SCORE_TOLERANCE:g} of every score, not bit "
                f"for bit: every episode's status and the entry are the card's, the scores "
                f"differ by at most {self.score_difference:.1e} (floating point differs "
                f"between machines; bit for bit holds on one like the card's); {counted}"
            )
        return f"{self.card}: NOT reproduced: {counted}"


def same_bits(a: Any, b: Any) -> bool:
    """Equal values, floats by their bits (``None`` equals only ``None``)."""
    if isinstance(a, float) and isinstance(b, float):
        return struct.pack("<d", a) == struct.pack("<d", b)
    return type(a) is type(b) and a == b


def card_differences(card: Scorecard, rerun: Scorecard) -> Differences:
    """Every value of the two cards compared, ``provenance`` left out: how many, each that
    differs, whether all of those are episodes' metrics or scores, and the largest
    difference of a score."""
    found = Differences()

    def compare(name: str, a: Any, b: Any) -> None:
        found.compared += 1
        if same_bits(a, b):
            return
        found.differences.append(f"{name}: card {a!r}, re-run {b!r}")
        floats = isinstance(a, float) and isinstance(b, float)
        if name.startswith("scores."):
            found.only_metrics &= floats
            gap = abs(a - b) if floats else math.inf
            found.score_difference = max(found.score_difference, gap)
        else:
            found.only_metrics &= name.startswith("cells.") and ".status[seed" not in name

    old, new = card.model_dump(mode="json"), rerun.model_dump(mode="json")
    for key in ("format", "suite", "entry", "robots", "seeds"):
        compare(key, old[key], new[key])
    _compare_tree("scores", old["scores"], new["scores"], compare)
    missing = [c for c in old["cells"] if c not in new["cells"]]
    extra = [c for c in new["cells"] if c not in old["cells"]]
    for cell_id in missing:
        found.differences.append(f"cells.{cell_id}: in the card, not in the re-run")
    for cell_id in extra:
        found.differences.append(f"cells.{cell_id}: in the re-run, not in the card")
    found.only_metrics &= not (missing or extra)
    for cell_id, columns in old["cells"].items():
        if cell_id not in new["cells"]:
            continue
        for name, values in columns.items():
            others = new["cells"][cell_id][name]
            for i, seed in enumerate(card.seeds):
                other = others[i] if i < len(others) else "(none)"
                compare(f"cells.{cell_id}.{name}[seed {seed}]", values[i], other)
    return found


def _compare_tree(name: str, a: Any, b: Any, compare) -> None:
    if isinstance(a, dict) and isinstance(b, dict):
        for key in dict.fromkeys([*a, *b]):
            _compare_tree(f"{name}.{key}", a.get(key), b.get(key), compare)
    else:
        compare(name, a, b)


def verify_card(
    path: str | Path,
    suite: str | Path | None = None,
    output_dir: str | Path | None = None,
    workers: int | None = None,
    backend: str = DEFAULT_BACKEND,
    progress: bool = True,
    overwrite: bool = False,
) -> Verification:
    """Re-run the card at ``path`` by its command and compare (module docstring).

    ``suite`` replaces the suite the command names (a file of the same suite elsewhere);
    the re-run writes into ``output_dir`` (default: a temporary folder, removed).
    ``ValueError`` for a card that is invalid, fails its suite's checks, or has no command
    (a Python callable)."""
    from elastic_gym.benchmark.run import run_benchmark

    path = Path(path)
    card = read_scorecard(path)
    if card.command is None:
        raise ValueError(
            f"{path}: command: null: the card's entry is a Python object no command names, "
            "so no command reproduces it"
        )
    command = parse_command(card.command, f"{path}: command")
    suite_name = str(suite) if suite is not None else command.suite
    check_card(card, load_suite(suite_name), str(path))
    with tempfile.TemporaryDirectory(prefix="elastic-gym-verify-") as scratch:
        out = Path(output_dir) if output_dir is not None else Path(scratch) / "rerun"
        rerun = run_benchmark(
            command.entry,
            suite=suite_name,
            robots=command.robots,
            output_dir=out,
            workers=workers,
            backend=backend,
            progress=progress,
            overwrite=overwrite,
        )
    return Verification(card=path, rerun=rerun, **vars(card_differences(card, rerun)))
