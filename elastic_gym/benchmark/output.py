"""The output folder of a benchmark: one writer at a time, and an earlier result replaced
only by a whole new one.

A result is ``runs/`` (the comparison), ``scores.png``, ``scorecard.md`` and
``scorecard.json``. A run that replaces one (``overwrite``) writes the new result into
`STAGING` inside the folder and `swap_in` moves it in at the end, the card last, with
SIGINT and SIGTERM held for the few renames; until then the earlier result is untouched,
and a run that fails or is interrupted before discards the new one (`discard`). Leftovers of
a killed run (`STAGING`, `OUTGOING`) are removed by the next writer, which holds the
folder's lock (`elastic_gym.runtime.folder_lock`).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import threading
from collections.abc import Iterator
from pathlib import Path

from elastic_gym.benchmark.scorecard import FIGURE_FILE, JSON_FILE, MARKDOWN_FILE

RUNS_DIR = "runs"
RESULT = (RUNS_DIR, FIGURE_FILE, MARKDOWN_FILE, JSON_FILE)  # the order of the swap
STAGING, OUTGOING = ".incoming", ".outgoing"


def earlier_result(folder: Path) -> list[str]:
    """The parts of an earlier result in ``folder`` (names of `RESULT`)."""
    return [name for name in RESULT if (folder / name).exists()]


def discard(path: Path) -> None:
    """Remove a staged (or outgoing) result, if there is one."""
    if path.is_dir():
        shutil.rmtree(path, ignore_errors=True)


def clear_leftovers(folder: Path) -> None:
    """Remove what a killed run left in ``folder`` (its caller holds the folder's lock)."""
    discard(folder / STAGING)
    discard(folder / OUTGOING)


@contextlib.contextmanager
def signals_held() -> Iterator[None]:
    """SIGINT and SIGTERM held (delivered at the end) inside the block (main thread only:
    elsewhere Python never runs signal handlers anyway)."""
    held = {signal.SIGINT, signal.SIGTERM}
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, held)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def swap_in(folder: Path, parts: tuple[str, ...] = RESULT) -> None:
    """Replace ``parts`` of the result in ``folder`` by those in ``folder / STAGING``: the
    earlier ones are moved aside, the new ones in (``scorecard.json`` last, replaced in
    one rename), the earlier ones removed. A part the new result lacks (no figure) goes."""
    staging, outgoing = folder / STAGING, folder / OUTGOING
    with signals_held():
        outgoing.mkdir(exist_ok=True)
        for name in (p for p in RESULT[:-1] if p in parts):
            if (folder / name).exists():
                os.replace(folder / name, outgoing / name)
            if (staging / name).exists():
                os.replace(staging / name, folder / name)
        os.replace(staging / JSON_FILE, folder / JSON_FILE)
    discard(outgoing)
    discard(staging)
