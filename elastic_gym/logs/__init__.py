"""Sensor logs: what a real (or simulated) arm measured, in one documented format.

A log is a table of columns (`time`, `motor_position_<j>`, `torque_<j>`,
`<sensor>_x/_y/_z`, optionally the state columns `q_<j>`, `dq_<j>`, `theta_<j>`,
`dtheta_<j>`; `elastic_gym.logs.columns`) with a sidecar `<log>.yaml` naming the robot
(`elastic_gym.logs.sidecar`). [`read_log`][elastic_gym.logs.read_log] reads CSV (always),
Parquet, ROS 2 bags and MCAP files (the `logs` extra) into a checked
[`SensorLog`][elastic_gym.logs.SensorLog]; [`LogWriter`][elastic_gym.logs.LogWriter]
writes one row per sample from a robot's controller; a bad log is a
[`LogError`][elastic_gym.logs.LogError] naming the file, the row and the column.
"""

from elastic_gym.logs.columns import LogError, LogLayout
from elastic_gym.logs.io import read_log, write_log
from elastic_gym.logs.recorder import LogRecorder
from elastic_gym.logs.replay import LogEstimate, error_table, estimate_log
from elastic_gym.logs.sensor_log import SensorLog
from elastic_gym.logs.sidecar import LogSidecar, Provenance, TopicMap, sidecar_path
from elastic_gym.logs.writer import LogWriter

__all__ = [
    "LogError",
    "LogEstimate",
    "LogLayout",
    "LogRecorder",
    "LogSidecar",
    "LogWriter",
    "Provenance",
    "SensorLog",
    "TopicMap",
    "error_table",
    "estimate_log",
    "read_log",
    "sidecar_path",
    "write_log",
]
