"""Helpers shared by the benchmark scripts: one-core BLAS, interleaved timing, tables.

Timings are ratios measured in one run on one machine. Every quantity is timed in
blocks, the blocks of the quantities being compared run in turn (interleaved), and the
best block of each is kept: on a shared machine, load from other processes only ever
adds time, so the best block is the closest to the cost of the code itself. Work done in
this process is timed in CPU time of the process (``time.process_time``: the time spent
waiting for a core busy with other processes is not counted); work spread over worker
processes is timed in wall time.
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable, Iterable, Mapping, Sequence

from rich import box
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from elastic_gym.runtime.parallel import SINGLE_THREAD_ENV

TABLE_WIDTH = 160  # characters: tables are not cut to a narrow (or absent) terminal


def ensure_single_thread_blas() -> None:
    """Re-run the current script with single-threaded BLAS ("one core").

    OpenBLAS reads its thread count when numpy loads it, i.e. before a script can set
    it, so the script is executed again with the variables set (Linux/macOS ``execve``).
    """
    if all(os.environ.get(key) == value for key, value in SINGLE_THREAD_ENV.items()):
        return
    os.execve(sys.executable, [sys.executable, *sys.argv], {**os.environ, **SINGLE_THREAD_ENV})


def machine_line() -> str:
    """The header of a benchmark's output: the CPUs and the load average while it runs
    (other processes slow the timings)."""
    load = ", ".join(f"{x:.2f}" for x in os.getloadavg())
    return f"{os.cpu_count()} CPUs, load average {load}"


def seconds_per_call(
    function: Callable[..., object],
    arguments: Sequence[tuple],
    clock: Callable[[], float] = time.process_time,
) -> float:
    """Mean time (s) of ``function(*args)`` over the argument tuples: CPU time of this
    process by default, ``clock=time.perf_counter`` for wall time (worker processes)."""
    start = clock()
    for args in arguments:
        function(*args)
    return (clock() - start) / len(arguments)


def interleaved_best(blocks: Mapping[str, Callable[[], float]], repeats: int) -> dict[str, float]:
    """Best seconds-per-call of each block; the blocks run in turn ``repeats`` times.

    Each block runs a batch of calls and returns its own seconds per call (so that it
    can leave set-up work, e.g. an observer reset, out of the timed part).
    """
    best = dict.fromkeys(blocks, float("inf"))
    for _ in range(repeats):
        for name, block in blocks.items():
            best[name] = min(best[name], block())
    return best


def print_table(
    title: str,
    headers: Sequence[str],
    rows: Iterable[Sequence[object]],
    console: Console | None = None,
) -> None:
    """A markdown-compatible table (pastes into reports and READMEs)."""
    table = Table(
        *(escape(h) for h in headers), title=escape(title), box=box.MARKDOWN, title_justify="left"
    )
    for row in rows:
        table.add_row(*(escape(str(cell)) for cell in row))
    (console or Console(width=TABLE_WIDTH)).print(table)
