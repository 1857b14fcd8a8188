"""The output folder of a comparison: checked before the first run, filled as runs finish.

A comparison writes ``runs.csv``, ``summary.csv``, ``summary.md``, ``scenario.yaml``
and ``plots/*.png`` (a sweep: also ``margins.csv``, ``margins.md`` and ``curves/*.png``)
in its folder, and nothing elsewhere. Before any run,
:func:`check_output_folder` refuses a folder that is a file, that cannot be written,
or that holds the results of an earlier comparison (old figures would stay beside the
new ones) unless ``overwrite`` is given; :func:`clear_results` then removes those
files (only those). :class:`RunsCsv` writes ``runs.csv`` row by row as runs finish,
so that an interrupted or crashed comparison keeps every finished run on disk.
"""

from __future__ import annotations

import csv
import re
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import TextIO

RESULT_FILES = (
    "runs.csv",
    "summary.csv",
    "summary.md",
    "scenario.yaml",
    "margins.csv",
    "margins.md",
)
PLOT_DIR = "plots"
CURVE_DIR = "curves"
FIGURE_DIRS = (PLOT_DIR, CURVE_DIR)
MAX_NAME_BYTES = 255  # longest file name on common file systems (ext4, APFS, NTFS)


def plot_file_name(group: Sequence) -> str:
    """File name of the figure of a group of runs: its labels joined by ``__``, every
    run of characters other than letters, digits, ``.``, ``+`` and ``-`` replaced by
    ``_``, and ``.png``."""
    stem = re.sub(r"[^A-Za-z0-9.+-]+", "_", "__".join(str(g) for g in group)).strip("_")
    return f"{stem}.png"


def folder_name_problem(name: str) -> str | None:
    """Why ``name`` cannot be a single folder inside another one (``None`` if it can)."""
    if name in ("", ".", ".."):
        return f"must name a folder, got {name!r}"
    if any(c in name for c in "/\\\0"):
        return f"must be a plain folder name without '/', '\\\\' or NUL, got {name!r}"
    if len(name.encode()) > MAX_NAME_BYTES:
        return f"is longer than {MAX_NAME_BYTES} bytes, the limit of a file name"
    return None


def earlier_results(folder: Path) -> list[str]:
    """Files of an earlier comparison in ``folder`` (relative names)."""
    found = [name for name in RESULT_FILES if (folder / name).exists()]
    for figures in FIGURE_DIRS:
        if (folder / figures).is_dir():
            found += sorted(f"{figures}/{p.name}" for p in (folder / figures).glob("*.png"))
    return found


def check_output_folder(folder: Path, overwrite: bool) -> None:
    """Raise before any run if ``folder`` cannot receive the results; changes nothing.

    ``NotADirectoryError``: it (or a parent) is a file. ``PermissionError``: no file can
    be created in it (or in the parent it would be created in). ``FileExistsError``: it
    holds the files of an earlier comparison and ``overwrite`` is false.
    """
    existing = folder
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir():
        raise NotADirectoryError(
            f"output folder {str(folder)!r}: {str(existing)!r} is a file, not a folder"
        )
    try:
        with tempfile.TemporaryFile(dir=existing):
            pass
    except OSError as exc:
        raise PermissionError(
            f"output folder {str(folder)!r}: cannot write in "
            f"{str(existing)!r} ({exc.strerror or exc})"
        ) from None
    if existing == folder and not overwrite:
        earlier = earlier_results(folder)
        if earlier:
            shown = ", ".join(earlier[:5]) + (", ..." if len(earlier) > 5 else "")
            raise FileExistsError(
                f"output folder {str(folder)!r} holds the results of an earlier comparison "
                f"({shown}); choose another folder, or replace them with --overwrite "
                "(overwrite=True)"
            )


def clear_results(folder: Path) -> None:
    """Remove the files a comparison writes (and nothing else) from ``folder``."""
    for name in earlier_results(folder):
        (folder / name).unlink()
    for figures in FIGURE_DIRS:
        if (folder / figures).is_dir() and not any((folder / figures).iterdir()):
            (folder / figures).rmdir()


class RunsCsv:
    """``runs.csv`` written as rows arrive (any order), flushed after each row.

    A row with a column not seen before (the diagnostics of another observer) rewrites
    the file with the wider header; :meth:`finish` rewrites it in run order.
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self.rows: dict[int, dict] = {}
        self.fields: list[str] = []
        self._handle: TextIO | None = None
        self._writer: csv.DictWriter | None = None

    def add(self, index: int, row: dict) -> None:
        self.rows[index] = row
        new = [key for key in row if key not in self.fields]
        if new or self._writer is None:
            self.fields += new
            self._rewrite(self.rows.values())
        else:
            self._writer.writerow(row)
        assert self._handle is not None  # opened by the first _rewrite
        self._handle.flush()

    def finish(self) -> list[dict]:
        """Rewrite the file in run order, close it, and return the rows in that order."""
        rows = [self.rows[i] for i in sorted(self.rows)]
        self._rewrite(rows)
        assert self._handle is not None  # opened by _rewrite
        self._handle.close()
        return rows

    def _rewrite(self, rows) -> None:
        if self._handle is not None:
            self._handle.close()
        self._handle = handle = self.path.open("w", newline="")
        self._writer = csv.DictWriter(handle, fieldnames=self.fields, restval="")
        self._writer.writeheader()
        self._writer.writerows(rows)
