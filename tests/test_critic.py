"""A critic that sees the true state, an actor that cannot (``critic_state``, PPO)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from gymnasium import spaces
from helpers import policy_env, policy_vec_env, spec_env

from elastic_gym.training import TrainConfig, evaluate_run, load_run, train
from elastic_gym.training.config import resolve_hyperparams
from elastic_gym.training.critic import PrivilegedCriticPolicy

TWO_LINK = "elastic_gym/TwoLinkElastic-v0"
SHORT_EPISODES = {"max_episode_steps": 200}
TRUE_FEATURES = {"features": ["error", "error_rate", "torsion", "torsion_rate"]}
TORQUE = {"kind": "torque"}  # the torque does not depend on the state source

pytestmark = pytest.mark.usefixtures("single_thread_torch")


def _policy(actor_size: int = 6, privileged: int = 4) -> PrivilegedCriticPolicy:
    torch.manual_seed(0)
    space = spaces.Box(-np.inf, np.inf, (actor_size + privileged,), dtype=np.float32)
    return PrivilegedCriticPolicy(
        space,
        spaces.Box(-1, 1, (2,), dtype=np.float32),
        lambda _: 1e-3,
        privileged_size=privileged,
        net_arch=[16, 16],
    )


def _mean_std(policy, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The action distribution's mean and std on ``obs``."""
    distribution = policy.get_distribution(obs).distribution
    return distribution.mean, distribution.stddev


@pytest.mark.slow
def test_actor_never_depends_on_the_privileged_entries_and_the_critic_does():
    """Changing the last k entries leaves the action distribution bit for bit the same
    (mean, std, log-probability), the action mean's gradient with respect to them is
    exactly zero, while the critic's value changes and has a nonzero gradient."""
    policy = _policy()
    obs = torch.randn(5, 10)
    other = obs.clone()
    other[:, 6:] = torch.randn(5, 4) * 10
    actions = torch.rand(5, 2) * 2 - 1
    # SB3 reuses one distribution object: read each one's tensors before the next call
    first, second = (_mean_std(policy, x) for x in (obs, other))
    assert torch.equal(first[0], second[0]) and torch.equal(first[1], second[1])
    values, log_prob, _ = policy.evaluate_actions(obs, actions)
    other_values, other_log_prob, _ = policy.evaluate_actions(other, actions)
    assert torch.equal(log_prob, other_log_prob)
    assert torch.all(torch.abs(values - other_values) > 1e-6)

    probe = obs.clone().requires_grad_(True)
    mean = policy.get_distribution(probe).distribution.mean.sum()
    (grad,) = torch.autograd.grad(mean, probe)
    assert torch.all(grad[:, 6:] == 0) and torch.any(grad[:, :6] != 0)
    (value_grad,) = torch.autograd.grad(policy.predict_values(probe).sum(), probe)
    assert torch.all(torch.any(value_grad[:, 6:] != 0, dim=1))
    # structurally: the actor's first layer has the policy's 6 inputs, the critic's 10
    assert policy.mlp_extractor.policy_net[0].in_features == 6
    assert policy.mlp_extractor.value_net[0].in_features == 10


def test_bad_privileged_size_and_shared_extractor_are_refused():
    with pytest.raises(ValueError, match="privileged_size"):
        _policy(privileged=0)
    with pytest.raises(ValueError, match="privileged_size"):
        _policy(actor_size=0)
    space = spaces.Box(-np.inf, np.inf, (6,), dtype=np.float32)
    with pytest.raises(ValueError, match="share"):
        PrivilegedCriticPolicy(
            space, spaces.Box(-1, 1, (2,)), lambda _: 1e-3, 2, share_features_extractor=True
        )


@pytest.mark.parametrize(
    ("algo", "overrides", "match"),
    [
        ("sac", {"critic_state": True}, "ppo only"),
        ("recurrentppo", {"critic_state": True}, "ppo only"),
        ("ppo", {"critic_state": True, "policy": "CnnPolicy"}, "MlpPolicy"),
        (
            "ppo",
            {"critic_state": True, "policy_kwargs": {"share_features_extractor": True}},
            "share_features_extractor",
        ),
        ("ppo", {"critic_state": "yes"}, "critic_state: Input should be a valid boolean"),
    ],
)
def test_critic_state_is_refused_where_it_does_not_apply(algo, overrides, match):
    with pytest.raises(ValueError, match=match):
        resolve_hyperparams(algo, TWO_LINK, overrides)


def test_critic_state_appends_the_true_sources_features_to_the_unchanged_observation():
    """Single env, raw sensors with 4 stacked frames: the observation is the plain
    stack's followed by exactly what the ``"true"`` source gives for error, error rate,
    torsion and torsion rate (the run's scales), step after step."""
    scales = {"error_scale": 0.02, "torsion_rate_scale": 2.0}
    kwargs = {"env_kwargs": SHORT_EPISODES, "decimation": 10, "action": TORQUE}
    critic = policy_env(
        TWO_LINK, "sensors", observation=scales, frame_stack=4, critic_state=True, **kwargs
    )
    plain = policy_env(TWO_LINK, "sensors", observation=scales, frame_stack=4, **kwargs)
    truth = policy_env(TWO_LINK, "true", observation={**TRUE_FEATURES, **scales}, **kwargs)
    m = plain.observation_space.shape[0]
    assert critic.observation_space.shape == (m + 8,)
    rng = np.random.default_rng(0)
    observations = [env.reset(seed=3)[0] for env in (critic, plain, truth)]
    for _ in range(6):
        np.testing.assert_array_equal(observations[0][:m], observations[1])
        np.testing.assert_array_equal(observations[0][m:], observations[2])
        action = rng.uniform(-0.3, 0.3, 2)
        observations = [env.step(action)[0] for env in (critic, plain, truth)]
    assert np.abs(observations[2][:2]).max() > 0.1  # the error moved: a real comparison
    for env in (critic, plain, truth):
        env.close()


def test_vector_critic_state_matches_the_single_env_truth_arm_by_arm():
    """Batched arms (De Luca source): arm i's privileged entries are the ``"true"``
    source's features of the single env seeded s + i."""
    kwargs = {"env_kwargs": SHORT_EPISODES, "decimation": 10, "action": TORQUE}
    envs = policy_vec_env(TWO_LINK, 3, "deluca", critic_state=True, **kwargs)
    m = envs.single_observation_space.shape[0] - 8
    obs, _ = envs.reset(seed=7)
    singles = [policy_env(TWO_LINK, "true", observation=TRUE_FEATURES, **kwargs) for _ in range(3)]
    single_obs = [env.reset(seed=7 + i)[0] for i, env in enumerate(singles)]
    rng = np.random.default_rng(1)
    for _ in range(4):
        np.testing.assert_allclose(obs[:, m:], np.array(single_obs), rtol=1e-5, atol=1e-5)
        actions = rng.uniform(-0.3, 0.3, (3, 2))
        obs = envs.step(actions)[0]
        single_obs = [env.step(a)[0] for env, a in zip(singles, actions, strict=True)]
    envs.close()
    for env in singles:
        env.close()


@pytest.mark.slow
def test_critic_state_run_deploys_without_the_true_state(tmp_path):
    """Training on batched arms with ``critic_state``: the saved run reloads as a
    PrivilegedCriticPolicy; on the deployment stack (no true state) its action equals the
    action given the true features, its critic's value depends on them, and
    ``evaluate_run`` tracks on fresh episodes."""
    config = TrainConfig(
        state="deluca",
        total_steps=128,
        out_dir=str(tmp_path / "r"),
        env_kwargs=SHORT_EPISODES,
        eval_freq=64,
        eval_episodes=2,
        hyperparams={
            "critic_state": True,
            "n_envs": 2,
            "batches": 1,
            "n_steps": 32,
            "batch_size": 32,
            "n_epochs": 2,
        },
    )
    train(config, progress_bar=False)
    run = load_run(config.out_dir, trust_pickle=True)
    policy = run.model.policy
    assert isinstance(policy, PrivilegedCriticPolicy) and policy.privileged_size == 8

    deployed = spec_env(run.spec)  # what compare / evaluate_run build
    training = spec_env(run.spec, critic=True)
    assert deployed.observation_space.shape[0] == policy.actor_size
    obs, _ = deployed.reset(seed=11)
    full, _ = training.reset(seed=11)
    for _ in range(3):
        normalized = run.normalizer.normalize_obs(full[None].astype(np.float32))
        with_truth, _ = run.model.predict(normalized, deterministic=True)
        np.testing.assert_array_equal(run.act(obs), with_truth[0])
        shifted = normalized.copy()
        shifted[:, policy.actor_size :] += 1.0
        with torch.no_grad():
            values = [
                float(policy.predict_values(torch.as_tensor(x))) for x in (normalized, shifted)
            ]
        assert abs(values[0] - values[1]) > 1e-6
        action = run.act(obs)
        obs, full = deployed.step(action)[0], training.step(action)[0]
        np.testing.assert_array_equal(full[: policy.actor_size], obs)
    deployed.close()
    training.close()

    result = evaluate_run(run, 2, 100)
    assert all(np.isfinite(result.tracking_rms)) and max(result.tracking_rms) < 0.1


RANDOMIZE = {
    "randomize": {
        "plant_scaling.link_mass": {"low": 0.7, "high": 1.3},
        "unmodelled_friction.coulomb": {"low": 0.0, "high": 0.03},
        "sensor_delay": {"low": 0, "high": 1},
    }
}


def test_critic_plant_appends_each_arms_drawn_plant_after_the_true_state():
    """Batched arms, De Luca source, randomized plants: the observation is the plain
    stack's, then the ``"true"`` source's features, then exactly the values each arm drew
    at its reset (``info["plant"]``, in the order of the randomization's paths), which
    stay fixed over the episode and differ between arms."""
    kwargs = {
        "env_kwargs": {**SHORT_EPISODES, **RANDOMIZE},
        "decimation": 10,
        "action": TORQUE,
    }
    both = policy_vec_env(TWO_LINK, 3, "deluca", critic_state=True, critic_plant=True, **kwargs)
    state_only = policy_vec_env(TWO_LINK, 3, "deluca", critic_state=True, **kwargs)
    plant_only = policy_vec_env(TWO_LINK, 3, "deluca", critic_plant=True, **kwargs)
    paths = ["plant_scaling.link_mass", "unmodelled_friction.coulomb", "sensor_delay"]
    m = state_only.single_observation_space.shape[0]
    assert both.single_observation_space.shape == (m + 3,)
    assert plant_only.single_observation_space.shape == (m - 8 + 3,)
    (obs, info), (state_obs, _), (plant_obs, _) = (
        env.reset(seed=5) for env in (both, state_only, plant_only)
    )
    drawn = np.stack([info["plant"][p] for p in paths], axis=1)
    assert np.all(np.ptp(drawn[:, :2], axis=0) > 0)  # arms drew different plants
    rng = np.random.default_rng(2)
    for _ in range(4):
        np.testing.assert_array_equal(obs[:, :m], state_obs)
        np.testing.assert_array_equal(obs[:, m:], drawn.astype(obs.dtype))
        np.testing.assert_array_equal(plant_obs[:, : m - 8], obs[:, : m - 8])
        np.testing.assert_array_equal(plant_obs[:, m - 8 :], obs[:, m:])
        actions = rng.uniform(-0.3, 0.3, (3, 2))
        obs, state_obs, plant_obs = (env.step(actions)[0] for env in (both, state_only, plant_only))
    for env in (both, state_only, plant_only):
        env.close()


def test_critic_plant_without_randomization_or_on_other_algorithms_is_refused():
    with pytest.raises(ValueError, match="critic_plant: the env randomizes no plant"):
        policy_vec_env(TWO_LINK, 2, "true", critic_plant=True, action=TORQUE)
    with pytest.raises(ValueError, match="ppo only"):
        resolve_hyperparams("recurrentppo", TWO_LINK, {"critic_plant": True})
    with pytest.raises(ValueError, match="critic_plant: applies only when policy is the MlpPolicy"):
        resolve_hyperparams("ppo", TWO_LINK, {"critic_plant": True, "policy": "CnnPolicy"})


@pytest.mark.slow
def test_critic_plant_run_acts_as_its_actor_alone_and_deploys_without_the_plant(tmp_path):
    """Training randomized with ``critic_state`` and ``critic_plant``: the actor's action
    is bit for bit the same whatever the privileged entries (true state and drawn plant),
    its gradient with respect to them is exactly zero while the critic's is not, and the
    deployment stack (no privileged entries) gives the same action and evaluates."""
    config = TrainConfig(
        state="deluca",
        total_steps=128,
        out_dir=str(tmp_path / "r"),
        env_kwargs={**SHORT_EPISODES, **RANDOMIZE},
        eval_freq=64,
        eval_episodes=2,
        hyperparams={
            "critic_state": True,
            "critic_plant": True,
            "n_envs": 2,
            "batches": 1,
            "n_steps": 32,
            "batch_size": 32,
            "n_epochs": 2,
        },
    )
    train(config, progress_bar=False)
    run = load_run(config.out_dir, trust_pickle=True)
    policy = run.model.policy
    assert isinstance(policy, PrivilegedCriticPolicy) and policy.privileged_size == 8 + 3

    deployed = spec_env(run.spec)
    training = spec_env(run.spec, critic=True)
    k = policy.actor_size
    assert deployed.observation_space.shape[0] == k
    obs, _ = deployed.reset(seed=13)
    full, _ = training.reset(seed=13)
    for _ in range(3):
        normalized = run.normalizer.normalize_obs(full[None].astype(np.float32))
        with_plant, _ = run.model.predict(normalized, deterministic=True)
        np.testing.assert_array_equal(run.act(obs), with_plant[0])
        probe = torch.as_tensor(normalized).requires_grad_(True)
        other = probe.detach().clone()
        other[:, k:] += torch.randn(1, 8 + 3) * 5
        first, second = (_mean_std(policy, x) for x in (probe, other))
        assert torch.equal(first[0], second[0]) and torch.equal(first[1], second[1])
        (grad,) = torch.autograd.grad(first[0].sum(), probe)
        assert torch.all(grad[:, k:] == 0) and torch.any(grad[:, :k] != 0)
        (value_grad,) = torch.autograd.grad(policy.predict_values(probe).sum(), probe)
        assert torch.all(value_grad[:, -3:] != 0)  # the critic reads the drawn plant
        action = run.act(obs)
        obs, full = deployed.step(action)[0], training.step(action)[0]
        np.testing.assert_array_equal(full[:k], obs)
    deployed.close()
    training.close()
    result = evaluate_run(run, 2, 100)
    assert all(np.isfinite(result.tracking_rms)) and max(result.tracking_rms) < 0.1
