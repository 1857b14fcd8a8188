"""Field paths, refusals, and pydantic's validation errors in the package's one form
(``section.field[0]: message``); plain data from numpy values."""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from functools import partial
from typing import Any, TypeVar, get_args

import numpy as np
from pydantic import (
    BaseModel,
    RootModel,
    TypeAdapter,
    ValidationError,
)

T = TypeVar("T")


def field_path(loc: Sequence[int | str], prefix: str = "") -> str:
    """``("controllers", 1, "options", "omega")`` -> ``controllers[1].options.omega``."""
    path = prefix
    for part in loc:
        if isinstance(part, int):
            path += f"[{part}]"
        else:
            path += f".{part}" if path else str(part)
    return path or "(top level)"


class ConfigError(ValueError):
    """A configuration refused with its message already in the package's form (the field
    path first): what a `ConfigModel` raises. Raised inside a validator, its path
    continues the validator's own, after ``loc`` (field names and list indices)."""

    def __init__(self, message: str, loc: Sequence[int | str] = ()) -> None:
        super().__init__(message)
        self.loc = tuple(loc)


class FieldError(ValueError):
    """Raised by a validator to refuse a part of its value: ``loc`` (field names and list
    indices) is appended to the validator's own path in the error message."""

    def __init__(self, loc: Sequence[int | str], message: str) -> None:
        super().__init__(message)
        self.loc = tuple(loc)


def refusal(loc: Sequence[int | str], message: str) -> ValueError:
    """The ``ValueError`` of a refused value: a `FieldError` continuing a
    validator's path when ``loc`` is given (a plain ``ValueError`` otherwise, as users
    see it named in a pre-run check's message)."""
    return FieldError(loc, message) if loc else ValueError(message)


_UNION_TAGS = frozenset({"int", "float", "str", "bool", "list", "dict", "tuple", "none"})


def _is_union_tag(part: int | str) -> bool:
    """pydantic names the failing member of a union in ``loc`` (``int``, ``list[str]``,
    ``function-after[...]``, a model class name): not a field of the user's data."""
    return isinstance(part, str) and (
        "[" in part
        or part.startswith("constrained-")  # "constrained-float"
        or part in _UNION_TAGS
        or (part.isidentifier() and part[0].isupper())
    )


def _models_in(annotation: Any) -> list[type[BaseModel]]:
    """The pydantic models in an annotation (through Annotated, unions, containers)."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return [annotation]
    return [model for arg in get_args(annotation) for model in _models_in(arg)]


def _contents(models: list[type[BaseModel]]) -> list[type[BaseModel]]:
    """``models`` with each root model (a mapping or list of models, like a file of
    entries) replaced by the models it holds: its data has no field of its own."""
    out: list[type[BaseModel]] = []
    for model in models:
        if issubclass(model, RootModel):
            out += _contents(_models_in(model.model_fields["root"].annotation))
        else:
            out.append(model)
    return out


def field_names(model: type[BaseModel], loc: Sequence[int | str]) -> list[str]:
    """The field names (aliases) of the model reached from ``model`` along ``loc`` (a
    union member named in ``loc`` is followed, the keys of a mapping of models and the
    content of a root model are passed through; none: ``[]``)."""
    models = _contents([model])
    for part in loc:
        named = [m for m in models if m.__name__ == part]
        fields = [f for m in models for n, f in m.model_fields.items() if part in (n, f.alias)]
        if named:
            models = named
        elif fields:
            models = _contents(_models_in(fields[0].annotation))
    return [f.alias or name for name, f in models[0].model_fields.items()] if models else []


def _data_path(loc: Sequence[int | str], model: type[BaseModel] | None) -> list[int | str]:
    """``loc`` without pydantic's union-member tags: a field name of the model reached so
    far is kept even when it looks like a tag (``R``, ``K_P``, ``Lambda``)."""
    return [
        part
        for i, part in enumerate(loc)
        if not _is_union_tag(part) or (model is not None and part in field_names(model, loc[:i]))
    ]


def format_validation_error(
    error: ValidationError, prefix: str = "", model: type[BaseModel] | None = None
) -> str:
    """One line per problem, the field path first: ``controllers[1].options.omega: ...``;
    an unknown field lists the valid ones when the validated ``model`` is given."""
    lines = []
    items = error.errors(include_url=False)
    for item in items:
        loc = _data_path(item["loc"], model)
        if item["type"] == "too_short" and any(
            other["loc"][: len(item["loc"])] == item["loc"] and other is not item for other in items
        ):
            continue  # a list left short by its own invalid items
        message = item["msg"]
        cause = item.get("ctx", {}).get("error")
        if isinstance(cause, ConfigError):  # a nested config's own, already formatted
            loc += list(cause.loc)
            lines.append(f"{field_path(loc, prefix)}.{cause}" if loc else str(cause))
            continue
        if item["type"] == "extra_forbidden":
            valid = field_names(model, item["loc"][:-1]) if model else []
            message = "unexpected field" + (f"; valid: {valid}" if valid else "")
        elif isinstance(cause, ValueError):  # a validator's own message, without "Value error, "
            loc += list(getattr(cause, "loc", ()))
            message = str(cause)
        elif item["type"] != "missing" and isinstance(item["input"], (str, int, float, type(None))):
            message += f", got {item['input']!r}"
        lines.append(f"{field_path(loc, prefix)}: {message}")
    return "; ".join(dict.fromkeys(lines))


M = TypeVar("M", bound=BaseModel)


def validated(model: type[M], data: Any, prefix: str = "") -> M:
    """``model`` built from ``data`` (an instance is returned as is, ``None`` gives the
    defaults). `ConfigError` (a ``ValueError``) with one ``field.path: message`` per
    problem otherwise."""
    if isinstance(data, model):
        return data
    return checked(lambda: model.model_validate({} if data is None else plain(data)), prefix, model)


def checked(
    validate: Callable[[], T],
    prefix: str = "",
    model: type[BaseModel] | None = None,
    by_kind: bool = False,
    loc: Sequence[int | str] = (),
) -> T:
    """``validate()``; its ``ValidationError`` as one line per problem, the field path
    (after ``prefix``) first: a `ConfigError` (continuing a validator's path after
    ``loc``), or with ``by_kind`` a ``TypeError`` when every problem is a value of the
    wrong type (a string for a number, 1 for a bool) and a ``ValueError`` otherwise."""
    try:
        return validate()
    except ValidationError as error:
        message = format_validation_error(error, prefix, model)
        wrong_type = all(map(_wrong_type, error.errors()))
        refusal: ValueError | TypeError = (
            ConfigError(message, loc)
            if not by_kind
            else (TypeError if wrong_type else ValueError)(message)
        )
        raise refusal from None


# ---------------------------------------------------------------- observer / controller options
def _wrong_type(item: Any) -> bool:
    return item["type"].endswith("_type") or item["type"] == "is_instance_of"


def validated_options(
    model: type[M], arguments: Mapping[str, Any], context: Mapping[str, Any] | None = None
) -> M:
    """The options of a constructor validated by their model: ``arguments`` is the
    constructor's ``locals()`` (only the model's fields are read); ``context`` (the robot
    ``model`` and the sampling period ``dt``) is what `PerSample` and
    `Needs` fields read. Errors read ``options.<name>: ...``, a ``TypeError`` when
    every problem is a value of the wrong type (a string for a number, 1 for a bool), a
    ``ValueError`` otherwise."""
    given = plain({key: value for key, value in arguments.items() if key in model.model_fields})
    validate = partial(model.model_validate, given, context=context)
    return checked(validate, "options", model, by_kind=True)


def option_value(
    name: str,
    value: Any,
    kind: Any,
    prefix: str = "options.",
    context: Mapping[str, Any] | None = None,
) -> Any:
    """One constructor option (or function argument, ``prefix=""``) validated by the
    (annotated) type ``kind`` (with the validation ``context``): errors read
    ``options.<name>: ...``, a ``TypeError`` for a value of the wrong type, a
    ``ValueError`` otherwise (as `validated_options`)."""
    adapter = TypeAdapter(kind)
    validate = partial(adapter.validate_python, plain(value), context=context)
    return checked(validate, prefix + name, by_kind=True)


@contextmanager
def errors_at(where: str) -> Iterator[None]:
    """A ``ValueError`` raised inside (a check that needs the robot or the other options,
    beyond a model) reads ``<where>: ...`` (e.g. ``options.poles``, ``per_arm[1]``)."""
    try:
        yield
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None


def plain(value: Any) -> Any:
    """numpy scalars and arrays as Python numbers and lists (recursively through mappings and
    sequences), so that ``np.float32(1e-3)`` validates like ``1e-3``."""
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Mapping):
        return {key: plain(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return type(value)(plain(item) for item in value)
    return value


def _leaves(value: Any) -> list:
    if isinstance(value, (list, tuple)):
        return [leaf for item in value for leaf in _leaves(item)]
    return [value]


def _floats(value: Any) -> Any:
    return tuple(map(_floats, value)) if isinstance(value, (list, tuple)) else float(value)
