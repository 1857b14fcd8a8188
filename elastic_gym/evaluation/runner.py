"""Runs of a comparison: planning the grid, one world of runs, and the parallel execution.

One run = (env id + kwargs, reset options, seed, state source, controller, model error of
the controller/observer). Runs that may share a world (:mod:`~elastic_gym.evaluation.groups`)
run as one vector env + vector observer + vector controller (:func:`run_group`), built on the
env's nominal model (``.perturbed(**model_error)`` with a model error); the controller sees
only ``{"state", "reference"}`` (on the source ``sensors``: the sensor observation) and the
public info, never the truth. An arm that terminates
gets its status row while its batch mates go on; a world that raises is rerun one run at a
time, so only the run that raised fails.

:func:`execute` runs the worlds with :func:`elastic_gym.runtime.parallel.for_each_result`: spawned
worker processes or Ray (``backend="ray"``, the same job function), with a progress bar.
"""

from __future__ import annotations

import contextlib
import inspect
import itertools
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import cast

import gymnasium as gym
import numpy as np

import elastic_gym  # noqa: F401 - registers the env ids
from elastic_gym.controllers.base import Controller, public_info
from elastic_gym.controllers.registry import CONTROLLERS
from elastic_gym.controllers.vector import VectorController, make_vector_controller
from elastic_gym.envs.arm_env import ArmEnv
from elastic_gym.envs.vector_env import ArmVectorEnv
from elastic_gym.evaluation.controllers import comparison_controller
from elastic_gym.evaluation.groups import DEFAULT_BATCH_SIZE, RunGroup, plan_groups
from elastic_gym.evaluation.metrics import ArmSeries, TimeSeries, compute_arm_metrics
from elastic_gym.evaluation.scenario import (
    ControllerEntry,
    Scenario,
    ScenarioError,
    SourceEntry,
    resolve_class,
)
from elastic_gym.observers.base import Observer
from elastic_gym.observers.registry import OBSERVERS, make_observer, source_class
from elastic_gym.observers.sensors import RawSensors
from elastic_gym.observers.vector import ObserverWrapper as VectorObserverWrapper
from elastic_gym.observers.vector import SensorWrapper
from elastic_gym.robots.catalog import get_robot
from elastic_gym.robots.spec import RobotSpec
from elastic_gym.runtime.parallel import (
    DEFAULT_BACKEND,
    for_each_result,
    resolve_workers,
    user_failure,
    worker_processes,
)
from elastic_gym.runtime.process_pool import WorkerDiedError, WorkerPool, refers_to_main

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
    ``episode_return``: the sum of the env's rewards over the run's control periods.
    ``controller_diagnostics``: the run's entry, at its end, of each per-arm array in the
    vector controller's ``arm_diagnostics`` (e.g. ``saturated_actions`` of a trained policy).
    """

    spec: RunSpec
    status: str
    metrics: dict
    series: TimeSeries | None  # None when the run failed before its first sample
    wall_time: float
    diagnostics: dict = field(default_factory=dict)
    episode_return: float = float("nan")
    controller_diagnostics: dict = field(default_factory=dict)

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


def arm_env(env: gym.Env) -> ArmEnv:
    """The elastic_gym env under the wrappers of ``env``."""
    return cast(ArmEnv, env.unwrapped)


def arm_vector_env(envs: gym.vector.VectorEnv) -> ArmVectorEnv:
    """The elastic_gym vector env under the wrappers of ``envs``."""
    return cast(ArmVectorEnv, envs.unwrapped)


def _entry_class(
    entry: ControllerEntry | SourceEntry, path: str, base: type, lookup: Callable[[str], type]
) -> type:
    """The class of a controller/observer entry: explicit ``class`` or registry name."""
    if entry.cls is not None:
        return resolve_class(entry.cls, f"{path}.class", (base,))
    try:
        return lookup(entry.name)
    except ImportError as exc:
        raise ScenarioError(
            f"{path}.name",
            f"{base.__name__.lower()} {entry.name!r} is "
            f"registered but not available in this installation ({exc})",
        ) from None


def check_options(cls: type, options: dict, path: str, fixed: dict | None = None) -> None:
    """Bind ``options`` to the constructor ``cls(model, dt, **fixed, **options)`` without
    calling it: unknown, duplicate or missing options raise :class:`ScenarioError` with
    the field path, e.g. ``controllers[1].options.omegaa: unexpected option``."""
    fixed = fixed or {}
    try:
        signature: inspect.Signature | None = inspect.signature(cls)
    except (TypeError, ValueError):  # no introspectable signature: checked when built
        signature = None
    parameters = list(signature.parameters.values())[2:] if signature else []  # after (model, dt)
    any_name = signature is None or any(p.kind is p.VAR_KEYWORD for p in parameters)
    valid = [
        p.name
        for p in parameters
        if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY) and p.name not in fixed
    ]
    problems = {key: f"fixed to {fixed[key]!r} by the name" for key in options if key in fixed}
    if not any_name:  # the first problem is refused, a fixed option before an unknown one
        unknown = [key for key in options if key not in valid and key not in fixed]
        problems |= dict.fromkeys(unknown, f"unexpected option; valid: {valid}")
    if problems:
        key, problem = next(iter(problems.items()))
        raise ScenarioError(f"{path}.options.{key}", problem)
    if signature is None:
        return
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
    controllers: list[tuple[ControllerEntry, type[Controller]]] = []
    sources: list[tuple[SourceEntry, type[Observer]]] = []
    for i, entry in enumerate(scenario.controllers):
        cls = _entry_class(entry, f"controllers[{i}]", Controller, comparison_controller)
        check_options(cls, entry.options, f"controllers[{i}]")
        controllers.append((entry, cls))
    for i, source_entry in enumerate(scenario.state_sources):
        cls = _entry_class(source_entry, f"state_sources[{i}]", Observer, source_class)
        named = source_entry.cls is None and source_entry.name in OBSERVERS
        fixed = OBSERVERS[source_entry.name][2] if named else {}
        check_options(cls, source_entry.options, f"state_sources[{i}]", fixed)
        if issubclass(cls, RawSensors) and source_entry.initial_estimate is not None:
            raise ScenarioError(
                f"state_sources[{i}].initial_estimate", "raw sensors have no estimate to start"
            )
        sources.append((source_entry, cls))
    axis_values = itertools.product(*(values for _, values in scenario.axes))
    runs: list[RunSpec] = []
    skipped: list[SkippedRun] = []
    for env, variations in itertools.product(scenario.envs, axis_values):
        kwargs = scenario.env_kwargs(env, variations)
        kind = env_robot(env.id, kwargs).kind
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
    kind: str,
    c_cls: type[Controller],
    o_cls: type[Observer],
    controller: ControllerEntry,
    source: SourceEntry,
) -> str:
    if kind not in c_cls.applies_to:
        return f"controller {controller.name!r} applies to {sorted(c_cls.applies_to)} arms"
    if kind not in o_cls.applies_to:
        return f"observer {source.name!r} applies to {sorted(o_cls.applies_to)} arms"
    if issubclass(o_cls, RawSensors) and not c_cls.takes_sensors:
        return f"controller {controller.name!r} needs a state source, not raw sensors"
    return ""


# ---------------------------------------------------------------------------- one world
class _Recorder:
    """Preallocated time series of the N arms of one world; arm i's samples stop at
    ``lengths[i]`` (its run ended)."""

    def __init__(self, steps: int, n_arms: int, n: int, state_dim: int, elastic: bool) -> None:
        size = steps + 1
        self.time = np.zeros(size)
        self.q, self.q_ref, self.dq_ref, self.torque = (
            np.zeros((size, n_arms, n)) for _ in range(4)
        )
        self.theta = np.zeros((size, n_arms, n)) if elastic else None
        self.error = np.zeros((size, n_arms, state_dim))
        self.saturated = np.zeros((size, n_arms), dtype=bool)
        self.lengths = np.zeros(n_arms, dtype=int)
        self.row = 0
        self._peaks: dict[str, np.ndarray] = {}

    def _track_diagnostics(self, diagnostics: dict, recording: np.ndarray) -> None:
        for key, value in diagnostics.items():
            column = np.asarray(value)
            if column.dtype.kind not in "biuf":
                continue
            peak = self._peaks.setdefault(key, np.full(len(self.lengths), -np.inf))
            np.maximum(peak, np.where(recording, column.astype(float), -np.inf), out=peak)

    @property
    def diagnostics(self) -> list[dict[str, float]]:
        """Per arm: the largest value of each numeric observer diagnostic it recorded."""
        return [
            {key: float(peak[i]) for key, peak in self._peaks.items() if peak[i] > -np.inf}
            for i in range(len(self.lengths))
        ]

    def record(self, info: dict, recording: np.ndarray) -> None:
        """Row ``row`` of every arm; it counts for the ``recording`` arms only."""
        k = self.row
        truth, reference = info["true_state"], info["reference"]
        self.time[k] = info["time"][np.argmax(recording)]  # an ended arm's clock restarted
        self.q[k] = truth["q"]
        self.q_ref[k] = reference["q"]
        self.dq_ref[k] = reference["dq"]
        self.torque[k] = info["torque"]
        self.error[k] = info["estimation_error"]
        self.saturated[k] = info["torque_saturated"]
        if self.theta is not None:
            self.theta[k] = truth["theta"]
        self._track_diagnostics(info.get("observer_diagnostics", {}), recording)
        self.lengths[recording] = k + 1
        self.row = k + 1

    def series(self, state_names: tuple[str, ...]) -> ArmSeries:
        k = self.row
        return ArmSeries(
            self.time[:k],
            self.q[:k],
            self.q_ref[:k],
            self.dq_ref[:k],
            self.torque[:k],
            self.error[:k],
            state_names,
            self.lengths.copy(),
            None if self.theta is None else self.theta[:k],
            self.saturated[:k],
        )


def run_model(env, spec: RunSpec):
    """The nominal model of the run's controller and observer (with its model error);
    ``env``: a single or vector env."""
    model = env.unwrapped.model
    return model.perturbed(**spec.model_error) if spec.model_error else model


def make_observer_of(spec: RunSpec, model, dt: float) -> Observer:
    """The run's state source on ``model`` (one arm's observer)."""
    source = spec.source
    if source.cls is None:
        return make_observer(source.name, model.copy(), dt, **source.options)
    return spec.observer_cls(model.copy(), dt, **source.options)


def initial_estimate(spec: RunSpec) -> np.ndarray | None:
    estimate = spec.source.initial_estimate
    return None if estimate is None else np.asarray(estimate, dtype=float)


def build_vector_controller(spec: RunSpec, model, dt: float, n_arms: int) -> VectorController:
    """The run's controller for ``n_arms`` arms: a built-in's batched twin by its registry
    name, one copy per arm of any other class (:func:`make_vector_controller`)."""
    named = spec.controller.cls is None and spec.controller.name in CONTROLLERS
    kind = spec.controller.name if named else spec.controller_cls
    return make_vector_controller(kind, model.copy(), dt, n_arms, **spec.controller.options)


@dataclass
class World:
    """The vector env of a group's arms with its vector observer and vector controller."""

    envs: gym.vector.VectorEnv
    wrapped: VectorObserverWrapper
    controller: VectorController

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self.envs.close()


def make_group_env(group: RunGroup) -> gym.vector.VectorEnv:
    """The vector env of the group's arms (no episode limit: the runs set the duration)."""
    kwargs = {**group.env_kwargs(), "episode_time": None}
    return gym.make_vec(
        group.first.env_id, len(group), vectorization_mode="vector_entry_point", **kwargs
    )


def build_observer_wrapper(
    envs: gym.vector.VectorEnv, spec: RunSpec, model
) -> VectorObserverWrapper:
    """The run's state source on ``model`` for every arm of ``envs`` (raw sensors: the
    sensor observation itself, :class:`~elastic_gym.observers.vector.SensorWrapper`)."""
    if issubclass(spec.observer_cls, RawSensors):
        return SensorWrapper(envs)
    observer = make_observer_of(spec, model, arm_vector_env(envs).control_dt)
    return VectorObserverWrapper(envs, observer, initial_estimate=initial_estimate(spec))


def build_world(group: RunGroup) -> World:
    """Build the world of ``group`` (exceptions propagate; nothing is left open)."""
    spec = group.first
    envs = make_group_env(group)
    try:
        model = run_model(envs, spec)
        wrapped = build_observer_wrapper(envs, spec, model)
        controller = build_vector_controller(
            spec, model, arm_vector_env(envs).control_dt, len(group)
        )
    except BaseException:
        envs.close()
        raise
    return World(envs, wrapped, controller)


def run_group(group: RunGroup) -> list[RunResult]:
    """Run the group's episodes in one world (:func:`build_world`), ``duration`` seconds
    each, and compute their metrics; one result per run, in the group's order.

    Never raises for what happens inside a run: an arm whose episode diverges ends early
    with status ``"terminated: <reason>"`` (the env's or the observer wrapper's
    termination) while the others go on (it is no longer recorded, its torque is zero);
    an exception (in the setup, or in a controller or observer during the loop) ends the
    world, and each of its runs is run again in a world of its own (the same episode,
    bit for bit), where the one that raises gets status ``"failed: <Type>: <message>"``
    with the metrics of the samples recorded until then (none, ``series=None``, when the
    setup failed). ``wall_time`` is the world's loop time divided by its arms.
    """
    world = recorder = loop = None
    wall = 0.0
    try:
        world = build_world(group)
        base = arm_vector_env(world.envs)
        steps = round(group.first.duration / base.control_dt)
        state_dim = world.wrapped.observer.state_dim
        recorder = _Recorder(steps, len(group), base.n_joints, state_dim, base.batch.robot.elastic)
        start = time.perf_counter()
        loop = ClosedLoop(world, group)
        try:
            _simulate(loop, recorder, steps)
        finally:
            wall = time.perf_counter() - start
        statuses = loop.statuses
    except BaseException as exc:
        if not user_failure(exc):
            raise
        if len(group) > 1:
            return [result for spec in group.runs for result in run_group(RunGroup((spec,)))]
        statuses = [failed_status(exc)]
    finally:
        if world is not None:
            world.close()
    if recorder is None or recorder.row == 0:
        return [
            RunResult(spec, status, {}, None, wall)
            for spec, status in zip(group.runs, statuses, strict=True)
        ]
    assert world is not None and loop is not None  # the recorder has rows
    tracking = arm_vector_env(world.envs).batch.task.name != "excitation"
    names = world.wrapped.state_names
    results = _results(group, statuses, recorder, names, tracking, wall / len(group))
    controller_diagnostics = getattr(world.controller, "arm_diagnostics", {})
    for i, result in enumerate(results):
        result.episode_return = float(loop.returns[i])
        result.controller_diagnostics = {
            key: float(values[i]) for key, values in controller_diagnostics.items()
        }
    return results


def _results(
    group: RunGroup,
    statuses: list[str],
    recorder: _Recorder,
    names: tuple[str, ...],
    tracking: bool,
    wall: float,
) -> list[RunResult]:
    series = recorder.series(names)
    try:
        all_metrics = compute_arm_metrics(series, tracking=tracking)
    except Exception as exc:
        status = failed_status(exc, "metrics: ")
        return [
            RunResult(spec, status, {}, series.arm(i), wall) for i, spec in enumerate(group.runs)
        ]
    results = []
    diagnostics = recorder.diagnostics
    for i, (spec, status, metrics) in enumerate(
        zip(group.runs, statuses, all_metrics, strict=True)
    ):
        one = series.arm(i)
        metrics["sim_time"] = float(one.time[-1])
        metrics["sim_wall_ratio"] = metrics["sim_time"] / wall if wall > 0 else float("nan")
        results.append(RunResult(spec, status, metrics, one, wall, diagnostics[i]))
    return results


def run_episode(spec: RunSpec) -> RunResult:
    """Run one episode alone (a world of one arm, :func:`run_group`)."""
    return run_group(RunGroup((spec,)))[0]


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


def crashed_results(group: RunGroup, exc: WorkerDiedError) -> list[RunResult]:
    """The rows of a world whose worker process died while running it: a run alone gets
    the failed row (no samples kept); a world of several runs runs each of them again in
    a worker process of its own, so that only the run that kills its worker fails and
    its batch mates get their rows."""
    if len(group) == 1:
        return [RunResult(group.first, failed_status(exc), {}, None, 0.0)]
    results: dict[int, RunResult] = {}
    for_each_result(
        run_group,
        [RunGroup((spec,)) for spec in group.runs],
        lambda _, alone: results.update((r.spec.index, r) for r in alone),
        workers=min(2, len(group)),
        progress=False,
        describe=describe_group,
        crashed=crashed_results,
    )
    return [results[spec.index] for spec in group.runs]


def _public(info: dict) -> dict:
    """The public info of the arms (time and reference, without Gymnasium's masks)."""
    public = public_info(info)
    public["reference"] = {
        key: value for key, value in public["reference"].items() if not key.startswith("_")
    }
    return public


class ClosedLoop:
    """The closed loop of a world's arms: each arm's status, and which arms still run.

    An arm whose episode ends (terminated by the env or the observer wrapper) is no
    longer recorded and gets zero torque (its status: ``"terminated: <reason>"``, with the
    observer's error in parentheses for a non-finite estimate); the env restarts it
    (autoreset) and its controller is reset then, so that it stays finite while its batch
    mates go on.
    Exceptions propagate.
    """

    def __init__(self, world: World, group: RunGroup) -> None:
        self.world = world
        self.group = group
        n_arms = len(group)
        self.statuses = [STATUS_OK] * n_arms
        self.running = np.ones(n_arms, dtype=bool)
        self.returns = np.zeros(n_arms)  # each arm's rewards while it runs
        self._ended = np.zeros(n_arms, dtype=bool)  # restarted by the autoreset next step
        self.info: dict = {}
        self._obs: dict = {}

    def start(self) -> dict:
        """Reset every arm and its controller; returns the info."""
        self.reset()
        self.reset_controllers()
        return self.info

    def reset(self) -> None:
        """Reset every arm with its seed and the reset options (env and observer)."""
        options = self.group.first.reset_options or None
        self._obs, self.info = self.world.wrapped.reset(seed=self.group.seeds, options=options)

    def reset_controllers(self) -> None:
        arms = np.arange(len(self.group))
        self.world.controller.reset_arms(self._obs, _public(self.info), arms)

    def advance(self) -> bool:
        """One control period of every arm; returns whether any arm still runs."""
        controller = self.world.controller
        restarted = np.flatnonzero(self._ended)
        if len(restarted):
            controller.reset_arms(self._obs, _public(self.info), restarted)
        action = np.where(self.running[:, None], controller(self._obs, _public(self.info)), 0.0)
        self._obs, reward, terminated, truncated, self.info = self.world.wrapped.step(action)
        self.returns[self.running] += reward[self.running]
        self._ended = terminated | truncated
        errors = self.info.get("observer_error", [None] * len(self.statuses))
        for i in np.flatnonzero(self.running & self._ended):
            reason = self.info["termination_reason"][i] or "terminated"
            why = f" ({' '.join(errors[i].split())})" if errors[i] else ""
            self.statuses[i] = f"terminated: {reason}{why}"
        self.running &= ~self._ended
        return bool(self.running.any())


def _simulate(loop: ClosedLoop, recorder: _Recorder, steps: int) -> None:
    """Run the closed loop ``steps`` control periods, recording."""
    with np.errstate(all="ignore"):
        recorder.record(loop.start(), loop.running)
        for _ in range(steps):
            if not loop.advance():
                break
            recorder.record(loop.info, loop.running)


# ---------------------------------------------------------------------------- execution
def execute(
    runs: Sequence[RunSpec],
    workers: int | None = None,
    backend: str = DEFAULT_BACKEND,
    progress: bool = True,
    batch_size: int = DEFAULT_BATCH_SIZE,
) -> list[RunResult]:
    """Run all episodes in parallel, grouped into worlds of at most ``batch_size`` arms
    (:func:`~elastic_gym.evaluation.groups.plan_groups`, :func:`run_group`); the results
    in run order.

    ``workers=1`` with the process backend runs in one worker process (in this one, with
    single-threaded BLAS, when the runs refer to classes of ``__main__``:
    :func:`~elastic_gym.runtime.parallel.for_each_result`). Every result stays in memory with its
    time series; :func:`compare <elastic_gym.evaluation.compare>` streams them to disk
    instead.
    """
    n_workers = resolve_workers(workers, len(runs), backend)
    results: dict[int, RunResult] = {}
    run_groups(
        plan_groups(runs, batch_size, n_workers),
        lambda _, group_results: results.update((r.spec.index, r) for r in group_results),
        n_workers,
        backend,
        progress,
    )
    return [results[spec.index] for spec in runs]


def group_workers(groups, workers: int, backend: str) -> contextlib.AbstractContextManager:
    """The worker processes that will run ``groups`` (:func:`run_groups`), started now so
    that the pre-run check (:func:`~elastic_gym.evaluation.preflight.preflight`) runs in
    one of them while the others start: a context manager giving the pool, or None where
    the runs need none (Ray; one worker for jobs that refer to ``__main__``, run in this
    process)."""
    if backend != "process" or (workers == 1 and refers_to_main(run_group, groups)):
        return contextlib.nullcontext()
    pool = worker_processes(min(workers, len(groups)))
    pool.start(run_group, list(groups))
    return pool


def run_groups(
    groups, on_results, workers: int, backend: str, progress: bool, pool: WorkerPool | None = None
) -> None:
    """Run the worlds ``groups`` (:func:`run_group`) on ``workers`` processes (of ``pool``
    when given) or Ray, calling ``on_results(group, results)`` as each ends; a world whose
    worker died gives its runs' rows through :func:`crashed_results`; the progress bar
    counts runs."""
    for_each_result(
        run_group,
        groups,
        on_results,
        workers=workers,
        backend=backend,
        progress=progress,
        label="runs",
        describe=describe_group,
        crashed=crashed_results,
        size=len,
        pool=pool,
    )


def describe_group(group: RunGroup) -> str:
    first = group.first.labels
    return f"run {first}" if len(group) == 1 else f"group of {len(group)} runs like {first}"
