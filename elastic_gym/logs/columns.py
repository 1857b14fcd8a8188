"""The columns of a sensor log: their names, units, order and meaning.

| column | unit | meaning |
|---|---|---|
| `time` | s | sample time, strictly increasing, one sample period apart |
| `motor_position_<j>` | rad | encoder reading of joint j = 1 … n (rigid arm: link) |
| `torque_<j>` | N m | motor torque applied from this sample until the next |
| `<sensor>_x`, `_y`, `_z` | m/s² | specific force f = R_WSᵀ (a − g), sensor frame |
| `q_<j>`, `dq_<j>` | rad, rad/s | link position and velocity (state columns) |
| `theta_<j>`, `dtheta_<j>` | rad, rad/s | motor position and velocity (state columns) |

`<sensor>` is an accelerometer mount's name (`acc_link1`), in the order of the mounts.
The state columns hold the truth of a simulated log, or an observer's estimate in a log
written by `elastic-gym observe` (the sidecar's `state` says which); all of them or none.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

TIME = "time"
AXES = ("x", "y", "z")
ELASTIC_STATE = ("theta", "q", "dtheta", "dq")  # De Luca et al. (2007), eq. (3)
RIGID_STATE = ("q", "dq")
UNITS = {
    "time": "s",
    "motor_position": "rad",
    "torque": "N m",
    "acceleration": "m/s^2",
    "q": "rad",
    "dq": "rad/s",
    "theta": "rad",
    "dtheta": "rad/s",
}


def joint_columns(prefix: str, n: int) -> list[str]:
    """`<prefix>_1` … `<prefix>_n`."""
    return [f"{prefix}_{j}" for j in range(1, n + 1)]


def sensor_columns(sensor_names: Sequence[str]) -> list[str]:
    """`<sensor>_x`, `<sensor>_y`, `<sensor>_z` of every sensor, in order."""
    return [f"{name}_{axis}" for name in sensor_names for axis in AXES]


@dataclass(frozen=True)
class LogLayout:
    """The columns a log of `n` joints and accelerometers `sensor_names` has, in the
    canonical order (time, motor positions, torques, sensors, state columns)."""

    n: int
    sensor_names: tuple[str, ...]
    elastic: bool = True

    @property
    def state_names(self) -> tuple[str, ...]:
        """The state blocks of the state columns: (theta, q, dtheta, dq) or (q, dq)."""
        return ELASTIC_STATE if self.elastic else RIGID_STATE

    @property
    def measured(self) -> list[str]:
        """The columns every log has."""
        n = self.n
        return [
            TIME,
            *joint_columns("motor_position", n),
            *joint_columns("torque", n),
            *sensor_columns(self.sensor_names),
        ]

    @property
    def state(self) -> list[str]:
        """The optional state columns, block by block (`q_1` … `q_n`, `dq_1` …)."""
        order = ("q", "dq", "theta", "dtheta") if self.elastic else RIGID_STATE
        return [column for block in order for column in joint_columns(block, self.n)]

    def columns(self, with_state: bool) -> list[str]:
        return self.measured + (self.state if with_state else [])

    def match(self, header: Sequence[str], where: str) -> bool:
        """Whether the header holds the state columns; `LogColumnError` naming the first
        missing, unknown or repeated column (and, for a joint or sensor count that is not
        the robot's, both counts) otherwise."""
        seen: set[str] = set()
        for name in header:
            if name in seen:
                raise LogColumnError(where, name, "appears twice in the header")
            seen.add(name)
        state = set(self.state)
        has_state = bool(seen & state)
        expected = self.columns(has_state)
        unknown = [name for name in header if name not in expected]
        missing = [name for name in expected if name not in seen]
        if unknown:
            raise LogColumnError(where, unknown[0], self._unknown(unknown[0], header))
        if missing:
            why = "is missing" + (
                "; state columns come all together or not at all" if missing[0] in state else ""
            )
            raise LogColumnError(where, missing[0], f"{why}{self._counts(header)}")
        return has_state

    def _counts(self, header: Sequence[str]) -> str:
        """`` (the log has 3 joints, the robot 2)`` when the motor position count differs."""
        joints = sum(name.startswith("motor_position_") for name in header)
        if joints != self.n:
            return f" (the log has {joints} motor_position columns, the robot {self.n} joints)"
        return ""

    def _unknown(self, name: str, header: Sequence[str]) -> str:
        prefix, _, index = name.rpartition("_")
        if index.isdigit() and prefix in ("motor_position", "torque", *ELASTIC_STATE):
            joints = sum(column.startswith("motor_position_") for column in header)
            return (
                f"is not a column of a robot with {self.n} joints "
                f"(the log has {joints} motor_position columns, the robot {self.n} joints)"
            )
        if index in AXES and prefix not in self.sensor_names:
            sensors = ", ".join(self.sensor_names) or "none"
            return (
                f"is not a column of this robot's accelerometers (mounts: {sensors}; the "
                "sidecar's 'accelerometers' overrides them)"
            )
        return f"is not a log column; expected {self.columns(True)}"


class LogError(ValueError):
    """A log refused: `str()` names the file and, where it applies, the row and column
    (`run.csv, row 17 (line 18), column 'torque_2': NaN`). `row` is the 1-based data row
    (None: the whole file), `column` the column's name (None: the whole row or file),
    `line` the row's line in a text file."""

    def __init__(
        self,
        where: str,
        problem: str,
        row: int | None = None,
        column: str | None = None,
        line: int | None = None,
    ) -> None:
        place = [where]
        if row is not None:
            place.append(f"row {row}" + (f" (line {line})" if line is not None else ""))
        if column is not None:
            place.append(f"column {column!r}")
        super().__init__(f"{', '.join(place)}: {problem}")
        self.where, self.problem, self.row, self.column = where, problem, row, column


class LogColumnError(LogError):
    """A column missing, unknown or repeated in a log's header."""

    def __init__(self, where: str, column: str, problem: str) -> None:
        super().__init__(where, problem, column=column)
