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

import contextlib
import inspect
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
    resolve_class,
)
from elastic_gym.observers.base import Observer
from elastic_gym.observers.registry import OBSERVERS, make_observer, observer_class
from elastic_gym.observers.wrappers import ObserverWrapper
from elastic_gym.parallel import run_jobs, user_failure
from elastic_gym.process_pool import WorkerDiedError
from elastic_gym.robots.catalog import get_robot
from elastic_gym.robots.spec import RobotSpec

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
    series: TimeSeries | None  # None when the run failed before its first sample
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
def env_robot(env_id: str, env_kwargs: dict) -> RobotSpec:
    """The robot of an env id with kwargs (from the registry, without building the env)."""
    robot = env_kwargs.get("robot", gym.spec(env_id).kwargs.get("robot"))
    return robot if isinstance(robot, RobotSpec) else get_robot(robot)


def is_elastic(env_id: str, env_kwargs: dict) -> bool:
    """Whether the env's robot has elastic joints (from its spec, without building the env)."""
    return env_robot(env_id, env_kwargs).elastic


def _entry_class(
    entry: ControllerEntry | SourceEntry, path: str, base: type, lookup: Callable[[str], type]
) -> type:
    """The class of a controller/observer entry: explicit ``class`` or registry name."""
    if entry.cls is not None:
        cls = resolve_class(entry.cls, f"{path}.class")
        if not issubclass(cls, base):
            raise ScenarioError(f"{path}.class", f"{cls!r} is not a subclass of {base.__name__}")
        return cls
    try:
        return lookup(entry.name)
    except ImportError as exc:
        raise ScenarioError(
            f"{path}.name",
            f"{base.__name__.lower()} {entry.name!r} is "
            f"registered but not available in this installation ({exc})",
        ) from None


def _controller_lookup(name: str) -> type[Controller]:
    return BUILTIN_CONTROLLERS.get(name) or controller_class(name)


def check_options(cls: type, options: dict, path: str, fixed: dict | None = None) -> None:
    """Bind ``options`` to the constructor ``cls(model, dt, **fixed, **options)`` without
    calling it: unknown, duplicate or missing options raise :class:`ScenarioError` with
    the field path, e.g. ``controllers[1].options.omegaa: unexpected option``."""
    fixed = fixed or {}
    for key in options:
        if key in fixed:
            raise ScenarioError(f"{path}.options.{key}", f"fixed to {fixed[key]!r} by the name")
    try:
        signature = inspect.signature(cls)
    except (TypeError, ValueError):  # no introspectable signature: checked when built
        return
    parameters = list(signature.parameters.values())[2:]  # after (model, dt)
    if not any(p.kind is p.VAR_KEYWORD for p in parameters):
        valid = [
            p.name
            for p in parameters
            if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY) and p.name not in fixed
        ]
        for key in options:
            if key not in valid:
                raise ScenarioError(f"{path}.options.{key}", f"unexpected option; valid: {valid}")
    try:
        signature.bind(None, None, **fixed, **options)
    except TypeError as exc:
        raise ScenarioError(
            f"{path}.options", f"{cls.__name__}(model, dt, **options): {exc}"
        ) from None


def plan_runs(scenario: Scenario) -> tuple[list[RunSpec], list[SkippedRun]]:
    """All runs of the grid, and the combinations skipped because they do not apply.

    Raises :class:`ScenarioError` naming the field when a controller or observer module
    is not available (registry names are checked when the scenario is loaded) or when
    its options do not fit its constructor (:func:`check_options`).
    """
    controllers, sources = [], []
    for i, entry in enumerate(scenario.controllers):
        cls = _entry_class(entry, f"controllers[{i}]", Controller, _controller_lookup)
        check_options(cls, entry.options, f"controllers[{i}]")
        controllers.append((entry, cls))
    for i, entry in enumerate(scenario.state_sources):
        cls = _entry_class(entry, f"state_sources[{i}]", Observer, observer_class)
        fixed = OBSERVERS[entry.name][2] if entry.cls is None else {}
        check_options(cls, entry.options, f"state_sources[{i}]", fixed)
        sources.append((entry, cls))
    axis_values = itertools.product(*(values for _, values in scenario.axes))
    runs: list[RunSpec] = []
    skipped: list[SkippedRun] = []
    for env, variations in itertools.product(scenario.envs, axis_values):
        kwargs = scenario.env_kwargs(env, variations)
        kind = "elastic" if is_elastic(env.id, kwargs) else "rigid"
        base_labels = {"env": env.label}
        base_labels.update(
            {name: v.label for (name, _), v in zip(scenario.axes, variations, strict=True)}
        )
        for error, seed in itertools.product(scenario.model_errors, scenario.seeds):
            for (controller, c_cls), (source, o_cls) in itertools.product(controllers, sources):
                if controller.sources is not None and source.label not in controller.sources:
                    continue
                labels = {
                    **base_labels,
                    "model_error": error.label,
                    "controller": controller.label,
                    "source": source.label,
                    "seed": seed,
                }
                reason = _inapplicable(kind, c_cls, o_cls, controller, source)
                if reason:
                    skipped.append(SkippedRun(labels, reason))
                    continue
                runs.append(
                    RunSpec(
                        index=len(runs),
                        labels=labels,
                        env_id=env.id,
                        env_kwargs=kwargs,
                        reset_options=env.reset_options,
                        duration=scenario.duration,
                        seed=seed,
                        controller=controller,
                        controller_cls=c_cls,
                        source=source,
                        observer_cls=o_cls,
                        model_error=error.values,
                    )
                )
    return runs, skipped


def _inapplicable(
    kind: str, c_cls: type, o_cls: type, controller: ControllerEntry, source: SourceEntry
) -> str:
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
        return TimeSeries(
            self.time,
            self.q,
            self.q_ref,
            self.dq_ref,
            self.torque,
            self.error,
            state_names,
            self.theta,
        ).truncated(self.length)


def run_model(env: gym.Env, spec: RunSpec):
    """The nominal model of the run's controller and observer (with its model error)."""
    model = env.unwrapped.model
    return model.perturbed(**spec.model_error) if spec.model_error else model


def build_observer(env: gym.Env, spec: RunSpec, model) -> ObserverWrapper:
    """The run's state source on ``model``, wrapped around ``env``."""
    source, dt = spec.source, env.unwrapped.control_dt
    observer = (
        make_observer(source.name, model.copy(), dt, **source.options)
        if source.cls is None
        else spec.observer_cls(model.copy(), dt, **source.options)
    )
    estimate = (
        None
        if source.initial_estimate is None
        else np.asarray(source.initial_estimate, dtype=float)
    )
    return ObserverWrapper(env, observer, initial_estimate=estimate)


def build_controller(env: gym.Env, spec: RunSpec, model) -> Controller:
    """The run's controller on ``model``."""
    return spec.controller_cls(model.copy(), env.unwrapped.control_dt, **spec.controller.options)


def run_episode(spec: RunSpec) -> RunResult:
    """Run one episode of ``spec.duration`` seconds and compute its metrics.

    Never raises for what happens inside the run: an episode that diverges ends early
    with status ``"terminated: <reason>"`` (the env's or the wrapper's termination); any
    exception (in the setup, or in a user's controller or observer during the loop)
    gives status ``"failed: <Type>: <message>"`` with the metrics of the samples recorded
    until then (none, ``series=None``, when the setup failed).
    """
    env = recorder = None
    wall = 0.0
    try:
        env = gym.make(spec.env_id, **{**spec.env_kwargs, "episode_time": None})
        model = run_model(env, spec)
        wrapped = build_observer(env, spec, model)
        controller = build_controller(env, spec, model)
        base = env.unwrapped
        steps = round(spec.duration / base.control_dt)
        recorder = _Recorder(steps, base.n_joints, wrapped.observer.state_dim, base.robot.elastic)
        names, tracking = wrapped.state_names, base.task.name != "excitation"
        start = time.perf_counter()
        try:
            status = _simulate(wrapped, controller, recorder, spec, steps)
        finally:
            wall = time.perf_counter() - start
    except BaseException as exc:
        if not user_failure(exc):
            raise
        status = failed_status(exc)
    finally:
        if env is not None:
            with contextlib.suppress(Exception):
                env.close()
    if recorder is None or recorder.length == 0:
        return RunResult(spec, status, {}, None, wall)
    series = recorder.series(names)
    try:
        metrics = compute_metrics(series, tracking=tracking)
    except Exception as exc:
        return RunResult(spec, failed_status(exc, "metrics: "), {}, series, wall)
    metrics["sim_time"] = float(series.time[-1])
    metrics["sim_wall_ratio"] = metrics["sim_time"] / wall if wall > 0 else float("nan")
    return RunResult(spec, status, metrics, series, wall, recorder.diagnostics)


def describe_failure(exc: BaseException) -> str:
    """``"<Type>: <message>"`` on one line (``SystemExit``: the exit code it was given;
    a ``KeyboardInterrupt``: that it came from the code, not from a signal)."""
    if isinstance(exc, SystemExit):
        message = f"sys.exit({exc.code!r}) called by the run's code"
    elif isinstance(exc, KeyboardInterrupt):
        message = "raised by the run's code (no signal)"
    else:
        message = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {message}"


def failed_status(exc: BaseException, where: str = "") -> str:
    """``"failed: <Type>: <message>"`` (:func:`describe_failure`)."""
    return f"failed: {where}{describe_failure(exc)}"


def crashed_result(spec: RunSpec, exc: WorkerDiedError) -> RunResult:
    """The row of a run whose worker process died while running it (no samples kept)."""
    return RunResult(spec, failed_status(exc), {}, None, 0.0)


def _simulate(
    wrapped: ObserverWrapper, controller: Controller, recorder: _Recorder, spec: RunSpec, steps: int
) -> str:
    """The closed loop; returns the status. Exceptions of the reset propagate, those of
    the loop end it with a ``failed`` status (the samples recorded so far are kept)."""
    with np.errstate(all="ignore"):
        obs, info = wrapped.reset(seed=spec.seed, options=spec.reset_options or None)
        controller.reset(obs, public_info(info))
        recorder.record(info)
        for _ in range(steps):
            try:
                action = controller(obs, public_info(info))
                obs, _, terminated, _, info = wrapped.step(action)
            except BaseException as exc:
                if not user_failure(exc):
                    raise
                return failed_status(exc)
            if terminated:
                return f"terminated: {info.get('termination_reason') or 'terminated'}"
            recorder.record(info)
    return STATUS_OK


# ---------------------------------------------------------------------------- execution
def execute(
    runs: Sequence[RunSpec],
    workers: int | None = None,
    backend: str = "process",
    progress: bool = True,
) -> list[RunResult]:
    """Run all episodes in parallel (:func:`elastic_gym.parallel.run_jobs`), in order.

    ``workers=1`` with the process backend runs in this process (single-threaded BLAS
    meanwhile). Every result stays in memory with its time series; :func:`compare
    <elastic_gym.evaluation.compare>` streams them to disk instead.
    """
    return run_jobs(
        run_episode,
        runs,
        workers=workers,
        backend=backend,
        progress=progress,
        label="runs",
        describe=describe_run,
        crashed=crashed_result,
    )


def describe_run(spec: RunSpec) -> str:
    return f"run {spec.labels}"
