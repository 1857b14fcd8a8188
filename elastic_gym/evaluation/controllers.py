"""The controller names a comparison accepts, and their classes.

Two sources: the registry of `elastic_gym.controllers` (its entries are imported at their
first use, so a comparison of classical controllers never loads the policy package or
the training stack) and the comparison's own (``open-loop``).
"""

from __future__ import annotations

from elastic_gym.controllers.base import Controller
from elastic_gym.controllers.registry import CONTROLLERS, controller_class
from elastic_gym.evaluation.open_loop import BUILTIN_CONTROLLERS


def controller_names() -> list[str]:
    """Every controller name a scenario may use, sorted."""
    return sorted({*CONTROLLERS, *BUILTIN_CONTROLLERS})


def comparison_controller(name: str) -> type[Controller]:
    """The class of a controller name (``ValueError`` for an unknown one)."""
    if name in BUILTIN_CONTROLLERS:
        return BUILTIN_CONTROLLERS[name]
    return controller_class(name)
