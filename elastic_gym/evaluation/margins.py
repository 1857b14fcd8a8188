"""Robustness margins of every loop along every sweep.

For a [`SweepCurve`][elastic_gym.evaluation.sweeps.SweepCurve] and a criterion, walk away from
the nominal magnitude on each side, in order; a magnitude *passes* when the point is
stable (every seed completed) and the metric's mean over seeds is at most ``FACTOR`` (2)
times its nominal value. The margin on a side is the largest magnitude reached before the
first failure. Criteria: ``tracking`` (``track_rms``, every loop) and ``estimation``
(``est_rms_q`` and ``est_rms_dq``, the loops on an observer). `margin_rows` gives
one row per context, loop, sweep and criterion (the CSV);
[`margins_markdown`][elastic_gym.evaluation.margins.margins_markdown] one
table per context and criterion.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from elastic_gym.evaluation.scenario import TRUE_STATE
from elastic_gym.evaluation.sweeps import SweepCurve, SweepPoint
from elastic_gym.evaluation.tables import write_csv

FACTOR = 2.0
CRITERIA = {
    "tracking": ("track_rms",),
    "estimation": ("est_rms_q", "est_rms_dq"),
}


def failure(point: SweepPoint, nominal: dict[str, float]) -> str:
    """Why ``point`` fails the criterion with nominal values ``nominal`` ('' if it passes)."""
    if not point.stable:
        return f"unstable ({'; '.join(point.statuses)})"
    for metric, reference in nominal.items():
        value = point.mean(metric)
        if not value <= FACTOR * reference:  # NaN fails too
            return (
                f"{metric} {value / reference:.3g}x nominal"
                if reference > 0
                else f"{metric} {value:.3g} (nominal 0)"
            )
    return ""


def side_margin(
    points: Sequence[SweepPoint], nominal: dict[str, float], start: float
) -> tuple[float, str, float]:
    """(margin, reason of the first failure or '', first failing magnitude or NaN) walking
    through ``points`` (ordered away from the nominal magnitude ``start``)."""
    margin = start
    for point in points:
        reason = failure(point, nominal)
        if reason:
            return margin, reason, point.magnitude
        margin = point.magnitude
    return margin, "", math.nan


def curve_margin(curve: SweepCurve, criterion: str) -> dict:
    """The margin row of one curve for one criterion (see the module docstring)."""
    metrics = CRITERIA[criterion]
    nominal_point = curve.nominal
    nominal = {m: nominal_point.mean(m) for m in metrics}
    sweep = curve.sweep
    row = {
        **curve.context,
        "controller": curve.controller,
        "source": curve.source,
        "criterion": criterion,
        "sweep": sweep.name,
        "parameter": sweep.parameter,
        "nominal": sweep.nominal,
        **{f"nominal_{m}": v for m, v in nominal.items()},
        "tested_min": curve.points[0].magnitude,
        "tested_max": curve.points[-1].magnitude,
    }
    if not nominal_point.stable or any(math.isnan(v) for v in nominal.values()):
        reason = failure(nominal_point, {}) or "no nominal value"
        return {
            **row,
            "lower": math.nan,
            "upper": math.nan,
            "lower_failure": reason,
            "upper_failure": reason,
            "lower_failed_at": sweep.nominal,
            "upper_failed_at": sweep.nominal,
        }
    center = sweep.nominal
    below = [p for p in reversed(curve.points) if p.magnitude < center]
    above = [p for p in curve.points if p.magnitude > center]
    for side, points in (("lower", below), ("upper", above)):
        margin, reason, failed_at = side_margin(points, nominal, center)
        row.update({side: margin, f"{side}_failure": reason, f"{side}_failed_at": failed_at})
    return row


def applies(curve: SweepCurve, criterion: str) -> bool:
    """Whether ``criterion`` applies: estimation only with an observer, and a metric that
    is defined for the loop's runs (no tracking metric for the excitation task)."""
    if criterion == "estimation" and curve.source == TRUE_STATE:
        return False
    rows = [row for point in curve.points for row in point.rows]
    return any(not math.isnan(float(row[m])) for row in rows for m in CRITERIA[criterion])


def margin_rows(curves: Sequence[SweepCurve]) -> list[dict]:
    """Margin rows of every curve and criterion that applies
    ([`applies`][elastic_gym.evaluation.margins.applies])."""
    return [
        curve_margin(curve, criterion)
        for criterion in CRITERIA
        for curve in curves
        if applies(curve, criterion)
    ]


def cell(row: dict) -> str:
    """Markdown cell: how far from the nominal the loop passes, per side tested.

    ``1.4``: passes up to 1.4 and fails at the next magnitude tested; ``2*``: passes
    every magnitude tested, 2 being the farthest; ``<1.1`` (``>0.9`` below the
    nominal): already fails at the first magnitude tested; two-sided sweeps show
    ``lower .. upper``; ``unstable at nominal`` when the nominal runs do not complete;
    ``-`` when only the nominal was run.
    """
    if row["tested_min"] == row["tested_max"] == row["nominal"]:
        return "-"  # nothing but the nominal tested
    if math.isnan(row["upper"]) and math.isnan(row["lower"]):
        return (
            "unstable at nominal"
            if row["upper_failure"].startswith("unstable")
            else row["upper_failure"]
        )
    parts = []
    for side, beyond in (("lower", ">"), ("upper", "<")):
        tested = row["tested_min"] if side == "lower" else row["tested_max"]
        if tested == row["nominal"]:
            continue  # nothing tested on this side
        if not row[f"{side}_failure"]:
            parts.append(f"{row[side]:.3g}*")
        elif row[side] == row["nominal"]:
            parts.append(f"{beyond}{row[f'{side}_failed_at']:.3g}")
        else:
            parts.append(f"{row[side]:.3g}")
    return " .. ".join(parts)


def margins_markdown(rows: Sequence[dict], context_keys: Sequence[str]) -> str:
    """One table per context and criterion: a row per loop, a column per sweep."""
    blocks = []
    keyed: dict[tuple, list[dict]] = {}
    for row in rows:
        context = tuple(row[k] for k in context_keys)
        keyed.setdefault((context, row["criterion"]), []).append(row)
    for (context, criterion), members in keyed.items():
        sweeps = list(dict.fromkeys(r["sweep"] for r in members))
        loops = list(dict.fromkeys((r["controller"], r["source"]) for r in members))
        cells = {(r["controller"], r["source"], r["sweep"]): cell(r) for r in members}
        title = ", ".join(f"{k}: {v}" for k, v in zip(context_keys, context, strict=True))
        metrics = " and ".join(CRITERIA[criterion])
        header = ["controller", "source", *sweeps]
        lines = [
            f"### {title} — {criterion} ({metrics} within {FACTOR:g}x nominal, stable)",
            "",
            "| " + " | ".join(header) + " |",
            "|" + "|".join("---" for _ in header) + "|",
        ]
        for controller, source in loops:
            lines.append(
                "| "
                + " | ".join(
                    [controller, source, *(cells.get((controller, source, s), "-") for s in sweeps)]
                )
                + " |"
            )
        nominal = {
            r["sweep"]: f"{r['sweep']} = {r['parameter']} (nominal {r['nominal']:g})"
            for r in members
        }
        lines += ["", "Sweeps: " + "; ".join(nominal.values()) + ".", ""]
        blocks.append("\n".join(lines))
    return "\n".join(blocks)


def write_margins(rows: Sequence[dict], context_keys: Sequence[str], directory, title: str) -> list:
    """``margins.csv`` (one row per context, loop, sweep, criterion) and ``margins.md``."""
    csv_path = write_csv(rows, directory / "margins.csv")
    md_path = directory / "margins.md"
    md_path.write_text(
        f"# {title}: robustness margins\n\n"
        "Each cell: how far from the nominal magnitude the loop stays stable (every seed "
        f"completes) and within {FACTOR:g}x its nominal value: `1.4` passes up to 1.4 and "
        "fails at the next magnitude tested; `2*` passes every magnitude tested (2 the "
        "farthest); `<1.1` (`>0.9` below the nominal) fails at the first magnitude tested; "
        "`lower .. upper` for sweeps on both sides of the nominal.\n\n"
        + margins_markdown(rows, context_keys)
    )
    return [csv_path, md_path]
