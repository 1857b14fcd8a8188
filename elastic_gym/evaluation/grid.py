"""The runs of a comparison's grid: what each run is, as plain data, no env built.

One run ([`RunSpec`][elastic_gym.evaluation.grid.RunSpec]) = env id + kwargs, reset
options, duration, seed, state source and controller (entries and their classes) and the
model error of the controller/observer. [`plan_runs`][elastic_gym.evaluation.grid.plan_runs]
expands the scenario's grid (envs x robustness axes x model errors x seeds x controllers x
state sources) in that order and sets aside the combinations that do not apply (a
controller or observer for another kind of arm, raw sensors for a controller that needs a
state), each with its reason. The classes are resolved and their options bound to their
constructors here, so that a typo is refused naming its field before anything is built.
"""

from __future__ import annotations

import inspect
import itertools
from collections.abc import Callable
from dataclasses import dataclass

import gymnasium as gym

import elastic_gym  # noqa: F401 - registers the env ids
from elastic_gym.controllers.base import Controller
from elastic_gym.evaluation.controllers import comparison_controller
from elastic_gym.evaluation.scenario import (
    ControllerEntry,
    Scenario,
    ScenarioError,
    SourceEntry,
    resolve_class,
)
from elastic_gym.model.identified import load_identified_model
from elastic_gym.observers.base import Observer
from elastic_gym.observers.registry import OBSERVERS, source_class
from elastic_gym.observers.sensors import RawSensors
from elastic_gym.robots.catalog import get_robot
from elastic_gym.robots.spec import RobotSpec


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
    model_file: str | None = None  # an identified model file replacing the nominal model

    @property
    def group(self) -> tuple:
        """Labels of the scenario this run belongs to (all but controller, source, seed)."""
        return tuple(v for k, v in self.labels.items() if k not in ("controller", "source", "seed"))


@dataclass(frozen=True)
class SkippedRun:
    """A combination of the grid that does not apply, and why."""

    labels: dict
    reason: str


def env_robot(env_id: str, env_kwargs: dict) -> RobotSpec:
    """The robot of an env id with kwargs (from the registry, without building the env)."""
    robot = env_kwargs.get("robot", gym.spec(env_id).kwargs.get("robot"))
    return robot if isinstance(robot, RobotSpec) else get_robot(robot)


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
    """Bind ``options`` (at field ``path``) to the constructor
    ``cls(model, dt, **fixed, **options)`` without calling it: unknown, duplicate or missing
    options raise `ScenarioError` (a ``ValueError``) with the field path, e.g.
    ``controllers[1].options.omegaa: unexpected option; valid: [...]``."""
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
        raise ScenarioError(f"{path}.{key}", problem)
    if signature is None:
        return
    try:
        signature.bind(None, None, **fixed, **options)
    except TypeError as exc:
        raise ScenarioError(path, f"{cls.__name__}(model, dt, **options): {exc}") from None


def _controllers(scenario: Scenario) -> list[tuple[ControllerEntry, type[Controller]]]:
    """Each controller entry with its class, its options checked."""
    out = []
    for i, entry in enumerate(scenario.controllers):
        cls = _entry_class(entry, f"controllers[{i}]", Controller, comparison_controller)
        check_options(cls, entry.options, f"controllers[{i}].options")
        out.append((entry, cls))
    return out


def _sources(scenario: Scenario) -> list[tuple[SourceEntry, type[Observer]]]:
    """Each state source entry with its class, its options checked."""
    out = []
    for i, entry in enumerate(scenario.state_sources):
        cls = _entry_class(entry, f"state_sources[{i}]", Observer, source_class)
        named = entry.cls is None and entry.name in OBSERVERS
        fixed = OBSERVERS[entry.name][2] if named else {}
        check_options(cls, entry.options, f"state_sources[{i}].options", fixed)
        if issubclass(cls, RawSensors) and entry.initial_estimate is not None:
            raise ScenarioError(
                f"state_sources[{i}].initial_estimate", "raw sensors have no estimate to start"
            )
        out.append((entry, cls))
    return out


def plan_runs(scenario: Scenario) -> tuple[list[RunSpec], list[SkippedRun]]:
    """All runs of the grid, and the combinations skipped because they do not apply.

    Raises `ScenarioError` naming the field when a controller or observer module is not
    available (registry names are checked when the scenario is loaded) or when its
    options do not fit its constructor
    ([`check_options`][elastic_gym.evaluation.grid.check_options]).
    """
    controllers, sources = _controllers(scenario), _sources(scenario)
    files = identified_files(scenario)
    axis_values = itertools.product(*(values for _, values in scenario.axes))
    runs: list[RunSpec] = []
    skipped: list[SkippedRun] = []
    for env, variations in itertools.product(scenario.envs, axis_values):
        kwargs = scenario.env_kwargs(env, variations)
        robot = env_robot(env.id, kwargs)
        kind = robot.kind
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
                        model_file=files.get(robot.name),
                    )
                )
    return runs, skipped


def identified_files(scenario: Scenario) -> dict[str, str]:
    """Robot name -> the scenario's identified model file of that robot (``models``):
    `ScenarioError` for a second file of one robot or a file of no env's robot."""
    if not scenario.models:
        return {}
    robots = {env_robot(e.id, scenario.env_kwargs(e)).name for e in scenario.envs}
    files: dict[str, str] = {}
    for i, path in enumerate(scenario.models):
        robot = load_identified_model(path).robot
        if robot in files:
            raise ScenarioError(f"models[{i}]", f"a second model file of robot {robot!r}")
        if robot not in robots:
            raise ScenarioError(
                f"models[{i}]", f"a model of robot {robot!r}, which no env has ({sorted(robots)})"
            )
        files[robot] = path
    return files


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
