"""PNG figures of a comparison: one per scenario (env x axis values x model error).

Each figure has a column per joint and a row per signal, over time:

* link tracking error |q_i - q_d,i| (log scale);
* link position and link velocity estimation errors |q_hat_i - q_i|, |q_hat'_i - q'_i|
  (log scale; the true-state source has none and is left out);
* joint torsion theta_i - q_i (elastic arms);
* applied motor torque tau_i, with the torque limits +-tau_max,i as dashed lines.

A line per controller / state-source pair (colour: state source, line style:
controller) is the mean over the seeds, the shaded band spans the smallest to the
largest seed at each instant (runs that ended early contribute until their end and
are marked "ended early" in the legend). The legend sits outside the panels. Uses
matplotlib's Agg canvas through ``matplotlib.figure.Figure`` (no pyplot, no display).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from elastic_gym.evaluation.episodes import RunResult
from elastic_gym.evaluation.figure_names import plot_file_name
from elastic_gym.evaluation.grid import env_robot
from elastic_gym.evaluation.metrics import TimeSeries

MAX_POINTS = 2000  # samples per line after decimation
LINE_STYLES = ("-", "--", ":", "-.")
LEGEND_WIDTH = 3.2  # inches right of the panels


@dataclass(frozen=True)
class Panel:
    """One row of panels: a per-joint signal of a run's series, (K, N)."""

    label: str
    signal: Callable[[TimeSeries], np.ndarray | None]
    log: bool


def _estimation(block: str) -> Callable[[TimeSeries], np.ndarray]:
    return lambda s: np.abs(s.estimation_blocks()[block])


PANELS = (
    Panel("|q - q_d| [rad]", lambda s: np.abs(s.q - s.q_ref), True),
    Panel("|q_hat - q| [rad]", _estimation("q"), True),
    Panel("|q_hat' - q'| [rad/s]", _estimation("dq"), True),
    Panel("torsion theta - q [rad]", lambda s: None if s.theta is None else s.theta - s.q, False),
    Panel("torque tau [N m]", lambda s: s.torque, False),
)


def _series(result: RunResult) -> TimeSeries:
    """The samples of a plotted run (only runs with samples are plotted)."""
    if result.series is None:
        raise ValueError(f"run {result.spec.labels} has no samples to plot")
    return result.series


def _stack(results: Sequence[RunResult], panel: Panel) -> np.ndarray | None:
    """(seeds, K, N) values of ``panel``, runs that ended early padded with NaN."""
    found = [panel.signal(_series(r)) for r in results]
    signals = [s for s in found if s is not None]
    if len(signals) < len(found):
        return None
    length = max(len(s) for s in signals)
    out = np.full((len(signals), length, signals[0].shape[1]), np.nan)
    for i, signal in enumerate(signals):
        out[i, : len(signal)] = signal
    return out


def _loops(results: Sequence[RunResult]) -> dict[tuple[str, str], list[RunResult]]:
    loops: dict[tuple[str, str], list[RunResult]] = {}
    for result in results:
        labels = result.spec.labels
        loops.setdefault((labels["controller"], labels["source"]), []).append(result)
    return loops


def plot_scenario(results: Sequence[RunResult], title: str, path: Path) -> Path:
    """One figure of the runs of one scenario (all seeds; see the module docstring)."""
    loops = _loops(results)
    longest = max((_series(r) for r in results), key=len)
    n = longest.q.shape[1]
    panels = [p for p in PANELS if p.signal(longest) is not None]
    fig = Figure(figsize=(3.6 * n + LEGEND_WIDTH, 2.0 * len(panels) + 0.8))
    axes = fig.subplots(len(panels), n, sharex=True, squeeze=False)
    sources = list(dict.fromkeys(source for _, source in loops))
    controllers = list(dict.fromkeys(controller for controller, _ in loops))
    for (controller, source), members in loops.items():
        style = {
            "color": f"C{sources.index(source) % 10}",
            "linestyle": LINE_STYLES[controllers.index(controller) % len(LINE_STYLES)],
        }
        label = f"{controller} / {source}"
        ended = sum(not r.ok for r in members)
        if ended:
            label += f" ({ended} of {len(members)} ended early)"
        time = max((_series(r) for r in members), key=len).time
        stride = max(1, len(time) // MAX_POINTS)
        for row, panel in enumerate(panels):
            values = _stack(members, panel)
            if values is None:  # the signal is missing in some of the runs
                continue
            if panel.log:
                values = np.where(values > 0, values, np.nan)
                if np.all(np.isnan(values)):
                    continue  # e.g. no estimation error for the true state
            values = values[:, ::stride]
            with warnings.catch_warnings():  # all-NaN instants (every run ended) stay NaN
                warnings.simplefilter("ignore", RuntimeWarning)
                mean, low, high = (
                    np.nanmean(values, 0),
                    np.nanmin(values, 0),
                    np.nanmax(values, 0),
                )
            for joint in range(n):
                ax = axes[row, joint]
                ax.plot(time[::stride], mean[:, joint], linewidth=1.0, label=label, **style)
                if len(members) > 1:
                    ax.fill_between(
                        time[::stride],
                        low[:, joint],
                        high[:, joint],
                        color=style["color"],
                        alpha=0.15,
                        linewidth=0,
                    )
    limits = np.asarray(_torque_limit(results[0]), dtype=float)
    for row, panel in enumerate(panels):
        for joint in range(n):
            ax = axes[row, joint]
            ax.set_yscale("log" if panel.log else "linear")
            ax.grid(True, alpha=0.3)
            if row == 0:
                ax.set_title(f"joint {joint + 1}")
            if joint == 0:
                ax.set_ylabel(panel.label)
            if panel.label.startswith("torque"):
                for sign in (-1, 1):
                    ax.axhline(
                        sign * limits[joint],
                        color="k",
                        linestyle="--",
                        linewidth=0.8,
                        label="torque limit",
                    )
    for ax in axes[-1]:
        ax.set_xlabel("time [s]")
    handles: dict[str, object] = {}
    for ax in axes.ravel():
        for handle, label in zip(*ax.get_legend_handles_labels(), strict=True):
            handles.setdefault(label, handle)
    seeds = sorted({r.spec.labels["seed"] for r in results})
    legend_outside(fig, handles, f"mean and band over seeds {seeds}", title)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    return path


def legend_outside(
    fig: Figure, handles: dict, legend_title: str, title: str, hspace: float = 0.25
) -> None:
    """Figure title, and the legend in a strip right of the panels (never over the data).

    A fixed layout (``subplots_adjust``): matplotlib's constrained layout costs most of
    the drawing time of these many-panel figures.
    """
    width, height = fig.get_size_inches()
    right = 1.0 - LEGEND_WIDTH / width
    fig.subplots_adjust(
        left=0.9 / width,
        right=right - 0.15 / width,
        bottom=0.55 / height,
        top=1.0 - 0.75 / height,
        wspace=0.3,
        hspace=hspace,
    )
    fig.legend(
        handles.values(),
        handles.keys(),
        loc="upper left",
        bbox_to_anchor=(right, 0.97),
        fontsize="small",
        title=legend_title,
        title_fontsize="small",
        frameon=False,
    )
    fig.suptitle(title)


def _torque_limit(result: RunResult) -> Sequence[float]:
    """The torque limits of a run's env (its ``torque_limit`` kwarg or the robot's)."""
    spec = result.spec
    limit = spec.env_kwargs.get("torque_limit")
    if limit is None:
        return env_robot(spec.env_id, spec.env_kwargs).torque_limit
    return np.broadcast_to(np.asarray(limit, dtype=float), (len(_series(result).q[0]),)).tolist()


def plot_results(results: Sequence[RunResult], directory: Path) -> list[Path]:
    """One PNG per scenario group of ``results`` (all seeds), in ``directory``."""
    groups: dict[tuple, list[RunResult]] = {}
    for result in results:
        groups.setdefault(result.spec.group, []).append(result)
    paths = []
    for group, members in groups.items():
        title = " | ".join(str(g) for g in group)
        paths.append(plot_scenario(members, title, directory / plot_file_name(group)))
    return paths
