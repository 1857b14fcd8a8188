"""The benchmark suite: tasks x categories of plant perturbations x robots x fixed seeds, as data.

A suite is a YAML file of ``elastic_gym/benchmark/suites/`` validated by `SuiteConfig`
(unknown keys refused, errors naming the field). `suite_hash` is the sha256 of the
canonical JSON form of the validated suite, so comments do not change it and any change of a
task, magnitude, seed, tolerance or weight does; scorecards carry it.

``robots`` (label -> env id + kwargs), ``tasks`` (env kwargs and the `Tolerance` an
episode must stay within), ``categories`` (weight and cells: one task under one perturbation
of the simulated plant only, which no model knows), ``precision`` (the map of the nominal
tracking RMS, `scoring`), ``seeds``, ``duration``, ``integrator`` and ``physics_dt`` (v1:
PyBullet's Euler at 1/16 ms; v2: the RK4 at the control period; the hash leaves out the
default ``pybullet``, so v1 keeps its hash). `expand_cells` lists the cells;
`suite_scenario` turns them and one entry into the comparison `Scenario` that is executed.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Annotated, Any

from pydantic import Field, ValidationError, field_validator, model_validator
from pydantic_core import InitErrorDetails, PydanticCustomError

from elastic_gym.envs.config import Integrator
from elastic_gym.envs.ids import registered_env_id
from elastic_gym.evaluation.scenario import (
    ControllerEntry,
    EnvEntry,
    Scenario,
    SourceEntry,
    merge,
)
from elastic_gym.evaluation.scenario_models import env_parameters
from elastic_gym.validation import (
    ConfigError,
    StrictModel,
    distinct,
    errors_at,
    known,
    ordered,
    validated,
)
from elastic_gym.yaml_io import load_yaml

SUITE_DIR = Path(__file__).resolve().parent / "suites"
DEFAULT_SUITE = "elastic-gym-v2"
MIN_SEEDS = 10
CELL_SEPARATOR = "/"

Label = Annotated[str, Field(min_length=1, pattern=r"^[A-Za-z0-9_.+%=-]+$")]
Positive = Annotated[float, Field(gt=0, allow_inf_nan=False)]


class Tolerance(StrictModel):
    """Thresholds of one task: an episode passes when it completes (no termination, no
    failure) and every metric given here is at most its threshold (metric names of
    `metrics`). A missing or NaN metric fails the episode."""

    track_rms: Positive | None = None
    track_max: Positive | None = None
    overshoot_pct: Annotated[float, Field(ge=0, allow_inf_nan=False)] | None = None
    settling_time: Positive | None = None

    def limits(self) -> dict[str, float]:
        """Metric name -> threshold, for the metrics this task checks."""
        return {k: v for k, v in self.model_dump().items() if v is not None}

    @model_validator(mode="after")
    def _not_empty(self) -> Tolerance:
        if not self.limits():
            raise ValueError("give at least one threshold")
        return self


class RobotEntry(StrictModel):
    """A robot of the suite: its env id and kwargs shared by all its cells."""

    env: str
    kwargs: dict[str, Any] = Field(default_factory=dict)

    @field_validator("env")
    @classmethod
    def _registered(cls, value: str) -> str:
        return registered_env_id(value)


class TaskConfig(StrictModel):
    """A task: env kwargs (``robots`` adds per-robot kwargs) and its tolerances."""

    description: str
    kwargs: dict[str, Any]
    robots: dict[str, dict[str, Any]] = Field(default_factory=dict)
    tolerance: Tolerance


class CellConfig(StrictModel):
    """One task under one plant perturbation (env kwargs); ``robots`` restricts the robots."""

    task: Label
    label: Label
    plant: dict[str, Any] = Field(default_factory=dict)
    robots: list[Label] | None = None


class CategoryConfig(StrictModel):
    """A category: its weight in the overall score and its cells."""

    description: str
    weight: Annotated[float, Field(ge=0, allow_inf_nan=False)]
    cells: list[CellConfig] = Field(min_length=1)


class PrecisionConfig(StrictModel):
    """The precision score: the tracking RMS r of every episode of ``cells`` (``category``
    cells of those tasks) mapped log-linearly, p = clip(log(high / r) / log(high / low),
    0, 1): 1 at or below ``low``, 0 at or above ``high``; an episode that does not complete
    scores 0."""

    category: Label
    tasks: list[Label] = Field(min_length=1)
    low: Positive
    high: Positive
    weight: Annotated[float, Field(ge=0, allow_inf_nan=False)]

    @model_validator(mode="after")
    def _ordered(self) -> PrecisionConfig:
        ordered(self.low, self.high, strict=True)
        return self


class SuiteConfig(StrictModel):
    """A versioned benchmark suite (module docstring)."""

    name: Label
    version: Annotated[int, Field(ge=1)]
    description: str
    duration: Positive
    integrator: Integrator = "pybullet"
    physics_dt: Annotated[float, Field(gt=0, le=1e-3)]
    seeds: list[Annotated[int, Field(ge=0)]] = Field(min_length=MIN_SEEDS)
    robots: dict[Label, RobotEntry] = Field(min_length=1)
    tasks: dict[Label, TaskConfig] = Field(min_length=1)
    categories: dict[Label, CategoryConfig] = Field(min_length=1)
    precision: PrecisionConfig

    @field_validator("seeds")
    @classmethod
    def _unique_seeds(cls, seeds: list[int]) -> list[int]:
        return list(distinct(seeds, "seed(s)"))

    @model_validator(mode="after")
    def _references(self) -> SuiteConfig:
        """Names that must exist elsewhere in the suite, and env kwargs the envs take."""
        robots, tasks = sorted(self.robots), sorted(self.tasks)
        problems: list[tuple[tuple, str]] = []
        for name, task in self.tasks.items():
            problems += [
                (("tasks", name, "robots", r), f"unknown robot; valid: {robots}")
                for r in task.robots
                if r not in self.robots
            ]
        for name, category in self.categories.items():
            labels = [c.label for c in category.cells]
            for i, cell in enumerate(category.cells):
                loc = ("categories", name, "cells", i)
                if cell.task not in self.tasks:
                    problems.append(((*loc, "task"), f"unknown task {cell.task!r}; valid: {tasks}"))
                if labels.count(cell.label) > 1:
                    problems.append(((*loc, "label"), f"duplicate label {cell.label!r}"))
                problems += [
                    ((*loc, "robots"), f"unknown robot {r!r}; valid: {robots}")
                    for r in cell.robots or ()
                    if r not in self.robots
                ]
        if self.precision.category not in self.categories:
            problems.append(
                (("precision", "category"), f"unknown category; valid: {sorted(self.categories)}")
            )
        problems += [
            (("precision", "tasks"), f"unknown task {t!r}; valid: {tasks}")
            for t in self.precision.tasks
            if t not in self.tasks
        ]
        if self.precision.weight + sum(c.weight for c in self.categories.values()) <= 0:
            problems.append(
                (
                    ("categories",),
                    "every weight is 0 (the categories' and precision.weight): the overall "
                    "score would be 0 / 0; give at least one a positive weight",
                )
            )
        if not problems:
            problems = _unknown_kwargs(self)
        if problems:
            raise ValidationError.from_exception_data(
                type(self).__name__,
                [
                    InitErrorDetails(
                        type=PydanticCustomError("suite", message), loc=loc, input=self
                    )
                    for loc, message in problems
                ],
            )
        return self

    @cached_property
    def hash(self) -> str:
        """sha256 of the canonical form (`suite_hash`)."""
        return suite_hash(self)

    @cached_property
    def cells(self) -> tuple[Cell, ...]:
        return expand_cells(self)


@dataclass(frozen=True)
class Cell:
    """One (robot, category, cell) of a suite: the env and its kwargs, and the tolerances."""

    robot: str
    category: str
    label: str
    task: str
    env_id: str
    kwargs: dict
    tolerance: Tolerance
    perturbed: bool = False  # the cell changes the task's plant

    @property
    def id(self) -> str:
        """``robot/category/label``: the env label of the cell in the comparison."""
        return CELL_SEPARATOR.join((self.robot, self.category, self.label))


def expand_cells(suite: SuiteConfig) -> tuple[Cell, ...]:
    """Every cell of every category on every robot it applies to, in suite order."""
    cells = []
    for category, config in suite.categories.items():
        for cell in config.cells:
            task = suite.tasks[cell.task]
            for robot in cell.robots or suite.robots:
                entry = suite.robots[robot]
                kwargs = merge(
                    merge(merge(entry.kwargs, task.kwargs), task.robots.get(robot, {})),
                    cell.plant,
                )
                cells.append(
                    Cell(
                        robot,
                        category,
                        cell.label,
                        cell.task,
                        entry.env,
                        kwargs,
                        task.tolerance,
                        bool(cell.plant),
                    )
                )
    return tuple(cells)


def _unknown_kwargs(suite: SuiteConfig) -> list[tuple[tuple, str]]:
    """Env kwargs of a cell that its env does not take (values are checked when the runs'
    envs are built, before the first run)."""
    problems = []
    for category, config in suite.categories.items():
        for i, cell in enumerate(config.cells):
            for robot in cell.robots or suite.robots:
                env_id = suite.robots[robot].env
                task = suite.tasks[cell.task]
                given = {*cell.plant, *task.kwargs, *task.robots.get(robot, {})}
                unknown = sorted(given - env_parameters(env_id))
                if unknown:
                    problems.append(
                        (
                            ("categories", category, "cells", i),
                            f"unknown env kwarg(s) {unknown} on {robot}; "
                            f"valid: {sorted(env_parameters(env_id))}",
                        )
                    )
    return problems


def canonical_form(suite: SuiteConfig) -> str:
    """The JSON text the hash is taken of: the validated suite, keys sorted, no spaces
    (without ``integrator`` when it is PyBullet's, the default: a suite written before
    the field keeps its hash)."""
    data = suite.model_dump(mode="json")
    if data["integrator"] == "pybullet":
        del data["integrator"]
    return json.dumps(data, sort_keys=True, separators=(",", ":"))


def suite_hash(suite: SuiteConfig) -> str:
    """sha256 (hex) of `canonical_form`."""
    return hashlib.sha256(canonical_form(suite).encode()).hexdigest()


def list_suites() -> list[str]:
    """Names of the suites shipped in the package."""
    return sorted(path.stem for path in SUITE_DIR.glob("*.yaml"))


def load_suite(name_or_path: str | Path = DEFAULT_SUITE) -> SuiteConfig:
    """A shipped suite by name, or a suite YAML file by path (``ValueError`` naming the file
    and the field path when it does not validate, ``FileNotFoundError`` when it does not
    exist)."""
    path = Path(name_or_path)
    if str(name_or_path) in list_suites():
        path = SUITE_DIR / f"{name_or_path}.yaml"
    elif not path.is_file():
        raise FileNotFoundError(
            f"suite {str(name_or_path)!r} is neither a shipped suite {list_suites()} nor a file"
        )
    data = load_yaml(path)  # YAMLInputError: a ValueError naming the file
    try:
        return validated(SuiteConfig, data)
    except ConfigError as error:
        raise ConfigError(f"{name_or_path}: {error}") from None


def suite_schema() -> dict:
    """JSON schema of a suite file (for YAML editor completion)."""
    return SuiteConfig.model_json_schema()


def suite_scenario(
    suite: SuiteConfig,
    controller: ControllerEntry,
    source: SourceEntry,
    robots: list[str] | None = None,
    name: str = "benchmark",
    models: tuple[str, ...] = (),
) -> Scenario:
    """The comparison grid of one entry on the suite: one env entry per cell (labelled
    `Cell.id`), the suite's seeds, duration, integrator and physics step, no model error
    (``models``: identified model files the controller and observer build on).

    ``robots`` restricts the cells to some robots (``ValueError`` for an unknown one)."""
    with errors_at("robots"):
        known(robots or (), suite.robots, "robot")
    cells = [c for c in suite.cells if robots is None or c.robot in robots]
    return Scenario(
        name=name,
        envs=tuple(EnvEntry(id=c.env_id, label=c.id, kwargs=c.kwargs) for c in cells),
        controllers=(controller,),
        state_sources=(source,),
        duration=suite.duration,
        seeds=tuple(suite.seeds),
        integrator=suite.integrator,
        physics_dt=suite.physics_dt,
        description=f"{suite.name} (version {suite.version}, sha256 {suite.hash[:12]})",
        models=models,
    )
