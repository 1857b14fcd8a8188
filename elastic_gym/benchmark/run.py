"""Score one entry on a suite: :func:`run_benchmark`, the Python form of ``elastic-gym benchmark``.

The suite's cells become the env entries of one comparison grid
(:func:`~elastic_gym.benchmark.suite.suite_scenario`) run by the comparison itself
(:func:`elastic_gym.evaluation.compare`: the checks before the first run, the run count and
time estimate, the progress bar, local worker processes or Ray, the per-run table on disk);
the benchmark adds the scoring (:mod:`~elastic_gym.benchmark.scoring`) and the scorecard
(:mod:`~elastic_gym.benchmark.scorecard`).

Output folder (default ``./benchmark_out/<entry label>``): ``scorecard.json``,
``scorecard.md``, ``scores.png`` and ``runs/`` (the comparison's ``runs.csv``,
``summary.csv``, ``summary.md``, ``scenario.yaml`` and ``compare.log``, its printed output
after the first line). A folder holding an earlier scorecard is refused unless ``overwrite``.
"""

from __future__ import annotations

import io
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
from elastic_gym.benchmark.scorecard import JSON_FILE, build_scorecard, write_scorecard
from elastic_gym.benchmark.scoring import compute_scores, score_episodes
from elastic_gym.benchmark.suite import (
    DEFAULT_SUITE,
    SuiteConfig,
    list_suites,
    load_suite,
    suite_scenario,
)
from elastic_gym.runtime.folder_lock import check_free
from elastic_gym.runtime.parallel import DEFAULT_BACKEND
from elastic_gym.validation import validated

DEFAULT_OUTPUT_ROOT = Path("benchmark_out")
RUNS_DIR = "runs"


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
) -> Scorecard:
    """Run every cell and seed of ``suite`` with ``entry`` and return its scorecard (also
    written to ``output_dir``, see the module docstring).

    Args:
        entry: an :class:`~elastic_gym.benchmark.entry.Entry` or its fields, e.g.
            ``{"controller": "feedforward-state-feedback", "source": "deluca"}``,
            ``{"controller": "mypkg.ctl:MyController", "source": "mypkg.obs:MyObserver"}``,
            ``{"run": "runs/ppo-TwoLinkElastic-v0-deluca"}``, or
            ``{"controller": "policy", "options": {"policy": my_callable}, "source": "ekf"}``.
        suite: a suite, a shipped suite's name or a suite file.
        robots: score on these robots of the suite only (default: all; a run folder: the
            robots of the env it was trained on). Scores of a subset are not leaderboard
            scores of the suite.
        output_dir, workers, backend, progress, overwrite: as for ``elastic-gym compare``.
        figure: write ``scores.png``.

    Raises ``ValueError`` (field path first) for a bad entry, suite or robot, and the
    comparison's errors for everything its checks refuse, before any run.
    """
    from elastic_gym.evaluation import compare
    from elastic_gym.evaluation.output import check_output_folder

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
    scenario = suite_scenario(suite, controller, source, robots, name=_slug(entry.name))
    out = Path(output_dir) if output_dir is not None else DEFAULT_OUTPUT_ROOT / _slug(entry.name)
    scorecard = [JSON_FILE] if (out / JSON_FILE).exists() else []
    check_free(out, lambda: scorecard, "an earlier scorecard", "--output", overwrite)
    check_output_folder(out / RUNS_DIR, overwrite)  # refuses a file, in ``out`` or above
    start, cpu_start = time.perf_counter(), _cpu_seconds()
    (out / RUNS_DIR).mkdir(parents=True, exist_ok=True)
    with open(out / RUNS_DIR / "compare.log", "w") as log:
        comparison = compare(
            scenario,
            output_dir=out / RUNS_DIR,
            workers=workers,
            backend=backend,
            progress=progress,
            plots=False,
            overwrite=overwrite,
            console=Console(file=_FirstLine(log), soft_wrap=True),  # type: ignore[arg-type]
        )
    rows = comparison.runs
    rows = rows.to_dict("records") if hasattr(rows, "to_dict") else list(rows)
    episodes = score_episodes(suite, rows)
    scores = compute_scores(suite, episodes)
    used = sorted({c.robot for c in suite.cells if c.id in {e.cell for e in episodes}})
    used.sort(key=list(suite.robots).index)
    wall, cpu = time.perf_counter() - start, _cpu_seconds() - cpu_start
    card = build_scorecard(suite, record, used, episodes, scores, command, wall, cpu)
    write_scorecard(card, out, suite, figure)
    print(
        f"{card.label}: overall {card.scores.overall:.3f}, {scores.passed} of "
        f"{scores.episodes} episodes pass ({wall:.0f} s, {cpu:.0f} s CPU); scorecard in {out}/"
    )
    return card


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
