"""Training's round of fault injection: hyper-parameters outside their meaning refused."""

from __future__ import annotations

import pytest

from elastic_gym.training import TrainConfig


# ------------------------------------------------------------------ hyper-parameters
@pytest.mark.parametrize(
    ("algo", "key", "value", "interval"),
    [
        ("ppo", "gamma", 1.5, "(0, 1]"),
        ("ppo", "gamma", 0.0, "(0, 1]"),
        ("ppo", "gae_lambda", 1.01, "[0, 1]"),
        ("ppo", "gae_lambda", -0.1, "[0, 1]"),
        ("ppo", "learning_rate", 0.0, "(0, inf)"),
        ("ppo", "learning_rate", -3e-4, "(0, inf)"),
        ("ppo", "clip_range", 0.0, "(0, inf)"),
        ("ppo", "batch_size", 0, "[1, inf)"),
        ("ppo", "n_steps", 0, "[1, inf)"),
        ("ppo", "n_epochs", 0, "[1, inf)"),
        ("ppo", "ent_coef", -0.01, "[0, inf)"),
        ("ppo", "max_grad_norm", 0.0, "(0, inf)"),
        ("recurrentppo", "gamma", 2.0, "(0, 1]"),
        ("sac", "tau", 0.0, "(0, 1]"),
        ("sac", "buffer_size", 0, "[1, inf)"),
        ("sac", "gradient_steps", 0, "[1, inf) or -1"),
        ("td3", "policy_delay", 0, "[1, inf)"),
    ],
)
def test_hyper_parameters_outside_their_meaning_are_refused(algo, key, value, interval):
    config = TrainConfig(algo=algo, state="true", hyperparams={key: value})
    with pytest.raises(ValueError, match=rf"hyper-parameter {key}: must be in \{interval[0]}"):
        config.settings()
    with pytest.raises(ValueError) as refused:
        config.settings()
    assert f"must be in {interval}, got {value!r}" in str(refused.value)


@pytest.mark.parametrize(
    ("algo", "key", "value"),
    [
        ("ppo", "gamma", 1.0),
        ("ppo", "gae_lambda", 0.0),
        ("ppo", "gae_lambda", 1.0),
        ("sac", "gradient_steps", -1),
        ("sac", "learning_starts", 0),
        ("sac", "ent_coef", "auto"),
    ],
)
def test_the_ends_of_the_ranges_and_sb3s_special_values_are_accepted(algo, key, value):
    _, algo_kwargs = TrainConfig(algo=algo, state="true", hyperparams={key: value}).settings()
    assert algo_kwargs[key] == value


def test_an_unknown_key_inside_a_hyper_parameter_files_entry_lists_the_valid_ones(tmp_path):
    path = tmp_path / "hp.yaml"
    path.write_text("default:\n  distill: {iteration: 4}\n")
    config = TrainConfig(algo="recurrentppo", state="sensors", hyperparams_file=str(path))
    with pytest.raises(ValueError, match=r"default\.distill\.iteration: unexpected field") as no:
        config.settings()
    assert "valid: ['iterations', 'episodes', 'steps'," in str(no.value), no.value
    assert "'root'" not in str(no.value)
