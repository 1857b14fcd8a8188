"""Checks of a comparison before its first run, and an estimate of its duration.

:func:`preflight` builds, once each, what the runs will build: every env with its kwargs
and each axis value, its reset with the reset options, each model error's perturbed
model, every controller and observer (trained policies loaded). A failure raises
:class:`~elastic_gym.evaluation.scenario.ScenarioError` with the field path before any
compute is spent; errors of the closed loop itself are left to the runs' statuses.
The estimate times ``SAMPLE_TIME`` of closed loop of each (env, controller, state source)
in CPU time and divides the total by the share of a core each worker can expect (from
the load average). :func:`check_plot_names` refuses labels whose figure file names would
be too long or coincide.
"""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import gymnasium as gym
import numpy as np

from elastic_gym.evaluation.groups import RunGroup
from elastic_gym.evaluation.output import MAX_NAME_BYTES, plot_file_name
from elastic_gym.evaluation.runner import (
    ClosedLoop,
    RunSpec,
    World,
    arm_env,
    arm_vector_env,
    build_observer_wrapper,
    build_vector_controller,
    describe_failure,
    make_group_env,
    run_model,
)
from elastic_gym.evaluation.scenario import IDENTITY_COLUMNS, Scenario, ScenarioError
from elastic_gym.parallel import single_threaded, user_failure

SAMPLE_TIME = 0.05  # CPU s of closed loop timed per (env, controller, source) combination
SAMPLE_STEPS = (3, 1000)  # fewest and most steps of a sample
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


def _error(path: str, exc: BaseException) -> ScenarioError:
    return ScenarioError(path, describe_failure(exc))


@contextlib.contextmanager
def _named(path: str) -> Iterator[None]:
    """What the code inside raises for itself (:func:`~elastic_gym.parallel.user_failure`:
    any exception, ``sys.exit``, its own ``KeyboardInterrupt``) becomes a
    :class:`ScenarioError` naming ``path``."""
    try:
        yield
    except BaseException as exc:
        if not user_failure(exc):
            raise
        raise _error(path, exc) from None


@contextlib.contextmanager
def _left_to_the_runs() -> Iterator[None]:
    """What the closed loop raises for itself ends the sample; the runs report it."""
    try:
        yield
    except BaseException as exc:
        if not user_failure(exc):
            raise


def _make_env(entry_id: str, kwargs: dict, path: str) -> gym.Env:
    try:
        return gym.make(entry_id, **kwargs)
    except Exception as exc:
        raise _error(path, exc) from None


def _combo(spec: RunSpec) -> tuple:
    return spec.labels["env"], spec.labels["controller"], spec.labels["source"]


def preflight(scenario: Scenario, groups: Sequence[RunGroup], workers: int) -> Estimate:
    """Build everything the runs of ``groups`` need once (see the module docstring);
    raise :class:`ScenarioError` on the first failure; return the estimated wall time."""
    controller_index = {c.label: i for i, c in enumerate(scenario.controllers)}
    source_index = {s.label: i for i, s in enumerate(scenario.state_sources)}
    error_index = {v.label: i for i, v in enumerate(scenario.model_errors)}
    combos: dict[tuple, RunGroup] = {}
    for group in groups:
        combos.setdefault(_combo(group.first), RunGroup(group.runs[:SAMPLE_ARMS]))
    cost: dict[tuple, float] = {}
    with single_threaded():
        for i, entry in enumerate(scenario.envs):
            if not any(key[0] == entry.label for key in combos):
                continue
            path = f"envs[{i}]"
            env = _make_env(entry.id, scenario.env_kwargs(entry), f"{path}.kwargs")
            try:
                _check_duration(scenario.duration, env, path)
                _check_reset(env, entry.reset_options, scenario.seeds[0], path)
                _check_axes(scenario, entry, path)
                _check_model_errors(env, scenario, error_index)
                for key, sample in combos.items():
                    if key[0] != entry.label:
                        continue
                    paths = (
                        f"controllers[{controller_index[key[1]]}]",
                        f"state_sources[{source_index[key[2]]}]",
                    )
                    cost[key] = _sample(sample, paths, f"{path}.kwargs")
            finally:
                env.close()
    # a group's runs may come from several env entries (per-arm plants): its first run's
    # sample stands for all of them
    total = sum(cost[_combo(group.first)] * len(group) for group in groups)
    workers = min(workers, len(groups))
    return Estimate(total, workers, cpu_share(workers))


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
    try:
        env.reset(seed=seed, options=options or None)
    except Exception as exc:
        raise _error(f"{path}.reset_options" if options else path, exc) from None


def _check_axes(scenario: Scenario, entry, path: str) -> None:
    for axis, values in scenario.axes:
        for j, variation in enumerate(values):
            if not variation.values:
                continue
            env = _make_env(
                entry.id, scenario.env_kwargs(entry, (variation,)), f"axes.{axis}[{j}] (on {path})"
            )
            env.close()


def _check_model_errors(env: gym.Env, scenario: Scenario, error_index: dict) -> None:
    model = arm_env(env).model
    for variation in scenario.model_errors:
        if variation.values:
            try:
                model.perturbed(**variation.values)
            except Exception as exc:
                raise _error(f"model_errors[{error_index[variation.label]}]", exc) from None


def _sample(group: RunGroup, paths: tuple[str, str], env_path: str) -> float:
    """Build the world of ``group`` (errors name their field) and time ``SAMPLE_TIME`` of
    its closed loop; returns the CPU time of one of its runs (s), setup included."""
    controller_path, source_path = paths
    spec, n_arms = group.first, len(group)
    start = time.process_time()
    with _named(env_path):
        envs = make_group_env(group)
    try:
        model = run_model(envs, spec)
        dt = arm_vector_env(envs).control_dt
        with _named(f"{source_path}.options"):
            wrapped = build_observer_wrapper(envs, spec, model)
        with _named(f"{controller_path}.options"):
            controller = build_vector_controller(spec, model, dt, n_arms)
        loop = ClosedLoop(World(envs, wrapped, controller), group)
        with _named(source_path):
            loop.reset()
        setup = time.process_time() - start
        steps, elapsed = 0, 0.0
        with np.errstate(all="ignore"), _left_to_the_runs():
            loop.reset_controllers()
            loop.advance()  # warms caches up
            tick = time.process_time()
            while steps < SAMPLE_STEPS[1] and (steps < SAMPLE_STEPS[0] or elapsed < SAMPLE_TIME):
                running = loop.advance()
                steps += 1
                elapsed = time.process_time() - tick
                if not running:
                    break
    finally:
        envs.close()
    step = elapsed / steps if steps else 0.0
    return (setup + step * round(spec.duration / dt)) / n_arms


def check_plot_names(scenario: Scenario, runs: Sequence[RunSpec]) -> None:
    """Refuse labels whose figure file names are too long or coincide (see module doc)."""
    columns = [IDENTITY_COLUMNS[0], *scenario.axis_names, IDENTITY_COLUMNS[1]]
    fields = ["envs", *(f"axes.{name}" for name in scenario.axis_names), "model_errors"]
    seen: dict[str, tuple] = {}
    for group in dict.fromkeys(spec.group for spec in runs):
        name = plot_file_name(group)
        if len(name.encode()) > MAX_NAME_BYTES:
            longest = max(range(len(group)), key=lambda k: len(str(group[k])))
            raise ScenarioError(
                fields[longest],
                f"the labels {list(group)} give a figure file name of "
                f"{len(name.encode())} bytes (the limit is {MAX_NAME_BYTES}): shorten the "
                f"{columns[longest]} label {group[longest]!r}",
            )
        other = seen.setdefault(name, group)
        if other != group:
            differ = next(k for k in range(len(group)) if group[k] != other[k])
            raise ScenarioError(
                fields[differ],
                f"the {columns[differ]} labels {other[differ]!r} and "
                f"{group[differ]!r} give the same figure file name {name!r} (only letters, "
                "digits, '.', '+' and '-' are kept): make them differ in those",
            )
