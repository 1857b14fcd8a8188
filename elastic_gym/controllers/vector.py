"""Vector controllers: the torques of N arms from arrays with a leading arm axis.

A [`VectorController`][elastic_gym.controllers.vector.VectorController] is the batched twin of the
single-arm interface (`controllers.base`): ``obs["state"]`` (N, dim) and ``obs["reference"]``
(N, 2n), as a vector `ObserverWrapper` gives them; ``info["time"]`` (N,) and ``info["reference"]``
with (N, n) arrays ``q`` .. ``d4q``; ``reset_arms(obs, info, arms)`` restarts the arms ``arms``
(an env reset or autoreset), ``controller(obs, info)`` returns the (N, n) motor torques.

Every built-in controller has a batched twin computing all arms in one pass (INVDYN through the
[`SerialChain`][elastic_gym.model.SerialChain] kernels); the single-arm controller runs its twin
with N = 1, so arm i of a batch gets the single controller's torque.
[`make_vector_controller`][elastic_gym.controllers.vector.make_vector_controller] builds the twin of
a built-in, and [`ControllerArray`][elastic_gym.controllers.vector.ControllerArray] (one copy per
arm) for any other `Controller`.
"""

from __future__ import annotations

import copy
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping
from typing import Any, ClassVar, Generic, TypeVar

import numpy as np
from typing_extensions import Self

from elastic_gym.arms import arm_view, as_batch
from elastic_gym.controllers.base import Controller, public_info
from elastic_gym.controllers.invdyn import checked_reference_rows, info_time, state_vector
from elastic_gym.controllers.registry import controller_class
from elastic_gym.model import RobotModel
from elastic_gym.robots.spec import check_applies
from elastic_gym.validation import checked_count, only_when

ARM0 = np.array([0])


def arm_rows(A: np.ndarray, X: np.ndarray) -> np.ndarray:
    """A x_i for every row x_i of X, (N, m): one matrix-vector product per arm, so that an
    arm's result does not depend on the other rows of the batch."""
    return np.matmul(A, X[..., None])[..., 0]


class VectorController(ABC):
    """Base class of the controllers of N arms.

    Args:
        model: nominal model the controller is designed on.
        dt: control period (s).
        n_arms: number of arms N.
    """

    name: str = ""
    applies_to: frozenset[str] = frozenset({"elastic", "rigid"})

    def __init__(self, model: RobotModel, dt: float, n_arms: int) -> None:
        checked_count(n_arms, "n_arms", 1)
        check_applies("controller", self.name, self.applies_to, model)
        self.model = model
        self.dt = float(dt)
        self.n_arms = int(n_arms)
        self.n = model.n
        self.elastic = model.elastic
        self.state_dim = (4 if model.elastic else 2) * model.n

    def reset_arms(self, obs: Mapping, info: Mapping, arms: np.ndarray) -> None:  # noqa: B027
        """Called after the arms ``arms`` were reset; stateless controllers need nothing."""

    @abstractmethod
    def __call__(self, obs: Mapping, info: Mapping) -> np.ndarray:
        """Motor torques (N, n) for the batched observation and public info."""

    # helpers
    def states(self, obs: Mapping) -> np.ndarray:
        """``obs["state"]`` checked, (N, dim)."""
        return state_vector(obs, self.state_dim, self.n_arms)

    def references(self, info: Mapping) -> np.ndarray:
        """q_d .. q_d^(4) of every arm, (N, 5, n)."""
        return checked_reference_rows(info, self.n, self.n_arms)

    def times(self, info: Mapping) -> np.ndarray:
        """``info["time"]`` of every arm, (N,)."""
        return np.asarray(info_time(info, self.n_arms))


class ControllerArray(VectorController):
    """One deep copy of a single-arm controller per arm, behind the vector interface.

    Each arm sees its own slice of ``obs`` and of the public ``info`` (arrays indexed by
    arm, nested mappings too), so its torque is bit for bit that of the single controller.
    """

    def __init__(self, controller: Controller, n_arms: int) -> None:
        if not isinstance(controller, Controller):
            raise TypeError(f"ControllerArray needs a Controller, got {type(controller).__name__}")
        self.name = controller.name
        self.applies_to = controller.applies_to
        super().__init__(controller.model, controller.dt, n_arms)
        self.controllers = [copy.deepcopy(controller) for _ in range(self.n_arms)]

    def reset_arms(self, obs: Mapping, info: Mapping, arms: np.ndarray) -> None:
        info = public_info(info)
        for i in arms:
            self.controllers[i].reset(arm_view(obs, i), arm_view(info, i))

    def __call__(self, obs: Mapping, info: Mapping) -> np.ndarray:
        info = public_info(info)
        torques = [c(arm_view(obs, i), arm_view(info, i)) for i, c in enumerate(self.controllers)]
        return np.array(torques, dtype=float).reshape(self.n_arms, self.n)


C = TypeVar("C", bound=Controller)


class ControllerTwin(VectorController, Generic[C]):
    """The batched law of a built-in single-arm controller (its design and options).

    ``Twin(model, dt, n_arms, **options)`` designs the single controller
    ``single_class(model, dt, **options)`` (every option checked there) and runs its law
    on N arms; ``Twin.of(controller, n_arms)`` runs an already built one
    (``self.controller``).
    """

    single_class: ClassVar[type[Controller]]
    controller: C

    def __init__(self, model: RobotModel, dt: float, n_arms: int, **options) -> None:
        controller: Any = self.single_class(model, dt, **options)
        self._bind(controller, n_arms)

    @classmethod
    def of(cls, controller: C, n_arms: int) -> Self:
        twin = cls.__new__(cls)
        twin._bind(controller, n_arms)
        return twin

    def _bind(self, controller: C, n_arms: int) -> None:
        self.name, self.applies_to = controller.name, controller.applies_to
        VectorController.__init__(self, controller.model, controller.dt, n_arms)
        self.controller = controller


class StateLaw(ControllerTwin[C]):
    """A twin whose torque depends on the time, the state and the reference only."""

    @abstractmethod
    def torques(self, t: np.ndarray, x: np.ndarray, ref: np.ndarray) -> np.ndarray:
        """(N, n) torques at times t (N,), states x (N, dim), references (N, 5, n)."""

    def __call__(self, obs: Mapping, info: Mapping) -> np.ndarray:
        return self.torques(self.times(info), self.states(obs), self.references(info))


class OneArmLaw:
    """Mixin of the built-in single-arm controllers: their law is their
    [`vector_twin`][elastic_gym.controllers.base.Controller.vector_twin] run with N = 1."""

    _law: Any  # the twin: a StateLaw of this class
    vector_twin: ClassVar[Any]
    n: int

    def bind_law(self) -> None:
        """Build the one-arm law on this controller's design (end of ``__init__``)."""
        self._law = self.vector_twin.of(self, 1)

    def reset(self, obs: Mapping, info: Mapping) -> None:
        self._law.reset_arms(as_batch(obs), as_batch(info), ARM0)

    def __call__(self, obs: Mapping, info: Mapping) -> np.ndarray:
        x = state_vector(obs, self._law.state_dim)
        t = np.array([info_time(info)])
        return self._law.torques(t, x[None], checked_reference_rows(info, self.n, None)[None])[0]


def twin_of(single_class: type[Controller]) -> Callable[[type[ControllerTwin]], type]:
    """Class decorator: the decorated
    [`ControllerTwin`][elastic_gym.controllers.vector.ControllerTwin] is ``single_class``'s twin."""

    def register(twin: type[ControllerTwin]) -> type[ControllerTwin]:
        twin.single_class = single_class
        single_class.vector_twin = twin
        return twin

    return register


def make_vector_controller(
    name_or_class: str | type[Controller] | Controller,
    model: RobotModel,
    dt: float,
    n_arms: int,
    **options,
) -> VectorController:
    """The controller of N arms: the batched twin of a built-in (a registry name, or its
    class), a [`ControllerArray`][elastic_gym.controllers.vector.ControllerArray] for any other
    `Controller` class. A built
    controller instance (then without options) is run by its twin or copied per arm."""
    built = isinstance(name_or_class, Controller)
    only_when(not built, {"options": options}, "a controller is named or given as a class")
    if isinstance(name_or_class, Controller):
        twin = type(name_or_class).__dict__.get("vector_twin")
        return twin.of(name_or_class, n_arms) if twin else ControllerArray(name_or_class, n_arms)
    cls = controller_class(name_or_class) if isinstance(name_or_class, str) else name_or_class
    if not (isinstance(cls, type) and issubclass(cls, Controller)):
        raise TypeError(
            f"controller must be a registry name, a Controller class or instance, got {cls!r}"
        )
    twin = cls.__dict__.get("vector_twin")
    if twin is not None:
        return twin(model, dt, n_arms, **options)
    return ControllerArray(cls(model, dt, **options), n_arms)


__all__ = [
    "ControllerArray",
    "ControllerTwin",
    "OneArmLaw",
    "StateLaw",
    "VectorController",
    "arm_rows",
    "make_vector_controller",
    "twin_of",
]
