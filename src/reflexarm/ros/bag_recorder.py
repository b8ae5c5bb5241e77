"""Recording what the node hears into a rosbag2 bag (the rosbags writer), off the callback's thread.

The callback hands over the message's CDR bytes (``rclpy.serialization.serialize_message``) and the reception
time; a writer thread appends them. ``reflexarm detect`` and the log readers (:mod:`reflexarm.logs.bags`) read
such a bag back.
"""

from __future__ import annotations

import queue
import threading
from pathlib import Path

from reflexarm.errors import ConfigError

__all__ = ["BagRecorder"]


class BagRecorder:
    """A rosbag2 bag (sqlite3, version 9) at ``path`` (a folder that must not exist yet) fed from any thread.

    Args:
        path: the bag's folder.
        topics: ``{topic: message type}`` ("sensor_msgs/msg/JointState", ...), one connection each.
    """

    def __init__(self, path: str | Path, topics: dict[str, str]) -> None:
        self.path = Path(path)
        if self.path.exists():
            raise ConfigError(f"record_bag: {str(self.path)!r} exists already; name a new folder")
        self.topics = dict(topics)
        self._queue: queue.SimpleQueue[tuple[str, bytes, int] | None] = queue.SimpleQueue()
        self.count = 0
        self.error = ""
        self._ready = threading.Event()
        # the writer lives in its thread from open to close (its SQLite connection belongs to one thread)
        self._thread = threading.Thread(target=self._run, name="bag-writer", daemon=True)
        self._thread.start()
        self._ready.wait()
        if self.error:
            raise ConfigError(f"record_bag: cannot write a bag at {str(self.path)!r}: {self.error}")

    def put(self, topic: str, data: bytes, stamp_ns: int) -> None:
        """Queue one serialized message of ``topic`` received at ``stamp_ns`` [ns since the epoch]."""
        self._queue.put((topic, data, stamp_ns))

    def _run(self) -> None:
        from rosbags.rosbag2 import Writer
        from rosbags.typesys import Stores, get_typestore

        try:
            store = get_typestore(Stores.ROS2_JAZZY)
            writer = Writer(self.path, version=9)
            writer.open()
            connections = {t: writer.add_connection(t, m, typestore=store) for t, m in self.topics.items()}
        except Exception as e:  # noqa: BLE001 - raised as a ConfigError by the constructor
            self.error = f"{type(e).__name__}: {e}"
            self._ready.set()
            return
        self._ready.set()
        try:
            while (item := self._queue.get()) is not None:
                topic, data, stamp = item
                try:
                    writer.write(connections[topic], stamp, data)
                    self.count += 1
                except Exception as e:  # noqa: BLE001 - reported in the summary, never a crash of the node
                    self.error = f"{type(e).__name__}: {e}"
        finally:
            writer.close()

    def close(self) -> None:
        """Write what is queued and close the bag."""
        if self._thread.is_alive():
            self._queue.put(None)
            self._thread.join()
