"""Validation helpers shared by every configurable part (clear errors naming the field)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import fields
from typing import Any, TypeVar

import numpy as np

T = TypeVar("T")
ENV_NAMESPACE = "elastic_gym/"


def registered_env_id(value: Any) -> str:
    """A registered Gymnasium env id; a bare name (``TwoLinkElastic-v0``) is looked up in
    the ``elastic_gym/`` namespace. ``ValueError`` lists the package's ids otherwise."""
    from gymnasium import registry

    if not isinstance(value, str):
        raise ValueError(f"env id must be a string, got {value!r}")
    env_id = value if "/" in value else ENV_NAMESPACE + value
    if env_id not in registry:
        valid = sorted(k for k in registry if k.startswith(ENV_NAMESPACE))
        raise ValueError(f"unknown env id {value!r}; valid: {valid}")
    return env_id


def checked_fields(cls: type[T], config: Any, what: str) -> dict | T | None:
    """Validate the keys of a mapping against the fields of dataclass ``cls``.

    Returns ``None`` for ``None``, the object itself for an instance of ``cls``, and the
    mapping as a dict otherwise. Raises ``TypeError`` for anything else and
    ``ValueError`` listing unknown and valid field names.
    """
    if config is None or isinstance(config, cls):
        return config
    if not isinstance(config, Mapping):
        raise TypeError(f"{what} must be a mapping, got {type(config).__name__}")
    allowed = {f.name for f in fields(cls)}
    unknown = set(config) - allowed
    if unknown:
        raise ValueError(f"unknown {what} field(s) {sorted(unknown)}; valid: {sorted(allowed)}")
    return dict(config)


def config_from(cls: type[T], config: Any, what: str) -> T:
    """An instance of dataclass ``cls`` from ``None`` (the defaults), an instance (itself)
    or a mapping of its field names (checked by :func:`checked_fields`)."""
    config = checked_fields(cls, config, what)
    if config is None:
        return cls()
    return config if isinstance(config, cls) else cls(**config)


def check_applies(kind: str, name: str, applies_to: frozenset[str], model) -> None:
    """Refuse an observer/controller built for elastic arms on a rigid robot and vice versa."""
    arm = "elastic" if model.elastic else "rigid"
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
    names the option (``name``) and shows what was given.
    """
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        arr = np.full(n + 1, np.nan)  # reported below
    if arr.ndim == 0:
        arr = np.full(n, float(arr))
    ok = arr.shape == (n,) and bool(np.all(np.isfinite(arr)))
    if ok and minimum is not None:
        ok = bool(np.all(arr > minimum) if strict else np.all(arr >= minimum))
    if not ok:
        bound = "" if minimum is None else f" {'>' if strict else '>='} {minimum:g}"
        raise ValueError(f"{name} must be one or {n} finite numbers{bound}, got {value!r}")
    return arr.copy()
