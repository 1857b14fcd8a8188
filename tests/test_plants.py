"""Per-arm plants: arm i of a heterogeneous batch is bit for bit the single env made with
the shared kwargs deep-merged with ``per_arm[i]`` (observations, rewards, terminations,
truth), across resets, for every env id."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pybullet as p
import pytest
from helpers import arm_row, fast_lane, flat

import elastic_gym
from elastic_gym.envs.arm_config import deep_merge
from elastic_gym.envs.sensors import AccelerometerConfig

ELASTIC_ARMS = [
    {},
    {
        "plant_scaling": {"link_mass": 1.3, "damping": 2.0},
        "unmodelled_friction": {"coulomb": 0.01, "viscous": 0.002},
        "encoder": {"noise_std": 1e-4},
    },
    {
        "plant_scaling": {"link_inertia": 0.8, "motor_inertia": 1.2, "stiffness": 0.9},
        "accelerometer": {"cutoff_hz": 50.0, "noise_density": 3e-3, "bias_std": 0.0},
        "sensor_delay": 2,
    },
]
RIGID_ARMS = [
    {"encoder": {"resolution": 0.0}},
    {"plant_scaling": {"link_mass": [1.3, 0.7]}, "unmodelled_friction": {"viscous": 0.01}},
    {"plant_scaling": {"link_inertia": 1.5}, "encoder": {"noise_std": 1e-3}, "sensor_delay": 1},
]
PER_ARM = {
    "elastic_gym/TwoLinkElastic-v0": ELASTIC_ARMS,
    "elastic_gym/KR15Elastic-v0": ELASTIC_ARMS,
    "elastic_gym/IiwaElastic-v0": ELASTIC_ARMS,
    "elastic_gym/TwoLinkRigid-v0": RIGID_ARMS,
    "elastic_gym/TwoLinkRigidFriction-v0": [
        *RIGID_ARMS[:2],
        {"plant_scaling": {"friction": 1.5}, "sensor_delay": 1},
    ],
}
SHARED = {"episode_time": 0.03, "max_velocity": 5.0}


def assert_arms_equal_single_envs(env_id, shared, per_arm, steps=70, seed=5, scale=0.05):
    """Step a vector env with ``per_arm`` and one single env per arm with the same actions
    (autoresets included); every output must be identical."""
    n_arms = len(per_arm)
    envs = gym.make_vec(
        env_id, n_arms, vectorization_mode="vector_entry_point", per_arm=per_arm, **shared
    )
    singles = []
    for options in per_arm:
        kwargs = dict(shared)
        for key, value in options.items():
            kwargs[key] = deep_merge(shared[key], value) if key in shared else value
        singles.append(gym.make(env_id, **kwargs))
    obs, info = envs.reset(seed=seed)
    for i, env in enumerate(singles):
        single_obs, single_info = env.reset(seed=seed + i)
        assert np.array_equal(flat(arm_row(obs, i)), flat(single_obs))
        assert np.array_equal(flat(arm_row(info, i)), flat(single_info))
    rng = np.random.default_rng(1)
    limit = envs.unwrapped.torque_limit
    ended = np.zeros(n_arms, dtype=bool)
    resets = 0
    for _ in range(steps):
        actions = scale * limit * rng.uniform(-1, 1, (n_arms, len(limit)))
        obs, reward, terminated, truncated, info = envs.step(actions)
        for i, env in enumerate(singles):
            if ended[i]:
                single_obs, single_info = env.reset()
                expected = (single_obs, 0.0, False, False, single_info)
                resets += 1
            else:
                expected = env.step(actions[i])
            got = (arm_row(obs, i), reward[i], terminated[i], truncated[i], arm_row(info, i))
            for a, b in zip(got, expected, strict=True):
                assert np.array_equal(flat(a), flat(b)), (env_id, i)
        ended = terminated | truncated
    assert resets >= n_arms  # every arm went through a reset
    envs.close()
    for env in singles:
        env.close()
    return info


@pytest.mark.parametrize("env_id", fast_lane(elastic_gym.ENV_IDS, "elastic_gym/TwoLinkElastic-v0"))
def test_heterogeneous_arms_equal_their_single_envs_bit_for_bit(env_id):
    assert_arms_equal_single_envs(env_id, SHARED, PER_ARM[env_id])


def _features(env_id: str) -> tuple[dict, list[dict]]:
    """Shared randomization and per-arm plant features (pulses, payload, delays)."""
    limit = np.asarray(gym.spec(env_id).make().unwrapped.torque_limit)
    random_pulses = {
        "random": {
            "count": 2,
            "window": [0.0, 0.02],
            "duration": {"low": 0.002, "high": 0.006},
            "amplitude": {"low": 0.005, "high": 0.02},
        }
    }
    given = {
        "times": [0.004, 0.01],
        "durations": [0.003, 0.002],
        "amplitudes": [0.01 * limit, -0.01 * limit[0]],
    }
    shared = {
        **SHARED,
        "randomize": {
            "plant_scaling.link_mass": {"low": 0.8, "high": 1.2},
            "sensor_delay": {"low": 0, "high": 2},
            "encoder.noise_std": {"low": 0.0, "high": 1e-4},
        },
    }
    per_arm = [
        {"torque_pulses": random_pulses},
        {
            "torque_pulses": given,
            "payload": {"mass": 0.5, "change": {"time": 0.015, "mass": 0.1}},
            "actuator_delay": 2,
        },
        {
            "torque_pulses": random_pulses,
            "randomize": {
                "plant_scaling.link_mass": {"low": 1.0, "high": 1.5, "log": True},
                "payload.mass": {"low": 0.0, "high": 0.3},
                "actuator_delay": {"low": 0, "high": 3},
            },
        },
    ]
    return shared, per_arm


@pytest.mark.parametrize("env_id", fast_lane(elastic_gym.ENV_IDS, "elastic_gym/IiwaElastic-v0"))
def test_randomized_arms_with_plant_features_equal_their_single_envs(env_id):
    shared, per_arm = _features(env_id)
    info = assert_arms_equal_single_envs(env_id, shared, per_arm, steps=80)
    plant = info["plant"]
    assert plant["actuator_delay"][1] == 2
    assert np.isfinite(plant["plant_scaling.link_mass"]).all()
    assert plant["torque_pulses.amplitudes"].shape == (3, 2, len(plant["torque_pulse"][0]))


def test_per_arm_plants_differ_in_pybullet_and_in_the_chain():
    envs = gym.make_vec(
        "elastic_gym/KR15Elastic-v0",
        2,
        vectorization_mode="vector_entry_point",
        per_arm=[{}, {"plant_scaling": {"link_mass": 1.5, "motor_inertia": 0.8}}],
    )
    sim = envs.unwrapped.batch.sim
    link = sim.joint_indices[1]
    masses = [p.getDynamicsInfo(b, link, physicsClientId=sim.client)[0] for b in sim.bodies]
    assert masses[1] == 1.5 * masses[0]
    q = np.full((2, 3), 0.4)
    M, _ = sim.plants.chain.mass_and_bias(q, np.zeros((2, 3)))
    for arm in range(2):
        assert np.allclose(M[arm], sim.plants.models[arm].mass_matrix(q[arm]), rtol=1e-12)
    assert not np.allclose(M[0], M[1])
    assert np.array_equal(sim.plants.S[1], 0.8 * sim.plants.S[0])
    envs.close()


@pytest.mark.parametrize(
    ("per_arm", "match"),
    [
        ([{}], "exactly 2 mappings"),
        ({"plant_scaling": {}}, "per_arm: Input should be a valid list"),
        ([{}, {"stiffness": 1.0}], r"per_arm\[1\]\.stiffness: unexpected field"),
        (
            [{}, {"plant_scaling": {"link_mass": -1}}],
            r"per_arm\[1\]\.plant_scaling\.link_mass: must be",
        ),
        (
            [{}, {"sensor_delay": -1}],
            r"per_arm\[1\]\.sensor_delay: Input should be greater than or equal to 0",
        ),
        ([{"payload": {"mass": -2}}, {}], r"per_arm\[0\]\.payload\.mass"),
    ],
)
def test_bad_per_arm_is_refused_with_its_path(per_arm, match):
    with pytest.raises(ValueError, match=match):
        gym.make_vec(
            "elastic_gym/TwoLinkElastic-v0",
            2,
            vectorization_mode="vector_entry_point",
            per_arm=per_arm,
        )


def test_per_arm_mappings_are_deep_merged_into_the_shared_kwargs():
    envs = gym.make_vec(
        "elastic_gym/TwoLinkElastic-v0",
        2,
        vectorization_mode="vector_entry_point",
        accelerometer="ideal",
        plant_scaling={"link_mass": 1.2, "stiffness": 0.9},
        per_arm=[{"plant_scaling": {"stiffness": 1.1}}, {"accelerometer": {"noise_density": 3e-3}}],
    )
    batch = envs.unwrapped.batch
    scaling = [s.scaling for s in batch.settings]
    assert (scaling[0].link_mass, scaling[0].stiffness) == (1.2, 1.1)
    assert (scaling[1].link_mass, scaling[1].stiffness) == (1.2, 0.9)
    accelerometers = [s.accelerometer for s in batch.settings]
    assert accelerometers[0] == AccelerometerConfig.ideal()
    assert accelerometers[1] == AccelerometerConfig.ideal().model_copy(
        update={"noise_density": 3e-3}
    )
    envs.close()


def test_a_stacked_chain_computes_each_row_as_its_own_chain_bit_for_bit():
    from elastic_gym.model import RobotModel, SerialChain
    from elastic_gym.robots.catalog import get_robot

    spec = get_robot("kr15_elastic")
    models = [RobotModel(spec, {"link_mass": m, "link_inertia": 2.0 - m}) for m in (0.7, 1.0, 1.4)]
    chains = [m.chain for m in models]
    stacked = SerialChain.stack(chains)
    rng = np.random.default_rng(0)
    q, dq, tau = (rng.uniform(-1, 1, (3, 3)) for _ in range(3))
    M, h = stacked.mass_and_bias(q, dq)
    ddq = stacked.forward_dynamics(q, dq, tau, np.stack([0.1 * np.eye(3) * k for k in range(3)]))
    for k, chain in enumerate(chains):
        Mk, hk = chain.mass_and_bias(q[k : k + 1], dq[k : k + 1])
        assert np.array_equal(M[k], Mk[0]) and np.array_equal(h[k], hk[0])
        alone = chain.forward_dynamics(
            q[k : k + 1], dq[k : k + 1], tau[k : k + 1], 0.1 * k * np.eye(3)
        )
        assert np.array_equal(ddq[k], alone[0])
        assert np.allclose(Mk[0], models[k].mass_matrix(q[k]), rtol=1e-12)
    assert not np.allclose(M[0], M[2])
    subset = stacked.select(np.array([2, 0]))
    assert np.array_equal(subset.gravity(q[[2, 0]]), stacked.gravity(q)[[2, 0]])
    with pytest.raises(ValueError, match="stacked for 3 arms got 2 rows"):
        stacked.gravity(q[:2])
