"""Comparison scenarios: the grid of runs, from a dict (YAML files and the shipped presets:
:mod:`~elastic_gym.evaluation.presets`).

A scenario is the product

    envs x (values of each robustness axis) x model errors x seeds x controllers x state sources

written in YAML as::

    name: my-study
    description: free text
    duration: 4.0                       # simulated seconds per run
    physics_dt: 6.25e-5                 # physics step of every env (default 1/16 ms; null:
                                        # each robot's own default), see below
    seeds: [0, 1]                       # env reset seeds (task sampling and sensor noise)
    envs:
      - TwoLinkElastic-v0               # an id (the "elastic_gym/" prefix is optional), or
      - id: elastic_gym/KR15Elastic-v0
        label: kr15-5deg
        kwargs: {task: tracking, task_options: {waypoints: [[0.1, 0.2, -0.3]]}}
        reset_options: {initial_state: {q: [0, 0.2, -0.3]}}
    axes:                               # robustness axes: each value is a set of env kwargs
      plant:                            # (deep-merged into every env entry's kwargs)
        - {label: nominal}
        - {label: mass+30%, plant_scaling: {link_mass: 1.3}}
      encoder:
        - {}
        - {encoder: {resolution: 1.0e-3}}
      mass:                             # an axis generated from magnitudes of one parameter
        parameter: plant_scaling.link_mass    # dotted path into the env kwargs
        values: [1.1, 1.3]              # or range: [1.0, 1.5] with num: 6 (log: true: geometric)
    sweeps:                             # one-at-a-time sweeps (curves and margins): the runs of
      link_mass:                        # the grid above are the nominal runs, and each sweep
        parameter: plant_scaling.link_mass    # adds runs that change only its parameter
        nominal: 1.0                    # the magnitude the nominal runs have
        range: [1.0, 2.0]
        num: 6
      delay: {parameter: sensor_delay, nominal: 0, values: [1, 2, 3, 5]}
    model_errors:                       # error of the controller's and observer's model:
      - {}                              # env.unwrapped.model.perturbed(**values)
      - {label: K-10%, stiffness: 0.9}
    controllers:
      - feedforward-state-feedback      # a registry name, or
      - name: motor-pd
        label: motor-only
        options: {}                     # constructor options
        sources: [finite-difference]    # pair only with these state-source labels
      - name: my-pd                     # a class not in the registry ("module:Class")
        class: mypackage.control:MyPD
    state_sources:
      - true                            # the truth (oracle); YAML's bare `true` is accepted
      - deluca                          # an observer registry name, or
      - name: ekf
        label: ekf-acc
        options: {use_accelerometers: true}
        initial_estimate: [...]         # full state vector, overrides the observer's own

Axes combine as a product. ``sweeps`` do not: they become one more axis named
``sweep`` whose values are ``nominal`` (the runs as given) and ``<name>=<magnitude>``
for each magnitude of each sweep (a magnitude equal to the sweep's ``nominal`` is the
nominal run itself, run once for all sweeps), so N sweeps of k magnitudes cost
1 + N k runs per loop instead of k^N. :mod:`~elastic_gym.evaluation.curves` and
:mod:`~elastic_gym.evaluation.margins` turn them into metric-versus-magnitude curves
and robustness margins.

Physics step. PyBullet's first-order semi-implicit Euler puts an O(physics_dt) error in
every closed loop's tracking; comparisons default to ``COMPARISON_PHYSICS_DT`` = 1/16 ms
(:mod:`~elastic_gym.evaluation.convergence` checks a scenario at a finer step). An env
entry's or axis value's own ``physics_dt`` kwarg takes precedence.

Loading validates the fields (the models of :mod:`~elastic_gym.evaluation.scenario_models`,
whose JSON Schema ``elastic-gym schema scenario`` prints) and raises :class:`ScenarioError`
(a ``ValueError``) naming the offending field, e.g. ``controllers[1].name``. Whether an
observer or controller module is available and applies to an env's arm is decided when
the runs are planned (:func:`elastic_gym.evaluation.runner.plan_runs`).
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping, Sequence
from typing import Annotated, Any, TypeVar

from pydantic import (
    AfterValidator,
    ConfigDict,
    Discriminator,
    Field,
    StrictInt,
    StrictStr,
    Tag,
    ValidationError,
    WithJsonSchema,
    field_validator,
    model_validator,
)

from elastic_gym.evaluation.magnitudes import Magnitudes, Sweep
from elastic_gym.evaluation.output import folder_name_problem
from elastic_gym.evaluation.scenario_models import (
    IDENTITY_COLUMNS,
    NOMINAL,
    SWEEP_AXIS,
    TRUE_STATE,
    AxisName,
    AxisValue,
    ControllerEntry,
    EnvEntry,
    ModelError,
    Positive,
    SourceEntry,
    Variation,
    check_env_kwargs,
    unique_labels,
)
from elastic_gym.validation import FieldError, StrictModel, format_validation_error

__all__ = [
    "IDENTITY_COLUMNS",
    "NOMINAL",
    "SWEEP_AXIS",
    "TRUE_STATE",
    "ControllerEntry",
    "EnvEntry",
    "Scenario",
    "ScenarioError",
    "SourceEntry",
    "Sweep",
    "Variation",
]

QUICK_DURATION = 0.5  # s, Scenario.quick()
COMPARISON_PHYSICS_DT = 1.0 / 16000.0  # s; see the module docstring
MAX_PHYSICS_DT = 1e-3  # s, the envs' own bound


class ScenarioError(ValueError):
    """Invalid scenario; the message starts with the path of the offending field."""

    def __init__(self, path: str, message: str) -> None:
        super().__init__(f"{path}: {message}")
        self.path = path


def _distinct(seeds: tuple[int, ...]) -> tuple[int, ...]:
    duplicates = sorted({seed for seed in seeds if seeds.count(seed) > 1})
    if duplicates:
        raise ValueError(
            f"duplicate seed(s) {duplicates}: a seed repeated would "
            "count the same run twice in the means over seeds"
        )
    return seeds


def _folder_name(name: str) -> str:
    problem = folder_name_problem(name)
    if problem:
        raise ValueError(f"{problem} (it names the output folder compare_out/<name>)")
    return name


SEED = {"type": "integer", "minimum": 0}
Seeds = Annotated[
    tuple[Annotated[StrictInt, Field(ge=0)], ...],
    Field(min_length=1),
    AfterValidator(_distinct),
    WithJsonSchema(
        {"anyOf": [SEED, {"type": "array", "items": SEED, "minItems": 1, "uniqueItems": True}]}
    ),
]
Values = Annotated[tuple[AxisValue, ...], Field(min_length=1), AfterValidator(unique_labels)]
Axis = Annotated[  # a list of values, or a mapping of magnitudes
    Annotated[Values, Tag("list")] | Annotated[Magnitudes, Tag("Magnitudes")],
    Discriminator(lambda v: "Magnitudes" if isinstance(v, Mapping | Magnitudes) else "list"),
]
E = TypeVar("E")
Entries = Annotated[tuple[E, ...], Field(min_length=1), AfterValidator(unique_labels)]


class Scenario(StrictModel):
    """A validated comparison grid; build it with :meth:`from_dict` or the loaders below.

    The fields are the YAML file's (module docstring); :attr:`axes` are the grid's axes
    as (name, values), the ``sweep`` axis of :attr:`sweeps` last.
    """

    model_config = ConfigDict(frozen=True)

    name: Annotated[StrictStr, AfterValidator(_folder_name)] = "scenario"
    description: StrictStr = ""
    duration: Positive = 3.0
    physics_dt: Annotated[Positive, Field(le=MAX_PHYSICS_DT)] | None = COMPARISON_PHYSICS_DT
    seeds: Seeds = (0,)
    envs: Entries[EnvEntry]
    axis_table: dict[AxisName, Axis] = Field({}, alias="axes")
    sweep_table: dict[AxisName, Sweep] = Field({}, alias="sweeps")
    model_errors: Entries[ModelError] = (Variation(label="exact"),)
    controllers: Entries[ControllerEntry]
    state_sources: Entries[SourceEntry]

    @model_validator(mode="before")
    @classmethod
    def _one_seed(cls, data: Any) -> Any:
        if isinstance(data, Mapping) and isinstance(data.get("seeds"), int):
            return {**data, "seeds": [data["seeds"]]}
        return data

    @field_validator("axis_table", "sweep_table")
    @classmethod
    def _named(cls, table: dict) -> dict:
        for name, value in table.items():
            if isinstance(value, Magnitudes):
                value.named(name)
        return table

    @model_validator(mode="after")
    def _references(self) -> Scenario:
        """Controllers' ``sources`` name state sources; every axis value and sweep
        magnitude is a valid kwarg of every env."""
        labels = {s.label for s in self.state_sources}
        for i, controller in enumerate(self.controllers):
            missing = sorted(set(controller.sources or ()) - labels)
            if missing:
                raise FieldError(
                    ("controllers", i, "sources"),
                    f"unknown state source label(s) {missing}; valid: {sorted(labels)}",
                )
        tables = {"axes": self.axis_table, "sweeps": self.sweep_table}
        for table, items in tables.items():
            for name, values in items.items():
                generated = isinstance(values, Magnitudes)
                for i, value in enumerate(values.axis_values() if generated else values):
                    for env in self.envs:
                        try:
                            check_env_kwargs(env.id, value.values)
                        except FieldError as exc:
                            loc = (table, name, "parameter") if generated else (table, name, i)
                            raise FieldError((*loc, *exc.loc), str(exc)) from None
        return self

    @classmethod
    def from_dict(cls, data: Mapping, name: str | None = None) -> Scenario:
        """Validate a mapping (parsed YAML, or Python objects) into a scenario."""
        return _validated(cls, {**data, "name": name} if name else data)

    @property
    def sweeps(self) -> tuple[Sweep, ...]:
        return tuple(self.sweep_table.values())

    @property
    def axes(self) -> tuple[tuple[str, tuple[Variation, ...]], ...]:
        axes = tuple(
            (name, values.axis_values() if isinstance(values, Magnitudes) else values)
            for name, values in self.axis_table.items()
        )
        if not self.sweeps:
            return axes
        sweep = (Variation(label=NOMINAL), *(v for w in self.sweeps for v in w.variations()))
        return (*axes, (SWEEP_AXIS, sweep))

    def with_overrides(
        self,
        *,
        seeds: Sequence[int] | None = None,
        duration: float | None = None,
        physics_dt: float | None = None,
        **fields: Any,
    ) -> Scenario:
        """A copy with other seeds, duration, physics step or other fields, validated like
        the YAML fields."""
        changes = {"seeds": seeds, "duration": duration, "physics_dt": physics_dt}
        changes = {**{k: v for k, v in changes.items() if v is not None}, **fields}
        return _validated(type(self), {**self.__dict__, **changes}, by_name=True)

    def quick(self) -> Scenario:
        """A fast look at the same grid: the first seed, at most ``QUICK_DURATION`` s per
        run, and each sweep thinned to its farthest magnitude on each side of the nominal."""
        sweeps = {
            n: w.model_copy(update={"values": w.extremes()}) for n, w in self.sweep_table.items()
        }
        return self.model_copy(
            update={
                "seeds": self.seeds[:1],
                "duration": min(self.duration, QUICK_DURATION),
                "sweep_table": sweeps,
            }
        )

    def env_kwargs(self, env: EnvEntry, variations: Sequence[Variation] = ()) -> dict:
        """Kwargs of ``env`` under axis values ``variations``: the scenario's physics step,
        then the entry's kwargs, then each variation, deep-merged in that order."""
        kwargs = {} if self.physics_dt is None else {"physics_dt": self.physics_dt}
        kwargs = merge(kwargs, env.kwargs)
        for variation in variations:
            kwargs = merge(kwargs, variation.values)
        return kwargs

    @property
    def axis_names(self) -> tuple[str, ...]:
        return tuple(name for name, _ in self.axes)

    @property
    def identity_columns(self) -> tuple[str, ...]:
        """Columns that identify a run: env, the axes, model error, controller, source, seed."""
        return (IDENTITY_COLUMNS[0], *self.axis_names, *IDENTITY_COLUMNS[1:])

    def to_dict(self) -> dict:
        """Plain-data form (YAML-serialisable; classes as ``"module:Class"``)."""
        data = self.model_dump(mode="json", by_alias=True, exclude_none=True, fallback=str)
        return {**data, "physics_dt": self.physics_dt}  # None: each robot's own step


def _validated(model: type[Scenario], data: Any, by_name: bool = False) -> Scenario:
    try:
        return model.model_validate(data, by_name=by_name)
    except ValidationError as error:
        path, _, message = format_validation_error(error, model=model).partition(": ")
        raise ScenarioError(path, message) from None


def resolve_class(cls: type | str, path: str) -> type:
    """A class given directly or as ``"module:Class"``, which imports the module (running
    its top-level code: a scenario file is code, load only trusted ones)."""
    if isinstance(cls, type):
        return cls
    module, _, attr = cls.partition(":")
    try:
        found = getattr(importlib.import_module(module), attr)
    except (ImportError, AttributeError) as exc:
        raise ScenarioError(path, f"cannot import class {cls!r}: {exc}") from None
    except (Exception, SystemExit) as exc:  # the module's own code failed or does not compile
        message = " ".join(str(exc).split())
        raise ScenarioError(
            path, f"importing module {module!r} failed: {type(exc).__name__}: {message}"
        ) from None
    if not isinstance(found, type):
        raise ScenarioError(path, f"{cls!r} is not a class but {type(found).__name__} {found!r}")
    return found


def merge(base: Mapping, override: Mapping) -> dict:
    """Recursive dict merge: mappings are merged, anything else is replaced."""
    out = dict(base)
    for key, value in override.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), Mapping):
            out[key] = merge(out[key], value)
        else:
            out[key] = value
    return out
