"""The arm axis: what every layer shares about one arm versus a batch of arms.

Observations and infos of a vector env (and of :class:`~elastic_gym.envs.batch.ArmBatch`)
carry a leading arm axis on every array and Gymnasium's boolean ``_key`` masks; those of a
single env have neither. These helpers move between the two layouts and read the desired
trajectory q_d .. q_d^(4) (``info["reference"]``, keys :data:`REFERENCE_KEYS`) the same
way for one arm and for N.
"""

from __future__ import annotations

from collections.abc import Mapping

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
