"""RL training on the estimated state: the stable-baselines3 pipeline (``elastic-gym train``).

What a trained policy is (its spec, the env stack it acts on, its action and observation,
the controller that runs it in a comparison, loading it) lives in `elastic_gym.policy`;
this package learns: hyper-parameters, the vector envs SB3 trains on, training, the
privileged critic, the plant teacher and distillation, learning curves and run folders.
The policy names it used to hold are re-exported here unchanged.
"""

from elastic_gym.observers.registry import state_sources
from elastic_gym.policy import (
    ActionConfig,
    ActionMap,
    ActionRepeat,
    ObservationBuilder,
    ObservationConfig,
    PolicyAction,
    PolicyObservation,
    PolicySpec,
)
from elastic_gym.training.config import ALGORITHMS, TrainConfig, parse_overrides
from elastic_gym.training.run_folder import RunFolder
from elastic_gym.training.train import TrainResult, train, train_many
from elastic_gym.training.trained import TrainedRun, evaluate_run, load_run

__all__ = [
    "ALGORITHMS",
    "ActionConfig",
    "ActionMap",
    "ActionRepeat",
    "ObservationBuilder",
    "ObservationConfig",
    "PolicyAction",
    "PolicyObservation",
    "PolicySpec",
    "RunFolder",
    "TrainConfig",
    "TrainResult",
    "TrainedRun",
    "evaluate_run",
    "load_run",
    "parse_overrides",
    "state_sources",
    "train",
    "train_many",
]
