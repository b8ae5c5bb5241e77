"""ROS 2 bags read as robot logs: JointState messages decoded per second, bulk against per message.

Two bags of 100,000 7-joint ``sensor_msgs/msg/JointState`` messages (100 s at 1 kHz), one MCAP and one
rosbag2 sqlite3, written with rosbags' own writer; and a 60 s bag of the arm's JointState, a gripper's
messages on the same topic (every 10th sample) and a WrenchStamped topic, in both storages. Timed in the
same process, the best of a few runs:

* **bulk**: the topic read as ``read_bag`` reads it (``reflexarm.logs.bags``: rosbags reads the
  container, numpy decodes the messages of each CDR layout together);
* **per message**: the reference path (``bulk=False``): rosbags' reader yields each message and
  deserializes it, as every reader did before (issue 19: ~48k messages/s for one topic);
* **bulk, bag already open**: the same without rosbags' opening of the bag (metadata, connections, message
  counts), which both paths pay once per bag;
* **rosbags iteration only**: ``AnyReader.messages`` yielding the raw bytes and nothing else, the
  ceiling of any decoder that goes through rosbags' per-message iterator;
* **read_bag**: the whole log (arm joints mapped by name, stamps, the wrench interpolated).

Issue 19's target: >= 500k JointState messages/s from MCAP and sqlite3. Run with ``make bench`` or
``python bench/bench_bags.py``.
"""

from __future__ import annotations

import os
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from reflexarm.logs._cdr import JOINT_STATE
from reflexarm.logs.bags import _open, _read_topic, read_bag

N_MESSAGES = 100_000
MIXED_SECONDS = 60
REPEATS = 3
TARGET = 500_000
EPOCH_NS = 1_795_435_200_000_000_000
ARM = tuple(f"panda_joint{k}" for k in range(1, 8))


def write_bag(path: Path, storage: str, n: int, *, gripper: bool = False, wrench: bool = False) -> int:
    """``n`` arm JointState messages at 1 kHz (and the gripper's, the wrench); the arm topic's message count."""
    store = get_typestore(Stores.ROS2_HUMBLE)
    T = store.types
    JS, WS = "sensor_msgs/msg/JointState", "geometry_msgs/msg/WrenchStamped"
    rng = np.random.default_rng(0)
    values = rng.normal(size=(n, 3, 7))

    def header(s: int, frame: str = "") -> object:
        return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=s // 10**9, nanosec=s % 10**9),
                                        frame_id=frame)  # fmt: skip

    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    count = 0
    with Writer(path, version=9, storage_plugin=plugin) as w:
        arm = w.add_connection("/joint_states", JS, typestore=store)
        ft = w.add_connection("/ft", WS, typestore=store) if wrench else None
        for k in range(n):
            s = EPOCH_NS + k * 1_000_000
            if gripper and k % 10 == 0:
                g = T[JS](header=header(s), name=["finger_joint1", "finger_joint2"], position=np.array([0.04, 0.04]),
                          velocity=np.zeros(0), effort=np.zeros(0))  # fmt: skip
                w.write(arm, s + 100_000, store.serialize_cdr(g, JS))
                count += 1
            m = T[JS](header=header(s), name=list(ARM), position=values[k, 0], velocity=values[k, 1],
                      effort=values[k, 2])  # fmt: skip
            w.write(arm, s + 300_000, store.serialize_cdr(m, JS))
            count += 1
            if ft is not None:
                V = T["geometry_msgs/msg/Vector3"]
                f = values[k, 0, :6]
                msg = T[WS](header=header(s, "ft_sensor"), wrench=T["geometry_msgs/msg/Wrench"](
                    force=V(x=f[0], y=f[1], z=f[2]), torque=V(x=f[3], y=f[4], z=f[5])))  # fmt: skip
                w.write(ft, s + 200_000, store.serialize_cdr(msg, WS))
    return count


def best(f: Callable[[], object], repeats: int = REPEATS) -> tuple[float, float]:
    """The shortest wall time and the shortest CPU time of this process over ``repeats`` runs [s]."""
    wall, cpu = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        f()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return min(wall), min(cpu)


def rates(n: int, times: tuple[float, float]) -> tuple[float, float]:
    return n / times[0], n / times[1]


def text(rate: tuple[float, float]) -> str:
    return f"{rate[0] / 1e3:5.0f}k/s ({rate[1] / 1e3:5.0f}k/s CPU)"


def topic(p: Path, bulk: bool) -> object:
    with _open(p) as reader:
        return _read_topic(reader, "/joint_states", JOINT_STATE, p.name, bulk)


def iterate(p: Path) -> int:
    with AnyReader([p]) as reader:
        conns = [c for c in reader.connections if c.topic == "/joint_states"]
        return sum(1 for _ in reader.messages(connections=conns))


def bench_storage(root: Path, storage: str) -> dict[str, object]:
    p = root / f"arm_{storage}"
    n = write_bag(p, storage, N_MESSAGES)
    topic(p, True)  # warm: imports, type generation
    bulk = rates(n, best(lambda: topic(p, True)))
    per_message = rates(n, best(lambda: topic(p, False), repeats=1))
    with _open(p) as reader:  # the messages alone, the bag opened once (rosbags' open: metadata, counts)
        opened = rates(n, best(lambda: _read_topic(reader, "/joint_states", JOINT_STATE, p.name, True)))
    raw = rates(n, best(lambda: iterate(p), repeats=2))
    log = rates(n, best(lambda: read_bag(p, joint_names=ARM, n_joints=None, joint_topic=None, wrench_topic=None)))
    met = "met" if bulk[0] >= TARGET else ("met in CPU time only" if bulk[1] >= TARGET else "NOT met")
    print(f"{storage:8s} {n:,} JointState messages (wall, and per CPU-second of this process):")
    print(f"    bulk                    {text(bulk)}   target {TARGET // 1000}k/s: {met}")
    print(f"    per message (reference) {text(per_message)}   bulk / per message: {bulk[0] / per_message[0]:.1f}x "
          f"({bulk[1] / per_message[1]:.1f}x CPU)")  # fmt: skip
    print(f"    bulk, bag already open  {text(opened)}   (without rosbags' open: metadata, message counts)")
    print(f"    rosbags iteration only  {text(raw)}   (the ceiling through rosbags' per-message iterator)")
    print(f"    read_bag (whole log)    {text(log)}")
    return {"messages": n, "bulk_per_s": bulk, "per_message_per_s": per_message, "ratio": bulk[0] / per_message[0],
            "bulk_opened_per_s": opened, "rosbags_iteration_per_s": raw, "read_bag_per_s": log}  # fmt: skip


def bench_mixed(root: Path, storage: str) -> dict[str, object]:
    p = root / f"mixed_{storage}"
    n = write_bag(p, storage, MIXED_SECONDS * 1000, gripper=True, wrench=True)
    n_all = n + MIXED_SECONDS * 1000  # the arm topic (arm + gripper messages) and the wrench topic

    def read(bulk: bool) -> None:
        read_bag(p, joint_names=ARM, n_joints=None, joint_topic="/joint_states", wrench_topic="/ft", bulk=bulk)

    read(True)
    bulk = rates(n_all, best(lambda: read(True)))
    per_message = rates(n_all, best(lambda: read(False), repeats=1))
    print(f"{storage:8s} {MIXED_SECONDS} s arm + gripper + wrench ({n_all:,} messages) through read_bag: bulk "
          f"{text(bulk)}, per message {text(per_message)}: {bulk[0] / per_message[0]:.1f}x")  # fmt: skip
    return {"messages": n_all, "bulk_per_s": bulk, "per_message_per_s": per_message, "ratio": bulk[0] / per_message[0]}


def main() -> dict[str, object]:
    load = os.getloadavg()[0]
    print(f"load average {load:.1f} on {os.cpu_count()} cores (wall rates fall with it; CPU rates much less)")
    results: dict[str, object] = {"load_average": load}
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        for storage in ("mcap", "sqlite3"):
            results[storage] = bench_storage(root, storage)
        for storage in ("mcap", "sqlite3"):
            results[f"mixed_{storage}"] = bench_mixed(root, storage)
    return results


if __name__ == "__main__":
    main()
