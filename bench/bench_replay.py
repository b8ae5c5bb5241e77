"""Replay of a whole log in one call (issue 19): the residual-only path against the full path, Atlas arm (7 joints).

The full path (``replay(..., torque=True)``) runs every sample through a whole ``update()`` (gravity, Coriolis
matrix, two inverse dynamics, the law, the modal damping, the observers); the residual-only path (the default)
runs the input contract, the observers and the detection on dynamics terms from one pass over the tree
(bench/replay_terms_timing.cpp measures each term). Printed: M samples per second (wall) and per CPU second
(both threads' time counted), and the ratios against the full path measured in the same process. On a shared
machine the wall rate of two threads is only as good as the second core is free: the CPU rate is the steadier.
"""

from __future__ import annotations

import statistics
import time
from typing import Any

import numpy as np

from reflexarm import load_robot

ROBOT = "atlas_v5_left_arm"
N = 200_000
ROUNDS = 3


def _timed(fn: Any) -> tuple[float, float]:
    """(wall, CPU time of this process, all threads) of fn() [s]."""
    c0, t0 = time.process_time(), time.perf_counter()
    fn()
    return time.perf_counter() - t0, time.process_time() - c0


def _log(robot: Any) -> tuple[np.ndarray, ...]:
    """bench_long_runs' replay log: a smooth motion, noisy velocities and torques, 1 kHz."""
    rng = np.random.default_rng(0)
    n = robot.n
    t = np.arange(N) * 1e-3
    q = robot.home + 0.2 * np.sin(np.outer(t, 0.5 + 0.3 * np.arange(n)))
    dq = np.gradient(q, t, axis=0) + 1e-3 * rng.standard_normal((N, n))
    tau = np.tile(robot.compute_gravity(robot.home), (N, 1)) + 0.3 * rng.standard_normal((N, n))
    return t, q, dq, tau


def main() -> dict[str, Any]:
    from reflexarm.control import Controller, replay

    robot = load_robot(ROBOT)
    t, q, dq, tau = _log(robot)

    def ctrl() -> Any:
        return Controller(robot, threshold=None, reaction="none", torque_limit=None)

    paths = {
        "full": lambda: replay(ctrl(), t, q, dq, tau, torque=True),
        "residual-only, 1 thread": lambda: replay(ctrl(), t, q, dq, tau, threads=1),
        "residual-only, 2 threads": lambda: replay(ctrl(), t, q, dq, tau, threads=2),
    }
    rates: dict[str, list[tuple[float, float]]] = {k: [] for k in paths}
    results: dict[str, Any] = {}
    for _ in range(ROUNDS):
        for name, fn in paths.items():
            kept: list[Any] = []
            wall, cpu = _timed(lambda: kept.append(fn()))  # noqa: B023 (called at once)
            rates[name].append((N / wall, N / cpu))
            results[name] = kept[0]
    assert results["residual-only, 2 threads"].residual_only and not results["full"].residual_only
    diff = max(float(np.max(np.abs(results[k].residual - results["full"].residual))) for k in paths)
    out: dict[str, Any] = {"samples": N, "max |residual - full path's| Nm": diff}
    base = [r[0] for r in rates["full"]], [r[1] for r in rates["full"]]
    print(f"replay, Atlas (7 joints), {N:,} samples, median of {ROUNDS}; max |residual - full path's| {diff:.1e} Nm")
    for name, r in rates.items():
        wall = statistics.median(x[0] for x in r) / 1e6
        cpu = statistics.median(x[1] for x in r) / 1e6
        ratio_wall = statistics.median(x[0] / b for x, b in zip(r, base[0], strict=True))
        ratio_cpu = statistics.median(x[1] / b for x, b in zip(r, base[1], strict=True))
        print(f"  {name:<26} {wall:6.3f} M samples/s ({ratio_wall:5.2f}x the full path), "
              f"{cpu:6.3f} M per CPU second ({ratio_cpu:5.2f}x)")  # fmt: skip
        out[name] = {"M samples/s": wall, "M samples per CPU s": cpu, "x full (wall)": ratio_wall,
                     "x full (cpu)": ratio_cpu}  # fmt: skip
    return out


if __name__ == "__main__":
    main()
