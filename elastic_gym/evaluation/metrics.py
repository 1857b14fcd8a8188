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
`compute_metrics` states each definition.
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
    saturated: np.ndarray | None = None  # (K,) bool: torque clipped at a limit

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
            None if self.saturated is None else self.saturated[:length],
        )

    def estimation_blocks(self) -> dict[str, np.ndarray]:
        """Estimation error per state block, each (K, N)."""
        n = self.q.shape[1]
        blocks = self.estimation_error.reshape(len(self), len(self.state_names), n)
        return {name: blocks[:, i] for i, name in enumerate(self.state_names)}


@dataclass
class ArmSeries:
    """The signals of N arms recorded at the same control steps (row k at time k *
    control_dt): arrays with a leading time axis and an arm axis, ``(K, N, ...)``; arm i
    holds samples ``0 .. lengths[i] - 1`` (an arm whose run ended early has fewer)."""

    time: np.ndarray  # (K,)
    q: np.ndarray  # (K, N, n)
    q_ref: np.ndarray  # (K, N, n)
    dq_ref: np.ndarray  # (K, N, n)
    torque: np.ndarray  # (K, N, n)
    estimation_error: np.ndarray  # (K, N, len(state_names) * n)
    state_names: tuple[str, ...]
    lengths: np.ndarray  # (N,) int
    theta: np.ndarray | None = None  # (K, N, n)
    saturated: np.ndarray | None = None  # (K, N) bool: torque clipped at a limit

    @classmethod
    def of(cls, series: TimeSeries) -> ArmSeries:
        """One run's series as the one-arm case."""

        def arm(x):  # (K, n) -> (K, 1, n); None stays None
            return None if x is None else x[:, None]

        return cls(
            series.time,
            arm(series.q),
            arm(series.q_ref),
            arm(series.dq_ref),
            arm(series.torque),
            arm(series.estimation_error),
            series.state_names,
            np.array([len(series)]),
            arm(series.theta),
            arm(series.saturated),
        )

    def arm(self, i: int) -> TimeSeries:
        """Arm i's own samples (views)."""
        k = int(self.lengths[i])
        return TimeSeries(
            self.time[:k],
            self.q[:k, i],
            self.q_ref[:k, i],
            self.dq_ref[:k, i],
            self.torque[:k, i],
            self.estimation_error[:k, i],
            self.state_names,
            None if self.theta is None else self.theta[:k, i],
            None if self.saturated is None else self.saturated[:k, i],
        )


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
    starts: list[int] = (np.flatnonzero(edges == 1) + 1).tolist()
    arrivals: list[int] = (np.flatnonzero(edges == -1) + 1).tolist()
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
    """All metrics of one run (see module docstring); NaN where not applicable: the
    one-arm case of `compute_arm_metrics`."""
    return compute_arm_metrics(ArmSeries.of(series), tracking)[0]


def _window_rms(x: np.ndarray, starts: np.ndarray, stops: np.ndarray) -> np.ndarray:
    """Per arm i: sqrt(mean over k in [starts[i], stops[i]) of |x_k,i|^2) (NaN for no
    samples); x (K, N, d). The arms with the same window are summed together, each row
    alone and contiguous, so an arm's value is the same bit for bit whatever arms share its
    series (and equal to [`rms_norm`][elastic_gym.evaluation.metrics.rms_norm] of its own
    samples)."""
    squares = np.sum(x**2, axis=2).T  # (N, K)
    out = np.full(len(starts), np.nan)
    for start, stop in {(int(a), int(b)) for a, b in zip(starts, stops, strict=True)}:
        if stop > start:
            arms = np.flatnonzero((starts == start) & (stops == stop))
            block = np.ascontiguousarray(squares[arms, start:stop])
            out[arms] = np.sqrt(np.sum(block, axis=1) / (stop - start))
    return out


def compute_arm_metrics(series: ArmSeries, tracking: bool = True) -> list[dict[str, float]]:
    """The metrics of every arm of ``series`` (see module docstring), one dict per arm.

    The norms and means run over all arms at once, each over its own ``lengths[i]``
    samples; the rest-to-rest moves (overshoot, settling, residual torsion) are found
    on each arm's own reference.
    """
    nan = float("nan")
    K, N = series.q.shape[:2]
    lengths = series.lengths
    rows = np.arange(K)[:, None]
    valid = rows < lengths  # (K, N)
    zero = np.zeros_like(lengths)
    arms: list[dict[str, float]] = [{} for _ in range(N)]
    with np.errstate(invalid="ignore", over="ignore"):
        columns: dict[str, np.ndarray] = {}
        if tracking:
            error = series.q - series.q_ref
            columns["track_rms"] = _window_rms(error, zero, lengths)
            norm = np.where(valid, np.sqrt(np.sum(error**2, axis=2)), -np.inf)
            columns["track_max"] = np.max(norm, axis=0)
        if series.theta is not None:
            torsion = np.where(valid[..., None], np.abs(series.theta - series.q), -np.inf)
            columns["torsion_max"] = np.max(torsion, axis=(0, 2))
        columns["torque_rms"] = _window_rms(series.torque, zero, lengths)
        rate = np.diff(series.torque, axis=0) / np.diff(series.time)[:, None, None]
        columns["torque_rate_rms"] = _window_rms(rate, zero, np.maximum(lengths - 1, 0))
        if series.saturated is not None:
            counts = np.sum(series.saturated & valid, axis=0)
            columns["saturation_share"] = np.where(
                lengths > 0, counts / np.maximum(lengths, 1), nan
            )
        last_time = series.time[np.maximum(lengths - 1, 0)]
        start = np.searchsorted(series.time, np.minimum(ESTIMATION_TRANSIENT, last_time / 2))
        n_blocks = len(series.state_names)  # 0: raw sensors, nothing estimated (no block)
        blocks = series.estimation_error.reshape(K, N, max(n_blocks, 1), -1)
        for b, name in enumerate(series.state_names):
            columns[f"est_rms_{name}"] = _window_rms(blocks[:, :, b], start, lengths)
    for i, metrics in enumerate(arms):
        one = series.arm(i)
        metrics.update(dict.fromkeys(("track_rms", "track_max"), nan))
        metrics["overshoot_pct"], metrics["settling_time"] = (
            step_response(one) if tracking and lengths[i] else (nan, nan)
        )
        metrics["torsion_max"] = metrics["torsion_osc"] = nan
        if tracking and lengths[i]:
            metrics["track_rms"] = float(columns["track_rms"][i])
            metrics["track_max"] = float(columns["track_max"][i])
        if series.theta is not None and lengths[i]:
            metrics["torsion_max"] = float(columns["torsion_max"][i])
            metrics["torsion_osc"] = residual_torsion(one) if tracking else nan
        metrics["torque_rms"] = float(columns["torque_rms"][i])
        metrics["torque_rate_rms"] = float(columns["torque_rate_rms"][i])
        metrics["saturation_share"] = (
            float(columns["saturation_share"][i]) if "saturation_share" in columns else nan
        )
        for name in series.state_names:
            metrics[f"est_rms_{name}"] = float(columns[f"est_rms_{name}"][i])
    return arms
