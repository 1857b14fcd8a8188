"""Score one entry on a suite: `run_benchmark`, the Python form of ``elastic-gym benchmark``.

The suite's cells become the env entries of one comparison grid
(`elastic_gym.benchmark.suite.suite_scenario`) run by the comparison itself
(`elastic_gym.evaluation.compare`: checks before the first run, the time estimate, the
progress bar, worker processes or Ray, the per-run table on disk); the benchmark adds the
scoring (`elastic_gym.benchmark.scoring`) and the scorecard. With ``rescore`` the runs of
an earlier benchmark (``runs/runs.csv``) are scored again instead, nothing is run.

Output folder (default ``./benchmark_out/<entry label>``): ``scorecard.json``,
``scorecard.md``, ``scores.png`` and ``runs/`` (the comparison's files and ``compare.log``).
One writer at a time (another is refused, naming its process); an earlier result is
refused unless ``overwrite``, and then replaced only by a whole new one
(`elastic_gym.benchmark.output`).
"""

from __future__ import annotations

import csv
import io
import math
import re
import resource
import sys
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from rich.console import Console

from elastic_gym.benchmark.card import Scorecard
from elastic_gym.benchmark.command import entry_command
from elastic_gym.benchmark.entry import Entry, describe_entry, resolve_entry
from elastic_gym.benchmark.output import (
    RESULT,
    RUNS_DIR,
    STAGING,
    clear_leftovers,
    discard,
    earlier_result,
    swap_in,
)
from elastic_gym.benchmark.scorecard import (
    FIGURE_FILE,
    MARKDOWN_FILE,
    build_scorecard,
    write_scorecard,
)
from elastic_gym.benchmark.scoring import compute_scores, score_episodes
from elastic_gym.benchmark.suite import (
    DEFAULT_SUITE,
    SuiteConfig,
    list_suites,
    load_suite,
    suite_scenario,
)
from elastic_gym.evaluation.scenario import Scenario
from elastic_gym.evaluation.tables import columns
from elastic_gym.runtime.folder_lock import check_writable, folder_lock
from elastic_gym.runtime.parallel import DEFAULT_BACKEND, with_detail
from elastic_gym.validation import validated

DEFAULT_OUTPUT_ROOT = Path("benchmark_out")
RUNS_FILE = "runs.csv"


def run_benchmark(
    entry: Entry | Mapping[str, Any],
    suite: SuiteConfig | str | Path = DEFAULT_SUITE,
    robots: list[str] | None = None,
    output_dir: str | Path | None = None,
    workers: int | None = None,
    backend: str = DEFAULT_BACKEND,
    progress: bool = True,
    overwrite: bool = False,
    figure: bool = True,
    rescore: bool = False,
) -> Scorecard:
    """Run every cell and seed of ``suite`` with ``entry`` and return its scorecard (also
    written to ``output_dir``, see the module docstring).

    Args:
        entry: an `Entry` or its fields, e.g.
            ``{"controller": "feedforward-state-feedback", "source": "deluca"}``,
            ``{"controller": "mypkg.ctl:MyController", "source": "mypkg.obs:MyObserver"}``,
            ``{"run": "runs/ppo-TwoLinkElastic-v0-deluca"}``, or
            ``{"controller": "policy", "options": {"policy": my_callable}, "source": "ekf"}``.
        suite: a suite, a shipped suite's name or a suite file.
        robots: score on these robots of the suite only (default: all; a run folder: the
            robots of the env it was trained on). Such a card is listed apart on the
            leaderboard, unranked.
        output_dir, workers, backend, progress: as for ``elastic-gym compare``.
        overwrite: replace an earlier result in ``output_dir`` (once the new one is whole).
        figure: write ``scores.png``.
        rescore: score ``output_dir/runs/runs.csv`` of an earlier run of this entry instead
            of running (``ValueError`` if it lacks runs or holds another entry's).

    Raises ``ValueError`` (field path first) for a bad entry, suite or robot,
    ``FileExistsError`` for a folder holding an earlier result or in use by another
    process, and the comparison's errors for everything its checks refuse, before any run.
    """
    entry = validated(Entry, entry, prefix="entry")
    suite_name = suite_argument(suite)
    if not isinstance(suite, SuiteConfig):
        suite = load_suite(suite)
    controller, source = resolve_entry(entry)
    record = describe_entry(entry)
    command = entry_command(entry, suite_name, robots) if suite_name else None
    if robots is None and entry.run is not None:
        robots = [r for r, e in suite.robots.items() if e.env == record["run"]["env_id"]]
        if not robots:
            raise ValueError(
                f"run: trained on {record['run']['env_id']}, which is not a robot of "
                f"{suite.name} ({sorted(e.env for e in suite.robots.values())})"
            )
    scenario = suite_scenario(
        suite, controller, source, robots, name=_slug(entry.name), models=entry.models
    )
    _check_applicable(scenario, suite)
    out = Path(output_dir) if output_dir is not None else DEFAULT_OUTPUT_ROOT / _slug(entry.name)
    check_writable(out)
    with folder_lock(out):  # another writer: "in use by process N"
        found = earlier_result(out)
        if rescore:
            found = [name for name in found if name != RUNS_DIR]
        if found and not overwrite:
            raise FileExistsError(
                f"output folder {str(out)!r} holds an earlier result ({', '.join(found)}); "
                "choose another --output, or replace it with --overwrite (overwrite=True)"
            )
        clear_leftovers(out)
        stage = bool(found)
        target = out / STAGING if stage else out
        start, cpu_start = time.perf_counter(), _cpu_seconds()
        try:
            if rescore:
                rows = _runs_of(out / RUNS_DIR / RUNS_FILE, scenario)
                note = f"re-scored from {RUNS_DIR}/{RUNS_FILE} (the run's own times unknown)"
            else:
                rows, note = _run(scenario, target / RUNS_DIR, workers, backend, progress), None
            episodes = score_episodes(suite, rows)
            scores = compute_scores(suite, episodes)
            used = [r for r in suite.robots if any(e.cell.startswith(f"{r}/") for e in episodes)]
            wall, cpu = time.perf_counter() - start, _cpu_seconds() - cpu_start
            card = build_scorecard(suite, record, used, episodes, scores, command, wall, cpu, note)
            _write(card, target, suite, figure, out, stage)
        except BaseException as exc:
            if not stage:
                raise
            discard(out / STAGING)
            raise _kept(exc, out)  # noqa: B904 - _kept sets the cause
        if stage:
            swap_in(out, RESULT[1:] if rescore else RESULT)
    print(
        f"{card.label}: overall {card.scores.overall:.3f}, {scores.passed} of "
        f"{scores.episodes} episodes pass ({wall:.0f} s, {cpu:.0f} s CPU); scorecard in {out}/"
    )
    return card


def _kept(exc: BaseException, out: Path) -> BaseException:
    """What to raise when a run that was to replace the result in ``out`` failed and its
    new result was discarded: a refused input as it is (nothing was replaced), else the
    error or interrupt saying that the earlier result is kept."""
    kept = f"the earlier result in {out}/ is kept, the new one discarded"
    if isinstance(exc, (ValueError, FileExistsError)):
        return exc
    if isinstance(exc, Exception):
        from elastic_gym.evaluation.output import write_problem

        reason = write_problem(exc) if isinstance(exc, OSError) else str(exc)
        replacement = RuntimeError(f"the new result could not be made ({reason}): {kept}")
        replacement.__cause__ = exc
        return replacement
    return with_detail(exc, kept)


def _check_applicable(scenario: Scenario, suite: SuiteConfig) -> None:
    """``ValueError`` in one line when no run of the grid applies (e.g. a classical
    controller on raw sensors): the distinct reasons, not the skipped runs."""
    from elastic_gym.evaluation import plan_runs

    runs, skipped = plan_runs(scenario)
    if not runs:
        reasons = sorted({s.reason for s in skipped})
        raise ValueError(f"entry: no run of {suite.name} applies: " + "; ".join(reasons))


def _run(
    scenario: Scenario, folder: Path, workers: int | None, backend: str, progress: bool
) -> list[dict]:
    """The comparison's rows, its files in ``folder``."""
    from elastic_gym.evaluation import compare

    folder.mkdir(parents=True, exist_ok=True)
    with open(folder / "compare.log", "w") as log:
        comparison = compare(
            scenario,
            output_dir=folder,
            workers=workers,
            backend=backend,
            progress=progress,
            plots=False,
            console=Console(file=_FirstLine(log), soft_wrap=True),  # type: ignore[arg-type]
            dataframes=False,
        )
    return records(comparison.runs)


def records(rows: list[dict]) -> list[dict]:
    """The rows as the records of one table: every column any row has, in first-seen
    order, NaN where a row has none (what pandas' ``DataFrame(rows).to_dict("records")``
    gives, without importing pandas)."""
    keys = columns(rows)
    return [{key: row.get(key, math.nan) for key in keys} for row in rows]


def _runs_of(path: Path, scenario: Scenario) -> list[dict]:
    """The rows of an earlier run's ``runs.csv``, checked to be every run of this entry's
    grid (``ValueError`` naming the file otherwise)."""
    from elastic_gym.evaluation import plan_runs

    try:
        with open(path, newline="") as handle:
            rows = list(csv.DictReader(handle))
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise ValueError(f"--rescore: cannot read {path}: {exc}") from None
    wanted = {(c.label, s.label) for c in scenario.controllers for s in scenario.state_sources}
    other = sorted({(r.get("controller"), r.get("source")) for r in rows} - wanted)
    if other:
        raise ValueError(
            f"{path}: runs of controller/source {other}, not of this entry {sorted(wanted)}"
        )
    runs, _ = plan_runs(scenario)
    have = {(r.get("env"), r.get("seed")) for r in rows}
    missing = [r for r in runs if (r.labels["env"], str(r.seed)) not in have]
    if missing:
        shown = ", ".join(f"{r.labels['env']} seed {r.seed}" for r in missing[:3])
        raise ValueError(
            f"{path}: {len(missing)} of the entry's {len(runs)} runs missing ({shown}, ...): "
            "the benchmark did not finish; run it again"
        )
    return rows


def _write(
    card: Scorecard, target: Path, suite: SuiteConfig, figure: bool, out: Path, staged: bool
) -> None:
    """Write the card's files; a failure removes those written and names what is kept (the
    runs, for ``--rescore``)."""
    from elastic_gym.evaluation.output import ResultsWriteError, write_problem

    try:
        write_scorecard(card, target, suite, figure)
    except OSError as exc:
        if staged:
            raise
        for name in (FIGURE_FILE, MARKDOWN_FILE):  # a card's views without the card
            (target / name).unlink(missing_ok=True)
        raise ResultsWriteError(
            f"{write_problem(exc)}: the scorecard could not be written; the runs are kept in "
            f"{out / RUNS_DIR / RUNS_FILE}: score them with the same command and --rescore"
        ) from exc


def suite_argument(suite: SuiteConfig | str | Path) -> str | None:
    """How a command line names ``suite``: a shipped suite by its name, a file by its
    path as given (``None`` for a suite object that is neither)."""
    if isinstance(suite, SuiteConfig):
        shipped = suite.name in list_suites() and load_suite(suite.name).hash == suite.hash
        return suite.name if shipped else None
    return str(suite)


def _cpu_seconds() -> float:
    """CPU time of this process and its finished child processes (the workers) so far."""
    own, children = (
        resource.getrusage(w) for w in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN)
    )
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def _slug(label: str) -> str:
    """A file-system-safe folder name for an entry label."""
    return re.sub(r"[^A-Za-z0-9_.@+-]+", "_", label).strip("._") or "entry"


class _FirstLine(io.TextIOBase):
    """A text stream that shows its first line (the comparison's run count and time
    estimate) on stdout and writes everything else to ``log``."""

    def __init__(self, log: io.TextIOBase) -> None:
        self.log, self.shown = log, False

    def write(self, text: str) -> int:
        if not self.shown:
            head, newline, rest = text.partition("\n")
            sys.stdout.write(head + newline)
            sys.stdout.flush()
            self.shown = bool(newline)
            text = rest
        self.log.write(text)
        return len(text)

    def writable(self) -> bool:
        return True
