"""The arm axis: what every layer shares about one arm versus a batch of arms.

Observations and infos of a vector env (and of [`ArmBatch`][elastic_gym.envs.batch.ArmBatch])
carry a leading arm axis on every array and Gymnasium's boolean ``_key`` masks; those of a
single env have neither. These helpers move between the two layouts (`arm_view`,
`as_batch`, `single_arm`) and read the desired trajectory q_d .. q_d^(4)
(``info["reference"]``, keys `REFERENCE_KEYS`) the same way for one arm and for N.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

REFERENCE_KEYS = ("q", "dq", "ddq", "d3q", "d4q")  # q_d and its first four derivatives


def arm_view(batched: Mapping, i: int) -> dict:
    """Arm i of a batched observation or info (nested mappings too; ``_key`` masks dropped)."""
    return {
        key: arm_view(value, i) if isinstance(value, Mapping) else value[i]
        for key, value in batched.items()
        if not key.startswith("_")
    }


def reference_rows(info: Mapping) -> np.ndarray:
    """``info["reference"]`` as float rows q_d .. q_d^(4): (5, n) for one arm, (N, 5, n)
    for a batch."""
    reference = info["reference"]
    return np.stack([np.asarray(reference[key], dtype=float) for key in REFERENCE_KEYS], axis=-2)


def as_batch(value: Any) -> Any:
    """``value`` of one arm as a batch of one arm: a leading axis of length 1 (mappings
    item by item; strings and None as object arrays, so that a longer string can replace
    them)."""
    kind = type(value)  # the types of an arm's info first, by identity (no ABC test)
    if kind is np.ndarray:
        if value.dtype.kind not in "OUS":
            return value[None]
    elif kind is float or kind is bool or kind is int:
        return np.array((value,))  # float64, bool, int64 as np.asarray gives them
    elif kind is dict:
        return {key: as_batch(item) for key, item in value.items()}
    if isinstance(value, np.ndarray | float | int | np.generic):  # before the slower ABC test
        arr = np.asarray(value)
        if arr.dtype.kind not in "OUS":  # bool is an int
            return arr[None]
    elif type(value) is dict or isinstance(value, Mapping):  # arrays inline: an info holds
        return {  # about twenty
            key: item[None]
            if type(item) is np.ndarray and item.dtype.kind not in "OUS"
            else as_batch(item)
            for key, item in value.items()
        }
    out = np.empty(1, dtype=object)
    out[0] = value
    return out


def single_arm(value: Any) -> Any:
    """The one arm of a batch of one arm (`as_batch` reversed: ``_key`` masks
    dropped, numpy scalars as Python scalars, as a single env gives them)."""
    if type(value) is not np.ndarray and (type(value) is dict or isinstance(value, Mapping)):
        return {
            key: item[0]
            if type(item) is np.ndarray and item.ndim > 1 and item.dtype.kind not in "OUS"
            else single_arm(item)
            for key, item in value.items()
            if key[:1] != "_"
        }
    item = value[0]
    return item.item() if isinstance(item, np.generic) else item


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
