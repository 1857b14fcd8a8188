"""Convergence of a comparison's metrics in the physics step.

With PyBullet's integrator (first-order semi-implicit Euler) every metric carries an
O(physics_dt) error; with the RK4 the physics step is its largest substep (the step-size
control refines it further where the error needs). A metric m at the physics step h is
*converged* when

    |m(h) - m(h / r)| <= tolerance * |m(h / r)| + floor(metric)

(refinement r = 8, tolerance 0.2 by default). ``floor`` is the resolution below which
differences carry no information: overshoot below ``OVERSHOOT_FLOOR`` %, settling times
within one control period, residual torsion oscillation within one count of the default
motor encoders. `check_convergence` runs each planned run at its own step and at
1/r of it (same seed) and returns one row per run and metric.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

from elastic_gym.evaluation.episodes import RunResult
from elastic_gym.evaluation.execute import execute
from elastic_gym.evaluation.grid import RunSpec, env_robot, plan_runs
from elastic_gym.evaluation.scenario import Scenario
from elastic_gym.evaluation.tables import METRIC_KEYS
from elastic_gym.runtime.parallel import DEFAULT_BACKEND
from elastic_gym.validation import checked_count

REFINEMENT = 8
TOLERANCE = 0.2
OVERSHOOT_FLOOR = 0.01  # % of the move amplitude
TORSION_FLOOR = 2.0 * math.pi / 2**20  # rad, one count of the default motor encoders
CONVERGENCE_METRICS = tuple(k for k in METRIC_KEYS if k != "sim_wall_ratio")  # physics only


def run_physics_dt(spec: RunSpec) -> float:
    """The physics step a run uses: its ``physics_dt`` kwarg or the env's default (the
    RK4's: the control period)."""
    kwargs = spec.env_kwargs
    if "physics_dt" in kwargs:
        return float(kwargs["physics_dt"])
    robot = env_robot(spec.env_id, kwargs)
    if kwargs.get("integrator") == "rk4":
        return float(kwargs.get("control_dt", robot.control_dt))
    return float(robot.physics_dt)


def refined(spec: RunSpec, refinement: int = REFINEMENT) -> RunSpec:
    """The same run with the physics step divided by ``refinement``."""
    kwargs = {**spec.env_kwargs, "physics_dt": run_physics_dt(spec) / refinement}
    return replace(spec, env_kwargs=kwargs)


def metric_floor(metric: str, control_dt: float) -> float:
    """Absolute resolution of a metric (see the module docstring)."""
    if metric == "overshoot_pct":
        return OVERSHOOT_FLOOR
    if metric == "settling_time":
        return control_dt
    if metric == "torsion_osc":
        return TORSION_FLOOR
    return 0.0


def converged(coarse: float, fine: float, floor: float, tolerance: float = TOLERANCE) -> bool:
    """Whether ``coarse`` agrees with ``fine`` (see the module docstring); NaN == NaN."""
    if math.isnan(coarse) or math.isnan(fine):
        return math.isnan(coarse) and math.isnan(fine)
    if math.isinf(coarse) or math.isinf(fine):
        return coarse == fine
    return abs(coarse - fine) <= tolerance * abs(fine) + floor


def compare_results(
    coarse: Sequence[RunResult],
    fine: Sequence[RunResult],
    tolerance: float = TOLERANCE,
    metrics: Sequence[str] = CONVERGENCE_METRICS,
) -> list[dict]:
    """One row per run and metric: labels, both values, relative difference, verdict."""
    rows = []
    for a, b in zip(coarse, fine, strict=True):
        series = a.series
        control_dt = (
            float(series.time[1] - series.time[0])
            if series is not None and len(series) > 1
            else 0.0
        )
        for metric in metrics:
            m_a = a.metrics.get(metric, math.nan)
            m_b = b.metrics.get(metric, math.nan)
            if math.isnan(m_a) and math.isnan(m_b):
                continue  # not applicable to this run
            finite = math.isfinite(m_a) and math.isfinite(m_b) and m_b != 0.0
            rows.append(
                {
                    **a.spec.labels,
                    "status": a.status if a.status == b.status else f"{a.status} / {b.status}",
                    "metric": metric,
                    "physics_dt": run_physics_dt(a.spec),
                    "value": m_a,
                    "refined": m_b,
                    "relative_difference": abs(m_a - m_b) / abs(m_b) if finite else math.nan,
                    "converged": a.status == b.status
                    and converged(m_a, m_b, metric_floor(metric, control_dt), tolerance),
                }
            )
    return rows


def check_convergence(
    scenario: Scenario,
    refinement: int = REFINEMENT,
    tolerance: float = TOLERANCE,
    workers: int | None = None,
    backend: str = DEFAULT_BACKEND,
    progress: bool = True,
) -> list[dict]:
    """Run every run of ``scenario`` at its physics step and at 1/``refinement`` of it.

    Returns `compare_results` rows; ``all(row["converged"] for row in rows)`` is
    the verdict for the whole grid.
    """
    checked_count(refinement, "refinement", 2)
    runs, _ = plan_runs(scenario)
    coarse = execute(runs, workers=workers, backend=backend, progress=progress)
    fine = execute(
        [refined(spec, refinement) for spec in runs],
        workers=workers,
        backend=backend,
        progress=progress,
    )
    return compare_results(coarse, fine, tolerance)
