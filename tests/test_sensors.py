"""Sensor models: accelerometer readings are the specific force of the sensor point; noise,
bias, saturation, filtering and encoder quantization behave as configured."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pinocchio as pin
import pytest
from helpers import ELASTIC_IDS, make_noise_free

from elastic_gym.envs.sensors import AccelerometerArray, AccelerometerConfig, Encoder, GaussianNoise


def _record(env_id: str, steps: int = 300):
    """Sensor-point poses from PyBullet link states, joint positions and readings."""
    env = make_noise_free(env_id, task="excitation", task_options={"amplitude": 0.0})
    obs, info = env.reset(seed=3)
    u = env.unwrapped
    mounts = u.model.accelerometers
    poses, joints, readings = [], [], []
    for k in range(steps):
        frame = []
        for m in mounts:
            p, R = u.sim.link_pose(m.link)
            frame.append((p + R @ np.asarray(m.position), R @ pin.rpy.rpyToMatrix(*m.rpy)))
        poses.append(frame)
        joints.append(u.sim.q[0].copy())
        readings.append(obs["acceleration"])
        tau = 0.01 * u.torque_limit * np.sin(np.arange(u.n_joints) + 10.0 * k * u.control_dt)
        obs, *_ = env.step(tau)
    env.close()
    return u, poses, joints, np.array(readings)


@pytest.mark.parametrize("env_id", ELASTIC_IDS)
def test_accelerometer_equals_finite_difference_of_sensor_position(env_id):
    u, poses, joints, readings = _record(env_id)
    g = np.asarray(u.robot.gravity)
    n_sensors = u.model.n_sensors

    def specific_force(points, rotation, h):
        accel = (points[2] - 2.0 * points[1] + points[0]) / h**2
        return rotation.T @ (accel - g)

    exact_err, pybullet_err, dynamic = 0.0, 0.0, 0.0
    dt = u.control_dt
    for k in range(3, len(joints) - 3):
        # (a) sensor points from PyBullet's joint positions (double precision), 1 ms stencil
        placements = [u.model.sensor_placements(joints[j]) for j in (k - 1, k, k + 1)]
        # (b) sensor points from PyBullet's own link states (single-precision poses), 3 ms stencil
        for i in range(n_sensors):
            reading = readings[k][3 * i : 3 * i + 3]
            f_exact = specific_force(
                [p[i].translation for p in placements], placements[1][i].rotation, dt
            )
            f_pybullet = specific_force(
                [poses[j][i][0] for j in (k - 3, k, k + 3)], poses[k][i][1], 3 * dt
            )
            exact_err = max(exact_err, np.abs(f_exact - reading).max())
            pybullet_err = max(pybullet_err, np.abs(f_pybullet - reading).max())
            dynamic = max(dynamic, np.abs(reading - poses[k][i][1].T @ (-g)).max())
    assert dynamic > 0.5  # m/s^2 of real motion on top of gravity
    assert exact_err < 0.01 * dynamic
    assert pybullet_err < 0.06 * dynamic  # limited by PyBullet's float32 link poses


@pytest.mark.parametrize("env_id", ELASTIC_IDS)
def test_accelerometer_at_rest_reads_g_upwards(env_id):
    env = make_noise_free(env_id, task="excitation", task_options={"amplitude": 0.0})
    obs, info = env.reset(seed=1)
    model = env.unwrapped.model
    for i, placement in enumerate(model.sensor_placements(info["true_state"]["q"])):
        world = placement.rotation @ obs["acceleration"][3 * i : 3 * i + 3]
        assert np.allclose(world, [0.0, 0.0, 9.81], atol=1e-9)
    env.close()


def test_accelerometer_noise_bias_saturation_and_filter():
    rng = np.random.default_rng(0)
    dt = 1e-3
    config = AccelerometerConfig(noise_density=2e-3, bias_std=0.05, range=20.0)
    rngs = [np.random.default_rng(1), np.random.default_rng(2)]  # two arms
    arms = np.arange(2)
    array = AccelerometerArray(config, n_sensors=2, sample_time=dt, n_arms=2)
    array.reset(arms, rngs)
    assert not np.array_equal(array.bias[0], array.bias[1])  # one bias per arm
    truth = np.array([[0.0, 0.0, 9.81, 1.0, -2.0, 30.0]] * 2)
    samples = np.array([array.measure(truth, rngs, arms) for _ in range(20000)])  # (T, arm, axis)
    assert np.allclose(samples[:, :, :5].std(axis=0), 2e-3 * np.sqrt(0.5 / dt), rtol=0.05)
    assert np.allclose(samples[:, :, :5].mean(axis=0) - truth[:, :5], array.bias[:, :5], atol=2e-3)
    assert np.all(samples[:, :, 5] == 20.0)  # saturated at the range
    # first-order low-pass: a step settles with time constant 1 / (2 pi f_c)
    filtered = AccelerometerConfig(noise_density=0, bias_std=0, cutoff_hz=10.0)
    lowpass = AccelerometerArray(filtered, 1, dt)
    lowpass.reset(arms[:1], [rng])
    lowpass.measure(np.zeros((1, 3)), [rng], arms[:1])
    tau = 1.0 / (2 * np.pi * 10.0)
    response = [
        lowpass.measure(np.ones((1, 3)), [rng], arms[:1])[0, 0] for _ in range(round(tau / dt))
    ]
    assert response[-1] == pytest.approx(1 - np.exp(-1), abs=0.01)


def test_encoder_quantization_and_noise():
    rng = np.random.default_rng(0)
    one = np.arange(1)
    encoder = Encoder(resolution=7e-4, noise_std=0.0, n_joints=1000)
    x = rng.uniform(-3, 3, size=(1, 1000))
    y = encoder.measure(x, [rng], one)
    assert np.abs(y - x).max() <= 3.5e-4 + 1e-15
    assert np.allclose(np.round(y / 7e-4) * 7e-4, y)
    noisy_encoder = Encoder(resolution=0.0, noise_std=0.01, n_joints=200)
    noisy = np.array([noisy_encoder.measure(np.zeros((1, 200)), [rng], one) for _ in range(100)])
    assert noisy.std() == pytest.approx(0.01, rel=0.05)


def test_noise_of_an_arm_depends_only_on_its_generator_and_readings():
    """Block draws: arm 1 of a batch whose arm 0 reads at other times and resets gets the
    samples of an arm alone with the same generator, and within a block they are the
    generator's own normal sequence."""
    steps = 2 * GaussianNoise.BLOCK + 7
    alone, rng = GaussianNoise(1, 3), np.random.default_rng(5)
    solo = np.array([alone.draw(np.arange(1), [rng])[0] for _ in range(steps)])
    assert np.array_equal(
        solo[: GaussianNoise.BLOCK].ravel(),
        np.random.default_rng(5).standard_normal(3 * GaussianNoise.BLOCK),
    )
    batch = GaussianNoise(2, 3)
    rngs = [np.random.default_rng(9), np.random.default_rng(5)]
    both, second = np.arange(2), np.array([1])
    shared = []
    for t in range(steps):
        if t % 3 == 0:
            shared.append(batch.draw(both, rngs)[1])
        else:
            shared.append(batch.draw(second, rngs[1:])[0])
        if t == 100:
            batch.restart(np.array([0]))
            rngs[0] = np.random.default_rng(11)
    assert np.array_equal(np.array(shared), solo)


def test_env_sensor_defaults_follow_the_papers():
    env = gym.make("elastic_gym/TwoLinkRigid-v0")
    assert env.unwrapped.encoder.resolution == pytest.approx(7e-4)  # Cristofaro & De Luca
    env.close()
    env = gym.make("elastic_gym/TwoLinkRigidFriction-v0")
    assert env.unwrapped.encoder.noise_std == pytest.approx(0.01)  # Solsona & Puleston
    env.close()


def test_accelerometer_placement_can_be_configured():
    mounts = [{"link": "link2", "position": [0.2, 0.0, 0.0]}]
    env = make_noise_free("elastic_gym/TwoLinkElastic-v0", accelerometers=mounts)
    obs, _ = env.reset(seed=0)
    assert obs["acceleration"].shape == (3,)
    env.close()


def test_sensor_delay_shifts_the_measurements_not_the_reference():
    delayed = make_noise_free("elastic_gym/TwoLinkElastic-v0", sensor_delay=3)
    direct = make_noise_free("elastic_gym/TwoLinkElastic-v0")
    obs_d, _ = delayed.reset(seed=0)
    obs, _ = direct.reset(seed=0)
    history = [obs]
    assert np.array_equal(obs_d["motor_position"], obs["motor_position"])
    torque = np.array([5.0, -3.0])
    for _ in range(10):
        obs_d, *_ = delayed.step(torque)
        obs, *_ = direct.step(torque)
        history.append(obs)
        past = history[max(len(history) - 1 - 3, 0)]
        for key in ("motor_position", "acceleration"):
            assert np.array_equal(obs_d[key], past[key])
        assert np.array_equal(obs_d["reference"], obs["reference"])
    with pytest.raises(ValueError, match="sensor_delay"):
        make_noise_free("elastic_gym/TwoLinkElastic-v0", sensor_delay=-1)


def test_compiled_readings_of_every_arm_equal_the_numpy_path():
    """Measured with ``every_arm`` (one compiled call) or with an index array (numpy), the
    readings and the noise streams are the same bit for bit, NaN and saturation included."""
    from elastic_gym.envs.sensors import every_arm

    n_arms, steps = 3, GaussianNoise.BLOCK + 5
    config = AccelerometerConfig(noise_density=2e-3, bias_std=0.05, range=20.0, resolution=1e-3)
    fast, slow = (AccelerometerArray(config, 2, 1e-3, n_arms) for _ in range(2))
    enc_fast, enc_slow = (Encoder(7e-4, 1e-3, 2, n_arms) for _ in range(2))
    rngs_fast, rngs_slow = ([np.random.default_rng(s) for s in range(n_arms)] for _ in range(2))
    fast.reset(every_arm(n_arms), rngs_fast)
    slow.reset(np.arange(n_arms), rngs_slow)
    truth = np.random.default_rng(7).uniform(-30.0, 30.0, (steps, n_arms, 6))
    truth[3, 1, 2] = np.nan
    position = truth[..., :2] / 10.0
    for t in range(steps):
        a = fast.measure(truth[t], rngs_fast, every_arm(n_arms))
        b = slow.measure(truth[t], rngs_slow, np.arange(n_arms))
        assert np.array_equal(a, b, equal_nan=True)
        a = enc_fast.measure(position[t], rngs_fast, every_arm(n_arms))
        b = enc_slow.measure(position[t], rngs_slow, np.arange(n_arms))
        assert np.array_equal(a, b, equal_nan=True)
    assert np.any(np.abs(fast.measure(truth[0], rngs_fast, every_arm(n_arms))) == 20.0)
