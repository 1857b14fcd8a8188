"""The report of a comparison: its output folder, filled as the executed worlds end.

The third of the comparison's three stages (plan → execute → report).
[`Report`][elastic_gym.evaluation.report.Report] checks the output folder and the figure
names before the first run, writes ``scenario.yaml``, then each run's row to ``runs.csv``
as its world ends (and the figure of a scenario once all its runs are in, dropping the time
series), and at the end the tables (``summary.csv``, ``summary.md``: the
[`elastic_gym.evaluation.tables`][elastic_gym.evaluation.tables]), the sweeps' margins and
curves, and the summary on the console; it returns the
[`Comparison`][elastic_gym.evaluation.report.Comparison]. An interrupted comparison keeps
its finished rows and a summary of them. A full disk raises `ResultsWriteError` saying
what ``runs.csv`` kept.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml
from rich.console import Console

from elastic_gym.evaluation.episodes import RunResult
from elastic_gym.evaluation.figure_names import check_plot_names
from elastic_gym.evaluation.grid import SkippedRun, identified_files
from elastic_gym.evaluation.margins import margin_rows, write_margins
from elastic_gym.evaluation.output import (
    CURVE_DIR,
    PLOT_DIR,
    ResultsWriteError,
    RunsCsv,
    check_output_folder,
    clear_results,
    write_atomic,
    write_problem,
)
from elastic_gym.evaluation.plan import Plan
from elastic_gym.evaluation.preflight import Estimate
from elastic_gym.evaluation.scenario import NOMINAL, SWEEP_AXIS, Scenario
from elastic_gym.evaluation.sweeps import context_columns, sweep_curves
from elastic_gym.evaluation.tables import (
    as_table,
    markdown_table,
    run_row,
    summary_rows,
    write_csv,
)
from elastic_gym.runtime.parallel import with_detail


@dataclass
class Comparison:
    """Everything a comparison produced.

    ``runs`` (one row per run) and ``summary`` (per scenario, controller and source: the
    mean of each metric over the seeds and its spread ``<metric>_std``) are pandas
    ``DataFrame`` objects when pandas is installed (unless ``compare`` was told
    ``dataframes=False``), lists of row dicts otherwise.
    """

    scenario: Scenario
    runs: Any
    summary: Any
    skipped: list[SkippedRun]
    markdown: str
    output_dir: Path
    files: list[Path] = field(default_factory=list)
    failed: int = 0  # runs with status "failed: ..."


class _Figures:
    """The figure of each scenario (env x axis values x model error), drawn once all of
    its runs are in (in run order); a sweep's runs are summarized by its curves."""

    def __init__(self, plan: Plan, folder: Path) -> None:
        self.folder = folder
        self.remaining = Counter(spec.group for spec in plan.runs)
        self.waiting: dict[tuple, list[RunResult]] = {}
        self.files: list[Path] = []

    def add(self, result: RunResult) -> None:
        if result.spec.labels.get(SWEEP_AXIS, NOMINAL) != NOMINAL:
            return
        group = result.spec.group
        members = self.waiting.setdefault(group, [])
        if result.series is not None:
            members.append(result)
        self.remaining[group] -= 1
        if self.remaining[group] == 0:
            members = sorted(self.waiting.pop(group), key=lambda r: r.spec.index)
            if members:
                # imported here: matplotlib is not needed by the workers, which import this
                # package, nor by comparisons without plots
                from elastic_gym.evaluation.plots import plot_results

                self.files += plot_results(members, self.folder)


class Report:
    """The report stage of a comparison writing into ``out`` (module docstring); the
    execute stage delivers to it ([`ResultSink`][elastic_gym.evaluation.execute.ResultSink]).

    Made before any run: refuses (changing nothing) a folder that holds an earlier
    comparison unless ``overwrite`` (`FileExistsError`), and with ``plots`` labels whose
    figure names do not work (`ScenarioError`).

    Args:
        plan: the comparison's plan.
        out: the output folder (locked by the caller).
        plots: write the PNG figures.
        overwrite: replace the files of an earlier comparison in ``out``.
        console: where the plan, the summary and where it was written are printed.
    """

    def __init__(
        self, plan: Plan, out: Path, plots: bool, overwrite: bool, console: Console
    ) -> None:
        self.plan, self.out, self.plots, self.overwrite = plan, out, plots, overwrite
        self.console = console
        check_output_folder(out, overwrite)
        if plots:
            check_plot_names(plan.scenario, plan.runs)
        self.csv = RunsCsv(out / "runs.csv")
        self.figures = _Figures(plan, out / PLOT_DIR) if plots else None

    def start(self, estimate: Estimate) -> None:
        """The runs are about to start: say what runs and how long it should take, clear
        an earlier comparison's files (with ``overwrite``) and write ``scenario.yaml``."""
        plan = self.plan
        self.console.print(f"[bold]{plan.scenario.name}[/bold]: {plan}, {estimate}")
        self.console.print(plan.skipped_note, markup=False, end="")
        if self.overwrite:
            clear_results(self.out)
        self.out.mkdir(parents=True, exist_ok=True)
        text = yaml.safe_dump(self.plan.scenario.to_dict(), sort_keys=False)
        try:
            write_atomic(self.out / "scenario.yaml", text)
        except OSError as exc:
            raise ResultsWriteError(
                f"{write_problem(exc)}: nothing written in {self.out}/"
            ) from exc

    def add(self, index: int, results: list[RunResult]) -> None:
        """The results of a world (its ``index`` in the plan): their rows, and figures."""
        for result in results:
            self.csv.add(result.spec.index, run_row(result))
            if self.figures is not None:
                self.figures.add(result)

    def interrupted(self, exc: BaseException) -> BaseException:
        """``exc`` (which ended the runs) saying what was kept: the finished rows in
        ``runs.csv`` and a summary of them."""
        rows = self.csv.finish()
        kept = f"kept the {len(rows)} finished of {len(self.plan.runs)} runs in {self.out}/"
        self._write_tables(rows, self.plan.skipped_note + f"\nInterrupted: {kept}.\n")
        return with_detail(exc, kept)

    def finish(self, dataframes: bool = True) -> Comparison:
        """The tables, margins and curves written, the summary printed; ``runs`` and
        ``summary`` as pandas DataFrames when pandas is installed and ``dataframes``."""
        out, scenario, console = self.out, self.plan.scenario, self.console
        rows = self.csv.finish()
        failed = [row["status"] for row in rows if row["status"].startswith("failed")]
        failed_note = (
            f"{len(failed)} of {len(rows)} runs failed (status column of runs.csv), "
            f"e.g. {failed[0]}\n"
            if failed
            else ""
        )
        summary, markdown = self._write_tables(rows, self.plan.skipped_note + failed_note)
        files = [out / "runs.csv", out / "summary.csv", out / "summary.md", out / "scenario.yaml"]
        files += self.figures.files if self.figures is not None else []
        if scenario.sweeps:
            curves = sweep_curves(scenario, rows)
            files += write_margins(
                margin_rows(curves), context_columns(scenario), out, scenario.name
            )
            if self.plots:
                from elastic_gym.evaluation.curves import plot_all_curves  # matplotlib: _Figures

                files += plot_all_curves(curves, out / CURVE_DIR)
        console.print(markdown, soft_wrap=True, markup=False)  # long lines are not cut
        console.print(failed_note, markup=False, end="")
        if scenario.sweeps:
            console.print(f"robustness margins: {out / 'margins.md'}", markup=False)
        console.print(f"written to {out}/")
        table = as_table if dataframes else list
        return Comparison(
            scenario,
            table(rows),
            table(summary),
            list(self.plan.skipped),
            markdown,
            out,
            files,
            len(failed),
        )

    def _write_tables(self, rows: list[dict], note: str) -> tuple[list[dict], str]:
        out, scenario = self.out, self.plan.scenario
        identity = scenario.identity_columns
        summary = summary_rows(rows, identity)
        markdown = markdown_table(summary, identity)
        models = "".join(
            f"Controllers and observers of robot {robot!r} built on the identified model "
            f"{path} (the simulated plant is the env's).\n\n"
            for robot, path in identified_files(scenario).items()
        )
        try:
            write_csv(summary, out / "summary.csv")
            write_atomic(
                out / "summary.md",
                f"# {scenario.name}\n\n{scenario.description}\n\n{models}{markdown}\n{note}",
            )
        except OSError as exc:
            raise ResultsWriteError(
                f"{write_problem(exc)}: the summary could not be written; {out / 'runs.csv'} "
                f"keeps all {len(rows)} finished rows"
            ) from exc
        return summary, markdown
