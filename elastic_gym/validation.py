"""Validation helpers shared by every configurable part (clear errors naming the field)."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from functools import partial
from typing import Annotated, Any, ClassVar, TypeGuard, TypeVar, get_args

import numpy as np
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    StrictFloat,
    TypeAdapter,
    ValidationError,
    model_validator,
)
from pydantic_core import PydanticCustomError, core_schema
from typing_extensions import Self

T = TypeVar("T")
ENV_NAMESPACE = "elastic_gym/"


def is_real(value: Any) -> bool:
    """Whether ``value`` is a real number: Python's ``int`` / ``float`` or a numpy scalar
    (``np.float32(1e-3)``, ``np.int64(3)``); not a bool."""
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(
        value, (bool, np.bool_)
    )


def is_count(value: Any, minimum: int | None = 0) -> TypeGuard[int | np.integer]:
    """Whether ``value`` is an integer (Python or numpy, not a bool) >= ``minimum``
    (``None``: any integer)."""
    return bool(
        isinstance(value, (int, np.integer))
        and not isinstance(value, (bool, np.bool_))
        and (minimum is None or value >= minimum)
    )


def checked_count(value: Any, name: str, minimum: int = 0) -> int:
    """``value`` as an ``int`` if :func:`is_count`; ``ValueError`` naming ``name`` otherwise."""
    if not is_count(value, minimum):
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def distinct(values: Sequence[Any], what: str, why: str = "", where: str = "") -> Sequence[Any]:
    """``values`` if none repeats; ``ValueError: [<where>: ]duplicate <what> [...]<why>``
    otherwise."""
    repeated = sorted({x for x in values if values.count(x) > 1})
    if repeated:
        raise ValueError(f"{where}{': ' if where else ''}duplicate {what} {repeated}{why}")
    return values


def _given(options: Mapping[str, Any]) -> list[str]:
    return [name for name, value in options.items() if value is not None]


def at_most_one(options: Mapping[str, Any], required: bool = False, loc: Sequence = ()) -> None:
    """Refuse more than one of ``options`` (name -> value, ``None``: not given), and none
    when ``required``: ``FieldError`` (a ``ValueError``; ``loc`` continues a validator's
    path) reading ``give one of a or b, not a and b``."""
    given = _given(options)
    if len(given) > 1 or (required and not given):
        choice = f"give {'one' if required else 'at most one'} of {' or '.join(options)}"
        raise FieldError(loc, choice + (f", not {' and '.join(given)}" if given else ""))


def all_or_none(options: Mapping[str, Any], loc: Sequence = ()) -> None:
    """Refuse some but not all of ``options`` (name -> value, ``None``: not given):
    ``FieldError`` reading ``give kp and kd together (or none): kd missing``."""
    given = _given(options)
    if 0 < len(given) < len(options):
        missing = [name for name in options if name not in given]
        together = f"give {' and '.join(options)} together (or none)"
        raise FieldError(loc, f"{together}: {' and '.join(missing)} missing")


def only_when(condition: bool, options: Mapping[str, Any], when: str, loc: Sequence = ()) -> None:
    """Refuse ``options`` (name -> value; ``None``, ``False`` or an empty mapping: not
    given) unless ``condition``: ``FieldError`` (``loc`` continues a validator's path)
    reading ``best: applies only when run is a run folder, not a loaded run`` (without
    the name when ``loc`` ends with it)."""
    given = [
        name
        for name, value in options.items()
        if value is not None
        and value is not False
        and not (isinstance(value, Mapping) and not value)
    ]
    if given and not condition:
        text = f"{'apply' if len(given) > 1 else 'applies'} only when {when}"
        named = tuple(loc[-1:]) == tuple(given)  # the path names it already
        raise refusal(loc, text if named else f"{' and '.join(given)}: {text}")


def ordered(
    low: float,
    high: float,
    strict: bool = False,
    names: tuple[str, str] = ("low", "high"),
    loc: Sequence = (),
) -> None:
    """Refuse ``low > high`` (``strict``: ``low >= high``) of a range: ``FieldError``
    (``loc`` continues a validator's path) reading ``low (2) must be <= high (1)``."""
    if low > high or (strict and low == high):
        relation = "<" if strict else "<="
        raise FieldError(loc, f"{names[0]} ({low:g}) must be {relation} {names[1]} ({high:g})")


def numbers(
    value: Any,
    name: str,
    what: str | Callable[[], str],
    shapes: Sequence[tuple[int | None, ...]],
    *,
    dtype: type = float,
    broadcast: int | None = None,
    finite: bool = True,
    minimum: float | None = None,
    strict: bool = False,
    bound: float | None = None,
    stable: bool = False,
    exact: bool = False,
    show_shape: bool = False,
    shown: Any = None,
    loc: Sequence[int | str] = (),
) -> np.ndarray:
    """The one check of numeric input: ``value`` as a ``dtype`` array (``float`` or
    ``complex``) whose shape is one of ``shapes`` (a ``None`` entry: any length; a scalar
    is first repeated ``broadcast`` times when given), with finite entries (``finite``),
    each > ``minimum`` (``strict``) or >= it, of magnitude <= ``bound``, with negative
    real parts (``stable``: poles of a stable design), and Python or numpy numbers only
    (``exact``: no bool, no string). ``ValueError: <name> <what>, got <value or shape>``
    otherwise (``show_shape``: the shape given; ``shown``: what the user gave, when
    ``value`` was derived from it): a :class:`FieldError` whose ``loc`` continues a
    validator's path."""
    try:
        arr: np.ndarray | None = np.asarray(value, dtype=dtype)
    except (TypeError, ValueError):  # not numbers, or ragged rows
        arr = None
    if arr is not None and arr.ndim == 0 and broadcast is not None:
        arr = np.full(broadcast, arr[()])
    if (
        arr is None
        or not (arr.shape in shapes or any(_fits_shape(arr.shape, shape) for shape in shapes))
        or (finite and not np.all(np.isfinite(arr)))
        or (minimum is not None and not np.all(arr > minimum if strict else arr >= minimum))
        or (bound is not None and np.any(np.abs(arr) > bound))
        or (stable and np.any(arr.real >= 0.0))
        or (exact and not all(map(is_real, _leaves(plain(value)))))
    ):
        given = value if shown is None else shown
        got = ("ragged rows" if arr is None else arr.shape) if show_shape else repr(given)
        what = what() if callable(what) else what  # a callable: the hot paths build no text
        raise refusal(loc, f"{name}{' ' if name else ''}{what}, got {got}")
    return arr


def _fits_shape(actual: tuple[int, ...], wanted: tuple[int | None, ...]) -> bool:
    """Whether an array shape is ``wanted`` (a ``None`` entry: any length)."""
    if len(actual) != len(wanted) or not actual:
        return False
    if None not in wanted[1:]:  # the common (None, n): any number of rows of n
        return wanted[0] in (None, actual[0]) and actual[1:] == wanted[1:]
    return all(w in (None, a) for a, w in zip(actual, wanted, strict=True))


def bound_text(minimum: float | None, strict: bool) -> str:
    """`` > 0`` / `` >= 0`` (or nothing) for the messages of :func:`numbers`."""
    return "" if minimum is None else f" {'>' if strict else '>='} {minimum:g}"


def shaped(
    value: Any, shape: tuple[int | None, ...], name: str, finite: bool = False
) -> np.ndarray:
    """``value`` as a float64 array of ``shape`` (a leading ``None``: any length N, e.g.
    one row per arm), with finite entries if ``finite`` (:func:`numbers`)."""

    def what() -> str:
        shown = str(shape).replace("None", "N")
        return f"must have {'finite entries and ' if finite else ''}shape {shown}"

    return numbers(value, name, what, [shape], finite=finite, show_shape=True)


def entry(
    data: Any,
    where: str,
    key: str,
    shape: tuple[int | None, ...] | None,
    missing: str,
    finite: bool = False,
) -> Any:
    """``data[key]`` of a step's ``obs`` or ``info`` (``where``) as :func:`shaped` makes it
    (``shape`` ``None``: the value as given). ``ValueError`` reading ``missing`` (who needs
    the entry and where it comes from) when ``data`` lacks it."""
    if not isinstance(data, Mapping) or key not in data:
        raise ValueError(missing)
    return data[key] if shape is None else shaped(data[key], shape, f"{where}[{key!r}]", finite)


def stable_poles(value: Any, *shapes: tuple[int, ...]) -> np.ndarray:
    """``value`` as a complex array of one of ``shapes``: finite poles with negative real
    parts (a stable design); ``ValueError`` naming ``poles`` and what was given otherwise."""
    what = (
        "must be finite numbers (complex allowed) with negative real parts, of shape "
        + " or ".join(map(str, shapes))
    )
    return numbers(value, "poles", what, shapes, dtype=complex, stable=True)


def lookup(table: Mapping[str, T], name: Any, what: str, loc: Sequence = ()) -> T:
    """``table[name]``; ``FieldError`` (a ``ValueError``; ``loc`` continues a validator's
    path) naming the ``what`` and listing the valid names."""
    if not isinstance(name, str) or name not in table:
        raise refusal(loc, f"unknown {what} {name!r}; valid: {sorted(table)}")
    return table[name]


def known(
    names: Iterable[Any], valid: Iterable[str], what: str, of: str = "", loc: Sequence = ()
) -> None:
    """Refuse the ``names`` not in ``valid``: ``FieldError`` (``loc`` continues a
    validator's path) reading ``unknown env kwarg(s) ['x'] for <of>; valid: [...]``."""
    valid = set(valid)
    unknown = sorted(set(names) - valid)
    if unknown:
        where = f" for {of}" if of else ""
        raise refusal(loc, f"unknown {what}(s) {unknown}{where}; valid: {sorted(valid)}")


def registered_env_id(value: Any) -> str:
    """A registered Gymnasium env id; a bare name (``TwoLinkElastic-v0``) is looked up in
    the ``elastic_gym/`` namespace. ``ValueError`` lists the package's ids otherwise."""
    from gymnasium import registry

    env_id = value if not isinstance(value, str) or "/" in value else ENV_NAMESPACE + value
    if not (isinstance(env_id, str) and env_id in registry):  # refused, the package's ids listed
        lookup({k: k for k in registry if k.startswith(ENV_NAMESPACE)}, value, "env id")
    return env_id


def elastic_base(env: Any, who: str, vector: bool = True) -> Any:
    """``env.unwrapped`` if it is an elastic_gym env (one holding the ``batch`` of its arms);
    ``TypeError`` naming ``who`` and how to make one otherwise."""
    base = env.unwrapped
    if getattr(base, "batch", None) is None:
        kind, make = (
            ("vector env", "gym.make_vec(..., vectorization_mode='vector_entry_point')")
            if vector
            else ("env", "gym.make('elastic_gym/...')")
        )
        raise TypeError(f"{who} needs an elastic_gym {kind} ({make}), got {env}")
    return base


def check_applies(kind: str, name: str, applies_to: frozenset[str], model) -> None:
    """Refuse an observer/controller built for elastic arms on a rigid robot and vice versa."""
    arm = model.spec.kind
    if arm not in applies_to:
        raise ValueError(
            f"{kind} {name!r} applies to {sorted(applies_to)} arms, "
            f"not to the {arm} robot {model.spec.name!r}"
        )


def per_joint_values(
    value: Any, n: int, name: str, minimum: float | None = None, strict: bool = False
) -> np.ndarray:
    """A scalar or N finite numbers as an (N,) float array, optionally bounded below.

    ``minimum`` with ``strict`` means every value > minimum, else >= minimum. The error
    names the option (``name``) and shows what was given (:func:`numbers`).
    """
    what = f"must be one or {n} finite numbers{bound_text(minimum, strict)}"
    arr = numbers(value, name, what, [(n,)], broadcast=n, minimum=minimum, strict=strict)
    return arr.copy()


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


@dataclass(frozen=True)
class PerSample:
    """Annotation of a rate (1/s; a number or numbers, complex allowed: poles) whose
    largest magnitude times the sampling period ``dt`` of the validation context must be
    at most ``limit`` (``why``: what a faster one would break). Without a ``dt`` in the
    context, or for a value that is not numbers (its form is the field's to check),
    nothing is checked."""

    limit: float
    why: str = ""

    def check(self, value: Any, info: core_schema.ValidationInfo) -> Any:
        dt = (info.context or {}).get("dt")
        try:
            rate = float(np.abs(np.asarray(value, dtype=complex)).max(initial=0.0))
        except (TypeError, ValueError):
            rate = 0.0
        limit = np.inf if dt is None else self.limit / dt
        if rate > limit:
            raise ValueError(
                f"too fast for the sampling period dt = {dt:g} s: must be <= "
                f"{self.limit:g}/dt = {limit:g} in magnitude{self.why}, got {value!r}"
            )
        return value

    def __get_pydantic_core_schema__(self, source: Any, handler: Any) -> Any:
        return core_schema.with_info_after_validator_function(self.check, handler(source))


@dataclass(frozen=True)
class Needs:
    """Annotation of an option whose values ``when`` need what the robot model of the
    validation context may lack: ``what`` (shown in the error, ``{n}`` the number of
    joints), present when ``has(model)``. Without a model in the context nothing is
    checked."""

    when: tuple
    what: str
    has: Callable[[Any], bool]

    def check(self, value: Any, info: core_schema.ValidationInfo) -> Any:
        model = (info.context or {}).get("model")
        if model is not None and value in self.when and not self.has(model):
            what = self.what.format(n=model.n)
            raise ValueError(f"{value!r} needs {what}, which robot {model.spec.name!r} lacks")
        return value

    def __get_pydantic_core_schema__(self, source: Any, handler: Any) -> Any:
        return core_schema.with_info_after_validator_function(self.check, handler(source))


def square_matrix(
    value: Any,
    size: int,
    name: str,
    blocks: tuple[int, ...] = (),
    symmetric: bool = False,
    psd_tolerance: float | None = None,
    definite: bool = False,
) -> np.ndarray:
    """The (size, size) matrix of a :class:`Matrix` option (``options.<name>``) from its
    compact forms: a scalar (times the identity), one value per block of ``blocks`` (each
    repeated over its block), the diagonal, or the matrix itself.

    ``symmetric``: the matrix must be symmetric (the mean of it and its transpose is
    returned); ``psd_tolerance``: its symmetric part must be positive semi-definite, to
    ``-psd_tolerance * max(1, max|entry|)`` for a full matrix, exactly for a diagonal;
    ``definite``: positive definite (its smallest eigenvalue > 0).
    """
    try:
        arr = np.asarray(value, dtype=float)
    except ValueError:  # a ragged matrix
        arr = np.full(size + 1, np.nan)
    full = arr.ndim == 2
    if arr.ndim == 0:
        arr = np.full(size, float(arr))
    elif blocks and arr.ndim == 1 and arr.size == len(blocks):
        arr = np.repeat(arr, blocks)
    if arr.shape == (size,):
        arr = np.diag(arr)
    per_block = f"{len(blocks)} block values, " if len(blocks) > 1 else ""
    what = f"must be a scalar, {per_block}{size} diagonal entries or a {size}x{size} matrix"
    numbers(arr, f"options.{name}:", what, [(size, size)], shown=value)
    mean = 0.5 * (arr + arr.T)
    scale = max(1.0, float(np.abs(arr).max())) if full else 0.0
    lowest = np.linalg.eigvalsh(mean).min() if psd_tolerance is not None or definite else 0.0
    if (
        (symmetric and not np.allclose(arr, arr.T))
        or (psd_tolerance is not None and lowest < -psd_tolerance * scale)
        or (definite and lowest <= 0.0)
    ):
        semi = "" if definite else "semi-"
        shape = f"{'symmetric ' if symmetric else ''}positive {semi}definite"
        raise ValueError(f"options.{name}: must be {shape}, got {value!r}")
    return mean if symmetric else arr


def _leaves(value: Any) -> list:
    if isinstance(value, (list, tuple)):
        return [leaf for item in value for leaf in _leaves(item)]
    return [value]


def _floats(value: Any) -> Any:
    return tuple(map(_floats, value)) if isinstance(value, (list, tuple)) else float(value)


FiniteNumbers = Annotated[float | tuple[float, ...], Numbers()]
PositiveNumbers = Annotated[float | tuple[float, ...], Numbers(0.0)]
NonNegativeNumbers = Annotated[float | tuple[float, ...], Numbers(0.0, strict=False)]


class ConfigModel(StrictModel):
    """A frozen plain-data configuration, built by :meth:`from_config` from ``None`` (the
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
    path first): what a :class:`ConfigModel` raises. Raised inside a validator, its path
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
    """The ``ValueError`` of a refused value: a :class:`FieldError` continuing a
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


def field_names(model: type[BaseModel], loc: Sequence[int | str]) -> list[str]:
    """The field names (aliases) of the model reached from ``model`` along ``loc`` (a
    union member named in ``loc`` is followed; none: ``[]``)."""
    models = [model]
    for part in loc:
        named = [m for m in models if m.__name__ == part]
        fields = [f for m in models for n, f in m.model_fields.items() if part in (n, f.alias)]
        if named:
            models = named
        elif fields:
            models = _models_in(fields[0].annotation)
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
    defaults). :class:`ConfigError` (a ``ValueError``) with one ``field.path: message`` per
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
    (after ``prefix``) first: a :class:`ConfigError` (continuing a validator's path after
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
    ``model`` and the sampling period ``dt``) is what :class:`PerSample` and
    :class:`Needs` fields read. Errors read ``options.<name>: ...``, a ``TypeError`` when
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
    ``ValueError`` otherwise (as :func:`validated_options`)."""
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
