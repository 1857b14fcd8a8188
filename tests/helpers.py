"""Helpers shared by several test modules (import as ``from helpers import ...``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

GRAVITY = 9.81


def synthetic_log_columns(rows: int = 1200, dt: float = 1e-3, state: bool = True) -> dict:
    """Columns of a plausible TwoLinkElastic log (not a simulation): smooth motions inside
    the limits, torques inside the limits, accelerometers reading about g."""
    t = np.arange(rows) * dt
    theta = np.stack([0.4 * np.sin(2 * np.pi * 0.5 * t), 1.0 + 0.3 * np.cos(2 * np.pi * t)], 1)
    dtheta = np.stack(
        [0.4 * np.pi * np.cos(np.pi * t), -0.6 * np.pi * np.sin(2 * np.pi * t)], axis=1
    )
    torque = np.stack([20.0 * np.sin(3 * t), -5.0 + 4.0 * np.cos(5 * t)], axis=1)
    wobble = 0.2 * np.sin(7 * t)[:, None]
    acc1 = np.hstack([wobble, 0.1 + 0 * wobble, GRAVITY + wobble])
    acc2 = np.hstack([GRAVITY * 0.6 + wobble, GRAVITY * 0.8 - wobble, 0.05 + 0 * wobble])
    columns = {"time": t}
    for j in range(2):
        columns[f"motor_position_{j + 1}"] = theta[:, j]
    for j in range(2):
        columns[f"torque_{j + 1}"] = torque[:, j]
    for name, acc in (("acc_link1", acc1), ("acc_link2", acc2)):
        for c, axis in enumerate("xyz"):
            columns[f"{name}_{axis}"] = acc[:, c]
    if state:
        for j in range(2):
            columns[f"q_{j + 1}"] = theta[:, j] - 0.01
            columns[f"dq_{j + 1}"] = dtheta[:, j]
            columns[f"theta_{j + 1}"] = theta[:, j]
            columns[f"dtheta_{j + 1}"] = dtheta[:, j]
    return columns


def write_csv_columns(path: Path, columns: dict, sidecar: str | None = None) -> Path:
    """A CSV log of ``columns`` (name -> array) and its sidecar text (default: the
    TwoLinkElastic robot at 1 ms)."""
    names = list(columns)
    values = np.column_stack([columns[name] for name in names])
    lines = [",".join(names)] + [",".join(map(repr, row)) for row in values.tolist()]
    path.write_text("\n".join(lines) + "\n")
    side = sidecar if sidecar is not None else "robot: TwoLinkElastic-v0\nsample_time: 0.001\n"
    path.with_suffix(".yaml").write_text(side)
    return path
