"""The SB3 VecEnv adapter of the batched arms: SB3's episode-end contract, exactly."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode
from gymnasium.wrappers.vector import FlattenObservation, RescaleAction
from stable_baselines3 import PPO
from stable_baselines3.common.vec_env import VecNormalize

from elastic_gym.observers import TrueStateWrapper, vector
from elastic_gym.policy.vector import ActionRepeat
from elastic_gym.training.sb3_vec_env import SB3VecEnv

ID = "elastic_gym/TwoLinkRigid-v0"
KWARGS = {"task": "excitation", "episode_time": 0.02}


STATE = slice(4, 8)  # FlattenObservation puts "reference" (4) before "state" (4)


def _vector(n: int, **kwargs):
    envs = gym.make_vec(
        ID,
        num_envs=n,
        vectorization_mode="vector_entry_point",
        autoreset_mode=AutoresetMode.DISABLED,
        **{**KWARGS, **kwargs},
    )
    return FlattenObservation(vector.TrueStateWrapper(envs))


def test_episode_ends_follow_sb3_and_match_single_envs():
    venv = SB3VecEnv(_vector(2), info_keys=("time",))
    venv.seed(3)
    obs = venv.reset()
    singles = [TrueStateWrapper(gym.make(ID, **KWARGS)) for _ in range(2)]
    first = [env.reset(seed=3 + i)[0] for i, env in enumerate(singles)]
    assert np.array_equal(obs[1, STATE], first[1]["state"])
    actions = np.array([[1.0, -1.0], [0.5, 0.5]])
    for step in range(25):
        venv.step_async(actions)
        obs, reward, dones, infos = venv.step_wait()
        expected = [env.step(actions[i]) for i, env in enumerate(singles)]
        for i, (single_obs, single_reward, terminated, truncated, _) in enumerate(expected):
            assert reward[i] == pytest.approx(single_reward, rel=1e-6)  # float32
            assert dones[i] == (terminated or truncated)
            if dones[i]:
                assert np.array_equal(infos[i]["terminal_observation"][STATE], single_obs["state"])
                assert infos[i]["TimeLimit.truncated"] is True
                restart = singles[i].reset()[0]
                assert np.array_equal(obs[i, STATE], restart["state"])  # the next episode
                assert infos[i]["time"] == pytest.approx(0.02)
            else:
                assert np.array_equal(obs[i, STATE], single_obs["state"])
        assert dones.all() == (step % 20 == 19)
    venv.close()


def test_refuses_autoreset_modes_sb3_cannot_follow():
    envs = gym.make_vec(ID, num_envs=2, vectorization_mode="vector_entry_point")
    with pytest.raises(ValueError, match="DISABLED"):
        SB3VecEnv(envs)
    envs.close()


@pytest.mark.slow
def test_ppo_trains_on_batched_arms_with_decimation(tmp_path, monkeypatch):
    monkeypatch.setenv("SB3_LOGDIR", str(tmp_path))  # SB3's logger folder, else one in /tmp
    envs = RescaleAction(ActionRepeat(_vector(4, episode_time=0.2), 5), -1.0, 1.0)
    venv = VecNormalize(SB3VecEnv(envs))
    model = PPO("MlpPolicy", venv, n_steps=32, batch_size=64, n_epochs=1, seed=0, device="cpu")
    model.learn(256)
    assert model.num_timesteps == 256
    venv.close()


def _batch_factory(n: int):
    return SB3VecEnv(_vector(n))


@pytest.mark.slow
def test_batches_in_worker_processes_equal_the_batches_in_this_process():
    import functools

    from elastic_gym.training.sb3_vec_env import ProcessBatches

    workers = ProcessBatches(
        [functools.partial(_batch_factory, 2), functools.partial(_batch_factory, 1)]
    )
    local = [_batch_factory(2), _batch_factory(1)]
    assert workers.num_envs == 3
    workers.seed(7)
    obs = workers.reset()
    for k, venv in enumerate(local):
        venv.seed(7 + 2 * k)
    expected = np.concatenate([venv.reset() for venv in local])
    assert np.array_equal(obs, expected)
    actions = np.tile([[0.5, -0.5]], (3, 1))
    for _ in range(25):
        workers.step_async(actions)
        obs, rewards, dones, infos = workers.step_wait()
        parts = []
        for venv, rows in zip(local, (slice(0, 2), slice(2, 3)), strict=True):
            venv.step_async(actions[rows])
            parts.append(venv.step_wait())
        assert np.array_equal(obs, np.concatenate([part[0] for part in parts]))
        assert np.array_equal(dones, np.concatenate([part[2] for part in parts]))
    assert "terminal_observation" in infos[2] or not dones[2]
    workers.close()
    for venv in local:
        venv.close()
