"""run_closed_loop: controller <-> plant at the control rate, recorded into a :class:`Trace`;
stream_closed_loop: the same loop for long runs, in bounded memory (statistics, and the trace streamed
to a Parquet file block by block if asked)."""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from reflexarm._progress import show_progress
from reflexarm.errors import ConfigError
from reflexarm.signals import Command, Measurement, Reference
from reflexarm.sim._trace_rows import check_every, every_nth
from reflexarm.sim.plant import Plant
from reflexarm.sim.recording import RunStatistics, _Recorder
from reflexarm.sim.run_observers import attach_observers
from reflexarm.sim.scene import Scene
from reflexarm.sim.trace import Trace, TraceWriter

__all__ = ["DEFAULT_BLOCK_SIZE", "ControllerLike", "TrajectoryLike", "run_closed_loop", "stream_closed_loop"]

#: Rows per block of :func:`stream_closed_loop` (10 s at 1 kHz: ~6 MB of buffers for 7 joints; large
#: enough that the per-block statistics and Parquet row groups cost nothing per tick).
DEFAULT_BLOCK_SIZE = 10_000


class ControllerLike(Protocol):
    """What :func:`run_closed_loop` needs from a controller."""

    def reset(self) -> None: ...

    def step(self, measurement: Measurement, reference: Reference) -> Command: ...


class TrajectoryLike(Protocol):
    """What :func:`run_closed_loop` needs from a trajectory (e.g. :class:`JointTrajectory`)."""

    def sample(self, t: float) -> Reference: ...


Callback = Callable[[int, Plant, Measurement, Command], "bool | None"]


def run_closed_loop(
    plant: Plant,
    controller: ControllerLike,
    trajectory: TrajectoryLike,
    duration: float,
    *,
    progress: bool = False,
    callback: Callback | None = None,
    reset_controller: bool = True,
) -> Trace:
    """Run ``controller`` on ``plant`` for ``duration`` seconds from the plant's current state.

    Each control tick k: ``m = plant.measure()``, ``r = trajectory.sample(m.t)``,
    ``cmd = controller.step(m, r)``, the row is recorded, then ``plant.step(cmd.tau)``. The plant is not
    reset (call ``plant.reset(q0)`` first); the controller is (``reset_controller=False`` keeps its state).

    Args:
        plant: the simulated arm.
        controller: any object with ``step(Measurement, Reference) -> Command`` and ``reset()``.
        trajectory: any object with ``sample(t) -> Reference``.
        duration: run length [s]; ``round(duration / plant.control_period)`` ticks are recorded.
        progress: show a tqdm progress bar.
        callback: ``callback(k, plant, measurement, command)`` after each tick's command; returning
            True stops the run (the trace then ends at that tick).
        reset_controller: call ``controller.reset()`` before the first tick.

    Returns:
        The :class:`Trace`; ``meta`` holds the plant's and controller's descriptions.

    Raises:
        Whatever the plant or controller raise mid-run (e.g. :class:`SimulationError` on divergence); the
        ticks recorded so far are attached to the exception as ``.trace`` (a valid :class:`Trace`; the
        failing tick is included when its command was computed).
    """
    N, meta = _check(plant, controller, trajectory, duration)
    callback = attach_observers(plant, callback)  # reflexarm.sim.run_observers (video, stills)
    rec = _Recorder(N, plant.n)
    try:
        with plant.in_use("a closed-loop run"):  # one run per plant (Plant.in_use)
            _loop(plant, controller, trajectory, N, rec, None, progress, callback, reset_controller)
    except BaseException as e:
        try:
            e.trace = rec.trace(meta | {"error": f"{type(e).__name__}: {e}"})  # type: ignore[attr-defined]
        except Exception:  # pragma: no cover - never mask the original error
            pass
        raise
    return rec.trace(meta | {"collision_event": _event(controller)})


def _event(controller: Any) -> dict[str, Any] | None:
    """The controller's collision event record, JSON-ready (None: no detection, or a controller without one)."""
    event = getattr(controller, "event", None)
    return None if event is None or not hasattr(event, "to_dict") else event.to_dict()  # type: ignore[no-any-return]


def stream_closed_loop(
    plant: Plant,
    controller: ControllerLike,
    trajectory: TrajectoryLike,
    duration: float,
    *,
    path: str | os.PathLike[str] | None = None,
    block_size: int = DEFAULT_BLOCK_SIZE,
    progress: bool = False,
    callback: Callback | None = None,
    reset_controller: bool = True,
    trace_every: int = 1,
) -> RunStatistics:
    """:func:`run_closed_loop` for long runs: memory bounded by one block, whatever ``duration``.

    The ticks are recorded into a buffer of ``block_size`` rows; each full block is folded into the
    returned :class:`RunStatistics` (max |residual| per joint and when, collision ticks and separate
    detections, ticks per mode and fault, a |residual| histogram per joint for choosing a threshold
    afterwards) and, with ``path``, appended to a Parquet trace file as one row group (read it with
    :meth:`Trace.load` or block by block with :meth:`Trace.iter_blocks`); then the buffer is reused.

    Args:
        path: write the full trace here (``.parquet``); None: statistics only.
        block_size: rows per block [ticks].
        trace_every: write every this many ticks to ``path`` (those whose index is a multiple of it; 1: all).
        plant, controller, trajectory, duration, progress, callback, reset_controller: as in
            :func:`run_closed_loop`.

    Raises:
        Whatever the plant or controller raise mid-run; the rows so far are in the statistics (attached
        to the exception as ``.statistics``, with ``error`` set) and in the file, which is closed.
    """
    N, meta = _check(plant, controller, trajectory, duration)
    callback = attach_observers(plant, callback)  # reflexarm.sim.run_observers (video, stills)
    if isinstance(block_size, bool) or not isinstance(block_size, int) or block_size < 1:
        raise ConfigError(f"block_size must be a positive number of ticks; got {block_size!r}")
    stats = RunStatistics(plant.n, path=None if path is None else Path(path))
    rec = _Recorder(min(block_size, N), plant.n)
    writer = None if path is None else TraceWriter(path)
    every, first = check_every(trace_every), [0]

    def flush() -> None:
        block = rec.trace(meta, copy=False)
        stats.update(block)
        if writer is not None:
            writer.write(every_nth(block, first[0], every))
        first[0] += len(block)
        rec.clear()

    try:
        with plant.in_use("a streamed closed-loop run"):  # one run per plant (Plant.in_use)
            _loop(plant, controller, trajectory, N, rec, flush, progress, callback, reset_controller)
    except BaseException as e:
        stats.error = f"{type(e).__name__}: {e}"
        try:
            flush()
        except Exception:  # pragma: no cover - never mask the original error
            pass
        e.statistics = stats  # type: ignore[attr-defined]
        raise
    finally:
        if writer is not None:
            writer.close()
    return stats


def _check(plant: Plant, controller: Any, trajectory: Any, duration: float) -> tuple[int, dict[str, Any]]:
    """(ticks, meta) of a run, after checking the arguments."""
    try:
        dur = float(duration)
    except (TypeError, ValueError) as e:
        raise ConfigError(f"duration must be a positive number of seconds; got {duration!r}") from e
    if not math.isfinite(dur) or dur <= 0.0:
        raise ConfigError(f"duration must be a positive number of seconds; got {duration!r}")
    if not callable(getattr(controller, "step", None)):
        raise ConfigError(
            f"controller must have a step(measurement, reference) method; got {type(controller).__name__}"
        )
    if not callable(getattr(trajectory, "sample", None)):
        raise ConfigError(f"trajectory must have a sample(t) method; got {type(trajectory).__name__}")
    return max(1, round(dur / plant.control_period)), _meta(plant, controller, trajectory, dur)


def _loop(
    plant: Plant,
    controller: ControllerLike,
    trajectory: TrajectoryLike,
    N: int,
    rec: _Recorder,
    flush: Callable[[], None] | None,
    progress: bool,
    callback: Callback | None,
    reset_controller: bool,
) -> None:
    """N ticks recorded into ``rec`` block by block; ``flush()`` after every full block and at the end
    (``flush`` None: ``rec`` holds all N ticks, nothing is flushed)."""
    bar = None
    if show_progress(progress):
        from tqdm.auto import tqdm

        bar = tqdm(total=N, unit="tick", desc="simulating", mininterval=0.5)
    ticks = 0
    try:
        if reset_controller and callable(getattr(controller, "reset", None)):
            controller.reset()
        qpos, qadr, qvel, vadr = plant._qpos, plant._qadr, plant._qvel, plant._vadr
        observe = [s for s in plant.scenes if type(s).observe is not Scene.observe]
        T, Q, DQ, QM, QD, DQD = rec.t, rec.q, rec.dq, rec.q_meas, rec.q_d, rec.dq_d
        TAU, TAUM, RES, COL, COLD = rec.tau, rec.tau_m, rec.residual, rec.collision, rec.collided
        W, FEE, TEXT, modes, faults = rec.wrench, rec.f_ext_ee, rec.tau_ext, rec.mode, rec.fault
        measure, sample, control, step = plant.measure, trajectory.sample, controller.step, plant.step
        external_torque, ee_force = plant.true_external_torque, plant.ee_contact_force
        B = rec.size
        for k0 in range(0, N, B):
            stop = False
            for k in range(min(B, N - k0)):
                m = measure()
                r = sample(m.t)
                cmd = control(m, r)
                T[k] = m.t
                Q[k] = qpos[qadr]
                DQ[k] = qvel[vadr]
                QM[k] = m.q
                QD[k] = r.q_d
                DQD[k] = r.dq_d
                TAU[k] = cmd.tau
                TAUM[k] = m.tau_m
                RES[k] = cmd.residual
                COL[k] = cmd.collision
                if cmd.collided_joints:
                    COLD[k, list(cmd.collided_joints)] = True
                modes.append(str(cmd.mode))
                faults.append(str(cmd.fault) if cmd.fault else "")
                W[k] = m.wrench
                external_torque(out=TEXT[k])
                ee_force(out=FEE[k])
                for s in observe:
                    rec.put_extras(k, s.observe(plant))
                rec.done = k + 1
                ticks = k0 + k + 1
                if callback is not None and callback(k0 + k, plant, m, cmd):
                    stop = True
                    break
                step(cmd.tau)
                if bar is not None and ticks % 100 == 0:
                    bar.update(100)
            if flush is not None:
                flush()
            if stop:
                break
    finally:
        if bar is not None:
            bar.update(ticks - bar.n)
            bar.close()


def _describe(obj: Any) -> dict[str, Any]:
    describe = getattr(obj, "describe", None)
    info: dict[str, Any] = {"type": type(obj).__name__}
    if callable(describe):
        try:
            extra = describe()
            if isinstance(extra, dict):
                info.update(extra)
        except Exception as e:  # a description must never stop a run
            info["describe_error"] = repr(e)
    return _jsonable(info)


def _jsonable(value: Any) -> Any:
    """Best-effort conversion to JSON types (numpy arrays/scalars to lists/floats, others to repr)."""
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    try:
        json.dumps(value)
        return value
    except (TypeError, ValueError):
        return repr(value)


def _meta(plant: Plant, controller: Any, trajectory: Any, duration: float) -> dict[str, Any]:
    meta: dict[str, Any] = {"format": "reflexarm.Trace/1", "duration": duration}
    meta.update(_jsonable(plant.describe()))
    meta["controller"] = _describe(controller)
    meta["trajectory"] = _describe(trajectory)
    return meta
