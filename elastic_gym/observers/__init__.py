"""State observers and the wrappers that put them in the loop.

Observers by name (`make_observer`): ``deluca`` (accelerometer-based, eq. (12)),
``deluca-ideal`` (Theorem 1/2 with the ideal link acceleration), ``ekf``,
``reduced-order`` (Cristofaro & De Luca), ``solsona-puleston``, ``nicosia-tomei``,
``finite-difference`` and ``true`` (oracle).
"""

from elastic_gym.observers.base import ELASTIC_STATE, RIGID_STATE, Observer
from elastic_gym.observers.registry import (
    OBSERVERS,
    applicable_observers,
    make_observer,
    observer_class,
)
from elastic_gym.observers.wrappers import ObserverWrapper, TrueStateWrapper

__all__ = [
    "ELASTIC_STATE",
    "OBSERVERS",
    "RIGID_STATE",
    "Observer",
    "ObserverWrapper",
    "TrueStateWrapper",
    "applicable_observers",
    "make_observer",
    "observer_class",
]
