"""The checks a log's values pass before anything reads them, each refusal a
[`LogError`][elastic_gym.logs.columns.LogError] naming the file, the row and the column:

* every value finite; `time` strictly increasing, every step within `time_tolerance` of
  the sample time (a dropped or repeated sample, a clock jump);
* motor positions (and the state's link positions) within the URDF's joint limits +
  0.1 rad (the spring's deflection), or one turn (2π) either way for a joint without
  limits: angles in degrees fail here; torques within the torque limits (N m);
* each accelerometer's mean |f| in [g/2, 20 g]: a specific force f = R_WSᵀ (a − g) has
  |f| = |a − g|, whose mean over a log of duration T is at least |g − Δv/T| (Δv the
  sensor's change of velocity), about g for a log of a second or more: readings in g
  or mm/s² fail here;
* the state velocities of a simulated log (truth) at most `MAX_VELOCITY`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from elastic_gym.logs.columns import LogError

DEFAULT_TOLERANCE = 1e-3  # of the sample time
MAX_VELOCITY = 100.0  # rad/s: the envs end an episode beyond it
MIN_DURATION_FOR_GRAVITY = 1.0  # s: shorter logs skip the mean |f| check
TORQUE_SLACK = 1e-9  # relative: a clipped torque written and read back


@dataclass(frozen=True)
class Source:
    """Where values come from, for error messages: a file's name and the line of its
    first data row (None: not a text file)."""

    name: str
    first_line: int | None = None

    def error(self, problem: str, row: int | None = None, column: str | None = None) -> LogError:
        """A `LogError` at data row `row` (0-based here, 1-based in the message)."""
        if row is None:
            return LogError(self.name, problem, column=column)
        line = None if self.first_line is None else self.first_line + row
        return LogError(self.name, problem, row + 1, column, line)


def check_finite(values: np.ndarray, names: Sequence[str], source: Source) -> None:
    """Every value finite; else the first non-finite cell (row-major)."""
    bad = ~np.isfinite(values)
    if bad.any():
        row, col = np.argwhere(bad)[0]
        value = values[row, col]
        kind = "NaN" if np.isnan(value) else f"{value} (infinite)"
        raise source.error(f"{kind}: every value of a log must be finite", row, names[col])


def sample_time(time: np.ndarray, given: float | None) -> float:
    """The log's sample time: `given`, or the mean step of `time`."""
    if given is not None:
        return float(given)
    return float((time[-1] - time[0]) / (len(time) - 1))


def check_time(time: np.ndarray, dt: float, tolerance: float | None, source: Source) -> None:
    """`time` strictly increasing, every step within `tolerance` (default
    `DEFAULT_TOLERANCE` of `dt`) of `dt`."""
    if len(time) < 2:
        raise source.error(
            f"{len(time)} data row(s): a log needs at least two samples", column="time"
        )
    step = np.diff(time)
    back = np.flatnonzero(step <= 0.0)
    if len(back):
        k = back[0] + 1
        raise source.error(
            f"{time[k]!r} s is not after the previous row's {time[k - 1]!r} s "
            "(time must increase strictly)",
            k,
            "time",
        )
    tol = DEFAULT_TOLERANCE * dt if tolerance is None else tolerance
    off = np.flatnonzero(np.abs(step - dt) > tol)
    if len(off):
        k = off[0] + 1
        raise source.error(
            f"a step of {step[k - 1]:.9g} s from the previous row, the sample time is "
            f"{dt:.9g} s (irregular time: a dropped or repeated sample, or a clock jump; "
            f"tolerance {tol:.3g} s, the sidecar's 'time_tolerance')",
            k,
            "time",
        )


def check_bound(
    values: np.ndarray,
    bound: np.ndarray,
    names: Sequence[str],
    unit: str,
    why: str,
    source: Source,
) -> None:
    """|values[:, j]| <= bound[j]; else the first cell beyond it, with `why`."""
    beyond = np.abs(values) > bound
    if beyond.any():
        row, col = np.argwhere(beyond)[0]
        raise source.error(
            f"{values[row, col]:.6g} {unit} is beyond the limit ±{bound[col]:.6g} {unit}{why}",
            row,
            names[col],
        )


DEGREES = " (angles in degrees where radians are due? the sidecar's 'position_limit' widens it)"
TORQUES = " (torque in other units than N m? the sidecar's 'torque_limit' replaces the robot's)"
VELOCITIES = " (velocities in degrees/s where rad/s are due?)"


def check_gravity(
    acceleration: np.ndarray,
    sensor_names: Sequence[str],
    gravity: float,
    duration: float,
    source: Source,
) -> None:
    """Each sensor's mean |f| in [g/2, 20 g] (module docstring), for logs of at least
    `MIN_DURATION_FOR_GRAVITY` and a robot under gravity."""
    if duration < MIN_DURATION_FOR_GRAVITY or gravity < 1.0 or not len(sensor_names):
        return
    norms = np.linalg.norm(acceleration.reshape(len(acceleration), -1, 3), axis=2).mean(axis=0)
    for name, mean in zip(sensor_names, norms, strict=True):
        if not 0.5 * gravity <= mean <= 20.0 * gravity:
            raise source.error(
                f"accelerometer {name!r} reads a mean |f| of {mean:.4g} m/s² over the log; "
                f"a specific force in m/s² averages about g = {gravity:.4g} m/s² (readings in "
                "g, or in other units than m/s²?)",
                column=f"{name}_x",
            )
