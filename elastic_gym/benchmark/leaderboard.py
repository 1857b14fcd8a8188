"""The leaderboard: a table, a CSV and a figure rebuilt from scorecard JSON files, no re-run.

:func:`rebuild_leaderboard` reads every ``*.json`` of ``docs/leaderboard/scorecards/``
(:func:`~elastic_gym.benchmark.scorecard.read_scorecard` validates each), refuses a card of
another suite (name, version or hash different from the current suite's) or a duplicate
label, and writes ``docs/leaderboard.md``, ``docs/leaderboard/leaderboard.csv`` and
``docs/leaderboard/leaderboard.png``. Implementable entries and oracle references (entries
whose state source read the ground truth) are separate tables, each ranked by the overall
score; below them, for each score, the best implementable entry and its lead over the
next one, the notes of ``docs/leaderboard/notes.md``, and each task's tolerances beside the
spread the shipped entries measured.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence
from pathlib import Path

from elastic_gym.benchmark.scorecard import Scorecard, SuiteRef, fmt, read_scorecard, score_value
from elastic_gym.benchmark.scoring import OVERALL, PRECISION
from elastic_gym.benchmark.suite import DEFAULT_SUITE, SuiteConfig, load_suite

DOCS = Path("docs")
SCORECARD_DIR = DOCS / "leaderboard" / "scorecards"
PAGE = DOCS / "leaderboard.md"
NOTES = "notes.md"  # beside the scorecard folder: what the leaderboard shows, in words


def _identity(suite: SuiteRef | SuiteConfig) -> tuple[str, int, str]:
    """What a scorecard must share with the suite it is ranked on."""
    return suite.name, suite.version, suite.hash


def _shown(suite: SuiteRef | SuiteConfig) -> str:
    return f"{suite.name} version {suite.version} (hash {suite.hash[:12]})"


def load_cards(folder: Path, suite: SuiteConfig) -> list[Scorecard]:
    """The scorecards of ``folder`` (sorted by file name), all of ``suite``."""
    paths = sorted(Path(folder).glob("*.json"))
    if not paths:
        raise FileNotFoundError(f"no scorecard JSON file in {folder}")
    cards: list = []
    labels: dict[str, Path] = {}
    for path in paths:
        card = read_scorecard(path)
        if _identity(card.suite) != _identity(suite):
            changed = " (the suite changed)" if card.suite.name == suite.name else ""
            raise ValueError(
                f"{path}: scorecard of suite {_shown(card.suite)}, not of {_shown(suite)}"
                f"{changed}: re-run the entry on this suite"
            )
        if card.label in labels:
            raise ValueError(f"{path}: entry label {card.label!r} also in {labels[card.label]}")
        labels[card.label] = path
        cards.append(card)
    return cards


def _columns(suite: SuiteConfig) -> list[str]:
    return [OVERALL, PRECISION, *suite.categories]


def _ranked(cards: Sequence[Scorecard]) -> list[Scorecard]:
    return sorted(cards, key=lambda c: -(c.scores.overall or 0.0))


def _table(cards: Sequence[Scorecard], columns: list[str]) -> list[str]:
    lines = [
        "| entry | controller | state source | robots | " + " | ".join(columns) + " |",
        "|---|---|---|---|" + "---|" * len(columns),
    ]
    for card in _ranked(cards):
        values = " | ".join(fmt(score_value(card, c)) for c in columns)
        lines.append(
            f"| {card.label} | `{card.entry['controller']}` | `{card.entry['source']}` | "
            f"{', '.join(card.robots)} | {values} |"
        )
    return lines


def winners(cards: Sequence[Scorecard], columns: list[str]) -> list[str]:
    """One line per score column: the best implementable entry and its lead."""
    lines = []
    for column in columns:
        values = {c.label: score_value(c, column) for c in cards}
        ranked = sorted(
            (c for c in cards if values[c.label] is not None),
            key=lambda c: -float(values[c.label]),  # type: ignore[arg-type]
        )
        if not ranked:
            continue
        best = ranked[0]
        ties = [c.label for c in ranked if score_value(c, column) == score_value(best, column)]
        if len(ties) > 1:
            lines.append(f"* {column}: {', '.join(ties)} tie at {fmt(score_value(best, column))}.")
            continue
        lead = ""
        if len(ranked) > 1:
            lead = (
                f", {float(values[best.label]) - float(values[ranked[1].label]):.2f} ahead of "  # type: ignore[arg-type]
                f"{ranked[1].label} ({fmt(score_value(ranked[1], column))})"
            )
        lines.append(f"* {column}: {best.label} ({fmt(score_value(best, column))}){lead}.")
    return lines


def spread_table(cards: Sequence[Scorecard], suite: SuiteConfig) -> list[str]:
    """Per task and tolerance metric: the threshold, and each entry's range (min - max over
    the completed episodes of the task's unperturbed cells) with its count of episodes
    beyond the threshold: the measured spread the thresholds sit in."""
    base = {c.id: c for c in suite.cells if not c.perturbed}
    ordered = [
        *_ranked([c for c in cards if not c.oracle]),
        *_ranked([c for c in cards if c.oracle]),
    ]
    lines = [
        "| task | metric | threshold | " + " | ".join(c.label for c in ordered) + " |",
        "|---|---|---|" + "---|" * len(ordered),
    ]
    for name, task in suite.tasks.items():
        for metric, limit in task.tolerance.limits().items():
            cells = []
            for card in ordered:
                values = [
                    e.metrics.get(metric)
                    for cell in card.cells
                    if cell.id in base and cell.task == name
                    for e in cell.episodes
                    if e.status == "ok"
                ]
                finite = [v for v in values if v is not None and math.isfinite(v)]
                if not values:
                    cells.append("-")
                    continue
                beyond = sum(1 for v in values if v is None or not v <= limit)
                span = f"{min(finite):.2g} - {max(finite):.2g}" if finite else "n/a"
                cells.append(f"{span} ({beyond}/{len(values)} over)")
            lines.append(f"| {name} | {metric} | {limit:g} | " + " | ".join(cells) + " |")
    return lines


def leaderboard_markdown(cards: Sequence[Scorecard], suite: SuiteConfig, notes: str = "") -> str:
    """The leaderboard page; ``notes`` (markdown) goes under the tables."""
    columns = _columns(suite)
    implementable = [c for c in cards if not c.oracle]
    oracle = [c for c in cards if c.oracle]
    weights = ", ".join(f"{n} {c.weight:g}" for n, c in suite.categories.items())
    commits = sorted({(c.package["version"], c.package.get("commit") or "?") for c in cards})
    lines = [
        f"# Leaderboard: {suite.name}",
        "",
        f"Suite {suite.name} version {suite.version} (sha256 `{suite.hash}`): "
        f"{len(suite.cells)} cells x {len(suite.seeds)} seeds, {suite.duration:g} s "
        f"episodes at a {suite.physics_dt * 1e3:g} ms physics step. Scores in [0, 1]: "
        "a category's score is the share of its episodes that stay stable and within the "
        "task's tolerances; precision maps the nominal tracking RMS log-linearly from "
        f"{suite.precision.low:g} rad (1) to {suite.precision.high:g} rad (0); overall is "
        f"the weighted mean (weights: {weights}, precision {suite.precision.weight:g}). "
        "How to score and add an entry: [the submission guide](benchmark.md).",
        "",
        "Measured with elastic-gym "
        + ", ".join(f"{v} (commit {c[:10]})" for v, c in commits)
        + "; rebuilt from the scorecards in `docs/leaderboard/scorecards/` by "
        "`elastic-gym benchmark --leaderboard`.",
        "",
        "## Implementable entries",
        "",
        *(_table(implementable, columns) if implementable else ["(none)"]),
        "",
        "## Oracle references (read the true state)",
        "",
        *(_table(oracle, columns) if oracle else ["(none)"]),
        "",
        "## Best implementable entry per score",
        "",
        *winners(implementable, columns),
        "",
        *([notes.strip(), ""] if notes.strip() else []),
        "![per-category scores](leaderboard/leaderboard.png)",
        "",
        "## Tolerances and the measured spread",
        "",
        "Each task's thresholds against the range of each entry's completed episodes on the "
        "task's unperturbed cells (both robots), with the count of those episodes beyond "
        "the threshold.",
        "",
        *spread_table(cards, suite),
        "",
    ]
    return "\n".join(lines)


def write_csv(cards: Sequence[Scorecard], suite: SuiteConfig, path: Path) -> Path:
    columns = _columns(suite)
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["entry", "oracle", "controller", "source", *columns, "commit"])
        for card in [
            *_ranked([c for c in cards if not c.oracle]),
            *_ranked([c for c in cards if c.oracle]),
        ]:
            writer.writerow(
                [card.label, card.oracle, card.entry["controller"], card.entry["source"]]
                + [
                    ("" if score_value(card, c) is None else f"{score_value(card, c):.4f}")
                    for c in columns
                ]
                + [card.package.get("commit") or ""]
            )
    return path


def plot_leaderboard(cards: Sequence[Scorecard], suite: SuiteConfig, path: Path) -> Path:
    """A heat map: entries (implementable, then oracle) x scores."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    columns = _columns(suite)
    ordered = [
        *_ranked([c for c in cards if not c.oracle]),
        *_ranked([c for c in cards if c.oracle]),
    ]
    data = np.array(
        [
            [math.nan if score_value(c, k) is None else score_value(c, k) for k in columns]
            for c in ordered
        ]
    )
    fig, ax = plt.subplots(
        figsize=(1.1 * len(columns) + 3, 0.45 * len(ordered) + 1.5), constrained_layout=True
    )
    image = ax.imshow(data, cmap="viridis", vmin=0, vmax=1, aspect="auto")
    ax.set_xticks(range(len(columns)), columns, rotation=30, ha="right")
    labels = [f"{c.label} (oracle)" if c.oracle else c.label for c in ordered]
    ax.set_yticks(range(len(ordered)), labels)
    for i, row in enumerate(data):
        for j, value in enumerate(row):
            if math.isfinite(value):
                ax.text(
                    j,
                    i,
                    f"{value:.2f}",
                    ha="center",
                    va="center",
                    fontsize=8,
                    color="white" if value < 0.6 else "black",
                )
    fig.colorbar(image, ax=ax, label="score")
    ax.set_title(f"{suite.name} leaderboard", fontsize=10)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def rebuild_leaderboard(
    scorecards: str | Path = SCORECARD_DIR,
    page: str | Path = PAGE,
    suite: SuiteConfig | str | Path = DEFAULT_SUITE,
) -> list[Path]:
    """Rebuild the leaderboard page, CSV and figure from the scorecards (module docstring).
    The CSV and the figure go to the scorecards' parent folder; a ``notes.md`` there (what the
    results show, in words) is put under the tables."""
    if not isinstance(suite, SuiteConfig):
        suite = load_suite(suite)
    cards = load_cards(Path(scorecards), suite)
    page = Path(page)
    tables = Path(scorecards).parent
    page.parent.mkdir(parents=True, exist_ok=True)
    notes = tables / NOTES
    page.write_text(leaderboard_markdown(cards, suite, notes.read_text() if notes.exists() else ""))
    return [
        page,
        write_csv(cards, suite, tables / "leaderboard.csv"),
        plot_leaderboard(cards, suite, tables / "leaderboard.png"),
    ]
