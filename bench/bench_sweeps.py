"""Sweep throughput: Fig. 12 runs per second with 1 and with 2 local workers, and the default Fig. 13 sweep.

The runs use the compiled closed loop (compensation.run_case -> sim.compiled_loop.run_fast). Diagnostics of
the scaling in the same run: what two processes of pure CPU work get from the machine at that moment (the
ceiling the sweep cannot beat when other processes share the cores), the in-worker run time with 1 and 2
workers (a slower run with 2 workers means the cores are shared or memory-bound), and the share of the wall
time spent outside runs (dispatch, pickling, the JSON store).

Baselines in the same process: one run's wall time (the unit of work), and the 1-worker throughput the
2-worker one is compared with (scaling ratio; 2.0 would be perfect on 2 free cores). The wall time of
the default Fig. 13 sweep (30 levels x 10 trials x 2 settings = 600 runs + the reference) is estimated
from the 2-worker throughput; ``--full`` runs it for real.

    python bench/bench_sweeps.py [--runs 24] [--full]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time

from reflexarm.experiments.compensation import CompensationSetup, reference_run, run_case
from reflexarm.experiments.robustness import (
    DEFAULT_LEVELS,
    PaperSweepContext,
    paper_sweep,
    paper_sweep_tasks,
    run_paper_task,
)
from reflexarm.experiments.sweeps import run_sweep

SIM_SECONDS = CompensationSetup().duration


def _sweep_wall(workers: int, n_runs: int, root: str, tag: str, context: PaperSweepContext) -> tuple[float, float]:
    """(wall time, mean in-worker run time) of ``n_runs`` runs of a model-error sweep through :func:`run_sweep`."""
    tasks = paper_sweep_tasks("model-error", list(range(1, n_runs // 2 + 1)), trials=1, seed=0)
    t0 = time.perf_counter()
    res = run_sweep(tasks, run_paper_task, os.path.join(root, tag), context=context, workers=workers, progress=False)
    wall = time.perf_counter() - t0
    assert len(res.ran) == n_runs, (len(res.ran), n_runs)
    return wall, sum(res.run_wall_s.values()) / len(res.run_wall_s)


def _spin(seconds: float) -> float:
    """CPU-bound work of a fixed size (pure Python arithmetic, no memory traffic); returns its wall time."""
    t0 = time.perf_counter()
    x = 0
    for i in range(int(seconds * 2e7)):
        x += i & 7
    return time.perf_counter() - t0


def _cpu_ceiling(seconds: float = 1.0) -> float:
    """What 2 processes get from the machine now: the wall time of one fixed CPU task run alone, over the
    wall time of two of them run at once in the joblib pool, times 2 (2.0: two free cores; ~1.0: the
    other core is busy). The sweep's 1 -> 2 worker scaling cannot exceed it."""
    from joblib import Parallel, delayed

    one = _spin(seconds)
    t0 = time.perf_counter()
    Parallel(n_jobs=2)(delayed(_spin)(seconds) for _ in range(2))
    return 2.0 * one / (time.perf_counter() - t0)


def main(argv: list[str] | None = None) -> dict[str, float]:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=24, help="runs per throughput measurement (even, default 24)")
    ap.add_argument("--full", action="store_true", help="also run the default Fig. 13 sweep (600 runs)")
    args = ap.parse_args([] if argv is None else argv)
    load0 = os.getloadavg()  # other processes on the machine distort the scaling: reported
    setup = CompensationSetup()
    ref = reference_run(setup)  # also the warm-up: imports, compiled kernels, model loading
    context = PaperSweepContext(setup, ref.t, ref.q)
    t0 = time.perf_counter()
    for _ in range(3):
        run_case(setup, 1, 1, model_seed=1, noise_seed=1)
    one = (time.perf_counter() - t0) / 3
    n = args.runs + args.runs % 2
    with tempfile.TemporaryDirectory() as root:
        _sweep_wall(2, 2, root, "warm", context)  # start the worker pool (loky reuses it)
        ceiling_before = _cpu_ceiling()
        w1, r1 = _sweep_wall(1, n, root, "w1", context)
        w2, r2 = _sweep_wall(2, n, root, "w2", context)
        ceiling_after = _cpu_ceiling()
        res = {
            "one_run_s": one,
            "one_run_x_realtime": SIM_SECONDS / one,
            "runs_per_s_1_worker": n / w1,
            "runs_per_s_2_workers": n / w2,
            "scaling_2_vs_1": w1 / w2,
            "run_s_in_worker_1": r1,
            "run_s_in_worker_2": r2,
            "cores": float(os.cpu_count() or 1),
            "load_average_at_start": load0[0],
            "cpu_ceiling_2_procs_before": ceiling_before,
            "cpu_ceiling_2_procs_after": ceiling_after,
            # the part of the 2-worker wall time not spent inside runs (dispatch, pickling, the store)
            "dispatch_share_2_workers": max(0.0, 1.0 - n * r2 / (2.0 * w2)),
        }
        n_default = len(DEFAULT_LEVELS["model-error"]) * 10 * 2
        res["fig13_default_runs"] = float(n_default)
        res["fig13_default_estimated_s"] = n_default / res["runs_per_s_2_workers"] + one
        print(
            f"one Fig. 12 run ({SIM_SECONDS:g} s simulated at 1 kHz): {one:.2f} s = {res['one_run_x_realtime']:.1f}x "
            "real time"
        )
        print(f"sweep throughput, 1 worker:  {res['runs_per_s_1_worker']:.2f} runs/s ({n} runs in {w1:.1f} s)")
        print(
            f"sweep throughput, 2 workers: {res['runs_per_s_2_workers']:.2f} runs/s ({n} runs in {w2:.1f} s); "
            f"scaling {res['scaling_2_vs_1']:.2f}x on {os.cpu_count()} cores"
        )
        print(
            f"  one run inside a worker: {r1:.2f} s alone, {r2:.2f} s with 2 workers (the rest of the gap is "
            "dispatch, pickling and the store); load average at start: " + " ".join(f"{x:.2f}" for x in load0)
        )
        print(
            f"  what 2 processes of pure CPU work get from this machine now (2.0: two free cores): "
            f"{ceiling_before:.2f} before, {ceiling_after:.2f} after; share of the 2-worker wall time outside "
            f"the runs: {res['dispatch_share_2_workers']:.1%}"
        )
        print(
            f"default Fig. 13 sweep ({n_default} runs), 2 workers: ~{res['fig13_default_estimated_s'] / 60:.1f} min "
            "(estimated)"
        )
        if args.full:
            t0 = time.perf_counter()
            paper_sweep("model-error", os.path.join(root, "full"), workers=2, progress=True)
            res["fig13_default_measured_s"] = time.perf_counter() - t0
            print(f"default Fig. 13 sweep, measured: {res['fig13_default_measured_s'] / 60:.1f} min")
    return res


if __name__ == "__main__":
    main(sys.argv[1:])
