"""Test helpers: one RobotLog written the ways robots and ROS tools export logs (CSV variants, bags).

The bags are written with ``rosbags``' own writer (what a robot's recorder would produce), never by
reflexarm: the reader under test must not share code with the writer.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from reflexarm.ident import RobotLog

#: 2026-11-23 12:00:00 UTC in ns: an epoch start as ROS header stamps carry it.
EPOCH_NS = 1_795_435_200_000_000_000


def stamps_ns(log: RobotLog, start_ns: int = EPOCH_NS) -> list[int]:
    """The log's times as integer epoch nanoseconds (exact to 1 ns)."""
    return [start_ns + int(round(x * 1e9)) for x in log.t - log.t[0]]


def write_named_csv(log: RobotLog, path: Path, joint_names: list[str], start_ns: int = EPOCH_NS) -> Path:
    """ns epoch stamps, ``position_<joint>``/``<joint>/velocity``/``effort_<joint>`` columns, extra columns,
    the wrench (if any) as ``wrench.force.x`` .. ``wrench.torque.z``."""
    cols: dict[str, object] = {"seq": np.arange(len(log)), "timestamp": np.asarray(stamps_ns(log, start_ns))}
    for j, name in enumerate(joint_names):
        cols[f"position_{name}"] = log.q[:, j]
        cols[f"{name}/velocity"] = log.dq[:, j]
        cols[f"effort_{name}"] = log.measured_torque[:, j]
        cols[f"temperature_{name}"] = 40.0 + j
    if log.wrench is not None:
        for k, axis in enumerate(("force.x", "force.y", "force.z", "torque.x", "torque.y", "torque.z")):
            cols[f"wrench.{axis}"] = log.wrench[:, k]
    pd.DataFrame(cols).to_csv(path, index=False, float_format="%.17g")
    return path


def write_joint_state_csv(log: RobotLog, path: Path, joint_names: list[str], start_ns: int = EPOCH_NS) -> Path:
    """The JointState array layout of a bag-to-CSV export (header.stamp.sec/nanosec, name.k, position.k),
    the joint order reversed on every other row."""
    n = len(joint_names)
    rows = []
    for i, stamp in enumerate(stamps_ns(log, start_ns)):
        order = list(range(n)) if i % 2 == 0 else list(range(n))[::-1]
        row: dict[str, object] = {"header.stamp.sec": stamp // 10**9, "header.stamp.nanosec": stamp % 10**9}
        row |= {f"name.{k}": joint_names[j] for k, j in enumerate(order)}
        for field, arr in (("position", log.q), ("velocity", log.dq), ("effort", log.measured_torque)):
            row |= {f"{field}.{k}": arr[i, j] for k, j in enumerate(order)}
        rows.append(row)
    pd.DataFrame(rows).to_csv(path, index=False, float_format="%.17g")
    return path


def write_bag(
    log: RobotLog,
    path: Path,
    joint_names: list[str],
    *,
    storage: str,
    topic: str = "/joint_states",
    wrench_topic: str | None = None,
    gripper: bool = True,
    start_ns: int = EPOCH_NS,
    receive_delay_ns: int = 300_000,
    effort: bool = True,
    sample_order: np.ndarray | None = None,
) -> Path:
    """A rosbag2 bag (``storage`` "sqlite3" or "mcap") of ``log`` as sensor_msgs/JointState messages
    (header stamps = the log's times from ``start_ns``; bag receive times ``receive_delay_ns`` later),
    the joint order rotated from message to message, and (``gripper``) a gripper's own JointState
    message before every 10th sample; with ``wrench_topic`` the log's wrench as WrenchStamped at the same stamps;
    ``effort=False`` leaves the arm's effort arrays empty; ``sample_order`` writes the samples in that
    order (receive times still increasing: a recorder that got them out of order)."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    JointState = store.types["sensor_msgs/msg/JointState"]
    Header = store.types["std_msgs/msg/Header"]
    Time = store.types["builtin_interfaces/msg/Time"]
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    n = len(joint_names)

    def header(stamp: int, frame: str = "") -> Any:
        return Header(stamp=Time(sec=stamp // 10**9, nanosec=stamp % 10**9), frame_id=frame)

    with Writer(path, version=9, storage_plugin=plugin) as writer:
        conn = writer.add_connection(topic, JointState.__msgtype__, typestore=store)
        wconn = None
        if wrench_topic is not None:
            wconn = writer.add_connection(wrench_topic, "geometry_msgs/msg/WrenchStamped", typestore=store)
        stamps = stamps_ns(log, start_ns)
        for w_i, i in enumerate(range(len(log)) if sample_order is None else sample_order):
            stamp = stamps[i]
            received = stamps[w_i] + receive_delay_ns
            order = np.roll(np.arange(n), i % n)
            msg = JointState(
                header=header(stamp),
                name=[joint_names[j] for j in order],
                position=np.ascontiguousarray(log.q[i, order], dtype=np.float64),
                velocity=np.ascontiguousarray(log.dq[i, order], dtype=np.float64),
                effort=np.ascontiguousarray(log.measured_torque[i, order] if effort else [], dtype=np.float64),
            )
            if gripper and i % 10 == 0:
                grip = JointState(
                    header=header(stamp),
                    name=["finger_joint1", "finger_joint2"],
                    position=np.array([0.04, 0.04]),
                    velocity=np.zeros(0),
                    effort=np.zeros(0),
                )
                writer.write(conn, received - 1, store.serialize_cdr(grip, JointState.__msgtype__))
            writer.write(conn, received, store.serialize_cdr(msg, JointState.__msgtype__))
            if wconn is not None:
                assert log.wrench is not None
                w = log.wrench[i]
                Wrench = store.types["geometry_msgs/msg/Wrench"]
                Vector3 = store.types["geometry_msgs/msg/Vector3"]
                WrenchStamped = store.types["geometry_msgs/msg/WrenchStamped"]
                ws = WrenchStamped(
                    header=header(stamp, "ft_sensor"),
                    wrench=Wrench(force=Vector3(x=w[0], y=w[1], z=w[2]), torque=Vector3(x=w[3], y=w[4], z=w[5])),
                )
                writer.write(wconn, received + 2, store.serialize_cdr(ws, WrenchStamped.__msgtype__))
    return path
