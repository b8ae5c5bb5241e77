"""record_measurements: a simulated robot log, what the controller measured on every tick of a streamed run.

The compiled stream (:mod:`reflexarm.sim.compiled_stream`) copies each block's measured signals (the measured
velocity is recorded by C++ on request) into arrays of the whole run; the Python loop records them with a
callback when the run cannot be compiled. Used by :func:`reflexarm.tuning.record_free_motion_log`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from reflexarm.sim._run_memory import check_log_memory
from reflexarm.sim.compiled_loop import _modules
from reflexarm.sim.compiled_stream import _BlockRun, stream_reason
from reflexarm.sim.plant import Plant
from reflexarm.sim.recording import RunStatistics
from reflexarm.sim.run_observers import observers_active
from reflexarm.sim.runner import DEFAULT_BLOCK_SIZE, ControllerLike, TrajectoryLike, _check, stream_closed_loop

__all__ = ["record_measurements"]


def record_measurements(
    plant: Plant,
    controller: ControllerLike,
    trajectory: TrajectoryLike,
    duration: float,
    *,
    block_size: int = DEFAULT_BLOCK_SIZE,
    progress: bool = False,
) -> tuple[RunStatistics, dict[str, np.ndarray]]:
    """A streamed run (no trace file) that keeps what the controller measured on every tick, a robot's log:
    ``t`` (N,), ``q``, ``dq``, ``tau_m`` (N, n) and ``wrench`` (N, 6), as :meth:`Plant.measure` returned them
    (with their noise). The compiled loop when :func:`stream_reason` allows it, else the Python loop with a
    callback; the same numbers either way (tests/test_long_runs.py).

    Raises:
        ConfigError: the log's rows cannot fit in the memory available (checked before allocating).
    """
    N, _ = _check(plant, controller, trajectory, duration)
    n = plant.n
    check_log_memory(N, n, "record_measurements")
    if stream_reason(plant, controller) is not None or observers_active():
        return _record_in_python(plant, controller, trajectory, duration, N, block_size, progress)
    mods = _modules()
    assert not isinstance(mods, str)
    with plant.in_use("a compiled recording run"):
        run = _BlockRun(plant, controller, mods, min(block_size, N), {}, None, 1, False, log_rows=N)
        try:
            run.run(trajectory, N, progress)
        finally:
            run.finish(None)
    assert run.log is not None
    return run.stats, {k: v[: run.done] for k, v in run.log.items()}


def _record_in_python(
    plant: Plant, controller: ControllerLike, trajectory: TrajectoryLike, duration: float, N: int, B: int, p: bool
) -> tuple[RunStatistics, dict[str, np.ndarray]]:
    n = plant.n
    log = {"t": np.zeros(N), "q": np.zeros((N, n)), "dq": np.zeros((N, n)), "tau_m": np.zeros((N, n)),
           "wrench": np.zeros((N, 6))}  # fmt: skip
    count = [0]

    def record(k: int, _plant: Plant, m: Any, _cmd: Any) -> None:
        log["t"][k], log["q"][k], log["dq"][k], log["tau_m"][k], log["wrench"][k] = m.t, m.q, m.dq, m.tau_m, m.wrench
        count[0] = k + 1

    stats = stream_closed_loop(plant, controller, trajectory, duration, block_size=B, progress=p, callback=record)
    return stats, {k: v[: count[0]] for k, v in log.items()}
