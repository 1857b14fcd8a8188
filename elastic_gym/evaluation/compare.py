"""The comparison: plan the grid, check it, run it in parallel, write tables and plots.

``compare(load_preset("default"))`` returns the runs and the summary over seeds (pandas
DataFrames, lists of dicts without pandas). Everything that can fail without running is
checked first (:mod:`~elastic_gym.evaluation.preflight`). The output folder holds
``runs.csv`` (a row per run, as it finishes), ``summary.csv`` / ``summary.md``,
``scenario.yaml`` and ``plots/``; with sweeps also ``margins.csv`` / ``margins.md`` and
``curves/``. An earlier comparison's folder is refused unless ``overwrite``, a folder
another process writes into always (:mod:`~elastic_gym.runtime.folder_lock`). A run that fails
(raises, calls ``sys.exit``, kills its process) is a row ``failed: <Type>: <message>``
(counted in ``summary.md`` and ``Comparison.failed``); a full disk raises
:class:`~elastic_gym.evaluation.output.ResultsWriteError` saying what ``runs.csv`` kept.
Runs and checks run in spawned workers (one with ``workers=1``), which import a script's
``__main__`` only for classes defined there: then several workers need the ``__main__``
guard, and one worker runs them here (:func:`~elastic_gym.runtime.parallel.for_each_result`).
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml
from rich.console import Console

from elastic_gym.evaluation.groups import DEFAULT_BATCH_SIZE, plan_groups
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
from elastic_gym.evaluation.preflight import check_plot_names, preflight
from elastic_gym.evaluation.report import (
    as_table,
    markdown_table,
    run_row,
    summary_rows,
    write_csv,
)
from elastic_gym.evaluation.runner import (
    RunResult,
    RunSpec,
    SkippedRun,
    group_workers,
    plan_runs,
    run_groups,
)
from elastic_gym.evaluation.scenario import NOMINAL, SWEEP_AXIS, Scenario
from elastic_gym.evaluation.sweeps import context_columns, sweep_curves
from elastic_gym.runtime.folder_lock import check_writable, folder_lock
from elastic_gym.runtime.parallel import (
    DEFAULT_BACKEND,
    interrupts_raised,
    resolve_workers,
    with_detail,
)
from elastic_gym.validation import checked_count

DEFAULT_OUTPUT_ROOT = Path("compare_out")


@dataclass
class Comparison:
    """Everything a comparison produced.

    ``runs`` (one row per run) and ``summary`` (per scenario, controller and source: the
    mean of each metric over the seeds and its spread ``<metric>_std``) are pandas
    ``DataFrame`` objects when pandas is installed, lists of row dicts otherwise.
    """

    scenario: Scenario
    runs: Any
    summary: Any
    skipped: list[SkippedRun]
    markdown: str
    output_dir: Path
    files: list[Path] = field(default_factory=list)
    failed: int = 0  # runs with status "failed: ..."


def compare(
    scenario: Scenario,
    output_dir: str | Path | None = None,
    workers: int | None = None,
    backend: str = DEFAULT_BACKEND,
    progress: bool = True,
    plots: bool = True,
    overwrite: bool = False,
    console: Console | None = None,
    batch_size: int = DEFAULT_BATCH_SIZE,
) -> Comparison:
    """Run every applicable run of ``scenario`` and write the tables (and plots).

    Args:
        scenario: the grid (:func:`~elastic_gym.evaluation.load_preset`, ``Scenario.from_dict``).
        output_dir: output folder (default ``./compare_out/<scenario.name>``).
        workers: parallel worker processes (default: one per CPU, at most one per run).
        backend: ``"process"`` (local processes) or ``"ray"``.
        progress: show a progress bar.
        plots: write the PNG figures.
        overwrite: replace the files of an earlier comparison in ``output_dir``.
        console: where to print the summary table (default: stdout; silence it with
            ``Console(quiet=True)``).
        batch_size: most arms in one world (:mod:`~elastic_gym.evaluation.groups`);
            1 runs every run in a world of its own (the same rows).

    Raises (before any run, changing nothing): ``ScenarioError`` naming the field that
    cannot work, ``NotADirectoryError`` / ``PermissionError`` / ``FileExistsError`` for
    the output folder, ``ValueError`` for the other arguments.
    """
    checked_count(batch_size, "batch_size", 1)
    out = Path(output_dir) if output_dir is not None else DEFAULT_OUTPUT_ROOT / scenario.name
    check_writable(out)
    with folder_lock(out):
        return _compare(
            scenario, out, workers, backend, progress, plots, overwrite, console, batch_size
        )


def _compare(
    scenario: Scenario,
    out: Path,
    workers: int | None,
    backend: str,
    progress: bool,
    plots: bool,
    overwrite: bool,
    console: Console | None,
    batch_size: int,
) -> Comparison:
    """:func:`compare` once the output folder is locked."""
    console = console or Console()
    runs, skipped = plan_runs(scenario)
    if not runs:
        raise ValueError(
            f"scenario {scenario.name!r} has no applicable run "
            f"({len(skipped)} combinations skipped: {skipped[:3]})"
        )
    n_workers = resolve_workers(workers, len(runs), backend)
    groups = plan_groups(runs, batch_size, n_workers)
    check_output_folder(out, overwrite)
    if plots:
        check_plot_names(scenario, runs)
    with group_workers(groups, n_workers, backend) as pool:  # started: the check runs in one
        with interrupts_raised():  # a real Ctrl-C is not taken for the sampled user code's own
            estimate = preflight(scenario, groups, n_workers, pool)
        skipped_note = _skipped_note(skipped)
        console.print(
            f"[bold]{scenario.name}[/bold]: {len(runs)} runs in {len(groups)} "
            f"{'world' if len(groups) == 1 else 'worlds'} on {n_workers} "
            f"{'worker' if n_workers == 1 else 'workers'}, {estimate}"
        )
        console.print(skipped_note, markup=False, end="")

        if overwrite:
            clear_results(out)
        out.mkdir(parents=True, exist_ok=True)
        try:
            write_atomic(out / "scenario.yaml", yaml.safe_dump(scenario.to_dict(), sort_keys=False))
        except OSError as exc:
            raise ResultsWriteError(f"{write_problem(exc)}: nothing written in {out}/") from exc
        sink = _Sink(out, runs, plots)
        try:
            run_groups(groups, sink.add_group, n_workers, backend, progress, pool)
        except BaseException as exc:
            rows = sink.csv.finish()
            kept = f"kept the {len(rows)} finished of {len(runs)} runs in {out}/"
            _write_tables(scenario, out, rows, skipped_note + f"\nInterrupted: {kept}.\n")
            raise with_detail(exc, kept)  # noqa: B904 - with_detail sets the cause
    rows = sink.csv.finish()
    failed = [row["status"] for row in rows if row["status"].startswith("failed")]
    failed_note = (
        f"{len(failed)} of {len(rows)} runs failed (status column of runs.csv), e.g. {failed[0]}\n"
        if failed
        else ""
    )
    summary, markdown = _write_tables(scenario, out, rows, skipped_note + failed_note)
    files = [
        out / "runs.csv",
        out / "summary.csv",
        out / "summary.md",
        out / "scenario.yaml",
        *sink.plots,
    ]
    if scenario.sweeps:
        curves = sweep_curves(scenario, rows)
        files += write_margins(margin_rows(curves), context_columns(scenario), out, scenario.name)
        if plots:
            from elastic_gym.evaluation.curves import plot_all_curves  # matplotlib, see _Sink

            files += plot_all_curves(curves, out / CURVE_DIR)
    console.print(markdown, soft_wrap=True, markup=False)  # long lines are not cut
    console.print(failed_note, markup=False, end="")
    if scenario.sweeps:
        console.print(f"robustness margins: {out / 'margins.md'}", markup=False)
    console.print(f"written to {out}/")
    return Comparison(
        scenario, as_table(rows), as_table(summary), skipped, markdown, out, files, len(failed)
    )


class _Sink:
    """Receives each result as it arrives: writes its row, plots its group once all of
    the group's runs are in (in run order), and drops the time series."""

    def __init__(self, out: Path, runs: list[RunSpec], plots: bool) -> None:
        self.csv = RunsCsv(out / "runs.csv")
        self.plot_dir = out / PLOT_DIR if plots else None
        self.remaining = Counter(spec.group for spec in runs)
        self.waiting: dict[tuple, list[RunResult]] = {}
        self.plots: list[Path] = []

    def add_group(self, index: int, results: list[RunResult]) -> None:
        for result in results:
            self.add(result)

    def add(self, result: RunResult) -> None:
        self.csv.add(result.spec.index, run_row(result))
        if self.plot_dir is None or result.spec.labels.get(SWEEP_AXIS, NOMINAL) != NOMINAL:
            return  # a sweep's runs are summarized by its curves
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

                self.plots += plot_results(members, self.plot_dir)


def _write_tables(
    scenario: Scenario, out: Path, rows: list[dict], note: str
) -> tuple[list[dict], str]:
    identity = scenario.identity_columns
    summary = summary_rows(rows, identity)
    markdown = markdown_table(summary, identity)
    try:
        write_csv(summary, out / "summary.csv")
        write_atomic(
            out / "summary.md", f"# {scenario.name}\n\n{scenario.description}\n\n{markdown}\n{note}"
        )
    except OSError as exc:
        raise ResultsWriteError(
            f"{write_problem(exc)}: the summary could not be written; {out / 'runs.csv'} "
            f"keeps all {len(rows)} finished rows"
        ) from exc
    return summary, markdown


def _skipped_note(skipped: list[SkippedRun]) -> str:
    """One line per reason: how many combinations were skipped because they do not apply."""
    counts: dict[str, int] = {}
    for run in skipped:
        counts[run.reason] = counts.get(run.reason, 0) + 1
    return "".join(f"skipped {n} runs: {reason}\n" for reason, n in counts.items())
