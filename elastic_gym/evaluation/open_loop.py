"""The ``open-loop`` controller of a comparison: zero action.

Used for observer-only studies with the ``excitation`` task, where the env itself
applies the open-loop torque (e.g. Cristofaro & De Luca eq. (18): g(q) + (cos t/2, -cos t))
and the action is added to it.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from elastic_gym.controllers.base import Controller


class OpenLoopController(Controller):
    """Always zero torque: the task's open-loop command drives the arm."""

    name = "open-loop"

    def __call__(self, obs: Mapping, info: Mapping) -> np.ndarray:
        return np.zeros(self.n)


BUILTIN_CONTROLLERS: dict[str, type[Controller]] = {"open-loop": OpenLoopController}
