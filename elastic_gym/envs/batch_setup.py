"""A batch's configuration resolved for its robot: what needs the robot to be checked.

[`EnvConfig`][elastic_gym.envs.config.EnvConfig] validates what needs no robot; here the
rest is resolved before any PyBullet client exists: the physics step and control period,
the torque limits, each arm's settings (`per_arm` merged in), `randomize` ranges and plant
model, and the stability of every plant a range can reach under PyBullet's integrator
(physics_dt * omega_max <= `STABILITY_LIMIT` for the stiffest joint mode of semi-implicit
Euler; the RK4 controls its own step).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from elastic_gym.envs.arm_config import ArmResolver, ArmSettings, arm_kwargs
from elastic_gym.envs.config import PER_ARM_KEYS, EnvConfig, PlantRange
from elastic_gym.envs.randomization import check_ranges, with_values
from elastic_gym.model import RobotModel
from elastic_gym.robots.spec import RobotSpec, substeps
from elastic_gym.validation import errors_at, per_joint_values, validated

STABILITY_LIMIT = 0.2  # largest admissible physics_dt * omega_max


def timing(robot: RobotSpec, config: EnvConfig) -> tuple[float, float, int]:
    """(physics step, control period, physics steps per control period): the config's or
    the robot's defaults (the RK4's physics step: the control period)."""
    control = robot.control_dt if config.control_dt is None else config.control_dt
    default = control if config.integrator == "rk4" else robot.physics_dt
    physics = default if config.physics_dt is None else config.physics_dt
    return float(physics), float(control), substeps(control, physics)


def torque_limits(robot: RobotSpec, torque_limit: float | tuple[float, ...] | None) -> np.ndarray:
    """The motor torque limits (n,): the robot's, or the config's (one or n numbers > 0)."""
    if torque_limit is None:
        return np.asarray(robot.torque_limit, dtype=float)
    given = list(torque_limit) if isinstance(torque_limit, tuple) else torque_limit
    return per_joint_values(given, robot.n_joints, "torque_limit", 0.0, strict=True)


def check_within_limits(
    name: str, points: np.ndarray, lower: np.ndarray, upper: np.ndarray
) -> None:
    """Refuse configurations ``points`` (the option ``name``) outside the joint limits."""
    if np.any(points < lower) or np.any(points > upper):
        raise ValueError(
            f"{name}: {points.tolist()} is outside the joint limits [{lower}, {upper}]"
        )


def check_stability(robot: RobotSpec, physics_dt: float, plant: RobotModel) -> None:
    """Refuse a physics step too coarse for the stiffest joint mode of an elastic
    ``plant`` (its natural frequencies at the middle of the workspace)."""
    if not robot.elastic:
        return
    q = 0.5 * (np.asarray(robot.workspace_low) + np.asarray(robot.workspace_high))
    omega = plant.natural_frequencies(q)[0].max()
    if physics_dt * omega > STABILITY_LIMIT:
        raise ValueError(
            f"physics_dt={physics_dt} too coarse for the stiffest joint mode "
            f"({omega:.0f} rad/s): need physics_dt * omega <= {STABILITY_LIMIT}"
        )


@dataclass(frozen=True)
class ArmPlans:
    """Each arm's settings, `randomize` ranges, per-arm kwargs and plant model."""

    settings: list[ArmSettings]
    ranges: list[dict[str, PlantRange]]
    arm_kwargs: list[dict]
    models: list[RobotModel]


def shared_arm_options(config: EnvConfig) -> dict:
    """The per-arm kwargs every arm shares (`PER_ARM_KEYS` of the config)."""
    return {key: getattr(config, key) for key in PER_ARM_KEYS}


def per_arm_options(config: EnvConfig) -> list[dict] | None:
    """Each arm's own per-arm kwargs as given (None: no `per_arm`), to be deep-merged into
    the shared ones."""
    if config.per_arm is None:
        return None
    return [options.model_dump(exclude_unset=True) for options in config.per_arm]


def plan_arms(resolver: ArmResolver, config: EnvConfig, n_arms: int, physics_dt: float) -> ArmPlans:
    """Each arm's settings (`per_arm` merged in), randomization ranges and plant model;
    every plant a range can reach is checked for stability."""
    robot = resolver.spec
    shared = shared_arm_options(config)
    shared_settings = resolver.settings(shared)
    merged = arm_kwargs(shared, per_arm_options(config), n_arms)
    kwargs = [shared] * n_arms if merged is None else merged
    settings, ranges, models = [], [], []
    checked: set[tuple] = set()  # plants whose stability is checked
    for i, arm in enumerate(kwargs):
        where = "" if merged is None else f"per_arm[{i}]."
        with errors_at(f"per_arm[{i}]"):
            arm_settings = shared_settings if merged is None else resolver.settings(arm)
        arm_ranges = {
            path: validated(PlantRange, spec, f"{where}randomize[{path!r}]")
            for path, spec in (arm.get("randomize") or {}).items()
        }
        corners = check_ranges(arm_ranges, arm, resolver, where)
        if "payload.mass" in arm_ranges and arm_settings.payload is None:  # a payload link
            low = {"payload.mass": arm_ranges["payload.mass"].low}  # is needed
            arm_settings = resolver.settings(with_values(arm, low))
        settings.append(arm_settings)
        ranges.append(arm_ranges)
        models.append(resolver.plant_model(arm_settings))
        for option in (arm_settings, *corners):
            masses = [None] if option.payload is None else [None, *_later_masses(option)]
            for mass in masses:
                key = (option.scaling, repr(option.payload), mass)
                if key not in checked:
                    checked.add(key)
                    if config.integrator == "pybullet":  # the RK4 controls its own step
                        check_stability(robot, physics_dt, resolver.plant_model(option, mass))
    return ArmPlans(settings, ranges, kwargs, models)


def _later_masses(settings: ArmSettings) -> list[float]:
    change = None if settings.payload is None else settings.payload.change
    return [] if change is None else [change.mass]


def observation_shapes(spaces: Mapping) -> dict[str, tuple[int, ...]]:
    """The shape of each entry of an observation space (a `spaces.Dict`)."""
    return {key: space.shape or () for key, space in spaces.items()}
