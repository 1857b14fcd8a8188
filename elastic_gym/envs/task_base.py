"""The base of every task: what a task gives the batch (references, open-loop torques,
start configurations, its compiled arguments), shared by ``tasks`` and ``fourier``.

A task serves N arms at once; ``REFERENCE_ORDER`` is the highest derivative of q_d a
reference carries (eq. (13)'s feedforward needs q_d .. q_d^(4)).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from elastic_gym.model import RobotModel
from elastic_gym.robots.spec import RobotSpec
from elastic_gym.validation import StrictModel, per_joint_values

REFERENCE_ORDER = 4


def per_joint_option(value, n: int, name: str) -> np.ndarray:
    """A per-joint option (a number or N numbers, already finite by its model) as (N,)."""
    return per_joint_values(value, n, f"task_options.{name}")


@dataclass
class Task(ABC):
    """Base class: reference trajectories, an optional external torque, start configurations.

    A task serves ``n_arms`` arms at once (arrays with a leading arm axis); arm i samples
    its episode from its own generator, so each arm's episode is the one a single arm
    with the same generator would get.
    """

    spec: RobotSpec
    model: RobotModel
    n_arms: int = field(default=1, kw_only=True)
    name: str = field(default="", init=False)
    options_model: ClassVar[type[StrictModel]]

    def reset(self, arms: np.ndarray, rngs: list[np.random.Generator]) -> np.ndarray:
        """Sample the episodes of ``arms``; return their initial link configurations
        (len(arms), N), at rest. ``rngs`` holds the generators of all arms."""
        return np.array([self.reset_arm(i, rngs[i]) for i in arms]).reshape(-1, self.spec.n_joints)

    @abstractmethod
    def reset_arm(self, arm: int, rng: np.random.Generator) -> np.ndarray:
        """Sample arm ``arm``'s episode from ``rng``; return its initial configuration (N,)."""

    @abstractmethod
    def reference(self, t: np.ndarray, arms: slice | np.ndarray = slice(None)) -> np.ndarray:
        """(len(arms), REFERENCE_ORDER + 1, N): q_d and its derivatives, arm k at time t[k]."""

    def external_torque(self, t: np.ndarray, q: np.ndarray) -> np.ndarray | None:
        """Open-loop torque (n_arms, N) added to the action; None when there is none."""
        return None

    def compiled_arguments(self) -> tuple[tuple, tuple] | None:
        """For compiled callers (the batch's control period): the ``arguments`` of
        `open_loop_torque_kernel` and of `reference_kernel`, each (whether the task has
        an open-loop torque / a reference that moves during an episode, the kernel's
        arguments: of the same types either way, so that every task compiles one
        signature), the arrays a reset changes in place; or None for a task computed in
        Python only (the batch then steps it call by call). A subclass that overrides
        [`external_torque`][elastic_gym.envs.task_base.Task.external_torque] or
        [`reference`][elastic_gym.envs.task_base.Task.reference] overrides this too."""
        return None

    def snapshot(self) -> dict:
        """The task's own state (its options and every arm's episode: paths, targets,
        holds), without the robot and its model: what `restore` takes."""
        return {k: v for k, v in vars(self).items() if k not in ("spec", "model")}

    def restore(self, snapshot: dict) -> None:
        """The state of a `snapshot` of a task of the same class and robot."""
        vars(self).update(snapshot)

    def configured_points(self) -> dict[str, np.ndarray]:
        """The configurations given as options (start, goal, waypoints), by option name."""
        names = ("start", "goal", "waypoints")
        values = {
            name: getattr(self, f"_{name if name != 'waypoints' else 'given'}", None)
            for name in names
        }
        return {name: np.atleast_2d(v) for name, v in values.items() if v is not None}

    # helpers
    @property
    def low(self) -> np.ndarray:
        return np.asarray(self.spec.workspace_low, dtype=float)

    @property
    def high(self) -> np.ndarray:
        return np.asarray(self.spec.workspace_high, dtype=float)

    def sample_configuration(self, rng: np.random.Generator) -> np.ndarray:
        return rng.uniform(self.low, self.high)

    def sample_move(
        self, rng: np.random.Generator, start: np.ndarray, max_move: float
    ) -> np.ndarray:
        """A reachable configuration within ``max_move`` (per joint) of ``start``."""
        step = rng.uniform(-max_move, max_move, size=start.shape)
        return np.clip(start + step, self.low, self.high)

    def held(self, configurations: np.ndarray, arms: slice | np.ndarray) -> np.ndarray:
        """A constant reference at the given configurations (derivatives zero)."""
        rows = configurations[arms]
        out = np.zeros((len(rows), REFERENCE_ORDER + 1, self.spec.n_joints))
        out[:, 0] = rows
        return out
