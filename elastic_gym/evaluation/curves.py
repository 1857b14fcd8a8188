"""Metric-versus-magnitude curves of a scenario's sweeps (PNG).

One figure per context (env, the other axes, model error) and metric: a panel per
sweep, a line per loop (colour: state source, line style: controller) through the mean
over seeds at each magnitude, a shaded band from the smallest to the largest seed, the
nominal runs at the sweep's nominal magnitude (on a log axis a nominal of 0 is drawn
as a dotted horizontal line instead), and an ``x`` at the top of the panel where a
loop is unstable (a seed's run ended early, see
[`sweeps`][elastic_gym.evaluation.sweeps]); its line is broken there. Metrics:
``track_rms`` for every loop, ``est_rms_q`` and ``est_rms_dq`` (after the
observer's initial transient) for the loops whose state comes from an observer. The
legend sits outside the panels.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import NullFormatter
from matplotlib.transforms import blended_transform_factory

from elastic_gym.evaluation.figure_names import plot_file_name
from elastic_gym.evaluation.plots import LEGEND_WIDTH, legend_outside
from elastic_gym.evaluation.scenario import TRUE_STATE
from elastic_gym.evaluation.sweeps import SweepCurve

CURVE_METRICS = (
    ("track_rms", "link tracking RMS [rad]", False),
    ("est_rms_q", "link position estimation RMS, steady [rad]", True),
    ("est_rms_dq", "link velocity estimation RMS, steady [rad/s]", True),
)
COLUMNS = 3
LINE_STYLES = ("-", "--", ":", "-.")


def _style(curves: Sequence[SweepCurve]) -> dict[tuple[str, str], dict]:
    """Colour per state source, line style per controller (the same in every figure)."""
    sources = list(dict.fromkeys(c.source for c in curves))
    controllers = list(dict.fromkeys(c.controller for c in curves))
    return {
        (c.controller, c.source): {
            "color": f"C{sources.index(c.source) % 10}",
            "linestyle": LINE_STYLES[controllers.index(c.controller) % len(LINE_STYLES)],
        }
        for c in curves
    }


def _draw(ax, curve: SweepCurve, metric: str, style: dict, slot: int) -> None:
    sweep = curve.sweep
    drawable = [p for p in curve.points if not (sweep.log and p.magnitude <= 0)]
    x = np.array([p.magnitude for p in drawable], dtype=float)
    mean = np.array([p.mean(metric) if p.stable else math.nan for p in drawable])
    bands = np.array(
        [p.band(metric) if p.stable else (math.nan, math.nan) for p in drawable]
    ).reshape(-1, 2)
    ax.plot(x, mean, marker="o", markersize=3, linewidth=1.2, label=curve.loop, **style)
    ax.fill_between(x, bands[:, 0], bands[:, 1], color=style["color"], alpha=0.15, linewidth=0)
    nominal = curve.nominal
    if nominal.stable and sweep.log and nominal.magnitude <= 0:
        ax.axhline(nominal.mean(metric), color=style["color"], linestyle=":", linewidth=0.8)
    unstable = [p.magnitude for p in drawable if not p.stable]
    if unstable:
        marks = blended_transform_factory(ax.transData, ax.transAxes)
        ax.plot(
            unstable,
            [0.97 - 0.035 * slot] * len(unstable),
            linestyle="none",
            marker="x",
            markersize=7,
            markeredgewidth=2,
            color=style["color"],
            transform=marks,
        )


def plot_curves(
    curves: Sequence[SweepCurve],
    metric: str,
    ylabel: str,
    title: str,
    path: Path,
    styles: dict | None = None,
) -> Path:
    """One figure: a panel per sweep of ``curves`` (one context), a line per loop
    (``styles``: line styles by (controller, source), default from ``curves``)."""
    sweeps = list(dict.fromkeys(c.sweep for c in curves))
    rows = math.ceil(len(sweeps) / COLUMNS)
    cols = min(COLUMNS, len(sweeps))
    fig = Figure(figsize=(4.0 * cols + LEGEND_WIDTH, 3.1 * rows + 1.0))
    axes = np.atleast_1d(fig.subplots(rows, cols, squeeze=False).ravel())
    styles = styles or _style(curves)
    loops = list(styles)
    for ax, sweep in zip(axes, sweeps, strict=False):
        for curve in (c for c in curves if c.sweep == sweep):
            key = (curve.controller, curve.source)
            _draw(ax, curve, metric, styles[key], loops.index(key))
        ax.set_xscale("log" if sweep.log else "linear")
        ax.xaxis.set_minor_formatter(NullFormatter())  # no crowded labels on short log ranges
        positive = any(
            np.any(p.values(metric) > 0) for c in curves if c.sweep == sweep for p in c.points
        )
        ax.set_yscale("log" if positive else "linear")
        ax.set_xlabel(f"{sweep.parameter} (nominal {sweep.nominal:g})")
        ax.set_title(sweep.name, fontsize="medium")
        ax.grid(True, which="both", alpha=0.25)
    for ax in axes[len(sweeps) :]:
        ax.set_visible(False)
    for ax in axes[::cols]:
        ax.set_ylabel(ylabel)
    handles: dict = {}
    for ax in axes:
        for handle, label in zip(*ax.get_legend_handles_labels(), strict=True):
            handles.setdefault(label, handle)
    legend_outside(
        fig,
        handles,
        "controller / state\n(mean and band over seeds;\nx: unstable)",
        title,
        hspace=0.5,
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    return path


def plot_all_curves(curves: Sequence[SweepCurve], directory: Path) -> list[Path]:
    """Every figure (one per context and metric, see the module docstring)."""
    contexts: dict[tuple, list[SweepCurve]] = {}
    for curve in curves:
        contexts.setdefault(tuple(curve.context.items()), []).append(curve)
    paths = []
    for context, members in contexts.items():
        labels = dict(context)
        styles = _style(members)  # the same colours in the tracking and estimation figures
        for metric, ylabel, observers_only in CURVE_METRICS:
            selected = [c for c in members if not (observers_only and c.source == TRUE_STATE)]
            if not any(p.values(metric).size for c in selected for p in c.points):
                continue
            title = " | ".join(str(v) for v in labels.values()) + f": {ylabel}"
            paths.append(
                plot_curves(
                    selected,
                    metric,
                    ylabel,
                    title,
                    directory / plot_file_name((*labels.values(), metric)),
                    styles,
                )
            )
    return paths
