"""Scores of a benchmark run, from the per-episode metrics of the comparison.

* An **episode passes** when it completes (status ``ok``: no divergence, no failure) and
  each metric its task's `Tolerance` names is finite
  and at most its threshold (smooth and fast tracking: tracking RMS and maximum error;
  steps: overshoot and settling time).
* A **category score** in [0, 1] is the share of its episodes that pass, over all its
  cells, robots and seeds (each cell has the same number of episodes); per robot as well.
* The **precision score** in [0, 1] maps the tracking RMS r of every episode of the
  nominal tracking cells (`PrecisionConfig`)
  log-linearly, p(r) = clip(log(high / r) / log(high / low), 0, 1) with low = 1e-6 and
  high = 1e-1 rad in ``elastic-gym-v1``: monotone decreasing, 1 at 1 µrad, 0.2 per decade,
  0 from 0.1 rad; an episode that does not complete scores 0. The score is the mean of p.
* The **overall score** is the weighted mean of the category scores and the precision
  score with the suite's weights: sum_c w_c s_c + w_p p over sum_c w_c + w_p.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from elastic_gym.benchmark.suite import Cell, SuiteConfig
from elastic_gym.evaluation.closed_loop import STATUS_OK

PRECISION = "precision"
OVERALL = "overall"


@dataclass(frozen=True)
class Episode:
    """One scored episode: its cell, seed, status, metrics, and the checks it failed."""

    cell: str
    seed: int
    status: str
    metrics: dict
    failed_checks: tuple[str, ...]

    @property
    def passed(self) -> bool:
        return self.status == STATUS_OK and not self.failed_checks


def episode_checks(cell: Cell, status: str, metrics: Mapping) -> tuple[str, ...]:
    """The tolerance checks an episode fails (``"track_rms > 0.001"``; ``"status"`` when it
    did not complete)."""
    failed = [] if status == STATUS_OK else ["status"]
    for metric, limit in cell.tolerance.limits().items():
        value = metrics.get(metric, math.nan)
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value <= limit):
            failed.append(f"{metric} > {limit:g}")
    return tuple(failed)


def precision_value(rms: float, low: float, high: float) -> float:
    """p(r) = clip(log(high / r) / log(high / low), 0, 1); 0 for a non-finite r."""
    if not (isinstance(rms, (int, float)) and math.isfinite(rms)) or rms < 0:
        return 0.0
    if rms <= low:
        return 1.0
    return min(1.0, max(0.0, math.log(high / rms) / math.log(high / low)))


def score_episodes(suite: SuiteConfig, rows: Sequence[Mapping]) -> list[Episode]:
    """Episodes from the comparison's run rows (``env`` = cell id, ``seed``, ``status``,
    metric columns), in suite order; ``ValueError`` if a cell or seed is missing."""
    cells = {c.id: c for c in suite.cells}
    by_key = {(row["env"], int(row["seed"])): row for row in rows}
    episodes = []
    for cell_id, cell in cells.items():
        for seed in suite.seeds:
            row = by_key.get((cell_id, seed))
            if row is None:
                continue
            metrics = {k: _number(v) for k, v in row.items() if k not in _ROW_KEYS}
            checks = episode_checks(cell, row["status"], metrics)
            episodes.append(Episode(cell_id, seed, row["status"], metrics, checks))
    return episodes


_ROW_KEYS = ("env", "model_error", "controller", "source", "seed", "status")


def _number(value) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan


@dataclass(frozen=True)
class Scores:
    """Category scores (overall and per robot), the precision score and the overall one."""

    categories: dict[str, float]
    per_robot: dict[str, dict[str, float]]
    precision: float
    overall: float
    episodes: int
    passed: int


def compute_scores(suite: SuiteConfig, episodes: Sequence[Episode]) -> Scores:
    """The scores of the module docstring; categories without an episode (robots left out)
    are NaN and do not enter the overall score."""
    cells = {c.id: c for c in suite.cells}
    robots = sorted({cells[e.cell].robot for e in episodes}, key=list(suite.robots).index)
    categories: dict = {}
    per_robot: dict[str, dict] = {robot: {} for robot in robots}
    for category in suite.categories:
        members = [e for e in episodes if cells[e.cell].category == category]
        categories[category] = _share(members)
        for robot in robots:
            per_robot[robot][category] = _share(
                [e for e in members if cells[e.cell].robot == robot]
            )
    config = suite.precision
    tracked = [
        e
        for e in episodes
        if cells[e.cell].category == config.category and cells[e.cell].task in config.tasks
    ]
    precision = _precision(tracked, config.low, config.high)
    for robot in robots:
        mine = [e for e in tracked if cells[e.cell].robot == robot]
        per_robot[robot][PRECISION] = _precision(mine, config.low, config.high)
    weights = {name: c.weight for name, c in suite.categories.items()}
    values = {**categories, PRECISION: precision}
    weights[PRECISION] = config.weight
    overall = weighted_mean(values, weights)
    for robot in robots:
        per_robot[robot][OVERALL] = weighted_mean(per_robot[robot], weights)
    return Scores(
        categories, per_robot, precision, overall, len(episodes), sum(e.passed for e in episodes)
    )


def weighted_mean(values: Mapping[str, float], weights: Mapping[str, float]) -> float:
    """sum w_k v_k / sum w_k over the keys of ``weights`` whose value is finite."""
    pairs = [(weights[k], values[k]) for k in weights if math.isfinite(values.get(k, math.nan))]
    total = sum(w for w, _ in pairs)
    return sum(w * v for w, v in pairs) / total if total > 0 else math.nan


def _share(episodes: Sequence[Episode]) -> float:
    return sum(e.passed for e in episodes) / len(episodes) if episodes else math.nan


def _precision(episodes: Sequence[Episode], low: float, high: float) -> float:
    if not episodes:
        return math.nan
    values = [
        precision_value(e.metrics.get("track_rms", math.nan), low, high)
        if e.status == STATUS_OK
        else 0.0
        for e in episodes
    ]
    return sum(values) / len(values)
