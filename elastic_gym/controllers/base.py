"""The controller interface: ``torque = controller(obs, info)``.

A controller reads only

* ``obs["state"]``: the state estimate (or the truth) from an
  [`ObserverWrapper`][elastic_gym.observers.ObserverWrapper], layout (theta, q, theta', q') for
  elastic arms and (q, q') for rigid ones;
* ``obs["reference"]`` and `public_info` of ``info``: the time and the desired
  trajectory with derivatives up to order 4 (``info["reference"]``);
* its nominal [`RobotModel`][elastic_gym.model.RobotModel].

It never sees the simulator's ground truth; the comparison runner strips ``info``
with `public_info` before calling it.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping
from typing import ClassVar

import numpy as np

from elastic_gym.model import RobotModel
from elastic_gym.robots.spec import check_applies

PUBLIC_INFO_KEYS = ("time", "reference")


def public_info(info: Mapping) -> dict:
    """The part of an env ``info`` a controller may read: time and desired trajectory."""
    return {key: info[key] for key in PUBLIC_INFO_KEYS if key in info}


class Controller(ABC):
    """Base class of the classical controllers.

    Args:
        model: nominal model the controller is designed on.
        dt: control period (s).

    Attributes:
        name: registry name.
        applies_to: ``{"elastic"}``, ``{"rigid"}`` or both.
        takes_sensors: whether it runs on raw sensors too (an observation without
            ``state``: the encoders, accelerometers and ``reference`` of the env).
    """

    name: ClassVar[str] = ""
    applies_to: ClassVar[frozenset[str]] = frozenset({"elastic", "rigid"})
    takes_sensors: ClassVar[bool] = False
    vector_twin: ClassVar[type | None] = None
    """The batched law
    (a ``ControllerTwin`` of [`elastic_gym.controllers.vector`][elastic_gym.controllers.vector])
    that
    built-ins run with N = 1 and that ``make_vector_controller`` runs for N arms."""
    options_model: ClassVar[type | None] = None
    """The pydantic model (a ``StrictModel``) of the constructor's plain-data options."""

    def __init__(self, model: RobotModel, dt: float) -> None:
        check_applies("controller", self.name, self.applies_to, model)
        self.model = model
        self.dt = float(dt)
        self.n = model.n
        self.elastic = model.elastic

    def reset(self, obs: Mapping, info: Mapping) -> None:  # noqa: B027 - optional hook
        """Called after ``env.reset``; stateless controllers need nothing."""

    @abstractmethod
    def __call__(self, obs: Mapping, info: Mapping) -> np.ndarray:
        """Motor torque (N,) for the current observation and public info."""

    # helpers
    def split_state(self, obs: Mapping) -> tuple[np.ndarray, ...]:
        """(theta, q, theta', q') for elastic arms, (q, q') for rigid arms."""
        x = np.asarray(obs["state"], dtype=float)
        return tuple(x.reshape(-1, self.n))
