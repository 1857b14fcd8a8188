"""Eq. (13) on the RK4 at the control period tracks as on PyBullet's Euler at 1/128 ms.

De Luca et al. 2007 eq. (13) (inverse-dynamics feedforward + full-state feedback) on the
true state, on each elastic id's comparison task (the robustness preset's and the suite's
smooth C4 rest-to-rest move), on the nominal plant and on the sweeps' plant perturbations
(link masses, joint stiffness K, motor inertia B, unmodelled Coulomb friction): the
tracking RMS with `integrator="rk4"` at the 1 ms control period is within 10 % of the one
with PyBullet's first-order integrator at a 1/128 ms physics step, the converged
reference of the comparisons before the RK4.
"""

from __future__ import annotations

import pytest

from elastic_gym.evaluation import Scenario, plan_runs
from elastic_gym.evaluation.episodes import run_group
from elastic_gym.evaluation.groups import plan_groups

ELASTIC = [
    "elastic_gym/TwoLinkElastic-v0",
    "elastic_gym/KR15Elastic-v0",
    "elastic_gym/IiwaElastic-v0",
]
PLANTS = {
    "nominal": {},
    "link-mass+10%": {"plant_scaling": {"link_mass": 1.1}},
    "K-5%": {"plant_scaling": {"stiffness": 0.95}},
    "B+5%": {"plant_scaling": {"motor_inertia": 1.05}},
    "coulomb-1%": {"unmodelled_friction": {"coulomb": 0.01}},
}
PHYSICS = {
    "rk4": {"integrator": "rk4"},
    "pybullet-1/128ms": {"integrator": "pybullet", "physics_dt": 1.0 / 128000.0},
}
COARSE = {"pybullet-0.5ms": {"integrator": "pybullet", "physics_dt": 5e-4}}  # robots' default


def tracking_rms(
    env_ids: list[str],
    plants: list[str],
    move_time: float,
    physics: dict = PHYSICS,
    duration: float | None = None,
) -> dict:
    """{(env id, plant, physics): eq. (13)'s true-state tracking RMS} of one seed over
    `duration` (default: the move and 0.1 s at rest)."""
    options = {"n_moves": 1, "move_time": move_time, "dwell_time": 0.1}
    scenario = Scenario.from_dict(
        {
            "name": "rk4-tracking",
            "duration": move_time + 0.1 if duration is None else duration,
            "envs": [
                {"id": i, "kwargs": {"task": "tracking", "task_options": options}} for i in env_ids
            ],
            "axes": {
                "physics": [{"label": k, **v} for k, v in physics.items()],
                "plant": [{"label": k, **PLANTS[k]} for k in plants],
            },
            "controllers": ["feedforward-state-feedback"],
            "state_sources": [True],
        }
    )
    runs, skipped = plan_runs(scenario)
    assert not skipped
    results = [r for group in plan_groups(runs) for r in run_group(group)]  # this process
    assert all(r.status == "ok" for r in results), [r.status for r in results]
    return {
        (r.spec.env_id, r.spec.labels["plant"], r.spec.labels["physics"]): r.metrics["track_rms"]
        for r in results
    }


def assert_within_10_percent(rms: dict) -> None:
    for (env_id, plant, physics), value in rms.items():
        if physics == "rk4":
            reference = rms[env_id, plant, "pybullet-1/128ms"]
            assert value > 0.0, (env_id, plant)
            assert abs(value / reference - 1.0) < 0.1, (env_id, plant, value, reference)


def test_two_link_nominal_and_pybullet_at_its_default_step_is_not():
    """The first 0.25 s of a 0.4 s move of TwoLinkElastic, nominal plant; PyBullet at the robots'
    default 0.5 ms step is not within 10 % (its first-order error dominates: the check
    can tell)."""
    rms = tracking_rms(["elastic_gym/TwoLinkElastic-v0"], ["nominal"], 0.4, PHYSICS | COARSE, 0.25)
    assert_within_10_percent(rms)
    coarse, fine = (
        rms["elastic_gym/TwoLinkElastic-v0", "nominal", k] for k in (*COARSE, "pybullet-1/128ms")
    )
    assert abs(coarse / fine - 1.0) > 0.1, (coarse, fine)


@pytest.mark.slow
@pytest.mark.parametrize("env_id", ELASTIC)
def test_each_elastic_id_nominal_and_perturbed(env_id):
    """The comparison task's 0.5 s move on each elastic id, nominal and under each
    perturbation (measured: within 2.5 %, the RK4's RMS slightly above PyBullet's, whose
    first-order error at 1/128 ms is what remains)."""
    assert_within_10_percent(tracking_rms([env_id], list(PLANTS), 0.5))
