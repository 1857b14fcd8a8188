"""Gymnasium/SB3 API compliance, observation content, determinism, rendering."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from gymnasium.wrappers import FlattenObservation, RescaleAction
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import elastic_gym
from elastic_gym.envs import ElasticArmEnv, RigidArmEnv


def test_every_documented_id_is_registered():
    expected = {
        "TwoLinkElastic-v0",
        "KR15Elastic-v0",
        "IiwaElastic-v0",
        "TwoLinkRigid-v0",
        "TwoLinkRigidFriction-v0",
    }
    assert {i.split("/")[1] for i in elastic_gym.ENV_IDS} == expected
    for env_id in elastic_gym.ENV_IDS:
        assert env_id in gym.registry
        spec = gym.spec(env_id)
        assert spec.vector_entry_point is not None
        assert spec.max_episode_steps is None  # the env truncates itself after episode_time


@pytest.mark.parametrize("control_dt", [1e-3, 2e-3])
def test_episode_length_is_simulated_time_and_video_plays_in_real_time(control_dt):
    env = gym.make(
        "elastic_gym/TwoLinkRigid-v0", task="excitation", episode_time=0.5, control_dt=control_dt
    )
    env.reset(seed=0)
    assert env.metadata["render_fps"] * control_dt == pytest.approx(1.0)
    steps, truncated = 0, False
    while not truncated:
        _, _, terminated, truncated, info = env.step(np.zeros(2))
        assert not terminated
        steps += 1
    assert steps == round(0.5 / control_dt) and info["time"] == pytest.approx(0.5)
    env.close()


@pytest.mark.filterwarnings("ignore::UserWarning")
def test_gymnasium_check_env(env_id):
    env = gym.make(env_id)
    gym_check_env(env.unwrapped, skip_render_check=True)
    env.close()


@pytest.mark.filterwarnings("ignore::UserWarning")
def test_sb3_check_env_after_documented_wrappers(env_id):
    env = RescaleAction(FlattenObservation(gym.make(env_id)), -1.0, 1.0)
    sb3_check_env(env, warn=False)
    env.close()


def test_observation_has_only_sensor_data(env_id):
    env = gym.make(env_id)
    obs, info = env.reset(seed=0)
    n = env.unwrapped.n_joints
    if "Elastic" in env_id:
        assert set(obs) == {"motor_position", "acceleration", "reference"}
        assert obs["acceleration"].shape == (3 * env.unwrapped.model.n_sensors,)
    else:
        assert set(obs) == {"link_position", "reference"}
    assert obs["reference"].shape == (2 * n,)
    truth = info["true_state"]
    assert set(truth) == {"q", "dq", "theta", "dtheta", "ddq", "x"}
    assert set(info["reference"]) == {"q", "dq", "ddq", "d3q", "d4q"}
    if "Elastic" in env_id:
        # Encoders see the motors: the motor position differs from the link position by the
        # static deflection K^-1 g(q), which the link position must not leak through.
        assert not np.allclose(obs["motor_position"], truth["q"], atol=1e-9)
    env.close()


def test_metadata_and_timing(env_id):
    env = gym.make(env_id)
    meta = env.unwrapped.metadata
    assert meta["control_dt"] == pytest.approx(1e-3)
    assert meta["physics_dt"] <= 1e-3
    assert env.unwrapped.n_substeps * meta["physics_dt"] == pytest.approx(meta["control_dt"])
    env.close()


def _rollout(env_id: str, seed: int, steps: int = 150) -> list:
    env = gym.make(env_id)
    obs, info = env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    record = [obs, info["true_state"]["x"]]
    limit = env.unwrapped.torque_limit
    for _ in range(steps):
        obs, reward, *_, info = env.step(0.02 * limit * rng.uniform(-1, 1, size=limit.shape))
        record += [obs, reward, info["true_state"]["x"]]
    env.close()
    return record


def _flatten(record: list) -> np.ndarray:
    parts = []
    for item in record:
        if isinstance(item, dict):
            parts += [np.ravel(item[k]) for k in sorted(item)]
        else:
            parts.append(np.ravel(item))
    return np.concatenate(parts)


def test_same_seed_same_episode_bit_for_bit(env_id):
    a, b = _flatten(_rollout(env_id, 7)), _flatten(_rollout(env_id, 7))
    assert np.array_equal(a, b)
    c = _flatten(_rollout(env_id, 8))
    assert not np.array_equal(a, c)


def test_rgb_array_render(env_id):
    env = gym.make(env_id, render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (360, 480, 3) and frame.dtype == np.uint8
    assert frame.std() > 1.0  # the arm is visible, not a blank image
    env.close()


def test_human_render_without_display_is_a_clear_error(monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    with pytest.raises(RuntimeError, match="display"):
        gym.make("elastic_gym/TwoLinkElastic-v0", render_mode="human")


def test_env_classes_reject_the_wrong_robot_kind():
    with pytest.raises(ValueError, match="rigid"):
        ElasticArmEnv("two_link_rigid")
    with pytest.raises(ValueError, match="elastic"):
        RigidArmEnv("two_link_elastic")


def test_tracking_reference_is_c4_rest_to_rest():
    env = gym.make("elastic_gym/TwoLinkElastic-v0", task_options={"move_time": 0.8})
    env.reset(seed=3)
    task = env.unwrapped.task
    times = np.linspace(0.0, task.duration, 4001)
    ref = task.reference(times, np.zeros(len(times), dtype=int))  # (T, 5, N)
    path = task.path(0)
    assert np.array_equal(ref[1234], path.evaluate(times[1234]))
    # derivatives are consistent: integrate each derivative and compare with the one below
    dt = times[1] - times[0]
    for k in range(4):
        integral = ref[0, k] + np.cumsum(0.5 * (ref[1:, k + 1] + ref[:-1, k + 1]), axis=0) * dt
        assert np.allclose(integral, ref[1:, k], atol=1e-4 * max(1.0, np.abs(ref[:, k]).max()))
    # at rest at the start, at the end, and between moves
    assert np.allclose(ref[0, 1:], 0.0) and np.allclose(ref[-1, 1:], 0.0)
    # the compiled kernel reads one time per arm: other lengths are refused, not read past
    with pytest.raises(ValueError, match="one time per arm"):
        task.reference(times)
    env.close()


def test_regulation_and_excitation_tasks():
    env = gym.make(
        "elastic_gym/TwoLinkElastic-v0",
        task="regulation",
        task_options={"goal": [0.1, 0.2], "start": [0.0, 0.0]},
    )
    obs, info = env.reset(seed=0)
    assert np.allclose(info["reference"]["q"], [0.1, 0.2])
    assert np.allclose(info["true_state"]["q"], [0.0, 0.0])
    env.close()
    env = gym.make(
        "elastic_gym/TwoLinkRigid-v0",
        task="excitation",
        task_options={"amplitude": [1.0, -1.0], "frequency": [0.5, 1.0]},
    )
    obs, info = env.reset(seed=0)
    _, _, _, _, info = env.step(np.zeros(2))
    model = env.unwrapped.model
    q_before = env.unwrapped.task.reference(np.zeros(1))[0, 0]
    expected = model.gravity(q_before) + np.array([1.0, -1.0])
    assert np.allclose(info["torque"], expected, atol=1e-9)
    env.close()


def test_pickled_env_continues_bit_for_bit(env_id):
    import copy
    import pickle

    env = gym.make(env_id, accelerometer={"cutoff_hz": 50.0}, sensor_delay=2)
    env.reset(seed=3)
    rng = np.random.default_rng(0)
    limit = env.unwrapped.torque_limit
    for _ in range(20):
        env.step(0.02 * limit * rng.uniform(-1, 1, limit.shape))
    clones = [pickle.loads(pickle.dumps(env)), copy.deepcopy(env)]
    assert all(c.unwrapped.sim.client != env.unwrapped.sim.client for c in clones)
    for _ in range(30):
        action = 0.02 * limit * rng.uniform(-1, 1, limit.shape)
        expected = _flatten(list(env.step(action)[:2]))
        for clone in clones:
            assert np.array_equal(_flatten(list(clone.step(action)[:2])), expected)
    for clone in clones:
        clone.close()
    env.close()
