"""Validation shared by every configurable part: clear errors naming the field.

* `errors` — field paths, refusals, and pydantic's errors in the package's one form;
* `values` — checks of plain values (numbers and shapes, counts, names, options
  given together);
* `models` — the pydantic base models and annotated number types of the configuration
  files.

Checks that belong to one domain live beside it (env ids in `elastic_gym.envs.ids`,
robot kinds in `elastic_gym.robots.spec`, gain and covariance options in
`elastic_gym.model.option_checks`).
"""

from elastic_gym.validation.errors import (
    ConfigError,
    FieldError,
    checked,
    errors_at,
    field_names,
    field_path,
    format_validation_error,
    option_value,
    plain,
    refusal,
    validated,
    validated_options,
)
from elastic_gym.validation.models import (
    ConfigModel,
    Finite,
    FiniteNumbers,
    Matrix,
    NonNegativeFinite,
    NonNegativeNumbers,
    Numbers,
    PositiveFinite,
    PositiveNumbers,
    StrictModel,
)
from elastic_gym.validation.values import (
    all_or_none,
    at_most_one,
    bound_text,
    checked_count,
    distinct,
    entry,
    is_count,
    is_real,
    known,
    lookup,
    numbers,
    only_when,
    ordered,
    per_joint_values,
    shaped,
)

__all__ = [
    "ConfigError",
    "ConfigModel",
    "FieldError",
    "Finite",
    "FiniteNumbers",
    "Matrix",
    "NonNegativeFinite",
    "NonNegativeNumbers",
    "Numbers",
    "PositiveFinite",
    "PositiveNumbers",
    "StrictModel",
    "all_or_none",
    "at_most_one",
    "bound_text",
    "checked",
    "checked_count",
    "distinct",
    "entry",
    "errors_at",
    "field_names",
    "field_path",
    "format_validation_error",
    "is_count",
    "is_real",
    "known",
    "lookup",
    "numbers",
    "only_when",
    "option_value",
    "ordered",
    "per_joint_values",
    "plain",
    "refusal",
    "shaped",
    "validated",
    "validated_options",
]
