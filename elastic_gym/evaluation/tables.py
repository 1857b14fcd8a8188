"""Tables of a comparison: one row per run (CSV) and the seed-averaged summary (CSV + markdown).

Part of the report stage. Metric columns are defined in
[`elastic_gym.evaluation.metrics`][elastic_gym.evaluation.metrics]. The summary
gives, for each metric, the mean over the seeds whose run completed (status ``ok``)
and its spread ``<metric>_std``, the sample standard deviation over those seeds (NaN
with fewer than two); its ``status`` column reads ``ok`` or e.g.
``1/3 ok (terminated: velocity limit exceeded)``. The markdown table shows the means.
[`as_table`][elastic_gym.evaluation.tables.as_table] gives a pandas ``DataFrame`` when
pandas is installed (the ``tables`` extra), the list of row dicts otherwise.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from elastic_gym.evaluation.episodes import RunResult


@dataclass(frozen=True)
class Column:
    key: str
    header: str
    digits: int  # significant digits in the markdown table


METRIC_COLUMNS = (
    Column("track_rms", "track RMS [rad]", 3),
    Column("track_max", "track max [rad]", 3),
    Column("overshoot_pct", "overshoot [%]", 3),
    Column("settling_time", "settling [s]", 3),
    Column("torsion_max", "max torsion [rad]", 3),
    Column("torsion_osc", "torsion osc. [rad]", 3),
    Column("torque_rms", "torque RMS [Nm]", 3),
    Column("torque_rate_rms", "torque rate RMS [Nm/s]", 3),
    Column("saturation_share", "saturated share", 2),
    Column("est_rms_theta", "est. RMS theta [rad]", 2),
    Column("est_rms_q", "est. RMS q [rad]", 2),
    Column("est_rms_dtheta", "est. RMS theta' [rad/s]", 2),
    Column("est_rms_dq", "est. RMS q' [rad/s]", 2),
    Column("sim_wall_ratio", "sim/wall", 2),
)
METRIC_KEYS = tuple(c.key for c in METRIC_COLUMNS)
SPREAD_SUFFIX = "_std"


def run_row(result: RunResult) -> dict:
    """The row of a run: identity labels, status, every metric (NaN where not applicable
    or when the run failed before its first sample), simulated time and ``max_<key>``
    of the observer diagnostics."""
    row = {**result.spec.labels, "status": result.status}
    row.update({key: result.metrics.get(key, math.nan) for key in METRIC_KEYS})
    row["sim_time"] = result.metrics.get("sim_time", math.nan)
    row.update({f"max_{key}": value for key, value in result.diagnostics.items()})
    return row


def run_rows(results: Sequence[RunResult]) -> list[dict]:
    """One row per run ([`run_row`][elastic_gym.evaluation.tables.run_row])."""
    return [run_row(result) for result in results]


def summary_rows(rows: Sequence[dict], identity: Sequence[str]) -> list[dict]:
    """Rows averaged over seeds (first-seen order), metrics from completed runs only."""
    keys = [k for k in identity if k != "seed"]
    groups: dict[tuple, list[dict]] = {}
    for row in rows:
        groups.setdefault(tuple(row[k] for k in keys), []).append(row)
    out = []
    for key, members in groups.items():
        ok = [r for r in members if r["status"] == "ok"]
        summary = dict(zip(keys, key, strict=True))
        summary["seeds"] = len(members)
        failures = sorted({r["status"] for r in members} - {"ok"})
        summary["status"] = (
            "ok" if not failures else (f"{len(ok)}/{len(members)} ok ({'; '.join(failures)})")
        )
        for column in METRIC_KEYS:
            values = np.array([r[column] for r in ok], dtype=float)
            summary[column] = float(np.mean(values)) if len(values) else math.nan
        for column in METRIC_KEYS:
            values = np.array([r[column] for r in ok], dtype=float)
            with np.errstate(invalid="ignore"):  # inf (did not settle) has no spread: NaN
                spread = float(np.std(values, ddof=1)) if len(values) > 1 else math.nan
            summary[column + SPREAD_SUFFIX] = spread
        out.append(summary)
    return out


def as_table(rows: Sequence[dict]):
    """A pandas ``DataFrame`` of the rows when pandas is installed, else the list of rows."""
    try:
        import pandas
    except ImportError:
        return list(rows)
    return pandas.DataFrame(list(rows))


def columns(rows: Sequence[dict]) -> list[str]:
    """The columns of a table of ``rows``: every key any row has, in first-seen order."""
    return list(dict.fromkeys(key for row in rows for key in row))


def write_csv(rows: Sequence[dict], path: Path) -> Path:
    """Write rows as CSV (`columns`; floats in full)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fields = columns(rows)
    with path.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=fields, restval="")
        writer.writeheader()
        writer.writerows(rows)
    return path


def format_value(value, digits: int = 3) -> str:
    """Markdown cell: ``digits`` significant digits, NaN as '-', inf as 'not settled'."""
    if isinstance(value, float):
        if math.isnan(value):
            return "-"
        if math.isinf(value):
            return "not settled"
        return f"{value:.{digits}g}"
    return str(value)


def markdown_table(rows: Sequence[dict], identity: Sequence[str]) -> str:
    """A markdown table of (summary) rows.

    Identity columns whose value is the same in every row are left out of the table
    and listed above it; metric columns that are NaN everywhere are left out.
    """
    if not rows:
        return "_no runs_\n"
    constant = [k for k in (*identity, "seeds") if k in rows[0] and len({r[k] for r in rows}) == 1]
    labels = [
        k
        for k in rows[0]
        if k not in METRIC_KEYS
        and k not in constant
        and not (k.endswith(SPREAD_SUFFIX) and k[: -len(SPREAD_SUFFIX)] in METRIC_KEYS)
    ]
    metrics = [
        c for c in METRIC_COLUMNS if any(not math.isnan(r.get(c.key, math.nan)) for r in rows)
    ]
    headers = labels + [c.header for c in metrics]
    body = [
        [format_value(row[k]) for k in labels]
        + [format_value(row[c.key], c.digits) for c in metrics]
        for row in rows
    ]
    widths = [max(len(text) for text in column) for column in zip(headers, *body, strict=True)]
    numeric = [False] * len(labels) + [True] * len(metrics)

    def line(cells: list[str]) -> str:
        padded = [
            c.rjust(w) if n else c.ljust(w) for c, w, n in zip(cells, widths, numeric, strict=True)
        ]
        return "| " + " | ".join(padded) + " |"

    lines = [", ".join(f"{k}: {rows[0][k]}" for k in constant) + "\n"] if constant else []
    lines.append(line(headers))
    lines.append(
        "|"
        + "|".join(
            ("-" * (w + 1) + ":") if n else "-" * (w + 2)
            for w, n in zip(widths, numeric, strict=True)
        )
        + "|"
    )
    lines += [line(cells) for cells in body]
    return "\n".join(lines) + "\n"
