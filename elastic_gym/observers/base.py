"""The observer interface shared by every state estimator of the suite.

An observer sees what a real controller would: the sensor observation, the torque
actually applied and its nominal [`RobotModel`][elastic_gym.model.RobotModel]; it never imports
the simulator. State layout (De Luca et al., eq. (3)): elastic arms x = (theta, q,
theta', q'), rigid arms x = (q, q'). Non-implementable observers (the oracle, Theorem 1
with the ideal link acceleration) declare the ground-truth items they need in
``privileged``; the wrappers add exactly those. `BatchedObserver` subclasses
estimate N arms at once (``reset_arms`` / ``update_arms``); their ``reset`` / ``update``
are the case N = 1 of the same code.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np

from elastic_gym.arms import as_batch
from elastic_gym.model import RobotModel
from elastic_gym.robots.spec import check_applies
from elastic_gym.validation import PositiveFinite, numbers, option_value, shaped

ELASTIC_STATE = ("theta", "q", "dtheta", "dq")
RIGID_STATE = ("q", "dq")


class Observer(ABC):
    """Base class: ``reset`` gives the initial estimate, ``update`` advances one period.

    Args:
        model: nominal model the observer is designed on (possibly with errors).
        dt: sampling period (s), normally the env's control period.

    Attributes:
        name: registry name.
        applies_to: ``{"elastic"}``, ``{"rigid"}`` or both.
        privileged: ground-truth observation items needed (``"link_acceleration"``,
            ``"true_state"``); empty for implementable observers.
    """

    name: ClassVar[str] = ""
    applies_to: ClassVar[frozenset[str]] = frozenset({"elastic", "rigid"})
    privileged: tuple[str, ...] = ()  # a class default; an instance may set its own
    options_model: ClassVar[type | None] = None
    """The pydantic model (a ``StrictModel``) of the constructor's plain-data options."""

    def __init__(self, model: RobotModel, dt: float) -> None:
        self.dt = option_value("dt", dt, PositiveFinite, prefix="observer ")
        check_applies("observer", self.name, self.applies_to, model)
        self.model = model
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
    def reset(
        self, obs: Mapping[str, np.ndarray], initial_estimate: np.ndarray | None = None
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
        """``initial_estimate`` (``state_dim`` finite numbers) as a float array, or None."""
        if initial_estimate is None:
            return None
        return self._estimate_rows(initial_estimate, [(self.state_dim,)])

    def _estimate_rows(self, value: Any, shapes: list[tuple[int, ...]]) -> np.ndarray:
        rows = " (or one row per arm)" if len(shapes) > 1 else ""
        what = f"must be {self.state_dim} finite numbers {self.state_names}{rows}"
        return numbers(value, "initial_estimate", what, shapes, show_shape=True).copy()


ARM0 = np.array([0])


class BatchedObserver(Observer):
    """An observer whose state holds N arms: ``reset_arms`` and ``update_arms``.

    ``obs`` arguments are batched observations (arrays with a leading arm axis of length
    N, the number of arms); ``arm_diagnostics`` holds one value per arm for each entry of
    ``diagnostics``. ``reset`` and ``update`` run the same code with N = 1. An arm whose
    update fails numerically gets a non-finite row, so that the wrappers end its episode
    alone; an exception from ``update_arms`` ends the episodes of all the arms it updated.
    """

    def __init__(self, model: RobotModel, dt: float) -> None:
        super().__init__(model, dt)
        self.arm_diagnostics: dict[str, np.ndarray] = {}

    @abstractmethod
    def reset_arms(
        self,
        obs: Mapping[str, np.ndarray],
        arms: np.ndarray,
        initial_estimate: np.ndarray | None = None,
    ) -> np.ndarray:
        """Initialise the arms ``arms`` (rows of ``obs``); return their estimates.

        The number of arms is that of ``obs``; ``initial_estimate`` is one state vector
        (for every reset arm) or one row per reset arm.
        """

    @abstractmethod
    def update_arms(
        self,
        obs: Mapping[str, np.ndarray],
        torque: np.ndarray,
        dt: float,
        arms: np.ndarray | None = None,
    ) -> np.ndarray:
        """Estimates (N, dim) after one period; only ``arms`` (default all) are advanced."""

    def update_sequence(
        self, obs: Mapping[str, np.ndarray], torque: np.ndarray, dt: float
    ) -> np.ndarray:
        """Estimates (T, N, dim) of every arm after each of T periods: `obs` holds each
        observation item with a leading time axis (T, N, ...), `torque` (T, N, n) the
        torque of each period. One `update_arms` per period here; a subclass may run the
        periods in one compiled call that gives the same numbers bit for bit (an offline
        log: `elastic-gym observe`)."""
        out = np.empty((len(torque), np.shape(torque)[1], self.state_dim))
        for t in range(len(torque)):
            out[t] = self.update_arms({key: value[t] for key, value in obs.items()}, torque[t], dt)
        return out

    def reset(
        self, obs: Mapping[str, np.ndarray], initial_estimate: np.ndarray | None = None
    ) -> np.ndarray:
        estimate = self.reset_arms(as_batch(obs), ARM0, initial_estimate)[0]
        self.diagnostics = {key: value[0].item() for key, value in self.arm_diagnostics.items()}
        return estimate

    def update(self, obs: Mapping[str, np.ndarray], torque: np.ndarray, dt: float) -> np.ndarray:
        tau = shaped(torque, (self.n,), "torque")
        estimate = self.update_arms(as_batch(obs), tau[None], dt)[0]
        self.diagnostics = {key: value[0].item() for key, value in self.arm_diagnostics.items()}
        return estimate

    # helpers for subclasses
    def initial_rows(self, initial_estimate: np.ndarray | None, count: int) -> np.ndarray | None:
        """``initial_estimate`` checked and broadcast to ``count`` rows (or None)."""
        if initial_estimate is None:
            return None
        d = self.state_dim
        x = self._estimate_rows(initial_estimate, [(d,), (1, d), (count, d)])
        return np.broadcast_to(x, (count, d)).copy()

    def measured_positions(self, obs: Mapping, arms: np.ndarray | slice) -> np.ndarray:
        """Encoder readings of ``arms``, (len(arms), N)."""
        key = "motor_position" if self.elastic else "link_position"
        return np.asarray(obs[key], dtype=float)[arms]

    def checked_torque(self, torque: np.ndarray, n_arms: int) -> np.ndarray:
        return shaped(torque, (n_arms, self.n), "torque")


def arm_count(obs: Mapping) -> int:
    """The number of arms of a batched observation."""
    for value in obs.values():
        return arm_count(value) if isinstance(value, Mapping) else len(value)
    raise ValueError("empty observation")
