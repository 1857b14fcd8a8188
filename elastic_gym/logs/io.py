"""Reading and writing sensor logs: `read_log(path)` and `write_log(path, log)`.

The file's suffix picks the format: `.csv` (always), `.parquet` (pyarrow), `.mcap`, `.bag`
or a ROS 2 bag folder (rosbags / mcap: the `logs` extra). The sidecar is `<log>.yaml`
beside the log unless given.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path

import yaml

from elastic_gym.logs.csv_format import read_csv_table, write_csv_table
from elastic_gym.logs.parquet_format import read_parquet_table, write_parquet_table
from elastic_gym.logs.ros_format import BAG_SUFFIXES, read_ros_table
from elastic_gym.logs.sensor_log import SensorLog
from elastic_gym.logs.sidecar import (
    FORMAT,
    ROBOT_FILE_SUFFIXES,
    LogSidecar,
    load_sidecar,
    mounts_of,
    robot_of,
    sidecar_path,
)
from elastic_gym.runtime.atomic import atomic_file
from elastic_gym.validation import validated

TABLE_SUFFIXES = (".csv", ".parquet")
ROS_SUFFIXES = (".mcap", *BAG_SUFFIXES)


def log_kind(path: Path) -> str:
    """`csv`, `parquet` or `ros` from the path (a folder is a ROS 2 bag)."""
    if path.is_dir():
        return "ros"
    suffix = path.suffix.lower()
    if suffix in TABLE_SUFFIXES:
        return suffix[1:]
    if suffix in ROS_SUFFIXES:
        return "ros"
    raise ValueError(
        f"{path}: unknown log format {suffix!r}; logs are {', '.join(TABLE_SUFFIXES)}, "
        f"{', '.join(ROS_SUFFIXES)} or a ROS 2 bag folder"
    )


def read_log(
    path: str | Path,
    sidecar: str | Path | LogSidecar | Mapping | None = None,
    name: str | None = None,
) -> SensorLog:
    """The checked log at `path` (module docstring); `sidecar`: its file or contents
    (default `<log>.yaml` beside the log); `name`: the log's name in errors (default its
    path). Raises `FileNotFoundError` for a missing log
    or sidecar and [`LogError`][elastic_gym.logs.LogError] (a `ValueError` naming file,
    row and column) for a bad one."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such log file")
    kind = log_kind(path)
    if sidecar is None or isinstance(sidecar, (str, Path)):
        side_file = sidecar_path(path) if sidecar is None else Path(sidecar)
        side, where, base = load_sidecar(side_file), str(side_file), side_file.parent
    else:
        side, where, base = validated(LogSidecar, sidecar, prefix="sidecar"), "sidecar", path.parent
    shown = name or str(path)
    if kind == "csv":
        header, values, source = read_csv_table(path, shown)
    elif kind == "parquet":
        header, values, source = read_parquet_table(path, shown)
    else:
        spec = robot_of(side, where, base)
        sensors = [m.name for m in mounts_of(side, spec)]
        header, values, source = read_ros_table(path, side.topics, spec.joint_names, sensors, shown)
    return SensorLog.from_table(header, values, side, source, where, base)


def sidecar_text(sidecar: LogSidecar, with_state: bool = False) -> str:
    """The YAML of a sidecar: its schema comment, `format`, then the fields that differ
    from their defaults (and `state`, for a log with state columns)."""
    from elastic_gym.schemas import schema_comment

    data = {"format": FORMAT, **sidecar.model_dump(mode="json", exclude_defaults=True)}
    if with_state:
        data = {"format": FORMAT, "robot": sidecar.robot, "state": sidecar.state, **data}
    return schema_comment("log") + yaml.safe_dump(data, sort_keys=False)


def relocated(sidecar: LogSidecar, base: Path | None, folder: Path) -> LogSidecar:
    """`sidecar` whose robot description file (relative to `base`) is named relative to
    `folder`, where the sidecar is written."""
    if base is None or not sidecar.robot.endswith(ROBOT_FILE_SUFFIXES):
        return sidecar
    target = (base / sidecar.robot).resolve()
    robot = os.path.relpath(target, folder.resolve())
    return sidecar.model_copy(update={"robot": robot})


def write_log(path: str | Path, log: SensorLog) -> tuple[Path, Path]:
    """Write `log` to `path` (`.csv` or `.parquet`) and its sidecar beside it
    (`<log>.yaml`), each atomically; returns both paths."""
    path = Path(path)
    kind = log_kind(path)
    if kind not in ("csv", "parquet"):
        raise ValueError(f"{path}: logs are written as .csv or .parquet, not {path.suffix!r}")
    header, values = log.table()
    side = sidecar_path(path)
    text = sidecar_text(relocated(log.sidecar, log.base, side.parent), log.state is not None)
    if kind == "csv":
        write_csv_table(path, header, values)
    else:
        write_parquet_table(path, header, values)
    with atomic_file(side, "w", encoding="utf-8") as stream:
        stream.write(text)
    return path, side
