"""Checks of plain values: numbers and shapes, counts, names, options given together."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any, TypeGuard, TypeVar

import numpy as np

from elastic_gym.validation.errors import FieldError, _leaves, plain, refusal

T = TypeVar("T")


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
    """``value`` as an ``int`` if `is_count`; ``ValueError`` naming ``name`` otherwise."""
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
    ``value`` was derived from it): a `FieldError` whose ``loc`` continues a
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
        or (finite and not np.isfinite(arr).all())
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
    """`` > 0`` / `` >= 0`` (or nothing) for the messages of `numbers`."""
    return "" if minimum is None else f" {'>' if strict else '>='} {minimum:g}"


def shaped(
    value: Any, shape: tuple[int | None, ...], name: str, finite: bool = False
) -> np.ndarray:
    """``value`` as a float64 array of ``shape`` (a leading ``None``: any length N, e.g.
    one row per arm), with finite entries if ``finite`` (`numbers`)."""

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
    """``data[key]`` of a step's ``obs`` or ``info`` (``where``) as `shaped` makes it
    (``shape`` ``None``: the value as given). ``ValueError`` reading ``missing`` (who needs
    the entry and where it comes from) when ``data`` lacks it."""
    if not isinstance(data, Mapping) or key not in data:
        raise ValueError(missing)
    return data[key] if shape is None else shaped(data[key], shape, f"{where}[{key!r}]", finite)


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


def per_joint_values(
    value: Any, n: int, name: str, minimum: float | None = None, strict: bool = False
) -> np.ndarray:
    """A scalar or N finite numbers as an (N,) float array, optionally bounded below.

    ``minimum`` with ``strict`` means every value > minimum, else >= minimum. The error
    names the option (``name``) and shows what was given (`numbers`).
    """
    what = f"must be one or {n} finite numbers{bound_text(minimum, strict)}"
    arr = numbers(value, name, what, [(n,)], broadcast=n, minimum=minimum, strict=strict)
    return arr.copy()
