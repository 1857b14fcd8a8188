"""Metrics of one run, computed from its recorded time series.

With e = q - q_d, norms Euclidean over the joints and means over the recorded samples:
``track_rms`` and ``track_max`` (rad); ``overshoot_pct`` and ``settling_time`` per
rest-to-rest move of the reference (``SETTLING_BAND`` of the move's amplitude, joints
moving less than ``MIN_AMPLITUDE`` not scored; the largest over the moves);
``torsion_max`` and ``torsion_osc`` (the standard deviation of theta - q from
``RESIDUAL_DELAY`` after each move: De Luca et al.'s "damping", Figs. 5-6);
``torque_rms`` (N m); ``est_rms_<block>`` per block of the state from
``ESTIMATION_TRANSIENT`` on (the observer's steady error); ``sim_wall_ratio``. A run that
ends early keeps the metrics of the samples recorded until then.
:func:`compute_metrics` states each definition.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MIN_AMPLITUDE = 1e-3  # rad: smaller per-joint moves are not scored for overshoot/settling
SETTLING_BAND = 0.02  # fraction of the move amplitude
REST_TOLERANCE = 1e-9  # |q_d'| (rad/s) below which the reference is at rest
RESIDUAL_DELAY = 0.1  # s after a move's arrival from which torsion oscillation is residual
ESTIMATION_TRANSIENT = 0.25  # s left out of the estimation errors (observer transient)


@dataclass
class TimeSeries:
    """Signals recorded at every control step of a run (row k at time k * control_dt).

    ``theta`` is ``None`` for rigid arms; ``estimation_error`` = estimate - truth with
    column blocks named by ``state_names``.
    """

    time: np.ndarray  # (K,)
    q: np.ndarray  # (K, N)
    q_ref: np.ndarray  # (K, N)
    dq_ref: np.ndarray  # (K, N)
    torque: np.ndarray  # (K, N)
    estimation_error: np.ndarray  # (K, len(state_names) * N)
    state_names: tuple[str, ...]
    theta: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.time)

    def truncated(self, length: int) -> TimeSeries:
        """The first ``length`` samples."""
        return TimeSeries(
            self.time[:length],
            self.q[:length],
            self.q_ref[:length],
            self.dq_ref[:length],
            self.torque[:length],
            self.estimation_error[:length],
            self.state_names,
            None if self.theta is None else self.theta[:length],
        )

    def estimation_blocks(self) -> dict[str, np.ndarray]:
        """Estimation error per state block, each (K, N)."""
        n = self.q.shape[1]
        blocks = self.estimation_error.reshape(len(self), len(self.state_names), n)
        return {name: blocks[:, i] for i, name in enumerate(self.state_names)}


@dataclass(frozen=True)
class Move:
    """A rest-to-rest move of the reference (sample indices into the series)."""

    start: int  # first moving sample
    arrival: int  # first sample at rest again
    end: int  # one past the last sample of the window
    origin: np.ndarray  # q_a
    target: np.ndarray  # q_b


def rms_norm(x: np.ndarray) -> float:
    """sqrt(mean_k |x_k|^2) over the rows of x (NaN for no rows)."""
    return float(np.sqrt(np.mean(np.sum(x**2, axis=1)))) if len(x) else float("nan")


def find_moves(series: TimeSeries) -> list[Move]:
    """Completed rest-to-rest moves of the reference (see module docstring)."""
    moving = np.any(np.abs(series.dq_ref) > REST_TOLERANCE, axis=1)
    edges = np.diff(moving.astype(np.int8))
    starts = list(np.flatnonzero(edges == 1) + 1)
    arrivals = list(np.flatnonzero(edges == -1) + 1)
    if len(moving) and moving[0]:
        starts.insert(0, 0)
    moves = []
    first_end = starts[0] if starts else len(series)
    if first_end and np.max(np.abs(series.q[0] - series.q_ref[0])) >= MIN_AMPLITUDE:
        moves.append(Move(0, 0, first_end, series.q[0].copy(), series.q_ref[0].copy()))
    for i, (start, arrival) in enumerate(zip(starts, arrivals, strict=False)):
        end = starts[i + 1] if i + 1 < len(starts) else len(series)
        origin = series.q_ref[max(start - 1, 0)]
        moves.append(Move(start, arrival, end, origin.copy(), series.q_ref[arrival].copy()))
    return moves


def move_response(series: TimeSeries, move: Move) -> tuple[float, float]:
    """(overshoot in % of the amplitude, settling time in s) of one move; NaN if not scored."""
    motion = move.target - move.origin
    scored = np.abs(motion) >= MIN_AMPLITUDE
    if not np.any(scored):
        return float("nan"), float("nan")
    amplitude = np.max(np.abs(motion))
    deviation = series.q[move.start : move.end, scored] - move.target[scored]
    overshoot = max(0.0, np.max(np.sign(motion[scored]) * deviation)) / amplitude * 100.0
    after = np.abs(series.q[move.arrival : move.end, scored] - move.target[scored])
    outside = np.any(after > SETTLING_BAND * amplitude, axis=1)
    if not len(after) or outside[-1]:
        return float(overshoot), float("inf")
    inside_from = len(after) - int(np.argmax(outside[::-1])) if outside.any() else 0
    settle_index = move.arrival + inside_from
    return float(overshoot), float(series.time[settle_index] - series.time[move.arrival])


def step_response(series: TimeSeries) -> tuple[float, float]:
    """Largest overshoot (%) and settling time (s) over all completed moves."""
    responses = [move_response(series, move) for move in find_moves(series)]
    responses = [r for r in responses if not np.isnan(r[0])]
    if not responses:
        return float("nan"), float("nan")
    overshoot, settling = np.max(np.asarray(responses), axis=0)
    return float(overshoot), float(settling)


def residual_torsion(series: TimeSeries) -> float:
    """Largest standard deviation of theta - q after a move's arrival (see module docstring)."""
    torsion = series.theta - series.q
    delay = np.searchsorted(series.time, series.time[0] + RESIDUAL_DELAY)
    windows = [
        torsion[m.arrival + delay : m.end]
        for m in find_moves(series)
        if m.end - m.arrival - delay > 1
    ]
    return max((float(np.max(np.std(w, axis=0))) for w in windows), default=float("nan"))


def compute_metrics(series: TimeSeries, tracking: bool = True) -> dict[str, float]:
    """All metrics of one run (see module docstring); NaN where not applicable."""
    nan = float("nan")
    metrics: dict[str, float] = dict.fromkeys(
        ("track_rms", "track_max", "overshoot_pct", "settling_time"), nan
    )
    if tracking and len(series):
        error = series.q - series.q_ref
        metrics["track_rms"] = rms_norm(error)
        metrics["track_max"] = float(np.max(np.linalg.norm(error, axis=1)))
        metrics["overshoot_pct"], metrics["settling_time"] = step_response(series)
    has_torsion = series.theta is not None and len(series)
    metrics["torsion_max"] = float(np.max(np.abs(series.theta - series.q))) if has_torsion else nan
    metrics["torsion_osc"] = residual_torsion(series) if has_torsion and tracking else nan
    metrics["torque_rms"] = rms_norm(series.torque)
    start = (
        np.searchsorted(series.time, min(ESTIMATION_TRANSIENT, series.time[-1] / 2))
        if len(series)
        else 0
    )
    for name, block in series.estimation_blocks().items():
        metrics[f"est_rms_{name}"] = rms_norm(block[start:])
    return metrics
