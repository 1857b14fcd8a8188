"""Controllers: eq. (13) feedforward + full-state feedback, PD, rigid-arm laws, policies."""

from elastic_gym.controllers.base import Controller, public_info
from elastic_gym.controllers.registry import (
    CONTROLLERS,
    controller_class,
    make_controller,
    register_controller,
)

__all__ = [
    "CONTROLLERS",
    "Controller",
    "controller_class",
    "make_controller",
    "public_info",
    "register_controller",
]
