"""The output folder of a comparison: checked before the first run, filled as runs finish.

A comparison writes ``runs.csv``, ``summary.csv``, ``summary.md``, ``scenario.yaml``
and ``plots/*.png`` (a sweep: also ``margins.csv``, ``margins.md`` and ``curves/*.png``)
in its folder, and nothing elsewhere. Before any run,
`check_output_folder` refuses a folder that is a file, that cannot be written,
or that holds the results of an earlier comparison (old figures would stay beside the
new ones) unless ``overwrite`` is given; `clear_results` then removes those
files (only those). `RunsCsv` writes ``runs.csv`` row by row as runs finish,
so that an interrupted or crashed comparison keeps every finished run on disk, and
never leaves a partial file: what is rewritten is written beside and renamed over
(`write_atomic`), so a full disk costs at most the rows it could not take.
"""

from __future__ import annotations

import contextlib
import csv
import errno
import io
import os
from pathlib import Path

from elastic_gym.runtime.folder_lock import check_free

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
    check_free(
        folder,
        lambda: earlier_results(folder),
        "the results of an earlier comparison",
        "output folder",
        overwrite,
    )


def clear_results(folder: Path) -> None:
    """Remove the files a comparison writes (and nothing else) from ``folder``."""
    for name in earlier_results(folder):
        (folder / name).unlink()
    for figures in FIGURE_DIRS:
        if (folder / figures).is_dir() and not any((folder / figures).iterdir()):
            (folder / figures).rmdir()


class ResultsWriteError(RuntimeError):
    """Results could not be written (a full disk, an I/O error); the message says what
    was kept on disk."""


def write_problem(exc: OSError) -> str:
    """``"disk full"`` for ENOSPC (and EDQUOT, EFBIG), else ``"cannot write (<error>)"``."""
    if exc.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG):
        return "disk full"
    return f"cannot write ({exc})"


def write_atomic(path: Path, text: str) -> None:
    """Write ``text`` to a new file beside ``path`` and rename it over ``path``: either
    the whole new content is there or the old file (or none) is left untouched."""
    partial = path.with_name(f".{path.name}.partial")
    try:
        fd = os.open(partial, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o666)
        try:
            write_all(fd, text.encode())
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(partial, path)
    except BaseException:
        with contextlib.suppress(OSError):
            partial.unlink()
        raise


def write_all(fd: int, data: bytes) -> None:
    """``os.write`` until every byte is written (a full disk raises ``OSError``)."""
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view) :]


class RunsCsv:
    """``runs.csv`` written as rows arrive (any order): each row appended and flushed.

    A row with a column not seen before (the diagnostics of another observer) writes
    the file anew with the wider header, beside the old one, and renames it over it
    (`write_atomic`); [`finish`][elastic_gym.evaluation.report.Report.finish] does the same
    in run order. So the file on disk always holds complete rows. When a write fails (e.g.
    the disk is full), the partial row is cut off again and `ResultsWriteError` says how
    many rows the file keeps; later calls raise it again.
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self.rows: dict[int, dict] = {}
        self.fields: list[str] = []
        self._fd: int | None = None  # appending
        self._written = 0  # complete rows in the file
        self._error: ResultsWriteError | None = None

    def add(self, index: int, row: dict) -> None:
        self._check_no_error()
        self.rows[index] = row
        new = [key for key in row if key not in self.fields]
        if new or self._fd is None:
            self.fields += new
            self._replace(list(self.rows.values()))
        else:
            self._append(row)

    def finish(self) -> list[dict]:
        """Write the file in run order, close it, and return the rows in that order."""
        self._check_no_error()
        rows = [self.rows[i] for i in sorted(self.rows)]
        self._replace(rows)
        self._close()
        return rows

    def _text(self, rows: list[dict]) -> str:
        buffer = io.StringIO()
        writer = csv.DictWriter(buffer, fieldnames=self.fields, restval="")
        writer.writeheader()
        writer.writerows(rows)
        return buffer.getvalue()

    def _replace(self, rows: list[dict]) -> None:
        try:
            write_atomic(self.path, self._text(rows))
        except OSError as exc:
            self._fail(exc)
        self._close()
        self._written = len(rows)
        self._fd = os.open(self.path, os.O_WRONLY | os.O_APPEND)

    def _append(self, row: dict) -> None:
        assert self._fd is not None
        buffer = io.StringIO()
        csv.DictWriter(buffer, fieldnames=self.fields, restval="").writerow(row)
        size = os.fstat(self._fd).st_size
        try:
            write_all(self._fd, buffer.getvalue().encode())
        except OSError as exc:
            with contextlib.suppress(OSError):
                os.ftruncate(self._fd, size)  # cut the partial row off (frees space)
            self._fail(exc)
        self._written += 1

    def _close(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None

    def _fail(self, exc: OSError) -> None:
        reason = write_problem(exc)
        where = self.path if self._written else self.path.parent
        self._error = ResultsWriteError(
            f"{reason}: {self._written} of {len(self.rows)} finished rows kept in {where}"
        )
        self._close()
        raise self._error from exc

    def _check_no_error(self) -> None:
        """A failed write is raised again by every later call (the file keeps its rows)."""
        if self._error is not None:
            raise self._error
