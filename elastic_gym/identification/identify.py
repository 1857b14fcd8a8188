"""Identify a sensor log and write the model file and the report.

[`identify`][elastic_gym.identification.identify.identify] takes a checked
[`SensorLog`][elastic_gym.logs.SensorLog] (its columns only: motor positions, torques,
accelerometers; truth columns, if any, are never read) and the nominal model of its
robot; [`write_identification`][elastic_gym.identification.identify.write_identification]
writes `model.yaml` (the identified model file), `report.md` and `identification.png`.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Protocol

import numpy as np

from elastic_gym.identification.fit import FitResult, FitSettings, fit_log
from elastic_gym.identification.model_file import identified_model
from elastic_gym.identification.problem import SamplingModel, Signals
from elastic_gym.identification.report import FIGURE_NAME, figure_png, report_markdown
from elastic_gym.model import RobotModel
from elastic_gym.model.identified import IdentifiedModel
from elastic_gym.runtime.atomic import write_bytes, write_text

MODEL_FILE = "model.yaml"
REPORT_FILE = "report.md"


class LogLike(Protocol):
    """What identification reads of a log (a `SensorLog` is one)."""

    @property
    def time(self) -> np.ndarray: ...
    @property
    def motor_position(self) -> np.ndarray: ...
    @property
    def torque(self) -> np.ndarray: ...
    @property
    def acceleration(self) -> np.ndarray: ...
    @property
    def sensor_names(self) -> tuple[str, ...]: ...
    @property
    def source(self) -> str: ...
    def nominal_model(self) -> RobotModel: ...


@dataclass
class Identification:
    """The fit and its model file."""

    result: FitResult
    model_file: IdentifiedModel
    title: str


def file_sha256(path: str | Path) -> str:
    """SHA-256 of a file's bytes (a folder, e.g. a ROS 2 bag: of its files in name order)."""
    digest = hashlib.sha256()
    path = Path(path)
    files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    for file in files:
        with file.open("rb") as handle:
            for block in iter(lambda: handle.read(1 << 20), b""):
                digest.update(block)
    return digest.hexdigest()


def sampling_of(
    log: LogLike,
    torque_hold: bool = True,
    delay: float | None = None,
    accelerometer_cutoff_hz: float | None = None,
) -> SamplingModel:
    """What the log's sampling did: the given values, else the sidecar's
    (``sensor_delay``, ``accelerometer_cutoff_hz``), else none."""
    sidecar = getattr(log, "sidecar", None)
    if delay is None:
        delay = getattr(sidecar, "sensor_delay", None) or 0.0
    if accelerometer_cutoff_hz is None:
        accelerometer_cutoff_hz = getattr(sidecar, "accelerometer_cutoff_hz", None)
    return SamplingModel(torque_hold, float(delay), accelerometer_cutoff_hz)


def identify(log: LogLike, settings: FitSettings | None = None) -> Identification:
    """Fit the elastic-joint model to ``log`` (see `elastic_gym.identification.fit`); the
    settings' sampling model, if None, is the log's (`sampling_of`).

    Raises ``ValueError`` naming the log when its robot has rigid joints or no
    accelerometers, or when it is too short."""
    settings = settings or FitSettings()
    if settings.sampling is None:
        settings = replace(settings, sampling=sampling_of(log))
    model = log.nominal_model()
    where = log.source
    if not model.spec.elastic:
        raise ValueError(
            f"{where}: robot {model.spec.name!r} has rigid joints; identify fits the "
            "elastic-joint model (motor encoders and link accelerometers)"
        )
    if not len(log.sensor_names):
        raise ValueError(
            f"{where}: no accelerometer columns; identify needs the link accelerometers "
            "(the motor side alone cannot tell the link motion)"
        )
    signals = Signals(
        time=np.asarray(log.time, dtype=float) - float(log.time[0]),
        motor_position=np.asarray(log.motor_position, dtype=float),
        torque=np.asarray(log.torque, dtype=float),
        acceleration=np.asarray(log.acceleration, dtype=float),
        sensor_names=tuple(log.sensor_names),
    )
    try:
        result = fit_log(signals, model, settings)
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None
    path = Path(where)
    sha = file_sha256(path) if path.exists() else ""
    model_file = identified_model(
        result, log_name=path.name, log_sha256=sha, sampling=settings.sampling
    )
    return Identification(result, model_file, path.name)


def write_identification(identification: Identification, output: str | Path) -> list[Path]:
    """Write `model.yaml`, `report.md` and the figure into ``output`` (created); each file
    is written whole or not at all. Returns the paths."""
    folder = Path(output)
    folder.mkdir(parents=True, exist_ok=True)
    report = report_markdown(identification.result, identification.model_file, identification.title)
    figure = figure_png(identification.result)
    return [
        write_text(folder / MODEL_FILE, identification.model_file.to_yaml()),
        write_text(folder / REPORT_FILE, report),
        write_bytes(folder / FIGURE_NAME, figure),
    ]
