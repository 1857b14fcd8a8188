"""Envs on the RK4 integrator (`integrator="rk4"`): the same guarantees as on PyBullet's.

Arm i of a batch is the single env bit for bit (heterogeneous plants, friction, payload
changes, torque pulses, delays, terminations); the compiled control period equals the
step by step one; a pickled env continues bit for bit; PyBullet stays the world (its
link poses follow the state when read); an open loop of 3 s matches scipy's DOP853 of
the model within 1e-6 rad.
"""

from __future__ import annotations

import pickle

import gymnasium as gym
import numpy as np
import pytest
from helpers import arm_row, fast_lane, flat, leaves, make_noise_free, step_in_lockstep
from scipy.integrate import solve_ivp

import elastic_gym
from elastic_gym.envs.packing import FusedArguments

ELASTIC = [i for i in elastic_gym.ENV_IDS if "Elastic" in i]
N_ARMS = 3
PER_ARM = [
    {},
    {"unmodelled_friction": {"coulomb": 0.03}, "plant_scaling": {"link_mass": 1.2}},
    {"payload": {"mass": 0.0, "change": {"time": 0.02, "mass": 1.0}}, "actuator_delay": 1},
]


def _actions(limit: np.ndarray, rng: np.random.Generator, n_arms: int) -> np.ndarray:
    actions = 0.05 * limit * rng.uniform(-1, 1, (n_arms, len(limit)))
    actions[-1] = 1.5 * limit  # saturated: the last arm hits the velocity limit
    return actions


@pytest.mark.parametrize("env_id", fast_lane(elastic_gym.ENV_IDS, "elastic_gym/KR15Elastic-v0"))
def test_each_arm_equals_the_single_env_bit_for_bit(env_id):
    kwargs = {
        "integrator": "rk4",
        "episode_time": 0.06,
        "max_velocity": 2.0,
        "sensor_delay": 1,
    }
    if env_id == "elastic_gym/TwoLinkElastic-v0":
        # (a pulse at t = 0.03 s: no arm ends inside it, whose info would keep its torque)
        pulse = {"times": [0.03], "durations": [0.005], "amplitudes": [[2.0, -1.0]]}
        kwargs |= {"per_arm": PER_ARM, "torque_pulses": pulse}
    envs = gym.make_vec(env_id, num_envs=N_ARMS, vectorization_mode="vector_entry_point", **kwargs)
    per_arm = kwargs.pop("per_arm", [{}] * N_ARMS)
    singles = [gym.make(env_id, **kwargs, **options) for options in per_arm]
    obs, info = envs.reset(seed=11)
    for i, env in enumerate(singles):
        single_obs, single_info = env.reset(seed=11 + i)
        assert np.array_equal(flat(arm_row(obs, i)), flat(single_obs))
    rng = np.random.default_rng(0)
    limit = envs.unwrapped.torque_limit
    reasons = step_in_lockstep(envs, singles, lambda: _actions(limit, rng, N_ARMS), 100)
    assert reasons == {"velocity limit exceeded"}
    envs.close()
    for env in singles:
        env.close()


def _rollout(env_id: str, step_by_step: bool, monkeypatch) -> list:
    original = FusedArguments._build
    monkeypatch.setattr(
        FusedArguments, "_build", lambda self: None if step_by_step else original(self)
    )
    kwargs = {
        "integrator": "rk4",
        "sensor_delay": 1,
        "encoder": {"noise_std": 1e-4},
        "randomize": {"plant_scaling.link_mass": {"low": 0.8, "high": 1.2}},
        "episode_time": 0.05,
    }
    envs = gym.make_vec(env_id, 3, vectorization_mode="vector_entry_point", **kwargs)
    rng = np.random.default_rng(5)
    high = envs.single_action_space.high
    out = leaves(envs.reset(seed=3), [])
    for _ in range(120):
        leaves(envs.step(rng.uniform(-0.05, 0.05, (3, len(high))) * high), out)
    envs.close()
    return out


@pytest.mark.parametrize("env_id", ["elastic_gym/TwoLinkElastic-v0", "elastic_gym/KR15Elastic-v0"])
def test_compiled_period_equals_the_step_by_step_one(env_id, monkeypatch):
    fused = _rollout(env_id, False, monkeypatch)
    monkeypatch.undo()
    stepwise = _rollout(env_id, True, monkeypatch)
    assert fused == stepwise


def test_pickled_env_continues_bit_for_bit():
    """The substep counts of the step-size control travel with the state."""
    kwargs = {"integrator": "rk4", "unmodelled_friction": {"coulomb": 0.05}}
    envs = gym.make_vec(
        "elastic_gym/TwoLinkElastic-v0", 2, vectorization_mode="vector_entry_point", **kwargs
    )
    envs.reset(seed=4)
    rng = np.random.default_rng(1)
    limit = envs.unwrapped.torque_limit
    for _ in range(30):
        envs.step(0.02 * limit * rng.uniform(-1, 1, (2, 2)))
    substeps = envs.unwrapped.batch.sim.rk4.substeps
    assert substeps.max() > 1  # the friction's steep tanh near rest takes substeps
    clone = pickle.loads(pickle.dumps(envs))
    assert np.array_equal(clone.unwrapped.batch.sim.rk4.substeps, substeps)
    for _ in range(20):
        action = 0.02 * limit * rng.uniform(-1, 1, (2, 2))
        assert leaves(envs.step(action), []) == leaves(clone.step(action), [])
    clone.close()
    envs.close()


def test_pybullet_stays_the_world():
    """Link poses read from PyBullet follow the RK4's state (pinocchio at the same q)."""
    env = gym.make("elastic_gym/TwoLinkElastic-v0", integrator="rk4")
    env.reset(seed=0)
    u = env.unwrapped
    for _ in range(50):
        env.step(0.1 * u.torque_limit)
    position, rotation = u.sim.link_pose("link2")
    model = u.plant_model
    frame = model.pin_model.getFrameId("link2")
    import pinocchio as pin

    data = model.pin_model.createData()
    pin.framesForwardKinematics(model.pin_model, data, u.sim.q[0])
    np.testing.assert_allclose(position, data.oMf[frame].translation, atol=1e-6)
    np.testing.assert_allclose(rotation, data.oMf[frame].rotation, atol=1e-6)
    assert env.render().shape[2] == 3 if env.render_mode else True
    env.close()


def test_bad_integrator_is_refused():
    with pytest.raises(ValueError, match="integrator"):
        gym.make("elastic_gym/TwoLinkElastic-v0", integrator="euler")


@pytest.mark.slow
@pytest.mark.parametrize("env_id", ELASTIC)
def test_three_second_open_loop_matches_dop853_within_1e_6_rad(env_id):
    """The excitation task (gravity compensation + a smooth torque of 1 % of the limits,
    0.2 % on the light iiwa wrist, held over each 1 ms period) for 3 s: the env's link
    positions within 1e-6 rad of a DOP853 integration (rtol 1e-12) of the plant model
    under the torques it applied."""
    env = make_noise_free(
        env_id,
        integrator="rk4",
        task="excitation",
        task_options={"amplitude": 0.0},
        episode_time=None,
    )
    amplitude = 0.002 if "Iiwa" in env_id else 0.01
    obs, info = env.reset(seed=3)
    u = env.unwrapped
    steps = 3000
    states, torques = [info["true_state"]["x"]], []
    for k in range(steps):
        tau = amplitude * u.torque_limit * np.sin(np.arange(u.n_joints) + 10.0 * k * u.control_dt)
        obs, _, terminated, _, info = env.step(tau)
        assert not terminated
        torques.append(info["torque"])
        states.append(info["true_state"]["x"])
    env.close()
    model, n, dt = u.plant_model, u.n_joints, u.control_dt
    x, worst = states[0], 0.0
    for k, tau in enumerate(torques):
        x = solve_ivp(
            lambda t, y, tau=tau: model.elastic_dynamics(y, tau),
            (0.0, dt),
            x,
            method="DOP853",
            rtol=1e-12,
            atol=1e-14,
        ).y[:, -1]
        worst = max(worst, np.abs(x[n : 2 * n] - states[k + 1][n : 2 * n]).max())
    motion = np.ptp(np.array(states)[:, n : 2 * n], axis=0).max()
    assert motion > 0.02  # rad: the arm moved
    assert worst < 1e-6, worst
