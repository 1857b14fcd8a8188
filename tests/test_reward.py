"""The tracking reward ranks controllers like their tracking RMS, is bounded, and never
makes ending an episode pay."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from elastic_gym.controllers import make_controller, public_info
from elastic_gym.envs.reward import TERM_NAMES, RewardConfig, reward_terms, total_reward
from elastic_gym.observers import ObserverWrapper

DT = 1e-3
LIMIT = np.array([120.0, 60.0])


def _zeros(n_arms: int = 1) -> np.ndarray:
    return np.zeros((n_arms, 2))


def _track(error: float, config: RewardConfig | None = None) -> float:
    e = np.full((1, 2), error)
    terms = reward_terms(
        config or RewardConfig(), DT, e, _zeros(), _zeros(), _zeros(), LIMIT, _zeros()
    )
    return float(terms["track"][0])


def _episode(controller: str | None, options: dict, source: str, seed: int, steps: int):
    env = ObserverWrapper(
        gym.make("elastic_gym/TwoLinkElastic-v0", max_episode_steps=steps), source
    )
    base = env.unwrapped
    law = (
        None
        if controller is None
        else make_controller(controller, base.model, base.control_dt, **options)
    )
    obs, info = env.reset(seed=seed)
    if law is not None:
        law.reset(obs, public_info(info))
    total, errors, done = 0.0, [], False
    while not done:
        torque = np.zeros(2) if law is None else law(obs, public_info(info))
        obs, reward, terminated, truncated, info = env.step(torque)
        total += reward
        errors.append(info["true_state"]["q"] - info["reference"]["q"])
        done = terminated or truncated
    env.close()
    return total, float(np.sqrt(np.mean(np.square(errors))))


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1])
def test_returns_rank_controllers_like_their_tracking_rms(seed):
    """eq. (13) on the true state, motor PD on the motor encoders (the comparison's
    motor-only law), motor PD without the INVDYN feedforward at two bandwidths and zero
    torque on the same episode: higher return <=> lower tracking RMS, over errors from
    about 1e-5 to 1 rad."""
    laws = [
        ("feedforward-state-feedback", {}, "true"),
        ("motor-pd", {}, "finite-difference"),
        ("motor-pd", {"feedforward": False}, "true"),
        ("motor-pd", {"feedforward": False, "omega": 10.0}, "true"),
        (None, {}, "true"),
    ]
    results = [_episode(name, options, source, seed, steps=800) for name, options, source in laws]
    returns, rms = np.array(results).T
    assert rms.min() < 1e-4 and rms.max() > 0.3  # the range the ranking must cover
    assert list(np.argsort(-returns)) == list(np.argsort(rms))


def test_each_decade_of_precision_is_worth_the_same():
    """The tracking term is a bounded, smooth -log10|e|: every decade from 1e-5 to 1e-1
    rad adds about w_track / len(sigmas), and it decreases strictly with |e|."""
    config = RewardConfig()
    errors = np.logspace(-6, 0.5, 300)
    values = np.array([_track(e) for e in errors])
    assert np.all(np.diff(values) < 0)
    per_decade = DT * config.track / len(config.sigmas)
    for exponent in range(-5, -1):
        gain = _track(10.0**exponent) - _track(10.0 ** (exponent + 1))
        assert 0.8 * per_decade < gain < 1.25 * per_decade


def test_torque_cannot_outweigh_tracking():
    """Halving the error anywhere in 1e-5 .. 1e-1 rad is worth more than the whole range
    of the torque term (zero torque vs full torque on every joint)."""
    config = RewardConfig()
    full = reward_terms(config, DT, _zeros(), _zeros(), LIMIT[None], LIMIT[None], LIMIT, _zeros())[
        "torque"
    ][0]
    smallest_gain = min(_track(e) - _track(2 * e) for e in np.logspace(-5, -1, 200))
    assert -full < smallest_gain


def test_reward_is_bounded_and_termination_never_pays():
    """Every step pays 0 <= r <= dt * max_rate whatever the inputs, and the termination
    reward is negative: an episode that ends early gets less than any continuation."""
    config = RewardConfig(velocity=0.1, torsion=0.05)
    rng = np.random.default_rng(0)
    scale = 10.0 ** rng.uniform(-8, 3, size=(6, 500, 2))
    e, de, torsion = (scale[i] * rng.choice([-1, 1], size=(500, 2)) for i in range(3))
    tau, previous = (np.clip(scale[i] * rng.normal(size=(500, 2)), -LIMIT, LIMIT) for i in (3, 4))
    r = total_reward(config, DT, e, de, tau, previous, LIMIT, torsion)
    assert r.shape == (500,)
    assert np.all(r >= 0) and np.all(r <= DT * config.max_rate + 1e-15)
    perfect = total_reward(config, DT, _zeros(), _zeros(), _zeros(), _zeros(), LIMIT, _zeros())
    assert perfect[0] == pytest.approx(DT * config.max_rate)
    assert config.termination_reward < 0


def test_a_torque_step_costs_more_than_a_ramp():
    """The rate term penalizes jumps: one 10 N m step vs the same change over 10 periods."""
    config = RewardConfig()
    step = total_reward(
        config, DT, _zeros(), _zeros(), np.array([[10.0, 0.0]]), _zeros(), LIMIT, _zeros()
    )[0]
    ramp = sum(
        total_reward(
            config,
            DT,
            _zeros(),
            _zeros(),
            np.array([[k + 1.0, 0.0]]),
            np.array([[float(k), 0.0]]),
            LIMIT,
            _zeros(),
        )[0]
        for k in range(10)
    )
    still = total_reward(
        config,
        DT,
        _zeros(),
        _zeros(),
        np.array([[10.0, 0.0]]),
        np.array([[10.0, 0.0]]),
        LIMIT,
        _zeros(),
    )[0]
    assert ramp - 9 * still > step  # the ramp's rate cost summed is below the one jump's


def test_arms_of_a_batch_are_independent():
    """Arm i of an (N, n) call equals the same arm alone (the batched core's contract)."""
    rng = np.random.default_rng(1)
    arrays = [rng.normal(scale=s, size=(4, 2)) for s in (1e-3, 1e-2, 10.0, 10.0, 1e-2)]
    config = RewardConfig(velocity=0.2, torsion=0.1)
    batch = reward_terms(config, DT, *arrays[:4], LIMIT, arrays[4])
    for i in range(4):
        single = reward_terms(
            config, DT, *(a[i : i + 1] for a in arrays[:4]), LIMIT, arrays[4][i : i + 1]
        )
        for name in TERM_NAMES:
            assert batch[name][i] == single[name][0]


@pytest.mark.parametrize(
    ("config", "match"),
    [
        ({"trak": 1.0}, "trak"),
        ({"torque": -1.0}, "torque"),
        ({"sigmas": []}, "sigmas"),
        ({"rate_time": 0.0}, "rate_time"),
        ({"termination": float("inf")}, "termination"),
        ({"track": True}, "track"),
    ],
)
def test_bad_reward_config(config, match):
    with pytest.raises(ValueError, match=match):
        RewardConfig.from_config(config)


def test_bad_reward_inputs():
    with pytest.raises(ValueError, match="arms, joints"):
        total_reward(RewardConfig(), DT, np.zeros(2), _zeros(), _zeros(), _zeros(), LIMIT, _zeros())
    with pytest.raises(ValueError, match="torque"):
        total_reward(RewardConfig(), DT, _zeros(), _zeros(), _zeros(3), _zeros(), LIMIT, _zeros())
