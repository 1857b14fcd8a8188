"""The simulated physics is the model of the papers: PyBullet links + elastic transmission.

* PyBullet's link accelerations equal pinocchio's forward dynamics of model (1)/(2) at
  the same state (also with a scaled plant);
* an open-loop run of 0.5 s matches an independent scipy integration of the model,
  with the first-order convergence of PyBullet's semi-implicit Euler in physics_dt;
* with zero torque and no damping the total energy is conserved.
"""

from __future__ import annotations

import dataclasses

import gymnasium as gym
import numpy as np
import pytest
from helpers import ELASTIC_IDS, make_noise_free
from scipy.integrate import solve_ivp

import elastic_gym  # noqa: F401 (registers the env ids)
from elastic_gym.envs import ElasticArmEnv
from elastic_gym.envs.simulator import ArmSimulator
from elastic_gym.model import RobotModel
from elastic_gym.robots.catalog import get_robot

ROBOTS = ["two_link_elastic", "kr15_elastic", "iiwa_elastic", "two_link_rigid", "two_link_friction"]


@pytest.mark.parametrize("robot", ROBOTS)
@pytest.mark.parametrize("scaling", [None, {"link_mass": 1.3, "stiffness": 0.8}])
def test_pybullet_accelerations_equal_pinocchio(robot, scaling):
    """Three arms in one world, random states: PyBullet's q'' (one physics step) and the
    simulator's own q'' (the batched chain) equal pinocchio's model (1)/(2) forward dynamics."""
    spec = get_robot(robot)
    if scaling and not spec.elastic:
        scaling = {"link_mass": 1.3}
    plant = RobotModel(spec, scaling)
    arms = np.arange(3)
    sim = ArmSimulator(spec, plant, spec.physics_dt, n_arms=len(arms))
    rng = np.random.default_rng(0)
    n = spec.n_joints
    worst = worst_chain = 0.0
    for _ in range(3):
        q = rng.uniform(spec.workspace_low, spec.workspace_high, (3, n))
        theta = q + 0.01 * rng.standard_normal((3, n))
        dq, dtheta = rng.standard_normal((3, n)), rng.standard_normal((3, n))
        sim.reset_state(arms, q, dq, theta, dtheta)
        tau = 0.05 * np.asarray(spec.torque_limit) * rng.uniform(-1, 1, (3, n))
        if spec.elastic:
            x = np.concatenate([theta, q, dtheta, dq], axis=1)
            expected = np.array([plant.elastic_accelerations(x[i], tau[i])[1] for i in arms])
        else:
            expected = np.array([plant.rigid_acceleration(q[i], dq[i], tau[i]) for i in arms])
        chain = sim.link_acceleration(tau)
        sim.step(tau, 1)
        measured = (sim.dq - dq) / spec.physics_dt
        scale = np.abs(expected).max()
        worst = max(worst, np.abs(measured - expected).max() / scale)
        worst_chain = max(worst_chain, np.abs(chain - expected).max() / scale)
    sim.close()
    assert worst < 1e-6
    assert worst_chain < 1e-12


def _open_loop(env_id: str, physics_dt: float | None, duration: float = 0.5):
    kwargs = {"task": "excitation", "task_options": {"amplitude": 0.0}}
    if physics_dt is not None:
        kwargs["physics_dt"] = physics_dt
    env = make_noise_free(env_id, **kwargs)
    obs, info = env.reset(seed=3)
    u = env.unwrapped
    steps = round(duration / u.control_dt)
    states, torques = [info["true_state"]["x"]], []
    for k in range(steps):
        # a smooth torque on top of gravity compensation (excitation task)
        tau = 0.01 * u.torque_limit * np.sin(np.arange(u.n_joints) + 10.0 * k * u.control_dt)
        obs, _, terminated, _, info = env.step(tau)
        assert not terminated
        torques.append(info["torque"])
        states.append(info["true_state"]["x"])
    env.close()
    return u.plant_model, u.control_dt, np.array(states), np.array(torques)


@pytest.mark.slow
@pytest.mark.parametrize("env_id", ELASTIC_IDS)
def test_open_loop_matches_scipy_integration_of_the_model(env_id):
    model, dt, states, torques = _open_loop(env_id, None)
    steps, n = len(torques), model.n

    def rhs(t, x):
        return model.elastic_dynamics(x, torques[min(int(t / dt), steps - 1)])

    times = np.arange(steps + 1) * dt
    sol = solve_ivp(
        rhs,
        (0.0, times[-1]),
        states[0],
        method="DOP853",
        rtol=1e-9,
        atol=1e-10,
        t_eval=times,
        max_step=dt,
    )
    error = np.abs(sol.y.T - states)
    motion = np.ptp(states[:, n : 2 * n], axis=0).max()
    assert motion > 0.02  # the arm really moved
    assert error[:, n : 2 * n].max() < 2e-3  # link positions (rad)
    assert error[:, 3 * n :].max() < 5e-3  # link velocities (rad/s)
    if env_id.endswith("TwoLinkElastic-v0"):
        # semi-implicit Euler is first order: halving physics_dt halves the error
        spec_dt = get_robot("two_link_elastic").physics_dt
        _, _, fine, _ = _open_loop(env_id, spec_dt / 2)
        fine_error = np.abs(sol.y.T - fine)[:, n : 2 * n].max()
        assert 1.7 < error[:, n : 2 * n].max() / fine_error < 2.3


@pytest.mark.parametrize("robot", ["two_link_elastic", "kr15_elastic", "iiwa_elastic"])
def test_energy_is_conserved_without_torque_and_damping(robot):
    base = get_robot(robot)
    changes = {"damping": tuple(0.0 for _ in range(base.n_joints))}
    if robot == "iiwa_elastic":
        changes["gravity"] = (0.0, 0.0, 0.0)  # a free fall would hit the joint limits
    spec = dataclasses.replace(base, **changes)
    env = ElasticArmEnv(spec, task="regulation", accelerometer="ideal")
    n = spec.n_joints
    rng = np.random.default_rng(1)
    options = None
    if robot == "iiwa_elastic":
        q = 0.5 * (np.asarray(spec.workspace_low) + np.asarray(spec.workspace_high))
        options = {
            "initial_state": {
                "q": q,
                "theta": q + 0.02 * rng.standard_normal(n),
                "dq": 0.5 * rng.standard_normal(n),
            }
        }
    obs, info = env.reset(seed=0, options=options)
    model = env.plant_model
    energy, exchanged = [], []
    for _ in range(2000):  # 2 s
        s = info["true_state"]
        energy.append(model.energy(s["q"], s["dq"], s["theta"], s["dtheta"]))
        delta = s["theta"] - s["q"]
        kinetic = 0.5 * s["dq"] @ model.mass_matrix(s["q"]) @ s["dq"]
        kinetic += 0.5 * s["dtheta"] @ (model.B * s["dtheta"])
        exchanged.append(kinetic + 0.5 * delta @ (model.K * delta))
        obs, _, terminated, _, info = env.step(np.zeros(n))
        assert not terminated
    env.close()
    energy, scale = np.array(energy), max(exchanged)  # kinetic + elastic energy in play
    assert scale > 0.01  # something moved
    # secular drift: mean energy over the last 0.1 s vs the first 0.1 s
    assert abs(energy[-100:].mean() - energy[:100].mean()) / scale < 0.01
    # semi-implicit Euler keeps the energy error bounded; its oscillation grows with
    # (dt * omega_max)^2, 0.15 for the iiwa wrist at 0.25 ms (1.5 % measured), 0.1 for the others
    max_deviation = np.abs(energy - energy[0]).max() / scale
    assert max_deviation < (0.02 if robot == "iiwa_elastic" else 0.01)


def test_model_2_coupling_changes_the_motion():
    """KR15 has S23 != 0: the same torque gives another motion than with S = 0."""
    spec = get_robot("kr15_elastic")
    uncoupled = dataclasses.replace(spec, coupling=None)
    results = []
    for robot in (spec, uncoupled):
        env = ElasticArmEnv(
            robot,
            task="excitation",
            accelerometer="ideal",
            task_options={"amplitude": 0.0, "start": [0.0, 0.0, 0.0]},
        )
        env.reset(seed=0)
        for _ in range(200):
            *_, info = env.step(np.array([0.0, 0.0, 300.0]))
        results.append(info["true_state"]["x"])
        env.close()
    n = spec.n_joints
    assert np.abs(results[0][n : 2 * n] - results[1][n : 2 * n]).max() > 1e-4


def test_physics_dt_too_coarse_for_the_stiffest_joint_is_rejected():
    with pytest.raises(ValueError, match="too coarse"):
        gym.make("elastic_gym/IiwaElastic-v0", physics_dt=1e-3)


def test_natural_frequencies_and_static_equilibrium():
    model = RobotModel(get_robot("two_link_elastic"))
    q = np.array([0.3, -0.4])
    free, locked = model.natural_frequencies(q)
    assert np.all(free > locked.min()) and np.all(free > 10.0)
    # at theta = q + K^-1 g(q) the arm is at rest: zero accelerations
    x = np.concatenate([model.static_motor_position(q), q, np.zeros(2), np.zeros(2)])
    ddtheta, ddq = model.elastic_accelerations(x, model.K * (x[:2] - q))
    assert np.allclose(ddq, 0.0, atol=1e-10) and np.allclose(ddtheta, 0.0, atol=1e-10)


def test_unmodelled_friction_acts_on_the_simulated_plant_only():
    """``unmodelled_friction`` (fractions of the torque limit): the plant's link equation
    has d(q') = tau_max (v q' + c tanh(q' / 0.01)), PyBullet's q'' follows it, and the
    nominal model (what observers and controllers use) knows nothing of it."""
    env = gym.make(
        "elastic_gym/TwoLinkElastic-v0",
        unmodelled_friction={"coulomb": 0.05, "viscous": [0.01, 0.02]},
    )
    u = env.unwrapped
    plant, model, limit = u.plant_model, u.model, u.torque_limit
    assert model.friction is None
    q, dq = np.array([0.3, -0.5]), np.array([0.5, -0.3])
    theta, dtheta = q + 0.01, dq
    np.testing.assert_allclose(
        plant.link_friction(dq),
        limit * (np.array([0.01, 0.02]) * dq + 0.05 * np.tanh(dq / 0.01)),
        rtol=1e-12,
    )
    tau = 0.02 * limit
    x = np.concatenate([theta, q, dtheta, dq])
    expected = plant.elastic_accelerations(x, tau)[1]
    frictionless = model.elastic_accelerations(x, tau)[1]
    arm = np.arange(1)
    u.sim.reset_state(arm, q[None], dq[None], theta[None], dtheta[None])
    u.sim.step(tau[None], 1)
    measured = (u.sim.dq[0] - dq) / u.physics_dt
    assert np.abs(measured - expected).max() < 1e-6 * np.abs(expected).max()
    assert np.abs(expected - frictionless).min() > 1.0  # rad/s^2: the friction is felt
    env.close()
