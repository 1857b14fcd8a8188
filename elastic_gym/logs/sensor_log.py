"""`SensorLog`: a log in memory, checked, with the robot it belongs to.

Arrays (float64, read-only): `time` (T,), `motor_position` (T, n), `torque` (T, n),
`acceleration` (T, 3 s) with `sensor_names` (s mounts; columns `<name>_x/_y/_z`) and,
where the log has state columns, `state` (`q`, `dq`, `theta`, `dtheta`, each (T, n); rigid
arms `q`, `dq`), exposed as `truth` or `estimate` as the sidecar says. Row k holds the
sensors read at `time[k]` and the torque applied from `time[k]` until `time[k + 1]`: an
observer's update to row k + 1 takes the measurements of row k + 1 and the torque of row
k, as in the envs, where `step(action)` applies the action for one control period and then
returns the measurements.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from elastic_gym.logs import checks
from elastic_gym.logs.checks import Source
from elastic_gym.logs.columns import (
    ELASTIC_STATE,
    TIME,
    LogError,
    LogLayout,
    joint_columns,
    sensor_columns,
)
from elastic_gym.logs.sidecar import (
    LogSidecar,
    mounts_of,
    nominal_model,
    position_limit_of,
    robot_of,
    torque_limit_of,
)
from elastic_gym.model import RobotModel
from elastic_gym.robots.spec import RobotSpec


def _frozen(values: np.ndarray) -> np.ndarray:
    out = np.array(values, dtype=np.float64)  # a copy: the log owns its arrays
    out.flags.writeable = False
    return out


@dataclass(frozen=True, eq=False)
class SensorLog:
    """A checked sensor log (module docstring). Build one with
    [`read_log`][elastic_gym.logs.read_log], [`SensorLog.from_table`] or
    [`SensorLog.create`]; each checks every value (`LogError` naming row and column)."""

    time: np.ndarray
    motor_position: np.ndarray
    torque: np.ndarray
    acceleration: np.ndarray
    sensor_names: tuple[str, ...]
    sidecar: LogSidecar
    state: Mapping[str, np.ndarray] | None = None
    source: str = "<log>"
    base: Path | None = field(default=None, repr=False)  # folder of the sidecar

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_table(
        cls,
        header: Sequence[str],
        values: np.ndarray,
        sidecar: LogSidecar,
        source: Source,
        sidecar_name: str = "sidecar",
        base: Path | None = None,
    ) -> SensorLog:
        """A log from a table (`values` (T, columns) in `header`'s order), checked: the
        columns against the robot of the sidecar, then every value (module
        `elastic_gym.logs.checks`)."""
        spec = robot_of(sidecar, sidecar_name, base)
        model = nominal_model(sidecar, spec, sidecar_name)
        sensors = tuple(m.name for m in mounts_of(sidecar, spec))
        layout = LogLayout(spec.n_joints, sensors, spec.elastic)
        has_state = layout.match(list(header), source.name)
        if values.ndim != 2 or values.shape[1] != len(header):
            raise source.error(f"a table of {len(header)} columns expected, got {values.shape}")
        if not len(values):
            raise source.error("no data rows (an empty log)")
        index = {name: k for k, name in enumerate(header)}
        checks.check_finite(values, header, source)

        def block(names: list[str]) -> np.ndarray:
            return values[:, [index[name] for name in names]]

        n = spec.n_joints
        time = values[:, index[TIME]]
        dt = checks.sample_time(time, sidecar.sample_time) if len(time) > 1 else 0.0
        checks.check_time(time, dt, sidecar.time_tolerance, source)
        state = None
        if has_state:
            state = {name: block(joint_columns(name, n)) for name in layout.state_names}
        log = cls(
            time=_frozen(time),
            motor_position=_frozen(block(joint_columns("motor_position", n))),
            torque=_frozen(block(joint_columns("torque", n))),
            acceleration=_frozen(block(sensor_columns(sensors))),
            sensor_names=sensors,
            sidecar=sidecar,
            state=None if state is None else {k: _frozen(v) for k, v in state.items()},
            source=source.name,
            base=base,
        )
        log._check_ranges(spec, sidecar_name, source)
        vars(log)["_model"] = model  # built once above (it checked the mounts)
        vars(log)["robot"] = spec
        return log

    @classmethod
    def create(
        cls,
        sidecar: LogSidecar | Mapping,
        time: np.ndarray,
        motor_position: np.ndarray,
        torque: np.ndarray,
        acceleration: np.ndarray | None = None,
        state: Mapping[str, np.ndarray] | None = None,
        source: str = "<log>",
        base: Path | None = None,
    ) -> SensorLog:
        """A log from arrays (shapes of the module docstring; `acceleration` None: a
        robot without accelerometers), checked like a file."""
        from elastic_gym.validation import validated

        sidecar = validated(LogSidecar, sidecar, prefix="sidecar")
        spec = robot_of(sidecar, "sidecar", base)
        sensors = tuple(m.name for m in mounts_of(sidecar, spec))
        layout = LogLayout(spec.n_joints, sensors, spec.elastic)
        T = len(np.atleast_1d(time))
        arrays = {
            "time": np.reshape(np.asarray(time, dtype=float), (T, 1)),
            "motor_position": motor_position,
            "torque": torque,
            "acceleration": np.zeros((T, 0)) if acceleration is None else acceleration,
        }
        widths = {"time": 1, "motor_position": spec.n_joints, "torque": spec.n_joints}
        widths["acceleration"] = 3 * len(sensors)
        if state is not None:
            missing = sorted(set(layout.state_names) - set(state))
            unknown = sorted(set(state) - set(layout.state_names))
            if missing or unknown:
                raise ValueError(f"state must hold {list(layout.state_names)}, got {sorted(state)}")
            for name in layout.state_names:
                arrays[name] = state[name]
                widths[name] = spec.n_joints
        columns = []
        for name, array in arrays.items():
            array = np.asarray(array, dtype=float)
            if array.shape != (T, widths[name]):
                raise ValueError(
                    f"{source}: {name} must have shape ({T}, {widths[name]}) for robot "
                    f"{spec.name!r} ({spec.n_joints} joints, sensors {list(sensors)}), got "
                    f"{array.shape}"
                )
            columns.append(array)
        header = layout.columns(False) + (
            [c for name in layout.state_names for c in joint_columns(name, spec.n_joints)]
            if state is not None
            else []
        )
        values = np.hstack(columns) if columns else np.zeros((T, 0))
        return cls.from_table(header, values, sidecar, Source(source), "sidecar", base)

    def _check_ranges(self, spec: RobotSpec, sidecar_name: str, source: Source) -> None:
        n = spec.n_joints
        position = position_limit_of(self.sidecar, spec, sidecar_name)
        checks.check_bound(
            self.motor_position,
            position,
            joint_columns("motor_position", n),
            "rad",
            checks.DEGREES,
            source,
        )
        limit = torque_limit_of(self.sidecar, spec, sidecar_name) * (1.0 + checks.TORQUE_SLACK)
        checks.check_bound(
            self.torque, limit, joint_columns("torque", n), "N m", checks.TORQUES, source
        )
        gravity = float(np.linalg.norm(spec.gravity))
        checks.check_gravity(self.acceleration, self.sensor_names, gravity, self.duration, source)
        if self.truth is not None:
            for name in ("q", "theta"):
                if name in self.truth:
                    checks.check_bound(
                        self.truth[name],
                        position,
                        joint_columns(name, n),
                        "rad",
                        checks.DEGREES,
                        source,
                    )
            for name in ("dq", "dtheta"):
                if name in self.truth:
                    bound = np.full(n, checks.MAX_VELOCITY)
                    names = joint_columns(name, n)
                    checks.check_bound(
                        self.truth[name], bound, names, "rad/s", checks.VELOCITIES, source
                    )

    # ------------------------------------------------------------------ the robot
    @functools.cached_property
    def robot(self) -> RobotSpec:
        """The robot the sidecar names."""
        return robot_of(self.sidecar, "sidecar", self.base)

    @functools.cached_property
    def _model(self) -> RobotModel:
        return nominal_model(self.sidecar, self.robot, "sidecar")

    def nominal_model(self) -> RobotModel:
        """A fresh copy of the nominal model of the log's robot, with the log's
        accelerometer mounts (what observers and identification start from)."""
        return self._model.copy()

    # ------------------------------------------------------------------ sizes
    @property
    def n(self) -> int:
        """Number of joints."""
        return self.motor_position.shape[1]

    @property
    def elastic(self) -> bool:
        return self.robot.elastic

    def __len__(self) -> int:
        return len(self.time)

    @property
    def sample_time(self) -> float:
        """The sample period (s): the sidecar's `sample_time`, or the mean time step."""
        return checks.sample_time(self.time, self.sidecar.sample_time)

    @property
    def duration(self) -> float:
        """Time from the first to the last sample (s)."""
        return float(self.time[-1] - self.time[0])

    @property
    def layout(self) -> LogLayout:
        return LogLayout(self.n, self.sensor_names, self.elastic)

    # ------------------------------------------------------------------ state columns
    @property
    def truth(self) -> Mapping[str, np.ndarray] | None:
        """The state columns of a simulated log (`q`, `dq`, `theta`, `dtheta`), or None."""
        return self.state if self.sidecar.state == "truth" else None

    @property
    def estimate(self) -> Mapping[str, np.ndarray] | None:
        """The state columns of a log written by `observe` (an observer's estimate)."""
        return self.state if self.sidecar.state == "estimate" else None

    def state_vector(self) -> np.ndarray | None:
        """The state columns as (T, 4 n) rows (θ, q, θ', q') of De Luca et al. (2007)
        eq. (3) (rigid arms: (q, q')), or None."""
        if self.state is None:
            return None
        names = ELASTIC_STATE if self.elastic else ("q", "dq")
        return np.hstack([self.state[name] for name in names])

    # ------------------------------------------------------------------ as an env sees it
    def observations(self) -> dict[str, np.ndarray]:
        """The sensor observation of every row, as an env gives it (leading time axis):
        `motor_position` (elastic) or `link_position` (rigid) and `acceleration`."""
        key = "motor_position" if self.elastic else "link_position"
        out = {key: self.motor_position}
        if self.elastic:
            out["acceleration"] = self.acceleration
        return out

    def table(self) -> tuple[list[str], np.ndarray]:
        """(header, values (T, columns)) in the canonical column order."""
        layout = self.layout
        blocks = [self.time[:, None], self.motor_position, self.torque, self.acceleration]
        header = layout.columns(False)
        if self.state is not None:
            order = ("q", "dq", "theta", "dtheta") if self.elastic else ("q", "dq")
            blocks += [self.state[name] for name in order]
            header += layout.state
        return header, np.hstack(blocks)

    def with_state(
        self, state: Mapping[str, np.ndarray], kind: str, provenance: Mapping | None = None
    ) -> SensorLog:
        """This log's measurements with other state columns (`kind`: `truth` or
        `estimate`), the provenance updated with `provenance`."""
        update: dict = {"state": kind}
        if provenance is not None:
            update["provenance"] = self.sidecar.provenance.model_copy(update=dict(provenance))
        sidecar = self.sidecar.model_copy(update=update)
        return SensorLog.create(
            sidecar,
            self.time,
            self.motor_position,
            self.torque,
            self.acceleration,
            state,
            self.source,
            self.base,
        )


__all__ = ["LogError", "SensorLog"]
