"""Comparisons on batches of arms: metrics over arms, row-stacked products, grouping of
runs into worlds, and the rows of a grid run batched equal to one arm per world."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import same_metric
from rich.console import Console

from elastic_gym.controllers.base import Controller
from elastic_gym.evaluation import Scenario, compare, plan_runs
from elastic_gym.evaluation.groups import DEFAULT_BATCH_SIZE, plan_groups
from elastic_gym.evaluation.metrics import (
    ArmSeries,
    TimeSeries,
    compute_arm_metrics,
    compute_metrics,
    rms_norm,
)
from elastic_gym.model.rows import rows_matmul
from elastic_gym.observers.registry import OBSERVERS

QUIET = Console(quiet=True)


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
    of every arm equals compute_metrics of that arm's own series, bit for bit."""
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
            np.testing.assert_array_equal(metrics[key], value, err_msg=key)
        assert metrics["torque_rms"] == rms_norm(run.torque)  # the definition, on its samples
        if tracking:
            assert metrics["track_rms"] == rms_norm(run.q - run.q_ref)


# ------------------------------------------------------------------ a grid both ways
def small_policy(obs: dict) -> np.ndarray:
    """A deterministic 'policy' (obs -> one action in [-1, 1] per joint) for the residual
    controller: the link position error (the reference is [q_d, dq_d], the state starts
    with q on either arm)."""
    reference = np.asarray(obs["reference"])
    n = reference.shape[-1] // 2
    return np.tanh(np.asarray(obs["state"])[..., :n] - reference[..., :n])


class FullTorque(Controller):
    """Full torque on every joint: the arm soon exceeds the velocity limit (terminated)."""

    name = "full-torque"

    def __call__(self, obs, info):
        return np.full(self.n, 1e6)


class Picky(Controller):
    """Zero torque, and an exception from 30 ms on when the reference's last joint is
    positive (seed 1 of both arms): a run that raises while its batch mates go on."""

    name = "picky"

    def __call__(self, obs, info):
        if info["time"] >= 0.03 and info["reference"]["q"][-1] > 0:
            raise RuntimeError("refused")
        return np.zeros(self.n)


# Each built-in controller on two state sources of each arm it applies to, each source
# under two controllers or more: every controller and every observer runs both ways (that
# each vector controller and observer equals its single twin, arm by arm, is the claim of
# test_vector_controllers and test_vector_observers). Name -> source labels (those of the
# other arm are skipped).
PAIRS = {
    "feedforward-state-feedback": ["ekf", "nicosia-tomei", "true"],
    "integral-state-feedback": ["deluca", "reduced-order", "finite-difference"],
    "link-pd": ["deluca-ideal", "solsona-puleston", "true"],
    "motor-pd": ["ekf", "finite-difference"],  # elastic arms only
    "cristofaro-tracking": ["reduced-order", "true"],  # rigid arms only
    "feedback-linearization": ["solsona-puleston", "finite-difference"],  # rigid arms only
}
RESIDUAL_SOURCES = ["deluca", "deluca-ideal", "nicosia-tomei", "reduced-order"]


ARMS = (
    {"id": "TwoLinkElastic-v0", "label": "elastic", "kwargs": {"max_velocity": 4.0}},
    {"id": "TwoLinkRigid-v0", "label": "rigid", "kwargs": {"max_velocity": 1.5}},
)  # the full-torque controller trips them within 45 ms, the others keep below


def grid(arms: tuple[dict, ...] = ARMS) -> Scenario:
    """Every built-in controller (and a residual policy) on state sources of its arm
    (`PAIRS`: every source of the arm is used), two seeds, a plant sweep and a sensor
    sweep (both per-arm kwargs), an early end (the full-torque controller trips the
    velocity limit on either arm) and a run that raises beside batch mates that go on."""
    return Scenario.from_dict(
        {
            "name": "both-ways",
            "duration": 0.05,
            "physics_dt": None,
            "seeds": [0, 1],
            "envs": list(arms),
            "sweeps": {
                "mass": {"parameter": "plant_scaling.link_mass", "nominal": 1.0, "values": [1.3]},
                "delay": {"parameter": "sensor_delay", "nominal": 0, "values": [2]},
            },
            "controllers": [
                *({"name": name, "sources": sources} for name, sources in PAIRS.items()),
                {
                    "name": "policy",
                    "label": "residual",
                    "options": {
                        "policy": small_policy,
                        "residual": "feedforward-state-feedback",
                        "residual_scale": 0.05,
                    },
                    "sources": RESIDUAL_SOURCES,
                },
                {"name": "full-torque", "class": FullTorque, "sources": ["true"]},
                {"name": "picky", "class": Picky, "sources": ["true", "ekf"]},
            ],
            "state_sources": sorted(OBSERVERS),
        }
    )


@pytest.mark.slow
@pytest.mark.usefixtures("jobs_in_this_process")  # the rows are the claim, not the worker
@pytest.mark.parametrize("arm", ARMS, ids=lambda arm: arm["label"])
def test_rows_of_a_grid_batched_equal_one_arm_per_world(tmp_path, arm):
    """One arm's half of the grid per test, so the two halves run on both xdist workers."""
    scenario = grid((arm,))
    runs, _ = plan_runs(scenario)
    sources: dict[str, set] = {}  # controller -> its sources on this arm
    for run in runs:
        sources.setdefault(run.labels["controller"], set()).add(run.labels["source"])
    assert len(sources) == (7 if arm["label"] == "elastic" else 8)  # every controller
    assert all(len(sources[name]) == 2 for name in set(sources) - {"full-torque", "picky"})
    used = [source for labels in sources.values() for source in labels]
    assert len(set(used)) == 5 and all(used.count(source) >= 2 for source in used)
    assert max(len(g) for g in plan_groups(runs, DEFAULT_BATCH_SIZE, 1)) > 2  # really batched
    results = {}
    for batch_size in (1, DEFAULT_BATCH_SIZE):
        results[batch_size] = compare(
            scenario,
            output_dir=tmp_path / str(batch_size),
            workers=1,
            progress=False,
            plots=False,
            console=QUIET,
            batch_size=batch_size,
        ).runs.to_dict("records")
    alone, batched = results[1], results[DEFAULT_BATCH_SIZE]
    assert len(alone) == len(batched) == len(runs)
    statuses = {(row["controller"], row["seed"]): row["status"] for row in alone}
    assert statuses["feedforward-state-feedback", 0] == "ok"
    assert statuses["full-torque", 0].startswith("terminated: velocity limit")
    assert statuses["picky", 0] == "ok"
    assert statuses["picky", 1] == "failed: RuntimeError: refused"
    others = {(row["controller"], row["status"]) for row in alone}
    assert {status for name, status in others if name not in ("full-torque", "picky")} == {"ok"}
    assert any(name in ("residual", "policy") for name, _ in others)
    for a, b in zip(alone, batched, strict=True):
        assert a.keys() == b.keys()
        differ = {
            k: (a[k], b[k]) for k in a if k != "sim_wall_ratio" and not same_metric(a[k], b[k])
        }
        assert not differ, (a["controller"], a["source"], a["sweep"], a["seed"], differ)


@pytest.mark.parametrize("batch_size", [0, -1, 2.5, True, "8"])
def test_a_bad_batch_size_is_refused_before_anything_is_written(tmp_path, batch_size):
    out = tmp_path / "out"
    with pytest.raises(ValueError, match=r"^batch_size must be an integer >= 1"):
        compare(grid(), output_dir=out, workers=1, progress=False, batch_size=batch_size)
    assert not out.exists()


def test_groups_share_a_world_only_when_they_may():
    """Seeds and per-arm kwargs (a sweep's magnitudes) share a world; the controller, the
    state source and shared kwargs do not; big groups are cut so both workers get work."""
    runs, _ = plan_runs(grid())
    for group in plan_groups(runs, DEFAULT_BATCH_SIZE, 1):
        first = group.first
        for spec in group.runs:
            assert (spec.env_id, spec.controller, spec.source) == (
                first.env_id,
                first.controller,
                first.source,
            )
    sizes = [len(g) for g in plan_groups(runs, 4, 2)]
    assert max(sizes) <= 4 and sum(sizes) == len(runs)
    one = [r for r in runs if r.labels["controller"] == "picky" and r.labels["source"] == "true"]
    halves = plan_groups(one[:6], DEFAULT_BATCH_SIZE, 2)  # one group of 6 arms, 2 workers
    assert [len(g) for g in halves] == [2, 1, 2, 1]
    mixed = plan_groups(one[:6], DEFAULT_BATCH_SIZE, 1)[0]  # nominal seeds 0, 1; mass seed 0
    per_arm = mixed.env_kwargs()["per_arm"]
    assert per_arm == [{}, {}, {"plant_scaling": {"link_mass": 1.3}}]
    assert mixed.seeds == [0, 1, 0]
