"""Controllers by name: ``make_controller("motor-pd", model, dt, **options)``.

The built-ins are listed below, each as ``(module, class)`` imported at its first use, so
that a controller of a package above this one (``policy`` and ``trained-policy``, the
policy controller of `elastic_gym.policy`) is named without importing upward; a user's
package adds its own with `register_controller`.
"""

from __future__ import annotations

import importlib

from elastic_gym.controllers.base import Controller
from elastic_gym.model import RobotModel
from elastic_gym.validation import lookup

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
    # the policy package sits above the controllers: named here, imported at first use
    "policy": ("elastic_gym.policy.controller", "PolicyController"),
    "trained-policy": ("elastic_gym.policy.controller", "PolicyController"),
}


def register_controller(name: str, target: str) -> None:
    """Make ``target`` (``"module:Class"``, imported at first use) known as ``name``.

    Registering the same target again does nothing; another target under a taken name
    raises ``ValueError``.
    """
    module, sep, cls = target.partition(":")
    if not (sep and module and cls):
        raise ValueError(f"controller target must be 'module:Class', got {target!r}")
    if CONTROLLERS.get(name, (module, cls)) != (module, cls):
        raise ValueError(
            f"controller name {name!r} is taken by {':'.join(CONTROLLERS[name])}, not {target!r}"
        )
    CONTROLLERS[name] = (module, cls)


def controller_class(name: str) -> type[Controller]:
    module, cls = lookup(CONTROLLERS, name, "controller")
    return getattr(importlib.import_module(module), cls)


def make_controller(name: str, model: RobotModel, dt: float, **options) -> Controller:
    """Instantiate a controller by registry name with its options."""
    return controller_class(name)(model, dt, **options)
