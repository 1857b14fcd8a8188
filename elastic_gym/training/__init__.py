"""RL training on the estimated state: stable-baselines3 pipeline (``elastic-gym train``).

Importing the package registers the ``trained-policy`` controller: a run folder as a
controller of the comparison
(:class:`~elastic_gym.training.policy_controller.TrainedPolicyController`).
"""

from elastic_gym.controllers.registry import register_controller
from elastic_gym.observers.registry import state_sources
from elastic_gym.training.actions import ActionConfig, ActionMap
from elastic_gym.training.config import ALGORITHMS, TrainConfig, parse_overrides
from elastic_gym.training.observation import ObservationBuilder, ObservationConfig
from elastic_gym.training.policy_env import make_policy_env
from elastic_gym.training.run_envs import PolicyStack
from elastic_gym.training.run_folder import RunFolder
from elastic_gym.training.train import TrainResult, train, train_many
from elastic_gym.training.trained import TrainedRun, evaluate_run, load_run
from elastic_gym.training.wrappers import ActionRepeat, PolicyAction, PolicyObservation

register_controller(
    "trained-policy", "elastic_gym.training.policy_controller:TrainedPolicyController"
)

__all__ = [
    "ALGORITHMS",
    "ActionConfig",
    "ActionMap",
    "ActionRepeat",
    "ObservationBuilder",
    "ObservationConfig",
    "PolicyAction",
    "PolicyObservation",
    "PolicyStack",
    "RunFolder",
    "TrainConfig",
    "TrainResult",
    "TrainedRun",
    "evaluate_run",
    "load_run",
    "make_policy_env",
    "parse_overrides",
    "state_sources",
    "train",
    "train_many",
]
