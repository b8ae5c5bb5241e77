"""Latency of the node: from a JointState's arrival (the middleware's reception time) to the publication of
everything the tick sends (command, residual, and the event on a detecting tick) [ns, system clock]."""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["LatencyLog"]


class LatencyLog:
    """Per-tick latencies in a growing buffer (16 bytes per tick; capped at ``capacity`` ticks): from the reception
    and from the callback's start (the node's own processing)."""

    def __init__(self, capacity: int = 10_000_000) -> None:
        self._ticks = np.zeros((65536, 2), dtype=np.int64)
        self._count = 0
        self.capacity = capacity
        self.events: list[int] = []

    def add(self, received_ns: int, started_ns: int, published_ns: int, event: bool) -> None:
        """One tick: the JointState's reception, the tick's start and the end of its publications [ns];
        ``event``: it sent one."""
        dt = published_ns - received_ns
        if event:
            self.events.append(dt)
        if self._count >= self._ticks.size:
            if self._count >= self.capacity:
                return
            self._ticks = np.concatenate([self._ticks, np.zeros_like(self._ticks)])
        self._ticks[self._count] = dt, published_ns - started_ns
        self._count += 1

    @property
    def ticks(self) -> np.ndarray:
        """Every tick's latency from the reception so far [ns] (a copy)."""
        return self._ticks[: self._count, 0].copy()

    @property
    def processing(self) -> np.ndarray:
        """Every tick's time from the callback's start to the end of its publications [ns] (a copy)."""
        return self._ticks[: self._count, 1].copy()

    def summary(self) -> dict[str, Any]:
        """Median, p99 and max of the ticks' and of the event ticks' latencies [ms]."""

        def stats(values: np.ndarray) -> dict[str, Any]:
            if values.size == 0:
                return {"count": 0, "median_ms": None, "p99_ms": None, "max_ms": None}
            ms = values * 1e-6
            return {"count": int(values.size), "median_ms": float(np.median(ms)),
                    "p99_ms": float(np.percentile(ms, 99)), "max_ms": float(ms.max())}  # fmt: skip

        return {"ticks": stats(self.ticks), "events": stats(np.asarray(self.events, dtype=np.int64)),
                "processing": stats(self.processing)}  # fmt: skip
