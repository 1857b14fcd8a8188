"""Parquet logs (the `logs` extra: pyarrow): the CSV's columns as float64 columns.

A missing value (null) or a column that is not a number is refused, naming the column
(and the row).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from elastic_gym.logs.checks import Source
from elastic_gym.logs.columns import LogError


def _pyarrow(what: str):
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError as exc:
        raise RuntimeError(
            f"{what} needs pyarrow ({exc}): pip install 'elastic-gym[logs]'"
        ) from None
    return pa, pq


def read_parquet_table(path: Path, name: str | None = None) -> tuple[list[str], np.ndarray, Source]:
    """(header, values, source) of a Parquet log (`name` in errors, default its path)."""
    pa, pq = _pyarrow(f"reading {path}")
    name = name or str(path)
    source = Source(name)
    try:
        table = pq.read_table(path)
    except (OSError, pa.ArrowException) as exc:
        raise LogError(name, f"cannot be read as Parquet: {exc}") from None
    header = [str(column) for column in table.column_names]
    if not header:
        raise LogError(name, "empty file: no columns")
    if table.num_rows == 0:
        raise LogError(name, "no data rows (an empty log)")
    columns = []
    for column_name, column in zip(header, table.columns, strict=True):
        if not (pa.types.is_floating(column.type) or pa.types.is_integer(column.type)):
            raise LogError(name, f"holds {column.type}, not numbers", column=column_name)
        if column.null_count:
            row = int(np.flatnonzero(column.is_null().to_numpy(zero_copy_only=False))[0])
            raise source.error("a missing value (null)", row, column_name)
        columns.append(column.to_numpy().astype(np.float64))
    return header, np.column_stack(columns), source


def write_parquet_table(path: Path, header: list[str], values: np.ndarray) -> None:
    """Write a table as Parquet (float64 columns), atomically."""
    from elastic_gym.runtime.atomic import atomic_file

    pa, pq = _pyarrow(f"writing {path}")
    table = pa.table({name: values[:, k] for k, name in enumerate(header)})
    with atomic_file(path, "wb") as stream:
        pq.write_table(table, stream)
