"""Bulk CDR decoding of ``sensor_msgs/msg/JointState`` and ``geometry_msgs/msg/WrenchStamped`` with numpy.

A message's CDR layout (where its stamp and its float64 arrays lie) is fixed once its frame id, joint
names and array lengths are known. The first message of each layout is walked in Python
(:func:`_walk_joint_state`, :func:`_walk_wrench`) and the walk is checked against ``rosbags``'
deserialization of that same message (stamp and every value bit for bit); it then serves as a template.
Messages of the same size whose every byte other than the stamp and the float64 values equals the
template's (encapsulation, frame id, names, counts, padding) are the same layout with other numbers:
they are decoded together through strided numpy views. Up to 3 trailing bytes are ignored, as rosbags
does. A message that matches no template and cannot make one is deserialized by rosbags on its own,
the reference path (``bulk=False`` takes it for every message).
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

__all__ = ["JOINT_STATE", "WRENCH", "Batch", "Kind", "RawBlock", "UndecodableMessage", "concatenate", "decode_block"]

#: At most this many layouts per topic are decoded in bulk; messages of further layouts go one by one.
MAX_TEMPLATES = 64
#: rosbags accepts up to this many bytes after a message's last field (alignment padding).
TRAILING = 3
_HEADER = 4  # the CDR encapsulation header; alignment counts from its end


class UndecodableMessage(Exception):
    """Message ``index`` (in the block's numbering) does not decode as its type; ``reason`` says why."""

    def __init__(self, index: int, reason: str) -> None:
        super().__init__(reason)
        self.index = index
        self.reason = reason


class Batch(NamedTuple):
    """Messages of one layout: ``key`` (JointState: names and the three array lengths; WrenchStamped:
    the frame id), their ``msg_index`` in the topic (int64), header ``stamp`` [ns] and float64 ``arrays``
    (JointState: position, velocity, effort, each (m, length); WrenchStamped: force and torque (m, 6))."""

    key: tuple[Any, ...]
    msg_index: np.ndarray
    stamp: np.ndarray
    arrays: tuple[np.ndarray, ...]


@dataclass(frozen=True)
class _Layout:
    key: tuple[Any, ...]
    template: np.ndarray  # the template message's bytes up to its end
    fixed: tuple[tuple[int, int], ...]  # byte ranges that must equal the template's
    fields: tuple[tuple[int, int], ...]  # (offset, count) of each float64 array
    little: bool


@dataclass(frozen=True)
class Kind:
    """A message type decoded in bulk: its name, the walk of one raw message (key, fields, end) and the
    reference values of one deserialized message (key, stamp [ns], arrays)."""

    msgtype: str
    walk: Callable[[bytes], tuple[tuple[Any, ...], list[tuple[int, int]], int]]
    values: Callable[[Any], tuple[tuple[Any, ...], int, tuple[np.ndarray, ...]]]


def _stamp(msg: Any) -> int:
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


class _Cursor:
    """Reads a CDR buffer as rosbags does (alignment from the end of the encapsulation header)."""

    def __init__(self, raw: bytes) -> None:
        self.raw = raw
        self.u32 = struct.Struct("<I" if raw[1] else ">I")
        self.pos = _HEADER + 8  # after the header stamp (sec, nanosec)

    def align(self, a: int) -> None:
        self.pos = _HEADER + ((self.pos - _HEADER + a - 1) & -a)

    def uint32(self) -> int:
        self.align(4)
        (v,) = self.u32.unpack_from(self.raw, self.pos)
        self.pos += 4
        return int(v)

    def string(self) -> str:
        n = self.uint32()
        if n < 1 or self.pos + n > len(self.raw) or self.raw[self.pos + n - 1] != 0:
            raise ValueError(f"invalid string length {n}")
        s = self.raw[self.pos : self.pos + n - 1].decode()
        self.pos += n
        return s

    def doubles(self, count: int) -> tuple[int, int]:
        if count:
            self.align(8)
        field = (self.pos, count)
        self.pos += 8 * count
        if self.pos > len(self.raw):
            raise ValueError("sequence beyond the message")
        return field


def _walk_joint_state(raw: bytes) -> tuple[tuple[Any, ...], list[tuple[int, int]], int]:
    c = _Cursor(raw)
    c.string()  # frame id
    count = c.uint32()
    if count > len(raw):
        raise ValueError(f"invalid name count {count}")
    names = tuple(c.string() for _ in range(count))
    fields = [c.doubles(c.uint32()) for _ in range(3)]
    return (names, *(n for _, n in fields)), fields, c.pos


def _joint_state_values(msg: Any) -> tuple[tuple[Any, ...], int, tuple[np.ndarray, ...]]:
    arrays = tuple(np.asarray(a, dtype=np.float64) for a in (msg.position, msg.velocity, msg.effort))
    return (tuple(msg.name), *(a.size for a in arrays)), _stamp(msg), arrays


def _walk_wrench(raw: bytes) -> tuple[tuple[Any, ...], list[tuple[int, int]], int]:
    c = _Cursor(raw)
    frame = c.string()
    field = c.doubles(6)  # force x y z, torque x y z: six float64 in a row
    return (frame,), [field], c.pos


def _wrench_values(msg: Any) -> tuple[tuple[Any, ...], int, tuple[np.ndarray, ...]]:
    f, m = msg.wrench.force, msg.wrench.torque
    values = np.array([[f.x, f.y, f.z, m.x, m.y, m.z]], dtype=np.float64)
    return (str(msg.header.frame_id),), _stamp(msg), (values,)


JOINT_STATE = Kind("sensor_msgs/msg/JointState", _walk_joint_state, _joint_state_values)
WRENCH = Kind("geometry_msgs/msg/WrenchStamped", _walk_wrench, _wrench_values)


def _decode(rows: np.ndarray, layout: _Layout) -> tuple[np.ndarray, tuple[np.ndarray, ...]]:
    """Stamps [ns] and float64 arrays of ``rows`` (m, size) uint8 (rows may be strided), all of ``layout``."""
    e = "<" if layout.little else ">"
    sec = rows[:, _HEADER : _HEADER + 4].view(f"{e}i4")[:, 0]
    nsec = rows[:, _HEADER + 4 : _HEADER + 8].view(f"{e}u4")[:, 0]
    stamp = sec.astype(np.int64) * 1_000_000_000 + nsec.astype(np.int64)
    arrays = tuple(rows[:, off : off + 8 * n].view(f"{e}f8").astype(np.float64) for off, n in layout.fields)
    return stamp, arrays


def _matches(rows: np.ndarray, layout: _Layout) -> np.ndarray:
    end = layout.template.size
    ok = np.full(rows.shape[0], 0 <= rows.shape[1] - end <= TRAILING)
    if not ok.any():
        return ok
    for a, b in layout.fixed:
        w = a + (b - a) // 8 * 8  # compared eight bytes at a time (unaligned views), the rest byte by byte
        if w > a:
            ok &= (rows[:, a:w].view("<u8") == layout.template[a:w].view("<u8")).all(axis=1)
        if w < b:
            ok &= (rows[:, w:b] == layout.template[w:b]).all(axis=1)
    return ok


def _rows(data: np.ndarray, start: np.ndarray, size: int) -> np.ndarray:
    """The (m, size) bytes of the messages at ``start``: a strided view when they are evenly spaced
    (one topic in a chunk or a table), else gathered."""
    step = int(start[1] - start[0]) if start.size > 1 else size
    if step >= size and (start.size < 3 or bool(np.all(np.diff(start) == step))):
        return np.lib.stride_tricks.as_strided(data[int(start[0]) :], (start.size, size), (step, 1), writeable=False)
    return np.lib.stride_tricks.sliding_window_view(data, size)[start]


def _template(kind: Kind, raw: bytes, msg: Any) -> _Layout | None:
    """The layout of ``raw``, if the walk finds it and it decodes ``raw`` exactly as rosbags did."""
    try:
        key, fields, end = kind.walk(raw)
    except (ValueError, struct.error, UnicodeDecodeError):
        return None
    if not 0 <= len(raw) - end <= TRAILING:
        return None
    values: list[tuple[int, int]] = [(_HEADER, _HEADER + 8)] + [(off, off + 8 * n) for off, n in fields if n]
    fixed, start = [], 0
    for a, b in sorted(values):
        if a > start:
            fixed.append((start, a))
        start = b
    if end > start:
        fixed.append((start, end))
    layout = _Layout(key, np.frombuffer(raw, np.uint8, count=end), tuple(fixed), tuple(fields), bool(raw[1]))
    try:
        ref_key, ref_stamp, ref_arrays = kind.values(msg)
    except (AttributeError, TypeError, ValueError):  # left to the one-by-one pass, which says why
        return None
    stamp, arrays = _decode(np.frombuffer(raw, np.uint8).reshape(1, -1), layout)
    same = ref_key == key and int(stamp[0]) == ref_stamp and len(arrays) == len(ref_arrays)
    same = same and all(
        a.reshape(-1).tobytes() == r.reshape(-1).tobytes() for a, r in zip(arrays, ref_arrays, strict=True)
    )
    return layout if same else None


def _deserialize(deserialize: Callable[[bytes, str], Any], kind: Kind, raw: bytes, index: int) -> Any:
    try:
        return deserialize(raw, kind.msgtype)
    except Exception as e:  # rosbags wraps its SerdeError (struct, unicode, size) in its own error types
        raise UndecodableMessage(index, str(e) or type(e).__name__) from e


class RawBlock(NamedTuple):
    """Raw messages: message k is ``data[start[k] : start[k] + size[k]]``; ``received`` [ns] bag times."""

    data: np.ndarray
    start: np.ndarray
    size: np.ndarray
    received: np.ndarray

    def raw(self, k: int) -> bytes:
        return self.data[int(self.start[k]) : int(self.start[k] + self.size[k])].tobytes()


def decode_block(
    block: RawBlock,
    first: int,
    kind: Kind,
    deserialize: Callable[[bytes, str], Any],
    templates: dict[int, list[_Layout]],
    *,
    bulk: bool = True,
) -> tuple[list[Batch], int]:
    """Decode messages ``first``, ``first + 1``, ... of ``block``: batches of one layout each, and how
    many messages were decoded in bulk. ``templates`` (by message size) carries the layouts found over
    the blocks of one topic.

    Raises:
        UndecodableMessage: a message rosbags cannot deserialize as ``kind``.
    """
    single: list[int] = [] if bulk else list(range(block.size.size))
    batches: list[Batch] = []
    n_bulk = 0
    one_size = bool(block.size.size) and bool(np.all(block.size == block.size[0]))
    for size in (block.size[:1] if one_size else np.unique(block.size)) if bulk else ():
        idx = np.arange(block.size.size) if one_size else np.flatnonzero(block.size == size)
        rows = _rows(block.data, block.start[idx], int(size))
        left = np.ones(idx.size, dtype=bool)
        known = templates.setdefault(int(size), [])
        tried = 0
        while left.any():
            if tried < len(known):
                layout = known[tried]
            else:
                r = int(np.argmax(left))
                raw = block.raw(int(idx[r]))
                try:
                    msg = deserialize(raw, kind.msgtype)
                except Exception:  # left to the one-by-one pass, which names the block's first such message
                    msg = None
                full = sum(map(len, templates.values())) >= MAX_TEMPLATES
                made = None if msg is None or full else _template(kind, raw, msg)
                if made is None:
                    single.append(int(idx[r]))
                    left[r] = False
                    continue
                layout = made
                known.append(layout)
            tried += 1
            hit = np.flatnonzero(left & _matches(rows, layout))
            if hit.size:
                left[hit] = False
                stamp, arrays = _decode(rows if hit.size == rows.shape[0] else rows[hit], layout)
                batches.append(Batch(layout.key, first + idx[hit], stamp, arrays))
                n_bulk += hit.size
    batches += _one_by_one(block, sorted(single), first, kind, deserialize)
    return batches, n_bulk


def _one_by_one(
    block: RawBlock, which: list[int], first: int, kind: Kind, deserialize: Callable[[bytes, str], Any]
) -> list[Batch]:
    """The reference path: each message deserialized by rosbags, grouped by layout key."""
    groups: dict[tuple[Any, ...], tuple[list[int], list[int], list[tuple[np.ndarray, ...]]]] = {}
    for i in which:
        msg = _deserialize(deserialize, kind, block.raw(i), first + i)
        try:
            key, stamp, arrays = kind.values(msg)
        except (AttributeError, TypeError, ValueError) as e:  # the bag's own definition of the type differs
            raise UndecodableMessage(first + i, f"not the standard {kind.msgtype} fields: {e}") from e
        index, stamps, values = groups.setdefault(key, ([], [], []))
        index.append(first + i)
        stamps.append(stamp)
        values.append(arrays)
    out = []
    for key, (index, stamps, values) in groups.items():
        arrays = tuple(np.stack([v[k].reshape(-1) for v in values]) for k in range(len(values[0])))
        out.append(Batch(key, np.asarray(index, dtype=np.int64), np.asarray(stamps, dtype=np.int64), arrays))
    return out


def concatenate(batches: list[Batch]) -> list[Batch]:
    """One batch per key, its messages in index order."""
    by_key: dict[tuple[Any, ...], list[Batch]] = {}
    for b in batches:
        by_key.setdefault(b.key, []).append(b)
    out = []
    for key, parts in by_key.items():
        index = np.concatenate([p.msg_index for p in parts])
        order = slice(None) if bool(np.all(index[1:] > index[:-1])) else np.argsort(index, kind="stable")
        stamp = np.concatenate([p.stamp for p in parts])[order]
        arrays = tuple(np.concatenate([p.arrays[k] for p in parts])[order] for k in range(len(parts[0].arrays)))
        out.append(Batch(key, index[order], stamp, arrays))
    return sorted(out, key=lambda b: int(b.msg_index[0]))
