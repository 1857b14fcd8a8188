"""An observer run offline on a log: the same estimates as online, bit for bit, and the
estimation error against the truth columns."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import closed_loop_log

from elastic_gym.logs import error_table, estimate_log, read_log


@pytest.mark.parametrize(
    ("env_id", "observer"),
    [
        ("elastic_gym/TwoLinkElastic-v0", "deluca"),
        ("elastic_gym/KR15Elastic-v0", "deluca"),
        pytest.param("elastic_gym/TwoLinkElastic-v0", "ekf", marks=pytest.mark.slow),
    ],
)
def test_offline_estimate_equals_the_online_one_bit_for_bit(tmp_path, env_id, observer):
    online, path = closed_loop_log(tmp_path, env_id, observer, seed=3)
    log = read_log(path)
    assert len(log) == len(online) - 1  # the last observation has no torque yet: no row
    offline = estimate_log(log, observer)
    assert offline.diverged_at is None
    assert np.array_equal(offline.estimate, online[: len(log)])


def test_the_error_table_measures_the_estimate_against_the_truth(tmp_path):
    _, path = closed_loop_log(tmp_path, "elastic_gym/TwoLinkElastic-v0", "deluca", seed=1)
    log = read_log(path)
    truth = log.state_vector()
    wrong = truth[0] + np.array([0.0, 0.0, 0.01, -0.01, 0.0, 0.0, 0.5, -0.5])
    result = estimate_log(log, "deluca", initial_estimate=wrong)
    table = {row["column"]: row for row in error_table(log, result, settle=0.1)}
    assert list(table) == [f"{b}_{j}" for b in ("theta", "q", "dtheta", "dq") for j in (1, 2)]
    e = result.estimate[:, 3] - truth[:, 3]  # q_2
    assert table["q_2"]["rms"] == pytest.approx(np.sqrt(np.mean(e**2)), rel=1e-12)
    assert table["q_2"]["max_abs"] == pytest.approx(np.abs(e).max(), rel=1e-12)
    assert table["dq_1"]["max_abs"] >= 0.5 and table["q_1"]["max_abs"] >= 0.01
    # the error dynamics are linear with poles at 250 rad/s (De Luca et al. 2007,
    # Theorem 1): after 0.1 s the initial error has decayed by e^-25 or more, what is left
    # is the sensor noise's
    for j in (1, 2):
        assert table[f"dq_{j}"]["rms_settled"] < 0.01 * table[f"dq_{j}"]["max_abs"]
        assert table[f"q_{j}"]["rms_settled"] < 0.01 * table[f"q_{j}"]["max_abs"]


def test_the_model_the_observer_is_built_on(tmp_path):
    """The same log observed with other models: a stiffness 30 % off leaves the spring
    torque in the error dynamics of eq. (12) and the link position estimate 10x worse;
    link masses 30 % off change nothing once the initial error (the static estimate at
    rest uses g(q)) has decayed: eq. (12) does not contain M(q) (De Luca et al. 2007,
    Theorem 1)."""
    _, path = closed_loop_log(tmp_path, "elastic_gym/TwoLinkElastic-v0", "deluca", seed=1)
    log = read_log(path)
    nominal = estimate_log(log, "deluca")
    soft = estimate_log(log, "deluca", model=log.nominal_model().perturbed(stiffness=1.3))
    heavy = estimate_log(log, "deluca", model=log.nominal_model().perturbed(link_mass=1.3))

    def settled(result):
        return {row["column"]: row["rms_settled"] for row in error_table(log, result, 0.1)}

    for j in (1, 2):
        assert settled(soft)[f"q_{j}"] > 10 * settled(nominal)[f"q_{j}"]
    gap = np.abs(heavy.estimate - nominal.estimate).max(axis=1)
    assert gap[0] > 1e-3  # the initial estimates differ (g(q) of the static estimate)
    assert gap[log.time >= 0.25].max() < 1e-8 * gap.max()  # and the difference decays


def test_privileged_observers_are_refused(tmp_path):
    _, path = closed_loop_log(
        tmp_path, "elastic_gym/TwoLinkElastic-v0", "deluca", seed=1, episode_time=0.05
    )
    log = read_log(path)
    with pytest.raises(ValueError, match="reads the simulator's truth"):
        estimate_log(log, "deluca-ideal")
    with pytest.raises(ValueError, match="unknown observer 'kalman'"):
        estimate_log(log, "kalman")
