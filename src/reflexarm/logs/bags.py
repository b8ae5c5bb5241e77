"""ROS 2 bags (rosbag2 sqlite3 ``.db3`` and MCAP) as robot logs, read with ``rosbags`` (no ROS install).

* **Joints**: the ``sensor_msgs/msg/JointState`` topic (``joint_topic``; by default the bag's only one).
  Joints are mapped by name in every message (the order may change between messages). Messages that
  hold none of the arm's joints (e.g. a gripper's own messages) are left out with a note naming their
  joints; a message with some but not all of the arm's joints is an error. Without joint names the
  first message's order is the model's (said so). Position, velocity and effort are required.
* **Time**: the messages' header stamps (when the robot sampled), unless they are unset (zero), then the
  bag's receive times (when the recorder got the message; they carry transport jitter), said so in a
  note. Messages recorded out of stamp order are sorted by stamp (counted in a note), as long as no
  message is stamped more than :data:`MAX_LATE_PERIODS` sample periods before an earlier one: a clock
  that jumps back or runs backwards is an error naming the topic, the message and its stamp (sorting
  would interleave two stretches of motion). Equal stamps are left to the log's repairs (exact repeats
  dropped, the rest re-timed). Times are relative to the first joint sample, in seconds.
* **Wrist wrench** (optional, ``wrench_topic``: ``geometry_msgs/msg/WrenchStamped``, force [N] and
  torque [Nm] in the message's frame): interpolated linearly, per component, at the joint samples'
  times on the same clock (header stamps or receive times, as chosen for the joints). Joint samples
  outside the wrench's time span are dropped (counted in a note); the note also gives the wrench's
  rate and frame.
* **Decoding**: ``rosbags`` reads the container (:mod:`._bag_messages`); the messages are decoded in
  bulk with numpy, one CDR layout (frame id, joint names, array lengths) at a time, each layout checked
  against rosbags' own deserialization of its first message (:mod:`._cdr`); ``bulk=False`` takes every
  message from rosbags' iterator and deserializes it with rosbags (the reference). A message that does
  not decode as its type (another type's payload, a sequence length beyond the message, a zeroed or
  truncated blob) is an error naming the topic, the message's index in the topic and its bag time.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from reflexarm.errors import DataError
from reflexarm.logs._bag_messages import ChunkError, raw_blocks
from reflexarm.logs._cdr import JOINT_STATE, WRENCH, Batch, Kind, UndecodableMessage, concatenate, decode_block
from reflexarm.logs.timestamps import relative_seconds

__all__ = ["BAG_SUFFIXES", "JOINT_STATE_TYPE", "WRENCH_TYPE", "read_bag"]

#: File suffixes read as bags (a rosbag2 folder is read too).
BAG_SUFFIXES = (".db3", ".mcap")
JOINT_STATE_TYPE = "sensor_msgs/msg/JointState"
WRENCH_TYPE = "geometry_msgs/msg/WrenchStamped"


#: A message whose header stamp lies more than this many sample periods behind an earlier message's is
#: not a message that arrived late but a clock that jumped back or runs backwards: an error.
MAX_LATE_PERIODS = 10


class _Topic(NamedTuple):
    """A topic's messages decoded: batches of one layout each, every message's receive time [ns] and
    how many messages were decoded in bulk."""

    topic: str
    batches: list[Batch]
    received: np.ndarray
    n_bulk: int


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
    bulk: bool = True,
) -> tuple[dict[str, np.ndarray], list[str]]:
    """The log's arrays (``t`` [s] from the first sample, ``q``, ``dq``, ``tau``, optional ``wrench``)
    and notes saying what was read and how (see the module docstring). ``bulk=False`` reads every
    message through ``AnyReader.messages`` and deserializes it with rosbags (the reference the bulk
    reading is tested against).

    Raises:
        DataError: no or several JointState topics and none chosen, an unknown topic (the message lists
            the bag's topics and types), missing arm joints or fields, unusable stamps, a message that
            does not decode as its type, a header clock that jumps back (topic, message and stamp named).
    """
    where = p.name
    if time_unit not in (None, "ns"):
        raise DataError(f"{where}: bag time stamps are nanoseconds; got time unit {time_unit!r}")
    with _open(p) as reader:
        joint_topic, notes = _choose_topics(reader, joint_topic, wrench_topic, where)
        joints = _read_topic(reader, joint_topic, JOINT_STATE, where, bulk)
        wrench = (
            None if wrench_topic is None else _wrench_messages(_read_topic(reader, wrench_topic, WRENCH, where, bulk))
        )
    data, order_notes = _map_joints(joints, joint_names, n_joints, where)
    notes += order_notes
    header, received, index = data.pop("header"), data.pop("received"), data.pop("index")
    stamps, clock = _choose_clock(header, received, joint_topic, where, notes)
    _check_clock(stamps, index, joint_topic, clock, where)
    if np.any(np.diff(stamps) < 0):  # recorded out of order: the stamps give the sampling order
        order = np.argsort(stamps, kind="stable")
        moved = int(np.sum(order != np.arange(order.size)))
        stamps = stamps[order]
        for k in ("q", "dq", "tau"):
            data[k] = data[k][order]
        notes.append(f"{where}: {moved:,} {joint_topic} message(s) were recorded out of stamp order; sorted by stamp")
    if wrench is not None:
        w_stamps = wrench["header"] if clock == "header" else wrench["received"]
        _check_clock(w_stamps, wrench["index"], wrench_topic or "", clock, where)
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


def _choose_topics(reader: Any, joint_topic: str | None, wrench_topic: str | None, where: str) -> tuple[str, list[str]]:
    """The JointState topic (given, or the bag's only one) and notes; both topics checked."""
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
    return joint_topic, notes


def _check_clock(stamps: np.ndarray, index: np.ndarray, topic: str, clock: str, where: str) -> None:
    """Refuse a clock that jumps back or runs backwards (a message stamped more than
    :data:`MAX_LATE_PERIODS` sample periods before an earlier message): sorting by stamp would then
    interleave two stretches of motion, and no stamp says which sample came when."""
    if stamps.size < 2:
        return
    steps = np.abs(np.diff(stamps))
    steps = steps[steps > 0]
    if not steps.size:
        return
    period = float(np.median(steps))
    latest = np.maximum.accumulate(stamps)
    late = latest - stamps
    bad = np.flatnonzero(late > MAX_LATE_PERIODS * period)
    if not bad.size:
        return
    i = int(bad[0])
    j = int(np.argmax(stamps[:i] == latest[i]))
    what = "header stamp" if clock == "header" else "receive time"
    raise DataError(
        f"{where}: the {topic} {what}s go back {late[i] * 1e-9:.6g} s at message {int(index[i])} "
        f"({what} {_ns_text(int(stamps[i]))} s after {_ns_text(int(latest[i]))} s at message {int(index[j])}): "
        f"more than {MAX_LATE_PERIODS} sample periods ({MAX_LATE_PERIODS * period * 1e-9:.3g} s), so not a late "
        "message but a clock that jumped back or runs backwards; the samples' order and times are unknown",
        source=where, column=topic, row=int(index[i]), value=int(stamps[i]), expected=f">= {int(latest[i])}",
    )  # fmt: skip


def _ns_text(ns: int) -> str:
    return f"{ns // 1_000_000_000}.{ns % 1_000_000_000:09d}"


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


def _read_topic(reader: Any, topic: str, kind: Kind, where: str, bulk: bool) -> _Topic:
    """Every message of ``topic`` decoded (in bulk where the layout allows, see :mod:`._cdr`)."""
    templates: dict[int, list[Any]] = {}
    batches: list[Batch] = []
    received: list[np.ndarray] = []
    count = n_bulk = 0
    blocks = raw_blocks(reader, topic, direct=bulk)
    while True:
        try:
            block = next(blocks, None)
        except ChunkError as e:
            raise DataError(
                f"{where}: cannot read the {topic} messages of the MCAP chunk at byte {e.offset:,} (bag times "
                f"{_ns_text(e.start)} s to {_ns_text(e.end)} s): {e}",
                source=where, column=topic, row=count, value=str(e),
            ) from e  # fmt: skip
        except Exception as e:  # rosbags' container errors (truncated chunk, checksum, database)
            after = f" after message {count - 1} (bag time {_ns_text(int(received[-1][-1]))} s)" if count else ""
            raise DataError(
                f"{where}: cannot read the {topic} messages{after}: {type(e).__name__}: {e}",
                source=where, column=topic, row=count, value=str(e),
            ) from e  # fmt: skip
        if block is None:
            break
        try:
            got, n = decode_block(block, count, kind, reader.deserialize, templates, bulk=bulk)
        except UndecodableMessage as e:
            i = e.index
            raise DataError(
                f"{where}: {topic} message {i} (bag time {_ns_text(int(block.received[i - count]))} s) does not "
                f"decode as {kind.msgtype}: {e.reason}",
                source=where, column=topic, row=i, value=e.reason, expected=kind.msgtype,
            ) from e  # fmt: skip
        batches += got
        received.append(block.received)
        count += block.size.size
        n_bulk += n
    if not count:
        raise DataError(f"{where}: topic {topic} has no messages", source=where, column=topic)
    return _Topic(topic, concatenate(batches), np.concatenate(received), n_bulk)


def _map_joints(
    joints: _Topic,
    joint_names: tuple[str, ...] | None,
    n_joints: int | None,
    where: str,
) -> tuple[dict[str, np.ndarray], list[str]]:
    topic, batches = joints.topic, joints.batches
    notes: list[str] = []
    if joint_names is None:
        joint_names, note = _first_order(batches, n_joints, topic, where)
        notes.append(note)
    n = len(joint_names)
    orders: list[tuple[Batch, np.ndarray]] = []
    skipped: dict[str, int] = {}
    for b in batches:  # in the order of their first message
        names = b.key[0]
        where_is = {name: k for k, name in enumerate(names)}
        have = [j for j in joint_names if j in where_is]
        if not have:
            for name in names:
                skipped[name] = skipped.get(name, 0) + b.msg_index.size
        elif len(have) < n:
            r = int(b.msg_index[0])
            missing = [j for j in joint_names if j not in where_is]
            raise DataError(
                f"{where}: {topic} message {r} holds joints {', '.join(names)}: the arm's joint(s) "
                f"{', '.join(map(repr, missing))} missing (a message must hold all of the arm's joints or none)",
                source=where, column=topic, row=r, joint=missing[0], value=names, expected=joint_names,
            )  # fmt: skip
        else:
            orders.append((b, np.array([where_is[j] for j in joint_names])))
    if not orders:
        raise DataError(f"{where}: no {topic} message holds the arm's joints ({', '.join(joint_names)}); "
                        f"joints found: {', '.join(skipped) or 'none'}")  # fmt: skip
    _check_lengths(orders, topic, where)
    rows = np.sort(np.concatenate([b.msg_index for b, _ in orders]))
    data: dict[str, np.ndarray] = {k: np.empty((rows.size, n)) for k in ("q", "dq", "tau")}
    header = np.empty(rows.size, dtype=np.int64)
    for b, order in orders:
        at = np.searchsorted(rows, b.msg_index)
        for k, signal in enumerate(("q", "dq", "tau")):
            data[signal][at] = b.arrays[k][:, order]
        header[at] = b.stamp
    data["header"], data["received"], data["index"] = header, joints.received[rows], rows
    if len({b.key[0] for b, _ in orders}) > 1:
        notes.append(f"{where}: the joint order changes between {topic} messages; mapped by name per message")
    if skipped:
        notes.append(
            f"{where}: left out {joints.received.size - rows.size:,} {topic} message(s) holding none of the arm's "
            f"joints (joints {', '.join(skipped)}: not in the arm)"
        )
    return data, notes


def _first_order(batches: list[Batch], n_joints: int | None, topic: str, where: str) -> tuple[tuple[str, ...], str]:
    """Without joint names: the first message's order (with the robot's joint count, if known)."""
    first = batches[0].key[0]
    fitting = [b for b in batches if n_joints is None or len(b.key[0]) == n_joints]
    names = min(fitting, key=lambda b: int(b.msg_index[0])).key[0] if fitting else first
    which = "first message" if names == first else f"first message with {n_joints} joints"
    if n_joints is not None and len(names) != n_joints:
        raise DataError(
            f"{where}: the first {topic} message has {len(names)} joints ({', '.join(names)}); "
            f"the robot has {n_joints}",
            source=where, column=topic, value=len(names), expected=n_joints,
        )  # fmt: skip
    return names, f"{where}: joint order taken from the {which}: {', '.join(names)}"


def _check_lengths(orders: list[tuple[Batch, np.ndarray]], topic: str, where: str) -> None:
    """Every arm message holds one position, velocity and effort value per joint name."""
    for k, field in enumerate(("position", "velocity", "effort")):
        bad = [b for b, _ in orders if b.key[1 + k] != len(b.key[0])]
        if bad:
            b = min(bad, key=lambda b: int(b.msg_index[0]))
            r, size, names = int(b.msg_index[0]), b.key[1 + k], len(b.key[0])
            raise DataError(
                f"{where}: {topic} message {r} has {size} {field} values for {names} joints"
                + (f"; the arm's {field} is required" if size == 0 else ""),
                source=where, column=f"{topic} {field}", row=r, value=size, expected=names,
            )  # fmt: skip


def _wrench_messages(wrench: _Topic) -> dict[str, Any]:
    (b,) = concatenate([bt._replace(key=()) for bt in wrench.batches])
    return {
        "header": b.stamp,
        "received": wrench.received[b.msg_index],
        "index": b.msg_index,
        "values": b.arrays[0],
        "frames": sorted(bt.key[0] for bt in wrench.batches),
    }


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
