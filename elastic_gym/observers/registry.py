"""Observers by name: ``make_observer("deluca", model, dt, **options)``."""

from __future__ import annotations

import importlib

from elastic_gym.model import RobotModel
from elastic_gym.observers.base import Observer
from elastic_gym.observers.sensors import SENSORS, RawSensors
from elastic_gym.robots.spec import joint_kind
from elastic_gym.validation import lookup

# name -> (module, class, fixed options)
OBSERVERS: dict[str, tuple[str, str, dict]] = {
    "deluca": ("elastic_gym.observers.deluca", "DeLucaObserver", {"acceleration": "accelerometer"}),
    "deluca-ideal": ("elastic_gym.observers.deluca", "DeLucaObserver", {"acceleration": "ideal"}),
    "ekf": ("elastic_gym.observers.ekf", "ExtendedKalmanFilter", {}),
    "reduced-order": ("elastic_gym.observers.reduced_order", "ReducedOrderObserver", {}),
    "solsona-puleston": (
        "elastic_gym.observers.solsona_puleston",
        "SolsonaPulestonObserver",
        {},
    ),
    "nicosia-tomei": ("elastic_gym.observers.nicosia_tomei", "NicosiaTomeiObserver", {}),
    "finite-difference": (
        "elastic_gym.observers.finite_difference",
        "FiniteDifferenceObserver",
        {},
    ),
    "true": ("elastic_gym.observers.oracle", "OracleObserver", {}),
}


def observer_class(name: str) -> type[Observer]:
    module, cls, _ = lookup(OBSERVERS, name, "observer")
    return getattr(importlib.import_module(module), cls)


def state_sources() -> list[str]:
    """Every state source name: raw ``"sensors"``, then the observers (``"true"`` = oracle)."""
    return [SENSORS, *OBSERVERS]


def source_class(name: str) -> type[Observer]:
    """The class of a state source name: `RawSensors` for raw sensors, else the
    observer's (``ValueError`` naming the valid ones for an unknown name)."""
    lookup(dict.fromkeys(state_sources()), name, "state source")
    return RawSensors if name == SENSORS else observer_class(name)


def make_observer(name: str, model: RobotModel, dt: float, **options) -> Observer:
    """Instantiate an observer by registry name with its options."""
    cls = observer_class(name)
    fixed = OBSERVERS[name][2]
    clash = set(fixed) & set(options)
    if clash:
        raise ValueError(f"option(s) {sorted(clash)} are fixed by the observer name {name!r}")
    return cls(model, dt, **fixed, **options)


def applicable_observers(elastic: bool) -> list[str]:
    """Registry names of the observers that apply to an elastic or a rigid arm."""
    kind = joint_kind(elastic)
    return [name for name in OBSERVERS if kind in observer_class(name).applies_to]
