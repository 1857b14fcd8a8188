"""Robot description files: a robot that is not in the catalog, as YAML.

A description file gives what a [`RobotSpec`][elastic_gym.robots.spec.RobotSpec] holds: the
URDF (relative to the file), the actuated joints in state order, the elastic transmission
of De Luca et al. (2007), model (1)/(2) — stiffness K, motor inertia B, damping D,
optionally the constant coupling S — the torque limits and the accelerometer mounts:

`name: my_arm`, `urdf: my_arm.urdf`, `joint_names: [shoulder, elbow]`, `stiffness: [3000.0,
1800.0]`, ... (the guide "Your robot's data" has a whole file). A sensor log's sidecar may
name such a file instead of an env id. Errors name the file and the field.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import numpy as np
from pydantic import Field, StrictBool, StrictStr

from elastic_gym.robots.spec import AccelerometerMount, LinkFriction, RobotSpec
from elastic_gym.robots.urdf_tools import joint_limits
from elastic_gym.validation import (
    Finite,
    NonNegativeFinite,
    PositiveFinite,
    StrictModel,
    errors_at,
    validated,
)

Name = Annotated[StrictStr, Field(min_length=1)]


class FrictionDescription(StrictModel):
    """Link-side friction d(q') = F_v q' + Coulomb (see `LinkFriction`), one value per joint."""

    viscous: list[NonNegativeFinite]
    coulomb_pos: list[NonNegativeFinite] | None = None
    coulomb_neg: list[NonNegativeFinite] | None = None
    smoothing_velocity: PositiveFinite = 0.01


class RobotDescription(StrictModel):
    """A robot description file (module docstring); lengths are checked against
    `joint_names` when the spec is built."""

    name: Name
    urdf: Name
    joint_names: Annotated[list[Name], Field(min_length=1)]
    elastic: StrictBool = True
    stiffness: list[PositiveFinite] | None = None
    motor_inertia: list[PositiveFinite] | None = None
    damping: list[NonNegativeFinite] | None = None
    coupling: list[list[Finite]] | None = None
    torque_limit: list[PositiveFinite]
    accelerometers: list[AccelerometerMount] = Field(default_factory=list)
    workspace_low: list[Finite] | None = None
    workspace_high: list[Finite] | None = None
    max_move: PositiveFinite = 0.8
    encoder_resolution: NonNegativeFinite = 2.0 * np.pi / 2**20
    encoder_noise_std: NonNegativeFinite = 0.0
    friction: FrictionDescription | None = None
    physics_dt: PositiveFinite = 5e-4
    control_dt: PositiveFinite = 1e-3
    gravity: tuple[Finite, Finite, Finite] = (0.0, 0.0, -9.81)
    source: StrictStr = ""


def _tuple(values: list | None) -> tuple | None:
    return None if values is None else tuple(values)


def robot_from_description(path: str | Path) -> RobotSpec:
    """The [`RobotSpec`][elastic_gym.robots.spec.RobotSpec] of a description file.

    The workspace box defaults to the URDF's joint limits, or to one turn either way
    (±π) for a joint without limits. `ValueError` naming the file (and the field) for an
    unreadable file, invalid YAML, a bad field or a URDF that does not exist.
    """
    from elastic_gym.yaml_io import load_yaml

    path = Path(path)
    data = load_yaml(path)
    with errors_at(str(path)):
        description = validated(RobotDescription, data)
    urdf = (path.parent / description.urdf).resolve()
    if not urdf.is_file():
        raise ValueError(f"{path}: urdf: no such file {str(urdf)!r}")
    n = len(description.joint_names)
    lower, upper = joint_limits(str(urdf), tuple(description.joint_names))
    low = np.where(np.isfinite(lower), lower, -np.pi)
    high = np.where(np.isfinite(upper), upper, np.pi)
    friction = description.friction
    try:
        return RobotSpec(
            name=description.name,
            urdf=str(urdf),
            joint_names=tuple(description.joint_names),
            elastic=description.elastic,
            stiffness=_tuple(description.stiffness),
            motor_inertia=_tuple(description.motor_inertia),
            damping=_tuple(description.damping),
            coupling=None
            if description.coupling is None
            else tuple(tuple(row) for row in description.coupling),
            torque_limit=tuple(description.torque_limit),
            friction=None
            if friction is None
            else LinkFriction(
                viscous=tuple(friction.viscous),
                coulomb_pos=_tuple(friction.coulomb_pos),
                coulomb_neg=_tuple(friction.coulomb_neg),
                smoothing_velocity=friction.smoothing_velocity,
            ),
            accelerometers=tuple(description.accelerometers),
            workspace_low=_tuple(description.workspace_low) or tuple(low.tolist()),
            workspace_high=_tuple(description.workspace_high) or tuple(high.tolist()),
            max_move=description.max_move,
            encoder_resolution=description.encoder_resolution,
            encoder_noise_std=description.encoder_noise_std,
            physics_dt=description.physics_dt,
            control_dt=description.control_dt,
            gravity=description.gravity,
            source=description.source or f"robot description file {path.name}",
        )
    except ValueError as exc:  # the spec's own checks (lengths, S strictly upper triangular)
        raise ValueError(f"{path}: {exc} ({n} joints: {description.joint_names})") from None
