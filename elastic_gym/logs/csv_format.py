"""Plain CSV logs: a header line of column names, then one line per sample.

Numbers are written as Python's shortest round-trip representation (`repr`), so that a
log read back holds the very same float64 values (bit for bit). Reading refuses, naming
the line: an empty file, a header without data rows, a blank line between rows, a row
with more or fewer cells than the header, a cell that is not a number.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from elastic_gym.logs.checks import Source
from elastic_gym.logs.columns import LogError
from elastic_gym.runtime.atomic import atomic_file

FIRST_DATA_LINE = 2


def read_csv_table(path: Path, name: str | None = None) -> tuple[list[str], np.ndarray, Source]:
    """(header, values (T, columns), source) of a CSV log; `LogError` naming the file
    (`name`, default its path), row, line and column of the first problem."""
    name = name or str(path)
    source = Source(name, FIRST_DATA_LINE)
    try:
        text = path.read_text(encoding="utf-8-sig")  # a BOM some spreadsheets write
    except (OSError, UnicodeDecodeError) as exc:
        raise LogError(name, f"cannot be read: {exc}") from None
    lines = text.splitlines()
    while lines and not lines[-1].strip():
        lines.pop()
    if not lines:
        raise LogError(name, "empty file: a log starts with a header line of column names")
    header = [cell.strip() for cell in lines[0].split(",")]
    rows = lines[1:]
    if not rows:
        raise LogError(name, "no data rows: the file holds only a header")
    try:
        values = np.loadtxt(rows, delimiter=",", dtype=np.float64, ndmin=2)
    except ValueError:
        _locate(header, rows, source)
        raise  # _locate always raises; this keeps the original if it did not
    if values.shape != (len(rows), len(header)):
        _locate(header, rows, source)
    return header, values, source


def _locate(header: list[str], rows: list[str], source: Source) -> None:
    """Raise the `LogError` of the first row numpy could not read."""
    for k, line in enumerate(rows):
        if not line.strip():
            raise source.error("a blank line between data rows", k)
        cells = line.split(",")
        if len(cells) != len(header):
            raise source.error(f"{len(cells)} cells, the header has {len(header)} columns", k)
        for column, cell in zip(header, cells, strict=True):
            try:
                float(cell)
            except ValueError:
                raise source.error(f"{cell.strip()!r} is not a number", k, column) from None
    raise source.error("cannot be read as a table of numbers")


def csv_text(header: list[str], values: np.ndarray) -> str:
    """The CSV text of a table (shortest round-trip numbers)."""
    out = [",".join(header)]
    out.extend(",".join(map(repr, row)) for row in values.tolist())
    return "\n".join(out) + "\n"


def write_csv_table(path: Path, header: list[str], values: np.ndarray) -> None:
    """Write a table as CSV, atomically (the earlier file or the whole new one)."""
    with atomic_file(path, "w", encoding="utf-8", newline="") as stream:
        stream.write(csv_text(header, values))
