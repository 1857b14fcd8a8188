"""A PPO critic that sees the true state for an actor that never does (asymmetric
actor-critic, Pinto et al., RSS 2018, Sec. IV).

PPO needs its value function only in training, so the critic may see what the deployed
actor cannot. With ``critic_state: true`` (PPO only) the training observation is
``[policy observation (m), true-state features (k)]``
([`CriticState`][elastic_gym.policy.vector.CriticState]) and
[`PrivilegedCriticPolicy`][elastic_gym.training.critic.PrivilegedCriticPolicy]
gives the actor's features extractor ([`ActorSlice`][elastic_gym.training.critic.ActorSlice])
the first m entries only (no actor weight multiplies a privileged entry), the critic all
m + k. Deployment builds the
stack without ``CriticState`` and pads the k entries with NaN: the actor never reads them.
"""

from __future__ import annotations

from typing import Annotated

import torch
from gymnasium import spaces
from pydantic import Field, StrictInt, TypeAdapter
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor, MlpExtractor

from elastic_gym.validation import checked


class ActorSlice(BaseFeaturesExtractor):
    """The first ``size`` entries of a flat observation (the policy's own)."""

    def __init__(self, observation_space: spaces.Space, size: int) -> None:
        super().__init__(observation_space, size)
        self.size = size

    def forward(self, observations: torch.Tensor) -> torch.Tensor:
        return observations[:, : self.size]


class _SplitMlpExtractor(MlpExtractor):
    """SB3's ``MlpExtractor`` with the policy net on ``actor_dim`` inputs and the value
    net on ``critic_dim`` (SB3's takes one input size for both)."""

    def __init__(self, actor_dim: int, critic_dim: int, net_arch, activation_fn, device) -> None:
        super().__init__(actor_dim, net_arch, activation_fn, device)
        self.value_net = MlpExtractor(critic_dim, net_arch, activation_fn, device).value_net


class PrivilegedCriticPolicy(ActorCriticPolicy):
    """SB3's ``ActorCriticPolicy`` (MLP) whose actor ignores the last ``privileged_size``
    observation entries and whose critic sees them (module docstring). Separate features
    extractors (``share_features_extractor=False``) by construction."""

    def __init__(
        self,
        observation_space: spaces.Box,
        action_space: spaces.Space,
        lr_schedule,
        privileged_size: int,
        **kwargs,
    ) -> None:
        if not isinstance(observation_space, spaces.Box) or len(observation_space.shape) != 1:
            raise ValueError(
                f"a privileged critic needs flat Box observations, got {observation_space}"
            )
        size = observation_space.shape[0]
        within = Annotated[StrictInt, Field(ge=1, le=size - 1)]  # not the whole observation
        checked(lambda: TypeAdapter(within).validate_python(privileged_size), "privileged_size")
        if kwargs.pop("share_features_extractor", False):
            raise ValueError("a privileged critic cannot share the actor's features extractor")
        self.privileged_size = privileged_size
        super().__init__(
            observation_space, action_space, lr_schedule, share_features_extractor=False, **kwargs
        )

    @property
    def actor_size(self) -> int:
        """Observation entries the actor sees (the first ones)."""
        return spaces.flatdim(self.observation_space) - self.privileged_size

    def _build_mlp_extractor(self) -> None:
        # called by ActorCriticPolicy._build after both (full) features extractors exist
        self.pi_features_extractor = ActorSlice(self.observation_space, self.actor_size)
        self.features_extractor = self.pi_features_extractor
        self.features_dim = self.actor_size
        self.mlp_extractor = _SplitMlpExtractor(
            self.actor_size,
            self.vf_features_extractor.features_dim,
            self.net_arch,
            self.activation_fn,
            self.device,
        )

    def _get_constructor_parameters(self) -> dict:
        return {**super()._get_constructor_parameters(), "privileged_size": self.privileged_size}
