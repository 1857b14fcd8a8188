"""The comparison: plan → execute → report.

``compare(load_preset("default"))`` returns the runs and the summary over seeds (pandas
DataFrames, lists of dicts without pandas), through three stages, data flowing one way:
plan ([`make_plan`][elastic_gym.evaluation.plan.make_plan]: the runs and the worlds they
share), execute ([`run_plan`][elastic_gym.evaluation.execute.run_plan]: the pre-run check,
then every world's closed loop, with recovery of failed runs and dead workers) and report
([`Report`][elastic_gym.evaluation.report.Report]: ``runs.csv`` row by row, ``summary.csv``
/ ``summary.md``, ``scenario.yaml``, ``plots/``; with sweeps ``margins.*`` and ``curves/``).
An earlier comparison's folder is refused unless ``overwrite``, a folder another process
writes into always. A run that fails (raises, calls ``sys.exit``, kills its process) is a
row ``failed: <Type>: <message>``. Runs and checks run in worker processes, which import a
script's ``__main__`` only for classes defined there: then several workers need the
``__main__`` guard, and one worker runs them in this process.
"""

from __future__ import annotations

from pathlib import Path

from rich.console import Console

from elastic_gym.evaluation.execute import run_plan
from elastic_gym.evaluation.groups import DEFAULT_BATCH_SIZE
from elastic_gym.evaluation.plan import make_plan
from elastic_gym.evaluation.report import Comparison, Report
from elastic_gym.evaluation.scenario import Scenario
from elastic_gym.runtime.folder_lock import check_writable, folder_lock
from elastic_gym.runtime.parallel import DEFAULT_BACKEND
from elastic_gym.validation import checked_count

DEFAULT_OUTPUT_ROOT = Path("compare_out")


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
    dataframes: bool = True,
) -> Comparison:
    """Run every applicable run of ``scenario`` and write the tables (and plots).

    Args:
        scenario: the grid (`load_preset`,
            ``Scenario.from_dict``).
        output_dir: output folder (default ``./compare_out/<scenario.name>``).
        workers: parallel worker processes (default: one per CPU, at most one per run).
        backend: ``"process"`` (local processes) or ``"ray"``.
        progress: show a progress bar.
        plots: write the PNG figures.
        overwrite: replace the files of an earlier comparison in ``output_dir``.
        console: where to print the summary table (default: stdout; silence it with
            ``Console(quiet=True)``).
        batch_size: most arms in one world
            ([`elastic_gym.evaluation.groups`][elastic_gym.evaluation.groups]); 1 runs every
            run in a world of its own (the same rows).
        dataframes: return ``runs`` and ``summary`` as pandas DataFrames (when pandas is
            installed); False: as lists of row dicts (pandas is not imported).

    Raises (before any run, changing nothing): ``ScenarioError`` naming the field that
    cannot work, ``NotADirectoryError`` / ``PermissionError`` / ``FileExistsError`` for
    the output folder, ``ValueError`` for the other arguments.
    """
    checked_count(batch_size, "batch_size", 1)
    out = Path(output_dir) if output_dir is not None else DEFAULT_OUTPUT_ROOT / scenario.name
    check_writable(out)
    with folder_lock(out):
        plan = make_plan(scenario, workers, backend, batch_size)
        report = Report(plan, out, plots, overwrite, console or Console())
        run_plan(plan, report, progress)
        return report.finish(dataframes)
