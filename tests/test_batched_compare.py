"""Comparisons on batches of arms: metrics over arms, row-stacked products, grouping of
runs into worlds, and the rows of a grid run batched equal to one arm per world."""

from __future__ import annotations

import numpy as np
import pytest

from elastic_gym.evaluation.metrics import (
    ArmSeries,
    TimeSeries,
    compute_arm_metrics,
    compute_metrics,
)
from elastic_gym.model.rows import rows_matmul


def test_rows_matmul_rows_do_not_depend_on_the_batch():
    rng = np.random.default_rng(0)
    A, B = rng.normal(size=(37, 18)), rng.normal(size=(18, 8))
    full = rows_matmul(A, B)
    for i in range(len(A)):
        assert np.array_equal(full[i], rows_matmul(A[i : i + 1], B)[0])
    np.testing.assert_allclose(full, A @ B, rtol=0, atol=1e-13)


def _series(rng: np.random.Generator, length: int, elastic: bool) -> TimeSeries:
    """A run with a rest-to-rest move of the reference and a noisy response."""
    time = np.arange(length) * 1e-3
    s = np.clip((time - 0.05) / 0.2, 0.0, 1.0)
    profile = s**3 * (10 - 15 * s + 6 * s**2)
    target = rng.uniform(-0.5, 0.5, 2)
    q_ref = profile[:, None] * target
    dq_ref = (30 * s**2 * (1 - s) ** 2 / 0.2)[:, None] * target
    q = q_ref + 1e-3 * rng.normal(size=q_ref.shape)
    names = ("theta", "q", "dtheta", "dq") if elastic else ("q", "dq")
    error = rng.normal(size=(length, 2 * len(names)))
    theta = q + 0.01 * rng.normal(size=q.shape) if elastic else None
    return TimeSeries(time, q, q_ref, dq_ref, rng.normal(size=(length, 2)), error, names, theta)


@pytest.mark.parametrize("elastic", [True, False])
@pytest.mark.parametrize("tracking", [True, False])
def test_metrics_over_arms_equal_each_arms_own(elastic, tracking):
    """Arms of different lengths (runs that ended early) in one ArmSeries: every metric
    of every arm equals compute_metrics of that arm's own series (1e-12 relative)."""
    rng = np.random.default_rng(1)
    lengths = [600, 600, 137, 1, 420]
    runs = [_series(rng, k, elastic) for k in lengths]
    K = max(lengths)

    def stacked(get):
        if get(runs[0]) is None:
            return None
        out = np.full((K, len(runs), get(runs[0]).shape[1]), np.nan)  # garbage past the end
        for i, run in enumerate(runs):
            out[: len(run), i] = get(run)
        return out

    series = ArmSeries(
        runs[0].time,
        stacked(lambda r: r.q),
        stacked(lambda r: r.q_ref),
        stacked(lambda r: r.dq_ref),
        stacked(lambda r: r.torque),
        stacked(lambda r: r.estimation_error),
        runs[0].state_names,
        np.array(lengths),
        stacked(lambda r: r.theta),
    )
    for run, metrics in zip(runs, compute_arm_metrics(series, tracking), strict=True):
        alone = compute_metrics(run, tracking)
        assert metrics.keys() == alone.keys()
        for key, value in alone.items():
            np.testing.assert_allclose(metrics[key], value, rtol=1e-12, atol=0, err_msg=key)
