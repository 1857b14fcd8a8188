"""Robustness: bit-for-bit determinism for every env id and wrapper, isolation of many envs
in one process, ``close()`` twice, pickling for ``SubprocVecEnv``, and the rows of the
bad-input reference (docs/bad-input.md) that no other test file covers (every row names
its test; the last test checks that those tests exist)."""

from __future__ import annotations

import copy
import functools
import re
from pathlib import Path

import cloudpickle
import gymnasium as gym
import numpy as np
import pytest
from helpers import fast_lane

import elastic_gym
from elastic_gym.observers import ObserverWrapper, TrueStateWrapper
from elastic_gym.observers.base import Observer
from elastic_gym.observers.registry import applicable_observers
from elastic_gym.robots.catalog import get_robot

EPISODE_STEPS = 200  # a "full episode" here: until the TimeLimit truncates it
HOLD_STEPS = 50  # the driver's random torque offset changes every 50 ms
OFFSET = 0.05  # ... within 5 % of the torque limits, around the static equilibrium
ROOT = Path(__file__).resolve().parent.parent


def wrapper_names(env_id: str) -> list[str]:
    """``raw``, ``true-state`` (TrueStateWrapper) and every applicable observer name."""
    elastic = get_robot(gym.spec(env_id).kwargs["robot"]).elastic
    return ["raw", "true-state", *applicable_observers(elastic)]


CASES = [(env_id, name) for env_id in elastic_gym.ENV_IDS for name in wrapper_names(env_id)]
FAST_CASES = fast_lane(  # model (2) on the EKF, model (1) on De Luca's observer, a rigid arm
    CASES,
    ("elastic_gym/KR15Elastic-v0", "ekf"),
    ("elastic_gym/TwoLinkElastic-v0", "deluca"),
    ("elastic_gym/TwoLinkRigidFriction-v0", "reduced-order"),
)


def make(env_id: str, wrapper: str = "raw", **kwargs) -> gym.Env:
    env = gym.make(env_id, max_episode_steps=EPISODE_STEPS, **kwargs)
    if wrapper == "raw":
        return env
    if wrapper == "true-state":
        return TrueStateWrapper(env)
    return ObserverWrapper(env, wrapper)


class Driver:
    """Steps an env with seeded torques: the static equilibrium of the reset state plus a
    random offset held for ``HOLD_STEPS``; records every (obs, reward, flags, info)."""

    def __init__(self, env: gym.Env, seed: int, action_seed: int | None = None) -> None:
        self.env = env
        obs, info = env.reset(seed=seed)
        self.rng = np.random.default_rng(seed if action_seed is None else action_seed)
        self.limit = env.unwrapped.torque_limit
        self.equilibrium = info["torque"]
        self.records: list[tuple] = [(obs, info)]
        self.done = False
        self.offset = np.zeros_like(self.limit)

    def driving(self, env: gym.Env) -> Driver:
        """A copy of this driver (history and random stream included) stepping ``env``."""
        other = copy.copy(self)
        other.env, other.rng, other.records = env, copy.deepcopy(self.rng), list(self.records)
        return other

    def step(self) -> None:
        if len(self.records) % HOLD_STEPS == 1:
            self.offset = OFFSET * self.limit * self.rng.uniform(-1.0, 1.0, self.limit.shape)
        record = self.env.step(self.equilibrium + self.offset)
        self.records.append(record)
        self.done = record[2] or record[3]


def episode(env: gym.Env, seed: int, steps: int | None = None, **kwargs) -> list[tuple]:
    """Records of one episode (until it ends, or ``steps`` steps); the env is closed."""
    driver = Driver(env, seed, **kwargs)
    while not driver.done and (steps is None or len(driver.records) <= steps):
        driver.step()
    env.close()
    return driver.records


def leaves(item, path: str = "") -> list[tuple]:
    """Every leaf of nested dicts/tuples as (path, exact content): arrays and numbers by
    dtype, shape and bytes (bit-for-bit), anything else by repr."""
    if isinstance(item, dict):
        return [leaf for key in sorted(item) for leaf in leaves(item[key], f"{path}/{key}")]
    if isinstance(item, (list, tuple)):
        return [leaf for i, value in enumerate(item) for leaf in leaves(value, f"{path}/{i}")]
    if isinstance(item, (np.ndarray, np.generic, int, float)) and not isinstance(item, bool):
        arr = np.asarray(item)
        return [(path, arr.dtype.str, arr.shape, arr.tobytes())]
    return [(path, repr(item))]


# ---------------------------------------------------------------------------- determinism
@pytest.mark.parametrize(("env_id", "wrapper"), FAST_CASES)
def test_same_seed_gives_a_bit_identical_full_episode(env_id, wrapper):
    first = episode(make(env_id, wrapper), seed=7)
    second = episode(make(env_id, wrapper), seed=7)
    assert len(first) == EPISODE_STEPS + 1 and first[-1][3] and not first[-1][2]  # truncated
    assert leaves(first) == leaves(second)


@pytest.mark.parametrize("env_id", elastic_gym.ENV_IDS)
def test_different_seeds_give_different_references_and_noise(env_id):
    a, b = episode(make(env_id), seed=0, steps=5), episode(make(env_id), seed=1, steps=5)
    assert not np.array_equal(a[0][0]["reference"], b[0][0]["reference"])
    # Same start, goal and torques: the readings differ through the sensor noise only.
    spec = gym.make(env_id).unwrapped.robot
    q = 0.5 * (np.asarray(spec.workspace_low) + np.asarray(spec.workspace_high))
    fixed = {"task": "regulation", "task_options": {"goal": q, "start": q}}
    a = episode(make(env_id, **fixed), seed=0, steps=20, action_seed=0)
    b = episode(make(env_id, **fixed), seed=1, steps=20, action_seed=0)
    base = make(env_id).unwrapped
    base.close()
    noisy = {
        "motor_position": base.encoder.noise_std > 0,
        "link_position": base.encoder.noise_std > 0,
        "acceleration": base.accelerometer_array.sample_std > 0,
    }
    for key in a[0][0].keys() - {"reference"}:
        readings = [np.array([r[0][key] for r in run]) for run in (a, b)]
        assert np.array_equal(*readings) != noisy[key], key
    assert np.array_equal(a[-1][0]["reference"], b[-1][0]["reference"])


# ---------------------------------------------------------------------------- isolation
@pytest.mark.slow
def test_32_envs_stepped_interleaved_match_each_env_alone():
    configs = CASES[:32]  # every id, raw env and wrappers with their observers
    steps = 50
    alone = [
        leaves(episode(make(*config), seed=i, steps=steps)) for i, config in enumerate(configs)
    ]
    drivers = [Driver(make(*config), seed=i) for i, config in enumerate(configs)]
    for _ in range(steps):
        for driver in drivers:
            driver.step()
    assert [leaves(d.records) for d in drivers] == alone
    for driver in drivers:
        driver.env.close()


def test_close_twice_and_closing_one_env_leaves_the_others_alone():
    env_id = "elastic_gym/TwoLinkElastic-v0"
    reference = leaves(episode(make(env_id), seed=3))
    driver = Driver(make(env_id), seed=3)
    for _ in range(50):
        driver.step()
    other = make(env_id, "deluca")
    other.reset(seed=0)
    other.close()
    other.close()
    other.unwrapped.close()
    make("elastic_gym/KR15Elastic-v0").reset(seed=0)  # dropped unclosed: __del__ cleans up
    while not driver.done:
        driver.step()
    assert leaves(driver.records) == reference
    driver.env.close()
    driver.env.close()


# ---------------------------------------------------------------------------- pickling
def test_env_factories_survive_a_cloudpickle_round_trip():
    by_spec = functools.partial(gym.make, make("elastic_gym/KR15Elastic-v0", "deluca").spec)
    by_lambda = lambda: ObserverWrapper(gym.make("elastic_gym/TwoLinkRigid-v0"), "reduced-order")  # noqa: E731
    for factory in (by_spec, by_lambda):
        clone = cloudpickle.loads(cloudpickle.dumps(factory))
        assert leaves(episode(clone(), seed=5, steps=50)) == leaves(
            episode(factory(), seed=5, steps=50)
        )


@pytest.mark.slow
def test_subproc_vec_env_with_env_factories_matches_envs_in_this_process():
    from stable_baselines3.common.vec_env import SubprocVecEnv

    spec = make("elastic_gym/TwoLinkElastic-v0", "deluca").spec  # rebuilds the wrapper too
    local = [gym.make(spec) for _ in range(2)]
    vec = SubprocVecEnv([functools.partial(gym.make, spec)] * 2)
    vec.seed(11)
    remote = vec.reset()
    obs = [env.reset(seed=11 + i)[0] for i, env in enumerate(local)]
    rng = np.random.default_rng(0)
    limit = local[0].unwrapped.torque_limit
    for _ in range(30):
        for key in obs[0]:
            assert np.array_equal(remote[key], np.stack([o[key] for o in obs])), key
        actions = 0.05 * limit * rng.uniform(-1.0, 1.0, (2, len(limit)))
        remote, *_ = vec.step(actions)
        obs = [env.step(a)[0] for env, a in zip(local, actions, strict=True)]
    vec.close()


@pytest.mark.parametrize(("env_id", "wrapper"), FAST_CASES)
def test_a_pickled_live_env_is_an_independent_copy(env_id, wrapper):
    """A live env, observer included, pickles its constructor arguments and episode state,
    not the PyBullet client: the clone continues bit for bit like an untouched twin, and
    stepping it leaves the original alone (so vector envs may also be given live envs)."""
    twin, original = Driver(make(env_id, wrapper), seed=0), Driver(make(env_id, wrapper), seed=0)
    for _ in range(10):
        twin.step()
        original.step()
    clone = original.driving(cloudpickle.loads(cloudpickle.dumps(original.env)))
    for driver in (clone, original, twin):
        for _ in range(10):
            driver.step()
        driver.env.close()
    assert leaves(original.records) == leaves(twin.records)
    assert leaves(clone.records) == leaves(twin.records)


# ---------------------------------------------------------------------------- bad input
def test_step_before_reset_through_gym_make():
    env = gym.make("elastic_gym/TwoLinkElastic-v0")
    with pytest.raises(gym.error.ResetNeeded, match="reset"):
        env.step(np.zeros(2))
    env.close()


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"accelerometer": {"noise_density": -1e-3}}, "noise_density"),
        ({"accelerometer": {"bias_std": -0.1}}, "bias_std"),
        ({"accelerometer": {"cutoff_hz": 0.0}}, "cutoff_hz"),
        ({"encoder": {"noise_std": -0.01}}, "noise_std"),
    ],
)
def test_negative_or_zero_sensor_noise_parameters_are_refused(kwargs, match):
    with pytest.raises(ValueError, match=match):
        gym.make("elastic_gym/TwoLinkElastic-v0", **kwargs)


def test_physics_step_too_coarse_for_the_stiffest_joint():
    # iiwa wrist: omega_max ~ 600 rad/s, so 1 ms gives physics_dt * omega ~ 0.6 > 0.2
    with pytest.raises(ValueError, match=r"physics_dt=0\.001 too coarse"):
        gym.make("elastic_gym/IiwaElastic-v0", physics_dt=1e-3)


def test_unknown_observer_option_is_named():
    with pytest.raises(TypeError, match="gain"):
        ObserverWrapper(gym.make("elastic_gym/TwoLinkElastic-v0"), "deluca", gain=3.0)


class _DivergingObserver(Observer):
    """Returns NaN from the first update (stands for an estimate that blew up)."""

    def reset(self, obs, initial_estimate=None):
        return np.zeros(self.state_dim)

    def update(self, obs, torque, dt):
        return np.full(self.state_dim, np.nan)


def test_diverged_estimate_ends_the_episode_with_a_reason():
    env = gym.make("elastic_gym/TwoLinkElastic-v0")
    wrapped = ObserverWrapper(env, _DivergingObserver(env.unwrapped.model, 1e-3))
    obs, info = wrapped.reset(seed=0)
    obs, _, terminated, _, info = wrapped.step(info["torque"])
    assert terminated and info["termination_reason"] == "non-finite state estimate"
    assert np.all(np.isfinite(obs["state"]))  # the last finite estimate, not the NaN
    wrapped.close()


def test_singular_accelerometer_placement_is_flagged_by_the_observer():
    """One sensor on the joint-2 axis of the 2-link arm: q2'' moves the point along no
    direction (T_A's second column is zero, rank 1 < N = 2). The env accepts it (encoders
    and other observers still work); De Luca's eq. (11) reports it at every update and
    its damped least-squares inverse keeps the estimate bounded, but the unobservable
    q2'' is reconstructed as 0, so the link-2 velocity estimate degrades."""
    env_id = "elastic_gym/TwoLinkElastic-v0"
    on_axis = [{"link": "link2", "position": [0.0, 0.0, 0.0]}]
    errors = {}
    for label, kwargs in (("singular", {"accelerometers": on_axis}), ("default", {})):
        env = make(env_id, "deluca", **kwargs)
        records = episode(env, seed=2)
        assert not records[-1][2]  # a full episode: the env runs, nothing raises
        infos = [r[-1] for r in records]
        diagnostics = [info["observer_diagnostics"] for info in infos]
        if label == "singular":
            T, _ = env.unwrapped.model.accelerometer_maps(infos[-1]["true_state"]["q"], np.zeros(2))
            assert np.array_equal(T[:, 1], np.zeros(3)) and np.linalg.matrix_rank(T) == 1
            assert all(
                d["near_singular"] and d["sigma_min_TA"] == 0.0 and d["cond_TA"] == np.inf
                for d in diagnostics
            )
        else:
            assert not any(d["near_singular"] for d in diagnostics)
        error = np.array([info["estimation_error"] for info in infos])
        assert np.all(np.isfinite(error))
        errors[label] = np.abs(error[:, 7]).max()  # link-2 velocity (theta, q, dtheta, dq)
    assert errors["singular"] > 5.0 * errors["default"]


def test_every_row_of_the_bad_input_reference_names_an_existing_test():
    text = (ROOT / "docs" / "bad-input.md").read_text()
    rows = [line for line in text.splitlines() if line.startswith("| ")][1:]  # no header
    assert len(rows) >= 15
    for row in rows:
        cell = row.rstrip(" |").rsplit("|", 1)[1]
        references = re.findall(r"(test_\w+\.py)::(test_\w+)", cell)
        assert references, f"bad-input row without a test: {row}"
        for file, name in references:
            assert f"def {name}(" in (ROOT / "tests" / file).read_text(), (file, name)
