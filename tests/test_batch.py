"""Batched arms: the vector env of every id is its single env, arm by arm, bit for bit.

Arm i of ``gym.make_vec(id, N, vectorization_mode="vector_entry_point")`` reset with
seed s must equal ``gym.make(id)`` reset with seed s + i under the same actions:
observations, rewards, terminations, truncations and the truth in info, across
autoresets (truncation and termination) and with every kind of env kwarg.
"""

from __future__ import annotations

import pickle

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode
from helpers import arm_row, fast_lane, flat, step_in_lockstep

import elastic_gym

N_ARMS = 3
# kwargs that exercise every batched part: filter + noise + bias, delay line, scaling,
# encoder noise, a coarser control period, short episodes (autoresets)
KWARGS = {
    "elastic_gym/TwoLinkElastic-v0": {
        "accelerometer": {"cutoff_hz": 80.0},
        "sensor_delay": 2,
        "plant_scaling": {"link_mass": 1.2, "stiffness": 0.9},
    },
    "elastic_gym/KR15Elastic-v0": {"encoder": {"noise_std": 1e-4}, "task": "regulation"},
    "elastic_gym/IiwaElastic-v0": {"control_dt": 2e-3, "sensor_delay": 1},
    "elastic_gym/TwoLinkRigid-v0": {"task": "excitation"},
    "elastic_gym/TwoLinkRigidFriction-v0": {"plant_scaling": {"friction": 1.5}},
}


def _actions(limit: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    actions = 0.05 * limit * rng.uniform(-1, 1, (N_ARMS, len(limit)))
    actions[2] = 1.5 * limit  # saturated: arm 2 hits the velocity limit (a termination)
    return actions


@pytest.mark.parametrize("env_id", fast_lane(elastic_gym.ENV_IDS, "elastic_gym/KR15Elastic-v0"))
def test_each_arm_equals_the_single_env_bit_for_bit(env_id):
    kwargs = {**KWARGS[env_id], "episode_time": 0.06, "max_velocity": 2.0}
    envs = gym.make_vec(env_id, num_envs=N_ARMS, vectorization_mode="vector_entry_point", **kwargs)
    assert isinstance(envs.unwrapped, gym.vector.VectorEnv)
    singles = [gym.make(env_id, **kwargs) for _ in range(N_ARMS)]
    obs, info = envs.reset(seed=11)
    for i, env in enumerate(singles):
        single_obs, single_info = env.reset(seed=11 + i)
        assert np.array_equal(flat(arm_row(obs, i)), flat(single_obs))
        assert np.array_equal(flat(arm_row(info, i)), flat(single_info))
    rng = np.random.default_rng(0)
    limit = envs.unwrapped.torque_limit
    reasons = step_in_lockstep(envs, singles, lambda: _actions(limit, rng), 150)
    assert reasons == {"velocity limit exceeded"}  # terminations were exercised, and truncations:
    assert envs.unwrapped.batch.steps.max() < 150
    envs.close()
    for env in singles:
        env.close()


def test_same_step_autoreset_and_masks():
    kwargs = {"task": "excitation", "episode_time": 0.01}
    envs = gym.make_vec(
        "elastic_gym/TwoLinkRigid-v0",
        num_envs=2,
        vectorization_mode="vector_entry_point",
        autoreset_mode=AutoresetMode.SAME_STEP,
        **kwargs,
    )
    assert envs.metadata["autoreset_mode"] is AutoresetMode.SAME_STEP
    single = gym.make("elastic_gym/TwoLinkRigid-v0", **kwargs)
    envs.reset(seed=[5, 9])
    single.reset(seed=9)
    for _ in range(9):
        envs.step(np.zeros((2, 2)))
        single.step(np.zeros(2))
    obs, reward, terminated, truncated, info = envs.step(np.zeros((2, 2)))
    final_obs, *_ = single.step(np.zeros(2))
    assert truncated.all() and not terminated.any()
    assert info["_final_obs"].all() and np.array_equal(
        info["final_obs"][1]["link_position"], final_obs["link_position"]
    )
    assert info["final_info"]["time"][1] == pytest.approx(0.01)
    reset_obs, _ = single.reset()  # the arm was reset in the same step
    assert np.array_equal(obs["link_position"][1], reset_obs["link_position"])
    assert info["time"][1] == 0.0 and info["_true_state"].all()
    envs.close()
    single.close()


def test_disabled_autoreset_needs_a_masked_reset():
    envs = gym.make_vec(
        "elastic_gym/TwoLinkRigid-v0",
        num_envs=2,
        vectorization_mode="vector_entry_point",
        autoreset_mode="Disabled",
        task="excitation",
        episode_time=0.002,
    )
    envs.reset(seed=0)
    envs.step(np.zeros((2, 2)))
    _, _, _, truncated, _ = envs.step(np.zeros((2, 2)))
    assert truncated.all()
    with pytest.raises(RuntimeError, match="reset_mask"):
        envs.step(np.zeros((2, 2)))
    _, info = envs.reset(options={"reset_mask": np.array([True, False])})
    assert info["_time"].tolist() == [True, False]
    with pytest.raises(RuntimeError, match="reset_mask"):  # arm 1 still has to be reset
        envs.step(np.zeros((2, 2)))
    envs.close()


def test_vector_env_bad_input_changes_nothing_and_closed_env_refuses():
    envs = gym.make_vec(
        "elastic_gym/TwoLinkElastic-v0", num_envs=2, vectorization_mode="vector_entry_point"
    )
    envs.reset(seed=0)
    batch = envs.unwrapped.batch
    before = batch.sim.state.copy()
    for bad, error in (
        ([[np.nan, 0.0], [0.0, 0.0]], ValueError),
        (np.zeros(2), ValueError),
        (np.zeros((2, 2), dtype=complex), TypeError),
    ):
        with pytest.raises(error):
            envs.step(bad)
    assert np.array_equal(batch.sim.state, before)
    with pytest.raises(TypeError, match="unexpected keyword argument 'stifness'"):
        gym.make_vec(
            "elastic_gym/TwoLinkElastic-v0",
            num_envs=2,
            vectorization_mode="vector_entry_point",
            stifness=1.0,
        )
    with pytest.raises(ValueError, match="seeds"):
        envs.reset(seed=[1, 2, 3])
    envs.close()
    with pytest.raises(RuntimeError, match="closed"):
        envs.step(np.zeros((2, 2)))


def test_pickled_vector_env_continues_bit_for_bit():
    envs = gym.make_vec(
        "elastic_gym/KR15Elastic-v0",
        num_envs=2,
        vectorization_mode="vector_entry_point",
        sensor_delay=1,
    )
    envs.reset(seed=4)
    rng = np.random.default_rng(1)
    limit = envs.unwrapped.torque_limit
    for _ in range(5):
        envs.step(0.05 * limit * rng.uniform(-1, 1, (2, 3)))
    clone = pickle.loads(pickle.dumps(envs))
    assert clone.unwrapped.batch.sim.client != envs.unwrapped.batch.sim.client
    for _ in range(10):
        action = 0.05 * limit * rng.uniform(-1, 1, (2, 3))
        expected = envs.step(action)
        got = clone.step(action)
        assert np.array_equal(flat(expected[0]), flat(got[0]))
        assert np.array_equal(expected[1], got[1])
    clone.close()
    envs.close()


def test_arms_of_a_large_batch_equal_single_envs():
    """64 arms: numpy may pick other loops for longer arrays; each arm must not notice."""
    env_id, kwargs = "elastic_gym/KR15Elastic-v0", {"sensor_delay": 1}
    envs = gym.make_vec(env_id, num_envs=64, vectorization_mode="vector_entry_point", **kwargs)
    envs.reset(seed=100)
    arms = (0, 37, 63)
    singles = {i: gym.make(env_id, **kwargs) for i in arms}
    for i, env in singles.items():
        env.reset(seed=100 + i)
    rng = np.random.default_rng(5)
    limit = envs.unwrapped.torque_limit
    for _ in range(40):
        actions = 0.1 * limit * rng.uniform(-1, 1, (64, 3))
        obs, reward, *_, info = envs.step(actions)
        for i, env in singles.items():
            single_obs, single_reward, *_, single_info = env.step(actions[i])
            assert np.array_equal(flat(arm_row(obs, i)), flat(single_obs))
            assert reward[i] == single_reward
            assert np.array_equal(flat(arm_row(info, i)), flat(single_info))
    envs.close()
    for env in singles.values():
        env.close()


def test_vector_env_renders_one_image_per_arm():
    envs = gym.make_vec(
        "elastic_gym/TwoLinkElastic-v0",
        num_envs=2,
        vectorization_mode="vector_entry_point",
        render_mode="rgb_array",
    )
    envs.reset(seed=0)
    frames = envs.render()
    assert len(frames) == 2 and all(f.shape == (360, 480, 3) for f in frames)
    assert all(f.std() > 1.0 for f in frames)  # each camera looks at its own arm
    assert not np.array_equal(frames[0], frames[1])  # different random configurations
    envs.close()
