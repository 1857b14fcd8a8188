"""The envs of a training run, made in one place: the policy stack a run trains and is
evaluated on (:class:`PolicyStack`), on one env, on the arms of one PyBullet world, or as
the SB3 vec env of training (:func:`training_vec_env`: arms split over worker processes).

Everything that decides what the policy sees and does — env id and kwargs, state source
and observer options, action and observation configs, decimation, frame stack — is
resolved once from the run's config and hyper-parameters (:meth:`PolicyStack.of`), so
that training, its learning curve, a loaded run's evaluation and the comparison's
``trained-policy`` build the same stack.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
from gymnasium.vector import AutoresetMode

from elastic_gym.training.actions import ActionConfig
from elastic_gym.training.config import Settings, TrainConfig
from elastic_gym.training.observation import ObservationConfig
from elastic_gym.training.policy_env import SENSORS, make_policy_env, make_policy_vec_env


@dataclass(frozen=True)
class PolicyStack:
    """The policy env of a run (:mod:`elastic_gym.training.policy_env`), resolved.

    Attributes:
        env_id, env_kwargs: the env and the run's kwargs (hyper-parameter file's updated
            by the run's, :meth:`TrainConfig.training_env_kwargs`).
        state, observer_options: the state source the policy sees.
        action, observation: the policy's action and observation configs.
        decimation: env steps per policy step.
        frame_stack: frames the policy sees: the run's ``frame_stack`` of raw sensors, the
            observation's ``frames`` of a state source.
    """

    env_id: str
    state: str
    action: ActionConfig
    observation: ObservationConfig
    decimation: int = 1
    frame_stack: int = 1
    env_kwargs: dict = field(default_factory=dict)
    observer_options: dict = field(default_factory=dict)

    @classmethod
    def of(cls, config: TrainConfig, settings: Settings) -> PolicyStack:
        """The stack of a run: its config with its resolved hyper-parameters ``settings``
        (:meth:`TrainConfig.settings`)."""
        action, observation = config.policy_configs(settings)
        return cls(
            env_id=config.env_id,
            state=config.state,
            action=action,
            observation=observation,
            decimation=settings.decimation,
            frame_stack=config.frame_stack if config.state == SENSORS else observation.frames,
            env_kwargs=config.training_env_kwargs(settings),
            observer_options=dict(config.observer_options),
        )

    def _options(
        self, env_kwargs: dict | None, critic_state: bool, critic_plant: bool
    ) -> dict[str, Any]:
        return {
            "state": self.state,
            "env_kwargs": {**self.env_kwargs, **(env_kwargs or {})},
            "observer_options": self.observer_options,
            "decimation": self.decimation,
            "action": self.action,
            "observation": self.observation,
            "frame_stack": self.frame_stack,
            "critic_state": critic_state,
            "critic_plant": critic_plant,
        }

    def make(
        self,
        env_kwargs: dict | None = None,
        critic_state: bool = False,
        critic_plant: bool = False,
    ) -> gym.Env:
        """The stack on one env. ``env_kwargs`` update the run's key by key (e.g. an
        evaluation plant); ``critic_state`` / ``critic_plant``: the training stack, with
        the true state / the drawn plant parameters appended for the critic."""
        return make_policy_env(self.env_id, **self._options(env_kwargs, critic_state, critic_plant))

    def make_vec(
        self,
        n_arms: int,
        env_kwargs: dict | None = None,
        critic_state: bool = False,
        autoreset_mode: AutoresetMode = AutoresetMode.DISABLED,
        critic_plant: bool = False,
        teacher: bool = False,
    ) -> gym.vector.VectorEnv:
        """The stack on ``n_arms`` arms of one PyBullet world (a Gymnasium vector env with
        ``autoreset_mode``); ``env_kwargs``, ``critic_state`` and ``critic_plant`` as in
        :meth:`make`; ``teacher``: with the plant teacher's labels (distillation)."""
        return make_policy_vec_env(
            self.env_id,
            n_arms,
            autoreset_mode=autoreset_mode,
            teacher=teacher,
            **self._options(env_kwargs, critic_state, critic_plant),
        )

    def sb3_vec_env(
        self,
        n_arms: int,
        env_kwargs: dict | None = None,
        critic_state: bool = False,
        critic_plant: bool = False,
        teacher: bool = False,
    ):
        """The stack on ``n_arms`` arms of one PyBullet world as an SB3 ``VecEnv`` (with
        ``teacher``, the teacher's label in each arm's info)."""
        from elastic_gym.training.sb3_vec_env import SB3VecEnv
        from elastic_gym.training.teacher import LABEL

        envs = self.make_vec(
            n_arms, env_kwargs, critic_state, critic_plant=critic_plant, teacher=teacher
        )
        return SB3VecEnv(envs, info_keys=(LABEL,) if teacher else ())


def training_vec_env(stack: PolicyStack, settings: Settings, n_envs: int, seed: int):
    """What SB3 trains on: one env (``n_envs`` 1), a batch of ``n_envs`` arms, or several
    batches in worker processes (hyper-parameter ``batches``,
    :attr:`~elastic_gym.training.config.Settings.batch_kwargs`); with the true state
    and/or the drawn plant parameters appended for the critic if the hyper-parameter
    ``critic_state`` / ``critic_plant`` is set. Seeded with
    ``seed``, under a ``VecMonitor``."""
    from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv, VecMonitor

    from elastic_gym.training.sb3_vec_env import ProcessBatches

    batches = settings.batch_kwargs
    one_env = n_envs == 1 and isinstance(settings.batches, int)  # a count: at most n_envs
    if n_envs % len(batches) and not one_env:
        raise ValueError(f"the number of batches ({len(batches)}) must divide n_envs ({n_envs})")
    privileged = {"critic_state": settings.critic_state, "critic_plant": settings.critic_plant}
    venv: VecEnv
    if settings.distill is not None:
        if one_env:
            raise ValueError("distill needs a batch of arms: n_envs > 1")
        privileged["teacher"] = True
    if one_env:
        venv = DummyVecEnv([functools.partial(stack.make, None, **privileged)])
        venv.action_space.seed(seed)
    else:
        factories = [
            functools.partial(stack.sb3_vec_env, n_envs // len(batches), kwargs, **privileged)
            for kwargs in batches
        ]
        venv = factories[0]() if len(factories) == 1 else ProcessBatches(factories)
    venv.seed(seed)
    # Episode returns and lengths, one wrapping whatever the arms' layout (VecNormalize's
    # statistics sync walks wrapper stacks in parallel).
    return VecMonitor(venv)
