"""The leaderboard page: the figure and short ranked tables first, the rest folded.

Top of the page: the heat map of every score, then one short table per kind of card —
implementable entries, oracle references (their source reads ground truth) and cards of
part of the suite's robots (not ranked with the others) — each with the entry, its state
source, the overall and the precision score. Below: the notes (what the results show, in
words), then folded blocks (mkdocs-material ``???``): per entry its scores per category
and robot, the command that reproduces it and where it was measured; the best
implementable entry per score; per task its tolerances against the spread each entry
measured. No table has more than five columns. Every string from a card goes through
`elastic_gym.benchmark.markdown`.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from pathlib import Path

from elastic_gym.benchmark.audit import CheckedCard
from elastic_gym.benchmark.markdown import code, text
from elastic_gym.benchmark.scorecard import fmt, score_value
from elastic_gym.benchmark.scoring import OVERALL, PRECISION, STATUS_OK
from elastic_gym.benchmark.suite import SuiteConfig

MARKER = (
    "<!-- Written by `elastic-gym benchmark --leaderboard` from scorecards: "
    "edit the cards or the notes, not this page. -->"
)
INDENT = "    "


def ranked(cards: Sequence[CheckedCard]) -> list[CheckedCard]:
    """Best first: by overall, then precision score, then label."""
    return sorted(cards, key=lambda c: (-c.card.scores.overall, -c.card.scores.precision, c.label))


def tables(cards: Sequence[CheckedCard]) -> dict[str, list[CheckedCard]]:
    """The cards of each table, ranked: ``implementable``, ``oracle``, ``subset``."""
    return {
        "implementable": ranked([c for c in cards if not c.oracle and not c.subset]),
        "oracle": ranked([c for c in cards if c.oracle and not c.subset]),
        "subset": ranked([c for c in cards if c.subset]),
    }


def shown_label(card: CheckedCard) -> str:
    """The label with what sets the card apart (figure and CSV order)."""
    return (
        card.label
        + (" (oracle)" if card.oracle else "")
        + (f" ({', '.join(card.card.robots)} only)" if card.subset else "")
    )


def _source(card: CheckedCard) -> str:
    source = card.card.entry.source
    return code(source.rpartition(":")[2])


def _short_table(cards: Sequence[CheckedCard], robots: bool = False) -> list[str]:
    if not cards:
        return ["(none)"]
    names = ["#", "entry", *(["robots"] if robots else []), "state source", "overall", "precision"]
    lines = ["| " + " | ".join(names) + " |", "|" + "---|" * len(names)]
    for rank, card in enumerate(cards, 1):
        scores = card.card.scores
        where = f"{text(', '.join(card.card.robots))} | " if robots else ""
        lines.append(
            f"| {rank} | [{text(card.label)}](#{anchor(card)}) | {where}{_source(card)} | "
            f"{fmt(scores.overall)} | {fmt(scores.precision)} |"
        )
    return lines


def anchor(card: CheckedCard) -> str:
    """The id of the entry's folded block (letters, digits and ``-`` of its file name)."""
    stem = Path(card.where).stem
    return "entry-" + "".join(ch if ch.isalnum() else "-" for ch in stem.lower()).strip("-")


def _fold(title: str, body: Sequence[str], anchor_id: str | None = None) -> list[str]:
    head = f'??? note "{title}"'
    lines = [f'<a id="{anchor_id}"></a>', ""] if anchor_id else []
    return [*lines, head, "", *(INDENT + line if line else "" for line in body), ""]


def _entry_block(card: CheckedCard, page: Path) -> list[str]:
    c = card.card
    entry, made = c.entry, c.provenance
    kind = "implementable"
    if card.oracle:
        kind = "oracle reference: reads " + ", ".join(card.privileged)
    link = os.path.relpath(Path(card.where), page.parent) if Path(card.where).exists() else None
    body = [
        f"Controller {code(entry.controller)} on state source {code(entry.source)} ({text(kind)}); "
        f"robots {text(', '.join(c.robots))}; {c.scores.passed} of {c.scores.episodes} "
        "episodes pass.",
        "",
        "| score | all | " + " | ".join(text(r) for r in c.robots) + " |",
        "|---|---|" + "---|" * len(c.robots),
    ]
    for name in [*c.scores.categories, PRECISION, OVERALL]:
        per_robot = [fmt(c.scores.per_robot[r].get(name)) for r in c.robots]
        body.append(f"| {name} | {fmt(score_value(c, name))} | " + " | ".join(per_robot) + " |")
    body += [
        "",
        "Reproduce: " + (code(c.command) if c.command else "a Python callable, no command."),
        "",
        f"Measured with elastic-gym {text(made.package)} (commit "
        f"{text((made.commit or 'unknown')[:10])}) on {text(made.created[:10])}: "
        f"{made.wall_time:.0f} s wall time"
        + (f", {made.cpu_time:.0f} s CPU" if made.cpu_time is not None else "")
        + (f"; the card: [{text(Path(card.where).name)}]({_url(link)})." if link else "."),
    ]
    title = f"{text(card.label)}: overall {fmt(c.scores.overall)}"
    return _fold(title, body, anchor(card))


def _url(path: str) -> str:
    """A relative link target (characters a markdown link or a URL would misread encoded)."""
    from urllib.parse import quote

    return quote(path.replace(os.sep, "/"), safe="/@+-._~")


def winners(cards: Sequence[CheckedCard], columns: list[str]) -> list[str]:
    """One line per score column: the best entry and its lead over the next."""
    lines = []
    for column in columns:
        values = {c.label: score_value(c.card, column) for c in cards}
        ranked_ = sorted(
            (c for c in cards if values[c.label] is not None),
            key=lambda c: (-float(values[c.label] or 0.0), c.label),
        )
        if not ranked_:
            continue
        best = float(values[ranked_[0].label] or 0.0)
        ties = [c for c in ranked_ if values[c.label] == best]
        names = ", ".join(text(c.label) for c in ties)
        if len(ties) > 1:
            lines.append(f"* {column}: {names} tie at {fmt(best)}.")
            continue
        lead = ""
        if len(ranked_) > 1:
            second = float(values[ranked_[1].label] or 0.0)
            lead = f", {best - second:.2f} ahead of {text(ranked_[1].label)} ({fmt(second)})"
        lines.append(f"* {column}: {names} ({fmt(best)}){lead}.")
    return lines


def spread_blocks(cards: Sequence[CheckedCard], suite: SuiteConfig) -> list[str]:
    """Per task, folded: each tolerance metric's threshold, and per entry the range (min -
    max over the completed episodes of the task's unperturbed cells) with the count of
    episodes beyond the threshold: the measured spread the thresholds sit in."""
    base = {c.id: c for c in suite.cells if not c.perturbed}
    lines: list[str] = []
    for name, task in suite.tasks.items():
        limits = task.tolerance.limits()
        body = [
            "| entry | " + " | ".join(f"{m} (≤ {v:g})" for m, v in limits.items()) + " |",
            "|---|" + "---|" * len(limits),
        ]
        for card in cards:
            done = [
                e
                for e in card.episodes
                if e.cell in base and base[e.cell].task == name and e.status == STATUS_OK
            ]
            if not done:
                continue
            cells = []
            for metric, limit in limits.items():
                values = [e.metrics.get(metric, math.nan) for e in done]
                finite = [v for v in values if math.isfinite(v)]
                beyond = sum(1 for v in values if not v <= limit)
                span = f"{min(finite):.2g} - {max(finite):.2g}" if finite else "n/a"
                cells.append(f"{span} ({beyond}/{len(values)} over)")
            body.append(f"| {text(shown_label(card))} | " + " | ".join(cells) + " |")
        shown = ", ".join(f"{m} ≤ {v:g}" for m, v in limits.items())
        lines += _fold(f"{text(name)}: {shown}", body)
    return lines


def leaderboard_markdown(
    cards: Sequence[CheckedCard],
    suite: SuiteConfig,
    page: Path,
    figure: Path,
    notes: str = "",
) -> str:
    """The leaderboard page (module docstring) to be written at ``page``, showing the
    figure at ``figure``; ``notes`` (markdown, what the results show) under the tables."""
    groups = tables(cards)
    columns = [OVERALL, PRECISION, *suite.categories]
    weights = ", ".join(f"{n} {c.weight:g}" for n, c in suite.categories.items())
    figure_link = _url(os.path.relpath(figure, page.parent))
    ordered = [*groups["implementable"], *groups["oracle"], *groups["subset"]]
    lines = [
        MARKER,
        f"# Leaderboard: {suite.name}",
        "",
        f"Suite {suite.name} version {suite.version}: {len(suite.cells)} cells x "
        f"{len(suite.seeds)} seeds. Each score is in [0, 1]: a category's is the share of "
        "its episodes within the task's tolerances, precision maps the nominal tracking "
        "error, overall is their weighted mean. Every score below is recomputed from the "
        "cards' own episodes. [How to score and add an entry](benchmark.md).",
        "",
        f"![scores of every entry]({figure_link})",
        "",
        "## Implementable entries",
        "",
        *_short_table(groups["implementable"]),
        "",
        "## Oracle references",
        "",
        "Their state source reads the true state: the bound an observer could reach.",
        "",
        *_short_table(groups["oracle"]),
        "",
    ]
    if groups["subset"]:
        lines += [
            "## Scored on part of the suite",
            "",
            "Cards of some of the suite's robots only: not ranked with the full entries.",
            "",
            *_short_table(groups["subset"], robots=True),
            "",
        ]
    if notes.strip():
        lines += [notes.strip(), ""]
    lines += ["## Per entry", ""]
    for card in ordered:
        lines += _entry_block(card, page)
    lines += [
        "## Best implementable entry per score",
        "",
        *_fold("Best per score", winners(groups["implementable"], columns) or ["(none)"]),
        "## Tolerances and the measured spread",
        "",
        "Each task's thresholds against the range of each entry's completed episodes on the "
        "task's unperturbed cells, with the count of those beyond the threshold.",
        "",
        *spread_blocks(ordered, suite),
        "## The suite",
        "",
        *_fold(
            "Suite, weights and hash",
            [
                f"{suite.name} version {suite.version}, sha256 `{suite.hash}`: "
                f"{len(suite.cells)} cells x {len(suite.seeds)} seeds, "
                f"{suite.duration:g} s episodes at a {suite.physics_dt * 1e3:g} ms physics "
                f"step. Precision maps the tracking RMS log-linearly from "
                f"{suite.precision.low:g} rad (1) to {suite.precision.high:g} rad (0). "
                f"Weights: {weights}, precision {suite.precision.weight:g}.",
            ],
        ),
    ]
    return "\n".join(lines).rstrip() + "\n"
