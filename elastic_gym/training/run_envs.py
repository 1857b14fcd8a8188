"""What SB3 trains on: the policy's env ([`PolicySpec`][elastic_gym.policy.spec.PolicySpec]
of the run, built by [`build_policy_env`][elastic_gym.policy.builder.build_policy_env]) with
the critic's privileged inputs, on one env, on the arms of one PyBullet world, or on
several such worlds in worker processes, as one SB3 ``VecEnv`` (`training_vec_env`).
"""

from __future__ import annotations

import functools

from elastic_gym.policy.builder import build_policy_env
from elastic_gym.policy.spec import PolicySpec
from elastic_gym.training.config import Settings


def training_env(spec: PolicySpec):
    """The training stack on one env: the spec's, with its privileged critic inputs."""
    return build_policy_env(spec, spec.make_env(), critic=True)


def training_arms(
    spec: PolicySpec, n_arms: int, env_kwargs: dict | None = None, teacher: bool = False
):
    """The training stack on ``n_arms`` arms of one PyBullet world as an SB3 ``VecEnv``;
    ``env_kwargs`` update the spec's (a batch's plant); ``teacher``: with the plant
    teacher's label in each arm's info
    ([`PlantTeacher`][elastic_gym.training.teacher.PlantTeacher], distillation)."""
    from elastic_gym.training.sb3_vec_env import SB3VecEnv
    from elastic_gym.training.teacher import LABEL, PlantTeacher

    envs = build_policy_env(spec, spec.make_env(n_arms, env_kwargs), critic=True)
    if teacher:
        envs = PlantTeacher(envs, spec.decimation)
    return SB3VecEnv(envs, info_keys=(LABEL,) if teacher else ())


def training_vec_env(spec: PolicySpec, settings: Settings, n_envs: int, seed: int):
    """What SB3 trains on: one env (``n_envs`` 1), a batch of ``n_envs`` arms, or several
    batches in worker processes (hyper-parameter ``batches``,
    [`Settings.batch_kwargs`][elastic_gym.training.config.Settings.batch_kwargs]); with the
    true state and/or the drawn plant parameters appended for the critic if the spec says
    so (``critic_state`` / ``critic_plant``), and the teacher's labels for distillation.
    Seeded with ``seed``, under a ``VecMonitor``."""
    from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv, VecMonitor

    from elastic_gym.training.sb3_vec_env import ProcessBatches

    batches = settings.batch_kwargs
    one_env = n_envs == 1 and isinstance(settings.batches, int)  # a count: at most n_envs
    if n_envs % len(batches) and not one_env:
        raise ValueError(f"the number of batches ({len(batches)}) must divide n_envs ({n_envs})")
    teacher = settings.distill is not None
    venv: VecEnv
    if teacher and one_env:
        raise ValueError("distill needs a batch of arms: n_envs > 1")
    if one_env:
        venv = DummyVecEnv([functools.partial(training_env, spec)])
        venv.action_space.seed(seed)
    else:
        factories = [
            functools.partial(training_arms, spec, n_envs // len(batches), kwargs, teacher)
            for kwargs in batches
        ]
        venv = factories[0]() if len(factories) == 1 else ProcessBatches(factories)
    venv.seed(seed)
    # Episode returns and lengths, one wrapping whatever the arms' layout (VecNormalize's
    # statistics sync walks wrapper stacks in parallel).
    return VecMonitor(venv)
