"""The scorecard of one entry on one suite: built from scored episodes, written as JSON
(`elastic_gym.benchmark.card`, the record), markdown and a figure, each file atomically.

The markdown page and the figure are views of the card for people: scores per category
and robot, then per cell the pass share, means of the completed episodes and the checks
that failed. `write_scorecard` writes every file beside its target and renames it over
it, so a full disk or a kill leaves the earlier file or the whole new one.
"""

from __future__ import annotations

import io
import math
import subprocess
from datetime import datetime, timezone
from pathlib import Path

import elastic_gym
from elastic_gym.benchmark.audit import card_episodes
from elastic_gym.benchmark.card import (
    FORMAT,
    METRICS,
    CellEpisodes,
    EntryRecord,
    Provenance,
    Scorecard,
    ScoreRecord,
    SuiteRef,
    card_text,
)
from elastic_gym.benchmark.markdown import code, plot_text, text
from elastic_gym.benchmark.scoring import OVERALL, PRECISION, Episode, Scores
from elastic_gym.benchmark.suite import SuiteConfig
from elastic_gym.observers.sensors import SENSORS
from elastic_gym.runtime.atomic import write_bytes, write_text

JSON_FILE, MARKDOWN_FILE, FIGURE_FILE = "scorecard.json", "scorecard.md", "scores.png"
CARD_FILES = (MARKDOWN_FILE, FIGURE_FILE, JSON_FILE)  # the JSON last: it is the record


def _finite(value: float) -> float | None:
    return float(value) if isinstance(value, (int, float)) and math.isfinite(value) else None


def git_commit() -> str | None:
    """The commit of the checkout the package is imported from (None outside git)."""
    try:
        out = subprocess.run(
            ["git", "rev-parse", "HEAD"],
            cwd=Path(elastic_gym.__file__).resolve().parent,
            capture_output=True,
            text=True,
            timeout=10,
            check=True,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() or None


def build_scorecard(
    suite: SuiteConfig,
    entry: dict,
    robots: list[str],
    episodes: list[Episode],
    scores: Scores,
    command: str | None,
    wall_time: float,
    cpu_time: float | None = None,
    note: str | None = None,
) -> Scorecard:
    """The card of scored episodes (`elastic_gym.benchmark.scoring`) of ``entry`` (its
    `describe_entry` record) on ``robots``; ``command`` reproduces it; ``note`` goes to the
    provenance."""
    cells: dict[str, CellEpisodes] = {}
    for cell in suite.cells:
        mine = {e.seed: e for e in episodes if e.cell == cell.id}
        if not mine:
            continue
        rows = [mine[seed] for seed in suite.seeds]
        columns = {m: [_finite(e.metrics.get(m, math.nan)) for e in rows] for m in METRICS}
        cells[cell.id] = CellEpisodes(status=[e.status for e in rows], **columns)
    return Scorecard(
        format=FORMAT,
        suite=SuiteRef(name=suite.name, version=suite.version, hash=suite.hash),
        entry=EntryRecord(**entry),
        command=command,
        robots=robots,
        seeds=list(suite.seeds),
        scores=ScoreRecord(
            overall=scores.overall,
            precision=scores.precision,
            categories={k: _finite(v) for k, v in scores.categories.items()},
            per_robot={
                robot: {k: _finite(v) for k, v in values.items()}
                for robot, values in scores.per_robot.items()
            },
            episodes=scores.episodes,
            passed=scores.passed,
        ),
        cells=cells,
        provenance=Provenance(
            package=elastic_gym.__version__,
            commit=git_commit(),
            created=datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
            wall_time=round(wall_time, 1),
            cpu_time=None if cpu_time is None else round(cpu_time, 1),
            note=note,
        ),
    )


def fmt(value: float | None, digits: int = 2) -> str:
    """A score or metric for a table ('-' for none)."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    return f"{value:.{digits}f}" if digits >= 0 else f"{value:.3g}"


def _mean(values: list[float | None]) -> float | None:
    finite = [v for v in values if v is not None]
    return sum(finite) / len(finite) if finite else None


def scorecard_markdown(card: Scorecard, suite: SuiteConfig) -> str:
    """The scorecard as a markdown page: scores per category (and robot), then per cell."""
    entry, scores, made = card.entry, card.scores, card.provenance
    kind = "oracle reference (reads the ground truth)" if entry.oracle else "implementable"
    if entry.source == SENSORS:
        kind = "implementable: the raw sensors, no estimate and no ground truth"
    lines = [
        f"# {text(card.label)} on {card.suite.name}",
        "",
        f"Controller {code(entry.controller)} on state source {code(entry.source)} ({kind}); "
        f"suite {card.suite.name} version {card.suite.version} (sha256 "
        f"`{card.suite.hash[:16]}`), elastic-gym {text(made.package)} "
        f"(commit {text(made.commit or 'unknown')}), {text(made.created)}, "
        f"{made.wall_time:.0f} s wall time"
        + (f" ({made.cpu_time:.0f} s CPU)" if made.cpu_time is not None else "")
        + f"; {scores.passed} of {scores.episodes} episodes pass.",
        "",
        f"Reproduce: {code(card.command) if card.command else 'a Python callable: no command'}",
        "",
        "| score | all | " + " | ".join(card.robots) + " |",
        "|---|---|" + "---|" * len(card.robots),
    ]
    for name in [*scores.categories, PRECISION, OVERALL]:
        per_robot = [fmt(scores.per_robot.get(r, {}).get(name)) for r in card.robots]
        lines.append(f"| {name} | {fmt(score_value(card, name))} | " + " | ".join(per_robot) + " |")
    lines += [
        "",
        "Per cell: the share of its episodes that pass, and means over its completed episodes.",
        "",
        "| cell | task | pass | track RMS [rad] | track max [rad] | overshoot [%] | "
        "settling [s] | torque rate RMS [Nm/s] | saturated | failures |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    tasks = {c.id: c.task for c in suite.cells}
    by_cell: dict[str, list[Episode]] = {}
    for episode in card_episodes(card, suite):
        by_cell.setdefault(episode.cell, []).append(episode)
    for cell_id, episodes in by_cell.items():
        done = [e for e in episodes if e.status == "ok"]
        means = [_mean([e.metrics[m] for e in done]) for m in METRICS]
        values = [fmt(means[i], -1) for i in (0, 1, 2, 3, 6)] + [fmt(means[7])]
        failures: dict[str, int] = {}
        for e in episodes:
            for check in e.failed_checks:
                label = e.status if check == "status" else check
                failures[label] = failures.get(label, 0) + 1
        failed = ", ".join(f"{text(k)} ({n})" for k, n in failures.items()) or "-"
        share = sum(e.passed for e in episodes) / len(episodes)
        lines.append(
            f"| {cell_id} | {tasks[cell_id]} | {fmt(share)} | "
            + " | ".join(values)
            + f" | {failed} |"
        )
    return "\n".join(lines) + "\n"


def _png(fig) -> bytes:
    """A figure as PNG bytes (closed)."""
    import matplotlib.pyplot as plt

    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=110)
    plt.close(fig)
    return buffer.getvalue()


def plot_scorecard(card: Scorecard) -> bytes:
    """Bars of the per-category scores (all robots, and each robot), as PNG bytes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    names = [*card.scores.categories, PRECISION, OVERALL]
    series = {"all": [score_value(card, n) for n in names]}
    for robot in card.robots:
        series[robot] = [card.scores.per_robot[robot].get(n) for n in names]
    fig, ax = plt.subplots(figsize=(9, 3.8), constrained_layout=True)
    width = 0.8 / len(series)
    x = np.arange(len(names))
    for i, (label, values) in enumerate(series.items()):
        heights = [np.nan if v is None else v for v in values]
        ax.bar(x + (i - (len(series) - 1) / 2) * width, heights, width, label=label)
    ax.set_xticks(x, names, rotation=20)
    ax.set_ylim(0, 1.05)
    ax.set_ylabel("score")
    ax.set_title(f"{plot_text(card.label)} on {card.suite.name}", fontsize=10)
    ax.legend(fontsize=8, ncols=len(series))
    return _png(fig)


def score_value(card: Scorecard, name: str) -> float | None:
    """A score of the card by name: a category, ``precision`` or ``overall``."""
    if name == PRECISION:
        return card.scores.precision
    if name == OVERALL:
        return card.scores.overall
    return card.scores.categories.get(name)


def write_scorecard(
    card: Scorecard, folder: Path, suite: SuiteConfig, figure: bool = True
) -> list[Path]:
    """``scores.png``, ``scorecard.md`` and last ``scorecard.json`` in ``folder``, each
    written atomically (`elastic_gym.runtime.atomic`)."""
    folder.mkdir(parents=True, exist_ok=True)
    files = []
    if figure:
        files.append(write_bytes(folder / FIGURE_FILE, plot_scorecard(card)))
    files.append(write_text(folder / MARKDOWN_FILE, scorecard_markdown(card, suite)))
    files.append(write_text(folder / JSON_FILE, card_text(card)))
    return files
