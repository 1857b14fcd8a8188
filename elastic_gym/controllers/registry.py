"""Controllers by name: ``make_controller("motor-pd", model, dt, **options)``."""

from __future__ import annotations

import importlib

from elastic_gym.controllers.base import Controller
from elastic_gym.model import RobotModel

# name -> (module, class)
CONTROLLERS: dict[str, tuple[str, str]] = {
    "feedforward-state-feedback": (
        "elastic_gym.controllers.state_feedback",
        "FeedforwardStateFeedback",
    ),
    "integral-state-feedback": ("elastic_gym.controllers.integral", "IntegralStateFeedback"),
    "motor-pd": ("elastic_gym.controllers.pd", "MotorPD"),
    "link-pd": ("elastic_gym.controllers.pd", "LinkPD"),
    "cristofaro-tracking": ("elastic_gym.controllers.rigid", "CristofaroTrackingController"),
    "feedback-linearization": ("elastic_gym.controllers.rigid", "FeedbackLinearizingController"),
    "policy": ("elastic_gym.controllers.policy", "PolicyController"),
    # a folder written by ``elastic-gym train`` (lazy import: training sits above controllers)
    "trained-policy": ("elastic_gym.training.policy_controller", "TrainedPolicyController"),
}


def controller_class(name: str) -> type[Controller]:
    if name not in CONTROLLERS:
        raise ValueError(f"unknown controller {name!r}; valid: {sorted(CONTROLLERS)}")
    module, cls = CONTROLLERS[name]
    return getattr(importlib.import_module(module), cls)


def make_controller(name: str, model: RobotModel, dt: float, **options) -> Controller:
    """Instantiate a controller by registry name with its options."""
    return controller_class(name)(model, dt, **options)
