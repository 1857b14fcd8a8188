"""The env classes' signature: their own parameters and `EnvConfig`'s fields.

An env of the package takes `**kwargs` and forwards them to its
[`ArmBatch`][elastic_gym.envs.batch.ArmBatch] as an
[`EnvConfig`][elastic_gym.envs.config.EnvConfig]. `with_batch_options` gives its
`__init__` the signature it really accepts (`inspect.signature`, `help`, the keyword
checks of scenarios and training configs), derived from the config's fields (names,
defaults, types), and refuses an unknown keyword with the valid ones before anything is
built.
"""

from __future__ import annotations

import functools
import inspect
import types
import typing
from typing import Annotated, Any, Literal

from pydantic import BaseModel

from elastic_gym.envs.config import EnvConfig

BATCH_OPTIONS = tuple(EnvConfig.model_fields)
"""The env kwargs every env of the package forwards to `ArmBatch` (`EnvConfig`'s fields)."""


def _type_text(annotation: Any) -> str:
    """A short text of a config field's type for a signature: `float | None`,
    `dict | EncoderConfig | None`, `dict[str, dict | PlantRange] | None` (constraints left
    out)."""
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if origin is Annotated:
        return _type_text(args[0])
    if origin in (typing.Union, types.UnionType):
        return " | ".join(dict.fromkeys(_type_text(a) for a in args))
    if origin is Literal:
        return " | ".join(repr(a) for a in args)
    if origin is not None:
        inner = ", ".join("..." if a is Ellipsis else _type_text(a) for a in args)
        return f"{getattr(origin, '__name__', str(origin))}[{inner}]"
    if annotation is type(None):
        return "None"
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return f"dict | {annotation.__name__}"  # a model is given as a mapping of its fields
    return getattr(annotation, "__name__", str(annotation))


def _batch_parameters() -> list[inspect.Parameter]:
    """The env kwargs as keyword-only parameters with `EnvConfig`'s defaults and types."""
    return [
        inspect.Parameter(
            name,
            inspect.Parameter.KEYWORD_ONLY,
            default=field.default,
            annotation=_type_text(field.annotation),
        )
        for name, field in EnvConfig.model_fields.items()
    ]


def with_batch_options(init):
    """Give an env `__init__(self, ..., **kwargs)` that forwards `kwargs` to `ArmBatch` (as
    its `EnvConfig`) the signature it really accepts (`inspect.signature`, `help`, keyword
    validation by the comparison runner): its own parameters and `EnvConfig`'s fields; an
    unknown keyword is refused with the valid ones."""
    own = inspect.signature(init)
    fixed = [p for p in own.parameters.values() if p.kind is not p.VAR_KEYWORD]
    signature = own.replace(parameters=[*fixed, *_batch_parameters()])

    @functools.wraps(init)
    def checked(self, *args, **kwargs):
        unknown = set(kwargs) - set(own.parameters) - set(BATCH_OPTIONS)
        if unknown:
            raise TypeError(
                f"{type(self).__name__}() got an unexpected keyword argument "
                f"{sorted(unknown)[0]!r}; valid: {sorted(BATCH_OPTIONS)}"
            )
        init(self, *args, **kwargs)

    checked.__signature__ = signature
    return checked
