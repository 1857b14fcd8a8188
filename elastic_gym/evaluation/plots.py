"""PNG figures of a comparison: one per scenario (env x axis values x model error).

Each figure overlays every controller / state-source pair of its scenario (the first
seed) in four panels over time: link tracking error |q - q_d|, link position and link
velocity estimation errors |q_hat - q|, |q_hat' - q'| (log scale; the true-state
source has none), and the applied torque |tau|. Uses matplotlib's Agg canvas through
``matplotlib.figure.Figure`` (no pyplot, no display needed).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from elastic_gym.evaluation.output import plot_file_name
from elastic_gym.evaluation.runner import RunResult

MAX_POINTS = 3000  # samples per line after decimation
PANELS = (
    ("|q - q_d| [rad]", "linear"),
    ("|q_hat - q| [rad]", "log"),
    ("|q_hat' - q'| [rad/s]", "log"),
    ("|tau| [N m]", "linear"),
)


def _panel_data(result: RunResult) -> list[np.ndarray]:
    series = result.series
    blocks = series.estimation_blocks()
    return [
        np.linalg.norm(series.q - series.q_ref, axis=1),
        np.linalg.norm(blocks["q"], axis=1),
        np.linalg.norm(blocks["dq"], axis=1),
        np.linalg.norm(series.torque, axis=1),
    ]


def plot_scenario(results: Sequence[RunResult], title: str, path: Path) -> Path:
    """One figure with a line per run of ``results`` (see module docstring)."""
    fig = Figure(figsize=(9.0, 10.0), layout="constrained")
    axes = fig.subplots(len(PANELS), 1, sharex=True)
    for index, result in enumerate(results):
        series = result.series
        stride = max(1, len(series) // MAX_POINTS)
        t = series.time[::stride]
        label = f"{result.spec.labels['controller']} / {result.spec.labels['source']}"
        if not result.ok:
            label += " (ended early)"
        for ax, (_, scale), values in zip(axes, PANELS, _panel_data(result), strict=True):
            values = values[::stride]
            if scale == "log":
                if not np.any(values > 0):
                    continue
                values = np.where(values > 0, values, np.nan)
            ax.plot(t, values, label=label, linewidth=1.0, color=f"C{index % 10}")
    for ax, (ylabel, scale) in zip(axes, PANELS, strict=True):
        ax.set_ylabel(ylabel)
        ax.set_yscale(scale)
        ax.grid(True, alpha=0.3)
    axes[0].legend(fontsize="small", loc="upper right")
    axes[-1].set_xlabel("time [s]")
    fig.suptitle(title)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    return path


def plot_results(results: Sequence[RunResult], directory: Path) -> list[Path]:
    """One PNG per scenario group of ``results`` (first seed of each), in ``directory``."""
    groups: dict[tuple, list[RunResult]] = {}
    for result in results:
        groups.setdefault(result.spec.group, []).append(result)
    paths = []
    for group, members in groups.items():
        seed = members[0].spec.labels["seed"]
        runs = [r for r in members if r.spec.labels["seed"] == seed]
        title = " | ".join(str(g) for g in group) + f" | seed {seed}"
        paths.append(plot_scenario(runs, title, directory / plot_file_name(group)))
    return paths
