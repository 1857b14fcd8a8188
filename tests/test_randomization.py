"""Domain randomization: each arm draws its plant at every reset from its own plant stream."""

from __future__ import annotations

import pickle

import gymnasium as gym
import numpy as np
import pybullet as p
import pytest

from elastic_gym.envs.config import PlantRange
from elastic_gym.envs.randomization import draw

TWO_LINK = "elastic_gym/TwoLinkElastic-v0"
RANGES = {
    "plant_scaling.link_mass": {"low": 0.7, "high": 1.3},
    "plant_scaling.stiffness": {"low": 0.8, "high": 1.25, "log": True},
    "unmodelled_friction.viscous": {"low": 0.0, "high": 0.01},
    "encoder.noise_std": {"low": 1e-5, "high": 1e-4},
    "accelerometer.bias_std": {"low": 0.0, "high": 0.05},
    "sensor_delay": {"low": 0, "high": 2},
    "actuator_delay": {"low": 0, "high": 2},
    "payload.mass": {"low": 0.0, "high": 1.0},
}


def _fixed_kwargs(plant: dict) -> dict:
    """The kwargs that give a plant with the drawn values of ``info["plant"]``."""
    return {
        "plant_scaling": {
            "link_mass": plant["plant_scaling.link_mass"],
            "stiffness": plant["plant_scaling.stiffness"],
        },
        "unmodelled_friction": {"viscous": plant["unmodelled_friction.viscous"]},
        "encoder": {"noise_std": plant["encoder.noise_std"]},
        "accelerometer": {"bias_std": plant["accelerometer.bias_std"]},
        "sensor_delay": int(plant["sensor_delay"]),
        "actuator_delay": int(plant["actuator_delay"]),
        "payload": {"mass": plant["payload.mass"]},
    }


def _run(env, actions, seed):
    out = [env.reset(seed=seed)]
    for action in actions:
        obs, reward, terminated, truncated, info = env.step(action)
        out.append((obs, reward, info["true_state"]))
    return out


def _same(a, b) -> bool:
    if isinstance(a, dict):
        return all(_same(a[k], b[k]) for k in a if k != "plant")
    if isinstance(a, (tuple, list)):
        return all(_same(x, y) for x, y in zip(a, b, strict=True))
    return np.array_equal(a, b)


def test_a_randomized_plant_is_the_env_made_with_the_drawn_values():
    env = gym.make(TWO_LINK, randomize=RANGES)
    actions = 3.0 * np.random.default_rng(0).uniform(-1, 1, (40, 2))
    for seed in (3, 4):
        _, info = env.reset(seed=seed)
        drawn = info["plant"]
        for path, spec in RANGES.items():
            assert spec["low"] <= drawn[path] <= spec["high"], path
        fixed = gym.make(TWO_LINK, **_fixed_kwargs(drawn))
        got, expected = _run(env, actions, seed), _run(fixed, actions, seed)
        assert _same(got[1:], expected[1:])
        sim, masses = env.unwrapped.sim, []
        for s in (sim, fixed.unwrapped.sim):
            masses.append(
                [p.getDynamicsInfo(s.bodies[0], j, physicsClientId=s.client)[0] for j in range(3)]
            )
        assert masses[0] == masses[1]


def test_same_seed_same_draws_and_every_reset_draws_anew():
    env = gym.make(TWO_LINK, randomize=RANGES)
    first = env.reset(seed=7)[1]["plant"]
    again = env.reset(seed=7)[1]["plant"]
    following = env.reset()[1]["plant"]
    for path in RANGES:
        assert first[path] == again[path]
    assert first["plant_scaling.link_mass"] != following["plant_scaling.link_mass"]


def test_randomization_does_not_change_the_task_draws():
    plain, randomized = gym.make(TWO_LINK), gym.make(TWO_LINK, randomize=RANGES)
    for seed in (0, 1):
        a, b = plain.reset(seed=seed)[1], randomized.reset(seed=seed)[1]
        assert np.array_equal(a["true_state"]["q"], b["true_state"]["q"])
        assert _same(a["reference"], b["reference"])
    for _ in range(5):
        a = plain.step(np.zeros(2))[4]
        b = randomized.step(np.zeros(2))[4]
        assert _same(a["reference"], b["reference"])


def test_uniform_and_log_uniform_draws():
    rng = np.random.default_rng(0)
    ranges = {
        "plant_scaling.link_mass": PlantRange(low=0.5, high=2.0),
        "plant_scaling.stiffness": PlantRange(low=0.1, high=10.0, log=True),
        "sensor_delay": PlantRange(low=1, high=3),
    }
    samples = [draw(ranges, rng) for _ in range(4000)]
    mass = np.array([s["plant_scaling.link_mass"] for s in samples])
    stiffness = np.log10([s["plant_scaling.stiffness"] for s in samples])
    delays = np.array([s["sensor_delay"] for s in samples])
    sigma = 1.0 / np.sqrt(12 * len(samples))  # of the mean of a unit uniform
    assert abs((mass.mean() - 0.5) / 1.5 - 0.5) < 4 * sigma
    assert abs((stiffness.mean() + 1.0) / 2.0 - 0.5) < 4 * sigma  # log10 x uniform in [-1, 1]
    assert set(delays) == {1, 2, 3}
    assert mass.min() >= 0.5 and mass.max() <= 2.0


def test_a_range_with_a_probability_draws_at_that_share_of_the_resets():
    """u ~ U[0, 1) < p draws from the range, else the path takes ``otherwise`` (default
    low); the env's plant and info["plant"] hold the value in force at every reset."""
    rng = np.random.default_rng(3)
    ranges = {
        "plant_scaling.link_mass": PlantRange(low=1.2, high=1.4, probability=0.3),
        "sensor_delay": PlantRange(low=1, high=2, probability=0.25, otherwise=0),
    }
    samples = [draw(ranges, rng) for _ in range(4000)]
    mass = np.array([s["plant_scaling.link_mass"] for s in samples])
    delays = np.array([s["sensor_delay"] for s in samples])
    drawn = mass != 1.2
    sigma = np.sqrt(0.3 * 0.7 / len(samples))  # of a share p
    assert abs(drawn.mean() - 0.3) < 4 * sigma
    assert mass[drawn].min() > 1.2 and mass[drawn].max() <= 1.4
    assert abs((delays > 0).mean() - 0.25) < 4 * np.sqrt(0.25 * 0.75 / len(samples))
    assert set(delays) == {0, 1, 2}
    assert all(isinstance(s["sensor_delay"], int) for s in samples)
    randomize = {"sensor_delay": {"low": 2, "high": 2, "probability": 0.5, "otherwise": 0}}
    env = gym.make(TWO_LINK, randomize=randomize, encoder={"noise_std": 0.0})
    seen = set()
    for seed in range(12):
        _, info = env.reset(seed=seed)
        delay = info["plant"]["sensor_delay"]
        seen.add(delay)
        alone = gym.make(TWO_LINK, sensor_delay=int(delay), encoder={"noise_std": 0.0})
        assert _same(_run(env, [np.ones(2)] * 4, seed), _run(alone, [np.ones(2)] * 4, seed))
    assert seen == {0.0, 2.0}


def test_vector_env_info_has_a_leading_arm_axis_and_pickles():
    envs = gym.make_vec(TWO_LINK, 3, vectorization_mode="vector_entry_point", randomize=RANGES)
    _, info = envs.reset(seed=2)
    assert info["plant"]["plant_scaling.link_mass"].shape == (3,)
    assert len(set(info["plant"]["plant_scaling.link_mass"])) == 3
    for _ in range(3):
        envs.step(np.zeros((3, 2)))
    clone = pickle.loads(pickle.dumps(envs.unwrapped))
    for _ in range(10):
        a = envs.step(np.ones((3, 2)))
        b = clone.step(np.ones((3, 2)))
        assert _same(a[0], b[0]) and np.array_equal(a[1], b[1])
        assert _same(a[4]["plant"], b[4]["plant"])
    _, info_a = envs.reset()
    _, info_b = clone.reset()
    assert _same(info_a["plant"], info_b["plant"])  # the plant streams continue alike


@pytest.mark.parametrize(
    ("randomize", "match"),
    [
        (
            {"plant_scaling.mass": {"low": 1, "high": 2}},
            "unknown parameter path 'plant_scaling.mass'",
        ),
        (
            {"sensor_delay": {"low": 2, "high": 1}},
            r"randomize\.sensor_delay: low \(2\) must be <= high",
        ),
        (
            {"plant_scaling.link_mass": {"low": 0.0, "high": 1.0, "log": True}},
            "log-uniform range needs low > 0",
        ),
        (
            {"plant_scaling.link_mass": {"low": 1.0}},
            r"randomize\.plant_scaling\.link_mass\.high: Field required",
        ),
        ({"sensor_delay": {"low": 0, "high": 1.5}}, "sensor_delay takes integers"),
        (
            {"plant_scaling.link_mass": {"low": 0.0, "high": 1.0}},
            r"randomize\['plant_scaling.link_mass'\]\.low: plant_scaling\.link_mass: must be",
        ),
        (
            {"sensor_delay": {"low": 0, "high": 5000}},
            r"randomize\['sensor_delay'\]\.high: sensor_delay of 5000 control periods is more than",
        ),
        (
            {"unmodelled_friction.coulomb": {"low": 0.0, "high": 1.0}},
            r"\.high: unmodelled_friction: coulomb must stay below 1",
        ),
        (
            {"plant_scaling.stiffness": {"low": 1.0, "high": 100.0}},
            "too coarse for the stiffest joint mode",
        ),
        (
            {"sensor_delay": {"low": 0, "high": 1, "probability": 0.0}},
            r"randomize\.sensor_delay\.probability: Input should be greater than 0",
        ),
        (
            {"sensor_delay": {"low": 0, "high": 1, "otherwise": 0}},
            "otherwise is used only with a probability below 1",
        ),
        (
            {"sensor_delay": {"low": 0, "high": 1, "probability": 0.5, "otherwise": 0.5}},
            "sensor_delay takes integers",
        ),
        (
            {"sensor_delay": {"low": 0, "high": 1, "probability": 0.5, "otherwise": 5000}},
            r"randomize\['sensor_delay'\]\.otherwise: sensor_delay of 5000 control periods",
        ),
        (
            {
                "plant_scaling.stiffness": {
                    "low": 1.0,
                    "high": 1.1,
                    "probability": 0.1,
                    "otherwise": 100.0,
                }
            },
            "too coarse for the stiffest joint mode",
        ),
        (
            {"payload.mass": {"low": 0.0, "high": 1e4}},
            r"\.high: payload\.mass: Input should be less than or equal to 1000",
        ),
    ],
)
def test_bad_ranges_are_refused_at_creation(randomize, match):
    with pytest.raises(ValueError, match=match):
        gym.make(TWO_LINK, randomize=randomize)


def test_a_bad_per_arm_range_names_its_arm():
    with pytest.raises(ValueError, match=r"per_arm\[1\]\.randomize\['sensor_delay'\]\.high"):
        gym.make_vec(
            TWO_LINK,
            2,
            vectorization_mode="vector_entry_point",
            per_arm=[{}, {"randomize": {"sensor_delay": {"low": 0, "high": 5000}}}],
        )
