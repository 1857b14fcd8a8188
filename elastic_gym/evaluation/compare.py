"""The comparison: plan the grid, run it in parallel, write tables and plots, print the summary.

Python API::

    from elastic_gym.evaluation import compare, load_preset

    result = compare(load_preset("default"), output_dir="compare_out/default")
    result.summary  # list of dict rows, averaged over seeds

Workers are started with the ``spawn`` method: a script that calls :func:`compare`
with more than one worker needs the usual ``if __name__ == "__main__":`` guard, and
controller/observer classes given directly are pickled by reference (define them at
module level).

Output folder (default ``./compare_out/<scenario name>``): ``runs.csv`` (one row per
run), ``summary.csv`` and ``summary.md`` (averaged over seeds), ``scenario.yaml``
(the resolved grid) and ``plots/<scenario>.png``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import yaml
from rich.console import Console

from elastic_gym.evaluation.plots import plot_results
from elastic_gym.evaluation.report import markdown_table, run_rows, summary_rows, write_csv
from elastic_gym.evaluation.runner import RunResult, SkippedRun, execute, plan_runs
from elastic_gym.evaluation.scenario import Scenario

DEFAULT_OUTPUT_ROOT = Path("compare_out")


@dataclass
class Comparison:
    """Everything a comparison produced."""

    scenario: Scenario
    results: list[RunResult]
    skipped: list[SkippedRun]
    rows: list[dict]
    summary: list[dict]
    markdown: str
    output_dir: Path
    files: list[Path] = field(default_factory=list)


def compare(
    scenario: Scenario,
    output_dir: str | Path | None = None,
    workers: int | None = None,
    backend: str = "process",
    progress: bool = True,
    plots: bool = True,
    console: Console | None = None,
) -> Comparison:
    """Run every applicable run of ``scenario`` and write the tables (and plots).

    Args:
        scenario: the grid (:func:`~elastic_gym.evaluation.load_preset`, ``Scenario.from_dict``).
        output_dir: output folder (default ``./compare_out/<scenario.name>``).
        workers: parallel worker processes (default: one per CPU, at most one per run).
        backend: ``"process"`` (local processes) or ``"ray"``.
        progress: show a progress bar.
        plots: write the PNG figures.
        console: where to print the summary table (default: stdout; silence it with
            ``Console(quiet=True)``).
    """
    console = console or Console()
    out = Path(output_dir) if output_dir is not None else DEFAULT_OUTPUT_ROOT / scenario.name
    runs, skipped = plan_runs(scenario)
    if not runs:
        raise ValueError(f"scenario {scenario.name!r} has no applicable run "
                         f"({len(skipped)} combinations skipped: {skipped[:3]})")
    skipped_note = _skipped_note(skipped)
    console.print(f"[bold]{scenario.name}[/bold]: {len(runs)} runs")
    console.print(skipped_note, markup=False, end="")
    results = execute(runs, workers=workers, backend=backend, progress=progress)

    identity = scenario.identity_columns
    rows = run_rows(results)
    summary = summary_rows(rows, identity)
    markdown = markdown_table(summary, identity)
    out.mkdir(parents=True, exist_ok=True)
    files = [write_csv(rows, out / "runs.csv"), write_csv(summary, out / "summary.csv")]
    (out / "summary.md").write_text(
        f"# {scenario.name}\n\n{scenario.description}\n\n{markdown}\n{skipped_note}"
    )
    (out / "scenario.yaml").write_text(yaml.safe_dump(scenario.to_dict(), sort_keys=False))
    files += [out / "summary.md", out / "scenario.yaml"]
    if plots:
        files += plot_results(results, out / "plots")
    console.print(markdown, soft_wrap=True, markup=False)  # long lines are not cut
    console.print(f"written to {out}/")
    return Comparison(scenario, results, skipped, rows, summary, markdown, out, files)


def _skipped_note(skipped: list[SkippedRun]) -> str:
    """One line per reason: how many combinations were skipped because they do not apply."""
    counts: dict[str, int] = {}
    for run in skipped:
        counts[run.reason] = counts.get(run.reason, 0) + 1
    return "".join(f"skipped {n} runs: {reason}\n" for reason, n in counts.items())
