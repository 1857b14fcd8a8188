"""What a policy sees and what its actions mean: features equal their definitions, the
motor-offset PD tracks with the right offsets, residual policies start as the base
controller, arms of a batch are independent, bad configs are refused."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from helpers import policy_env

from elastic_gym.arms import reference_rows
from elastic_gym.controllers import make_controller, public_info
from elastic_gym.observers import TrueStateWrapper
from elastic_gym.policy.observation import ObservationInputs
from elastic_gym.policy.wrappers import PolicyAction
from elastic_gym.training import (
    ActionConfig,
    ActionMap,
    ObservationBuilder,
    ObservationConfig,
)

ENV_ID = "elastic_gym/TwoLinkElastic-v0"
EXACT = {"encoder": {"resolution": 0.0, "noise_std": 0.0}, "accelerometer": "ideal"}


def _innermost_info(env):
    """The info of the last step as seen just above the observer (ground truth included)."""
    return env.get_wrapper_attr("_info")


def test_motor_offset_pd_with_the_invdyn_offset_tracks():
    """Through the policy stack (100 Hz actions, 1 kHz motor PD, no model term), the offset
    that makes the PD reproduce eq. (13)'s motor trajectory (theta_d - q_d plus the
    feedforward torque over kp, from INVDYN) tracks a 1 rad move to < 3e-4 rad RMS: the
    action map is the PD of its docstring, and the parameterization can reach 1e-4 rad."""
    config = ActionConfig(kind="motor-offset", offset_scale=0.05)
    env = policy_env(
        ENV_ID, "true", {"max_episode_steps": 1500, **EXACT}, decimation=10, action=config
    )
    base = env.unwrapped
    action_map = env.get_wrapper_attr("map")
    invdyn = make_controller("feedforward-state-feedback", base.model, base.control_dt)
    env.reset(seed=3)
    invdyn.reset({}, {})
    errors, done, offsets = [], False, []
    while not done:
        info = public_info(_innermost_info(env))
        x_d, tau_d = invdyn.desired(info)
        action = action_map.motor_offset_action(
            tau_d[None], x_d[None, :2], x_d[None, 4:6], reference_rows(info)[None]
        )[0]
        offsets.append(action * config.offset_scale)
        _, _, terminated, truncated, step_info = env.step(action)
        errors.append(step_info["true_state"]["q"] - step_info["reference"]["q"])
        done = terminated or truncated
    env.close()
    rms = np.sqrt(np.mean(np.square(errors)))
    assert rms < 3e-4
    assert np.abs(offsets).max() < config.offset_scale  # the default range covers them


def test_features_equal_their_definitions():
    """Each feature of the flat observation, read back from its slice, equals its formula
    applied to the truth, the reference and the last action."""
    observation = ObservationConfig(
        features=(
            "error",
            "error_rate",
            "error_integral",
            "reference",
            "preview",
            "torsion",
            "torsion_rate",
            "last_action",
        ),
        reference_order=3,
        preview=(0.05, 0.2),
    )
    env = policy_env(
        ENV_ID,
        "true",
        {"max_episode_steps": 500},
        decimation=10,
        action={"kind": "motor-offset"},
        observation=observation,
    )
    _, info = env.reset(seed=1)
    integral, time = np.zeros(2), info["time"]
    for _ in range(40):  # into the first move
        obs, _, _, _, info = env.step(np.array([0.3, -0.7]))
        integral += (info["time"] - time) * (info["true_state"]["q"] - reference_rows(info)[0])
        time = info["time"]
    c = observation
    truth, ref = info["true_state"], reference_rows(info)
    task = env.unwrapped.task
    expected = {
        "error": (truth["q"] - ref[0]) / c.error_scale,
        "error_rate": (truth["dq"] - ref[1]) / c.error_rate_scale,
        "error_integral": integral / c.error_integral_scale,
        "reference": np.concatenate([ref[0], ref[1], ref[2] / 10, ref[3] / 100]),
        "preview": np.concatenate(
            [task.reference(np.array([info["time"] + h]))[0, 0] - ref[0] for h in c.preview]
        )
        / c.preview_scale,
        "torsion": (truth["theta"] - truth["q"]) / c.torsion_scale,
        "torsion_rate": (truth["dtheta"] - truth["dq"]) / c.torsion_rate_scale,
        "last_action": np.array([0.3, -0.7]),
    }
    builder = env.get_wrapper_attr("builder")
    assert obs.dtype == np.float32 and obs.shape == (builder.size,) == (24,)
    assert time == pytest.approx(0.4) and np.abs(integral).max() > 1e-5
    start = 0
    for name, size in builder.sizes.items():
        np.testing.assert_allclose(obs[start : start + size], expected[name], rtol=1e-6, atol=1e-6)
        start += size
    assert np.abs(expected["preview"]).max() > 0.1  # the move is under way: a real preview
    env.close()


def test_full_state_adds_the_torsion_rate_to_the_default_selection_only():
    """``full_state`` lets the default actor of an elastic arm's state source see theta'
    (the torsion rate); raw sensors, rigid arms and explicit features are unchanged, and
    the shipped PPO defaults set it."""
    from elastic_gym.training import TrainConfig

    def selected(env_id, state, **observation):
        env = policy_env(env_id, state, observation=observation)
        features = env.get_wrapper_attr("builder").features
        env.close()
        return features

    rigid = "elastic_gym/TwoLinkRigid-v0"
    without = ("error", "error_rate", "reference", "torsion", "last_action")
    full = ("error", "error_rate", "reference", "torsion", "torsion_rate", "last_action")
    assert selected(ENV_ID, "true") == without
    assert selected(ENV_ID, "true", full_state=True) == full
    assert selected(ENV_ID, "deluca", full_state=True) == full
    assert selected(ENV_ID, "sensors", full_state=True) == selected(ENV_ID, "sensors")
    assert selected(rigid, "true", full_state=True) == selected(rigid, "true")
    assert "torsion_rate" not in selected(rigid, "true", full_state=True)
    explicit = selected(ENV_ID, "true", full_state=True, features=["error", "reference"])
    assert explicit == ("error", "reference")
    config = TrainConfig(env_id=ENV_ID, algo="ppo")
    _, observation = config.policy_configs(config.settings()[0])
    assert observation.full_state and observation.features is None


def test_arms_of_a_batch_are_independent():
    """Builder and action map on (N, ...) arrays: row i equals the same arm alone."""
    env = gym.make(ENV_ID)
    model = env.unwrapped.model
    env.close()
    rng = np.random.default_rng(0)
    n_arms = 3
    inputs = ObservationInputs(
        reference=rng.normal(size=(n_arms, 5, 2)),
        last_action=rng.uniform(-1, 1, (n_arms, 2)),
        state=rng.normal(size=(n_arms, 8)),
        preview=rng.normal(size=(n_arms, 2, 2)),
        base_torque=rng.normal(size=(n_arms, 2)),
    )
    builder = ObservationBuilder(
        ObservationConfig(preview=(0.1, 0.2)), 2, True, False, True, model.torque_limit
    )
    batch = builder.build(inputs)
    action = rng.uniform(-1.5, 1.5, (n_arms, 2))
    maps = [
        ActionMap(
            ActionConfig(
                kind=k,
                residual="motor-pd" if k == "residual" else None,
                gravity_compensation=k == "motor-offset",
            ),
            model,
        )
        for k in ("torque", "motor-offset", "residual")
    ]
    torques = [
        m.torque(
            action, inputs.state[:, :2], inputs.state[:, 4:6], inputs.reference, inputs.base_torque
        )
        for m in maps
    ]
    for i in range(n_arms):
        one = ObservationInputs(
            **{k: v[i : i + 1] for k, v in vars(inputs).items() if v is not None}
        )
        np.testing.assert_array_equal(batch[i], builder.build(one)[0])
        for m, tau in zip(maps, torques, strict=True):
            single = m.torque(
                action[i : i + 1],
                inputs.state[i : i + 1, :2],
                inputs.state[i : i + 1, 4:6],
                inputs.reference[i : i + 1],
                inputs.base_torque[i : i + 1],
            )
            np.testing.assert_array_equal(tau[i], single[0])
    # torque: clipped to the limits; residual: base + 10 % of the limit at |a| = 1, zero
    # inside the default deadzone 0.2
    assert np.all(np.abs(torques[0]) <= model.torque_limit)
    a = np.clip(action, -1, 1)
    np.testing.assert_allclose(
        torques[2] - inputs.base_torque,
        0.1 * model.torque_limit * np.sign(a) * np.maximum(np.abs(a) - 0.2, 0) / 0.8,
    )


@pytest.mark.slow
def test_residual_policy_starts_as_its_base_controller():
    """A fresh PPO residual policy (zeroed mean head) outputs exactly zero, so its first
    episode is eq. (13)'s."""
    from stable_baselines3 import PPO

    from elastic_gym.training.train import zero_action_head

    action = {"kind": "residual", "residual": "feedforward-state-feedback"}
    env = policy_env(
        ENV_ID, "true", {"max_episode_steps": 200, **EXACT}, decimation=10, action=action
    )
    model = PPO(
        "MlpPolicy",
        env,
        seed=0,
        device="cpu",
        policy_kwargs={"log_std_init": -3.0, "net_arch": [16]},
    )
    zero_action_head(model)
    obs, _ = env.reset(seed=2)
    policy_q = []
    done = False
    while not done:
        a, _ = model.predict(obs, deterministic=True)
        assert np.all(a == 0.0)
        obs, _, terminated, truncated, info = env.step(a)
        policy_q.append(info["true_state"]["q"])
        done = terminated or truncated
    env.close()

    plain = TrueStateWrapper(gym.make(ENV_ID, max_episode_steps=200, **EXACT))
    law = make_controller("feedforward-state-feedback", plain.unwrapped.model, 1e-3)
    obs, info = plain.reset(seed=2)
    law.reset(obs, public_info(info))
    for step in range(200):
        obs, _, _, _, info = plain.step(law(obs, public_info(info)))
        if step % 10 == 9:
            np.testing.assert_array_equal(info["true_state"]["q"], policy_q[step // 10])
    plain.close()


def test_residual_deadzone_is_zero_inside_and_continuous_to_the_bound():
    """tau = base + s tau_max sign(a) max(|a| - d, 0) / (1 - d): zero for |a| <= d, the
    full bound at |a| = 1, linear in between."""
    env = gym.make(ENV_ID)
    model = env.unwrapped.model
    env.close()
    config = ActionConfig.from_config(
        {
            "kind": "residual",
            "residual": "motor-pd",
            "residual_scale": 0.1,
            "residual_deadzone": 0.2,
        }
    )
    actions = ActionMap(config, model)
    base = np.array([[3.0, -1.0]] * 5)
    a = np.array([[0.0, 0.2], [-0.2, 0.19], [0.6, -0.6], [1.0, -1.0], [2.0, -0.3]])
    residual = (actions.torque(a, base_torque=base) - base) / (0.1 * model.torque_limit)
    expected = np.array([[0.0, 0.0], [0.0, 0.0], [0.5, -0.5], [1.0, -1.0], [1.0, -0.125]])
    np.testing.assert_allclose(residual, expected, atol=1e-12)


def test_raw_sensor_motor_offset_uses_the_encoder_difference():
    """On raw sensors the PD's motor velocity is the backward difference of the encoder:
    with exact encoders, the same torques as the PD on the true state within O(dt)."""
    action = {"kind": "motor-offset"}
    kwargs = {"max_episode_steps": 300, **EXACT}
    env_s = policy_env(ENV_ID, "sensors", kwargs, decimation=10, action=action)
    env_t = policy_env(ENV_ID, "true", kwargs, decimation=10, action=action)
    env_s.reset(seed=0)
    env_t.reset(seed=0)
    for _ in range(30):
        _, _, _, _, info_s = env_s.step(np.array([0.2, 0.1]))
        _, _, _, _, info_t = env_t.step(np.array([0.2, 0.1]))
    error = np.abs(info_s["true_state"]["q"] - info_t["true_state"]["q"]).max()
    moved = np.abs(info_t["true_state"]["q"] - info_t["reference"]["q"]).max()
    assert error < 0.05 * moved
    env_s.close()
    env_t.close()


@pytest.mark.parametrize(
    ("fields", "match"),
    [
        ({"kind": "velocity"}, "velocity"),
        ({"kind": "residual"}, "residual"),
        ({"kind": "torque", "residual": "motor-pd"}, "residual"),
        ({"offset_scale": -0.1}, "offset_scale"),
        ({"kp": 100.0}, "kp"),
        ({"residual_scale": 2.0}, "residual_scale"),
        ({"residual_deadzone": 1.0}, "residual_deadzone"),
        ({"residual_deadzone": -0.1}, "residual_deadzone"),
        ({"gain": 1.0}, "gain"),
    ],
)
def test_bad_action_config(fields, match):
    with pytest.raises(ValueError, match=match):
        ActionConfig.from_config(fields)


@pytest.mark.parametrize(
    ("fields", "match"),
    [
        ({"features": ["error", "speed"]}, "speed"),
        ({"features": []}, "features"),
        ({"reference_order": 5}, "reference_order"),
        ({"preview": [0.1, -0.2]}, "preview"),
        ({"error_scale": 0.0}, "error_scale"),
        ({"colour": 1}, "colour"),
    ],
)
def test_bad_observation_config(fields, match):
    with pytest.raises(ValueError, match=match):
        ObservationConfig.from_config(fields)


def test_features_that_the_stack_cannot_provide_are_refused():
    with pytest.raises(ValueError, match="raw sensors"):
        policy_env(ENV_ID, "sensors", observation={"features": ["error", "reference"]})
    with pytest.raises(ValueError, match="residual"):
        policy_env(ENV_ID, "true", observation={"features": ["base_torque"]})
    with pytest.raises(ValueError, match="preview horizons"):
        policy_env(ENV_ID, "true", observation={"features": ["preview"]})
    with pytest.raises(ValueError, match="elastic"):
        policy_env("elastic_gym/TwoLinkRigid-v0", "true", action={"kind": "motor-offset"})
    env = policy_env(ENV_ID, "true")
    with pytest.raises(ValueError, match="finite"):
        env.reset(seed=0)
        env.step(np.array([np.nan, 0.0]))
    assert isinstance(env.get_wrapper_attr("action_config"), ActionConfig)
    assert isinstance(env.env, PolicyAction)
    env.close()


def test_base_motor_error_is_the_extra_deflection_of_a_heavier_load():
    """``base_motor_error``: the motor half of the residual base's x - x_d on the current
    state. On the nominal plant at rest it is zero; on links 30 % heavier, at rest at their
    own equilibrium where eq. (13)'s x_d is the nominal one, the policy's first observation
    shows the extra static torsion K^-1 (g_1.3 - g)(q0) in its position part, before the
    links move, and a zero rate part."""
    from elastic_gym.controllers.vector import ControllerArray
    from elastic_gym.policy.observation import check_base_error

    observation = ObservationConfig(features=("error", "base_motor_error"))
    action = {"kind": "residual", "residual": "integral-state-feedback"}
    torsion, features = {}, {}
    for mass in (1.0, 1.3):
        plant = {"plant_scaling": {"link_mass": mass}}
        env = policy_env(ENV_ID, "true", plant, action=action, observation=observation)
        obs, info = env.reset(seed=3)
        torsion[mass] = info["true_state"]["theta"] - info["true_state"]["q"]
        features[mass] = obs[2:]
        assert obs.shape == (6,) and info["base_error"].shape == (8,)
        env.close()
    np.testing.assert_allclose(features[1.0], 0.0, atol=1e-10)
    extra = torsion[1.3] - torsion[1.0]
    assert np.abs(extra).max() > 1e-3  # a real load change: 30 % of the static torsion
    np.testing.assert_allclose(features[1.3][:2] * observation.error_scale, extra, rtol=1e-6)
    np.testing.assert_allclose(features[1.3][2:], 0.0, atol=1e-9)

    pd = make_controller("motor-pd", env.unwrapped.model, 1e-3)
    with pytest.raises(ValueError, match="desired state x_d"):  # a base that keeps no x_d
        check_base_error(observation.features, ControllerArray(pd, 2))
