"""ROS 2 bags and MCAP files (the `logs` extra: rosbags, mcap, mcap-ros2-support; no ROS
install needed), read through the sidecar's topic map
([`TopicMap`][elastic_gym.logs.sidecar.TopicMap]).

A ROS 2 bag folder (`metadata.yaml` + `.db3` or `.mcap` files) or a ROS 1 `.bag` is read
with rosbags, a lone `.mcap` file with mcap's ROS 2 decoder. The joint-state topic sets
the samples: its stamps (in seconds since its first message) are the log's `time`,
`position` gives `motor_position_<j>` and `effort` `torque_<j>`, in the robot's joint
order by the message's joint names. Each accelerometer topic (`sensor_msgs/msg/Imu`'s
`linear_acceleration`, `geometry_msgs/msg/Vector3Stamped`'s `vector` or
`geometry_msgs/msg/AccelStamped`'s `accel.linear`) gives its sensor's `_x/_y/_z` columns,
the latest message stamped at or before each sample; samples before every topic has
spoken are dropped. The table then passes the same checks as a CSV's.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from elastic_gym.logs.checks import Source
from elastic_gym.logs.columns import TIME, LogError, joint_columns, sensor_columns
from elastic_gym.logs.sidecar import TopicMap

BAG_SUFFIXES = (".bag", ".db3")
NANO = 1_000_000_000


def _extra(what: str) -> RuntimeError:
    return RuntimeError(f"{what} needs the 'logs' extra: pip install 'elastic-gym[logs]'")


def _rosbags_messages(path: Path, topics: Sequence[str]) -> Iterator[tuple[str, int, Any]]:
    """(topic, log time ns, message) of a ROS 2 bag folder or ROS 1 bag."""
    try:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        raise _extra(f"reading the bag {path}") from None
    bag = path.parent if path.suffix == ".db3" else path
    with AnyReader([bag], default_typestore=get_typestore(Stores.LATEST)) as reader:
        _check_topics(str(path), topics, {c.topic for c in reader.connections})
        connections = [c for c in reader.connections if c.topic in topics]
        for connection, stamp, raw in reader.messages(connections=connections):
            yield connection.topic, stamp, reader.deserialize(raw, connection.msgtype)


def _mcap_messages(path: Path, topics: Sequence[str]) -> Iterator[tuple[str, int, Any]]:
    """(topic, log time ns, message) of an MCAP file with ROS 2 messages."""
    try:
        from mcap.reader import make_reader
        from mcap_ros2.decoder import DecoderFactory
    except ImportError:
        raise _extra(f"reading the MCAP file {path}") from None
    with path.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        known = {c.topic for c in summary.channels.values()} if summary is not None else set()
        _check_topics(str(path), topics, known)
        for _, channel, message, decoded in reader.iter_decoded_messages(topics=list(topics)):
            yield channel.topic, message.log_time, decoded


def _check_topics(where: str, topics: Sequence[str], known: set[str]) -> None:
    missing = [topic for topic in topics if topic not in known]
    if missing:
        raise LogError(
            where,
            f"no topic {missing[0]!r} (the sidecar's 'topics'); the file has "
            f"{sorted(known) or 'no topics'}",
        )


def _stamp(message: Any, log_time: int, mode: str) -> int:
    if mode == "log":
        return int(log_time)
    stamp = message.header.stamp
    return int(stamp.sec) * NANO + int(stamp.nanosec)


def _vector(message: Any) -> tuple[float, float, float]:
    """The specific force of an Imu, Vector3Stamped or AccelStamped message."""
    for path in ("linear_acceleration", "vector", "accel"):
        value = getattr(message, path, None)
        if value is not None:
            if path == "accel":
                value = value.linear
            return float(value.x), float(value.y), float(value.z)
    raise TypeError(type(message).__name__)


def read_ros_table(
    path: Path,
    topics: TopicMap | None,
    joint_names: Sequence[str],
    sensor_names: Sequence[str],
    name: str | None = None,
) -> tuple[list[str], np.ndarray, Source]:
    """(header, values, source) of a bag or MCAP file (module docstring; `name` in
    errors, default its path)."""
    topics = topics or TopicMap()
    where = name or str(path)
    missing = [name for name in sensor_names if name not in topics.accelerometers]
    if missing:
        raise LogError(
            where,
            f"the sidecar's topics.accelerometers names no topic for sensor {missing[0]!r} "
            f"(sensors: {list(sensor_names)})",
        )
    unknown = [name for name in topics.accelerometers if name not in sensor_names]
    if unknown:
        raise LogError(
            where,
            f"topics.accelerometers: {unknown[0]!r} is not an accelerometer of the robot "
            f"(sensors: {list(sensor_names)})",
        )
    order = list(topics.joint_names or joint_names)
    if len(order) != len(joint_names):
        raise LogError(
            where,
            f"topics.joint_names has {len(order)} names, the robot {len(joint_names)} joints",
        )
    sensor_topic = {topics.accelerometers[name]: name for name in sensor_names}
    wanted = [topics.joint_states, *sensor_topic]
    reader = _mcap_messages if path.suffix == ".mcap" else _rosbags_messages
    joints: list[tuple[int, np.ndarray, np.ndarray]] = []
    sensors: dict[str, list[tuple[int, tuple[float, float, float]]]] = {
        name: [] for name in sensor_names
    }
    try:
        for topic, log_time, message in reader(path, wanted):
            stamp = _stamp(message, log_time, topics.stamp)
            if topic == topics.joint_states:
                joints.append((stamp, *_joint_sample(message, order, f"{where} ({topic})")))
            if topic in sensor_topic:
                try:
                    sensors[sensor_topic[topic]].append((stamp, _vector(message)))
                except TypeError as exc:
                    raise LogError(
                        f"{where} ({topic})",
                        f"a {exc} message, not sensor_msgs/msg/Imu, "
                        "geometry_msgs/msg/Vector3Stamped or AccelStamped",
                    ) from None
    except LogError:
        raise
    except Exception as exc:  # the readers' own errors: a broken or foreign file
        raise LogError(where, f"cannot be read as a ROS bag / MCAP file: {exc}") from None
    return _table(where, joints, sensors, joint_names, sensor_names, topics)


def _joint_sample(message: Any, order: list[str], where: str) -> tuple[np.ndarray, np.ndarray]:
    names = list(message.name)
    position = np.asarray(message.position, dtype=float)
    effort = np.asarray(message.effort, dtype=float)
    if not names and len(position) == len(order):
        names = order
    index = {name: k for k, name in enumerate(names)}
    absent = [name for name in order if name not in index]
    if absent:
        raise LogError(where, f"a JointState without joint {absent[0]!r} (it names {names})")
    if len(effort) != len(names):
        raise LogError(
            where,
            "a JointState whose effort does not give one torque per joint (the log needs "
            "the applied motor torque)",
        )
    picked = [index[name] for name in order]
    return position[picked], effort[picked]


def _table(
    where: str,
    joints: list[tuple[int, np.ndarray, np.ndarray]],
    sensors: dict[str, list[tuple[int, tuple[float, float, float]]]],
    joint_names: Sequence[str],
    sensor_names: Sequence[str],
    topics: TopicMap,
) -> tuple[list[str], np.ndarray, Source]:
    if not joints:
        raise LogError(where, f"no message on {topics.joint_states!r}: no data rows")
    joints.sort(key=lambda item: item[0])
    stamps = np.array([item[0] for item in joints], dtype=np.int64)
    keep = np.ones(len(stamps), dtype=bool)
    blocks = []
    for name in sensor_names:
        samples = sorted(sensors[name], key=lambda item: item[0])
        if not samples:
            topic = topics.accelerometers[name]
            raise LogError(where, f"no message on {topic!r} (sensor {name!r})")
        times = np.array([s[0] for s in samples], dtype=np.int64)
        index = np.searchsorted(times, stamps, side="right") - 1
        keep &= index >= 0
        blocks.append(np.array([s[1] for s in samples])[np.maximum(index, 0)])
    if not keep.any():
        raise LogError(where, "no joint-state sample after every accelerometer's first message")
    n = len(joint_names)
    time = (stamps - stamps[keep][0]) / NANO
    position = np.array([item[1] for item in joints])
    torque = np.array([item[2] for item in joints])
    values = np.hstack([time[:, None], position, torque, *blocks])[keep]
    header = [
        TIME,
        *joint_columns("motor_position", n),
        *joint_columns("torque", n),
        *sensor_columns(sensor_names),
    ]
    return header, values, Source(where)
