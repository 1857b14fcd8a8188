"""The single-env wrappers are the N = 1 case of the vector ones: the single env's info
comes back as a single env gives it, an ended episode needs a reset, and a user's
subclass of a batched observer runs its own single-arm code in both."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from helpers import policy_env

from elastic_gym.arms import as_batch, single_arm
from elastic_gym.observers import ObserverWrapper, TrueStateWrapper, vector
from elastic_gym.observers.finite_difference import FiniteDifferenceObserver
from elastic_gym.single_env import SingleArmWrapper

ID = "elastic_gym/TwoLinkRigid-v0"


def test_as_batch_and_single_arm_are_inverse_on_a_steps_info():
    env = gym.make("elastic_gym/TwoLinkElastic-v0")
    _, info = env.reset(seed=0)
    _, _, _, _, info = env.step(np.array([0.5, -0.5]))
    info["termination_reason"] = "non-finite state"
    back = single_arm(as_batch(info))
    assert back.keys() == info.keys()
    for key, value in info.items():
        if isinstance(value, dict):
            for name, array in value.items():
                np.testing.assert_array_equal(back[key][name], array)
        elif isinstance(value, np.ndarray):
            np.testing.assert_array_equal(back[key], value)
        else:  # Python scalars stay Python scalars
            assert back[key] == value and type(back[key]) is type(value)
    reasons = as_batch(info)["termination_reason"]
    reasons[0] = "non-finite state estimate"  # an object array: no truncation
    assert single_arm({"r": reasons})["r"] == "non-finite state estimate"
    env.close()


def test_the_wrapped_envs_info_items_come_back_unchanged():
    raw = gym.make(ID)
    env = TrueStateWrapper(gym.make(ID))
    _, reference_info = raw.reset(seed=3)
    _, info = env.reset(seed=3)
    for _ in range(3):
        _, r_raw, _, _, reference_info = raw.step(np.array([0.2, 0.1]))
        _, r, terminated, truncated, info = env.step(np.array([0.2, 0.1]))
        assert type(r) is float and r == r_raw
        assert type(terminated) is bool and type(truncated) is bool
    for key, value in reference_info.items():
        assert type(info[key]) is type(value)
    assert type(info["time"]) is float and info["termination_reason"] is None
    assert not any(key.startswith("_") for key in info)
    np.testing.assert_array_equal(
        info["estimate"], np.concatenate([info["true_state"]["q"], info["true_state"]["dq"]])
    )
    raw.close()
    env.close()


def test_an_ended_episode_needs_a_reset_at_every_level_of_a_stack():
    env = policy_env(ID, "true", {"episode_time": 0.005}, decimation=2)
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(2))
    env.reset(seed=0)
    done = False
    while not done:
        *_, terminated, truncated, _ = env.step(np.zeros(2))
        done = terminated or truncated
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(2))
    env.reset()
    env.step(np.zeros(2))
    env.close()


class _Counting(FiniteDifferenceObserver):
    """A batched observer whose subclass overrides the single-arm update."""

    name = "counting"

    def update(self, obs, torque, dt):
        self.updates = getattr(self, "updates", 0) + 1
        return super().update(obs, torque, dt)


def test_a_subclass_overriding_the_single_arm_update_runs_it_on_one_arm_and_on_n():
    env = ObserverWrapper(gym.make(ID), _Counting(gym.make(ID).unwrapped.model, 1e-3))
    envs = vector.ObserverWrapper(
        gym.make_vec(ID, num_envs=2, vectorization_mode="vector_entry_point"),
        _Counting(env.unwrapped.model, 1e-3),
    )
    assert not vector.runs_batched(env.observer)
    assert vector.runs_batched(FiniteDifferenceObserver(env.unwrapped.model, 1e-3))
    env.reset(seed=0)
    envs.reset(seed=0)
    for _ in range(4):
        obs, *_ = env.step(np.zeros(2))
        batch_obs, *_ = envs.step(np.zeros((2, 2)))
    assert env.observer.updates == 4
    assert [o.updates for o in envs.observer.observers] == [4, 4]
    np.testing.assert_array_equal(obs["state"], batch_obs["state"][0])
    env.close()
    envs.close()


def test_a_single_wrapper_needs_an_elastic_gym_env():
    with pytest.raises(TypeError, match="needs an elastic_gym env"):
        SingleArmWrapper(gym.make("CartPole-v1"), lambda arm: arm)
