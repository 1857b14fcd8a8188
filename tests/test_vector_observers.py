"""Vector observer wrappers: each arm's estimate is the single-env observer's bit for bit, across
autoresets, for the batched observers and for the per-arm fallback."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode
from helpers import fast_lane

from elastic_gym.observers import Observer, ObserverWrapper, vector
from elastic_gym.observers.base import BatchedObserver

N_ARMS = 3
CASES = [
    ("elastic_gym/TwoLinkElastic-v0", "deluca", {}),
    ("elastic_gym/KR15Elastic-v0", "deluca", {"bandwidth": 200.0}),
    ("elastic_gym/IiwaElastic-v0", "deluca-ideal", {}),
    ("elastic_gym/TwoLinkElastic-v0", "finite-difference", {}),
    ("elastic_gym/TwoLinkElastic-v0", "ekf", {}),
    ("elastic_gym/KR15Elastic-v0", "ekf", {"use_accelerometers": True}),
    ("elastic_gym/TwoLinkRigid-v0", "solsona-puleston", {}),  # per-arm fallback
    ("elastic_gym/TwoLinkRigid-v0", "reduced-order", {}),
    ("elastic_gym/TwoLinkRigid-v0", "true", {}),
]


def _relative(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.abs(a - b).max() / max(1.0, np.abs(b).max()))


@pytest.mark.parametrize(
    ("env_id", "name", "options"),
    fast_lane(CASES, CASES[1], CASES[5], CASES[7]),  # model (2) on both, a rigid arm
)
def test_each_arm_estimate_equals_the_single_observer(env_id, name, options):
    kwargs = {"episode_time": 0.04}
    envs = vector.ObserverWrapper(
        gym.make_vec(env_id, num_envs=N_ARMS, vectorization_mode="vector_entry_point", **kwargs),
        name,
        **options,
    )
    singles = [ObserverWrapper(gym.make(env_id, **kwargs), name, **options) for _ in range(N_ARMS)]
    batched = name in ("deluca", "deluca-ideal", "finite-difference", "true", "ekf")
    assert isinstance(envs.observer, BatchedObserver) == batched
    obs, info = envs.reset(seed=5)
    worst = max(
        _relative(obs["state"][i], env.reset(seed=5 + i)[0]["state"])
        for i, env in enumerate(singles)
    )
    limit = envs.unwrapped.torque_limit
    rng = np.random.default_rng(2)
    ended = np.zeros(N_ARMS, dtype=bool)
    for _ in range(90):  # two autoresets
        actions = 0.05 * limit * rng.uniform(-1, 1, (N_ARMS, len(limit)))
        obs, _, terminated, truncated, info = envs.step(actions)
        for i, env in enumerate(singles):
            single = env.reset()[0] if ended[i] else env.step(actions[i])[0]
            worst = max(worst, _relative(obs["state"][i], single["state"]))
        assert np.array_equal(
            info["estimation_error"], info["estimate"] - info["true_state_vector"]
        )
        ended = terminated | truncated
    assert worst == 0.0  # bit for bit: a stiff closed loop amplifies any difference
    assert envs.observation_space["state"].shape == (N_ARMS, envs.observer.state_dim)
    envs.close()
    for env in singles:
        env.close()


def test_vector_deluca_diagnostics_per_arm():
    envs = vector.ObserverWrapper(
        gym.make_vec(
            "elastic_gym/KR15Elastic-v0", num_envs=2, vectorization_mode="vector_entry_point"
        ),
        "deluca",
    )
    _, info = envs.reset(seed=0)
    _, _, _, _, info = envs.step(np.zeros((2, 3)))
    diagnostics = info["observer_diagnostics"]
    assert diagnostics["cond_TA"].shape == (2,) and np.all(diagnostics["cond_TA"] >= 1.0)
    assert diagnostics["near_singular"].dtype == bool
    envs.close()


class _Diverging(Observer):
    """Diverges on arm 1 only (its first encoder reading is negative in this test)."""

    name = "diverging"
    applies_to = frozenset({"rigid"})

    def reset(self, obs, initial_estimate=None):
        self._sign = np.sign(obs["link_position"][0])
        return np.zeros(4)

    def update(self, obs, torque, dt):
        return np.full(4, np.nan if self._sign < 0 else 0.0)


def test_a_diverged_arm_ends_its_episode_and_restarts():
    start = {"initial_state": {"q": [0.1, 0.0]}}
    envs = gym.make_vec(
        "elastic_gym/TwoLinkRigid-v0",
        num_envs=2,
        vectorization_mode="vector_entry_point",
        task="excitation",
    )
    wrapped = vector.ObserverWrapper(envs, _Diverging(envs.unwrapped.model, 1e-3))
    wrapped.reset(seed=0, options=start)
    wrapped.observer.observers[1]._sign = -1.0
    _, reward, terminated, _, info = wrapped.step(np.zeros((2, 2)))
    assert terminated.tolist() == [False, True]
    assert info["termination_reason"][1] == "non-finite state estimate"
    assert info["_termination_reason"].tolist() == [False, True]
    _, reward, terminated, _, info = wrapped.step(np.zeros((2, 2)))  # NEXT_STEP: arm 1 resets
    assert reward[1] == 0.0 and info["time"][1] == 0.0 and info["time"][0] > 0.0
    wrapped.close()


def test_same_step_final_observation_is_an_estimate():
    envs = vector.TrueStateWrapper(
        gym.make_vec(
            "elastic_gym/TwoLinkRigid-v0",
            num_envs=2,
            vectorization_mode="vector_entry_point",
            autoreset_mode=AutoresetMode.SAME_STEP,
            task="excitation",
            episode_time=0.003,
        )
    )
    envs.reset(seed=0)
    for _ in range(2):
        envs.step(np.zeros((2, 2)))
    obs, _, _, truncated, info = envs.step(np.zeros((2, 2)))
    assert truncated.all()
    final = info["final_obs"][0]
    truth = info["final_info"]["true_state"]
    assert np.array_equal(final["state"], np.concatenate([truth["q"][0], truth["dq"][0]]))
    assert np.array_equal(
        obs["state"][0], np.concatenate([info["true_state"]["q"][0], info["true_state"]["dq"][0]])
    )
    envs.close()


def test_vector_wrapper_refuses_what_it_cannot_serve():
    single = gym.make("elastic_gym/TwoLinkElastic-v0")
    with pytest.raises(TypeError, match="vector_entry_point"):
        vector.ObserverWrapper(
            gym.make_vec("elastic_gym/TwoLinkElastic-v0", num_envs=2, vectorization_mode="sync"),
            "deluca",
        )
    with pytest.raises(ValueError, match="applies to"):
        vector.ObserverWrapper(
            gym.make_vec(
                "elastic_gym/TwoLinkRigid-v0", num_envs=2, vectorization_mode="vector_entry_point"
            ),
            "deluca",
        )
    single.close()
