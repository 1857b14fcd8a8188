"""Plant features of the simulated plant: actuator delay, link torque pulses, payload —
each checked against the physics it claims (and refused when malformed)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pybullet as p
import pytest

TWO_LINK = "elastic_gym/TwoLinkElastic-v0"
RIGID = "elastic_gym/TwoLinkRigid-v0"


def test_actuator_delay_applies_each_command_k_periods_late():
    k, seed = 3, 4
    delayed = gym.make(TWO_LINK, actuator_delay=k)
    direct = gym.make(TWO_LINK)
    _, info_d = delayed.reset(seed=seed)
    _, info_0 = direct.reset(seed=seed)
    rest = info_0["torque"]  # the reset's equilibrium torque, held for the first k periods
    assert np.array_equal(info_d["torque"], rest)
    rng = np.random.default_rng(0)
    commands = 5.0 * rng.uniform(-1, 1, (40, 2))
    shifted = [rest] * k + list(commands[:-k])
    for command, late in zip(commands, shifted, strict=True):
        _, _, _, _, info_d = delayed.step(command)
        _, _, _, _, info_0 = direct.step(late)
        assert np.array_equal(info_d["torque"], late)  # what reaches the motors
        for key in ("q", "dq", "theta", "dtheta", "ddq"):
            assert np.array_equal(info_d["true_state"][key], info_0["true_state"][key])
    assert info_d["plant"]["actuator_delay"] == k


def _state_after_one_substep(env, q, torque):
    env.reset(seed=0, options={"initial_state": {"q": q}})
    u = env.unwrapped
    before = {key: value.copy() for key, value in env.unwrapped.batch.info(0)["true_state"].items()}
    _, _, _, _, info = env.step(torque)
    return u, before, info


def test_pybullet_link_acceleration_during_a_pulse_is_pinocchio_forward_dynamics():
    pulse = np.array([6.0, -4.0])
    q0 = np.array([0.4, -0.7])
    kwargs = {"physics_dt": 5e-4, "control_dt": 5e-4}  # one substep per control period
    env = gym.make(
        TWO_LINK,
        torque_pulses={"times": [0.0], "durations": [1e-3], "amplitudes": [pulse.tolist()]},
        **kwargs,
    )
    u, before, info = _state_after_one_substep(env, q0, np.zeros(2))
    plant, dt = u.plant_model, u.physics_dt
    q, dq, theta, dtheta = (before[key] for key in ("q", "dq", "theta", "dtheta"))
    tau_j = plant.joint_torque(theta, q, dtheta, dq)
    expected = plant.aba(q, dq, tau_j + pulse)  # M q'' + C q' + g = tau_J + pulse
    measured = (info["true_state"]["dq"] - dq) / dt  # PyBullet's semi-implicit Euler step
    assert np.allclose(measured, expected, rtol=1e-9, atol=1e-9)
    nominal = plant.aba(q, dq, tau_j)
    assert np.max(np.abs(expected - nominal)) > 1.0  # the pulse matters
    assert np.array_equal(info["plant"]["torque_pulse"], pulse)
    # after the pulse the links get no extra torque
    _, _, _, _, info = env.step(np.zeros(2))
    _, _, _, _, info = env.step(np.zeros(2))
    assert np.array_equal(info["plant"]["torque_pulse"], np.zeros(2))


def test_random_pulses_come_from_the_plant_stream_within_their_ranges():
    spec = {
        "count": 5,
        "window": [0.1, 0.5],
        "duration": {"low": 0.01, "high": 0.02},
        "amplitude": {"low": 0.1, "high": 0.3},
    }
    env = gym.make(TWO_LINK, torque_pulses={"random": spec})
    limit = env.unwrapped.torque_limit
    _, info = env.reset(seed=9)
    plant = info["plant"]
    times, durations = plant["torque_pulses.times"], plant["torque_pulses.durations"]
    fraction = np.abs(plant["torque_pulses.amplitudes"]) / limit
    assert np.all((times >= 0.1) & (times <= 0.5))
    assert np.all((durations >= 0.01 - 1e-15) & (durations <= 0.02 + 1e-15))
    assert np.all((fraction >= 0.1) & (fraction <= 0.3))
    assert np.array_equal(env.reset(seed=9)[1]["plant"]["torque_pulses.times"], times)
    assert not np.array_equal(env.reset()[1]["plant"]["torque_pulses.times"], times)
    # the task draws are those of the env without pulses
    plain = gym.make(TWO_LINK)
    _, reference = plain.reset(seed=9)
    _, info = env.reset(seed=9)
    assert np.array_equal(info["reference"]["q"], reference["reference"]["q"])


def test_payload_gravity_torque_at_rest_is_m_g_x():
    mass, q = 2.5, np.array([0.3, -0.9])
    env = gym.make(TWO_LINK, payload={"mass": mass})
    env.reset(seed=0, options={"initial_state": {"q": q}})
    u = env.unwrapped
    sim = u.sim
    # the planar arm (link lengths 0.5 and 0.4, x-z plane): the tip and joint 2's x
    x_tip = 0.5 * np.cos(q[0]) + 0.4 * np.cos(q[0] + q[1])
    x_joint2 = 0.5 * np.cos(q[0])
    z_tip = 0.5 * np.sin(q[0]) + 0.4 * np.sin(q[0] + q[1])
    link = sim.payload_links[0]
    state = p.getLinkState(
        sim.bodies[0], link, computeForwardKinematics=1, physicsClientId=sim.client
    )
    assert np.allclose(
        np.asarray(state[0]) - sim.base_positions[0], [x_tip, 0.0, z_tip], atol=1e-12
    )
    extra = u.plant_model.gravity(q) - u.model.gravity(q)
    assert np.allclose(extra, mass * 9.81 * np.array([x_tip, x_tip - x_joint2]), rtol=1e-12)
    # PyBullet's own inverse dynamics at rest sees the same extra gravity torque
    zero = [0.0, 0.0]
    with_payload = p.calculateInverseDynamics(
        sim.bodies[0], q.tolist(), zero, zero, physicsClientId=sim.client
    )
    bare = gym.make(TWO_LINK)
    bare.reset(seed=0, options={"initial_state": {"q": q}})
    s0 = bare.unwrapped.sim
    without = p.calculateInverseDynamics(
        s0.bodies[0], q.tolist(), zero, zero, physicsClientId=s0.client
    )
    assert np.allclose(np.subtract(with_payload, without), extra, rtol=1e-12)
    # a point mass: no rotational inertia in PyBullet either
    assert p.getDynamicsInfo(sim.bodies[0], link, physicsClientId=sim.client)[2] == (0.0, 0.0, 0.0)


def test_payload_change_at_its_time_in_pybullet_and_in_the_plant_model():
    env = gym.make(TWO_LINK, payload={"mass": 1.0, "change": {"time": 0.005, "mass": 3.0}})
    _, info = env.reset(seed=1)
    u = env.unwrapped
    sim, link = u.sim, u.sim.payload_links[0]
    masses = []
    for _ in range(8):
        masses.append(info["plant"]["payload.mass"])
        _, _, _, _, info = env.step(np.zeros(2))
    assert masses[:6] == [1.0] * 6 and masses[6:] == [3.0, 3.0]  # from the period at 5 ms
    assert p.getDynamicsInfo(sim.bodies[0], link, physicsClientId=sim.client)[0] == 3.0
    q = np.array([0.2, 0.5])
    three = u.plant_model.gravity(q) - u.model.gravity(q)
    assert np.allclose(
        three,
        3.0 * (u.batch.resolver.plant_model(u.batch.settings[0]).gravity(q) - u.model.gravity(q)),
        rtol=1e-12,
    )
    _, info = env.reset()  # a new episode starts with the initial mass again
    assert info["plant"]["payload.mass"] == 1.0
    assert p.getDynamicsInfo(sim.bodies[0], link, physicsClientId=sim.client)[0] == 1.0


def test_info_plant_of_one_arm_is_a_fresh_dict_at_every_step():
    """The one-arm ``info["plant"]`` keeps its plain values between steps: a caller that
    changes the dict it got changes no later info, and a reset with new draws shows them."""
    env = gym.make(
        TWO_LINK,
        randomize={"plant_scaling.link_mass": {"low": 0.8, "high": 1.2}},
        payload={"mass": 1.0},
    )
    _, info = env.reset(seed=3)
    first = dict(info["plant"])
    info["plant"]["payload.mass"] = -1.0
    info["plant"]["mine"] = True
    _, _, _, _, info = env.step(np.zeros(2))
    assert info["plant"] == {**first, "torque_pulse": info["plant"]["torque_pulse"]}
    assert info["plant"]["torque_pulse"] is not first["torque_pulse"]
    _, info = env.reset(seed=4)
    assert info["plant"]["plant_scaling.link_mass"] != first["plant_scaling.link_mass"]
    vector = env.unwrapped.batch.info(np.array([0]))["plant"]
    assert info["plant"]["plant_scaling.link_mass"] == vector["plant_scaling.link_mass"][0]
    env.close()


def test_rigid_arm_pulse_and_payload():
    env = gym.make(
        RIGID,
        physics_dt=1e-3,
        control_dt=1e-3,
        payload={"mass": 0.5},
        torque_pulses={"times": [0.0], "durations": [1e-3], "amplitudes": [[1.0, 0.5]]},
    )
    u, before, info = _state_after_one_substep(env, np.array([0.2, 0.3]), np.array([0.5, -0.2]))
    plant = u.plant_model
    q, dq = before["q"], before["dq"]
    expected = plant.rigid_acceleration(q, dq, np.array([0.5, -0.2]) + np.array([1.0, 0.5]))
    measured = (info["true_state"]["dq"] - dq) / u.physics_dt
    assert np.allclose(measured, expected, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"actuator_delay": -1}, "actuator_delay: Input should be greater than or equal to 0"),
        ({"actuator_delay": 1.0}, "actuator_delay: Input should be a valid integer"),
        ({"actuator_delay": 2000}, "actuator_delay of 2000 control periods is more than 1.0 s"),
        ({"payload": {"mass": -1.0}}, r"payload\.mass: Input should be greater than or equal to 0"),
        ({"payload": {"mass": 1.0, "where": 2}}, r"payload\.where: unexpected field"),
        ({"payload": {"mass": 1.0, "change": {"time": 0.0, "mass": 1}}}, r"payload\.change\.time"),
        ({"payload": {"mass": 1.0, "position": [0, 0]}}, r"payload\.position"),
        ({"torque_pulses": {"times": [0.1]}}, "give times and durations and amplitudes together"),
        (
            {"torque_pulses": {"times": [0.1], "durations": [0.1, 0.2], "amplitudes": [1.0]}},
            "one entry per pulse",
        ),
        (
            {"torque_pulses": {"times": [0.1], "durations": [-0.1], "amplitudes": [1.0]}},
            r"torque_pulses\.durations\[0\]: Input should be greater than 0",
        ),
        (
            {"torque_pulses": {"times": [0.1], "durations": [0.1], "amplitudes": [[1.0, 2, 3]]}},
            r"torque_pulses\.amplitudes\[0\] must be one or 2 finite numbers",
        ),
        (
            {
                "torque_pulses": {
                    "random": {
                        "count": 2,
                        "window": [0.5, 0.1],
                        "duration": {"low": 0.1, "high": 0.2},
                        "amplitude": {"low": 0, "high": 1},
                    }
                }
            },
            r"torque_pulses\.random\.window: start \(.*\) must be <= end",
        ),
    ],
)
def test_bad_plant_features_are_refused(kwargs, match):
    with pytest.raises(ValueError, match=match):
        gym.make(TWO_LINK, **kwargs)


@pytest.mark.slow
def test_a_pickled_env_with_plant_features_continues_bit_for_bit():
    import pickle

    env = gym.make(
        "elastic_gym/KR15Elastic-v0",
        payload={"mass": 0.5, "change": {"time": 0.01, "mass": 1.5}},
        actuator_delay=2,
        torque_pulses={
            "random": {
                "count": 3,
                "window": [0.0, 0.03],
                "duration": {"low": 0.002, "high": 0.004},
                "amplitude": {"low": 0.01, "high": 0.03},
            }
        },
        randomize={"plant_scaling.link_mass": {"low": 0.8, "high": 1.2}},
    ).unwrapped
    env.reset(seed=3)
    for _ in range(8):  # before the payload change, pulses under way
        env.step(np.ones(3))
    clone = pickle.loads(pickle.dumps(env))
    for _ in range(30):
        a, b = env.step(np.ones(3)), clone.step(np.ones(3))
        assert np.array_equal(a[0]["motor_position"], b[0]["motor_position"])
        assert np.array_equal(a[4]["true_state"]["x"], b[4]["true_state"]["x"])
        assert a[4]["plant"]["payload.mass"] == b[4]["plant"]["payload.mass"]
    assert a[4]["plant"]["payload.mass"] == 1.5
    drawn = [e.reset()[1]["plant"]["plant_scaling.link_mass"] for e in (env, clone)]
    assert drawn[0] == drawn[1]  # the plant streams continue alike


@pytest.mark.parametrize("friction", [False, True])
def test_step_dynamics_in_one_call_equal_the_separate_calls(friction):
    """q'' and the accelerometers' noise-free readings of a step (one compiled call) equal
    link_acceleration and eq. (9) computed apart, with a link-side pulse torque."""
    kwargs = {"unmodelled_friction": {"viscous": 0.02, "coulomb": 0.1}} if friction else {}
    env = gym.make(TWO_LINK, **kwargs)
    env.reset(seed=2)
    for _ in range(5):
        env.step(np.array([1.5, -0.7]))
    sim = env.unwrapped.sim
    tau, pulse = np.array([[0.8, -0.3]]), np.array([[0.4, 0.25]])
    for link_torque in (None, pulse):
        ddq, forces = sim.link_acceleration_and_forces(tau, link_torque)
        expected = sim.link_acceleration(tau, link_torque)
        assert np.array_equal(ddq, expected)
        assert np.array_equal(forces, sim.plants.chain.specific_forces(sim.q, sim.dq, expected))
    env.close()
