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
        from rosbags.rosbag2 import Writer
        from rosbags.typesys import Stores, get_typestore

        self.path = Path(path)
        if self.path.exists():
            raise ConfigError(f"record_bag: {str(self.path)!r} exists already; name a new folder")
        store = get_typestore(Stores.ROS2_JAZZY)
        self._writer = Writer(self.path, version=9)
        self._writer.open()
        self._connections = {t: self._writer.add_connection(t, m, typestore=store) for t, m in topics.items()}
        self._queue: queue.SimpleQueue[tuple[str, bytes, int] | None] = queue.SimpleQueue()
        self.count = 0
        self.error = ""
        self._thread = threading.Thread(target=self._run, name="bag-writer", daemon=True)
        self._thread.start()

    def put(self, topic: str, data: bytes, stamp_ns: int) -> None:
        """Queue one serialized message of ``topic`` received at ``stamp_ns`` [ns since the epoch]."""
        self._queue.put((topic, data, stamp_ns))

    def _run(self) -> None:
        while True:
            item = self._queue.get()
            if item is None:
                return
            topic, data, stamp = item
            try:
                self._writer.write(self._connections[topic], stamp, data)
                self.count += 1
            except Exception as e:  # noqa: BLE001 - reported in the node's diagnostics, never a crash
                self.error = f"{type(e).__name__}: {e}"

    def close(self) -> None:
        """Write what is queued and close the bag."""
        self._queue.put(None)
        self._thread.join()
        self._writer.close()
