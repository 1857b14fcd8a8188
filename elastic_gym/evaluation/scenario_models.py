"""The entries of a comparison scenario as pydantic models (field-path errors, JSON Schema).

Each model states its fields, types, bounds and defaults; the custom validators check only
what a schema cannot know: registry names, env kwargs against an env's constructor (the
package's envs: [`EnvKwargs`][elastic_gym.envs.config.EnvKwargs], the model the env validates
them with), model errors against [`ParameterScaling`][elastic_gym.model.ParameterScaling],
and labels that must be unique. [`Scenario`][elastic_gym.evaluation.scenario.Scenario]
combines them into the grid.
"""

from __future__ import annotations

import importlib
import inspect
from collections.abc import Callable, Iterable, Mapping
from typing import Annotated, Any, ClassVar

import gymnasium as gym
from pydantic import (
    AfterValidator,
    AllowInfNan,
    BeforeValidator,
    ConfigDict,
    Field,
    PlainSerializer,
    StrictFloat,
    StrictStr,
    ValidationInfo,
    WithJsonSchema,
    WrapValidator,
    field_serializer,
    field_validator,
    model_serializer,
    model_validator,
)

import elastic_gym  # noqa: F401 - registers the env ids
from elastic_gym.envs.config import EnvKwargs, KwargsSchema, checked_kwargs
from elastic_gym.envs.ids import ENV_NAMESPACE, registered_env_id
from elastic_gym.evaluation.controllers import controller_names
from elastic_gym.model import ParameterScaling
from elastic_gym.observers.registry import state_sources
from elastic_gym.validation import StrictModel, distinct, known, lookup

TRUE_STATE = "true"
NOMINAL = "nominal"
IDENTITY_COLUMNS = ("env", "model_error", "controller", "source", "seed")
SWEEP_AXIS = "sweep"
RESERVED_AXES = (*IDENTITY_COLUMNS, SWEEP_AXIS)


def _keep_int(value: Any, handler: Any) -> float | int:
    number = handler(value)
    return int(number) if isinstance(value, int) else number


Real = Annotated[  # 1 stays 1, also in the written scenario.yaml
    StrictFloat, AllowInfNan(False), WrapValidator(_keep_int), PlainSerializer(lambda v: v)
]
Positive = Annotated[StrictFloat, Field(gt=0, allow_inf_nan=False)]


def _label(value: Any) -> Any:
    """YAML's bare ``true`` is the true state's label; numbers are labels too."""
    if value is True:
        return TRUE_STATE
    return str(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else value


Label = Annotated[
    StrictStr,
    BeforeValidator(_label),
    Field(min_length=1),
    WithJsonSchema(
        {"anyOf": [{"type": "string", "minLength": 1}, {"type": "number"}, {"const": True}]}
    ),
]
Name = Annotated[
    StrictStr, BeforeValidator(lambda v: TRUE_STATE if v is True else v), Field(min_length=1)
]


def _axis_name(name: str) -> str:
    if not name.isidentifier() or name in RESERVED_AXES:
        raise ValueError(
            f"names must be identifiers other than {list(RESERVED_AXES)}, got {name!r}"
        )
    return name


AxisName = Annotated[str, AfterValidator(_axis_name)]


def _class_field(value: Any) -> type | str | None:
    if value is None or isinstance(value, type) or (isinstance(value, str) and ":" in value):
        return value
    raise ValueError(f"must be a class or a 'module:Class' string, got {value!r}")


ClassPath = Annotated[
    Any,
    BeforeValidator(_class_field),
    WithJsonSchema({"type": "string", "pattern": "^[\\w.]+:[\\w.]+$"}),
]


def unique_labels(entries: tuple) -> tuple:
    """Refuse entries of a list whose labels repeat (they name rows and figures)."""
    distinct([entry.label for entry in entries], "label(s)", "; give each entry a 'label'")
    return entries


# ---------------------------------------------------------------------------- env kwargs
def env_parameters(env_id: str) -> set[str]:
    """Constructor keyword names of a registered env (following ``**kwargs`` up the MRO)."""
    entry = gym.spec(env_id).entry_point
    if isinstance(entry, str):
        module, _, attr = entry.partition(":")
        entry = getattr(importlib.import_module(module), attr)
    names: set[str] = set()
    for klass in entry.__mro__ if isinstance(entry, type) else ():
        if "__init__" not in vars(klass):
            continue
        params = inspect.signature(vars(klass)["__init__"]).parameters.values()
        names |= {p.name for p in params if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)}
        if not any(p.kind is p.VAR_KEYWORD for p in params):
            break
    names.discard("self")
    return names


def is_package_env(env_id: str) -> bool:
    """Whether ``env_id``'s constructor takes exactly the package envs' kwargs
    ([`EnvKwargs`][elastic_gym.envs.config.EnvKwargs])."""
    return env_parameters(env_id) == set(EnvKwargs.model_fields)


def check_env_kwargs(env_id: str, kwargs: Mapping, loc: tuple = ()) -> None:
    """Refuse kwargs that ``env_id``'s constructor does not take: validated by
    [`EnvKwargs`][elastic_gym.envs.config.EnvKwargs] for an env of the package
    ([`checked_kwargs`][elastic_gym.envs.config.checked_kwargs]), by the constructor's names
    otherwise (``FieldError`` at ``loc``)."""
    if is_package_env(env_id):
        checked_kwargs(dict(kwargs), loc)
        return
    known(kwargs, env_parameters(env_id), "env kwarg", of=env_id, loc=loc)


# ---------------------------------------------------------------------------- entries
class BareEntry(StrictModel):
    """A list entry that may be written as its ``bare_key`` alone (a string; for state
    sources also YAML's ``true``), e.g. ``- deluca`` for ``- {name: deluca}``."""

    model_config = ConfigDict(frozen=True)
    bare_key: ClassVar[str] = "name"
    bare_schemas: ClassVar[tuple[dict, ...]] = ({"type": "string"},)

    @model_validator(mode="before")
    @classmethod
    def _bare(cls, data: Any) -> Any:
        return {cls.bare_key: data} if isinstance(data, str) or data is True else data

    @classmethod
    def __get_pydantic_json_schema__(cls, core_schema: Any, handler: Any) -> dict:
        return {"anyOf": [*cls.bare_schemas, handler(core_schema)]}


class EnvEntry(BareEntry):
    """One env of the grid: gym id (the ``elastic_gym/`` prefix is optional), constructor
    kwargs and ``reset`` options; the label defaults to the id's name."""

    bare_key = "id"
    id: Annotated[str, AfterValidator(registered_env_id)]
    label: Label = ""  # the id's name
    kwargs: Annotated[dict[str, Any], KwargsSchema()] = Field(default_factory=dict)
    reset_options: dict[Any, Any] = Field(default_factory=dict)

    @field_validator("kwargs")
    @classmethod
    def _known_kwargs(cls, kwargs: dict, info: ValidationInfo) -> dict:
        if "id" in info.data:
            check_env_kwargs(info.data["id"], kwargs)
        return kwargs

    @model_validator(mode="after")
    def _default_label(self) -> EnvEntry:
        if not self.label:
            vars(self)["label"] = self.id.removeprefix(ENV_NAMESPACE).removesuffix("-v0")
        return self


class _Named(BareEntry):
    """Base of the controller and state-source entries (a bare string is the name)."""

    kind: ClassVar[str]
    registry: ClassVar[Callable[[], Iterable[str]]]  # the names valid without a ``class``
    name: Name
    label: Label = ""  # the name
    options: dict[Any, Any] = Field(default_factory=dict)
    cls: ClassPath = Field(None, alias="class")

    @model_validator(mode="after")
    def _defaults(self) -> _Named:
        if self.cls is None:
            lookup(dict.fromkeys(type(self).registry()), self.name, self.kind, loc=("name",))
        if not self.label:
            vars(self)["label"] = self.name
        return self

    @field_serializer("cls")
    def _class_path(self, cls: type | str | None) -> str | None:
        return (
            cls if cls is None or isinstance(cls, str) else f"{cls.__module__}:{cls.__qualname__}"
        )


class ControllerEntry(_Named):
    """A controller by registry name (or explicit ``class``, a
    [`Controller`][elastic_gym.controllers.Controller] subclass or ``"module:Class"``) with its
    constructor options; ``sources`` restricts the state sources (by label) it is paired
    with (``None``: all)."""

    kind = "controller"
    sources: tuple[Label, ...] | None = Field(None, min_length=1)

    registry = staticmethod(controller_names)


class SourceEntry(_Named):
    """A state source: ``"true"`` (the oracle), an observer with options, or raw
    ``"sensors"`` (for controllers that read them, e.g. a policy trained on them);
    ``initial_estimate`` (full state vector) is passed to ``observer.reset``."""

    kind = "state source"
    bare_schemas = ({"type": "string"}, {"const": True})
    initial_estimate: tuple[Annotated[StrictFloat, AllowInfNan(False)], ...] | None = Field(
        None, min_length=1
    )

    registry = staticmethod(state_sources)


# ---------------------------------------------------------------------------- variations
VARIATION_SCHEMA = {
    "type": "object",
    "properties": {"label": {"type": ["string", "number"]}},
    "additionalProperties": True,
    "description": "a label and values: env kwargs (axes) or scaling factors (model errors)",
}


class Variation(StrictModel):
    """One value of an axis: env kwargs (robustness axes) or scaling factors (model errors).

    Written flat in YAML (``{label: heavy, plant_scaling: {link_mass: 1.3}}``); without a
    label it is named by its values
    ([`format_values`][elastic_gym.evaluation.scenario_models.format_values])."""

    model_config = ConfigDict(frozen=True)
    label: Label = ""  # made of the values
    values: dict[str, Any] = Field(default_factory=dict)

    @model_validator(mode="before")
    @classmethod
    def _flat(cls, data: Any) -> Any:
        if not isinstance(data, Mapping) or set(data) <= {"label", "values"}:
            return data
        values = {k: v for k, v in data.items() if k != "label"}
        label = data.get("label")
        return {"values": values} if label is None else {"label": label, "values": values}

    @model_serializer
    def _flat_dump(self) -> dict:
        return {"label": self.label, **self.values}

    def named(self, empty: str) -> Variation:
        """Itself with its label, or one made of its values (``empty`` without values)."""
        if self.label:
            return self
        return self.model_copy(update={"label": format_values(self.values) or empty})


def _model_error(variation: Variation) -> Variation:
    ParameterScaling.from_config(dict(variation.values))
    return variation.named("exact")


AxisValue = Annotated[
    Variation, AfterValidator(lambda v: v.named(NOMINAL)), WithJsonSchema(VARIATION_SCHEMA)
]
ModelError = Annotated[Variation, AfterValidator(_model_error), WithJsonSchema(VARIATION_SCHEMA)]


def format_values(values: Mapping, prefix: str = "") -> str:
    """Compact label of (nested) values: ``plant_scaling.link_mass=1.3,task=tracking``."""
    parts = []
    for key, value in values.items():
        if isinstance(value, Mapping):
            parts.append(format_values(value, f"{prefix}{key}."))
        else:
            parts.append(f"{prefix}{key}={value}")
    return ",".join(p for p in parts if p)
