"""Comparison scenarios: the grid of runs, from a dict (YAML files and the shipped presets:
`presets`).

A scenario is the product

    envs x (values of each robustness axis) x model errors x seeds x controllers x state sources

Axes combine as a product; ``sweeps`` become one more axis ``sweep`` whose values are
``nominal`` (the runs as given) and ``<name>=<magnitude>``, so N sweeps of k magnitudes
cost 1 + N k runs per loop. Comparisons run the RK4 at the control period (``integrator``;
PyBullet's Euler at ``COMPARISON_PHYSICS_DT``). Loading validates the fields (the models of
[`scenario_models`][elastic_gym.evaluation.scenario_models]; their JSON Schema: ``elastic-gym schema
scenario``, the docs' scenario file reference lists every field) and raises
`ScenarioError` (a ``ValueError``) naming the offending field, e.g.
``controllers[1].name``; inapplicable observer/controller pairs are skipped at planning.
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Annotated, Any, Literal, TypeVar

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

from elastic_gym.envs.config import Integrator
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
from elastic_gym.model.identified import checked_model_file
from elastic_gym.validation import (
    ConfigError,
    FieldError,
    StrictModel,
    distinct,
    format_validation_error,
    known,
)

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
COMPARISON_INTEGRATOR: Literal["rk4"] = "rk4"  # see the module docstring
COMPARISON_PHYSICS_DT = 1.0 / 16000.0  # s: PyBullet's step in a comparison
MAX_PHYSICS_DT = 1e-3  # s, the envs' own bound


def _model_file(path: str) -> str:
    return str(Path(checked_model_file(path)).resolve())


class ScenarioError(ValueError):
    """Invalid scenario; the message starts with the path of the offending field."""

    def __init__(self, path: str, message: str) -> None:
        super().__init__(f"{path}: {message}")
        self.path, self.message = path, message

    def __reduce__(self):  # pickled as (path, message), e.g. from a worker process
        return type(self), (self.path, self.message)


def _distinct(seeds: tuple[int, ...]) -> tuple[int, ...]:
    why = ": a seed repeated would count the same run twice in the means over seeds"
    return tuple(distinct(seeds, "seed(s)", why))


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
    """A validated comparison grid; build it with `from_dict` or the loaders below.

    The fields are the YAML file's (module docstring); `axes` are the grid's axes
    as (name, values), the ``sweep`` axis of [`sweeps`][elastic_gym.evaluation.sweeps] last.
    """

    model_config = ConfigDict(frozen=True)

    name: Annotated[StrictStr, AfterValidator(_folder_name)] = "scenario"
    description: StrictStr = ""
    duration: Positive = 3.0
    integrator: Integrator | None = COMPARISON_INTEGRATOR
    physics_dt: Annotated[Positive, Field(le=MAX_PHYSICS_DT)] | None = None
    seeds: Seeds = (0,)
    envs: Entries[EnvEntry]
    axis_table: dict[AxisName, Axis] = Field({}, alias="axes")
    sweep_table: dict[AxisName, Sweep] = Field({}, alias="sweeps")
    model_errors: Entries[ModelError] = (Variation(label="exact"),)
    models: tuple[Annotated[StrictStr, AfterValidator(_model_file)], ...] = ()
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
            where = ("controllers", i, "sources")
            known(controller.sources or (), labels, "state source label", loc=where)
        tables: dict[str, Mapping[str, Any]] = {"axes": self.axis_table, "sweeps": self.sweep_table}
        for table, items in tables.items():
            for name, values in items.items():
                generated = isinstance(values, Magnitudes)
                for i, value in enumerate(values.axis_values() if generated else values):
                    for env in self.envs:
                        try:
                            check_env_kwargs(env.id, value.values)
                        except (FieldError, ConfigError) as exc:
                            at = (table, name, "parameter") if generated else (table, name, i)
                            exc.loc = (*at, *exc.loc)
                            raise
        return self

    @classmethod
    def from_dict(cls, data: Mapping, name: str | None = None) -> Scenario:
        """Validate a mapping (parsed YAML, or Python objects) into a scenario (anything
        else is refused by the model)."""
        named = name and isinstance(data, Mapping)
        return _validated(cls, {**data, "name": name} if named else data)

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
        integrator: str | None = None,
        **fields: Any,
    ) -> Scenario:
        """A copy with other seeds, duration, physics step, integrator or other fields,
        validated like the YAML fields."""
        changes = {
            "seeds": seeds,
            "duration": duration,
            "physics_dt": physics_dt,
            "integrator": integrator,
        }
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

    def physics_kwargs(self) -> dict:
        """The env kwargs of the scenario's physics: ``integrator`` (None: each env's own)
        and ``physics_dt`` (None: the integrator's in a comparison, the control period for
        the RK4 and ``COMPARISON_PHYSICS_DT`` for PyBullet's, or each robot's own step
        when the integrator is each env's own)."""
        kwargs: dict[str, Any] = {}
        if self.integrator is not None:
            kwargs["integrator"] = self.integrator
        physics_dt = self.physics_dt
        if physics_dt is None and self.integrator == "pybullet":
            physics_dt = COMPARISON_PHYSICS_DT
        if physics_dt is not None:
            kwargs["physics_dt"] = physics_dt
        return kwargs

    def env_kwargs(self, env: EnvEntry, variations: Sequence[Variation] = ()) -> dict:
        """Kwargs of ``env`` under axis values ``variations``: the scenario's physics
        (`physics_kwargs`), then the entry's kwargs, then each variation, deep-merged in
        that order."""
        kwargs = merge(self.physics_kwargs(), env.kwargs)
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
        # None: the integrator's comparison step / each env's own integrator
        return {**data, "physics_dt": self.physics_dt, "integrator": self.integrator}


def _validated(model: type[Scenario], data: Any, by_name: bool = False) -> Scenario:
    try:
        return model.model_validate(data, by_name=by_name)
    except ValidationError as error:
        path, _, message = format_validation_error(error, model=model).partition(": ")
        raise ScenarioError(path, message) from None


def resolve_class(cls: type | str, path: str, bases: tuple[type, ...] = (object,)) -> type:
    """A class given directly or as ``"module:Class"``, which imports the module (running
    its top-level code: a scenario file is code, load only trusted ones), a subclass of
    one of ``bases``; `ScenarioError` at ``path`` otherwise."""
    module, _, attr = ("", "", "") if isinstance(cls, type) else cls.partition(":")
    problem = None
    try:
        found = cls if isinstance(cls, type) else getattr(importlib.import_module(module), attr)
        if not isinstance(found, type):
            problem = f"{cls!r} is not a class but {type(found).__name__} {found!r}"
        elif not issubclass(found, bases):
            kinds = " nor ".join(base.__name__ for base in bases)
            problem = f"{found!r} is {'neither' if len(bases) > 1 else 'not'} a subclass of {kinds}"
    except (ImportError, AttributeError) as exc:
        problem = f"cannot import class {cls!r}: {exc}"
    except (Exception, SystemExit) as exc:  # the module's own code failed or does not compile
        message = " ".join(str(exc).split())
        problem = f"importing module {module!r} failed: {type(exc).__name__}: {message}"
    if problem is not None:
        raise ScenarioError(path, problem)
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
