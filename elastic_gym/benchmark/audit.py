"""A card checked against its suite: nothing it states about itself is taken on trust.

`check_card` refuses (``ValueError`` naming the card, the field and both values) a card
of another suite, with other seeds, a robot the suite lacks, a missing or unknown cell or
category, an entry its own command does not score (`command_mismatches`), or stated scores
that its own per-episode records do not give: every episode is scored again with the
suite's tolerances and every score recomputed (`compute_scores`); stated and recomputed
values may differ by `SCORE_TOLERANCE` (rounding), not more.

What the card is, is derived too: an **oracle reference** when its state source reads any
ground truth (the registry's privileged items of a named source, or those the card lists
for a ``module:Class`` source, which is not imported here), whatever its ``oracle`` field
says; a **subset** card when it covers only some of the suite's robots.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from elastic_gym.benchmark.card import EntryRecord, Scorecard
from elastic_gym.benchmark.command import command_mismatches
from elastic_gym.benchmark.scoring import (
    OVERALL,
    PRECISION,
    Episode,
    Scores,
    compute_scores,
    episode_checks,
)
from elastic_gym.benchmark.suite import SuiteConfig

SCORE_TOLERANCE = 1e-12
SHOWN = 5  # names listed in a message before "..."


@dataclass(frozen=True)
class CheckedCard:
    """A card that passed `check_card`, with what was derived from it."""

    card: Scorecard
    where: str  # the file (or name) it came from
    oracle: bool  # reads ground truth (derived)
    subset: bool  # some of the suite's robots only
    privileged: tuple[str, ...]  # the ground truth its source reads (derived)
    episodes: tuple[Episode, ...]
    scores: Scores  # recomputed: equal to the stated ones within SCORE_TOLERANCE
    notes: tuple[str, ...] = ()  # what was derived against the card's own word

    @property
    def label(self) -> str:
        return self.card.label


def _listed(names: Sequence[object]) -> str:
    return str(names[:SHOWN])[:-1] + (", ...]" if len(names) > SHOWN else "]")


def _identity(suite: SuiteConfig | Scorecard) -> tuple[str, int, str]:
    ref = suite.suite if isinstance(suite, Scorecard) else suite
    return ref.name, ref.version, ref.hash


def _shown(name: str, version: int, hash_: str) -> str:
    return f"{name} version {version} (hash {hash_[:12]})"


def card_episodes(card: Scorecard, suite: SuiteConfig) -> list[Episode]:
    """The card's episodes in suite order, each checked again against its cell's
    tolerances (cells the card lacks are skipped: `check_card` refuses such a card)."""
    cells = {c.id: c for c in suite.cells}
    rows: dict[str, list] = {}
    for cell_id, seed, status, metrics in card.episode_rows():
        rows.setdefault(cell_id, []).append((seed, status, metrics))
    episodes = []
    for cell_id, cell in cells.items():
        for seed, status, metrics in rows.get(cell_id, ()):
            checks = episode_checks(cell, status, metrics)
            episodes.append(Episode(cell_id, seed, status, metrics, checks))
    return episodes


def check_card(card: Scorecard, suite: SuiteConfig, where: str = "scorecard") -> CheckedCard:
    """The card checked against ``suite`` (module docstring), or ``ValueError`` starting
    with ``where``."""
    if _identity(card) != _identity(suite):
        changed = " (the suite changed)" if card.suite.name == suite.name else ""
        raise ValueError(
            f"{where}: suite: scorecard of {_shown(*_identity(card))}, not of "
            f"{_shown(*_identity(suite))}{changed}: re-run the entry on this suite"
        )
    problems = _coverage(card, suite)
    if problems:
        raise ValueError(f"{where}: " + "; ".join(problems))
    episodes = card_episodes(card, suite)
    scores = compute_scores(suite, episodes)
    differences = score_differences(card, scores)
    if differences:
        more = f" (and {len(differences) - 3} more)" if len(differences) > 3 else ""
        raise ValueError(
            f"{where}: stated scores differ from those its episodes give: "
            + "; ".join(differences[:3])
            + more
        )
    privileged = derived_privileged(card.entry, where)
    try:
        contradictions = command_mismatches(card)
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None
    if contradictions:
        raise ValueError(f"{where}: " + "; ".join(contradictions))
    oracle = card.entry.oracle or bool(privileged)
    notes: tuple[str, ...] = ()
    if oracle and not card.entry.oracle:
        notes = (
            f"{where}: states oracle: false, but its source {card.entry.source!r} reads "
            f"{list(privileged)}: listed as an oracle reference",
        )
    subset = set(card.robots) != set(suite.robots)
    return CheckedCard(card, where, oracle, subset, privileged, tuple(episodes), scores, notes)


def _coverage(card: Scorecard, suite: SuiteConfig) -> list[str]:
    """Seeds, robots, cells and score names the card must share with the suite."""
    problems = []
    if card.seeds != list(suite.seeds):
        problems.append(f"seeds: {_listed(card.seeds)} are not the suite's {_listed(suite.seeds)}")
    unknown = [r for r in card.robots if r not in suite.robots]
    if unknown:
        return [*problems, f"robots: unknown robot(s) {unknown}; valid: {list(suite.robots)}"]
    expected = [c.id for c in suite.cells if c.robot in card.robots]
    missing = [c for c in expected if c not in card.cells]
    extra = [c for c in card.cells if c not in expected]
    if missing:
        problems.append(
            f"cells: {len(missing)} of the suite's {len(expected)} cells of robots "
            f"{card.robots} missing: {_listed(missing)}"
        )
    if extra:
        problems.append(f"cells: unknown cell(s) {_listed(extra)}")
    names = list(suite.categories)
    problems += _names("scores.categories", list(card.scores.categories), names)
    problems += _names("scores.per_robot", list(card.scores.per_robot), card.robots)
    for robot, values in card.scores.per_robot.items():
        problems += _names(f"scores.per_robot.{robot}", list(values), [*names, PRECISION, OVERALL])
    return problems


def _names(field: str, given: list[str], wanted: list[str]) -> list[str]:
    missing = [n for n in wanted if n not in given]
    unknown = [n for n in given if n not in wanted]
    return [f"{field}: missing {missing}"] * bool(missing) + [
        f"{field}: unknown {unknown}; valid: {wanted}"
    ] * bool(unknown)


def score_differences(card: Scorecard, scores: Scores) -> list[str]:
    """``field: the card states X, its episodes give Y`` for every stated score that differs
    from the recomputed one by more than `SCORE_TOLERANCE` (``null`` stands for NaN)."""
    stated = card.scores
    pairs: list[tuple[str, float | None, float]] = [
        ("scores.overall", stated.overall, scores.overall),
        ("scores.precision", stated.precision, scores.precision),
        *(
            (f"scores.categories.{name}", value, scores.categories[name])
            for name, value in stated.categories.items()
        ),
        *(
            (f"scores.per_robot.{robot}.{name}", value, scores.per_robot[robot][name])
            for robot, values in stated.per_robot.items()
            for name, value in values.items()
        ),
        ("scores.episodes", stated.episodes, scores.episodes),
        ("scores.passed", stated.passed, scores.passed),
    ]
    differences = []
    for field, given, recomputed in pairs:
        if not _same(given, recomputed):
            shown = _text(given), _text(recomputed)
            if shown[0] == shown[1]:
                shown = repr(given), repr(recomputed)
            differences.append(f"{field}: the card states {shown[0]}, its episodes give {shown[1]}")
    return differences


def _same(given: float | None, recomputed: float) -> bool:
    if given is None or not math.isfinite(recomputed):
        return given is None and not math.isfinite(recomputed)
    return abs(given - recomputed) <= SCORE_TOLERANCE


def _text(value: float | None) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "null"
    return f"{value:.6g}" if isinstance(value, float) else str(value)


def derived_privileged(entry: EntryRecord, where: str = "scorecard") -> tuple[str, ...]:
    """The ground-truth items the entry's state source reads: the registry's for a named
    source (``ValueError`` for a name the registry lacks), else those the card lists."""
    from elastic_gym.benchmark.entry import privileged_items
    from elastic_gym.evaluation.scenario import SourceEntry
    from elastic_gym.observers.registry import source_class

    listed = tuple(entry.privileged)
    if ":" in entry.source:  # a user's class: not imported to read a card
        return listed
    try:
        source_class(entry.source)  # a registry name: ValueError naming the valid ones
        named = privileged_items(SourceEntry(name=entry.source, label=entry.source))
    except ValueError as exc:
        raise ValueError(f"{where}: entry.source: {exc}") from None
    return tuple(dict.fromkeys([*named, *listed]))
