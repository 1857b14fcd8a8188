"""An identified model file: the parameters `elastic-gym identify` fitted to a sensor log.

The file is YAML validated by `IdentifiedModel` (JSON Schema ``model``
shipped with the package's other schemas). Per joint it holds the stiffness K, spring
damping D, motor inertia B of De Luca et al. (2007), eq. (1), a mass scale of the link the
joint moves (mass and rotational inertia scaled together, the centre of mass kept: the
``link_mass`` of `ParameterScaling`), viscous and Coulomb link friction
d(q') = F_v q' + F_c tanh(q' / v_s); per accelerometer its bias; each estimate with its
standard error and nominal value; the fit's summary; the base inertial parameters.

[`IdentifiedModel.robot_model`][elastic_gym.model.identified.IdentifiedModel.robot_model] turns it
into the `RobotModel` that observers and
controllers build on, from the nominal model of the same robot (its kinematics and
accelerometer mounts are kept): ``compare``, ``benchmark`` and ``train`` use it where they
use the nominal model (the simulated plant stays what it is).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from pydantic import Field, StrictStr

from elastic_gym.model.robot_model import ParameterScaling, RobotModel
from elastic_gym.robots.spec import LinkFriction
from elastic_gym.validation import (
    Finite,
    NonNegativeFinite,
    PositiveFinite,
    StrictModel,
    validated,
)
from elastic_gym.yaml_io import load_yaml

FORMAT = 1
SCHEMA_NAME = "model"
Name = Annotated[StrictStr, Field(min_length=1)]


class Estimate(StrictModel):
    """A fitted value with its standard error (None: not computed) and the nominal value
    the fit started from; ``held``: the log did not identify it and the value is the
    nominal one."""

    value: Finite
    std: NonNegativeFinite | None = None
    nominal: Finite | None = None
    held: bool = False


class PositiveEstimate(Estimate):
    value: PositiveFinite


class NonNegativeEstimate(Estimate):
    value: NonNegativeFinite


class JointEstimates(StrictModel):
    """The parameters of one joint (SI units: N m/rad, N m s/rad, kg m^2, N m s/rad, N m)."""

    name: Name
    stiffness: PositiveEstimate
    damping: NonNegativeEstimate
    motor_inertia: PositiveEstimate
    link_mass_scale: PositiveEstimate
    viscous_friction: Estimate
    coulomb_friction: Estimate


class AccelerometerBias(StrictModel):
    """The constant bias of one 3-axis accelerometer, in its own frame (m/s^2)."""

    name: Name
    bias: tuple[Finite, Finite, Finite]
    std: tuple[NonNegativeFinite, NonNegativeFinite, NonNegativeFinite] | None = None


class BaseParameter(StrictModel):
    """A base inertial parameter (a combination of the standard ones, ``name``)."""

    name: Name
    value: Finite
    std: NonNegativeFinite | None = None
    nominal: Finite | None = None


class FitSummary(StrictModel):
    """How the fit went: the log, the filter, the condition number, the held-out fit."""

    log: StrictStr = ""
    log_sha256: StrictStr = ""
    samples: Annotated[int, Field(ge=0)] = 0
    duration: NonNegativeFinite = 0.0
    torque_hold: bool = True
    delay: NonNegativeFinite = 0.0
    accelerometer_cutoff_hz: PositiveFinite | None = None
    pass_hz: PositiveFinite | None = None
    stop_hz: PositiveFinite | None = None
    condition_number: NonNegativeFinite | None = None
    residual_std_readings: dict[str, NonNegativeFinite] = Field(default_factory=dict)
    residual_std_link: dict[str, NonNegativeFinite] = Field(default_factory=dict)
    holdout_fit_readings: dict[str, Finite] = Field(default_factory=dict)
    holdout_fit_link: dict[str, Finite] = Field(default_factory=dict)
    warnings: list[StrictStr] = Field(default_factory=list)
    version: StrictStr = ""
    date: StrictStr = ""


class IdentifiedModel(StrictModel):
    """An identified model file (see the module docstring)."""

    format: Literal[1] = 1
    robot: Name
    coulomb_velocity: PositiveFinite = 0.01
    joints: list[JointEstimates]
    accelerometers: list[AccelerometerBias] = Field(default_factory=list)
    base_parameters: list[BaseParameter] = Field(default_factory=list)
    fit: FitSummary = Field(default_factory=FitSummary)

    def values(self, name: str) -> np.ndarray:
        """The fitted ``name`` (a field of `JointEstimates`) of every joint."""
        return np.array([getattr(joint, name).value for joint in self.joints], dtype=float)

    def robot_model(self, nominal: RobotModel) -> RobotModel:
        """The `RobotModel` of these parameters on ``nominal``'s robot (its spec,
        kinematics and accelerometer mounts; its own parameter scaling is replaced).

        Raises ``ValueError`` naming the mismatch when the file is of another robot or
        joint set, or gives a nonzero damping where the robot's spec has none."""
        spec = nominal.spec
        names = tuple(joint.name for joint in self.joints)
        if self.robot != spec.name or names != spec.joint_names:
            raise ValueError(
                f"the identified model is of robot {self.robot!r} with joints {list(names)}, "
                f"not of {spec.name!r} with joints {list(spec.joint_names)}"
            )
        if not spec.elastic:
            raise ValueError(f"robot {spec.name!r} has rigid joints: no elastic model to set")

        def ratio(field: str, spec_values: tuple[float, ...] | None) -> tuple[float, ...]:
            value = self.values(field)
            base = np.asarray(spec_values, dtype=float)
            zero = base == 0.0
            if np.any(zero & (value != 0.0)):
                joint = names[int(np.flatnonzero(zero & (value != 0.0))[0])]
                raise ValueError(f"joints[{joint}].{field}: robot {spec.name!r} has none to scale")
            return tuple(np.where(zero, 1.0, value / np.where(zero, 1.0, base)).tolist())

        scaling = ParameterScaling(
            stiffness=ratio("stiffness", spec.stiffness),
            damping=ratio("damping", spec.damping),
            motor_inertia=ratio("motor_inertia", spec.motor_inertia),
            link_mass=tuple(self.values("link_mass_scale").tolist()),
            friction=0.0,  # the spec's own link friction is replaced by the fitted one
        )
        viscous = np.maximum(self.values("viscous_friction"), 0.0)
        coulomb = np.maximum(self.values("coulomb_friction"), 0.0)
        friction = None
        if np.any(viscous > 0.0) or np.any(coulomb > 0.0):
            friction = LinkFriction(
                viscous=tuple(viscous.tolist()),
                coulomb_pos=tuple(coulomb.tolist()) if np.any(coulomb > 0.0) else None,
                smoothing_velocity=self.coulomb_velocity,
            )
        return RobotModel(spec, scaling, nominal.accelerometers, added_friction=friction)

    def to_yaml(self) -> str:
        """The file's text, with the schema comment on its first line."""
        import yaml

        from elastic_gym.schemas import schema_comment

        body = yaml.safe_dump(self.model_dump(mode="json"), sort_keys=False)
        return schema_comment(SCHEMA_NAME) + body


def load_identified_model(path: str | Path) -> IdentifiedModel:
    """The identified model file at ``path``, validated (errors name the file and the
    field: ``model.yaml: joints[0].stiffness.value: ...``)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"identified model file {str(path)!r} does not exist")
    return validated(IdentifiedModel, load_yaml(path), str(path))


def identified_robot_model(path: str | Path, nominal: RobotModel) -> RobotModel:
    """The `RobotModel` of the identified model file at ``path`` on ``nominal``'s robot."""
    model = load_identified_model(path)
    try:
        return model.robot_model(nominal)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None


def checked_model_file(path: str) -> str:
    """An identified model file (`elastic-gym identify`), checked (``ValueError`` for a
    missing or invalid one); returned as given."""
    try:
        load_identified_model(path)
    except FileNotFoundError as exc:
        raise ValueError(str(exc)) from None
    return path
