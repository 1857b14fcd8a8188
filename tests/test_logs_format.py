"""The sensor log format: CSV, Parquet, ROS 2 bag and MCAP readers, the LogWriter, the
sidecar and its schema, the nominal model a log belongs to."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from helpers import synthetic_log_columns, write_csv_columns

from elastic_gym.logs import LogError, LogWriter, SensorLog, read_log, write_log
from elastic_gym.robots.catalog import get_robot
from elastic_gym.schemas import SCHEMA_DIR, json_schema


def test_csv_round_trip_is_bit_exact(tmp_path):
    columns = synthetic_log_columns()
    # values whose shortest repr needs all 17 digits
    columns["torque_1"] = columns["torque_1"] + 1e-13 * np.pi
    path = write_csv_columns(tmp_path / "run.csv", columns)
    log = read_log(path)
    assert log.n == 2 and len(log) == 1200 and log.sensor_names == ("acc_link1", "acc_link2")
    assert log.sample_time == 0.001 and log.duration == pytest.approx(1.199)
    assert np.array_equal(log.torque[:, 0], columns["torque_1"])
    assert np.array_equal(log.truth["dtheta"][:, 1], columns["dtheta_2"])
    again = read_log(write_log(tmp_path / "copy.csv", log)[0])
    assert np.array_equal(again.table()[1], log.table()[1])
    assert again.sidecar.state == "truth" and again.truth is not None


def test_column_order_is_free(tmp_path):
    columns = synthetic_log_columns()
    shuffled = dict(reversed(list(columns.items())))
    log = read_log(write_csv_columns(tmp_path / "run.csv", shuffled))
    assert np.array_equal(log.motor_position[:, 1], columns["motor_position_2"])
    assert np.array_equal(log.acceleration[:, 5], columns["acc_link2_z"])


def test_parquet_round_trip(tmp_path):
    pytest.importorskip("pyarrow")
    log = read_log(write_csv_columns(tmp_path / "run.csv", synthetic_log_columns()))
    path, side = write_log(tmp_path / "run.parquet", log)
    again = read_log(path)
    assert np.array_equal(again.table()[1], log.table()[1])
    assert side.name == "run.yaml"


def test_log_writer_streams_rows_and_writes_the_sidecar(tmp_path):
    columns = synthetic_log_columns(state=False)
    path = tmp_path / "robot.csv"
    with LogWriter(path, robot="TwoLinkElastic-v0", sample_time=0.001) as log:
        for k in range(len(columns["time"])):
            log.append(
                columns["time"][k],
                [columns["motor_position_1"][k], columns["motor_position_2"][k]],
                [columns["torque_1"][k], columns["torque_2"][k]],
                {
                    name: [columns[f"{name}_{a}"][k] for a in "xyz"]
                    for name in ("acc_link2", "acc_link1")  # any order: by name
                },
            )
        assert not path.exists()  # written at close
    read = read_log(path)
    assert np.array_equal(read.acceleration[:, 3], columns["acc_link2_x"])
    assert read.state is None
    assert (tmp_path / "robot.yaml").read_text().startswith("# yaml-language-server: $schema=")


def test_log_writer_refuses_a_bad_row_and_writes_nothing_on_error(tmp_path):
    path = tmp_path / "robot.csv"
    log = LogWriter(path, robot="TwoLinkElastic-v0", sample_time=0.001)
    acc = [0.0, 0.0, 9.81] * 2
    log.append(0.0, [0.1, 0.2], [1.0, 2.0], acc)
    with pytest.raises(ValueError, match=r"row 2: torque\[1\] must be finite"):
        log.append(0.001, [0.1, 0.2], [1.0, np.nan], acc)
    with pytest.raises(ValueError, match="row 2: motor_position needs 2 values, got 3"):
        log.append(0.001, [0.1, 0.2, 0.3], [1.0, 2.0], acc)
    with pytest.raises(ValueError, match=r"row 2: time 0\.0 is not after"):
        log.append(0.0, [0.1, 0.2], [1.0, 2.0], acc)
    with pytest.raises(ValueError, match="unknown sensor"):
        log.append(0.001, [0.1, 0.2], [1.0, 2.0], {"acc_link3": [0, 0, 9.81]})
    assert log.rows == 1
    log.append(0.002, [0.1, 0.2], [1.0, 2.0], acc)  # a dropped sample: irregular time
    with pytest.raises(LogError, match=r"robot.csv, row 2 \(line 3\), column 'time'"):
        log.close()
    assert list(tmp_path.iterdir()) == []  # nothing written, no scratch file left
    with pytest.raises(RuntimeError), LogWriter(path, robot="TwoLinkElastic-v0") as log:
        log.append(0.0, [0.1, 0.2], [1.0, 2.0], acc)
        raise RuntimeError("the robot stopped")
    assert list(tmp_path.iterdir()) == []


def test_shipped_schema_is_the_sidecar_model_and_validates_a_written_sidecar(tmp_path):
    jsonschema = pytest.importorskip("jsonschema")
    import yaml

    shipped = json.loads((SCHEMA_DIR / "log.json").read_text())
    assert shipped == json_schema("log")
    log = read_log(write_csv_columns(tmp_path / "run.csv", synthetic_log_columns()))
    _, side = write_log(tmp_path / "out.csv", log)
    jsonschema.validate(yaml.safe_load(side.read_text()), shipped)
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate({"robot": "TwoLinkElastic-v0", "colour": "red"}, shipped)
    path = write_csv_columns(
        tmp_path / "bad.csv", synthetic_log_columns(), "robot: TwoLinkElastic-v0\ncolour: red\n"
    )
    with pytest.raises(ValueError, match=r"bad.yaml: colour: unexpected field; valid: \["):
        read_log(path)


def test_accelerometer_override_renames_the_columns_and_moves_the_model_sensor(tmp_path):
    columns = synthetic_log_columns()
    renamed = {
        key.replace("acc_link1", "imu_a").replace("acc_link2", "imu_b"): value
        for key, value in columns.items()
    }
    sidecar = (
        "robot: elastic_gym/TwoLinkElastic-v0\n"
        "accelerometers:\n"
        "  - {link: link1, position: [0.2, 0.0, 0.0], name: imu_a}\n"
        "  - {link: link2, position: [0.1, 0.0, 0.0], name: imu_b}\n"
    )
    log = read_log(write_csv_columns(tmp_path / "run.csv", renamed, sidecar))
    assert log.sensor_names == ("imu_a", "imu_b")
    model = log.nominal_model()
    # at q = 0 (links along x), a sensor 0.2 m out on link 1 moves by 0.2 m per rad of q1:
    # T_A's column of q1 has magnitude r = 0.2 (eq. (10))
    T, _ = model.chain.accelerometer_maps(np.zeros((1, 2)), np.zeros((1, 2)))
    assert np.linalg.norm(T[0, :3, 0]) == pytest.approx(0.2, rel=1e-12)
    assert np.linalg.norm(T[0, 3:, 0]) == pytest.approx(0.5 + 0.1, rel=1e-12)  # L1 + 0.1


def test_a_robot_description_file_gives_the_nominal_model(tmp_path):
    urdf = get_robot("two_link_elastic").urdf
    shutil.copy(urdf, tmp_path / "arm.urdf")
    (tmp_path / "arm.yaml").write_text(
        "name: my_arm\nurdf: arm.urdf\njoint_names: [joint1, joint2]\n"
        "stiffness: [3000.0, 1800.0]\nmotor_inertia: [0.4, 0.15]\ndamping: [2.5, 1.2]\n"
        "torque_limit: [100.0, 50.0]\n"
        "accelerometers:\n  - {link: link1, position: [0.3, 0.0, 0.0], name: acc_link1}\n"
        "  - {link: link2, position: [0.2, 0.0, 0.0], name: acc_link2}\n"
    )
    (tmp_path / "logs").mkdir()
    path = write_csv_columns(
        tmp_path / "logs" / "run.csv", synthetic_log_columns(), "robot: ../arm.yaml\n"
    )
    log = read_log(path)
    model = log.nominal_model()
    assert np.array_equal(model.K, [3000.0, 1800.0]) and np.array_equal(model.B, [0.4, 0.15])
    assert log.robot.name == "my_arm"
    out, side = write_log(tmp_path / "elsewhere.csv", log)  # the robot file follows
    assert "robot: arm.yaml" in side.read_text()
    assert read_log(out).robot.name == "my_arm"


def test_create_checks_shapes_and_gives_the_state_vector():
    columns = synthetic_log_columns(rows=50)
    theta = np.column_stack([columns["motor_position_1"], columns["motor_position_2"]])
    torque = np.column_stack([columns["torque_1"], columns["torque_2"]])
    acc = np.column_stack([columns[f"acc_link{s}_{a}"] for s in (1, 2) for a in "xyz"])
    state = {
        name: np.column_stack([columns[f"{name}_1"], columns[f"{name}_2"]])
        for name in ("q", "dq", "theta", "dtheta")
    }
    log = SensorLog.create(
        {"robot": "TwoLinkElastic-v0"}, columns["time"], theta, torque, acc, state
    )
    x = log.state_vector()
    assert x.shape == (50, 8) and np.array_equal(x[:, 2:4], state["q"])  # (theta, q, theta', q')
    assert not log.motor_position.flags.writeable
    with pytest.raises(ValueError, match=r"acceleration must have shape \(50, 6\)"):
        SensorLog.create({"robot": "TwoLinkElastic-v0"}, columns["time"], theta, torque, acc[:, :3])


def _bag_messages(columns, skip_first_imu: int = 0):
    """(time ns, positions, efforts, {sensor: (x, y, z)}) of every sample."""
    for k, t in enumerate(columns["time"]):
        yield (
            round(t * 1e9) + 1_700_000_000 * 1_000_000_000,
            [columns["motor_position_1"][k], columns["motor_position_2"][k]],
            [columns["torque_1"][k], columns["torque_2"][k]],
            {s: [columns[f"{s}_{a}"][k] for a in "xyz"] for s in ("acc_link1", "acc_link2")}
            if k >= skip_first_imu
            else {},
        )


TOPICS = (
    "robot: TwoLinkElastic-v0\nsample_time: 0.001\ntopics:\n  joint_states: /joint_states\n"
    "  joint_names: [joint1, joint2]\n"
    "  accelerometers: {acc_link1: /imu/link1, acc_link2: /imu/link2}\n"
)


def test_ros2_bag_through_the_topic_map(tmp_path):
    pytest.importorskip("rosbags")
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.LATEST)
    JointState, Imu = store.types["sensor_msgs/msg/JointState"], store.types["sensor_msgs/msg/Imu"]
    Header, Time = store.types["std_msgs/msg/Header"], store.types["builtin_interfaces/msg/Time"]
    Vector3 = store.types["geometry_msgs/msg/Vector3"]
    Quaternion = store.types["geometry_msgs/msg/Quaternion"]
    columns = synthetic_log_columns(rows=1100, state=False)
    bag = tmp_path / "rec"
    with Writer(bag, version=9) as writer:
        joints = writer.add_connection("/joint_states", JointState.__msgtype__, typestore=store)
        imus = {
            s: writer.add_connection(f"/imu/link{s[-1]}", Imu.__msgtype__, typestore=store)
            for s in ("acc_link1", "acc_link2")
        }
        for ns, position, effort, accs in _bag_messages(columns, skip_first_imu=3):
            header = Header(stamp=Time(sec=ns // 10**9, nanosec=ns % 10**9), frame_id="")
            # joint names in another order than the robot's: mapped by name
            message = JointState(
                header=header,
                name=["joint2", "joint1"],
                position=np.array(position[::-1]),
                velocity=np.zeros(0),
                effort=np.array(effort[::-1]),
            )
            writer.write(joints, ns, store.serialize_cdr(message, JointState.__msgtype__))
            for s, f in accs.items():
                imu = Imu(
                    header=header,
                    orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
                    orientation_covariance=np.zeros(9),
                    angular_velocity=Vector3(x=0.0, y=0.0, z=0.0),
                    angular_velocity_covariance=np.zeros(9),
                    linear_acceleration=Vector3(x=f[0], y=f[1], z=f[2]),
                    linear_acceleration_covariance=np.zeros(9),
                )
                writer.write(imus[s], ns, store.serialize_cdr(imu, Imu.__msgtype__))
    (tmp_path / "rec.yaml").write_text(TOPICS)
    log = read_log(bag)
    assert len(log) == 1100 - 3  # samples before the IMUs spoke are dropped
    assert log.time[0] == 0.0 and log.sample_time == 0.001
    assert np.array_equal(log.motor_position[:, 0], columns["motor_position_1"][3:])
    assert np.array_equal(log.torque[:, 1], columns["torque_2"][3:])
    assert np.array_equal(log.acceleration[:, 5], columns["acc_link2_z"][3:])


def test_mcap_file_through_the_topic_map(tmp_path):
    pytest.importorskip("mcap_ros2")
    from mcap_ros2.writer import Writer

    joint_def = (
        "std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\n"
        "float64[] effort\n================================================================"
        "================\nMSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n"
    )
    vector_def = (
        "std_msgs/Header header\ngeometry_msgs/Vector3 vector\n========================="
        "=======================================================\nMSG: std_msgs/Header\n"
        "builtin_interfaces/Time stamp\nstring frame_id\n======================================"
        "==========================================\nMSG: geometry_msgs/Vector3\nfloat64 x\n"
        "float64 y\nfloat64 z\n"
    )
    columns = synthetic_log_columns(rows=1100, state=False)
    path = tmp_path / "rec.mcap"
    with path.open("wb") as stream:
        writer = Writer(stream)
        joint_schema = writer.register_msgdef("sensor_msgs/msg/JointState", joint_def)
        vector_schema = writer.register_msgdef("geometry_msgs/msg/Vector3Stamped", vector_def)
        for ns, position, effort, accs in _bag_messages(columns):
            header = {"stamp": {"sec": ns // 10**9, "nanosec": ns % 10**9}, "frame_id": ""}
            writer.write_message(
                "/joint_states",
                joint_schema,
                {
                    "header": header,
                    "name": ["joint1", "joint2"],
                    "position": position,
                    "velocity": [],
                    "effort": effort,
                },
                log_time=ns,
            )
            for s, f in accs.items():
                message = {"header": header, "vector": {"x": f[0], "y": f[1], "z": f[2]}}
                writer.write_message(f"/imu/link{s[-1]}", vector_schema, message, log_time=ns)
        writer.finish()
    (tmp_path / "rec.yaml").write_text(TOPICS)
    log = read_log(path)
    assert len(log) == 1100
    assert np.array_equal(log.motor_position[:, 1], columns["motor_position_2"])
    assert np.array_equal(log.acceleration[:, 0], columns["acc_link1_x"])
    (tmp_path / "rec.yaml").write_text(TOPICS.replace("/imu/link2", "/imu/nowhere"))
    with pytest.raises(LogError, match="no topic '/imu/nowhere'"):
        read_log(path)


def test_log_writer_parquet_and_a_forgotten_close(tmp_path):
    pytest.importorskip("pyarrow")
    columns = synthetic_log_columns(rows=1100, state=False)
    path = tmp_path / "robot.parquet"
    with LogWriter(path, robot="TwoLinkElastic-v0", sample_time=0.001) as log:
        for k in range(1100):
            log.append(
                columns["time"][k],
                [columns[f"motor_position_{j}"][k] for j in (1, 2)],
                [columns[f"torque_{j}"][k] for j in (1, 2)],
                [columns[f"acc_link{s}_{a}"][k] for s in (1, 2) for a in "xyz"],
            )
    read = read_log(path)
    assert np.array_equal(read.torque[:, 1], columns["torque_2"])
    forgotten = LogWriter(tmp_path / "lost.csv", robot="TwoLinkElastic-v0")
    forgotten.append(0.0, [0.1, 0.2], [1.0, 2.0], [0.0, 0.0, 9.81] * 2)
    with pytest.warns(ResourceWarning, match="dropped without close"):
        del forgotten
        import gc

        gc.collect()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["robot.parquet", "robot.yaml"]
