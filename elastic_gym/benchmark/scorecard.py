"""The scorecard of one entry on one suite: JSON (the record), markdown and a figure.

JSON fields: ``format``; ``suite`` (name, version, sha256 hash); ``package`` (version, git
commit of the checkout when there is one); ``entry`` (what was scored and what it read:
:func:`~elastic_gym.benchmark.entry.describe_entry`); ``robots``; ``created`` (UTC);
``wall_time`` and ``cpu_time`` (s, this process and its worker processes; local
backend); ``scores`` (overall, precision, per category, per robot); ``cells`` (per
cell: robot, category, label, task, tolerances, pass share, and every episode with its
seed, status, metrics and the checks it failed). :func:`read_scorecard` validates a file.
"""

from __future__ import annotations

import json
import math
import subprocess
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from pydantic import Field

import elastic_gym
from elastic_gym.benchmark.scoring import OVERALL, PRECISION, Episode, Scores
from elastic_gym.benchmark.suite import SuiteConfig
from elastic_gym.observers.sensors import SENSORS
from elastic_gym.validation import StrictModel, validated

FORMAT = 1
JSON_FILE, MARKDOWN_FILE, FIGURE_FILE = "scorecard.json", "scorecard.md", "scores.png"
CELL_METRICS = (
    "track_rms",
    "track_max",
    "overshoot_pct",
    "settling_time",
    "torsion_max",
    "torque_rms",
    "torque_rate_rms",
    "saturation_share",
)


class SuiteRef(StrictModel):
    name: str
    version: int
    hash: str = Field(pattern=r"^[0-9a-f]{64}$")


class EpisodeRecord(StrictModel):
    seed: int
    status: str
    passed: bool
    failed_checks: list[str]
    metrics: dict[str, float | None]


class CellRecord(StrictModel):
    id: str
    robot: str
    category: str
    label: str
    task: str
    tolerance: dict[str, float]
    pass_share: float
    episodes: list[EpisodeRecord]


class ScoreRecord(StrictModel):
    overall: float | None
    precision: float | None
    categories: dict[str, float | None]
    per_robot: dict[str, dict[str, float | None]]
    episodes: int
    passed: int


class Scorecard(StrictModel):
    """A scorecard (module docstring)."""

    format: int
    suite: SuiteRef
    package: dict[str, str | None]
    entry: dict[str, Any]
    robots: list[str]
    created: str
    wall_time: float
    cpu_time: float | None = None
    scores: ScoreRecord
    cells: list[CellRecord]

    @property
    def label(self) -> str:
        return str(self.entry["label"])

    @property
    def oracle(self) -> bool:
        return bool(self.entry.get("oracle", False))


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
    wall_time: float,
    cpu_time: float | None = None,
) -> Scorecard:
    """The scorecard of scored episodes (:mod:`~elastic_gym.benchmark.scoring`)."""
    cells = []
    for cell in suite.cells:
        mine = [e for e in episodes if e.cell == cell.id]
        if not mine:
            continue
        cells.append(
            CellRecord(
                id=cell.id,
                robot=cell.robot,
                category=cell.category,
                label=cell.label,
                task=cell.task,
                tolerance=cell.tolerance.limits(),
                pass_share=sum(e.passed for e in mine) / len(mine),
                episodes=[
                    EpisodeRecord(
                        seed=e.seed,
                        status=e.status,
                        passed=e.passed,
                        failed_checks=list(e.failed_checks),
                        metrics={k: _finite(v) for k, v in e.metrics.items()},
                    )
                    for e in mine
                ],
            )
        )
    return Scorecard(
        format=FORMAT,
        suite=SuiteRef(name=suite.name, version=suite.version, hash=suite.hash),
        package={"version": elastic_gym.__version__, "commit": git_commit()},
        entry=entry,
        robots=robots,
        created=datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        wall_time=round(wall_time, 1),
        cpu_time=None if cpu_time is None else round(cpu_time, 1),
        scores=ScoreRecord(
            overall=_finite(scores.overall),
            precision=_finite(scores.precision),
            categories={k: _finite(v) for k, v in scores.categories.items()},
            per_robot={
                robot: {k: _finite(v) for k, v in values.items()}
                for robot, values in scores.per_robot.items()
            },
            episodes=scores.episodes,
            passed=scores.passed,
        ),
        cells=cells,
    )


def read_scorecard(path: str | Path) -> Scorecard:
    """A scorecard JSON file, validated (``ValueError`` naming the file and the field)."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: not a scorecard JSON file: {exc}") from None
    return validated(Scorecard, data, prefix=f"{path}:")


def fmt(value: float | None, digits: int = 2) -> str:
    """A score or metric for a table ('-' for none)."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    return f"{value:.{digits}f}" if digits >= 0 else f"{value:.3g}"


def _mean(values: list[float | None]) -> float | None:
    finite = [v for v in values if v is not None]
    return sum(finite) / len(finite) if finite else None


def scorecard_markdown(card: Scorecard) -> str:
    """The scorecard as a markdown page: scores per category (and robot), then per cell."""
    entry, scores = card.entry, card.scores
    kind = "oracle reference (reads the ground truth)" if card.oracle else "implementable"
    if entry["source"] == SENSORS:
        kind = "implementable: the raw sensors, no estimate and no ground truth"
    lines = [
        f"# {card.label} on {card.suite.name}",
        "",
        f"Controller `{entry['controller']}` on state source `{entry['source']}` ({kind}); "
        f"suite {card.suite.name} version {card.suite.version} (sha256 "
        f"`{card.suite.hash[:16]}`), elastic-gym {card.package['version']} "
        f"(commit {card.package.get('commit') or 'unknown'}), {card.created}, "
        f"{card.wall_time:.0f} s wall time"
        + (f" ({card.cpu_time:.0f} s CPU)" if card.cpu_time is not None else "")
        + f"; {scores.passed} of {scores.episodes} episodes pass.",
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
    for cell in card.cells:
        done = [e for e in cell.episodes if e.status == "ok"]
        means = [_mean([e.metrics.get(m) for e in done]) for m in CELL_METRICS]
        values = [fmt(means[i], -1) for i in (0, 1, 2, 3, 6)] + [fmt(means[7])]
        failures: dict[str, int] = {}
        for e in cell.episodes:
            for check in e.failed_checks:
                label = e.status if check == "status" else check
                failures[label] = failures.get(label, 0) + 1
        failed = ", ".join(f"{k} ({n})" for k, n in failures.items()) or "-"
        lines.append(
            f"| {cell.id} | {cell.task} | {fmt(cell.pass_share)} | "
            + " | ".join(values)
            + f" | {failed} |"
        )
    return "\n".join(lines) + "\n"


def plot_scorecard(card: Scorecard, path: Path) -> Path:
    """Bars of the per-category scores (all robots, and each robot)."""
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
    ax.set_title(f"{card.label} on {card.suite.name}", fontsize=10)
    ax.legend(fontsize=8, ncols=len(series))
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def score_value(card: Scorecard, name: str) -> float | None:
    """A score of the card by name: a category, ``precision`` or ``overall``."""
    if name == PRECISION:
        return card.scores.precision
    if name == OVERALL:
        return card.scores.overall
    return card.scores.categories.get(name)


def write_scorecard(card: Scorecard, folder: Path, figure: bool = True) -> list[Path]:
    """``scorecard.json``, ``scorecard.md`` and ``scores.png`` in ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    files = [folder / JSON_FILE, folder / MARKDOWN_FILE]
    files[0].write_text(json.dumps(card.model_dump(mode="json"), indent=1) + "\n")
    files[1].write_text(scorecard_markdown(card))
    if figure:
        files.append(plot_scorecard(card, folder / FIGURE_FILE))
    return files
