"""The pre-run check of a comparison's execution, and an estimate of its duration.

Part of the execute stage, before the first run:
[`preflight`][elastic_gym.evaluation.preflight.preflight] builds, once each and in
worker processes, what the runs will build: every env with its kwargs and each axis value,
its reset with the reset options, each model error's perturbed model, every controller and
observer (trained policies loaded). A failure, or user code that ends that process while
it is built, raises `ScenarioError` with the field path before any compute is spent;
errors of the closed loop itself are left to the runs' statuses. The estimate times
``SAMPLE_TIME`` of closed loop of each (env, controller, state source) in CPU time (at
most ``SAMPLE_WALL`` of wall time: a controller that waits spends little CPU per step)
and divides the total by the share of a core each worker can expect (from the load average).
"""

from __future__ import annotations

import contextlib
import itertools
import os
import time
from collections.abc import Generator, Iterator, Sequence
from dataclasses import dataclass
from typing import NoReturn

import gymnasium as gym
import numpy as np

from elastic_gym.evaluation.closed_loop import ClosedLoop
from elastic_gym.evaluation.episodes import describe_failure
from elastic_gym.evaluation.grid import RunSpec
from elastic_gym.evaluation.groups import RunGroup
from elastic_gym.evaluation.scenario import Scenario, ScenarioError
from elastic_gym.evaluation.world import (
    World,
    arm_env,
    arm_vector_env,
    build_observer_wrapper,
    build_vector_controller,
    make_group_env,
    run_model,
)
from elastic_gym.model.identified import identified_robot_model, load_identified_model
from elastic_gym.runtime.parallel import DEFAULT_BACKEND, for_each_result, user_failure
from elastic_gym.runtime.process_pool import WorkerDiedError, WorkerPool

SAMPLE_TIME = 0.05  # CPU s of closed loop timed per (env, controller, source) combination
SAMPLE_STEPS = (3, 1000)  # fewest and most steps of a sample
SAMPLE_WALL = 0.5  # wall s after which a sample stops (a controller that sleeps or waits)
SAMPLE_ARMS = 8  # arms of the world a combination is timed in


@dataclass(frozen=True)
class Estimate:
    """Expected CPU time of all runs (s), and the wall time on ``workers`` workers that
    each get ``share`` of a core."""

    cpu_seconds: float
    workers: int
    share: float

    @property
    def seconds(self) -> float:
        return self.cpu_seconds / self.workers / self.share

    def __str__(self) -> str:
        if self.seconds < 90:
            return f"about {self.seconds:.0f} s"
        if self.seconds < 5400:
            return f"about {self.seconds / 60:.0f} min"
        return f"about {self.seconds / 3600:.1f} h"


@contextlib.contextmanager
def _named(path: str | None) -> Iterator[None]:
    """What the code inside raises for itself (`user_failure`:
    any exception, ``sys.exit``, its own ``KeyboardInterrupt``) becomes a
    `ScenarioError` naming ``path``; with ``path`` None it only ends the code
    inside (a sample's closed loop: the runs report it)."""
    try:
        yield
    except BaseException as exc:
        if not user_failure(exc):
            raise
        if path is not None:
            _refuse(path, exc)


def _refuse(path: str, exc: BaseException, when: str = "") -> NoReturn:
    """The refusal of a pre-run check: `ScenarioError` naming ``path`` and what
    failed (``when``: at which step, for a worker process that died)."""
    raise ScenarioError(path, f"{describe_failure(exc)}{' ' if when else ''}{when}") from None


def _make_env(entry_id: str, kwargs: dict, path: str) -> gym.Env:
    with _named(path):
        return gym.make(entry_id, **kwargs)


def _combo(spec: RunSpec) -> tuple:
    return spec.labels["env"], spec.labels["controller"], spec.labels["source"]


@dataclass(frozen=True)
class _EnvCheck:
    """Job: the checks of env entry ``index`` that need no controller (`preflight`)."""

    scenario: Scenario
    index: int

    def run(self) -> float:
        scenario, entry, path = self.scenario, self.scenario.envs[self.index], self.path
        env = _make_env(entry.id, scenario.env_kwargs(entry), f"{path}.kwargs")
        try:
            _check_duration(scenario.duration, env, path)
            _check_reset(env, entry.reset_options, scenario.seeds[0], path)
            _check_axes(scenario, entry, path)
            _check_model_errors(env, scenario)
        finally:
            env.close()
        return 0.0

    @property
    def path(self) -> str:
        return f"envs[{self.index}]"

    def after_death(self, exc: WorkerDiedError) -> float:
        """The process running the checks died: refused."""
        _refuse(self.path, exc, "while the env was checked")


STAGES = ("env", "observer", "controller", "reset", "loop")  # of a sample, in order
_WHILE = {
    "env": "while the vector env of its runs was built",
    "observer": "while the observer was built",
    "controller": "while the controller was built",
    "reset": "at the reset of the arms and their observer",
}


@dataclass(frozen=True)
class _Sample:
    """Job: build the world of ``group`` and time its closed loop (`_stages`), up to
    the end of ``stage``."""

    group: RunGroup
    paths: tuple[str, str]  # of the controller and the state source
    env_path: str
    stage: str = "loop"

    def run(self) -> float:
        with contextlib.closing(_stages(self.group, self.paths, self.env_path)) as costs:
            return next(itertools.islice(costs, STAGES.index(self.stage), None))

    def at(self, stage: str) -> _Sample:
        return _Sample(self.group, self.paths, self.env_path, stage)

    def after_death(self, exc: WorkerDiedError) -> float:
        """The process running the sample died. Up to the reset: refused, naming the
        field of what was being built. In the whole sample: run again stage by stage
        (the first stage that kills its process is refused); if only the closed loop
        does, the cost of the setup (the closed loop is left to the runs)."""
        if self.stage == "loop":
            return _run_checks([self.at(stage) for stage in STAGES[:-1]])[-1]
        controller_path, source_path = self.paths
        path = {
            "env": self.env_path,
            "observer": f"{source_path}.options",
            "controller": f"{controller_path}.options",
            "reset": source_path,
        }[self.stage]
        _refuse(path, exc, _WHILE[self.stage])


def _check(job: _EnvCheck | _Sample) -> float | ScenarioError:
    """Run one job of the pre-run check: its cost, or the refusal it found."""
    try:
        return job.run()
    except ScenarioError as exc:
        return exc


def _run_checks(
    jobs: list[_EnvCheck | _Sample],
    pool: WorkerPool | None = None,
    workers: int = 1,
    backend: str = DEFAULT_BACKEND,
) -> list[float]:
    """Every job's cost, the jobs shared by ``workers`` worker processes (of ``pool``, or
    started for them; Ray's with ``backend="ray"``); raises the refusal of the first job
    in job order that has one (a job's own, or that of a job whose process died:
    ``after_death``, which checks again in processes of its own) as soon as every job
    before it has passed, so that the same scenario is always refused for the same
    reason."""
    costs: dict[int, float] = {}
    refusals: dict[int, ScenarioError] = {}

    def deliver(index: int, outcome: float | ScenarioError | WorkerDiedError) -> None:
        if isinstance(outcome, WorkerDiedError):
            try:
                outcome = jobs[index].after_death(outcome)
            except ScenarioError as exc:
                outcome = exc
        if isinstance(outcome, ScenarioError):
            refusals[index] = outcome
        else:
            costs[index] = outcome
        if refusals:
            first = min(refusals)
            if all(i in costs for i in range(first)):
                raise refusals[first]

    for_each_result(
        _check,
        jobs,
        deliver,
        workers=workers,
        progress=False,
        describe=lambda job: f"the pre-run check {job}",
        crashed=lambda job, exc: exc,
        pool=pool,
        backend=backend,
    )
    return [costs[i] for i in range(len(jobs))]


def preflight(
    scenario: Scenario,
    groups: Sequence[RunGroup],
    workers: int,
    pool: WorkerPool | None = None,
    backend: str = DEFAULT_BACKEND,
) -> Estimate:
    """Build everything the runs of ``groups`` need once (see the module docstring);
    raise `ScenarioError` on the first failure; return the estimated wall time.

    The checks run in worker processes (`for_each_result`: one started for them, or
    shared by the workers of ``pool``, the runs' own, when given; with
    ``backend="ray"``, on the Ray workers that will run the runs): user code that
    ends that process (``os._exit``, a signal, a segmentation fault) while its
    controller, observer or world is built is refused naming the field; in the closed
    loop it is left to the runs (their rows say so).
    """
    controller_index = {c.label: i for i, c in enumerate(scenario.controllers)}
    source_index = {s.label: i for i, s in enumerate(scenario.state_sources)}
    combos: dict[tuple, RunGroup] = {}
    for group in groups:
        combos.setdefault(_combo(group.first), RunGroup(group.runs[:SAMPLE_ARMS]))
    jobs: list[_EnvCheck | _Sample] = []
    keys: dict[int, tuple] = {}  # job index of each combination's sample -> combination
    for i, entry in enumerate(scenario.envs):
        if not any(key[0] == entry.label for key in combos):
            continue
        jobs.append(_EnvCheck(scenario, i))
        for key, sample in combos.items():
            if key[0] == entry.label:
                paths = (
                    f"controllers[{controller_index[key[1]]}]",
                    f"state_sources[{source_index[key[2]]}]",
                )
                keys[len(jobs)] = key
                jobs.append(_Sample(sample, paths, f"envs[{i}].kwargs"))
    used = min(workers, len(groups))  # the runs' processes (``pool``'s size)
    if backend == "ray":  # on the Ray runtime of the runs (started here, with their CPUs)
        costs = _run_checks(jobs, workers=workers, backend=backend)
    else:
        costs = _run_checks(jobs, pool, used if pool is not None else 1)
    cost = {key: costs[index] for index, key in keys.items()}
    # a group's runs may come from several env entries (per-arm plants): its first run's
    # sample stands for all of them
    total = sum(cost[_combo(group.first)] * len(group) for group in groups)
    return Estimate(total, used, cpu_share(used))


def cpu_share(workers: int) -> float:
    """The share of a core each of ``workers`` new processes can expect: cores / (other
    runnable processes + workers), at most 1; the others are the 1-minute load average
    less this process (1 where the load average is not available)."""
    try:
        others = max(0.0, os.getloadavg()[0] - 1.0)
    except (AttributeError, OSError):
        return 1.0
    return min(1.0, (os.cpu_count() or 1) / (others + workers))


def _check_duration(duration: float, env: gym.Env, path: str) -> None:
    """A run must last at least one control period (else it has no step to measure)."""
    control_dt = arm_env(env).control_dt
    if not duration >= control_dt:
        raise ScenarioError(
            "duration",
            f"{duration!r} s is shorter than the control period {control_dt!r} s of "
            f"{path}: its runs would have no step",
        )


def _check_reset(env: gym.Env, options: dict, seed: int, path: str) -> None:
    with _named(f"{path}.reset_options" if options else path):
        env.reset(seed=seed, options=options or None)


def _check_axes(scenario: Scenario, entry, path: str) -> None:
    for axis, values in scenario.axes:
        for j, variation in enumerate(values):
            if not variation.values:
                continue
            env = _make_env(
                entry.id, scenario.env_kwargs(entry, (variation,)), f"axes.{axis}[{j}] (on {path})"
            )
            env.close()


def _check_model_errors(env: gym.Env, scenario: Scenario) -> None:
    model = arm_env(env).model
    for i, path in enumerate(scenario.models):
        if load_identified_model(path).robot == model.spec.name:
            with _named(f"models[{i}]"):
                model = identified_robot_model(path, model)
    for i, variation in enumerate(scenario.model_errors):
        if variation.values:
            with _named(f"model_errors[{i}]"):
                model.perturbed(**variation.values)


def _stages(group: RunGroup, paths: tuple[str, str], env_path: str) -> Generator[float, None, None]:
    """Build the world of ``group`` (errors name their field) and time ``SAMPLE_TIME`` of
    its closed loop (at most ``SAMPLE_WALL`` of wall time), yielding after each of
    `STAGES` the CPU time of one of its runs so far (s): the setup's, then the whole
    run's."""
    controller_path, source_path = paths
    spec, n_arms = group.first, len(group)
    start = time.process_time()
    with _named(env_path):
        envs = make_group_env(group)
    try:
        yield (time.process_time() - start) / n_arms
        model = run_model(envs, spec)
        dt = arm_vector_env(envs).control_dt
        with _named(f"{source_path}.options"):
            wrapped = build_observer_wrapper(envs, spec, model)
        yield (time.process_time() - start) / n_arms
        with _named(f"{controller_path}.options"):
            controller = build_vector_controller(spec, model, dt, n_arms)
        yield (time.process_time() - start) / n_arms
        loop = ClosedLoop(World(envs, wrapped, controller), group)
        with _named(source_path):
            loop.reset()
        setup = time.process_time() - start
        yield setup / n_arms
        steps, elapsed = 0, 0.0
        with np.errstate(all="ignore"), _named(None):
            loop.reset_controllers()
            loop.advance()  # warms caches up
            tick, stop = time.process_time(), time.monotonic() + SAMPLE_WALL
            while steps < SAMPLE_STEPS[1] and (
                steps < SAMPLE_STEPS[0] or (elapsed < SAMPLE_TIME and time.monotonic() < stop)
            ):
                running = loop.advance()
                steps += 1
                elapsed = time.process_time() - tick
                if not running:
                    break
    finally:
        envs.close()
    step = elapsed / steps if steps else 0.0
    yield (setup + step * round(spec.duration / dt)) / n_arms
