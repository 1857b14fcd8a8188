"""RL training on the estimated state: SB3 runs save, reload, act identically, and learn."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from helpers import policy_env, spec_env

from elastic_gym.training import (
    ActionConfig,
    ObservationConfig,
    TrainConfig,
    evaluate_run,
    load_run,
    parse_overrides,
    train,
)
from elastic_gym.training.config import Settings, load_hyperparams_file, resolve_hyperparams
from elastic_gym.training.rollouts import evaluate_policy

SHORT_EPISODES = {"max_episode_steps": 200}


pytestmark = pytest.mark.usefixtures("single_thread_torch")


def short_deluca_run(out_dir: Path, algo: str, hyperparams: dict):
    """128 policy steps on the De Luca estimate with short episodes, one learning-curve
    point halfway."""
    config = TrainConfig(
        algo=algo,
        state="deluca",
        total_steps=128,
        out_dir=str(out_dir),
        env_kwargs=SHORT_EPISODES,
        hyperparams=hyperparams,
        eval_freq=64,
        eval_episodes=1,
    )
    return train(config, progress_bar=False)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("algo", "hyperparams"),
    [
        ("ppo", {"n_envs": 2, "batches": 1, "n_steps": 64, "batch_size": 64, "n_epochs": 2}),
        ("sac", {"learning_starts": 50, "batch_size": 32, "policy_kwargs": {"net_arch": [32, 32]}}),
    ],
)
def test_short_run_saves_reloads_and_acts_the_same(tmp_path, algo, hyperparams):
    result = short_deluca_run(tmp_path / algo, algo, hyperparams)
    for name in (
        "model.zip",
        "vecnormalize.pkl",
        "config.yaml",
        "summary.json",
        "best_model.zip",
        "evaluations.npz",
        "learning_curve.csv",
    ):
        assert (tmp_path / algo / name).exists(), name
    assert (tmp_path / algo / "tb").is_dir()
    assert result.policy_steps >= 128 and result.env_steps == 10 * result.policy_steps

    first, second = (
        load_run(result.out_dir, trust_pickle=True),
        load_run(result.out_dir, trust_pickle=True),
    )
    env = spec_env(first.spec)  # the run's own observation and actions
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


@pytest.mark.slow
def test_ppo_learns_to_hold_the_arm_against_gravity(tmp_path):
    """PPO with motor-offset actions (no model term) learns the offset that cancels the
    gravity sag of the elastic arm held at a configuration: after 2000 policy steps on 4
    arms of one batched PyBullet world its link error is below 30 % of the zero-offset
    policy's (the PD alone sags ~8 mrad)."""
    env_kwargs = {
        "max_episode_steps": 100,
        "task": "regulation",
        "accelerometer": "ideal",
        "task_options": {"start": [-1.0, 0.5], "goal": [-1.0, 0.5]},
    }
    hyperparams = {
        "n_envs": 4,
        "batches": 1,  # one world in this process (ppo.yaml: 2 worker processes)
        "n_steps": 25,
        "batch_size": 50,
        "n_epochs": 10,
        "learning_rate": 3e-3,
        "gamma": 0.9,
        "decimation": 10,
        "policy_kwargs": {"net_arch": [32, 32], "log_std_init": -1.0},
    }
    config = TrainConfig(
        algo="ppo",
        state="true",
        total_steps=2000,
        out_dir=str(tmp_path / "r"),
        env_kwargs=env_kwargs,
        hyperparams=hyperparams,
        eval_freq=1000,
        eval_episodes=2,
        action={"kind": "motor-offset"},
    )
    train(config, progress_bar=False)
    curve = np.genfromtxt(Path(config.out_dir) / "learning_curve.csv", delimiter=",", names=True)
    assert list(curve["policy_steps"]) == [0, 1000, 2000]
    # the learning curve shows the learning: return up, tracking error down
    assert curve["eval_return"][-1] > curve["eval_return"][0]
    assert curve["tracking_rms"][-1] < 0.3 * curve["tracking_rms"][0]
    trained = evaluate_run(load_run(config.out_dir, trust_pickle=True), n_episodes=2)
    settings, _ = config.settings()
    env = spec_env(config.policy_spec(settings))
    zero = evaluate_policy(env, lambda obs: np.zeros(2), trained.seeds)
    env.close()
    assert zero.rms > 5e-3
    assert trained.rms < 0.3 * zero.rms
    assert trained.mean_return > zero.mean_return


def test_residual_policy_env_starts_from_the_classical_controller():
    env = policy_env(
        "elastic_gym/TwoLinkElastic-v0",
        "true",
        {"max_episode_steps": 300, "accelerometer": "ideal"},
        decimation=10,
        action={
            "kind": "residual",
            "residual_scale": 0.1,
            "residual": "feedforward-state-feedback",
        },
    )
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


@pytest.mark.slow
def test_a_residual_on_link_masses_is_the_base_on_the_corrected_model():
    """``residual_space: link-mass``: an action in the deadzone is the base exactly; a
    constant action s = 1.3 on links 30 % heavier removes most of the base's error, the
    error of a model that knows the load (the base's own gains); one shared scale is the
    same law with one action entry."""
    kwargs = {
        "max_episode_steps": 500,  # the first 0.5 s of the move: the load shows from the start
        "task": "tracking",
        "task_options": {"n_moves": 1, "move_time": 0.6, "dwell_time": 0.2},
        "accelerometer": "ideal",
    }
    action = {
        "kind": "residual",
        "residual": "integral-state-feedback",
        "residual_space": "link-mass",
        "residual_scale": 0.6,
        "residual_deadzone": 0.2,
    }

    def run(a: float, space: str = "link-mass", shared: bool = False) -> np.ndarray:
        env = policy_env(
            "elastic_gym/TwoLinkElastic-v0",
            "true",
            {**kwargs, "plant_scaling": {"link_mass": 1.3}},
            decimation=10,
            action={**action, "residual_space": space, "residual_shared": shared},
            observation={"features": ["error", "last_action"]},
        )
        env.reset(seed=3)
        assert env.action_space.shape == (1 if shared else 2,)
        assert env.observation_space.shape == (2 + env.action_space.shape[0],)
        errors, done = [], False
        while not done:
            _, _, terminated, truncated, info = env.step(np.full(env.action_space.shape, a))
            errors.append(info["true_state"]["q"] - info["reference"]["q"])
            done = terminated or truncated
        env.close()
        return np.array(errors)

    base = run(0.0, "torque")  # a zero torque residual: the base alone
    np.testing.assert_array_equal(run(0.2), base)
    knows = run(0.2 + 0.8 * 0.3 / 0.6)  # s = 1 + 0.6 rho(a) = 1.3
    rms_base, rms_knows = (float(np.sqrt(np.mean(e**2))) for e in (base, knows))
    assert rms_base > 1e-3  # the base sags under the unmodelled load
    assert rms_knows < 0.1 * rms_base
    np.testing.assert_array_equal(run(0.2 + 0.8 * 0.3 / 0.6, shared=True), knows)
    # the action as the rate of s: integrated from 1 to its bound 1.3 in 3 ms, then held
    action.update(residual_rate=100.0, residual_scale=0.3)
    adapts = run(1.0)
    assert float(np.sqrt(np.mean(adapts**2))) < 0.1 * rms_base
    np.testing.assert_array_equal(run(0.2), base)  # the deadzone holds s = 1
    np.testing.assert_array_equal(run(1.0, shared=True), adapts)
    with pytest.raises(ValueError, match="needs kind 'residual'"):
        ActionConfig(kind="torque", residual_space="link-mass")
    with pytest.raises(ValueError, match="residual_rate needs"):
        ActionConfig(kind="residual", residual="motor-pd", residual_rate=1.0)
    with pytest.raises(ValueError, match="residual_shared needs"):
        ActionConfig(kind="residual", residual="motor-pd", residual_shared=True)
    with pytest.raises(ValueError, match="'link_mass_estimate' needs"):
        policy_env(
            "elastic_gym/TwoLinkElastic-v0",
            "true",
            action={**action, "residual_rate": None},
            observation={"features": ["error", "link_mass_estimate"]},
        )
    with pytest.raises(ValueError, match="needs a base with INVDYN"):
        policy_env(
            "elastic_gym/TwoLinkRigid-v0",
            "true",
            action={**action, "residual": "feedback-linearization"},
        )


@pytest.mark.parametrize(("state", "rtol"), [("true", 1e-4), ("deluca", 1e-2)])
def test_link_mass_fit_is_the_load_at_a_reset_at_rest(state, rtol):
    """``link_mass_fit``: an arm reset at rest in the static equilibrium of links 30 %
    heavier than the model (q = q_d, theta the true static torsion) shows the load as the
    fitted scales, per link and shared, held until the next reset; on the nominal plant
    they are zero (De Luca: the encoders' quantization and noise)."""
    action = {
        "kind": "residual",
        "residual": "integral-state-feedback",
        "residual_space": "link-mass",
        "residual_scale": 0.6,
    }
    for shared in (False, True):
        for scale, fitted in ((1.3, 0.3), (1.0, 0.0)):
            env = policy_env(
                "elastic_gym/TwoLinkElastic-v0",
                state,
                {"plant_scaling": {"link_mass": scale}, "task": "tracking"},
                action={**action, "residual_shared": shared},
                observation={"features": ["link_mass_fit"]},
            )
            obs, info = env.reset(seed=2)
            assert obs.shape == (1 if shared else 2,)
            np.testing.assert_allclose(obs * 0.6, fitted, rtol=rtol, atol=0.2 * rtol)
            for _ in range(5):  # held while the base moves the motor
                held, *_ = env.step(np.ones(env.action_space.shape))
                np.testing.assert_array_equal(held, obs)
            env.close()
    with pytest.raises(ValueError, match="'link_mass_fit' needs"):
        policy_env(
            "elastic_gym/TwoLinkElastic-v0",
            "true",
            action={**action, "residual_space": "torque"},
            observation={"features": ["error", "link_mass_fit"]},
        )


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
    wrong_kinds = [
        ({"n_steps": "abc"}, "hyper-parameter n_steps: Input should be a valid integer"),
        ({"learning_rate": float("nan")}, "learning_rate: Input should be a finite number"),
        ({"n_steps": 64.5}, "n_steps: Input should be a valid integer"),
        ({"n_envs": 0}, "n_envs: Input should be greater than or equal to 1"),
        ({"normalize": "yes"}, "normalize: Input should be a valid boolean, got 'yes'"),
        ({"use_sde": "no"}, "use_sde: Input should be a valid boolean"),
    ]
    for overrides, match in wrong_kinds:  # refused before any env exists, not inside SB3
        with pytest.raises(ValueError, match=match):
            resolve_hyperparams("ppo", "elastic_gym/TwoLinkElastic-v0", overrides)
    floats = resolve_hyperparams(
        "ppo", "elastic_gym/TwoLinkElastic-v0", {"n_timesteps": 1e6, "n_steps": 64.0}
    )  # YAML's !!float 1e6
    assert (floats["n_timesteps"], floats["n_steps"]) == (1_000_000, 64)
    assert type(floats["n_steps"]) is int
    assert parse_overrides(["learning_rate=1e-4", "n_envs=2"]) == {
        "learning_rate": 1e-4,
        "n_envs": 2,
    }


def test_a_shipped_recipe_is_found_by_its_name_from_any_directory(tmp_path, monkeypatch):
    """``--hyperparams-file ppo-robust.yaml`` outside the repository reads the shipped
    recipe; a file of that name in the working directory is the user's and wins; a name
    that is neither is refused naming it."""
    monkeypatch.chdir(tmp_path)
    env_id = "elastic_gym/TwoLinkElastic-v0"
    shipped = Path(__file__).parents[1] / "elastic_gym/training/hyperparams/ppo-robust.yaml"
    assert load_hyperparams_file("ppo-robust.yaml") == yaml.safe_load(shipped.read_text())
    (tmp_path / "ppo-robust.yaml").write_text("default: {n_timesteps: 1000}\n")
    assert load_hyperparams_file("ppo-robust.yaml") == {"default": {"n_timesteps": 1000}}
    with pytest.raises(ValueError, match=r"no-such-recipe\.yaml: cannot be read"):
        resolve_hyperparams("ppo", env_id, file="no-such-recipe.yaml")
    with pytest.raises(ValueError, match="cannot be read"):  # a path is never looked up
        resolve_hyperparams("ppo", env_id, file="sub/ppo.yaml")


def test_shipped_hyperparameters_are_valid():
    """Every algorithm's settings resolve for every id, and their action parameterization
    applies to its robot (motor offsets only on elastic arms)."""
    import gymnasium as gym

    import elastic_gym
    from elastic_gym.training import ActionMap

    for env_id in elastic_gym.ENV_IDS:
        env = gym.make(env_id)
        for algo in ("ppo", "sac", "td3"):
            config = TrainConfig(env_id=env_id, algo=algo)
            settings, _ = config.settings()
            assert settings.n_timesteps > 0 and settings.decimation >= 1
            action, _ = config.policy_configs(settings)
            ActionMap(action, env.unwrapped.model)
        env.close()


@pytest.mark.slow
def test_a_run_trained_without_normalization_loads_and_evaluates(tmp_path):
    """``normalize: false``: the saved VecNormalize has no observation statistics; the run
    folder still loads, acts on the raw features and evaluates on the comparison's loop
    (SB3's unpickled wrapper recursed when asked for the missing statistics)."""
    hyperparams = {"n_envs": 2, "batches": 1, "n_steps": 64, "batch_size": 64, "normalize": False}
    run = load_run(
        short_deluca_run(tmp_path / "raw", "ppo", hyperparams).out_dir, trust_pickle=True
    )
    assert not run.normalizer.norm_obs
    features = np.linspace(-1.0, 1.0, run.model.observation_space.shape[0], dtype=np.float32)
    assert np.array_equal(run.normalizer.normalize_obs(features[None])[0], features)
    evaluation = evaluate_run(run, 1, 100_000, SHORT_EPISODES)
    assert np.isfinite(evaluation.rms) and evaluation.rms > 0


@pytest.mark.parametrize(
    ("recipe", "delays_drawn"),
    [
        ("ppo-robust.yaml", True),
        ("recurrentppo-deluca-robust.yaml", True),
        ("recurrentppo-robust.yaml", True),
        ("ppo-residual-robust.yaml", False),  # plants on which its base is stable
    ],
)
def test_shipped_robust_recipes_randomize_every_plant_parameter(recipe, delays_drawn):
    """Link mass and inertia, unmodelled friction, K, B and D are drawn, and the sensor
    delay (1 ms in some episodes) by the pure-RL recipes; the env accepts the ranges."""
    import gymnasium as gym

    entry = load_hyperparams_file(recipe)["elastic_gym/TwoLinkElastic-v0"]
    ranges = entry["env_kwargs"]["randomize"]
    plant = {
        "plant_scaling.link_mass",
        "plant_scaling.link_inertia",
        "plant_scaling.stiffness",
        "plant_scaling.motor_inertia",
        "plant_scaling.damping",
        "unmodelled_friction.coulomb",
    }
    assert set(ranges) == plant | ({"sensor_delay"} if delays_drawn else set())
    assert all(ranges[key]["high"] > ranges[key]["low"] for key in plant)
    env = gym.make("elastic_gym/TwoLinkElastic-v0", **entry["env_kwargs"])
    resets = [env.reset(seed=seed)[1]["plant"] for seed in range(20)]
    delays = {float(info.get("sensor_delay", 0)) for info in resets}  # reported when drawn
    assert delays == ({0.0, 1.0} if delays_drawn else {0.0})
    masses = [info["plant_scaling.link_mass"] for info in resets]
    mass_range = ranges["plant_scaling.link_mass"]
    drawn = [m for m in masses if m != mass_range.get("otherwise", mass_range["low"])]
    assert len(set(drawn)) == len(drawn) >= 20 * mass_range.get("probability", 1.0) - 5
    env.close()


def test_raw_sensor_policy_env_stacks_frames():
    env = policy_env("elastic_gym/TwoLinkElastic-v0", "sensors", decimation=5, frame_stack=4)
    obs, _ = env.reset(seed=0)
    # motor error, 2 accelerometers, reference q_d, q_d', q_d'', last action
    assert obs.shape == (4 * (2 + 6 + 6 + 2),)
    env.close()


def test_a_state_source_is_seen_in_frames_oldest_first_and_raw_sensors_refuse_them():
    """``observation.frames`` k: the actor sees the last k feature vectors of the
    memoryless stack, oldest first (the reset frame repeated until k steps were taken);
    raw sensors are stacked by ``frame_stack`` and refuse ``frames``."""
    kwargs = {"decimation": 5, "action": {"kind": "motor-offset"}}
    plain = policy_env("elastic_gym/TwoLinkElastic-v0", "deluca", **kwargs)
    framed = policy_env("elastic_gym/TwoLinkElastic-v0", "deluca", frame_stack=3, **kwargs)
    seen = [plain.reset(seed=3)[0]]
    stacked = [framed.reset(seed=3)[0]]
    for k in range(4):
        action = np.full(2, 0.3 * (-1) ** k, dtype=np.float32)
        seen.append(plain.step(action)[0])
        stacked.append(framed.step(action)[0])
    size = seen[0].size
    assert stacked[0].shape == (3 * size,)
    np.testing.assert_array_equal(stacked[0], np.tile(seen[0], 3))
    for t in range(2, 5):
        np.testing.assert_array_equal(stacked[t], np.concatenate(seen[t - 2 : t + 1]))
    plain.close()
    framed.close()
    config = TrainConfig(algo="ppo", state="deluca", observation={"frames": 4})
    assert config.policy_spec(config.settings()[0]).frames == 4
    with pytest.raises(ValueError, match=r"observation\.frames: applies only when the state"):
        TrainConfig(algo="ppo", state="sensors", observation={"frames": 4})


EVERY_STATE_RESIDUAL_FEATURE = [
    "error",
    "error_rate",
    "error_integral",
    "reference",
    "torsion",
    "torsion_rate",
    "last_action",
    "base_torque",
    "base_motor_error",
]
SHORT_SAC = {"learning_starts": 25, "batch_size": 16, "policy_kwargs": {"net_arch": [32, 32]}}


@pytest.mark.slow
@pytest.mark.parametrize(
    ("action", "algo", "hyperparams"),
    [
        ({"kind": "torque"}, "sac", SHORT_SAC),
        ({"kind": "motor-offset"}, "sac", SHORT_SAC),
        (
            {"kind": "residual", "residual": "integral-state-feedback", "residual_deadzone": 0.0},
            "sac",  # every feature a residual on a state source can see, every action acts
            {**SHORT_SAC, "observation": {"features": EVERY_STATE_RESIDUAL_FEATURE}},
        ),
        (
            {
                "kind": "residual",
                "residual": "integral-state-feedback",
                "residual_space": "link-mass",
                "residual_deadzone": 0.0,
            },
            "ppo",  # the residual scales the base's link masses
            {"n_envs": 1, "n_steps": 50, "batch_size": 50, "n_epochs": 2},
        ),
        (
            {
                "kind": "residual",
                "residual": "integral-state-feedback",
                "residual_space": "link-mass",
                "residual_rate": 20.0,
                "residual_deadzone": 0.0,
            },
            "ppo",  # ... at the rate of its action, and sees its scales
            {
                "n_envs": 1,
                "n_steps": 50,
                "batch_size": 50,
                "n_epochs": 2,
                "observation": {"features": ["error", "error_integral", "link_mass_estimate"]},
            },
        ),
        (
            {
                "kind": "residual",
                "residual": "integral-state-feedback",
                "residual_space": "link-mass",
                "residual_rate": 20.0,
                "residual_shared": True,
                "residual_deadzone": 0.0,
            },
            "ppo",  # ... one scale for all links: one action entry; the fitted load
            {
                "n_envs": 1,
                "n_steps": 50,
                "batch_size": 50,
                "n_epochs": 2,
                "observation": {
                    "features": ["error", "last_action", "link_mass_estimate", "link_mass_fit"]
                },
            },
        ),
        (
            {"kind": "motor-offset"},
            "ppo",  # one env (DummyVecEnv); a critic with the truth
            {"critic_state": True, "n_envs": 1, "n_steps": 50, "batch_size": 50, "n_epochs": 2},
        ),
        (
            {"kind": "motor-offset"},
            "ppo",  # the error integral: a memory of the stack and of the controller
            {
                "n_envs": 1,
                "n_steps": 50,
                "batch_size": 50,
                "n_epochs": 2,
                "observation": {
                    "features": ["error", "error_integral", "reference", "last_action"],
                    "error_integral_scale": 1e-5,
                },
            },
        ),
    ],
)
def test_trained_run_as_comparison_controller_matches_the_policy_env(
    tmp_path, action, algo, hyperparams
):
    """The "trained-policy" controller behind an ObserverWrapper reproduces the training
    stack (same features, normalization, decimation and action map): same episode return.
    A PPO run whose critic saw the true state needs no true state here."""
    import gymnasium as gym

    from elastic_gym.controllers import make_controller, public_info
    from elastic_gym.observers import ObserverWrapper

    config = TrainConfig(
        algo=algo,
        state="deluca",
        total_steps=50,  # PPO: one update (n_steps 50); SAC: 25 gradient steps
        out_dir=str(tmp_path / "p"),
        env_kwargs=SHORT_EPISODES,
        eval_freq=10**9,
        eval_episodes=1,
        action=action,
        hyperparams=hyperparams,
    )
    train(config, progress_bar=False)
    run = load_run(config.out_dir, trust_pickle=True)

    env = ObserverWrapper(gym.make(config.env_id, **SHORT_EPISODES), "deluca")
    model = env.unwrapped.model
    controller = make_controller(
        "trained-policy", model, 1e-3, run=config.out_dir, trust_pickle=True
    )
    assert controller.decimation == 10 and controller.state_source == "deluca"
    obs, info = env.reset(seed=4)
    controller.reset(obs, public_info(info))
    comparison_return, done = 0.0, False
    while not done:
        obs, reward, terminated, truncated, info = env.step(controller(obs, public_info(info)))
        comparison_return += reward
        done = terminated or truncated
    env.close()
    comparison_state = info["true_state"]["x"]

    stack = policy_env(
        config.env_id,
        "deluca",
        SHORT_EPISODES,
        decimation=10,
        action=action,
        observation=config.policy_configs(run.settings)[1],
    )
    obs, _ = stack.reset(seed=4)
    training_return, done = 0.0, False
    while not done:
        obs, reward, terminated, truncated, info = stack.step(run.act(obs))
        training_return += reward
        done = terminated or truncated
    stack.close()
    assert comparison_return == pytest.approx(training_return, rel=1e-9)
    np.testing.assert_allclose(comparison_state, info["true_state"]["x"], rtol=0, atol=1e-12)


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
    assert "is neither an exported policy" in capsys.readouterr().err


def test_run_folder_freezes_its_hyperparameters(tmp_path):
    """config.yaml holds the hyper-parameters used and every field of the action and
    observation configs, so a later change of the shipped file or of a default cannot
    change how a saved policy is rebuilt (e.g. its decimation, its residual deadzone)."""
    import yaml

    config = TrainConfig(
        algo="sac",
        state="true",
        total_steps=30,
        out_dir=str(tmp_path / "f"),
        env_kwargs=SHORT_EPISODES,
        eval_freq=10**9,
        hyperparams={"learning_starts": 10, "batch_size": 8, "decimation": 5},
    )
    train(config, progress_bar=False)
    saved = yaml.safe_load((tmp_path / "f" / "config.yaml").read_text())
    assert saved["hyperparams_file"] is None
    assert saved["hyperparams"]["decimation"] == 5
    assert saved["hyperparams"]["gamma"] == resolve_hyperparams("sac", config.env_id)["gamma"]
    assert load_run(tmp_path / "f", trust_pickle=True).decimation == 5
    assert saved["action"] == ActionConfig(kind="motor-offset").to_dict()
    assert saved["observation"] == ObservationConfig().to_dict()


def test_a_run_saved_before_the_residual_deadzone_keeps_its_actions(tmp_path):
    """A run folder whose config has no ``residual_deadzone`` (written before the field
    existed) loads with none, not with today's default; a saved value is kept."""
    import yaml

    from elastic_gym.training.run_folder import RunFolder

    for name in ("model.zip", "vecnormalize.pkl"):
        (tmp_path / name).write_bytes(b"")
    residual = {"kind": "residual", "residual": "feedforward-state-feedback"}
    config = TrainConfig(algo="ppo", state="deluca", action=residual)
    (tmp_path / "config.yaml").write_text(yaml.safe_dump(config.to_dict()))
    old = RunFolder(tmp_path).read_config()
    assert old.policy_configs(old.settings()[0])[0].residual_deadzone == 0.0
    saved = config.model_copy(update={"action": {**residual, "residual_deadzone": 0.3}})
    (tmp_path / "config.yaml").write_text(yaml.safe_dump(saved.to_dict()))
    new = RunFolder(tmp_path).read_config()
    assert new.policy_configs(new.settings()[0])[0].residual_deadzone == 0.3
    assert ActionConfig(**residual).residual_deadzone == 0.2  # today's default


def tiny_config(out, **changes) -> TrainConfig:
    """A SAC run of a few policy steps on the true state (seconds)."""
    settings = {
        "algo": "sac",
        "state": "true",
        "total_steps": 30,
        "out_dir": str(out),
        "env_kwargs": SHORT_EPISODES,
        "eval_freq": 10**9,
        "hyperparams": {"learning_starts": 10, "batch_size": 8},
    }
    return TrainConfig(**{**settings, **changes})


def test_train_refuses_an_earlier_run_unless_overwrite_which_clears_it(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    stale = run / "best_model.zip"  # from a run whose config was different
    stale.write_bytes(b"stale")
    (run / "notes.txt").write_text("mine")
    with pytest.raises(FileExistsError, match=r"holds an earlier run \(best_model\.zip\)"):
        train(tiny_config(run), progress_bar=False)
    assert stale.read_bytes() == b"stale" and sorted(p.name for p in run.iterdir()) == [
        "best_model.zip",
        "notes.txt",
    ]
    train(tiny_config(run), progress_bar=False, overwrite=True)
    assert (run / "best_model.zip").read_bytes() != b"stale"  # this run's best model
    assert (run / "model.zip").exists() and (run / "notes.txt").read_text() == "mine"


def test_failed_training_removes_what_it_wrote(tmp_path, monkeypatch):
    from stable_baselines3 import SAC

    learn = SAC.learn

    def diverging(self, *args, **kwargs):
        learn(self, *args, **kwargs)  # writes tb/ and evaluations
        raise RuntimeError("loss is NaN")

    monkeypatch.setattr(SAC, "learn", diverging)
    run = tmp_path / "runs" / "bad"
    with pytest.raises(RuntimeError, match="loss is NaN"):
        train(tiny_config(run, eval_freq=10), progress_bar=False)
    assert sorted(tmp_path.iterdir()) == []  # nor the folders made for it
    with pytest.raises(ValueError, match="torque_limit"):
        train(tiny_config(run, env_kwargs={"torque_limit": -1.0}), progress_bar=False)
    assert not run.exists()


def test_runs_that_would_share_a_folder_are_refused(tmp_path, capsys):
    from elastic_gym.cli import main
    from elastic_gym.training import train_many

    with pytest.raises(ValueError, match=r"several runs would write to .* \(seeds \[0\]\)"):
        train_many([tiny_config(tmp_path / "a"), tiny_config(tmp_path / "a")], workers=1)
    with pytest.raises(SystemExit) as exit_info:
        main(["train", "--seeds", "0", "0", "--out", str(tmp_path / "b")])
    assert exit_info.value.code == 2
    assert "--seeds: duplicate seed(s) [0]" in capsys.readouterr().err
    assert sorted(tmp_path.iterdir()) == []


def test_bare_env_id_is_looked_up_in_the_package_namespace():
    assert TrainConfig(env_id="TwoLinkRigid-v0").env_id == "elastic_gym/TwoLinkRigid-v0"
    with pytest.raises(ValueError, match=r"unknown env id 'TwoLink-v0'; valid: \['elastic_gym/"):
        TrainConfig(env_id="TwoLink-v0")


def test_training_is_single_threaded_and_restores_the_thread_count(tmp_path, monkeypatch):
    """150 SAC steps took 95 s with 2 torch threads against 1.4 s with 1 on a loaded
    2-core machine: a single run pins torch and BLAS to one thread, like the workers."""
    from stable_baselines3 import SAC
    from threadpoolctl import threadpool_info

    seen = []
    learn = SAC.learn

    def spy(self, *args, **kwargs):
        blas = {pool["num_threads"] for pool in threadpool_info()}
        seen.append((torch.get_num_threads(), blas))
        return learn(self, *args, **kwargs)

    monkeypatch.setattr(SAC, "learn", spy)
    torch.set_num_threads(2)
    train(tiny_config(tmp_path / "run"), progress_bar=False)
    assert seen == [(1, {1})]
    assert torch.get_num_threads() == 2


def test_corrupted_run_folder_is_named(tmp_path):
    train(tiny_config(tmp_path / "run"), progress_bar=False)
    (tmp_path / "run" / "vecnormalize.pkl").write_bytes(b"garbage")
    with pytest.raises(ValueError, match=r"vecnormalize\.pkl cannot be loaded: UnpicklingError"):
        load_run(tmp_path / "run", trust_pickle=True)
    (tmp_path / "run" / "config.yaml").write_text("algo: ppo\nlearning_rate: 3\n")
    with pytest.raises(
        ValueError,
        match=r"config\.yaml is not a valid run configuration: "
        r"learning_rate: unexpected field",
    ):
        load_run(tmp_path / "run", trust_pickle=True)


@pytest.mark.slow
def test_training_on_batches_in_worker_processes(tmp_path):
    """n_envs arms split over ``batches`` worker processes (one PyBullet world each); the
    evaluation episodes run as arms of one batch; the run folder loads and acts."""
    config = TrainConfig(
        algo="ppo",
        state="deluca",
        total_steps=128,
        out_dir=str(tmp_path / "r"),
        env_kwargs={"episode_time": 0.1},
        eval_freq=64,
        eval_episodes=2,
        hyperparams={"n_envs": 4, "batches": 2, "n_steps": 16, "batch_size": 32, "n_epochs": 1},
    )
    result = train(config, progress_bar=False)
    assert result.policy_steps == 128
    run = load_run(config.out_dir, trust_pickle=True)
    assert run.settings.batches == 2
    assert np.load(Path(config.out_dir) / "evaluations.npz")["results"].shape[1] == 2
    with pytest.raises(ValueError, match="batches"):
        train(
            config.model_copy(
                update={
                    "out_dir": str(tmp_path / "bad"),
                    "hyperparams": {**config.hyperparams, "batches": 3},
                }
            ),
            progress_bar=False,
        )


@pytest.mark.slow
def test_batches_with_their_own_env_kwargs_train_on_two_plants():
    """``batches: [{}, {plant_scaling: ...}]``: the arms of the second worker batch are the
    single policy env on links 30 % heavier, those of the first the nominal one (arm i
    seeded s + i in both)."""
    from elastic_gym.training.run_envs import training_vec_env

    heavy = {"plant_scaling": {"link_mass": 1.3}}
    config = TrainConfig(
        state="true",
        env_kwargs={"episode_time": 0.05},
        hyperparams={"n_envs": 2, "batches": [{}, heavy]},
    )
    settings, _ = config.settings()
    venv = training_vec_env(config.policy_spec(settings), settings, 2, seed=4)
    venv.reset()
    actions = np.array([[0.2, -0.1], [0.2, -0.1]])
    for _ in range(3):
        obs, *_ = venv.step(actions)
    venv.close()
    for arm, kwargs in enumerate(({}, heavy)):
        expected = []
        for plant in ({}, heavy):
            env = policy_env(
                config.env_id,
                "true",
                {**config.training_env_kwargs(settings), **plant},
                decimation=10,
                action=config.policy_configs(settings)[0],
                observation=config.policy_configs(settings)[1],
            )
            env.reset(seed=4 + arm)
            for _ in range(3):
                single, *_ = env.step(actions[arm])
            env.close()
            expected.append(single)
        mine = expected[0] if kwargs == {} else expected[1]
        other = expected[1] if kwargs == {} else expected[0]
        assert np.array_equal(obs[arm], mine)
        assert not np.allclose(obs[arm], other, rtol=0, atol=1e-6)
    with pytest.raises(ValueError, match=r"batches\[0\]: Input should be a valid dictionary"):
        resolve_hyperparams("ppo", config.env_id, {"batches": [3]})


def test_env_kwargs_of_the_file_and_of_the_run():
    """The hyper-parameter file's ``env_kwargs`` apply unless the run sets the same key;
    a run that names its own task drops the file's task options (they belong to the
    file's task)."""
    settings = Settings(env_kwargs={"task_options": {"move_time": 0.8}, "episode_time": 2.0})
    own = TrainConfig(env_kwargs={"episode_time": 1.0})
    assert own.training_env_kwargs(settings) == {
        "task_options": {"move_time": 0.8},
        "episode_time": 1.0,
    }
    regulation = TrainConfig(env_kwargs={"task": "regulation"})
    assert regulation.training_env_kwargs(settings) == {"episode_time": 2.0, "task": "regulation"}
    with pytest.raises(ValueError, match="env_kwargs: Input should be a valid dictionary"):
        resolve_hyperparams("ppo", own.env_id, {"env_kwargs": "fast"})
