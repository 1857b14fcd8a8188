"""Distillation of the plant teacher into a raw-sensor policy: the teacher's motor-offset
actions track every plant it knows, the feature the student identifies the load from is the
static torsion at the reset, DAgger fits the student, and what distillation cannot use is
refused."""

from __future__ import annotations

import csv

import numpy as np
import pytest
import torch
from gymnasium.vector import AutoresetMode
from helpers import fast_lane, policy_vec_env

from elastic_gym.training import ActionConfig, ActionMap, TrainConfig, load_run, train
from elastic_gym.training.distill import DistillConfig, distill
from elastic_gym.training.plan import plan_run
from elastic_gym.training.rollouts import evaluate_arms

ENV_ID = "elastic_gym/TwoLinkElastic-v0"
TASK = {"task_options": {"n_moves": 1, "move_time": 0.6, "dwell_time": 0.2}}
EXACT = {"encoder": {"resolution": 0.0, "noise_std": 0.0}, "accelerometer": "ideal"}
STUDENT = {"features": ["reference", "motor_error", "reset_rest", "acceleration"]}

pytestmark = pytest.mark.usefixtures("single_thread_torch")


def _teacher_env(n_arms: int, env_kwargs: dict, autoreset=AutoresetMode.NEXT_STEP):
    return policy_vec_env(
        ENV_ID,
        n_arms,
        state="sensors",
        env_kwargs={**TASK, **env_kwargs},
        decimation=10,
        action={"kind": "motor-offset"},
        observation=STUDENT,
        frame_stack=1,
        autoreset_mode=autoreset,
        teacher=True,
    )


def _follow(env, seed: int, actions: list | None = None):
    """Run every arm on the teacher's labels (or replay ``actions``); the evaluation and
    the actions applied."""
    last, applied = {}, []
    step, reset = env.step, env.reset

    def labelled_reset(**kwargs):
        obs, info = reset(**kwargs)
        last["label"] = info["teacher_action"]
        return obs, info

    def labelled_step(action):
        out = step(action)
        last["label"] = out[-1]["teacher_action"]
        return out

    env.reset, env.step = labelled_reset, labelled_step

    def act(_obs):
        action = last["label"] if actions is None else actions[len(applied)]
        applied.append(action)
        return action

    return evaluate_arms(env, act, seed), applied


def test_motor_offset_action_inverts_the_motor_pd():
    """ActionMap.torque(motor_offset_action(tau, ...), ...) is tau, with and without the
    gravity compensation (the action unclipped, inside [-1, 1])."""
    env = policy_vec_env(ENV_ID, 1, state="sensors", action={"kind": "motor-offset"})
    model = env.unwrapped.batch.model
    env.close()
    rng = np.random.default_rng(0)
    for gravity in (False, True):
        config = ActionConfig(kind="motor-offset", gravity_compensation=gravity)
        action_map = ActionMap(config, model)
        reference = rng.normal(size=(5, 5, 2)) * 0.3
        theta = reference[:, 0] + rng.normal(size=(5, 2)) * 0.005
        dtheta = reference[:, 1] + rng.normal(size=(5, 2)) * 0.05
        torque = action_map.torque(rng.uniform(-0.5, 0.5, (5, 2)), theta, dtheta, reference)
        action = action_map.motor_offset_action(torque, theta, dtheta, reference)
        assert np.abs(action).max() < 1.0
        np.testing.assert_allclose(
            action_map.torque(action, theta, dtheta, reference), torque, rtol=1e-12, atol=1e-12
        )


PLANTS = {  # plant -> (its env kwargs, whether the nominal teacher's actions fail on it)
    "nominal": ({}, False),
    "K x0.9": ({"plant_scaling": {"stiffness": 0.9}}, True),
    "B x1.1": ({"plant_scaling": {"motor_inertia": 1.1}}, False),  # its labels change 0.4 %
    "link mass x1.3": ({"plant_scaling": {"link_mass": 1.3}}, True),
    "Coulomb 3 %": ({"unmodelled_friction": {"coulomb": 0.03}}, True),
    "sensor delay 1 ms": ({"sensor_delay": 1}, True),
}


@pytest.mark.parametrize("plant", fast_lane(list(PLANTS), "nominal", "link mass x1.3"))
def test_the_plant_teacher_tracks_every_plant_it_knows(plant):
    """Its actions held at 100 Hz through the 1 kHz motor PD track every plant to < 1e-4
    rad RMS (INVDYN of the plant's own model, with its friction and sensor delay); the
    nominal plant's teacher actions replayed on a plant whose K, load, friction or delay
    differ are far worse (the teacher knows the plant). Over the first 0.4 s of the move."""
    kwargs, differs = PLANTS[plant]
    first = {"episode_time": 0.4}
    env = _teacher_env(2, {**kwargs, **first})
    evaluation, _ = _follow(env, 7)
    env.close()
    assert evaluation.rms < 1e-4
    if differs:
        nominal = _teacher_env(2, first)
        _, actions = _follow(nominal, 7)
        nominal.close()
        env = _teacher_env(2, {**kwargs, **first})
        replayed, _ = _follow(env, 7, actions)
        env.close()
        assert replayed.rms > 3 * evaluation.rms


def _rest(info) -> np.ndarray:
    """The feature reset_rest of the true state of ``info``: torsion / torsion_scale, q."""
    state = info["true_state"]
    return np.hstack([(state["theta"] - state["q"]) / 0.05, state["q"]])


def test_reset_rest_is_the_static_torsion_held_until_the_next_reset():
    """The feature reset_rest is theta - q at the reset (the arm rests on the reference's
    start), over torsion_scale, and that start q_d(0); it holds while the motors move and
    takes the new values when an arm restarts (a masked reset, as in training)."""
    env = _teacher_env(
        3, {**EXACT, "plant_scaling": {"link_mass": 1.2}}, autoreset=AutoresetMode.DISABLED
    )
    obs, info = env.reset(seed=4)
    np.testing.assert_allclose(info["true_state"]["q"], info["reference"]["q"], atol=1e-12)
    columns = slice(8, 12)  # after reference (3 rows x 2) and motor_error (2)
    rest = _rest(info)
    np.testing.assert_allclose(obs[:, columns], rest, rtol=1e-6, atol=1e-7)
    assert np.abs(rest[:, :2]).max() > 0.05  # gravity loads the springs
    ended = np.zeros(3, dtype=bool)
    while not ended.any():
        obs, _, terminated, truncated, info = env.step(info["teacher_action"])
        ended = terminated | truncated
        np.testing.assert_allclose(obs[:, columns], rest, rtol=1e-6, atol=1e-7)
    assert not np.allclose(obs[:, 6:8], rest[:, :2])  # the motor error moved on
    ended[0] = False  # arm 0 runs on past its end: its features stay
    obs, info = env.reset(options={"reset_mask": ended})
    np.testing.assert_allclose(obs[ended, columns], _rest(info)[ended], rtol=1e-6, atol=1e-7)
    assert not np.allclose(_rest(info)[ended], rest[ended])
    np.testing.assert_allclose(obs[0, columns], rest[0], rtol=1e-6, atol=1e-7)
    env.close()


def test_distill_refuses_what_it_cannot_use():
    """distill needs RecurrentPPO, the motor-offset action, a batch of arms and no RL
    steps (total steps refused); its own keys are checked."""

    def run(algo="recurrentppo", total_steps=None, **hyperparams) -> TrainConfig:
        keys = {"n_envs": 4, "action": {"kind": "motor-offset"}, "distill": {}, **hyperparams}
        return TrainConfig(algo=algo, total_steps=total_steps, hyperparams=keys)

    plan_run(run())
    cases = [
        (run(algo="ppo"), "algo recurrentppo"),
        (run(action={"kind": "torque"}), "motor-offset"),
        (run(n_envs=1), "n_envs > 1"),
        (run(total_steps=1000), "imitation only"),
    ]
    for config, match in cases:
        with pytest.raises(ValueError, match=match):
            plan_run(config)
    for distill_keys in ({"iteration": 3}, {"teacher_mix": 1.5}, {"steps": 0}):
        bad = TrainConfig(algo="recurrentppo", hyperparams={"distill": distill_keys})
        with pytest.raises(ValueError, match="distill"):
            bad.settings()


@pytest.mark.slow
def test_a_distilled_run_loads_and_retrains_bit_for_bit(tmp_path):
    """A tiny distilled run: the learning curve has the start and one row per iteration
    at the policy steps collected, the run folder loads and evaluates, and the same
    command trains the same weights and normalization bit for bit."""
    config = TrainConfig(
        algo="recurrentppo",
        state="sensors",
        frame_stack=1,
        out_dir=str(tmp_path / "distilled"),
        env_kwargs={**TASK, "episode_time": 0.5},
        eval_episodes=2,
        hyperparams={
            "n_envs": 4,
            "decimation": 10,
            "action": {"kind": "motor-offset"},
            "observation": {**STUDENT, "reference_order": 4},
            "distill": {
                "iterations": 2,
                "steps": 30,  # Adam steps per fit: the claims hold from the first
                "batch_size": 4,
                "learning_rate": 3e-3,
                "final_learning_rate": 3e-4,  # the cosine schedule retrains bit for bit too
            },
            "policy_kwargs": {"lstm_hidden_size": 16, "net_arch": [32]},
        },
    )
    result = train(config, progress_bar=False)
    with open(tmp_path / "distilled" / "learning_curve.csv") as handle:
        rows = list(csv.DictReader(handle))
    assert [int(r["policy_steps"]) for r in rows] == [0, 200, 400]  # 4 arms x 50 steps
    assert result.policy_steps == 400
    run = load_run(config.out_dir, trust_pickle=True)
    assert run.settings.distill == DistillConfig(**config.hyperparams["distill"])
    assert np.isfinite(float(rows[-1]["tracking_rms"]))
    again = config.model_copy(update={"out_dir": str(tmp_path / "again")})
    train(again, progress_bar=False)
    rerun = load_run(again.out_dir, trust_pickle=True)
    for name, value in run.model.policy.state_dict().items():
        assert torch.equal(value, rerun.model.policy.state_dict()[name]), name
    assert np.array_equal(run.normalizer.obs_rms.mean, rerun.normalizer.obs_rms.mean)


@pytest.mark.slow
def test_distill_lowers_the_loss_of_the_student(tmp_path):
    """DAgger on 4 arms: the fit's mean squared error to the teacher's labels ends far
    below the labels' own mean square (what a zero action scores)."""
    from sb3_contrib import RecurrentPPO
    from stable_baselines3.common.vec_env import VecNormalize

    from elastic_gym.training.run_envs import training_vec_env

    config = TrainConfig(
        algo="recurrentppo",
        state="sensors",
        frame_stack=1,
        env_kwargs={**TASK, "episode_time": 0.5},
        hyperparams={
            "n_envs": 4,
            "decimation": 10,
            "action": {"kind": "motor-offset"},
            "observation": {**STUDENT, "reference_order": 4},
            "distill": {},
        },
    )
    settings, _ = config.settings()
    venv = VecNormalize(training_vec_env(config.policy_spec(settings), settings, 4, 0))
    model = RecurrentPPO(
        "MlpLstmPolicy",
        venv,
        n_steps=16,
        batch_size=16,
        seed=0,
        device="cpu",
        policy_kwargs={"lstm_hidden_size": 16, "net_arch": [32]},
    )
    try:
        obs = venv.reset()
        labels = np.stack([info["teacher_action"] for info in venv.unwrapped.reset_infos])
        assert obs.shape == (4, venv.observation_space.shape[0])
        losses = distill(model, venv, DistillConfig(iterations=2, steps=200, batch_size=4), 0)
    finally:
        venv.close()
    mean_square = float(np.mean(labels**2))
    assert losses[-1] < 0.05 * mean_square
