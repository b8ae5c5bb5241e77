"""ROS 2 bags (rosbag2 sqlite3 ``.db3`` and MCAP) as robot logs, read with ``rosbags`` (no ROS install).

* **Joints**: the ``sensor_msgs/msg/JointState`` topic (``joint_topic``; by default the bag's only one).
  Joints are mapped by name in every message (the order may change between messages). Messages that
  hold none of the arm's joints (e.g. a gripper's own messages) are left out with a note naming their
  joints; a message with some but not all of the arm's joints is an error. Without joint names the
  first message's order is the model's (said so). Position, velocity and effort are required.
* **Time**: the messages' header stamps (when the robot sampled), unless they are unset (zero), then the
  bag's receive times (when the recorder got the message; they carry transport jitter), said so in a
  note. Messages recorded out of stamp order are sorted by stamp (counted in a note); equal stamps are
  left to the log's repairs (exact repeats dropped, the rest re-timed). Times are relative to the first
  joint sample, in seconds.
* **Wrist wrench** (optional, ``wrench_topic``: ``geometry_msgs/msg/WrenchStamped``, force [N] and
  torque [Nm] in the message's frame): interpolated linearly, per component, at the joint samples'
  times on the same clock (header stamps or receive times, as chosen for the joints). Joint samples
  outside the wrench's time span are dropped (counted in a note); the note also gives the wrench's
  rate and frame.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from reflexarm.errors import DataError
from reflexarm.logs.timestamps import relative_seconds

__all__ = ["BAG_SUFFIXES", "JOINT_STATE_TYPE", "WRENCH_TYPE", "read_bag"]

#: File suffixes read as bags (a rosbag2 folder is read too).
BAG_SUFFIXES = (".db3", ".mcap")
JOINT_STATE_TYPE = "sensor_msgs/msg/JointState"
WRENCH_TYPE = "geometry_msgs/msg/WrenchStamped"


@contextmanager
def _open(p: Path) -> Iterator[Any]:
    from rosbags.highlevel import AnyReader

    try:
        reader = AnyReader([p])
        reader.open()
    except Exception as e:  # rosbags raises its own error types and OSError for unreadable files
        raise DataError(f"{p.name}: cannot read the file as a ROS 2 bag (.db3, .mcap or a rosbag2 folder): {e}") from e
    try:
        yield reader
    finally:
        reader.close()


def read_bag(
    p: Path,
    *,
    joint_names: tuple[str, ...] | None,
    n_joints: int | None,
    joint_topic: str | None,
    wrench_topic: str | None,
    time_unit: str | None = None,
) -> tuple[dict[str, np.ndarray], list[str]]:
    """The log's arrays (``t`` [s] from the first sample, ``q``, ``dq``, ``tau``, optional ``wrench``)
    and notes saying what was read and how (see the module docstring).

    Raises:
        DataError: no or several JointState topics and none chosen, an unknown topic (the message lists
            the bag's topics and types), missing arm joints or fields, unusable stamps.
    """
    where = p.name
    if time_unit not in (None, "ns"):
        raise DataError(f"{where}: bag time stamps are nanoseconds; got time unit {time_unit!r}")
    with _open(p) as reader:
        topics = {c.topic: c.msgtype for c in reader.connections}
        listing = ", ".join(f"{t} ({m})" for t, m in sorted(topics.items())) or "none"
        notes: list[str] = []
        if joint_topic is None:
            candidates = sorted(t for t, m in topics.items() if m == JOINT_STATE_TYPE)
            if len(candidates) != 1:
                what = "no" if not candidates else f"{len(candidates)}"
                raise DataError(
                    f"{where}: {what} {JOINT_STATE_TYPE} topics; "
                    + ("choose one with the joint topic (--joint-topic); " if candidates else "")
                    + f"topics: {listing}",
                    source=where,
                    column=tuple(candidates),
                    expected=JOINT_STATE_TYPE,
                )
            joint_topic = candidates[0]
            notes.append(f"{where}: joints from topic {joint_topic} ({JOINT_STATE_TYPE}, the bag's only one)")
        _check_topic(where, topics, joint_topic, JOINT_STATE_TYPE, listing)
        if wrench_topic is not None:
            _check_topic(where, topics, wrench_topic, WRENCH_TYPE, listing)
        else:
            others = sorted(t for t, m in topics.items() if m == WRENCH_TYPE)
            if others:
                notes.append(f"{where}: {WRENCH_TYPE} topic(s) {', '.join(others)} not used (no wrench topic given)")
        joints = _joint_messages(reader, joint_topic)
        wrench = None if wrench_topic is None else _wrench_messages(reader, wrench_topic)
    data, order_notes = _map_joints(joints, joint_names, n_joints, joint_topic, where)
    notes += order_notes
    header, received = data.pop("header"), data.pop("received")
    stamps, clock = _choose_clock(header, received, joint_topic, where, notes)
    if np.any(np.diff(stamps) < 0):  # recorded out of order: the stamps give the sampling order
        order = np.argsort(stamps, kind="stable")
        moved = int(np.sum(order != np.arange(order.size)))
        stamps = stamps[order]
        for k in ("q", "dq", "tau"):
            data[k] = data[k][order]
        notes.append(f"{where}: {moved:,} {joint_topic} message(s) were recorded out of stamp order; sorted by stamp")
    if wrench is not None:
        w_stamps = wrench["header"] if clock == "header" else wrench["received"]
        keep, data["wrench"], note = _align_wrench(stamps, w_stamps, wrench, wrench_topic or "", where)
        notes.append(note)
        stamps = stamps[keep]
        for k in ("q", "dq", "tau"):
            data[k] = data[k][keep]
    data["t"], t_note = relative_seconds(
        stamps,
        where=where,
        column=f"{joint_topic} {'header stamps' if clock == 'header' else 'receive times'}",
        unit="ns",
    )
    if t_note:
        notes.append(t_note)
    return data, notes


def _check_topic(where: str, topics: dict[str, str], topic: str, msgtype: str, listing: str) -> None:
    if topic not in topics:
        raise DataError(
            f"{where}: no topic {topic!r} in the bag; topics: {listing}",
            source=where,
            column=topic,
            expected=tuple(sorted(topics)),
        )
    if topics[topic] != msgtype:
        raise DataError(
            f"{where}: topic {topic!r} carries {topics[topic]}, not {msgtype}; topics: {listing}",
            source=where,
            column=topic,
            value=topics[topic],
            expected=msgtype,
        )


def _stamp(msg: Any) -> int:
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def _joint_messages(reader: Any, topic: str) -> list[tuple[int, int, tuple[str, ...], Any, Any, Any]]:
    conns = [c for c in reader.connections if c.topic == topic]
    out = []
    for conn, received, raw in reader.messages(connections=conns):
        msg = reader.deserialize(raw, conn.msgtype)
        out.append((_stamp(msg), int(received), tuple(msg.name), msg.position, msg.velocity, msg.effort))
    return out


def _wrench_messages(reader: Any, topic: str) -> dict[str, Any]:
    conns = [c for c in reader.connections if c.topic == topic]
    header, received, values, frames = [], [], [], set()
    for conn, rec, raw in reader.messages(connections=conns):
        msg = reader.deserialize(raw, conn.msgtype)
        f, m = msg.wrench.force, msg.wrench.torque
        header.append(_stamp(msg))
        received.append(int(rec))
        values.append((f.x, f.y, f.z, m.x, m.y, m.z))
        frames.add(str(msg.header.frame_id))
    if not values:
        raise DataError(f"wrench topic {topic!r} has no messages")
    return {
        "header": np.asarray(header, dtype=np.int64),
        "received": np.asarray(received, dtype=np.int64),
        "values": np.asarray(values, dtype=float),
        "frames": sorted(frames),
    }


def _map_joints(
    messages: list[tuple[int, int, tuple[str, ...], Any, Any, Any]],
    joint_names: tuple[str, ...] | None,
    n_joints: int | None,
    topic: str,
    where: str,
) -> tuple[dict[str, np.ndarray], list[str]]:
    if not messages:
        raise DataError(f"{where}: topic {topic} has no messages")
    notes: list[str] = []
    if joint_names is None:
        first = next((m[2] for m in messages if n_joints is None or len(m[2]) == n_joints), messages[0][2])
        joint_names = first
        which = "first message" if first == messages[0][2] else f"first message with {n_joints} joints"
        notes.append(f"{where}: joint order taken from the {which}: {', '.join(joint_names)}")
        if n_joints is not None and len(joint_names) != n_joints:
            raise DataError(
                f"{where}: the first {topic} message has {len(joint_names)} joints ({', '.join(joint_names)}); "
                f"the robot has {n_joints}",
                source=where,
                column=topic,
                value=len(joint_names),
                expected=n_joints,
            )
    n = len(joint_names)
    orders: dict[tuple[str, ...], np.ndarray | None] = {}
    skipped: dict[str, int] = {}
    rows: list[int] = []
    elements: list[np.ndarray] = []
    for r, (_, _, names, *_) in enumerate(messages):
        if names not in orders:
            where_is = {name: k for k, name in enumerate(names)}
            have = [j for j in joint_names if j in where_is]
            if not have:
                orders[names] = None
            elif len(have) < n:
                missing = [j for j in joint_names if j not in where_is]
                raise DataError(
                    f"{where}: {topic} message {r} holds joints {', '.join(names)}: the arm's joint(s) "
                    f"{', '.join(map(repr, missing))} missing (a message must hold all of the arm's joints or none)",
                    source=where,
                    column=topic,
                    row=r,
                    joint=missing[0],
                    value=names,
                    expected=joint_names,
                )
            else:
                orders[names] = np.array([where_is[j] for j in joint_names])
        order = orders[names]
        if order is None:
            for name in names:
                skipped[name] = skipped.get(name, 0) + 1
            continue
        rows.append(r)
        elements.append(order)
    if not rows:
        raise DataError(f"{where}: no {topic} message holds the arm's joints ({', '.join(joint_names)}); "
                        f"joints found: {', '.join(skipped) or 'none'}")  # fmt: skip
    data: dict[str, np.ndarray] = {}
    for k, (signal, field) in enumerate((("q", "position"), ("dq", "velocity"), ("tau", "effort"))):
        out = np.empty((len(rows), n))
        for i, (r, order) in enumerate(zip(rows, elements, strict=True)):
            values = np.asarray(messages[r][3 + k], dtype=float)
            if values.size != len(messages[r][2]):
                raise DataError(
                    f"{where}: {topic} message {r} has {values.size} {field} values for {len(messages[r][2])} joints"
                    + (f"; the arm's {field} is required" if values.size == 0 else ""),
                    source=where,
                    column=f"{topic} {field}",
                    row=r,
                    value=values.size,
                    expected=len(messages[r][2]),
                )
            out[i] = values[order]
        data[signal] = out
    data["header"] = np.asarray([messages[r][0] for r in rows], dtype=np.int64)
    data["received"] = np.asarray([messages[r][1] for r in rows], dtype=np.int64)
    if len([o for o in orders.values() if o is not None]) > 1:
        notes.append(f"{where}: the joint order changes between {topic} messages; mapped by name per message")
    if skipped:
        notes.append(
            f"{where}: left out {len(messages) - len(rows):,} {topic} message(s) holding none of the arm's joints "
            f"(joints {', '.join(skipped)}: not in the arm)"
        )
    return data, notes


def _choose_clock(
    header: np.ndarray, received: np.ndarray, topic: str, where: str, notes: list[str]
) -> tuple[np.ndarray, str]:
    if np.all(header > 0):
        notes.append(
            f"{where}: times from the {topic} header stamps (when the robot sampled), not the bag's receive times"
        )
        return header, "header"
    notes.append(
        f"{where}: the {topic} header stamps are unset (zero); times from the bag's receive times (transport jitter)"
    )
    return received, "receive"


def _align_wrench(
    stamps: np.ndarray, w_stamps: np.ndarray, wrench: dict[str, Any], topic: str, where: str
) -> tuple[np.ndarray, np.ndarray, str]:
    order = np.argsort(w_stamps, kind="stable")
    ws, values = w_stamps[order], wrench["values"][order]
    inside = (stamps >= ws[0]) & (stamps <= ws[-1])
    if not inside.any():
        raise DataError(f"{where}: the wrench topic {topic} does not overlap the joint samples in time")
    t0 = stamps[0]
    x = (stamps[inside] - t0).astype(float)
    xp = (ws - t0).astype(float)
    out = np.column_stack([np.interp(x, xp, values[:, k]) for k in range(6)])
    rate = (ws.size - 1) / max((ws[-1] - ws[0]) * 1e-9, 1e-300)
    note = (
        f"{where}: wrist wrench from {topic} ({WRENCH_TYPE}, {ws.size:,} messages, {rate:.4g} Hz, frame "
        f"{', '.join(map(repr, wrench['frames']))}) interpolated linearly at the joint samples' times"
        + (
            f"; dropped {int((~inside).sum()):,} joint samples outside the wrench's time span"
            if not inside.all()
            else ""
        )
    )
    return inside, out, note
