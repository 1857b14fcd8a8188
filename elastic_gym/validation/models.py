"""The pydantic base of every configuration model and the annotated number types
(with their JSON Schemas) that configuration files share."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Annotated, Any, ClassVar

import numpy as np
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    StrictFloat,
    model_validator,
)
from pydantic_core import PydanticCustomError, core_schema
from typing_extensions import Self

from elastic_gym.validation.errors import _floats, _leaves, checked, plain, validated
from elastic_gym.validation.values import bound_text, is_real, numbers


# ---------------------------------------------------------------- declarative configuration
class StrictModel(BaseModel):
    """Base of every configuration model: unknown keys are refused (``extra="forbid"``),
    values are validated on assignment too, and numpy scalars count as Python numbers."""

    model_config = ConfigDict(
        extra="forbid", validate_assignment=True, arbitrary_types_allowed=True
    )

    @model_validator(mode="before")
    @classmethod
    def _plain_numbers(cls, data: Any) -> Any:
        if isinstance(data, Mapping):
            return {key: plain(value) for key, value in data.items()}
        return data


Finite = Annotated[StrictFloat, Field(allow_inf_nan=False)]  # a number, not a bool or a string


PositiveFinite = Annotated[Finite, Field(gt=0)]


NonNegativeFinite = Annotated[Finite, Field(ge=0)]


@dataclass(frozen=True)
class Numbers:
    """Annotation of a number or a non-empty list of numbers (e.g. one per joint), finite,
    each > ``minimum`` (``strict``) or >= it: validated to a float or a tuple of floats,
    with its JSON Schema. Not a bool, not a string. Use the aliases below."""

    minimum: float | None = None
    strict: bool = True

    def check(self, value: Any) -> float | tuple[float, ...]:
        value = plain(value)
        what = f"must be a finite number or a list of them{bound_text(self.minimum, self.strict)}"
        shapes = [(), (None,)] if not isinstance(value, (list, tuple)) or value else [()]
        arr = numbers(value, "", what, shapes, minimum=self.minimum, strict=self.strict, exact=True)
        return tuple(arr.tolist()) if arr.ndim else float(arr)

    def __get_pydantic_core_schema__(self, source: Any, handler: Any) -> Any:
        return core_schema.no_info_plain_validator_function(self.check)

    def __get_pydantic_json_schema__(self, schema: Any, handler: Any) -> dict:
        key = "exclusiveMinimum" if self.strict else "minimum"
        number = {"type": "number", **({} if self.minimum is None else {key: self.minimum})}
        return {"anyOf": [number, {"type": "array", "items": number, "minItems": 1}]}


@dataclass(frozen=True)
class Matrix:
    """Annotation of a number, a list of numbers or a list of lists (a matrix) of finite
    entries of magnitude <= ``bound``: validated to nested tuples of floats. Its shape is
    the user's to check. Not a bool, not a string (a ``TypeError`` in option errors)."""

    bound: float = float("inf")

    def check(self, value: Any) -> Any:
        value = plain(value)
        leaves = _leaves(value)
        if not (
            leaves and all(is_real(x) and np.isfinite(x) and abs(x) <= self.bound for x in leaves)
        ):
            kind = "value_error" if all(map(is_real, leaves)) else "matrix_type"
            shown = f", got {value!r}" if isinstance(value, (list, tuple)) else ""  # else: added
            bound = f" and of magnitude <= {self.bound:g}" if np.isfinite(self.bound) else ""
            raise PydanticCustomError(
                kind, f"must be a number, a list of numbers or a matrix, finite{bound}{shown}"
            )
        return _floats(value)

    def __get_pydantic_core_schema__(self, source: Any, handler: Any) -> Any:
        return core_schema.no_info_plain_validator_function(self.check)

    def __get_pydantic_json_schema__(self, schema: Any, handler: Any) -> dict:
        number = {"type": "number", "minimum": -self.bound, "maximum": self.bound}
        row = {"type": "array", "items": number, "minItems": 1}
        return {"anyOf": [number, row, {"type": "array", "items": row, "minItems": 1}]}


FiniteNumbers = Annotated[float | tuple[float, ...], Numbers()]


PositiveNumbers = Annotated[float | tuple[float, ...], Numbers(0.0)]


NonNegativeNumbers = Annotated[float | tuple[float, ...], Numbers(0.0, strict=False)]


class ConfigModel(StrictModel):
    """A frozen plain-data configuration, built by `from_config` from ``None`` (the
    defaults), an instance (itself) or a mapping of its fields; errors are prefixed with
    its ``section`` (``reward.sigmas: ...``)."""

    model_config = ConfigDict(frozen=True)
    section: ClassVar[str] = ""

    def __init__(self, **data: Any) -> None:
        """Keyword construction refuses bad fields in the package's error form too."""
        checked(lambda: super(ConfigModel, self).__init__(**data), self.section, type(self))

    # not a custom __init__ for pydantic: a nested config is validated as a field, its
    # errors with their full path (``reward.sigmas[0]``), not through this prefix
    __init__.__pydantic_base_init__ = True  # type: ignore[attr-defined]

    @classmethod
    def from_config(cls, config: Any) -> Self:
        return validated(cls, config, cls.section)

    def to_dict(self) -> dict:
        """Plain data (lists, not tuples): YAML- and JSON-serialisable."""
        return self.model_dump(mode="json")
