"""Runs of a comparison: planning the grid, one episode, and the parallel execution.

One run = (env id + kwargs, reset options, seed, state source, controller, model
error of the controller/observer). In :func:`run_episode` the env is wrapped by an
:class:`~elastic_gym.observers.ObserverWrapper` (the ``"true"`` source is the oracle),
the observer and the controller are built on the env's nominal model
``env.unwrapped.model`` — ``.perturbed(**model_error)`` when the run has a model
error — and the controller sees only the observation ``{"state", "reference"}`` and
:func:`~elastic_gym.controllers.public_info` of ``info``, never the truth.

:func:`execute` runs the episodes with :func:`elastic_gym.parallel.run_jobs`: spawned
worker processes (every env is created inside its worker) or Ray (``backend="ray"``,
the same job function), with a progress bar.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import gymnasium as gym
import numpy as np

import elastic_gym  # noqa: F401 - registers the env ids
from elastic_gym.controllers.base import Controller, public_info
from elastic_gym.controllers.registry import controller_class
from elastic_gym.evaluation.metrics import TimeSeries, compute_metrics
from elastic_gym.evaluation.open_loop import BUILTIN_CONTROLLERS
from elastic_gym.evaluation.scenario import (
    ControllerEntry,
    Scenario,
    ScenarioError,
    SourceEntry,
    merge,
    resolve_class,
)
from elastic_gym.observers.base import Observer
from elastic_gym.observers.registry import make_observer, observer_class
from elastic_gym.observers.wrappers import ObserverWrapper
from elastic_gym.parallel import run_jobs
from elastic_gym.robots.catalog import get_robot
from elastic_gym.robots.spec import RobotSpec

UNLIMITED_STEPS = 2**62  # the run length is set by the scenario's duration, not TimeLimit
STATUS_OK = "ok"


@dataclass(frozen=True)
class RunSpec:
    """Everything a worker needs for one episode (picklable)."""

    index: int
    labels: dict  # identity columns -> label (env, axes..., model_error, controller, source, seed)
    env_id: str
    env_kwargs: dict
    reset_options: dict
    duration: float
    seed: int
    controller: ControllerEntry
    controller_cls: type[Controller]
    source: SourceEntry
    observer_cls: type[Observer]
    model_error: dict

    @property
    def group(self) -> tuple:
        """Labels of the scenario this run belongs to (all but controller, source, seed)."""
        return tuple(v for k, v in self.labels.items() if k not in ("controller", "source", "seed"))


@dataclass
class RunResult:
    """Outcome of one run: status (``"ok"``, ``"terminated: ..."``, ``"failed: ..."``).

    ``diagnostics``: the largest value over the run of each numeric entry of the
    observer's ``diagnostics`` (e.g. ``jumps`` of the hybrid gain, ``cond_TA``).
    """

    spec: RunSpec
    status: str
    metrics: dict
    series: TimeSeries
    wall_time: float
    diagnostics: dict = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return self.status == STATUS_OK


@dataclass(frozen=True)
class SkippedRun:
    labels: dict
    reason: str


# ---------------------------------------------------------------------------- planning
def is_elastic(env_id: str, env_kwargs: dict) -> bool:
    """Whether the env's robot has elastic joints (from its spec, without building the env)."""
    robot = env_kwargs.get("robot", gym.spec(env_id).kwargs.get("robot"))
    spec = robot if isinstance(robot, RobotSpec) else get_robot(robot)
    return spec.elastic


def _entry_class(entry: ControllerEntry | SourceEntry, path: str, base: type,
                 lookup: Callable[[str], type]) -> type:
    """The class of a controller/observer entry: explicit ``class`` or registry name."""
    if entry.cls is not None:
        cls = resolve_class(entry.cls, f"{path}.class")
        if not issubclass(cls, base):
            raise ScenarioError(f"{path}.class", f"{cls!r} is not a subclass of {base.__name__}")
        return cls
    try:
        return lookup(entry.name)
    except ImportError as exc:
        raise ScenarioError(f"{path}.name", f"{base.__name__.lower()} {entry.name!r} is "
                            f"registered but not available in this installation ({exc})") from None


def _controller_lookup(name: str) -> type[Controller]:
    return BUILTIN_CONTROLLERS.get(name) or controller_class(name)


def plan_runs(scenario: Scenario) -> tuple[list[RunSpec], list[SkippedRun]]:
    """All runs of the grid, and the combinations skipped because they do not apply.

    Raises :class:`ScenarioError` naming the field when a controller or observer module
    is not available (registry names are checked when the scenario is loaded).
    """
    controllers = [(c, _entry_class(c, f"controllers[{i}]", Controller, _controller_lookup))
                   for i, c in enumerate(scenario.controllers)]
    sources = [(s, _entry_class(s, f"state_sources[{i}]", Observer, observer_class))
               for i, s in enumerate(scenario.state_sources)]
    axis_values = itertools.product(*(values for _, values in scenario.axes))
    runs: list[RunSpec] = []
    skipped: list[SkippedRun] = []
    for env, variations in itertools.product(scenario.envs, axis_values):
        kwargs = env.kwargs
        for variation in variations:
            kwargs = merge(kwargs, variation.values)
        kind = "elastic" if is_elastic(env.id, kwargs) else "rigid"
        base_labels = {"env": env.label}
        base_labels.update({name: v.label for (name, _), v in zip(scenario.axes, variations,
                                                                  strict=True)})
        for error, seed in itertools.product(scenario.model_errors, scenario.seeds):
            for (controller, c_cls), (source, o_cls) in itertools.product(controllers, sources):
                if controller.sources is not None and source.label not in controller.sources:
                    continue
                labels = {**base_labels, "model_error": error.label,
                          "controller": controller.label, "source": source.label, "seed": seed}
                reason = _inapplicable(kind, c_cls, o_cls, controller, source)
                if reason:
                    skipped.append(SkippedRun(labels, reason))
                    continue
                runs.append(RunSpec(
                    index=len(runs), labels=labels, env_id=env.id, env_kwargs=kwargs,
                    reset_options=env.reset_options, duration=scenario.duration, seed=seed,
                    controller=controller, controller_cls=c_cls, source=source,
                    observer_cls=o_cls, model_error=error.values,
                ))
    return runs, skipped


def _inapplicable(kind: str, c_cls: type, o_cls: type, controller: ControllerEntry,
                  source: SourceEntry) -> str:
    if kind not in c_cls.applies_to:
        return f"controller {controller.name!r} applies to {sorted(c_cls.applies_to)} arms"
    if kind not in o_cls.applies_to:
        return f"observer {source.name!r} applies to {sorted(o_cls.applies_to)} arms"
    return ""


# ---------------------------------------------------------------------------- one episode
class _Recorder:
    """Preallocated time series of one episode."""

    def __init__(self, steps: int, n: int, state_dim: int, elastic: bool) -> None:
        size = steps + 1
        self.time = np.zeros(size)
        self.q, self.q_ref, self.dq_ref, self.torque = (np.zeros((size, n)) for _ in range(4))
        self.theta = np.zeros((size, n)) if elastic else None
        self.error = np.zeros((size, state_dim))
        self.length = 0
        self.diagnostics: dict[str, float] = {}

    def _track_diagnostics(self, diagnostics: dict) -> None:
        for key, value in diagnostics.items():
            if isinstance(value, (bool, int, float, np.number)):
                self.diagnostics[key] = max(float(value), self.diagnostics.get(key, -np.inf))

    def record(self, info: dict) -> None:
        k = self.length
        truth, reference = info["true_state"], info["reference"]
        self.time[k] = info["time"]
        self.q[k] = truth["q"]
        self.q_ref[k] = reference["q"]
        self.dq_ref[k] = reference["dq"]
        self.torque[k] = info["torque"]
        self.error[k] = info["estimation_error"]
        if self.theta is not None:
            self.theta[k] = truth["theta"]
        self._track_diagnostics(info.get("observer_diagnostics", {}))
        self.length = k + 1

    def series(self, state_names: tuple[str, ...]) -> TimeSeries:
        return TimeSeries(self.time, self.q, self.q_ref, self.dq_ref, self.torque, self.error,
                          state_names, self.theta).truncated(self.length)


def _wrap(env: gym.Env, spec: RunSpec) -> tuple[ObserverWrapper, Controller]:
    """The observer wrapper and the controller of a run, on the (perturbed) nominal model."""
    base = env.unwrapped
    model = base.model.perturbed(**spec.model_error) if spec.model_error else base.model
    source = spec.source
    observer = (
        make_observer(source.name, model.copy(), base.control_dt, **source.options)
        if source.cls is None
        else spec.observer_cls(model.copy(), base.control_dt, **source.options)
    )
    estimate = (None if spec.source.initial_estimate is None
                else np.asarray(spec.source.initial_estimate, dtype=float))
    wrapped = ObserverWrapper(env, observer, initial_estimate=estimate)
    controller = spec.controller_cls(model.copy(), base.control_dt, **spec.controller.options)
    return wrapped, controller


def run_episode(spec: RunSpec) -> RunResult:
    """Run one episode of ``spec.duration`` seconds and compute its metrics.

    Setup errors (bad options) raise; an episode that diverges ends early with status
    ``"terminated: <reason>"`` (the env's or the wrapper's termination) or
    ``"failed: <error>"`` (a numerical error raised inside the loop).
    """
    env = gym.make(spec.env_id, **{**spec.env_kwargs, "episode_time": None})
    try:
        wrapped, controller = _wrap(env, spec)
        base = env.unwrapped
        steps = round(spec.duration / base.control_dt)
        recorder = _Recorder(steps, base.n_joints, wrapped.observer.state_dim, base.robot.elastic)
        status = STATUS_OK
        start = time.perf_counter()
        with np.errstate(all="ignore"):
            obs, info = wrapped.reset(seed=spec.seed, options=spec.reset_options or None)
            controller.reset(obs, public_info(info))
            recorder.record(info)
            for _ in range(steps):
                try:
                    action = controller(obs, public_info(info))
                    obs, _, terminated, _, info = wrapped.step(action)
                except (ValueError, ArithmeticError) as exc:
                    status = f"failed: {type(exc).__name__}: {exc}"
                    break
                if terminated:
                    status = f"terminated: {info.get('termination_reason') or 'terminated'}"
                    break
                recorder.record(info)
        wall = time.perf_counter() - start
    finally:
        env.close()
    series = recorder.series(wrapped.state_names)
    metrics = compute_metrics(series, tracking=base.task.name != "excitation")
    metrics["sim_time"] = float(series.time[-1])
    metrics["sim_wall_ratio"] = metrics["sim_time"] / wall if wall > 0 else float("nan")
    return RunResult(spec, status, metrics, series, wall, recorder.diagnostics)


# ---------------------------------------------------------------------------- execution
def execute(
    runs: Sequence[RunSpec],
    workers: int | None = None,
    backend: str = "process",
    progress: bool = True,
) -> list[RunResult]:
    """Run all episodes in parallel (:func:`elastic_gym.parallel.run_jobs`), in order.

    ``workers=1`` with the process backend runs in this process (no pool, and the BLAS
    threading of this process: set ``OPENBLAS_NUM_THREADS=1`` for small matrices).
    """
    return run_jobs(run_episode, runs, workers=workers, backend=backend, progress=progress,
                    label="runs", describe=lambda spec: f"run {spec.labels}")
