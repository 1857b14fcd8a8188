"""An observer run offline on a log, through the observer wrappers' own estimation loop.

[`estimate_log`][elastic_gym.logs.replay.estimate_log] builds the observer as the
wrappers do (a registry name with options, or a copy of an instance) on the log's nominal
model (or a given one, e.g. an identified model) at the log's sample time, resets it on
row 0 and advances it to row k + 1 with the measurements of row k + 1 and the torque of
row k ([`Estimator`][elastic_gym.observers.estimation.Estimator], as
`ObserverWrapper.step` does). On a log recorded from a simulated run the estimates are the
online ones bit for bit. An estimate that stops being finite ends the run at its row.
"""

from __future__ import annotations

import copy
import importlib
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from elastic_gym.logs.columns import LogError
from elastic_gym.logs.sensor_log import SensorLog
from elastic_gym.model import RobotModel
from elastic_gym.observers.base import Observer
from elastic_gym.observers.estimation import Estimator
from elastic_gym.observers.registry import OBSERVERS, make_observer


@dataclass(frozen=True)
class LogEstimate:
    """The estimates of an observer over a log.

    `estimate` (T', dim): the estimate at each row (T' = T, or the rows before the
    estimate diverged); `state_names`: its blocks ((theta, q, dtheta, dq) or (q, dq));
    `diverged_at`: the row whose update gave a non-finite estimate (None: none) and
    `error` why; `diagnostics`: the observer's after the last update.
    """

    estimate: np.ndarray
    state_names: tuple[str, ...]
    observer: str
    diverged_at: int | None = None
    error: str | None = None
    diagnostics: dict = field(default_factory=dict)

    def blocks(self) -> dict[str, np.ndarray]:
        """The estimate by block: name -> (T', n)."""
        parts = np.split(self.estimate, len(self.state_names), axis=1)
        return dict(zip(self.state_names, parts, strict=True))


def observer_class(name: str) -> type[Observer]:
    """The class of a registry name or of `module:Class`."""
    if name in OBSERVERS or ":" not in name:
        from elastic_gym.observers.registry import observer_class as registered

        return registered(name)
    module, _, attr = name.partition(":")
    try:
        cls = getattr(importlib.import_module(module), attr)
    except (ImportError, AttributeError) as exc:
        raise ValueError(f"observer {name!r}: cannot import it ({exc})") from None
    if not (isinstance(cls, type) and issubclass(cls, Observer)):
        raise ValueError(f"observer {name!r} is not an Observer subclass")
    return cls


def build_observer(
    log: SensorLog,
    observer: str | Observer,
    model: RobotModel | None = None,
    options: Mapping | None = None,
) -> Observer:
    """The observer of `estimate_log` (module docstring): built on `model` (default the
    log's nominal model) at the log's sample time; privileged observers (those that read
    the simulator's truth) are refused, a log holds only what sensors measure."""
    options = dict(options or {})
    if isinstance(observer, Observer):
        if options or model is not None:
            raise ValueError("options and model apply to an observer given by name")
        built = copy.deepcopy(observer)
    else:
        model = model if model is not None else log.nominal_model()
        if observer in OBSERVERS:
            built = make_observer(observer, model, log.sample_time, **options)
        else:
            built = observer_class(observer)(model, log.sample_time, **options)
    if built.privileged:
        raise ValueError(
            f"observer {observer if isinstance(observer, str) else built.name!r} reads the "
            f"simulator's truth ({', '.join(built.privileged)}), which a log does not hold; "
            "observe runs implementable observers"
        )
    spec = built.model.spec
    if spec.n_joints != log.n or spec.elastic != log.elastic:
        raise ValueError(
            f"the observer's model is of robot {spec.name!r} ({spec.n_joints} {spec.kind} "
            f"joints), the log's robot {log.robot.name!r} has {log.n} {log.robot.kind} joints"
        )
    if built.model.n_sensors != len(log.sensor_names) and built.elastic:
        raise ValueError(
            f"the observer's model has {built.model.n_sensors} accelerometers, the log "
            f"{len(log.sensor_names)} ({', '.join(log.sensor_names)})"
        )
    return built


def estimate_log(
    log: SensorLog,
    observer: str | Observer,
    model: RobotModel | None = None,
    options: Mapping | None = None,
    initial_estimate: np.ndarray | None = None,
) -> LogEstimate:
    """Run `observer` over `log` (module docstring)."""
    built = build_observer(log, observer, model, options)
    estimator = Estimator(built, 1)
    observed = {key: value[:, None] for key, value in log.observations().items()}
    first = {key: value[0] for key, value in observed.items()}
    estimator.reset(first, np.array([0]), initial_estimate)
    start = estimator.estimates[0].copy()
    rest = {key: value[1:] for key, value in observed.items()}
    torques = np.ascontiguousarray(log.torque[:-1, None])
    estimates, diverged = estimator.run(rest, torques, log.sample_time)
    rows = np.concatenate([start[None], estimates[:, 0]])
    name = observer if isinstance(observer, str) else built.name or type(built).__name__
    diagnostics = {
        k: np.asarray(v)[0].item() for k, v in estimator.observer.arm_diagnostics.items()
    }
    return LogEstimate(
        estimate=rows,
        state_names=tuple(built.state_names),
        observer=name,
        diverged_at=None if diverged is None else diverged + 1,
        error=None if diverged is None else str(estimator.errors[0]),
        diagnostics=diagnostics,
    )


def estimate_as_log(log: SensorLog, result: LogEstimate, provenance: Mapping) -> SensorLog:
    """`log`'s measurements with `result` in the state columns (`state: estimate`)."""
    if result.diverged_at is not None:
        raise LogError(
            log.source,
            f"the estimate of {result.observer} is not finite after this row's update: "
            f"{result.error}",
            row=result.diverged_at + 1,
        )
    return log.with_state(result.blocks(), "estimate", provenance)


ERROR_COLUMNS = ("column", "unit", "rms", "max_abs", "rms_settled")


def error_table(log: SensorLog, result: LogEstimate, settle: float) -> list[dict]:
    """Per state column (`theta_1` … `dq_n`): the RMS and largest |estimate − truth| over
    the log, and the RMS after the first `settle` seconds (`rms_settled`)."""
    truth = log.truth
    if truth is None:
        raise ValueError(f"{log.source}: no truth columns: no estimation error to compute")
    blocks = result.blocks()
    rows_used = len(result.estimate)
    settled = log.time[:rows_used] - log.time[0] >= settle
    table = []
    for name in result.state_names:
        error = blocks[name] - truth[name][:rows_used]
        unit = "rad/s" if name.startswith("d") else "rad"
        for j in range(log.n):
            e = error[:, j]
            table.append(
                {
                    "column": f"{name}_{j + 1}",
                    "unit": unit,
                    "rms": float(np.sqrt(np.mean(e**2))),
                    "max_abs": float(np.max(np.abs(e))),
                    "rms_settled": float(np.sqrt(np.mean(e[settled] ** 2)))
                    if settled.any()
                    else float("nan"),
                }
            )
    return table
