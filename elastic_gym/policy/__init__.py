"""What a deployed policy is, apart from how it was learned.

* its spec ([`PolicySpec`][elastic_gym.policy.spec.PolicySpec]): env, state source,
  action, observation, rate, frames, the critic's privileged inputs;
* the one builder of the env stack it acts on
  ([`build_policy_env`][elastic_gym.policy.builder.build_policy_env], single env or N
  arms), its action map and observation features (`elastic_gym.policy.actions`,
  `elastic_gym.policy.observation`);
* the one controller that runs it in ``compare`` and ``benchmark``
  ([`PolicyController`][elastic_gym.policy.controller.PolicyController], registered as
  ``"policy"`` and ``"trained-policy"``);
* loading ([`load_policy`][elastic_gym.policy.loading.load_policy]): an exported policy
  (ONNX graph + manifest, no pickle) or a trusted training run folder;
* exporting ([`export_policy`][elastic_gym.policy.export.export_policy]).
"""

from elastic_gym.policy.actions import ActionConfig, ActionMap
from elastic_gym.policy.builder import build_policy_env, wrap_policy_env
from elastic_gym.policy.loading import (
    Policy,
    UntrustedPickleError,
    load_policy,
    read_spec,
)
from elastic_gym.policy.observation import ObservationBuilder, ObservationConfig
from elastic_gym.policy.spec import PolicySpec
from elastic_gym.policy.wrappers import ActionRepeat, PolicyAction, PolicyObservation

__all__ = [
    "ActionConfig",
    "ActionMap",
    "ActionRepeat",
    "ObservationBuilder",
    "ObservationConfig",
    "Policy",
    "PolicyAction",
    "PolicyObservation",
    "PolicySpec",
    "UntrustedPickleError",
    "build_policy_env",
    "load_policy",
    "read_spec",
    "wrap_policy_env",
]
