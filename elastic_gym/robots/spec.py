"""Robot descriptions: URDF, elastic transmission parameters, sensors, limits.

A `RobotSpec` is pure data. The simulator (``envs``), the nominal model
(``model``), observers and controllers all read the same spec, so the plant and
the designer's model are built from one source of truth.

Notation follows De Luca, Schroeder & Thuemmel (ICRA 2007), eqs. (1)-(2):
``K`` joint stiffness, ``B`` motor inertia reflected through the gearbox,
``D`` spring viscosity, ``S`` constant motor/link inertial coupling.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, ClassVar

import numpy as np
from pydantic import Field, StrictStr, model_validator

from elastic_gym.validation import ConfigModel, Finite

URDF_DIR = Path(__file__).parent / "urdf"


class AccelerometerMount(ConfigModel):
    """A 3-axis accelerometer rigidly attached to a link.

    ``position`` (m) and ``rpy`` (rad, URDF roll-pitch-yaw) give the sensor frame
    in the frame of ``link`` (the URDF link frame, i.e. the frame of the joint
    that moves the link); ``name`` defaults to ``acc_<link>``.
    """

    section: ClassVar[str] = "accelerometer"
    link: Annotated[StrictStr, Field(min_length=1)]
    position: tuple[Finite, Finite, Finite]
    rpy: tuple[Finite, Finite, Finite] = (0.0, 0.0, 0.0)
    name: StrictStr = ""

    @model_validator(mode="after")
    def _default_name(self) -> AccelerometerMount:
        if not self.name:
            vars(self)["name"] = f"acc_{self.link}"
        return self


@dataclass(frozen=True)
class LinkFriction:
    """Link-side friction d(q') = F_v q' + Coulomb (Solsona & Puleston, Sec. 4).

    The Coulomb part is asymmetric (``coulomb_pos`` for q' > 0, ``coulomb_neg`` for
    q' < 0) and smoothed with ``tanh(q' / smoothing_velocity)``, because a sign
    function is not integrable with an explicit physics step.
    """

    viscous: tuple[float, ...]
    coulomb_pos: tuple[float, ...] | None = None
    coulomb_neg: tuple[float, ...] | None = None
    smoothing_velocity: float = 0.01
    # arrays of each instance, set once by __post_init__ (not fields)
    _viscous: ClassVar[np.ndarray]
    _coulomb: ClassVar[tuple[np.ndarray, np.ndarray] | None]  # (q' > 0, q' < 0)

    def __post_init__(self) -> None:
        # arrays once: torque() is called at every physics step
        pos = self.coulomb_pos
        neg = self.coulomb_neg if self.coulomb_neg is not None else pos
        object.__setattr__(self, "_viscous", np.asarray(self.viscous, dtype=float))
        coulomb = (
            None if pos is None else (np.asarray(pos, dtype=float), np.asarray(neg, dtype=float))
        )
        object.__setattr__(self, "_coulomb", coulomb)

    def torque(self, dq: np.ndarray) -> np.ndarray:
        """Friction torque opposing the motion (enters the link equation with + sign)."""
        tau = self._viscous * dq
        if self._coulomb is not None:
            s = np.tanh(dq / self.smoothing_velocity)
            tau = tau + np.where(s > 0.0, *self._coulomb) * s
        return tau

    def derivative(self, dq: np.ndarray) -> np.ndarray:
        """Diagonal of d(friction)/d(q') (used by observers that linearize)."""
        d = self._viscous * np.ones_like(dq)
        if self._coulomb is not None:
            eps = self.smoothing_velocity
            s = np.tanh(dq / eps)
            d = d + np.where(s > 0.0, *self._coulomb) * (1.0 - s**2) / eps
        return d

    def plus(self, other: LinkFriction | None) -> LinkFriction:
        """The sum of two frictions (this one's smoothing velocity)."""
        if other is None:
            return self

        def _add(a: tuple[float, ...] | None, b: tuple[float, ...] | None) -> Any:
            if a is None and b is None:
                return None
            return tuple(
                (
                    np.zeros(len(self.viscous))
                    + (0.0 if a is None else np.asarray(a))
                    + (0.0 if b is None else np.asarray(b))
                ).tolist()
            )

        return LinkFriction(
            viscous=_add(self.viscous, other.viscous),
            coulomb_pos=_add(self.coulomb_pos, other.coulomb_pos),
            coulomb_neg=_add(self.negative_coulomb(), other.negative_coulomb()),
            smoothing_velocity=self.smoothing_velocity,
        )

    def negative_coulomb(self) -> tuple[float, ...] | None:
        """The Coulomb level for q' < 0 (`coulomb_neg`, or `coulomb_pos` when not given)."""
        return self.coulomb_neg if self.coulomb_neg is not None else self.coulomb_pos

    def scaled(self, factor: float) -> LinkFriction:
        def _scale(values: tuple[float, ...] | None) -> tuple[float, ...] | None:
            return None if values is None else tuple(factor * v for v in values)

        return LinkFriction(
            viscous=_scale(self.viscous),  # type: ignore[arg-type]
            coulomb_pos=_scale(self.coulomb_pos),
            coulomb_neg=_scale(self.coulomb_neg),
            smoothing_velocity=self.smoothing_velocity,
        )


def substeps(control_dt: float, physics_dt: float, where: str = "", tolerance: float = 1e-6) -> int:
    """Physics steps per control period; ``ValueError`` (after ``where``) unless
    ``control_dt`` is an integer multiple (within ``tolerance``) of ``physics_dt``."""
    ratio = control_dt / physics_dt
    if abs(ratio - round(ratio)) > tolerance or round(ratio) < 1:
        raise ValueError(
            f"{where}control_dt ({control_dt}) must be an integer multiple of physics_dt "
            f"({physics_dt})"
        )
    return round(ratio)


def joint_kind(elastic: bool) -> str:
    """``"elastic"`` for elastic joints, ``"rigid"`` otherwise."""
    return "elastic" if elastic else "rigid"


def check_applies(kind: str, name: str, applies_to: frozenset[str], model) -> None:
    """Refuse an observer/controller built for elastic arms on a rigid robot and vice versa."""
    arm = model.spec.kind
    if arm not in applies_to:
        raise ValueError(
            f"{kind} {name!r} applies to {sorted(applies_to)} arms, "
            f"not to the {arm} robot {model.spec.name!r}"
        )


@dataclass(frozen=True)
class RobotSpec:
    """Everything needed to simulate and model one arm.

    Attributes:
        name: short identifier.
        urdf: path of the URDF file (links, inertias, kinematics).
        joint_names: the N actuated joints, in state order.
        elastic: elastic joints (model (1)/(2)) or rigid joints.
        stiffness, motor_inertia, damping: diagonal K, B, D of eq. (1) (elastic only).
        coupling: constant motor/link inertia block S of eq. (2), or None for model (1).
        torque_limit: symmetric motor torque limit (N m), per joint.
        friction: link-side friction model d(q, q') or None.
        accelerometers: default accelerometer mounts.
        workspace_low, workspace_high: box of link configurations used by the tasks
            to sample reachable start/goal configurations (rad).
        max_move: largest per-joint displacement of one sampled motion (rad).
        encoder_resolution, encoder_noise_std: default position sensor quantum and
            Gaussian noise (rad): motor encoders on elastic arms, link encoders on rigid ones.
        camera: (target, distance, yaw, pitch) of the default render camera.
        physics_dt: default physics step (s); control_dt: default control period (s).
        gravity: world gravity vector (m/s^2).
        source: where the numbers come from (shown on the environment pages).
    """

    name: str
    urdf: str
    joint_names: tuple[str, ...]
    elastic: bool
    torque_limit: tuple[float, ...]
    workspace_low: tuple[float, ...]
    workspace_high: tuple[float, ...]
    stiffness: tuple[float, ...] | None = None
    motor_inertia: tuple[float, ...] | None = None
    damping: tuple[float, ...] | None = None
    coupling: tuple[tuple[float, ...], ...] | None = None
    friction: LinkFriction | None = None
    accelerometers: tuple[AccelerometerMount, ...] = ()
    max_move: float = 0.8
    encoder_resolution: float = 2.0 * np.pi / 2**20
    encoder_noise_std: float = 0.0
    camera: tuple[tuple[float, float, float], float, float, float] = (
        (0.0, 0.0, 0.0),
        2.0,
        0.0,
        -10.0,
    )
    physics_dt: float = 5e-4
    control_dt: float = 1e-3
    gravity: tuple[float, float, float] = (0.0, 0.0, -9.81)
    source: str = ""
    extra: dict = field(default_factory=dict)

    @property
    def n_joints(self) -> int:
        return len(self.joint_names)

    @property
    def kind(self) -> str:
        """``"elastic"`` or ``"rigid"``: the joint kind, as observers and controllers name
        the arms they apply to (``applies_to``)."""
        return joint_kind(self.elastic)

    def __post_init__(self) -> None:
        n = self.n_joints
        vectors: dict[str, tuple[tuple[float, ...] | None, bool]] = {  # (value, positive)
            "torque_limit": (self.torque_limit, False),
            "workspace_low": (self.workspace_low, False),
            "workspace_high": (self.workspace_high, False),
        }
        if self.elastic:
            vectors.update(
                stiffness=(self.stiffness, True),
                motor_inertia=(self.motor_inertia, True),
                damping=(self.damping, False),
            )
        for key, (value, positive) in vectors.items():
            if value is None or len(value) != n or (positive and min(value) <= 0):
                raise ValueError(
                    f"RobotSpec {self.name!r}: {key} must have {n} entries"
                    f"{', each > 0' if positive else ''}, got {value!r}"
                )
        if self.coupling is not None:
            S = np.asarray(self.coupling, dtype=float)
            if S.shape != (n, n) or np.any(np.tril(S) != 0.0):
                raise ValueError(
                    f"RobotSpec {self.name!r}: coupling S must be strictly upper triangular {n}x{n}"
                )
        substeps(self.control_dt, self.physics_dt, f"RobotSpec {self.name!r}: ", 1e-9)
