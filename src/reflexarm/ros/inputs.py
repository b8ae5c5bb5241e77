"""The node's edge: a JointState mapped onto the robot's joints by name, and stamps checked for jumps.

Plain Python on duck-typed messages (anything with ``name``, ``position``, ``velocity``, ``effort`` and
``header.stamp.sec/nanosec``), so the checks are tested without DDS. Every problem is returned as a fault text
that names the topic, what arrived and what was expected; the node turns it into the safe command and a
diagnostic. Values themselves (NaN, beyond the plausibility bounds) are the controller's contract to check.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

__all__ = ["JointStateReader", "StampClock", "stamp_ns"]


def stamp_ns(stamp: Any) -> int:
    """A ``builtin_interfaces/Time`` as integer nanoseconds."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


class JointStateReader:
    """Maps ``sensor_msgs/JointState`` onto the robot's joint order by ``name`` (the order a publisher uses may
    differ from the model's and change between messages; extra joints, e.g. a gripper's, are ignored).

    Args:
        joint_names: the robot's joints, model order.
        topic: the topic's name, for the fault texts.
        fields: the arrays read, each needed for every joint.
    """

    def __init__(
        self, joint_names: Sequence[str], topic: str, fields: tuple[str, ...] = ("position", "velocity", "effort")
    ) -> None:
        self.fields = fields
        self.joint_names = tuple(joint_names)
        self.n = len(self.joint_names)
        self.topic = topic
        self._cache: tuple[tuple[str, ...], np.ndarray | None, str] = ((), None, "")

    def _index(self, names: Sequence[str]) -> tuple[np.ndarray | None, str]:
        key = tuple(names)
        if key == self._cache[0]:
            return self._cache[1], self._cache[2]
        where = {name: i for i, name in enumerate(key)}
        missing = [j for j in self.joint_names if j not in where]
        if missing or len(where) != len(key):
            extra = sorted(set(key) - set(self.joint_names))
            dupes = sorted({n for n in key if key.count(n) > 1})
            fault = (
                f"JointState on {self.topic}: names do not match the robot's joints: missing {missing}"
                + (f", duplicated {dupes}" if dupes else "")
                + f"; received {list(key)}"
                + (f" (unknown {extra})" if extra else "")
                + f"; expected {list(self.joint_names)}"
            )
            index = None
        else:
            fault, index = "", np.array([where[j] for j in self.joint_names], dtype=np.intp)
        self._cache = (key, index, fault)
        return index, fault

    def read(self, msg: Any) -> list[np.ndarray] | str:
        """The fields ((q, dq, tau_m) by default) in the robot's joint order, contiguous float64; or the fault."""
        index, fault = self._index(msg.name)
        if index is None:
            return fault
        count = len(msg.name)
        out = []
        for field in self.fields:
            values = np.asarray(getattr(msg, field), dtype=np.float64)
            if values.shape != (count,):
                return (
                    f"JointState on {self.topic}: {field} has {values.size} values for {count} names "
                    f"({', '.join(self.fields)} are needed for every joint)"
                )
            out.append(values[index])
        return out


class StampClock:
    """The input's time: seconds since the first stamp heard (integer nanoseconds inside, so that a 1 kHz
    stream keeps exact periods), and the clock jumps a stamp can show.

    Args:
        max_gap: a stamp more than this past the last accepted one is a forward jump [s].
        topic: the topic, for the fault texts.
    """

    def __init__(self, max_gap: float, topic: str) -> None:
        self.max_gap_ns = int(round(max_gap * 1e9))
        self.topic = topic
        self.first_ns: int | None = None
        self.last_ns: int | None = None

    def reset(self) -> None:
        """Forget the time base: the next stamp is the first."""
        self.first_ns = self.last_ns = None

    def check(self, ns: int) -> tuple[float, str]:
        """(t [s] since the first stamp, fault text or ""). A forward jump is a fault once, after which the new
        time line is accepted; a stamp at or before the last one is left to the controller's contract (its fault
        names the stamps), except a jump back by more than ``max_gap``, reported as a clock jump."""
        if self.first_ns is None:
            self.first_ns = self.last_ns = ns
            return 0.0, ""
        t = (ns - self.first_ns) * 1e-9
        last = self.last_ns if self.last_ns is not None else ns
        gap = ns - last
        if gap > self.max_gap_ns:
            self.last_ns = ns
            return t, (
                f"clock jump on {self.topic}: stamp {gap * 1e-9:.6f} s past the last one "
                f"(more than max_stamp_gap = {self.max_gap_ns * 1e-9:g} s)"
            )
        if gap < -self.max_gap_ns:
            return t, (
                f"clock jump on {self.topic}: stamp {-gap * 1e-9:.6f} s before the last one "
                f"(a clock reset? more than max_stamp_gap = {self.max_gap_ns * 1e-9:g} s)"
            )
        if gap > 0:
            self.last_ns = ns
        return t, ""
