"""The Ray backend of comparisons and trainings, on one local Ray runtime for both (starting
Ray and its workers costs more than the jobs run on it)."""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from helpers import rigid_scenario

from elastic_gym.evaluation import Scenario, ScenarioError, compare, execute, plan_runs
from elastic_gym.evaluation.episodes import run_group
from elastic_gym.evaluation.plan import group_runs
from elastic_gym.runtime.parallel import SINGLE_THREAD_ENV


@pytest.mark.slow
@pytest.mark.usefixtures("single_thread_torch")
def test_ray_backend_gives_the_same_table_and_trains_two_seeds(tmp_path, capsys):
    """A comparison run on Ray gives the local table, bit for bit; `elastic-gym train --seeds
    0 1 --backend ray` runs both jobs on the Ray runtime and gathers them in one table;
    `elastic-gym compare --policy RUN` (on the same runtime) adds the policy's rows; the
    pre-run check (run on Ray) refuses an observer option no run could use, writing nothing."""
    ray = pytest.importorskip("ray", reason="the 'ray' extra is not installed")
    from elastic_gym.cli import main

    scenario = Scenario.from_dict(
        rigid_scenario(
            controllers=["open-loop"],
            state_sources=["finite-difference"],
            duration=0.1,
            envs=[{"id": "TwoLinkRigid-v0", "kwargs": {"task": "excitation"}}],
        )
    )
    runs = plan_runs(scenario)[0]
    groups, _ = group_runs(runs, workers=1)
    local = [result for group in groups for result in run_group(group)]  # the job, here
    out = tmp_path / "runs"
    small = tmp_path / "small.yaml"  # the default grid's eq. (13) row, one env and source
    small.write_text(
        yaml.safe_dump(
            {
                "name": "small",
                "duration": 0.05,
                "envs": [{"id": "elastic_gym/TwoLinkElastic-v0"}],
                "controllers": [
                    {"name": "feedforward-state-feedback", "label": "eq13-state-feedback"}
                ],
                "state_sources": [True],
            }
        )
    )
    # what the backend starts with --workers 2 (elastic_gym.runtime.parallel._run_ray)
    ray.init(
        num_cpus=2,
        include_dashboard=False,
        log_to_driver=False,
        runtime_env={"env_vars": SINGLE_THREAD_ENV},
    )
    try:
        remote = execute(runs, workers=2, backend="ray", progress=False)
        capsys.readouterr()
        code = main(
            [
                "train",
                "--algo",
                "sac",
                "--steps",
                "40",
                "--seeds",
                "0",
                "1",
                "--backend",
                "ray",
                "--workers",
                "2",
                "--out",
                str(out),
                "--env-kwargs",
                "{max_episode_steps: 100}",
                "--hyperparams",
                "learning_starts=20",
                "batch_size=16",
                "--eval-freq",
                "1000000",
                "--no-progress",
            ]
        )
        printed = capsys.readouterr().out
        assert code == 0
        compared = main(
            [
                "compare",
                "--config",
                str(small),
                "--policy",
                str(out / "seed0"),
                "--trust-pickle",
                "--backend",
                "ray",
                "--workers",
                "2",
                "--output",
                str(tmp_path / "cmp"),
                "--no-plots",
                "--no-progress",
            ]
        )
        bad = rigid_scenario(
            controllers=["open-loop"],
            state_sources=[{"name": "finite-difference", "options": {"cutoff_hz": -5.0}}],
        )
        with pytest.raises(ScenarioError, match=r"^state_sources\[0\]\.options: .*cutoff_hz"):
            compare(Scenario.from_dict(bad), tmp_path / "bad", workers=2, backend="ray")
    finally:
        ray.shutdown()
    assert remote[0].metrics["est_rms_dq"] == local[0].metrics["est_rms_dq"]
    np.testing.assert_array_equal(remote[0].series.q, local[0].series.q)

    for seed in (0, 1):
        assert (out / f"seed{seed}" / "model.zip").exists()
        assert (out / f"seed{seed}" / "vecnormalize.pkl").exists()
    assert "policy steps" in printed and printed.count("seed") >= 2

    assert compared == 0 and not (tmp_path / "bad").exists()
    summary = (tmp_path / "cmp" / "summary.md").read_text()
    assert "policy:seed0" in summary and "eq13-state-feedback" in summary
