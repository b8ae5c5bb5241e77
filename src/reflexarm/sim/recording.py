"""What a closed-loop run keeps: a block buffer of the recorded rows, and running statistics.

:func:`~reflexarm.sim.run_closed_loop` records every tick into one buffer sized for the whole run.
:func:`~reflexarm.sim.stream_closed_loop` reuses a buffer of ``block_size`` rows: each full block is
handed to :class:`RunStatistics` (and to a :class:`~reflexarm.sim.TraceWriter` when a file is asked
for) and overwritten, so an hour of free motion runs in the memory of one block.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from reflexarm.sim.trace import Trace

__all__ = ["RESIDUAL_BIN_NM", "RESIDUAL_RANGE_NM", "RunStatistics"]

#: Width of the |residual| histogram bins [Nm]: fine against the paper's 11 Nm threshold.
RESIDUAL_BIN_NM = 0.1
#: Upper end of the binned |residual| range [Nm]; larger values fall into one overflow bin.
RESIDUAL_RANGE_NM = 100.0
#: At most this many distinct fault texts are counted by name (the rest under "other").
_MAX_FAULT_KINDS = 32


class _Recorder:
    """Preallocated arrays for ``size`` ticks (one block); ``done`` rows are complete."""

    def __init__(self, size: int, n: int) -> None:
        self.size = size
        self.t = np.zeros(size)
        self.q, self.dq, self.q_meas = np.zeros((size, n)), np.zeros((size, n)), np.zeros((size, n))
        self.q_d, self.dq_d = np.zeros((size, n)), np.zeros((size, n))
        self.tau, self.tau_m, self.residual = np.zeros((size, n)), np.zeros((size, n)), np.zeros((size, n))
        self.tau_ext = np.zeros((size, n))
        self.collision = np.zeros(size, dtype=bool)
        self.collided = np.zeros((size, n), dtype=bool)
        self.mode: list[str] = []
        self.fault: list[str] = []
        self.wrench = np.zeros((size, 6))
        self.f_ext_ee = np.zeros((size, 3))
        self.extras: dict[str, np.ndarray] = {}
        self.done = 0

    def put_extras(self, k: int, values: dict[str, np.ndarray]) -> None:
        for key, value in values.items():
            arr = self.extras.get(key)
            if arr is None:
                v = np.asarray(value)
                arr = self.extras[key] = np.zeros((self.size, *v.shape), dtype=v.dtype)
            arr[k] = value

    def trace(self, meta: dict[str, Any], *, copy: bool = True) -> Trace:
        """The ``done`` rows as a Trace (``copy=False``: views of the buffer, valid until it is reused)."""
        d = self.done

        def take(a: np.ndarray) -> np.ndarray:
            return a[:d].copy() if copy else a[:d]

        return Trace(
            t=take(self.t),
            q=take(self.q),
            dq=take(self.dq),
            q_meas=take(self.q_meas),
            q_d=take(self.q_d),
            dq_d=take(self.dq_d),
            tau=take(self.tau),
            tau_m=take(self.tau_m),
            residual=take(self.residual),
            collision=take(self.collision),
            collided=take(self.collided),
            mode=np.array(self.mode[:d], dtype=str),
            fault=np.array(self.fault[:d], dtype=str),
            wrench=take(self.wrench),
            f_ext_ee=take(self.f_ext_ee),
            tau_ext=take(self.tau_ext),
            extras={k: take(v) for k, v in self.extras.items()},
            meta=meta,
        )

    def clear(self) -> None:
        """Start the next block (arrays are reused; the mode/fault lists are emptied in place)."""
        self.mode.clear()
        self.fault.clear()
        self.collided[:] = False
        self.done = 0


@dataclass
class RunStatistics:
    """Running statistics of a closed-loop run, updated block by block (memory independent of its length).

    Attributes:
        n: joints.
        ticks: ticks recorded; t_first, t_last: their first and last time [s].
        max_abs_residual: max |tau_eps_hat| per joint [Nm]; t_max_abs_residual: when [s].
        max_abs_tau: max |commanded torque| per joint [Nm].
        collision_ticks: ticks with the collision flag set; collision_events: rising edges of the flag
            (separate detections); first_collision_t: time of the first one [s] or None.
        collided_ticks: per joint, ticks on which that joint's residual crossed the threshold.
        fault_ticks: ticks with a non-empty fault; faults: ticks per fault text.
        modes: ticks per controller mode.
        residual_edges: bin edges of |residual| [Nm] (bins + 1; the last bin is [RESIDUAL_RANGE_NM, inf)).
        residual_counts: (n, bins) ticks per bin per joint, for tuning the threshold afterwards
            (:meth:`ticks_above`).
        path: the streamed trace file, if one was written.
        error: the exception that ended the run early, if any (``"Type: message"``).
        loop: which loop ran: "python" or "compiled" (:func:`~reflexarm.sim.stream_fast`).
    """

    n: int
    ticks: int = 0
    t_first: float = float("nan")
    t_last: float = float("nan")
    max_abs_residual: np.ndarray = field(default_factory=lambda: np.zeros(0))
    t_max_abs_residual: np.ndarray = field(default_factory=lambda: np.zeros(0))
    max_abs_tau: np.ndarray = field(default_factory=lambda: np.zeros(0))
    collision_ticks: int = 0
    collision_events: int = 0
    first_collision_t: float | None = None
    collided_ticks: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    fault_ticks: int = 0
    faults: dict[str, int] = field(default_factory=dict)
    modes: dict[str, int] = field(default_factory=dict)
    residual_edges: np.ndarray = field(default_factory=lambda: np.zeros(0))
    residual_counts: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), dtype=np.int64))
    path: Path | None = None
    error: str | None = None
    loop: str = "python"
    _last_collision: bool = field(default=False, repr=False)

    def __post_init__(self) -> None:
        n = self.n
        if self.max_abs_residual.size == 0:
            self.max_abs_residual = np.zeros(n)
            self.t_max_abs_residual = np.full(n, np.nan)
            self.max_abs_tau = np.zeros(n)
            self.collided_ticks = np.zeros(n, dtype=np.int64)
            bins = int(round(RESIDUAL_RANGE_NM / RESIDUAL_BIN_NM))
            self.residual_edges = np.r_[np.linspace(0.0, RESIDUAL_RANGE_NM, bins + 1), np.inf]
            self.residual_counts = np.zeros((n, bins + 1), dtype=np.int64)

    @property
    def duration(self) -> float:
        """t_last - t_first, the recorded span [s]."""
        return float(self.t_last - self.t_first) if self.ticks else 0.0

    def update(self, block: Trace) -> None:
        """Fold one block of rows (in time order, after the previous block) into the statistics."""
        m = len(block)
        if m == 0:
            return
        if self.ticks == 0:
            self.t_first = float(block.t[0])
        self.t_last = float(block.t[-1])
        self.ticks += m
        r = np.abs(block.residual)
        k = np.argmax(r, axis=0)
        peak = r[k, np.arange(self.n)]
        newer = peak > self.max_abs_residual
        self.max_abs_residual = np.where(newer, peak, self.max_abs_residual)
        self.t_max_abs_residual = np.where(newer, block.t[k], self.t_max_abs_residual)
        self.max_abs_tau = np.maximum(self.max_abs_tau, np.abs(block.tau).max(axis=0))
        c = block.collision
        self.collision_ticks += int(c.sum())
        rising = c & ~np.r_[self._last_collision, c[:-1]]
        self.collision_events += int(rising.sum())
        if self.first_collision_t is None and c.any():
            self.first_collision_t = float(block.t[int(np.argmax(c))])
        self._last_collision = bool(c[-1])
        self.collided_ticks += block.collided.sum(axis=0)
        bins = self.residual_counts.shape[1]
        scaled = np.nan_to_num(r / RESIDUAL_BIN_NM, nan=bins - 1, posinf=bins - 1)  # NaN/inf: the overflow bin
        idx = np.clip(scaled, 0, bins - 1).astype(np.int64)
        for j in range(self.n):
            self.residual_counts[j] += np.bincount(idx[:, j], minlength=bins)
        for name, counts in (("modes", self.modes), ("faults", self.faults)):
            values = block.mode if name == "modes" else block.fault[block.fault != ""]
            if name == "faults":
                self.fault_ticks += int(values.size)
            kinds, number = np.unique(values, return_counts=True)
            for kind, cnt in zip(kinds.tolist(), number.tolist(), strict=True):
                key = kind if (kind in counts or len(counts) < _MAX_FAULT_KINDS) else "other"
                counts[key] = counts.get(key, 0) + int(cnt)

    def ticks_above(self, threshold: float) -> np.ndarray:
        """Per joint, ticks with |residual| >= ``threshold`` [Nm] (to the histogram's resolution: counts
        whole bins from the one containing ``threshold``)."""
        first = int(np.searchsorted(self.residual_edges, threshold, side="right")) - 1
        return np.asarray(self.residual_counts[:, max(first, 0) :].sum(axis=1))

    def to_dict(self, *, histogram: bool = True) -> dict[str, object]:
        """JSON-ready summary; ``histogram``: with the |residual| histogram (lower bin edges and per-joint
        counts, trailing empty bins cut)."""
        used = int(np.max(np.flatnonzero(self.residual_counts.any(axis=0)), initial=-1)) + 1
        out: dict[str, object] = {
            "ticks": self.ticks,
            "t_first_s": self.t_first,
            "t_last_s": self.t_last,
            "max_abs_residual_Nm": self.max_abs_residual.tolist(),
            "t_max_abs_residual_s": self.t_max_abs_residual.tolist(),
            "max_abs_tau_Nm": self.max_abs_tau.tolist(),
            "collision_ticks": self.collision_ticks,
            "collision_events": self.collision_events,
            "first_collision_s": self.first_collision_t,
            "collided_ticks": self.collided_ticks.tolist(),
            "fault_ticks": self.fault_ticks,
            "faults": dict(self.faults),
            "modes": dict(self.modes),
            "path": None if self.path is None else str(self.path),
            "error": self.error,
        }
        if histogram:
            out["residual_histogram"] = {
                "bin_Nm": RESIDUAL_BIN_NM,
                "lower_edges_Nm": self.residual_edges[:used].tolist(),
                "counts": self.residual_counts[:, :used].tolist(),
                "note": f"ticks per joint with |residual| in [edge, edge + bin); the last bin at {RESIDUAL_RANGE_NM:g} "
                "Nm holds everything above",
            }
        return out
