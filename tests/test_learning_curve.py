"""Policy evaluation on the arms of one batch, learning curves, schedules, RecurrentPPO."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
from gymnasium.vector import AutoresetMode
from helpers import policy_env, policy_vec_env

from elastic_gym.training import TrainConfig, evaluate_run, load_run, train
from elastic_gym.training.config import resolve_hyperparams
from elastic_gym.training.learning_curve import COLUMNS, CURVE_FILE
from elastic_gym.training.rollouts import evaluate_arms, evaluate_policy

ENV_ID = "elastic_gym/TwoLinkElastic-v0"
SHORT = {"episode_time": 0.3}


pytestmark = pytest.mark.usefixtures("single_thread_torch")


def _sway(obs: np.ndarray) -> np.ndarray:
    """A deterministic feedback 'policy' that uses the observation (error feature)."""
    return np.clip(-0.5 * obs[..., :2] + 0.3, -1.0, 1.0)


def test_batch_evaluation_equals_episodes_one_by_one():
    """Arm i of the evaluation batch is the single env reset with seed s + i: same
    returns, tracking RMS (norm over the joints, as the comparison's track_rms) and
    saturation, including an arm whose action sits at its bound."""
    kwargs = {**SHORT, "accelerometer": "ideal"}
    action = {"kind": "motor-offset"}
    envs = policy_vec_env(
        ENV_ID,
        3,
        "deluca",
        kwargs,
        decimation=10,
        action=action,
        autoreset_mode=AutoresetMode.NEXT_STEP,
    )
    batch = evaluate_arms(envs, _sway, seed=5)
    envs.close()
    env = policy_env(ENV_ID, "deluca", kwargs, decimation=10, action=action)
    single = evaluate_policy(env, _sway, range(5, 8))
    env.close()
    assert batch.seeds == single.seeds == (5, 6, 7)
    np.testing.assert_allclose(batch.returns, single.returns, rtol=1e-12)
    np.testing.assert_allclose(batch.tracking_rms, single.tracking_rms, rtol=1e-12)
    assert batch.saturated_actions == single.saturated_actions
    assert all(0 < r < 0.05 for r in batch.tracking_rms)


def test_tracking_rms_is_the_norm_over_joints():
    """An error of (a, b) rad held on every sample has RMS sqrt(a^2 + b^2), the
    comparison's definition: checked on the zero-offset PD against the recorded errors."""
    env = policy_env(ENV_ID, "true", SHORT, decimation=10, action={"kind": "motor-offset"})
    env.reset(seed=1)
    errors, done = [], False
    while not done:
        _, _, terminated, truncated, info = env.step(np.zeros(2))
        errors.append(info["true_state"]["q"] - info["reference"]["q"])
        done = terminated or truncated
    evaluation = evaluate_policy(env, lambda obs: np.zeros(2), [1])
    env.close()
    norms = np.linalg.norm(errors, axis=1)
    assert evaluation.tracking_rms[0] == pytest.approx(np.sqrt(np.mean(norms**2)), rel=1e-12)


@pytest.mark.slow
def test_learning_curve_is_written_and_its_last_row_is_the_final_policy(tmp_path):
    """learning_curve.csv: a row at the start, one per eval_freq policy steps and one at the
    end, with growing steps and wall time; its last row is the saved model evaluated on
    the same episodes (seed + 10000, ...)."""
    config = TrainConfig(
        algo="ppo",
        state="true",
        total_steps=256,
        out_dir=str(tmp_path / "r"),
        env_kwargs=SHORT,
        eval_freq=100,
        eval_episodes=2,
        seed=3,
        hyperparams={"n_envs": 4, "batches": 1, "n_steps": 16, "batch_size": 32, "n_epochs": 1},
    )
    result = train(config, progress_bar=False)
    with open(Path(config.out_dir) / CURVE_FILE) as handle:
        rows = list(csv.DictReader(handle))
    assert tuple(rows[0]) == COLUMNS
    steps = [int(row["policy_steps"]) for row in rows]
    assert steps == [0, 100, 200, 256]  # 4 arms per step: evaluations at 100 and 200
    assert all(int(r["env_steps"]) == 10 * s for r, s in zip(rows, steps, strict=True))
    wall = [float(row["wall_time"]) for row in rows]
    assert wall[0] == pytest.approx(0.0, abs=0.05) and wall == sorted(wall)
    assert rows[0]["train_return"] == "" and float(rows[-1]["train_return"]) > 0
    final = evaluate_run(load_run(config.out_dir, trust_pickle=True), n_episodes=2, seed=3 + 10_000)
    assert float(rows[-1]["eval_return"]) == pytest.approx(final.mean_return, rel=1e-6)
    assert float(rows[-1]["tracking_rms"]) == pytest.approx(final.rms, rel=1e-6)
    assert result.eval_tracking_rms == pytest.approx(final.rms, rel=1e-6)
    saved = np.load(Path(config.out_dir) / "evaluations.npz")
    assert saved["tracking_rms"].shape == saved["results"].shape == (4, 2)
    # the same numbers whatever torch's thread count in the caller (a batch of 10 arms:
    # a multi-threaded matmul splits its rows differently, and the arms' episodes amplify
    # the last-bit differences)
    import torch

    run = load_run(config.out_dir, trust_pickle=True)
    one = evaluate_run(run, n_episodes=10, seed=7)
    torch.set_num_threads(2)
    assert evaluate_run(run, n_episodes=10, seed=7) == one


def test_linear_schedules_decay_to_zero():
    settings = resolve_hyperparams(
        "ppo", ENV_ID, {"learning_rate": "lin_1e-3", "clip_range": "lin_0.2"}
    )
    assert settings["learning_rate"](1.0) == pytest.approx(1e-3)
    assert settings["learning_rate"](0.25) == pytest.approx(2.5e-4)
    assert settings["clip_range"](0.5) == pytest.approx(0.1)
    for bad in ("exp_1e-3", "lin_x", "lin_-1", "lin_nan"):
        with pytest.raises(ValueError, match="lin_<number > 0>"):
            resolve_hyperparams("ppo", ENV_ID, {"learning_rate": bad})


def test_recurrent_ppo_on_raw_sensors_trains_reloads_and_remembers(tmp_path):
    """RecurrentPPO (sb3-contrib, an LSTM) on raw sensors: the run reloads and acts
    identically; its action depends on the memory (the same observation after a
    different history gives another action) until start() clears it."""
    config = TrainConfig(
        algo="recurrentppo",
        state="sensors",
        total_steps=128,
        out_dir=str(tmp_path / "r"),
        env_kwargs=SHORT,
        eval_freq=10**9,
        eval_episodes=2,
        frame_stack=1,
        hyperparams={
            "n_envs": 4,
            "n_steps": 16,
            "batch_size": 32,
            "n_epochs": 1,
            "policy_kwargs": {"lstm_hidden_size": 16, "net_arch": [16], "log_std_init": -1.0},
        },
    )
    train(config, progress_bar=False)
    first, second = (
        load_run(config.out_dir, trust_pickle=True),
        load_run(config.out_dir, trust_pickle=True),
    )
    env = policy_env(
        ENV_ID,
        "sensors",
        SHORT,
        decimation=10,
        action=first.config.policy_configs(first.settings)[0],
    )
    obs, _ = env.reset(seed=0)
    first.start()
    second.start()
    history = [obs]
    for _ in range(5):
        a, b = first.act(obs), second.act(obs)
        assert np.array_equal(a, b)
        obs, *_ = env.step(a)
        history.append(obs)
    env.close()
    remembered = first.act(history[0])
    first.start()
    fresh = first.act(history[0])
    second.start()
    assert np.array_equal(fresh, second.act(history[0]))
    assert not np.array_equal(remembered, fresh)
