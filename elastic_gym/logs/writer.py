"""`LogWriter`: a robot's controller appends one row per sample; the log and its sidecar
are written when it closes.

```python
with LogWriter("run.csv", robot="TwoLinkElastic-v0", sample_time=0.001) as log:
    for k in range(samples):
        ...  # read the sensors, compute and apply tau
        log.append(k * 0.001, theta, tau, {"acc_link1": f1, "acc_link2": f2})
```

`append` refuses a bad row at once (`ValueError` naming the row and the value) and does
not write it. Rows go to a temporary file as they come (a Parquet log stays in memory);
`close` checks the whole log as [`read_log`][elastic_gym.logs.read_log] would, then gives
it its name and writes the sidecar. An exception inside the `with` block, or a log that
fails the checks, leaves no log behind.
"""

from __future__ import annotations

import contextlib
import math
import os
import tempfile
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import IO, Any

import numpy as np

from elastic_gym.logs.columns import LogLayout
from elastic_gym.logs.io import log_kind, read_log, sidecar_text
from elastic_gym.logs.sidecar import LogSidecar, mounts_of, robot_of, sidecar_path
from elastic_gym.runtime.atomic import atomic_file
from elastic_gym.validation import validated


class LogWriter:
    """Write a sensor log row by row (module docstring).

    Args:
        path: the log file, `.csv` or `.parquet`.
        robot: the sidecar's `robot` (an env id or a robot description file).
        state: write state columns (`truth` of a simulation, or an observer's
            `estimate`); None: measurements only.
        **sidecar: the other fields of the sidecar
            ([`LogSidecar`][elastic_gym.logs.sidecar.LogSidecar]: `sample_time`,
            `accelerometers`, `encoder_resolution`, `torque_limit`, `provenance`, ...).
    """

    def __init__(
        self, path: str | Path, robot: str, state: str | None = None, **sidecar: Any
    ) -> None:
        self.path = Path(path)
        self.kind = log_kind(self.path)
        if self.kind not in ("csv", "parquet"):
            raise ValueError(f"{path}: LogWriter writes .csv or .parquet, not {self.path.suffix!r}")
        if state is not None:
            sidecar["state"] = state
        self.sidecar = validated(LogSidecar, {"robot": robot, **sidecar}, prefix="sidecar")
        self.base = self.path.parent
        spec = robot_of(self.sidecar, "sidecar", self.base)
        self.n = spec.n_joints
        self.sensor_names = tuple(m.name for m in mounts_of(self.sidecar, spec))
        self.layout = LogLayout(self.n, self.sensor_names, spec.elastic)
        self.with_state = state is not None
        self.header = self.layout.columns(self.with_state)
        self.rows = 0
        self._last_time = -math.inf
        self._memory: list[list[float]] = []
        self._stream: IO[str] | None = None
        self._scratch: str | None = None
        self._closed = False
        if self.kind == "csv":
            handle, self._scratch = tempfile.mkstemp(
                prefix=f".{self.path.stem}.", suffix=".part.csv", dir=self.path.parent
            )
            self._stream = open(handle, "w", encoding="utf-8", newline="")  # noqa: SIM115
            self._stream.write(",".join(self.header) + "\n")

    # ------------------------------------------------------------------ rows
    def append(
        self,
        time: float,
        motor_position: Sequence[float] | np.ndarray,
        torque: Sequence[float] | np.ndarray,
        acceleration: Mapping[str, Sequence[float]] | Sequence[float] | np.ndarray | None = None,
        state: Mapping[str, Sequence[float]] | None = None,
    ) -> None:
        """Append the sample at `time` (s): the encoder readings (rad), the motor torque
        applied from now until the next sample (N m), the accelerometers' specific
        forces (m/s²; a mapping sensor name → (x, y, z), or all 3 s values in mount
        order) and, for a log with state columns, `state` (`q`, `dq`, `theta`, `dtheta`)."""
        if self._closed:
            raise RuntimeError(f"{self.path}: the LogWriter is closed")
        where = f"{self.path}, row {self.rows + 1}"
        row = [self._number(time, where, "time")]
        if not row[0] > self._last_time:
            raise ValueError(
                f"{where}: time {time!r} is not after the previous row's {self._last_time!r}"
            )
        row += self._values(motor_position, self.n, where, "motor_position")
        row += self._values(torque, self.n, where, "torque")
        row += self._acceleration(acceleration, where)
        if self.with_state:
            if state is None:
                raise ValueError(f"{where}: this log has state columns: give state=")
            for name in ("q", "dq", "theta", "dtheta") if self.layout.elastic else ("q", "dq"):
                if name not in state:
                    raise ValueError(f"{where}: state has no {name!r}")
                row += self._values(state[name], self.n, where, f"state[{name!r}]")
        elif state is not None:
            raise ValueError(f"{where}: this log has no state columns (LogWriter(state=...))")
        self._last_time = row[0]
        if self._stream is not None:
            self._stream.write(",".join(map(repr, row)) + "\n")
        else:
            self._memory.append(row)
        self.rows += 1

    @staticmethod
    def _number(value: Any, where: str, what: str) -> float:
        try:
            number = float(value)
        except (TypeError, ValueError):
            raise ValueError(f"{where}: {what} must be a number, got {value!r}") from None
        if not math.isfinite(number):
            raise ValueError(f"{where}: {what} must be finite, got {number!r}")
        return number

    def _values(self, values: Any, count: int, where: str, what: str) -> list[float]:
        flat = np.asarray(values, dtype=float).ravel() if values is not None else np.zeros(0)
        if flat.size != count:
            raise ValueError(f"{where}: {what} needs {count} values, got {flat.size}")
        out = flat.tolist()
        for k, value in enumerate(out):
            if not math.isfinite(value):
                raise ValueError(f"{where}: {what}[{k}] must be finite, got {value!r}")
        return out

    def _acceleration(self, acceleration: Any, where: str) -> list[float]:
        if isinstance(acceleration, Mapping):
            unknown = sorted(set(acceleration) - set(self.sensor_names))
            if unknown:
                raise ValueError(
                    f"{where}: acceleration: unknown sensor(s) {unknown}; the log's "
                    f"sensors are {list(self.sensor_names)}"
                )
            out: list[float] = []
            for name in self.sensor_names:
                if name not in acceleration:
                    raise ValueError(f"{where}: acceleration: no reading of sensor {name!r}")
                out += self._values(acceleration[name], 3, where, f"acceleration[{name!r}]")
            return out
        return self._values(acceleration, 3 * len(self.sensor_names), where, "acceleration")

    # ------------------------------------------------------------------ closing
    def close(self) -> Path:
        """Check the whole log, then write it and its sidecar; returns the log's path.
        [`LogError`][elastic_gym.logs.LogError] if the log fails the checks of
        [`read_log`][elastic_gym.logs.read_log] (nothing is written then)."""
        if self._closed:
            return self.path
        self._closed = True
        try:
            scratch = self._finish_data()
            text = sidecar_text(self.sidecar, self.with_state)
            read_log(scratch, self.sidecar, str(self.path))  # same folder: same robot file
            side = sidecar_path(self.path)
            with atomic_file(side, "w", encoding="utf-8") as stream:
                stream.write(text)
            os.replace(scratch, self.path)
            self._scratch = None
        finally:
            self._discard()
        return self.path

    def _finish_data(self) -> str:
        """The path of the complete data file (not yet at its name)."""
        if self._stream is not None:
            self._stream.flush()
            os.fsync(self._stream.fileno())
            self._stream.close()
            self._stream = None
            assert self._scratch is not None
            return self._scratch
        from elastic_gym.logs.parquet_format import write_parquet_table

        handle, scratch = tempfile.mkstemp(
            prefix=f".{self.path.stem}.", suffix=".part.parquet", dir=self.path.parent
        )
        os.close(handle)
        self._scratch = scratch
        values = np.array(self._memory, dtype=float).reshape(-1, len(self.header))
        write_parquet_table(Path(scratch), self.header, values)
        return scratch

    def _discard(self) -> None:
        """Remove what is left of the temporary data file."""
        if self._stream is not None:
            self._stream.close()
            self._stream = None
        if self._scratch is not None:
            with contextlib.suppress(OSError):
                os.unlink(self._scratch)
            self._scratch = None

    def abort(self) -> None:
        """Drop the log: nothing is written."""
        self._closed = True
        self._discard()

    def __enter__(self) -> LogWriter:
        return self

    def __exit__(self, kind, value, traceback) -> None:
        if kind is None:
            self.close()
        else:
            self.abort()

    def __del__(self) -> None:
        if not vars(self).get("_closed", True) and vars(self).get("rows", 0):
            warnings.warn(
                f"LogWriter({str(self.path)!r}) dropped without close(): its {self.rows} rows "
                "are not written (use it in a with block, or call close())",
                ResourceWarning,
                stacklevel=2,
            )
        with contextlib.suppress(Exception):
            self._discard()
