"""The observer interface shared by every state estimator of the suite.

An observer sees what a real controller would: the sensor observation of the env
and the torque actually applied (after clipping), plus the nominal
:class:`~elastic_gym.model.RobotModel`. It never imports the simulator.

State layout (De Luca et al., eq. (3)):

* elastic arms: x = (theta, q, theta', q'), 4N entries;
* rigid arms:   x = (q, q'), 2N entries.

Non-implementable observers (the oracle, and Theorem 1 with the *ideal* link
acceleration) declare the ground-truth items they need in ``privileged``; the
:class:`~elastic_gym.observers.wrappers.ObserverWrapper` adds exactly those to the
observation they receive, and nothing else.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping
from typing import ClassVar

import numpy as np

from elastic_gym.model import RobotModel
from elastic_gym.validation import check_applies

ELASTIC_STATE = ("theta", "q", "dtheta", "dq")
RIGID_STATE = ("q", "dq")


class Observer(ABC):
    """Base class: ``reset`` gives the initial estimate, ``update`` advances one period.

    Args:
        model: nominal model the observer is designed on (possibly with errors).
        dt: sampling period (s), normally the env's control period.

    Class attributes:
        name: registry name.
        applies_to: ``{"elastic"}``, ``{"rigid"}`` or both.
        privileged: ground-truth observation items needed (``"link_acceleration"``,
            ``"true_state"``); empty for implementable observers.
    """

    name: ClassVar[str] = ""
    applies_to: ClassVar[frozenset[str]] = frozenset({"elastic", "rigid"})
    privileged: ClassVar[tuple[str, ...]] = ()

    def __init__(self, model: RobotModel, dt: float) -> None:
        if not (isinstance(dt, (int, float)) and np.isfinite(dt) and dt > 0):
            raise ValueError(f"observer dt must be a positive number, got {dt!r}")
        check_applies("observer", self.name, self.applies_to, model)
        self.model = model
        self.dt = float(dt)
        self.n = model.n
        self.elastic = model.elastic
        self.diagnostics: dict[str, float] = {}

    @property
    def state_names(self) -> tuple[str, ...]:
        """Names of the N-blocks of the estimated state, in order."""
        return ELASTIC_STATE if self.elastic else RIGID_STATE

    @property
    def state_dim(self) -> int:
        return len(self.state_names) * self.n

    @abstractmethod
    def reset(self, obs: Mapping[str, np.ndarray], initial_estimate: np.ndarray | None = None
              ) -> np.ndarray:
        """Initialise from the first observation; return the initial estimate.

        ``initial_estimate`` (full state vector) overrides the observer's own
        initialisation where the observer has a state to initialise (used to study
        convergence from a wrong initial estimate).
        """

    @abstractmethod
    def update(self, obs: Mapping[str, np.ndarray], torque: np.ndarray, dt: float) -> np.ndarray:
        """Estimate after one period in which ``torque`` was applied and ``obs`` was measured."""

    # helpers for subclasses
    def measured_position(self, obs: Mapping[str, np.ndarray]) -> np.ndarray:
        """Motor position (elastic) or link position (rigid) from the encoders."""
        key = "motor_position" if self.elastic else "link_position"
        return np.asarray(obs[key], dtype=float)

    def check_initial_estimate(self, initial_estimate: np.ndarray | None) -> np.ndarray | None:
        if initial_estimate is None:
            return None
        x = np.asarray(initial_estimate, dtype=float)
        if x.shape != (self.state_dim,) or not np.all(np.isfinite(x)):
            raise ValueError(
                f"initial_estimate must be {self.state_dim} finite numbers {self.state_names}, "
                f"got shape {x.shape}"
            )
        return x.copy()
