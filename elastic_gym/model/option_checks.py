"""Checks of observer and controller options against a robot model and a sampling period:
stable poles, matrices of gains and covariances, rates a sampled design can reach, and
options a robot must have the hardware for."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from pydantic_core import core_schema

from elastic_gym.validation import numbers


def stable_poles(value: Any, *shapes: tuple[int, ...]) -> np.ndarray:
    """``value`` as a complex array of one of ``shapes``: finite poles with negative real
    parts (a stable design); ``ValueError`` naming ``poles`` and what was given otherwise."""
    what = (
        "must be finite numbers (complex allowed) with negative real parts, of shape "
        + " or ".join(map(str, shapes))
    )
    return numbers(value, "poles", what, shapes, dtype=complex, stable=True)


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
    """The (size, size) matrix of a `Matrix` option (``options.<name>``) from its
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
