"""The sidecar `<log>.yaml`: which robot a log belongs to, and what its columns hold.

```yaml
robot: TwoLinkElastic-v0        # an env id, or a robot description file (my_arm.yaml)
sample_time: 0.001              # s (default: the time column's mean step)
accelerometers:                 # optional: mounts replacing the robot's (names = columns)
  - {link: link1, position: [0.35, 0.0, 0.03], name: acc_link1}
```

The sidecar of `run.csv` is `run.yaml` beside it (a bag folder `rec/`: `rec.yaml`). It
holds what rebuilds the nominal [`RobotModel`][elastic_gym.model.RobotModel] of the log
([`nominal_model`][elastic_gym.logs.sidecar.nominal_model]); a simulated log records its
plant (`plant_scaling`, sensor options, seed) under `provenance` for studies to compare
with, and nothing reads `provenance` to process the log.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import Field, StrictInt, StrictStr

from elastic_gym.model import RobotModel
from elastic_gym.robots.spec import AccelerometerMount, RobotSpec
from elastic_gym.validation import (
    NonNegativeFinite,
    PositiveFinite,
    PositiveNumbers,
    StrictModel,
    errors_at,
    per_joint_values,
    validated,
)

FORMAT = 1
ROBOT_FILE_SUFFIXES = (".yaml", ".yml")
Name = Annotated[StrictStr, Field(min_length=1)]


class Provenance(StrictModel):
    """What wrote the log, for the record: read by studies, never by `identify` or
    `observe`."""

    writer: StrictStr = ""
    version: StrictStr = ""
    created: StrictStr = ""
    env_id: StrictStr | None = None
    env_kwargs: dict[str, Any] | None = None
    seed: StrictInt | None = None
    excitation: dict[str, Any] | None = None
    controller: dict[str, Any] | None = None
    observer: dict[str, Any] | None = None
    source_log: StrictStr | None = None
    notes: StrictStr = ""


class TopicMap(StrictModel):
    """Where a ROS 2 bag or MCAP file holds the log's columns.

    `joint_states`: a `sensor_msgs/msg/JointState` topic (`position` → motor positions,
    `effort` → torques; its stamps are the log's time); `joint_names`: the message's
    joint names in the robot's joint order (default: the robot's joint names);
    `accelerometers`: mount name → a `sensor_msgs/msg/Imu` topic (`linear_acceleration`)
    or a `geometry_msgs/msg/Vector3Stamped` / `AccelStamped` topic. Each joint-state
    sample takes every sensor's latest message stamped at or before it (what a
    controller reading the topics would have had); samples before every topic has
    spoken are dropped. `stamp`: the header stamp (`header`) or the time the bag
    recorded the message (`log`).
    """

    joint_states: Name = "/joint_states"
    joint_names: list[Name] | None = None
    accelerometers: dict[str, Name] = Field(default_factory=dict)
    stamp: Literal["header", "log"] = "header"


class LogSidecar(StrictModel):
    """The sidecar of a sensor log (module docstring).

    Fields: `format` (1); `robot` (an env id such as `TwoLinkElastic-v0`, or a robot
    description file relative to the sidecar); `state` (what the state columns hold:
    `truth` of a simulation, or an observer's `estimate`); `sample_time` (s; default the
    time column's mean step); `time_tolerance` (s; the largest deviation of a time step
    from the sample time, default 0.1 % of it); `accelerometers` (mounts replacing the
    robot's); `encoder_resolution` (rad); `torque_limit` (N m, replacing the robot's: a
    torque beyond it is refused); `position_limit` (rad: |motor position| beyond it is
    refused, default the URDF's joint limits or 2π); `accelerometer_cutoff_hz` (the
    accelerometers' first-order low-pass, if they filter); `sensor_delay` (s, how late the
    readings are); `topics` (ROS 2 bags and MCAP files); `provenance`.
    """

    format: Literal[1] = 1
    robot: Name
    state: Literal["truth", "estimate"] = "truth"
    sample_time: PositiveFinite | None = None
    time_tolerance: PositiveFinite | None = None
    accelerometers: list[AccelerometerMount] | None = None
    encoder_resolution: NonNegativeFinite | None = None
    torque_limit: PositiveNumbers | None = None
    position_limit: PositiveNumbers | None = None
    accelerometer_cutoff_hz: PositiveFinite | None = None
    sensor_delay: NonNegativeFinite | None = None
    topics: TopicMap | None = None
    provenance: Provenance = Field(default_factory=Provenance)


def sidecar_path(log_path: str | Path) -> Path:
    """`run.csv` → `run.yaml` (a bag folder `rec/` → `rec.yaml`)."""
    path = Path(log_path)
    return path.with_name(path.name.rstrip("/")).with_suffix(".yaml")


def load_sidecar(path: str | Path) -> LogSidecar:
    """The sidecar at `path`; `ValueError` naming the file (and field) otherwise."""
    from elastic_gym.yaml_io import load_yaml

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(
            f"{path}: no sidecar (a log needs <log>.yaml naming its robot, e.g. 'robot: "
            "TwoLinkElastic-v0')"
        )
    data = load_yaml(path)
    with errors_at(str(path)):
        return validated(LogSidecar, data)


def robot_of(sidecar: LogSidecar, where: str, base: Path | None = None) -> RobotSpec:
    """The robot the sidecar names: an env id of the package (bare or with its
    `elastic_gym/` namespace) or a robot description file (relative to `base`, the
    sidecar's folder). `ValueError` naming `where` and the valid ids otherwise."""
    import gymnasium as gym

    import elastic_gym
    from elastic_gym.envs.ids import ENV_NAMESPACE
    from elastic_gym.robots.catalog import get_robot
    from elastic_gym.robots.description import robot_from_description

    name = sidecar.robot
    if name.endswith(ROBOT_FILE_SUFFIXES):
        file = Path(name) if base is None else base / name
        if not file.is_file():
            raise ValueError(f"{where}: robot: no robot description file {str(file)!r}")
        return robot_from_description(file)
    env_id = name if "/" in name else ENV_NAMESPACE + name
    if not env_id.startswith(ENV_NAMESPACE) or env_id not in gym.registry:
        raise ValueError(
            f"{where}: robot: unknown robot {name!r}: neither an env id of elastic_gym "
            f"({', '.join(elastic_gym.ENVIRONMENTS)}) nor a robot description file "
            f"({' or '.join(ROBOT_FILE_SUFFIXES)})"
        )
    return get_robot(gym.registry[env_id].kwargs["robot"])


def mounts_of(sidecar: LogSidecar, spec: RobotSpec) -> tuple[AccelerometerMount, ...]:
    """The accelerometer mounts of the log: the sidecar's, or the robot's."""
    return spec.accelerometers if sidecar.accelerometers is None else tuple(sidecar.accelerometers)


def nominal_model(sidecar: LogSidecar, spec: RobotSpec, where: str) -> RobotModel:
    """The nominal model of the log's robot with the log's accelerometer mounts (a mount
    on a link the URDF lacks: `ValueError` naming `where`)."""
    try:
        return RobotModel(spec, accelerometers=mounts_of(sidecar, spec))
    except ValueError as exc:
        raise ValueError(f"{where}: accelerometers: {exc}") from None


def torque_limit_of(sidecar: LogSidecar, spec: RobotSpec, where: str):
    """The motor torque limits (N m) a log's torques must respect."""
    value = spec.torque_limit if sidecar.torque_limit is None else sidecar.torque_limit
    return per_joint_values(value, spec.n_joints, f"{where}: torque_limit")


def position_limit_of(sidecar: LogSidecar, spec: RobotSpec, where: str):
    """The largest |motor position| (rad) per joint a log may hold (module docstring of
    `elastic_gym.logs.checks`)."""
    import numpy as np

    from elastic_gym.robots.urdf_tools import joint_limits

    if sidecar.position_limit is not None:
        return per_joint_values(sidecar.position_limit, spec.n_joints, f"{where}: position_limit")
    lower, upper = joint_limits(spec.urdf, spec.joint_names)
    bound = np.maximum(np.abs(lower), np.abs(upper))
    return np.where(np.isfinite(bound), bound + 0.1, 2.0 * np.pi)
