"""`LogRecorder`: a wrapper that keeps what an env's sensors gave, as a log.

Put it directly on an env of the package (below an observer wrapper, which replaces the
sensor observation): each `reset` starts a log, each `step` completes the row of the
previous observation with the torque the env applied in that step (`info["torque"]`,
clipped, with the task's open-loop torque) and the truth of that row. Row k is thus the
sensors at `time[k]` and the torque held from `time[k]` to `time[k + 1]`, the log
format's timing; the last observation, whose torque is not known yet, is not a row.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import gymnasium as gym
import numpy as np
from pydantic import BaseModel

import elastic_gym
from elastic_gym.arms import elastic_base
from elastic_gym.envs.config import EnvConfig
from elastic_gym.envs.sensors import AccelerometerConfig
from elastic_gym.logs.sensor_log import SensorLog
from elastic_gym.robots.spec import RobotSpec


class LogRecorder(gym.Wrapper):
    """Record an env's sensor log (module docstring).

    Args:
        env: an env of the package (sensor observation intact).
        sidecar: sidecar fields besides `robot`, `sample_time` and `accelerometers`
            (which the env gives), e.g. `provenance`.
        robot: the sidecar's `robot` (default: the env's id).
        state: record the truth in the state columns.
    """

    def __init__(
        self,
        env: gym.Env,
        sidecar: Mapping[str, Any] | None = None,
        robot: str | None = None,
        state: bool = True,
    ) -> None:
        super().__init__(env)
        base = elastic_base(env, "LogRecorder", vector=False)
        spec = env.spec
        if robot is None:
            registered = None if spec is None else gym.registry[spec.id].kwargs.get("robot")
            if registered != base.robot.name:
                raise ValueError(
                    f"LogRecorder: the env simulates robot {base.robot.name!r}, which its id "
                    f"{None if spec is None else spec.id!r} does not name: give robot= (an "
                    "env id or a robot description file)"
                )
        mounts = [m.to_dict() for m in base.model.accelerometers]
        kwargs = env_kwargs(env)
        self.sidecar = {
            "robot": robot or (spec.id if spec is not None else ""),
            "sample_time": base.control_dt,
            **({"accelerometers": mounts} if mounts != _default_mounts(base) else {}),
            **sensor_fields(kwargs, base.control_dt),
            "provenance": {
                "writer": "elastic_gym.logs.LogRecorder",
                "version": elastic_gym.__version__,
                "env_id": None if spec is None else spec.id,
                "env_kwargs": kwargs,
            },
        }
        for key, value in dict(sidecar or {}).items():
            if key == "provenance":
                self.sidecar["provenance"].update(value)
            else:
                self.sidecar[key] = value
        if state:
            self.sidecar["state"] = "truth"
        self.record_state = state
        self.elastic = base.robot.elastic
        self._rows: list[tuple] = []
        self._pending: tuple | None = None

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        self._rows = []
        self._pending = self._observed(obs, info)
        return obs, info

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        if self._pending is None:
            raise RuntimeError("LogRecorder: call reset() before step()")
        time, position, acceleration, truth = self._pending
        torque = np.array(info["torque"], dtype=float)
        self._rows.append((time, position, torque, acceleration, truth))
        self._pending = self._observed(obs, info)
        return obs, reward, terminated, truncated, info

    def _observed(self, obs: Mapping, info: Mapping) -> tuple:
        key = "motor_position" if self.elastic else "link_position"
        position = np.array(obs[key], dtype=float)
        acceleration = np.array(obs.get("acceleration", np.zeros(0)), dtype=float)
        truth = None
        if self.record_state:
            names = ("q", "dq", "theta", "dtheta") if self.elastic else ("q", "dq")
            truth = {name: np.array(info["true_state"][name], dtype=float) for name in names}
        return float(info["time"]), position, acceleration, truth

    def __len__(self) -> int:
        return len(self._rows)

    def log(self, provenance: Mapping | None = None) -> SensorLog:
        """The rows recorded since the last reset as a checked log."""
        if len(self._rows) < 2:
            raise ValueError(f"LogRecorder: {len(self._rows)} rows recorded, a log needs two")
        time, position, torque, acceleration, truth = zip(*self._rows, strict=True)
        sidecar = dict(self.sidecar)
        if provenance is not None:
            sidecar["provenance"] = {**dict(sidecar.get("provenance", {})), **provenance}
        state = None
        if self.record_state:
            state = {name: np.array([row[name] for row in truth]) for name in truth[0]}
        return SensorLog.create(
            sidecar,
            np.array(time),
            np.array(position),
            np.array(torque),
            np.array(acceleration) if self.elastic else None,
            state,
            source="<recorded>",
        )


def _default_mounts(base) -> list[dict]:
    return [m.to_dict() for m in base.robot.accelerometers]


def plain_data(value: Any) -> Any:
    """`value` as YAML-safe plain data (mappings, lists, numbers, strings; configs by
    their fields, a robot spec by its name)."""
    if isinstance(value, BaseModel):
        return value.model_dump(mode="json", exclude_none=True)
    if isinstance(value, RobotSpec):
        return value.name
    if isinstance(value, Mapping):
        return {str(key): plain_data(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain_data(item) for item in value]
    if isinstance(value, (np.ndarray, np.generic)):
        return value.tolist()
    return value


def env_kwargs(env: gym.Env) -> dict[str, Any]:
    """The kwargs the env was made with (its plant, sensors and task), as plain data."""
    spec = env.spec
    kwargs = {} if spec is None else dict(spec.kwargs)
    kwargs.pop("robot", None)
    kwargs.pop("render_mode", None)
    return plain_data(kwargs)


def sensor_fields(kwargs: Mapping[str, Any], control_dt: float) -> dict[str, float]:
    """The sidecar's `accelerometer_cutoff_hz` and `sensor_delay` (s) of env kwargs."""
    config = EnvConfig.model_validate(
        {key: kwargs[key] for key in ("accelerometer", "sensor_delay") if key in kwargs}
    )
    fields: dict[str, float] = {}
    accelerometer = config.accelerometer or AccelerometerConfig()
    if accelerometer.cutoff_hz is not None:
        fields["accelerometer_cutoff_hz"] = accelerometer.cutoff_hz
    if config.sensor_delay:
        fields["sensor_delay"] = config.sensor_delay * control_dt
    return fields
