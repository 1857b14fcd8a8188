"""Bad input gets a clear exception naming the problem and changes nothing."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from elastic_gym.envs.reward import RewardConfig
from elastic_gym.observers import ObserverWrapper


def _snapshot(env) -> tuple:
    u = env.unwrapped
    return (u.sim.state.copy(), u.time, u.np_random.bit_generator.state["state"]["state"])


@pytest.fixture
def env():
    env = gym.make("elastic_gym/TwoLinkElastic-v0")
    env.reset(seed=0)
    yield env
    env.close()


@pytest.mark.parametrize(
    ("action", "error", "match"),
    [
        ([np.nan, 0.0], ValueError, "finite"),
        ([np.inf, 0.0], ValueError, "finite"),
        ([0.0, 0.0, 0.0], ValueError, "shape"),
        ([[0.0, 0.0]], ValueError, "shape"),
        (["a", "b"], TypeError, "dtype"),
        (np.array([1 + 1j, 0]), TypeError, "dtype"),
    ],
)
def test_bad_actions_raise_and_leave_the_state_unchanged(env, action, error, match):
    before = _snapshot(env)
    with pytest.raises(error, match=match):
        env.step(action)
    after = _snapshot(env)
    assert np.array_equal(before[0], after[0]) and before[1:] == after[1:]
    env.step(np.zeros(2))  # still usable


def test_out_of_limit_torque_is_clipped_and_flagged(env):
    limit = env.unwrapped.torque_limit
    *_, info = env.step(10 * limit)
    assert info["torque_saturated"] is True
    assert np.allclose(info["torque"], limit)
    *_, info = env.step(0.1 * limit)
    assert info["torque_saturated"] is False


def test_step_before_reset():
    env = gym.make("elastic_gym/TwoLinkElastic-v0", disable_env_checker=True)
    with pytest.raises(RuntimeError, match="reset"):
        env.unwrapped.step(np.zeros(2))


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"not_a_kwarg": 1}, TypeError, "not_a_kwarg"),
        ({"task": "juggling"}, ValueError, "juggling"),
        ({"task_options": {"speed": 2}}, ValueError, "speed"),
        ({"accelerometer": {"noise": 1.0}}, ValueError, "noise"),
        ({"accelerometer": {"range": -1.0}}, ValueError, "range"),
        ({"encoder": {"resolution": -1.0}}, ValueError, "resolution"),
        ({"accelerometers": [{"link": "link9", "position": [0, 0, 0]}]}, ValueError, "link9"),
        ({"accelerometers": [{"link": "link2", "position": [0, 0]}]}, ValueError, "position"),
        ({"accelerometers": [{"link": "link2"}]}, ValueError, "position"),
        ({"plant_scaling": {"mass": 1.1}}, ValueError, "mass"),
        ({"plant_scaling": {"link_mass": -1.0}}, ValueError, "link_mass"),
        ({"unmodelled_friction": {"coulomb": -0.1}}, ValueError, "unmodelled_friction.coulomb"),
        ({"unmodelled_friction": {"coulomb": 1.0}}, ValueError, "below 1"),
        (
            {"unmodelled_friction": {"stiction": 0.1}},
            ValueError,
            r"unmodelled_friction\.stiction: unexpected field; valid: \['coulomb', 'viscous'\]",
        ),
        (
            {"unmodelled_friction": {"viscous": [0.1, 0.2, 0.3]}},
            ValueError,
            "unmodelled_friction.viscous",
        ),
        ({"physics_dt": 2e-3}, ValueError, "physics_dt"),
        ({"control_dt": 7.5e-4}, ValueError, "control_dt"),
        ({"torque_limit": [1.0]}, ValueError, "torque_limit"),
        ({"reward": {"speed": 1.0}}, ValueError, "speed"),
        ({"reward": {"sigmas": [1e-3, -1.0]}}, ValueError, "sigmas"),
        pytest.param(  # gymnasium's make warns of the unknown mode before the env refuses it
            {"render_mode": "ascii"},
            ValueError,
            "render_mode",
            marks=pytest.mark.filterwarnings("ignore:.*render_mode='ascii':UserWarning"),
        ),
        ({"reward": {"termination": float("nan")}}, ValueError, "termination"),
    ],
)
def test_bad_env_kwargs(kwargs, error, match):
    with pytest.raises(error, match=match):
        gym.make("elastic_gym/TwoLinkElastic-v0", **kwargs)


def test_bad_reset_options(env):
    with pytest.raises(ValueError, match="warp"):
        env.reset(options={"warp": 1})
    with pytest.raises(ValueError, match="initial_state"):
        env.reset(options={"initial_state": {"q": [0.0]}})
    with pytest.raises(ValueError, match="omega"):
        env.reset(options={"initial_state": {"omega": [0.0, 0.0]}})


def test_unknown_observer_lists_the_valid_ones(env):
    with pytest.raises(ValueError, match="deluca"):
        ObserverWrapper(env, "kalman-bucy")


def test_non_finite_physics_terminates_with_a_reason():
    env = gym.make("elastic_gym/TwoLinkRigid-v0", max_velocity=1e300)
    first, first_info = env.reset(
        seed=0, options={"initial_state": {"q": [0.0, 0.0], "dq": [1e300, 1e300]}}
    )
    obs, reward, terminated, _, info = env.step(np.zeros(2))
    assert terminated and info["termination_reason"] == "non-finite state"
    assert reward == RewardConfig().termination_reward < 0  # every other step pays >= 0
    # the last finite observation, the same info keys as every step (the truth is not finite)
    assert all(np.array_equal(obs[k], first[k]) for k in obs)
    assert set(info) == set(first_info) and set(info["true_state"]) == set(first_info["true_state"])
    assert not np.all(np.isfinite(info["true_state"]["x"]))
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(2))
    env.close()


def test_runaway_velocity_terminates_with_a_reason():
    env = gym.make("elastic_gym/TwoLinkRigid-v0", max_velocity=5.0)
    env.reset(seed=0)
    for _ in range(2000):
        *_, terminated, _, info = env.step(env.unwrapped.torque_limit)
        if terminated:
            break
    assert terminated and info["termination_reason"] == "velocity limit exceeded"
    env.close()
