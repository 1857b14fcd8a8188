"""RL training on the estimated state: SB3 runs save, reload, act identically, and learn."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from elastic_gym.training import (
    TrainConfig,
    evaluate_run,
    load_run,
    make_policy_env,
    parse_overrides,
    train,
)
from elastic_gym.training.config import algorithm_class, resolve_hyperparams
from elastic_gym.training.train import TrainedRun, env_factory, split_settings

SHORT_EPISODES = {"max_episode_steps": 200}


@pytest.fixture(autouse=True)
def _single_thread_torch():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.mark.parametrize(
    ("algo", "hyperparams"),
    [
        ("ppo", {"n_envs": 2, "n_steps": 64, "batch_size": 64, "n_epochs": 2}),
        ("sac", {"learning_starts": 50, "batch_size": 32,
                 "policy_kwargs": {"net_arch": [32, 32]}}),
    ],
)
def test_short_run_saves_reloads_and_acts_the_same(tmp_path, algo, hyperparams):
    config = TrainConfig(
        algo=algo, state="deluca", total_steps=128, out_dir=str(tmp_path / algo),
        env_kwargs=SHORT_EPISODES, hyperparams=hyperparams, eval_freq=64, eval_episodes=1,
    )
    result = train(config, progress_bar=False)
    for name in ("model.zip", "vecnormalize.pkl", "config.yaml", "summary.json",
                 "best_model.zip", "evaluations.npz"):
        assert (tmp_path / algo / name).exists(), name
    assert (tmp_path / algo / "tb").is_dir()
    assert result.policy_steps >= 128 and result.env_steps == 10 * result.policy_steps

    first, second = load_run(result.out_dir), load_run(result.out_dir)
    env = make_policy_env(config.env_id, "deluca", SHORT_EPISODES, decimation=10)
    obs, _ = env.reset(seed=0)
    observations = [obs]
    for _ in range(5):
        obs, *_ = env.step(env.action_space.sample())
        observations.append(obs)
    env.close()
    actions = [first.act(o) for o in observations]
    assert all(np.array_equal(a, second.act(o)) for a, o in zip(actions, observations, strict=True))
    assert all(a.shape == (2,) and np.all(np.abs(a) <= 1.0) for a in actions)
    assert first.normalizer.obs_rms.count > 1  # statistics were saved, not defaults


def test_training_improves_the_return_on_regulation(tmp_path):
    """SAC learns to hold the elastic arm at a goal: the trained return beats the untrained
    policy's (which lets the arm fall) by a clear margin."""
    hyperparams = {"learning_starts": 200, "batch_size": 64, "decimation": 20,
                   "learning_rate": 1e-3, "gamma": 0.95, "policy_kwargs": {"net_arch": [64, 64]}}
    env_kwargs = {"max_episode_steps": 400, "task": "regulation", "accelerometer": "ideal"}
    config = TrainConfig(algo="sac", state="true", total_steps=2500, out_dir=str(tmp_path / "r"),
                         env_kwargs=env_kwargs, hyperparams=hyperparams, eval_freq=10**9)
    train(config, progress_bar=False)
    trained = evaluate_run(load_run(config.out_dir), n_episodes=4)

    settings, algo_kwargs = split_settings(config)
    from stable_baselines3.common.env_util import make_vec_env

    fresh = algorithm_class("sac")("MlpPolicy", make_vec_env(env_factory(config, settings), 1),
                                   seed=0, device="cpu", **algo_kwargs)
    untrained = evaluate_run(TrainedRun(fresh, None, config, settings), n_episodes=4)
    assert trained > 0.5 * untrained  # returns are negative: at least halve the cost


def test_residual_policy_env_starts_from_the_classical_controller():
    env = make_policy_env("elastic_gym/TwoLinkElastic-v0", "true",
                          {"max_episode_steps": 300, "accelerometer": "ideal"},
                          decimation=10, residual="feedforward-state-feedback", residual_scale=0.1)
    obs, _ = env.reset(seed=0)
    total, errors = 0.0, []
    done = False
    while not done:
        obs, reward, terminated, truncated, info = env.step(np.zeros(2))
        total += reward
        errors.append(np.abs(info["true_state"]["q"] - info["reference"]["q"]).max())
        done = terminated or truncated
    env.close()
    assert max(errors) < 1e-3  # zero residual = eq. (13), which tracks


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"algo": "a2c"}, "a2c"),
        ({"state": "telepathy"}, "telepathy"),
        ({"total_steps": -5}, "total_steps"),
    ],
)
def test_bad_training_config(kwargs, match):
    with pytest.raises(ValueError, match=match):
        TrainConfig(**kwargs)


def test_bad_hyperparameters(tmp_path):
    with pytest.raises(ValueError, match="learning_rat"):
        resolve_hyperparams("sac", "elastic_gym/TwoLinkElastic-v0", {"learning_rat": 1e-3})
    broken = tmp_path / "broken.yaml"
    broken.write_text("default: [unclosed\n")
    with pytest.raises(ValueError, match="invalid YAML"):
        resolve_hyperparams("sac", "elastic_gym/TwoLinkElastic-v0", file=broken)
    wrong = tmp_path / "wrong.yaml"
    wrong.write_text("default: 3\n")
    with pytest.raises(ValueError, match="default"):
        resolve_hyperparams("sac", "elastic_gym/TwoLinkElastic-v0", file=wrong)
    with pytest.raises(ValueError, match="key=value"):
        parse_overrides(["learning_rate"])
    assert parse_overrides(["learning_rate=1e-4", "n_envs=2"]) == {"learning_rate": 1e-4,
                                                                    "n_envs": 2}


def test_shipped_hyperparameters_are_valid():
    import elastic_gym

    for algo in ("ppo", "sac", "td3"):
        for env_id in elastic_gym.ENV_IDS:
            settings = resolve_hyperparams(algo, env_id)
            assert settings["n_timesteps"] > 0 and settings["decimation"] >= 1


def test_raw_sensor_policy_env_stacks_frames():
    env = make_policy_env("elastic_gym/TwoLinkElastic-v0", "sensors", decimation=5,
                          frame_stack=4)
    obs, _ = env.reset(seed=0)
    assert obs.shape == (4 * (2 + 6 + 4),)  # motor position, 2 accelerometers, reference
    env.close()


def test_trained_run_as_comparison_controller_matches_the_policy_env(tmp_path):
    """The "trained-policy" controller behind an ObserverWrapper reproduces the training
    stack (same flattening, normalization and decimation): same episode return."""
    import gymnasium as gym

    from elastic_gym.controllers import make_controller, public_info
    from elastic_gym.observers import ObserverWrapper

    config = TrainConfig(algo="sac", state="deluca", total_steps=100, out_dir=str(tmp_path / "p"),
                         env_kwargs=SHORT_EPISODES, eval_freq=10**9,
                         hyperparams={"learning_starts": 50, "batch_size": 32,
                                      "policy_kwargs": {"net_arch": [32, 32]}})
    train(config, progress_bar=False)
    run = load_run(config.out_dir)

    env = ObserverWrapper(gym.make(config.env_id, **SHORT_EPISODES), "deluca")
    controller = make_controller("trained-policy", env.unwrapped.model, 1e-3, run=config.out_dir)
    assert controller.decimation == 10 and controller.state_source == "deluca"
    obs, info = env.reset(seed=4)
    controller.reset(obs, public_info(info))
    comparison_return, done = 0.0, False
    while not done:
        obs, reward, terminated, truncated, info = env.step(controller(obs, public_info(info)))
        comparison_return += reward
        done = terminated or truncated
    env.close()

    policy_env = make_policy_env(config.env_id, "deluca", SHORT_EPISODES, decimation=10)
    obs, _ = policy_env.reset(seed=4)
    training_return, done = 0.0, False
    while not done:
        obs, reward, terminated, truncated, _ = policy_env.step(run.act(obs))
        training_return += reward
        done = terminated or truncated
    policy_env.close()
    assert comparison_return == pytest.approx(training_return, rel=1e-6)


def test_cli_trains_two_seeds_on_ray_and_compares_the_policy(tmp_path, capsys):
    """`elastic-gym train --seeds 0 1 --backend ray` runs both jobs on a local Ray instance and
    gathers them in one table; `elastic-gym compare --policy RUN` adds the policy's rows."""
    ray = pytest.importorskip("ray", reason="the 'ray' extra is not installed")
    from elastic_gym.cli import main

    out = tmp_path / "runs"
    try:
        code = main(["train", "--steps", "40", "--seeds", "0", "1", "--backend", "ray",
                     "--workers", "2", "--out", str(out), "--env-kwargs",
                     "{max_episode_steps: 100}", "--hyperparams", "learning_starts=20",
                     "batch_size=16", "--eval-freq", "1000000", "--no-progress"])
    finally:
        ray.shutdown()
    assert code == 0
    printed = capsys.readouterr().out
    for seed in (0, 1):
        assert (out / f"seed{seed}" / "model.zip").exists()
        assert (out / f"seed{seed}" / "vecnormalize.pkl").exists()
    assert "policy steps" in printed and printed.count("seed") >= 2

    code = main(["compare", "--policy", str(out / "seed0"), "--seeds", "0", "--duration", "0.2",
                 "--workers", "1", "--output", str(tmp_path / "cmp"), "--no-plots",
                 "--no-progress"])
    assert code == 0
    summary = (tmp_path / "cmp" / "summary.md").read_text()
    assert "policy:seed0" in summary and "eq13-state-feedback" in summary


def test_cli_rejects_bad_training_input(tmp_path, capsys):
    from elastic_gym.cli import main

    with pytest.raises(SystemExit) as exit_info:
        main(["train", "--env-kwargs", "[1, 2", "--out", str(tmp_path)])
    assert exit_info.value.code == 2
    assert "--env-kwargs" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["train", "--algo", "a2c"])  # argparse lists the valid choices
    with pytest.raises(SystemExit) as exit_info:
        main(["compare", "--policy", str(tmp_path)])
    assert "not a training run folder" in capsys.readouterr().err


def test_run_folder_freezes_its_hyperparameters(tmp_path):
    """config.yaml holds the hyper-parameters used, so a later change of the shipped file
    cannot change how a saved policy is rebuilt (e.g. its decimation)."""
    import yaml

    config = TrainConfig(algo="sac", state="true", total_steps=30, out_dir=str(tmp_path / "f"),
                         env_kwargs=SHORT_EPISODES, eval_freq=10**9,
                         hyperparams={"learning_starts": 10, "batch_size": 8, "decimation": 5})
    train(config, progress_bar=False)
    saved = yaml.safe_load((tmp_path / "f" / "config.yaml").read_text())
    assert saved["hyperparams_file"] is None
    assert saved["hyperparams"]["decimation"] == 5
    assert saved["hyperparams"]["gamma"] == resolve_hyperparams("sac", config.env_id)["gamma"]
    assert load_run(tmp_path / "f").decimation == 5
