"""Bad logs: a clear error naming the file, the row and the column, one test per case of
the format's checks (and nothing read past the first problem)."""

from __future__ import annotations

import re

import numpy as np
import pytest
from helpers import synthetic_log_columns, write_csv_columns

from elastic_gym.logs import LogError, read_log


@pytest.fixture
def columns():
    return synthetic_log_columns()


def refused(path, *parts: str) -> LogError:
    """The error of reading ``path``, which must mention every one of ``parts``."""
    with pytest.raises(ValueError) as caught:
        read_log(path)
    message = str(caught.value)
    for part in parts:
        assert part in message, f"{part!r} not in {message!r}"
    return caught.value


def test_missing_column(tmp_path, columns):
    del columns["torque_2"]
    error = refused(
        write_csv_columns(tmp_path / "run.csv", columns), "run.csv", "'torque_2'", "missing"
    )
    assert error.column == "torque_2"


def test_missing_state_column_says_they_come_together(tmp_path, columns):
    del columns["dtheta_1"]
    refused(write_csv_columns(tmp_path / "run.csv", columns), "'dtheta_1'", "all together")


def test_unknown_column(tmp_path, columns):
    columns["current_1"] = columns["torque_1"]
    refused(
        write_csv_columns(tmp_path / "run.csv", columns), "column 'current_1'", "not a log column"
    )


def test_unknown_sensor_names_the_mounts(tmp_path, columns):
    columns = {k.replace("acc_link2", "imu2"): v for k, v in columns.items()}
    refused(
        write_csv_columns(tmp_path / "run.csv", columns), "'imu2_x'", "mounts: acc_link1, acc_link2"
    )


def test_joint_count_that_is_not_the_robots(tmp_path, columns):
    for name in ("motor_position", "torque", "q", "dq", "theta", "dtheta"):
        columns[f"{name}_3"] = columns[f"{name}_2"]
    refused(
        write_csv_columns(tmp_path / "run.csv", columns),
        "column 'motor_position_3'",
        "the log has 3 motor_position columns, the robot 2 joints",
    )


def test_too_few_joints(tmp_path, columns):
    for name in ("motor_position", "torque", "q", "dq", "theta", "dtheta"):
        del columns[f"{name}_2"]
    refused(
        write_csv_columns(tmp_path / "run.csv", columns),
        "'motor_position_2'",
        "is missing",
        "1 motor_position columns",
    )


def test_repeated_column(tmp_path, columns):
    path = write_csv_columns(tmp_path / "run.csv", columns)
    lines = path.read_text().splitlines()
    lines[0] = lines[0].replace("torque_2", "torque_1")
    path.write_text("\n".join(lines) + "\n")
    refused(path, "column 'torque_1'", "appears twice")


def test_non_monotonic_time(tmp_path, columns):
    columns["time"][500], columns["time"][501] = columns["time"][501], columns["time"][500]
    error = refused(
        write_csv_columns(tmp_path / "run.csv", columns),
        "row 502 (line 503), column 'time'",
        "increase strictly",
    )
    assert error.row == 502 and error.column == "time"


def test_repeated_time(tmp_path, columns):
    columns["time"][300] = columns["time"][299]
    refused(
        write_csv_columns(tmp_path / "run.csv", columns), "row 301", "'time'", "increase strictly"
    )


def test_irregular_time_a_dropped_sample(tmp_path, columns):
    columns = {key: np.delete(value, 700) for key, value in columns.items()}
    refused(
        write_csv_columns(tmp_path / "run.csv", columns),
        "row 701 (line 702), column 'time'",
        "a step of 0.002 s",
        "sample time is 0.001 s",
    )


def test_irregular_time_jitter_beyond_the_tolerance(tmp_path, columns):
    columns["time"][40] += 2e-5
    path = write_csv_columns(tmp_path / "run.csv", columns)
    refused(path, "row 41", "irregular time", "time_tolerance")
    # the sidecar can accept a clock's jitter
    path.with_suffix(".yaml").write_text(
        "robot: TwoLinkElastic-v0\nsample_time: 0.001\ntime_tolerance: 5.0e-5\n"
    )
    assert len(read_log(path)) == 1200


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_values(tmp_path, columns, bad):
    columns["acc_link2_y"][123] = bad
    error = refused(
        write_csv_columns(tmp_path / "run.csv", columns), "row 124 (line 125)", "'acc_link2_y'"
    )
    assert ("NaN" if np.isnan(bad) else "infinite") in str(error)


def test_degrees_where_radians_are_due(tmp_path, columns):
    for name in ("motor_position", "q", "theta"):
        for j in (1, 2):
            columns[f"{name}_{j}"] = np.degrees(columns[f"{name}_{j}"])
    error = refused(write_csv_columns(tmp_path / "run.csv", columns), "'motor_position_", "degrees")
    assert error.row is not None
    # the first motor position beyond one turn
    first = min(
        np.flatnonzero(np.abs(columns[f"motor_position_{j}"]) > 2 * np.pi)[0] for j in (1, 2)
    )
    assert error.row == first + 1


def test_degrees_in_the_state_columns_only(tmp_path, columns):
    columns["q_2"] = np.degrees(columns["q_2"])
    refused(write_csv_columns(tmp_path / "run.csv", columns), "column 'q_2'", "degrees")


def test_velocities_in_degrees(tmp_path, columns):
    columns["dtheta_1"] = np.degrees(columns["dtheta_1"]) * 100.0
    refused(write_csv_columns(tmp_path / "run.csv", columns), "column 'dtheta_1'", "rad/s")


def test_torque_beyond_the_limits(tmp_path, columns):
    columns["torque_2"][10] = 61.0  # the limit of joint 2 is 60 N m
    refused(write_csv_columns(tmp_path / "run.csv", columns), "row 11", "'torque_2'", "±60")


def test_accelerations_in_g(tmp_path, columns):
    for key in [k for k in columns if k.startswith("acc_link1_")]:
        columns[key] = columns[key] / 9.81
    refused(write_csv_columns(tmp_path / "run.csv", columns), "'acc_link1_x'", "readings in g")


def test_empty_file(tmp_path):
    path = tmp_path / "run.csv"
    path.write_text("")
    path.with_suffix(".yaml").write_text("robot: TwoLinkElastic-v0\n")
    refused(path, "run.csv", "empty file")


def test_header_without_rows(tmp_path, columns):
    path = write_csv_columns(tmp_path / "run.csv", columns)
    path.write_text(path.read_text().splitlines()[0] + "\n")
    refused(path, "run.csv", "no data rows")


def test_a_single_row(tmp_path, columns):
    columns = {key: value[:1] for key, value in columns.items()}
    refused(write_csv_columns(tmp_path / "run.csv", columns), "at least two samples")


def test_cell_that_is_not_a_number(tmp_path, columns):
    path = write_csv_columns(tmp_path / "run.csv", columns)
    lines = path.read_text().splitlines()
    cells = lines[8].split(",")
    cells[3] = "12,5".replace(",", ";")
    lines[8] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")
    refused(path, "row 8 (line 9), column 'torque_1'", "'12;5' is not a number")


def test_row_with_a_missing_cell(tmp_path, columns):
    path = write_csv_columns(tmp_path / "run.csv", columns)
    lines = path.read_text().splitlines()
    lines[20] = lines[20].rsplit(",", 1)[0]
    path.write_text("\n".join(lines) + "\n")
    refused(path, "row 20 (line 21)", "18 cells, the header has 19 columns")


def test_blank_line_between_rows(tmp_path, columns):
    path = write_csv_columns(tmp_path / "run.csv", columns)
    lines = path.read_text().splitlines()
    lines.insert(5, "")
    path.write_text("\n".join(lines) + "\n")
    refused(path, "row 5 (line 6)", "blank line")


def test_sidecar_naming_an_unknown_robot(tmp_path, columns):
    path = write_csv_columns(tmp_path / "run.csv", columns, "robot: Puma560Elastic-v0\n")
    refused(path, "run.yaml: robot: unknown robot 'Puma560Elastic-v0'", "TwoLinkElastic-v0")


def test_sidecar_naming_a_gymnasium_env_that_is_not_ours(tmp_path, columns):
    path = write_csv_columns(tmp_path / "run.csv", columns, "robot: CartPole-v1\n")
    refused(path, "unknown robot 'CartPole-v1'")


def test_sidecar_naming_a_missing_robot_file(tmp_path, columns):
    path = write_csv_columns(tmp_path / "run.csv", columns, "robot: my_arm.yaml\n")
    refused(path, "run.yaml: robot: no robot description file", "my_arm.yaml")


def test_sidecar_mount_on_a_link_the_robot_lacks(tmp_path, columns):
    sidecar = (
        "robot: TwoLinkElastic-v0\naccelerometers:\n"
        "  - {link: link7, position: [0.1, 0.0, 0.0], name: acc_link1}\n"
    )
    refused(
        write_csv_columns(tmp_path / "run.csv", columns, sidecar),
        "run.yaml: accelerometers",
        "'link7'",
    )


def test_missing_sidecar(tmp_path, columns):
    path = write_csv_columns(tmp_path / "run.csv", columns)
    path.with_suffix(".yaml").unlink()
    with pytest.raises(FileNotFoundError, match=re.escape("run.yaml: no sidecar")):
        read_log(path)


def test_sidecar_with_a_bad_field(tmp_path, columns):
    path = write_csv_columns(
        tmp_path / "run.csv", columns, "robot: TwoLinkElastic-v0\nsample_time: -1\n"
    )
    refused(path, "run.yaml: sample_time", "greater than 0")


def test_unknown_log_format(tmp_path, columns):
    path = write_csv_columns(tmp_path / "run.csv", columns)
    path.rename(tmp_path / "run.xlsx")
    refused(tmp_path / "run.xlsx", "unknown log format '.xlsx'")
