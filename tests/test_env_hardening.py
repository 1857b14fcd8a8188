"""Cases found by fault injection on the envs and observer wrappers: each gives a clear error
or the documented behaviour, and nothing is lost or silently wrong."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.wrappers import FlattenObservation

from elastic_gym.model import RobotModel
from elastic_gym.observers import ObserverWrapper, make_observer
from elastic_gym.robots.catalog import get_robot

ID = "elastic_gym/TwoLinkElastic-v0"


def test_a_closed_env_refuses_to_run_and_cannot_move_another_env():
    a = gym.make(ID)
    a.reset(seed=0)
    a.close()
    b = gym.make(ID)  # PyBullet may hand out the client id a had
    b.reset(seed=1)
    state = b.unwrapped.sim.state.copy()
    for call in (
        lambda: a.step(np.zeros(2)),
        lambda: a.reset(seed=0),
        lambda: a.unwrapped.render(),
    ):
        with pytest.raises(RuntimeError, match="closed"):
            call()
    assert np.array_equal(b.unwrapped.sim.state, state)
    b.step(np.zeros(2))
    b.close()
    a.close()  # closing twice is harmless


def test_human_render_with_an_unreachable_x_server_is_an_exception(monkeypatch):
    monkeypatch.setenv("DISPLAY", ":97")  # no X server there: PyBullet would abort the process
    with pytest.raises(RuntimeError, match="no X server"):
        gym.make(ID, render_mode="human")


def _terminating(env_id: str = "elastic_gym/TwoLinkRigid-v0", **kwargs):
    env = gym.make(env_id, max_velocity=0.5, **kwargs)
    return env, env.unwrapped.torque_limit


@pytest.mark.parametrize("observer", [None, "nicosia-tomei"])
def test_terminal_step_has_every_info_key_and_the_final_observation(observer):
    env, limit = _terminating()
    if observer:
        env = ObserverWrapper(env, observer)
    obs, first = env.reset(seed=0)
    for _ in range(1000):
        obs, reward, terminated, _, info = env.step(limit)
        if terminated:
            break
    assert terminated and info["termination_reason"] == "velocity limit exceeded"
    assert set(info) == set(first)
    assert set(info["true_state"]) == set(first["true_state"])
    assert set(info["reference"]) == set(first["reference"])
    if observer is None:  # the final state: link encoders read the final q (7e-4 quantum)
        assert np.abs(obs["link_position"] - info["true_state"]["q"]).max() <= 3.5e-4 + 1e-12
    else:
        assert np.array_equal(obs["state"], info["estimate"])
        assert np.abs(info["estimation_error"]).max() < 1.0
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(2))
    env.close()


def test_copies_of_a_wrapper_built_on_an_observer_instance_do_not_share_it():
    env = gym.make(ID)
    observer = make_observer("deluca", env.unwrapped.model, env.unwrapped.control_dt)
    wrapped = ObserverWrapper(env, observer)
    copy = gym.make(wrapped.spec)  # what make_vec / DummyVecEnv do
    assert wrapped.observer is not observer and copy.observer is not wrapped.observer
    wrapped.reset(seed=0)
    copy.reset(seed=1)
    for _ in range(50):
        *_, info = wrapped.step(np.array([1.0, -1.0]))
        *_, copy_info = copy.step(np.array([-2.0, 2.0]))
    assert np.abs(info["estimation_error"]).max() < 0.1  # not disturbed by the copy
    assert np.abs(copy_info["estimation_error"]).max() < 0.1
    wrapped.close()
    copy.close()


def test_observer_wrapper_refuses_what_would_be_silently_wrong():
    env = gym.make(ID)
    other = RobotModel(get_robot("kr15_elastic"))
    with pytest.raises(ValueError, match="kr15"):
        ObserverWrapper(env, make_observer("deluca", other, 1e-3))
    with pytest.raises(ValueError, match="FlattenObservation"):
        ObserverWrapper(FlattenObservation(env), "deluca")
    with pytest.raises(ValueError, match="'ideal'"):
        gym.make(ID, accelerometer="noisy")
    env.close()


@pytest.mark.parametrize(
    ("env_id", "kwargs", "match"),
    [
        (ID, {"max_velocity": float("nan")}, "max_velocity"),
        (ID, {"max_velocity": 0.0}, "max_velocity"),
        (ID, {"task_options": {"max_move": -0.1}}, "max_move"),
        (ID, {"task_options": {"move_time": float("nan")}}, "move_time"),
        (ID, {"task_options": {"n_moves": "2"}}, "n_moves"),
        (
            ID,
            {"task": "excitation", "task_options": {"gravity_compensation": "yes"}},
            "gravity_compensation",
        ),
        ("elastic_gym/TwoLinkRigid-v0", {"plant_scaling": {"stiffness": 0.5}}, "stiffness"),
        (ID, {"plant_scaling": {"friction": 2.0}}, "friction"),
        (ID, {"encoder": {"resolution": 1e-320}}, "resolution"),
        (ID, {"encoder": {"noise_std": 1e300}}, "noise_std"),
        (ID, {"accelerometer": {"noise_density": 1e300}}, "noise_density"),
        (ID, {"accelerometer": {"cutoff_hz": float("inf")}}, "cutoff_hz"),
        (ID, {"sensor_delay": 10**9}, "sensor_delay"),
        (ID, {"control_dt": 10.0}, "control_dt"),
        (ID, {"episode_time": -1.0}, "episode_time"),
        (
            "elastic_gym/IiwaElastic-v0",
            {"task": "regulation", "task_options": {"goal": [9.0, 0, 0, 0, 0, 0, 0]}},
            r"task_options\.goal: \[\[9\.0, .* is outside the joint limits",
        ),
        (
            ID,
            {"task_options": {"waypoints": [[0.1, 0.2], [0.3]]}},
            r"task_options\.waypoints must have shape \(N, 2\), got ragged rows",
        ),
        (
            ID,
            {"task_options": {"waypoints": [[0.1, 0.2, 0.3]]}},
            r"task_options\.waypoints must have shape \(N, 2\), got \(1, 3\)",
        ),
    ],
)
def test_numbers_that_would_break_later_are_refused_at_creation(env_id, kwargs, match):
    with pytest.raises(ValueError, match=match):
        gym.make(env_id, **kwargs)


@pytest.mark.parametrize(
    ("initial_state", "match"),
    [
        ({"q": [np.nan, 0.0]}, "finite"),
        ({"q": [1e10, 0.0]}, r"initial_state\.q\[0\]: Input should be less than or equal to 1000"),
        ({"dq": [500.0, 0.0]}, "magnitude"),
    ],
)
def test_bad_initial_states_are_refused_and_change_nothing(initial_state, match):
    env = gym.make(ID)
    env.reset(seed=0)
    state = env.unwrapped.sim.state.copy()
    with pytest.raises(ValueError, match=match):
        env.reset(options={"initial_state": initial_state})
    assert np.array_equal(env.unwrapped.sim.state, state)
    env.close()


def test_initial_state_beyond_the_joint_limits_is_refused():
    env = gym.make("elastic_gym/IiwaElastic-v0")
    with pytest.raises(ValueError, match=r"options\.initial_state\.q: .* outside the joint limits"):
        env.reset(options={"initial_state": {"q": [0.0, 3.0, 0.0, 0.0, 0.0, 0.0, 0.0]}})
    env.close()


def test_absurd_deluca_poles_are_refused():
    model = RobotModel(get_robot("two_link_elastic"))
    with pytest.raises(ValueError, match="too fast"):
        make_observer("deluca", model, 1e-3, bandwidth=1e6)
    with pytest.raises(TypeError, match="use_coupling"):
        make_observer("deluca", model, 1e-3, use_coupling="no")
