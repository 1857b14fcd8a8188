"""Are a comparison's metrics converged in the physics step?

    python studies/convergence.py                       # the default grid, 1/8 refinement
    python studies/convergence.py --preset robustness --sweep nominal --seeds 0
    python studies/convergence.py --preset default --physics-dt 5e-4   # the old step

Runs every run of a preset at the scenario's physics step h and at h / 8 (same seeds)
and prints, per metric, the worst relative difference and the runs that are not within
20 % (``elastic_gym.evaluation.convergence``). Writes the rows to
``convergence_out/<preset>.csv``. Exit code 1 if a metric of a run is not converged.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from pathlib import Path

from rich.console import Console
from rich.table import Table

from elastic_gym.evaluation import load_preset
from elastic_gym.evaluation.convergence import REFINEMENT, TOLERANCE, check_convergence
from elastic_gym.evaluation.tables import write_csv
from elastic_gym.runtime.parallel import single_thread_blas


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--preset", default="default")
    parser.add_argument("--physics-dt", type=float, help="override the scenario's physics step")
    parser.add_argument("--duration", type=float)
    parser.add_argument("--seeds", type=int, nargs="+")
    parser.add_argument(
        "--sweep",
        nargs="+",
        metavar="LABEL",
        help="keep only these values of the scenario's 'sweep' axis",
    )
    parser.add_argument("--refinement", type=int, default=REFINEMENT)
    parser.add_argument("--tolerance", type=float, default=TOLERANCE)
    parser.add_argument("--workers", type=int)
    parser.add_argument("--output", default="convergence_out")
    args = parser.parse_args()

    scenario = load_preset(args.preset).with_overrides(
        seeds=args.seeds, duration=args.duration, physics_dt=args.physics_dt
    )
    if args.sweep:
        axes = tuple(
            (name, tuple(v for v in values if name != "sweep" or v.label in args.sweep))
            for name, values in scenario.axes
        )
        scenario = dataclasses.replace(scenario, axes=axes)
    with single_thread_blas():
        rows = check_convergence(scenario, args.refinement, args.tolerance, workers=args.workers)
    path = write_csv(rows, Path(args.output) / f"{scenario.name}.csv")

    table = Table(
        title=f"{scenario.name}: metrics at physics_dt vs physics_dt/{args.refinement} "
        f"(tolerance {args.tolerance:.0%})"
    )
    for column in ("metric", "runs", "converged", "worst rel. diff.", "worst run"):
        table.add_column(column)
    failed = 0
    for metric in dict.fromkeys(row["metric"] for row in rows):
        members = [r for r in rows if r["metric"] == metric]
        ok = sum(r["converged"] for r in members)
        failed += len(members) - ok
        finite = [r for r in members if not math.isnan(r["relative_difference"])]
        worst = max(finite, key=lambda r: r["relative_difference"], default=None)
        table.add_row(
            metric,
            str(len(members)),
            str(ok),
            f"{worst['relative_difference']:.3f}" if worst else "-",
            ", ".join(f"{k}={worst[k]}" for k in scenario.identity_columns) if worst else "-",
        )
    console = Console()
    console.print(table)
    for row in rows:
        if not row["converged"]:
            labels = ", ".join(f"{k}={row[k]}" for k in scenario.identity_columns)
            console.print(
                f"not converged: {labels}: {row['metric']} {row['value']:.4g} vs "
                f"{row['refined']:.4g} ({row['status']})",
                markup=False,
            )
    print(
        f"physics_dt of the runs: {sorted({r['physics_dt'] for r in rows})}; "
        f"{failed} metric values not converged; rows in {path}"
    )
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
