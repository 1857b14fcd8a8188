"""The controller names a comparison accepts, and their classes.

Three sources: the registry of :mod:`elastic_gym.controllers`, the comparison's own
(``open-loop``), and names that a package above the controllers registers when it is
imported (``trained-policy``, by :mod:`elastic_gym.training`): that package is imported
here only when a scenario names one of them, so a comparison of classical controllers
never loads the training stack.
"""

from __future__ import annotations

import importlib

from elastic_gym.controllers.base import Controller
from elastic_gym.controllers.registry import CONTROLLERS, controller_class
from elastic_gym.evaluation.open_loop import BUILTIN_CONTROLLERS

# name -> the package whose import registers it
REGISTERED_ON_IMPORT = {"trained-policy": "elastic_gym.training"}


def controller_names() -> list[str]:
    """Every controller name a scenario may use, sorted."""
    return sorted({*CONTROLLERS, *BUILTIN_CONTROLLERS, *REGISTERED_ON_IMPORT})


def comparison_controller(name: str) -> type[Controller]:
    """The class of a controller name (``ValueError`` for an unknown one)."""
    if name in BUILTIN_CONTROLLERS:
        return BUILTIN_CONTROLLERS[name]
    if name in REGISTERED_ON_IMPORT and name not in CONTROLLERS:
        importlib.import_module(REGISTERED_ON_IMPORT[name])
    return controller_class(name)
