"""Helpers for data with a leading arm axis (batched observations and infos)."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np


def arm_view(batched: Mapping, i: int) -> dict:
    """Arm i of a batched observation or info (nested mappings too; ``_key`` masks dropped)."""
    return {
        key: arm_view(value, i) if isinstance(value, Mapping) else value[i]
        for key, value in batched.items()
        if not key.startswith("_")
    }


def as_batch(single: Mapping) -> dict:
    """A single-arm observation or info as a batch of one arm (nested mappings included)."""
    return {
        key: as_batch(value) if isinstance(value, Mapping) else np.asarray(value)[None]
        for key, value in single.items()
    }
