"""stream_fast: long runs (free motion, soaks) in the compiled loop, statistics in C++, the trace in blocks.

:func:`~reflexarm.sim.stream_closed_loop` runs the Python loop block by block. :func:`stream_compiled` runs the
same ticks in C++ (:mod:`reflexarm.sim.compiled_loop`'s ``ClosedLoop``): per block of ``block_size`` ticks, the
reference is sampled and the noise drawn in Python as whole arrays, C++ steps the ticks into the block
buffers and folds them into its running statistics (``reflexarm::RunStatistics``: max |residual| per joint and
when, alarms and separate detections, the |residual| histogram, ticks per mode and with a fault), and the
block is appended to the Parquet trace, every ``trace_every``-th tick or not at all: no Python call per tick.
The statistics equal those the Python loop computes on the same ticks (tests/test_long_runs.py).

:func:`stream_fast` uses the compiled loop when it can (:func:`stream_reason` is None: a reflexarm Controller,
no scene, no callback) and :func:`~reflexarm.sim.stream_closed_loop` otherwise. Stills (the CLI's run
observers) are kept in C++ as in :func:`~reflexarm.sim.run_fast`; a video takes the Python loop.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from reflexarm._progress import show_progress
from reflexarm.errors import ConfigError, SimulationError
from reflexarm.sim._compiled_inputs import _draw_noise, _forces, _sample_reference, _tick_times
from reflexarm.sim._trace_rows import check_every
from reflexarm.sim.compiled_loop import _MODES, _STILL_SPEC, _make_loop, _modules, compiled_reason
from reflexarm.sim.plant import Plant
from reflexarm.sim.recording import _MAX_FAULT_KINDS, RESIDUAL_BIN_NM, RESIDUAL_RANGE_NM, RunStatistics, _Recorder
from reflexarm.sim.run_observers import (
    CompiledStill,
    accepts_compiled,
    make_observers,
    observers_active,
    using_observers,
)
from reflexarm.sim.runner import (
    DEFAULT_BLOCK_SIZE,
    Callback,
    ControllerLike,
    TrajectoryLike,
    _check,
    stream_closed_loop,
)
from reflexarm.sim.trace import TraceWriter

__all__ = ["stream_compiled", "stream_fast", "stream_reason"]


def stream_reason(
    plant: Plant, controller: Any, *, callback: Callback | None = None, reset_controller: bool = True
) -> str | None:
    """Why this streamed run cannot use the compiled loop (a sentence), or None if it can."""
    if callback is not None:
        return "a callback is called after every tick (Python loop)"
    reason = compiled_reason(plant, controller, reset_controller=reset_controller)
    if reason is not None:
        return reason
    if plant.scenes:
        return f"the plant has scenes ({', '.join(type(s).__name__ for s in plant.scenes)}); run_fast plays them"
    return None


def stream_fast(
    plant: Plant,
    controller: ControllerLike,
    trajectory: TrajectoryLike,
    duration: float,
    *,
    path: str | os.PathLike[str] | None = None,
    block_size: int = DEFAULT_BLOCK_SIZE,
    trace_every: int = 1,
    progress: bool = False,
    callback: Callback | None = None,
    reset_controller: bool = True,
) -> RunStatistics:
    """:func:`stream_compiled` when :func:`stream_reason` finds nothing against it, else
    :func:`~reflexarm.sim.stream_closed_loop` (same arguments and :class:`RunStatistics`; ``stats.loop`` says
    which ran). Active run observers that accept a compiled run's recorded states (stills) get them after it;
    any other (a video) takes the Python loop."""
    every = check_every(trace_every)
    args = (plant, controller, trajectory, duration)
    kw: dict[str, Any] = dict(path=path, block_size=block_size, trace_every=every, progress=progress)
    if stream_reason(plant, controller, callback=callback, reset_controller=reset_controller) is None:
        if not observers_active():
            return stream_compiled(*args, **kw)
        observers = make_observers(plant)  # once per run, whichever loop runs it
        if all(accepts_compiled(o) for o in observers):

            def hand_over(record: CompiledStill) -> None:
                for o in observers:
                    o.take_compiled(plant, record)

            return _stream(*args, **kw, still=hand_over)
        with using_observers(plant, observers):  # a video: frames rendered every tick in Python
            stats = stream_closed_loop(*args, **kw)
    else:
        stats = stream_closed_loop(*args, **kw, callback=callback, reset_controller=reset_controller)
    stats.loop = "python"
    return stats


def stream_compiled(
    plant: Plant,
    controller: ControllerLike,
    trajectory: TrajectoryLike,
    duration: float,
    *,
    path: str | os.PathLike[str] | None = None,
    block_size: int = DEFAULT_BLOCK_SIZE,
    trace_every: int = 1,
    progress: bool = False,
) -> RunStatistics:
    """:func:`~reflexarm.sim.stream_closed_loop` (same ticks, statistics and trace file) as compiled code.

    Args:
        path: write the trace here (``.parquet``, one row group per block); None: statistics only.
        block_size: ticks per block (the buffers' rows; the memory does not grow with ``duration``).
        trace_every: write the ticks whose index is a multiple of this (1: every tick).
        plant, controller, trajectory, duration, progress: as in :func:`~reflexarm.sim.run_closed_loop`.

    Raises:
        ConfigError: this run cannot be compiled (:func:`stream_reason` says why), or a bad argument.
        SimulationError: the plant diverged (the statistics of the ticks so far are attached as
            ``.statistics``, with ``error`` set, and the file holds them), or the plant is in use.
    """
    return _stream(
        plant, controller, trajectory, duration, path=path, block_size=block_size, trace_every=trace_every,
        progress=progress, still=None,
    )  # fmt: skip


def _stream(
    plant: Plant,
    controller: ControllerLike,
    trajectory: TrajectoryLike,
    duration: float,
    *,
    path: str | os.PathLike[str] | None,
    block_size: int,
    trace_every: int,
    progress: bool,
    still: Callable[[CompiledStill], None] | None,
) -> RunStatistics:
    N, meta = _check(plant, controller, trajectory, duration)
    every = check_every(trace_every)
    if isinstance(block_size, bool) or not isinstance(block_size, int) or block_size < 1:
        raise ConfigError(f"block_size must be a positive number of ticks; got {block_size!r}")
    reason = stream_reason(plant, controller)
    if reason is not None:
        raise ConfigError(f"this run cannot use the compiled loop: {reason}")
    mods = _modules()
    assert not isinstance(mods, str)
    with plant.in_use("a compiled streamed run"):  # C++ steps the plant's MuJoCo data through raw pointers
        run = _BlockRun(plant, controller, mods, min(block_size, N), meta, path, every, still is not None)
        try:
            run.run(trajectory, N, progress)
        except BaseException as e:
            run.stats.error = f"{type(e).__name__}: {e}"
            e.statistics = run.stats  # type: ignore[attr-defined]
            raise
        finally:
            run.finish(still)
    return run.stats


class _BlockRun:
    """The compiled loop on one plant, block by block: buffers of ``B`` rows reused, statistics in C++."""

    def __init__(
        self,
        plant: Plant,
        controller: Any,
        mods: tuple[ModuleType, ModuleType],
        B: int,
        meta: dict[str, Any],
        path: str | os.PathLike[str] | None,
        every: int,
        keep_still: bool,
        log_rows: int = 0,
    ) -> None:
        self.core, cl = mods
        self.plant, self.meta, self.every, self.B = plant, meta, every, B
        controller.reset()  # the switches to configure from are those after a reset
        self.loop = loop = _make_loop(plant, controller, self.core, cl)
        if keep_still:
            loop.keep_still(_STILL_SPEC)
        n = plant.n
        self.rec = _Recorder(B, n)
        self.ddq_d = np.zeros((B, n))
        self.mode, self.code, self.info = np.zeros(B, np.int32), np.zeros(B, np.int32), np.zeros((B, 5))
        bins = int(round(RESIDUAL_RANGE_NM / RESIDUAL_BIN_NM)) + 1
        self.cstats = cl.RunStatistics(n, RESIDUAL_BIN_NM, bins, len(_MODES))
        self.stats = RunStatistics(n, path=None if path is None else Path(path))
        self.stats.loop = "compiled"
        self.writer = None if path is None else TraceWriter(path)
        self.meta_out = meta | {"loop": "compiled"} | ({"trace_every": every} if every > 1 else {})
        self.tick0, self.done, self.acted = plant._tick, 0, 0
        self.still_rows: dict[str, tuple[int, float, Any]] = {}  # "start"/"peak": (tick, time, Command)
        self.peak2 = 0.0
        # what the controller measured on every tick (record_measurements), copied out block by block
        n_ = plant.n
        widths = {"t": 1, "q": n_, "dq": n_, "tau_m": n_, "wrench": 6}
        self.log = {k: np.zeros((log_rows, w)) for k, w in widths.items()} if log_rows else None
        if self.log is not None:
            self.log["t"] = self.log["t"][:, 0].copy()
            self.dq_meas = np.zeros((B, n))
        loop.set_scene_data([], [], [])
        loop.set_forces(_forces(plant))  # forces the caller applied before the run stay on
        loop.set_applied_torque(np.array(plant._tau))

    def run(self, trajectory: TrajectoryLike, N: int, progress: bool) -> None:
        bar = None
        if show_progress(progress):
            from tqdm.auto import tqdm

            bar = tqdm(total=N, unit="tick", desc="simulating (compiled)", mininterval=0.5)
        try:
            while self.done < N:
                self._block(trajectory, min(self.B, N - self.done))
                if bar is not None:
                    bar.update(self.done - bar.n)
        finally:
            if bar is not None:
                bar.close()

    def _block(self, trajectory: TrajectoryLike, m: int) -> None:
        """Ticks [done, done + m) into the buffers' first m rows, folded and written."""
        plant, rec, loop = self.plant, self.rec, self.loop
        times = _tick_times(plant, m)
        _sample_reference(trajectory, times, rec.q_d[:m], rec.dq_d[:m], self.ddq_d[:m])
        noise = _draw_noise(plant, m)  # a local: the loop reads it through a raw pointer during run()
        loop.set_buffers(
            noise, rec.q_d[:m], rec.dq_d[:m], self.ddq_d[:m], rec.t[:m], rec.q[:m], rec.dq[:m], rec.q_meas[:m],
            rec.tau[:m], rec.tau_m[:m], rec.residual[:m], rec.wrench[:m], rec.tau_ext[:m], rec.f_ext_ee[:m],
            rec.collision[:m].view(np.uint8), rec.collided[:m].view(np.uint8), self.mode[:m], self.code[:m],
            self.info[:m],
        )  # fmt: skip
        if self.log is not None:
            loop.record_measured_velocity(self.dq_meas[:m])
        ran, status = loop.run(0, m)
        rec.done = ran
        if self.log is not None:
            self._copy_log(ran)
        self.acted = self.done + ran  # a failing tick is recorded and was stepped
        self._fold(ran)
        self._watch_still(ran)
        if self.writer is not None:
            self._write(ran)
        self.done += ran
        if status:
            self._sync()
            plant._fail(float(np.sum(plant.data.qvel**2)) if status == 1 else np.inf)
        if not np.array_equal(rec.t[:ran], times[:ran]):
            raise SimulationError("the compiled loop's clock differs from the sampled reference times")

    def _copy_log(self, rows: int) -> None:
        """The block's measurements (what Plant.measure returned: t, q, dq, tau_m, wrench) into the log."""
        assert self.log is not None
        k, rec = self.done, self.rec
        for key, src in (("t", rec.t), ("q", rec.q_meas), ("dq", self.dq_meas), ("tau_m", rec.tau_m),
                         ("wrench", rec.wrench)):  # fmt: skip
            self.log[key][k : k + rows] = src[:rows]

    def _fold(self, rows: int) -> None:
        """The block's rows into the C++ statistics; the fault texts of its fault rows counted by text."""
        rec = self.rec
        self.cstats.add_rows(
            rows, rec.t, rec.residual, rec.tau, rec.collision.view(np.uint8), rec.collided.view(np.uint8),
            self.mode, self.code,
        )  # fmt: skip
        faults = np.flatnonzero(self.code[:rows])
        if faults.size:
            _count_faults(self.stats, [self._fault_text(int(k)) for k in faults])

    def _fault_text(self, k: int) -> str:
        s, i, v, lo, hi = self.info[k]
        return str(self.core.describe_fault(int(self.code[k]), int(s), int(i), float(v), float(lo), float(hi)))

    def _write(self, rows: int) -> None:
        """The block's rows at ticks that are multiples of ``every`` appended to the trace file."""
        from reflexarm.sim.trace import Trace

        rec = self.rec
        first = (-self.done) % self.every
        sel = slice(first, rows, self.every)
        if first >= rows:
            return
        code = self.code[sel]
        fault = np.full(code.size, "", dtype=object)
        base = np.arange(rows)[sel]
        for j in np.flatnonzero(code):
            fault[j] = self._fault_text(int(base[j]))
        block = Trace(
            t=rec.t[sel], q=rec.q[sel], dq=rec.dq[sel], q_meas=rec.q_meas[sel], q_d=rec.q_d[sel], dq_d=rec.dq_d[sel],
            tau=rec.tau[sel], tau_m=rec.tau_m[sel], residual=rec.residual[sel], collision=rec.collision[sel],
            collided=rec.collided[sel], mode=_MODES[self.mode[sel]], fault=fault, wrench=rec.wrench[sel],
            f_ext_ee=rec.f_ext_ee[sel], tau_ext=rec.tau_ext[sel], meta=self.meta_out,
        )  # fmt: skip
        assert self.writer is not None
        self.writer.write(block)

    def _watch_still(self, rows: int) -> None:
        """The start and a new peak of the still (kept in C++) taken from this block: their tick, time, command."""
        if rows == 0:
            return
        spec, k0, _, kp, _, peak2 = self.loop.still_states()
        if not spec:
            return
        if "start" not in self.still_rows and k0 >= 0:
            self.still_rows["start"] = (self.done + int(k0), float(self.rec.t[k0]), self._command(int(k0)))
        if peak2 > self.peak2 and kp >= 0:
            self.peak2 = float(peak2)
            self.still_rows["peak"] = (self.done + int(kp), float(self.rec.t[kp]), self._command(int(kp)))

    def _command(self, k: int) -> Any:
        from reflexarm.signals import Command

        rec = self.rec
        return Command(
            tau=rec.tau[k].copy(),
            residual=rec.residual[k].copy(),
            collision=bool(rec.collision[k]),
            collided_joints=tuple(int(j) for j in np.flatnonzero(rec.collided[k])),
            mode=str(_MODES[self.mode[k]]),
            fault=self._fault_text(k) if self.code[k] else "",
            fault_code=int(self.code[k]),
        )

    def _sync(self) -> None:
        """The plant's own bookkeeping, as Plant.step keeps it."""
        self.plant._tau[:] = self.loop.applied_torque
        self.plant._tick = self.tick0 + self.acted

    def finish(self, still: Callable[[CompiledStill], None] | None) -> None:
        """Close the file, sync the plant, read the C++ statistics, hand the still over."""
        self._sync()
        if self.writer is not None:
            self.writer.close()
        _take(self.stats, self.cstats)
        if still is not None and "start" in self.still_rows:
            spec, _, start, _, peak, peak2 = self.loop.still_states()
            k0, t0, c0 = self.still_rows["start"]
            kp, tp, cp = self.still_rows.get("peak", (None, None, None))
            still(
                CompiledStill(
                    spec=int(spec), start_tick=k0, start_state=start, start_time=t0, start_command=c0,
                    peak_tick=kp, peak_state=peak if kp is not None else None, peak_time=tp, peak_command=cp,
                    peak2=float(peak2),
                )
            )  # fmt: skip


def _take(stats: RunStatistics, c: Any) -> None:
    """The C++ statistics ``c`` (``reflexarm._closed_loop.RunStatistics``) into ``stats`` (its fault texts are
    counted already)."""
    stats.ticks = int(c.ticks)
    stats.t_first, stats.t_last = float(c.t_first), float(c.t_last)
    stats.max_abs_residual, stats.t_max_abs_residual = c.max_abs_residual, c.t_max_abs_residual
    stats.max_abs_tau = c.max_abs_tau
    stats.collision_ticks, stats.collision_events = int(c.collision_ticks), int(c.collision_events)
    first = float(c.first_collision_t)
    stats.first_collision_t = None if np.isnan(first) else first
    stats._last_collision = bool(c.last_collision)
    stats.collided_ticks = c.collided_ticks
    stats.fault_ticks = int(c.fault_ticks)
    stats.modes = {str(_MODES[i]): int(v) for i, v in enumerate(c.mode_ticks.tolist()) if v}
    stats.residual_counts = c.counts


def _count_faults(stats: RunStatistics, texts: list[str]) -> None:
    """Fault texts of one block counted by text, as :meth:`RunStatistics.update` counts them."""
    kinds, number = np.unique(np.array(texts), return_counts=True)
    counts = stats.faults
    for kind, cnt in zip(kinds.tolist(), number.tolist(), strict=True):
        key = kind if (kind in counts or len(counts) < _MAX_FAULT_KINDS) else "other"
        counts[key] = counts.get(key, 0) + int(cnt)
