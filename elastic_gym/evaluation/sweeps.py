"""The runs of a scenario's one-at-a-time sweeps, arranged as curves.

A scenario with ``sweeps`` (`Sweep`) has an axis
``sweep`` whose values are ``nominal`` and ``<sweep>=<magnitude>``. `sweep_curves`
groups the result rows (one per run, as in ``runs.csv``) into one
[`SweepCurve`][elastic_gym.evaluation.sweeps.SweepCurve]
per context (env, the other axes, model error), loop (controller x state source) and
sweep: its points are the sweep's magnitudes in increasing order, the nominal runs
included at the sweep's ``nominal`` magnitude, each with the rows of its seeds.

A point is *stable* when every seed's run completed (status ``ok``); a run that ended
early (the env's or the observer wrapper's termination: non-finite state or estimate,
a velocity or joint limit crossed) or failed is unstable there. Metric values of a
point are the mean over its completed seeds; the band is their minimum and maximum.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from elastic_gym.evaluation.scenario import NOMINAL, SWEEP_AXIS, Scenario, Sweep

STATUS_OK = "ok"
LOOP_COLUMNS = ("controller", "source")


@dataclass(frozen=True)
class SweepPoint:
    """The runs (one per seed) of one loop at one magnitude of a sweep."""

    magnitude: float
    rows: tuple[dict, ...]

    @property
    def stable(self) -> bool:
        return all(row["status"] == STATUS_OK for row in self.rows)

    @property
    def statuses(self) -> list[str]:
        """The distinct statuses of the runs that did not complete."""
        return sorted({row["status"] for row in self.rows} - {STATUS_OK})

    def values(self, metric: str) -> np.ndarray:
        """The metric of each completed seed (NaN entries dropped)."""
        values = np.array(
            [float(row[metric]) for row in self.rows if row["status"] == STATUS_OK], dtype=float
        )
        return values[~np.isnan(values)]

    def mean(self, metric: str) -> float:
        values = self.values(metric)
        return float(np.mean(values)) if len(values) else math.nan

    def band(self, metric: str) -> tuple[float, float]:
        """(min, max) over the completed seeds."""
        values = self.values(metric)
        return (float(values.min()), float(values.max())) if len(values) else (math.nan,) * 2


@dataclass(frozen=True)
class SweepCurve:
    """One loop's points along one sweep, in one context."""

    context: dict  # env, other axes, model_error -> label
    controller: str
    source: str
    sweep: Sweep
    points: tuple[SweepPoint, ...]  # increasing magnitude, the nominal included

    @property
    def loop(self) -> str:
        return f"{self.controller} / {self.source}"

    @property
    def nominal(self) -> SweepPoint:
        return next(p for p in self.points if p.magnitude == self.sweep.nominal)


def context_columns(scenario: Scenario) -> tuple[str, ...]:
    """Identity columns that define a curve's context (not the sweep, loop or seed)."""
    return tuple(
        c for c in scenario.identity_columns if c not in (SWEEP_AXIS, *LOOP_COLUMNS, "seed")
    )


def sweep_curves(scenario: Scenario, rows: Sequence[dict]) -> list[SweepCurve]:
    """All curves of the scenario's sweeps (see the module docstring), in first-seen order.

    Rows need the identity columns, ``status`` and the metric columns. A curve whose
    nominal runs are missing (not applicable, or filtered out) is left out.
    """
    context_keys = context_columns(scenario)
    groups: dict[tuple, dict[str, list[dict]]] = {}
    for row in rows:
        key = (tuple(row[k] for k in context_keys), tuple(row[k] for k in LOOP_COLUMNS))
        groups.setdefault(key, {}).setdefault(str(row[SWEEP_AXIS]), []).append(row)
    curves = []
    for (context, (controller, source)), by_label in groups.items():
        if NOMINAL not in by_label:
            continue
        for sweep in scenario.sweeps:
            points = {sweep.nominal: by_label[NOMINAL]}
            for label, members in by_label.items():
                magnitude = sweep.magnitude(label)
                if magnitude is not None and label != NOMINAL:
                    points[magnitude] = members
            curves.append(
                SweepCurve(
                    dict(zip(context_keys, context, strict=True)),
                    controller,
                    source,
                    sweep,
                    tuple(SweepPoint(m, tuple(points[m])) for m in sorted(points)),
                )
            )
    return curves
