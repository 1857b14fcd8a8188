"""One arm's plant and sensors from its kwargs: what needs the robot to be validated.

`arm_kwargs` deep-merges the shared per-arm kwargs with each arm's ``per_arm``
mapping; `ArmResolver` turns one arm's kwargs into `ArmSettings` (refusing
what this robot cannot have) and builds the arm's exact plant model.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel

from elastic_gym.envs.config import (
    PER_ARM_KEYS,
    ArmOptions,
    PayloadConfig,
    TorquePulsesConfig,
    UnmodelledFriction,
)
from elastic_gym.envs.plant import default_payload_position, with_payload
from elastic_gym.envs.sensors import AccelerometerConfig, EncoderConfig
from elastic_gym.model import ParameterScaling, RobotModel
from elastic_gym.robots.spec import AccelerometerMount, LinkFriction, RobotSpec
from elastic_gym.validation import per_joint_values, validated

MAX_SENSOR_DELAY = 1.0  # s
MAX_ACTUATOR_DELAY = 1.0  # s


def as_mapping(value):
    """A dataclass or pydantic config as a plain dict (to be merged), ``"ideal"`` as the
    ideal accelerometer's fields; others unchanged."""
    if isinstance(value, str) and value == "ideal":
        value = AccelerometerConfig.ideal()
    if isinstance(value, BaseModel):
        return value.model_dump(exclude_none=True)
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return dataclasses.asdict(value)
    return value


def deep_merge(base, override):
    """``override`` merged into ``base``: mappings key by key (recursively), anything else
    replaced."""
    if not isinstance(override, Mapping):
        return override
    base, override = as_mapping(base), as_mapping(override)
    if isinstance(base, Mapping):
        merged = dict(base)
        for key, value in override.items():
            merged[key] = deep_merge(base[key], value) if key in base else value
        return merged
    return override


def arm_kwargs(shared: dict, per_arm, n_arms: int) -> list[dict] | None:
    """Each arm's per-arm kwargs: ``shared`` deep-merged with ``per_arm[i]`` (None: no
    per-arm mappings). ``per_arm``: exactly ``n_arms`` mappings of
    `PER_ARM_KEYS` (each validated by
    [`ArmOptions`][elastic_gym.envs.config.ArmOptions] with the env's kwargs)."""
    if per_arm is None:
        return None
    if len(per_arm) != n_arms:
        raise ValueError(
            f"per_arm must hold exactly {n_arms} mappings (one per arm), got {len(per_arm)}"
        )
    return [
        {
            key: deep_merge(shared[key], options[key]) if key in options else shared[key]
            for key in PER_ARM_KEYS
        }
        for options in per_arm
    ]


@dataclass(frozen=True)
class ArmSettings:
    """One arm's validated plant and sensor options."""

    scaling: ParameterScaling
    friction: LinkFriction | None
    encoder: tuple[float, float]  # resolution, noise_std (rad)
    accelerometer: AccelerometerConfig
    sensor_delay: int
    actuator_delay: int
    payload: PayloadConfig | None
    pulses: TorquePulsesConfig | None


class ArmResolver:
    """Validates one arm's per-arm kwargs against a robot and builds its plant model."""

    def __init__(
        self,
        spec: RobotSpec,
        mounts: tuple[AccelerometerMount, ...],
        torque_limit: np.ndarray,
        control_dt: float,
    ) -> None:
        self.spec, self.mounts = spec, mounts
        self.n = spec.n_joints
        self.torque_limit, self.control_dt = torque_limit, control_dt
        self._nominal_plant = RobotModel(spec, accelerometers=mounts)

    def settings(self, kwargs: Mapping) -> ArmSettings:
        """One arm's settings from its per-arm kwargs
        ([`ArmOptions`][elastic_gym.envs.config.ArmOptions] and the robot's
        limits)."""
        spec, options = self.spec, validated(ArmOptions, kwargs)
        encoder = options.encoder or EncoderConfig()
        return ArmSettings(
            scaling=self._scaling(options.plant_scaling),
            friction=self._unmodelled_friction(options.unmodelled_friction),
            encoder=(
                spec.encoder_resolution if encoder.resolution is None else encoder.resolution,
                spec.encoder_noise_std if encoder.noise_std is None else encoder.noise_std,
            ),
            accelerometer=options.accelerometer or AccelerometerConfig(),
            sensor_delay=self._delay(options.sensor_delay, "sensor_delay", MAX_SENSOR_DELAY),
            actuator_delay=self._delay(
                options.actuator_delay, "actuator_delay", MAX_ACTUATOR_DELAY
            ),
            payload=options.payload,
            pulses=self._pulses(options.torque_pulses),
        )

    def plant_model(self, settings: ArmSettings, payload_mass: float | None = None) -> RobotModel:
        """The exact model of the arm's plant (payload of ``payload_mass``, default the
        configured initial mass)."""
        model = RobotModel(self.spec, settings.scaling, self.mounts, settings.friction)
        position = self.payload_position(settings)
        if settings.payload is None or position is None:
            return model
        mass = settings.payload.mass if payload_mass is None else payload_mass
        return with_payload(model, mass, position)

    def payload_position(self, settings: ArmSettings) -> tuple[float, ...] | None:
        """Where the arm's payload sits in the last link's frame (None: no payload)."""
        payload = settings.payload
        if payload is None:
            return None
        if payload.position is not None:
            return tuple(payload.position)
        return tuple(default_payload_position(self._nominal_plant).tolist())

    # ------------------------------------------------------------------ checks
    def _scaling(self, scaling: ParameterScaling | None) -> ParameterScaling:
        """Refuse scaling a part the robot does not have (it would silently do nothing)."""
        scaling = scaling or ParameterScaling()
        spec = self.spec
        absent = {
            "stiffness": not spec.elastic,
            "motor_inertia": not spec.elastic,
            "damping": not spec.elastic,
            "friction": spec.friction is None,
        }
        for key, missing in absent.items():
            if missing and np.any(np.asarray(getattr(scaling, key)) != 1.0):
                raise ValueError(
                    f"plant_scaling {key!r}: robot {spec.name!r} has no "
                    f"{'elastic joints' if key != 'friction' else 'link friction'} to scale"
                )
        for key in ("link_mass", "link_inertia", "stiffness", "motor_inertia", "damping"):
            scaling.per_joint(key, self.n)  # one or n values
        return scaling

    def _unmodelled_friction(self, config: UnmodelledFriction | None) -> LinkFriction | None:
        """The ``unmodelled_friction`` kwarg as a `LinkFriction` in N m."""
        if config is None:
            return None
        n, limit = self.n, self.torque_limit
        coulomb = per_joint_values(config.coulomb, n, "unmodelled_friction.coulomb")
        viscous = per_joint_values(config.viscous, n, "unmodelled_friction.viscous")
        return LinkFriction(
            viscous=tuple((limit * viscous).tolist()), coulomb_pos=tuple((limit * coulomb).tolist())
        )

    def _delay(self, delay: int | None, name: str, limit: float) -> int:
        delay = delay or 0
        if delay * self.control_dt > limit:
            raise ValueError(f"{name} of {delay} control periods is more than {limit} s")
        return delay

    def _pulses(self, pulses: TorquePulsesConfig | None) -> TorquePulsesConfig | None:
        if pulses is None:
            return None
        for k, amplitude in enumerate(pulses.amplitudes or ()):
            per_joint_values(amplitude, self.n, f"torque_pulses.amplitudes[{k}]")
        return pulses
