"""Tasks: what the arm is asked to do, selected by the env kwarg ``task``.

* ``tracking``: follow smooth C^4 rest-to-rest motions between random reachable
  configurations (or given ``waypoints``); the reference carries q_d .. q_d^(4).
* ``regulation``: go to a goal configuration and stay there (constant reference).
* ``excitation``: an open-loop torque (e.g. g(q) + (cos t/2, -cos t) of Cristofaro &
  De Luca, Example 1) to which the action is added; for observer-only studies.
* ``fourier``: a Fourier-series reference and a torque dither, for identification
  (``elastic_gym.envs.fourier``).

Every task's options are a pydantic model (``TrackingOptions`` ...): unknown keys and bad
values raise ``ValueError`` naming the field (``task_options.max_move: ...``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Annotated

import numpy as np
from numba import njit
from pydantic import Field, StrictBool

from elastic_gym.envs.fourier import FourierTask
from elastic_gym.envs.task_base import REFERENCE_ORDER, Task, per_joint_option
from elastic_gym.envs.trajectories import (
    RestToRestPath,
    _rest_to_rest_kernel,
    rest_to_rest,
    timing_coefficients,
)
from elastic_gym.model import RobotModel
from elastic_gym.model.chain import _gravity_kernel
from elastic_gym.robots.spec import RobotSpec
from elastic_gym.validation import (
    Finite,
    FiniteNumbers,
    NonNegativeFinite,
    PositiveFinite,
    StrictModel,
    lookup,
    shaped,
    validated,
)


class RegulationOptions(StrictModel):
    """Options of [`RegulationTask`][elastic_gym.envs.tasks.RegulationTask] (see it); the lengths
    are checked by the task."""

    goal: FiniteNumbers | None = None
    start: FiniteNumbers | None = None
    max_move: PositiveFinite | None = None  # None: the robot's


class TrackingOptions(StrictModel):
    """Options of [`TrackingTask`][elastic_gym.envs.tasks.TrackingTask] (see it)."""

    waypoints: Annotated[tuple[tuple[Finite, ...], ...], Field(min_length=1)] | None = None
    n_moves: Annotated[int, Field(strict=True, ge=1)] = 2
    move_time: PositiveFinite = 1.0
    dwell_time: NonNegativeFinite = 0.25
    max_move: PositiveFinite | None = None  # None: the robot's
    start: FiniteNumbers | None = None


class ExcitationOptions(StrictModel):
    """Options of [`ExcitationTask`][elastic_gym.envs.tasks.ExcitationTask] (see it)."""

    gravity_compensation: StrictBool = True
    amplitude: FiniteNumbers | None = None
    frequency: FiniteNumbers | None = None
    phase: FiniteNumbers = 0.0
    offset: FiniteNumbers = 0.0
    start: FiniteNumbers | None = None


@dataclass
class TrackingTask(Task):
    """Rest-to-rest C^4 motions (9th-order timing law) through random or given waypoints.

    Options: ``waypoints`` (list of configurations; default random), ``n_moves`` (2),
    ``move_time`` (s, 1.0), ``dwell_time`` (s, 0.25), ``max_move`` (rad, robot default),
    ``start`` (first configuration; default random).
    """

    options: TrackingOptions = field(default_factory=TrackingOptions)
    options_model = TrackingOptions

    def __post_init__(self) -> None:
        self.name = "tracking"
        n, o = self.spec.n_joints, self.options
        self.n_moves, self.move_time, self.dwell_time = o.n_moves, o.move_time, o.dwell_time
        self._given: np.ndarray | None = None
        if o.waypoints is not None:
            self._given = shaped(o.waypoints, (None, n), "task_options.waypoints")
        self._start = None if o.start is None else per_joint_option(o.start, n, "start")
        self._max_move = self.spec.max_move if o.max_move is None else o.max_move
        if self._given is not None:
            n_points = len(self._given) + (self._start is not None)
        else:
            n_points = self.n_moves + 1
        self.paths = np.zeros((self.n_arms, n_points, n))  # the waypoints of every arm

    def reset_arm(self, arm: int, rng: np.random.Generator) -> np.ndarray:
        if self._given is not None:
            points = self._given
            if self._start is not None:
                points = np.vstack([self._start, points])
        else:
            first = self._start if self._start is not None else self.sample_configuration(rng)
            moves = [first]
            for _ in range(self.n_moves):
                moves.append(self.sample_move(rng, moves[-1], self._max_move))
            points = np.asarray(moves)
        self.paths[arm] = points
        return points[0].copy()

    @property
    def duration(self) -> float:
        """Time (s) of the last waypoint."""
        return (self.paths.shape[1] - 1) * (self.move_time + self.dwell_time)

    def path(self, arm: int = 0) -> RestToRestPath:
        """The motion of one arm."""
        return RestToRestPath(self.paths[arm].copy(), self.move_time, self.dwell_time)

    def reference(self, t: np.ndarray, arms: slice | np.ndarray = slice(None)) -> np.ndarray:
        return rest_to_rest(t, self.paths[arms], self.move_time, self.dwell_time, REFERENCE_ORDER)

    def compiled_arguments(self) -> tuple[tuple, tuple]:
        path = (self.paths, float(self.move_time), float(self.dwell_time), _COEFFICIENTS)
        return no_open_loop_torque(self.model), (True, path)


@dataclass
class RegulationTask(Task):
    """Go to ``goal`` (default: random within ``max_move`` of the start) and stay.

    Options: ``goal``, ``start``, ``max_move``.
    """

    options: RegulationOptions = field(default_factory=RegulationOptions)
    options_model = RegulationOptions

    def __post_init__(self) -> None:
        self.name = "regulation"
        n, o = self.spec.n_joints, self.options
        self._goal = None if o.goal is None else per_joint_option(o.goal, n, "goal")
        self._start = None if o.start is None else per_joint_option(o.start, n, "start")
        self._max_move = self.spec.max_move if o.max_move is None else o.max_move
        self.targets = np.zeros((self.n_arms, n))

    def reset_arm(self, arm: int, rng: np.random.Generator) -> np.ndarray:
        start = self._start if self._start is not None else self.sample_configuration(rng)
        self.targets[arm] = (
            self._goal if self._goal is not None else self.sample_move(rng, start, self._max_move)
        )
        return start.copy()

    def reference(self, t: np.ndarray, arms: slice | np.ndarray = slice(None)) -> np.ndarray:
        return self.held(self.targets, arms)

    def compiled_arguments(self) -> tuple[tuple, tuple]:
        return no_open_loop_torque(self.model), HELD_REFERENCE


@njit(cache=True)
def _excitation_kernel(
    t, q, tau, frequency, phase, offset, amplitude, gravity_compensation, gravity
):
    """tau = (offset + amplitude cos(frequency t + phase)) [+ g(q)] per arm and joint
    (g(q) where ``gravity_compensation``, from the chain's
    [`gravity_arguments`][elastic_gym.model.chain.SerialChain.gravity_arguments]
    ``gravity``)."""
    if gravity_compensation:
        _gravity_kernel(q, tau, gravity)
    else:
        tau[:] = 0.0
    for k in range(tau.shape[0]):
        for j in range(tau.shape[1]):
            cosine = np.cos(frequency[j] * t[k] + phase[j])
            tau[k, j] = (offset[j] + amplitude[j] * cosine) + tau[k, j]


@njit(cache=True, inline="always")  # a compiled layer would cost a compile of its own
def open_loop_torque_kernel(t, q, out, arguments):
    """[`Task.external_torque`][elastic_gym.envs.task_base.Task.external_torque] at times
    ``t`` (N,) and configurations ``q`` into ``out`` for compiled callers; returns False
    (``out`` untouched) for a task without one. ``arguments``: the first of the task's
    [`compiled_arguments`][elastic_gym.envs.task_base.Task.compiled_arguments], (whether
    the task has an open-loop torque, `_excitation_kernel`'s arguments after the output)."""
    active, excitation = arguments
    if not active:
        return False
    _excitation_kernel(t, q, out, *excitation)
    return True


@njit(cache=True, inline="always")  # a compiled layer would cost a compile of its own
def reference_kernel(t, arguments, out):
    """[`Task.reference`][elastic_gym.envs.task_base.Task.reference] of every arm at times
    ``t`` (N,) into ``out`` (N, 5, n) for compiled callers; ``out`` untouched for a
    reference that holds still during an episode. ``arguments``: the second of the task's
    [`compiled_arguments`][elastic_gym.envs.task_base.Task.compiled_arguments], (whether
    the reference moves, `_rest_to_rest_kernel`'s arguments after t)."""
    moving, path = arguments
    if moving:
        _rest_to_rest_kernel(t, *path, out)


def no_open_loop_torque(model: RobotModel) -> tuple:
    """`open_loop_torque_kernel`'s ``arguments`` of a task without an open-loop torque:
    the flag False and arguments of the types an open-loop torque has (never read), so
    that every task's control period is one compiled signature."""
    unused = np.zeros(0)
    return False, (unused, unused, unused, unused, False, model.chain.gravity_arguments())


# `_rest_to_rest_kernel`'s ``coefficients`` (the timing law's rows 0 .. REFERENCE_ORDER)
_COEFFICIENTS = timing_coefficients(REFERENCE_ORDER)

# `reference_kernel`'s ``arguments`` of a reference that holds still: the flag False and a
# path of the types a moving one has (never read), one compiled signature for every task.
HELD_REFERENCE = (False, (np.zeros((0, 0, 0)), 0.0, 0.0, _COEFFICIENTS))


@dataclass
class ExcitationTask(Task):
    """Open-loop torque tau_ext(t, q) = [g(q)] + offset + amplitude * cos(frequency t + phase).

    Cristofaro & De Luca Example 1 (eq. 18) is ``amplitude=(1, -1), frequency=(0.5, 1)``;
    Example 2 (eq. 19) is ``amplitude=(1, 1), frequency=(1, 2), phase=(0, -pi/2),
    offset=(0, -1)``. Default: gravity compensation plus 5 % of the torque limit at
    0.5 .. 1.5 rad/s. The reference holds the start configuration.

    Options: ``gravity_compensation`` (True), ``amplitude``, ``frequency`` (rad/s),
    ``phase`` (rad), ``offset`` (N m), ``start``.
    """

    options: ExcitationOptions = field(default_factory=ExcitationOptions)
    options_model = ExcitationOptions

    def __post_init__(self) -> None:
        self.name = "excitation"
        n, o = self.spec.n_joints, self.options
        self.gravity_compensation = o.gravity_compensation
        limit = np.asarray(self.spec.torque_limit)
        self._amplitude = (
            0.05 * limit if o.amplitude is None else per_joint_option(o.amplitude, n, "amplitude")
        )
        self._frequency = (
            np.linspace(0.5, 1.5, n)
            if o.frequency is None
            else per_joint_option(o.frequency, n, "frequency")
        )
        self._phase = per_joint_option(o.phase, n, "phase")
        self._offset = per_joint_option(o.offset, n, "offset")
        self._start = None if o.start is None else per_joint_option(o.start, n, "start")
        self.holds = np.zeros((self.n_arms, n))

    def reset_arm(self, arm: int, rng: np.random.Generator) -> np.ndarray:
        self.holds[arm] = self._start if self._start is not None else self.sample_configuration(rng)
        return self.holds[arm].copy()

    def reference(self, t: np.ndarray, arms: slice | np.ndarray = slice(None)) -> np.ndarray:
        return self.held(self.holds, arms)

    def external_torque(self, t: np.ndarray, q: np.ndarray) -> np.ndarray:
        tau = np.empty(q.shape)
        _excitation_kernel(t, q, tau, *self._torque_arguments())
        return tau

    def _torque_arguments(self) -> tuple:
        """`_excitation_kernel`'s arguments after t, q and the output."""
        gravity = self.model.chain.gravity_arguments()
        excitation = self._frequency, self._phase, self._offset, self._amplitude
        return (*excitation, self.gravity_compensation, gravity)

    def compiled_arguments(self) -> tuple[tuple, tuple]:
        return (True, self._torque_arguments()), HELD_REFERENCE


TASKS: dict[str, type[Task]] = {
    "tracking": TrackingTask,
    "regulation": RegulationTask,
    "excitation": ExcitationTask,
    "fourier": FourierTask,
}


def make_task(
    name: str, spec: RobotSpec, model: RobotModel, options: dict | None, n_arms: int = 1
) -> Task:
    """Instantiate a task for ``n_arms`` arms by name, its options validated by its model
    (errors read ``task_options.<field>: ...``)."""
    cls = lookup(TASKS, name, "task")
    config = validated(cls.options_model, options, "task_options")
    return cls(spec=spec, model=model, n_arms=n_arms, options=config)  # type: ignore[call-arg]
