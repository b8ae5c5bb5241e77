"""Long work at compiled speed (issue 19 items 1-2): free motion / soaks in the compiled stream, their memory, the
observer replay of a whole log in one call, and one hour of 1 kHz logs through ``tune-thresholds`` end to end.

1. Free motion (the Atlas arm's demo swing, paper noise, +-10 % model, the false-alarm soak of ``reflexarm
   simulate free-motion``) streamed by the compiled loop (stream_fast: statistics in C++), without a trace, with
   the full trace and with the long-run trace (every 100th tick), next to MuJoCo stepping the same plant alone
   (the compiled run's torques replayed into it from the same state, ``_closed_loop.replay_torques``: same
   motion, no sensors, controller or recording) and the Python stream (stream_closed_loop, today's path, one
   shorter run). Rounds alternate; ratios are medians of the ratios within a round, and the ratio of the best CPU
   times over the rounds (the steadier one on a loaded machine). Target: >= 0.6x MuJoCo alone.
2. Memory of a soak: a child process streams free motion with the default trace of an hour (every 100th tick) and
   samples its RSS; printed: after the imports, peak, the growth per simulated minute and the extrapolation to one
   simulated hour (REFLEXARM_BENCH_SOAK_S=3600 runs the whole hour instead). Target: < 400 MB, flat.
3. Memory of ``reflexarm simulate free-motion`` (10 simulated seconds, default trace, the still and the figure) in a
   child process, by phase: the peak RSS (VmHWM) during and the RSS after the imports, the set-up, the run, the
   figure and the still. Target: < 400 MB.
4. Replay: a 7-joint Atlas log through reflexarm.control.replay (one call) and through Controller.step per sample
   (what tune-thresholds did), in samples per second. Target: >= 1 M samples/s.
5. ``reflexarm tune-thresholds`` end to end (a child process: reading the files, replay, tail fit, outputs) on one
   hour of simulated 1 kHz free-motion logs (four 15-minute Parquet logs written by record_free_motion_log, kept
   in bench/out/long_logs/ for the next run). Target: < 60 s.
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from reflexarm import load_robot
from reflexarm.experiments import collision as C
from reflexarm.sim import PAPER_NOISE, Plant, run_compiled, stream_closed_loop, stream_fast

HERE = Path(__file__).resolve().parent
ROUNDS = 3
SIM_S = 60.0  # simulated seconds per timed compiled run
PY_S = 10.0  # ... of the Python stream (one run)
SOAK_S = float(os.environ.get("REFLEXARM_BENCH_SOAK_S", "600"))
LOG_MINUTES, LOG_PARTS = 15, 4  # one hour of logs in four files


def _timed(fn: Any) -> tuple[float, float]:
    """(wall, CPU time of this process) of fn() [s]: on a shared machine the CPU time is the steadier measure."""
    c0, t0 = time.process_time(), time.perf_counter()
    fn()
    return time.perf_counter() - t0, time.process_time() - c0


def _child_cpu() -> float:
    import resource

    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _setup(duration: float) -> tuple[Plant, Any, Any]:
    robot = load_robot(C.ROBOT)
    model, _ = C.controller_model(robot, 0.1, 0, None)
    traj = C.free_motion_trajectory(duration, "demo", robot)
    plant = Plant(robot, noise=PAPER_NOISE, seed=0)
    plant.reset(traj.sample(0.0).q_d)
    from reflexarm.control import Controller

    ctrl = Controller(model, stiffness=300.0, observer_gain=5.0, threshold=11.0, reaction="none")
    return plant, ctrl, traj


def _speed() -> dict[str, Any]:
    import reflexarm._closed_loop as cl

    plant, ctrl, traj = _setup(SIM_S)
    q0 = plant.q.copy()
    tau = run_compiled(plant, ctrl, traj, SIM_S).tau  # the torques MuJoCo alone replays
    tmp = Path(tempfile.mkdtemp())

    def compiled(every: int | None) -> None:
        p, c, tr = _setup(SIM_S)
        path = None if every is None else tmp / "t.parquet"
        stream_fast(p, c, tr, SIM_S, path=path, trace_every=every or 1)

    def alone() -> None:
        plant.reset(q0)
        cl.replay_torques(plant.model._address, plant.data._address, tau, plant._arm_dofs, plant.substeps, True)

    fns = {"no trace": lambda: compiled(None), "full trace": lambda: compiled(1),
           "every 100th": lambda: compiled(100), "MuJoCo alone": alone}  # fmt: skip
    times: dict[str, list[tuple[float, float]]] = {k: [] for k in fns}
    for _ in range(ROUNDS):
        for k, fn in fns.items():
            times[k].append(_timed(fn))
    p, c, tr = _setup(PY_S)
    py = _timed(lambda: stream_closed_loop(p, c, tr, PY_S))
    out: dict[str, Any] = {"simulated_s": SIM_S}
    print(f"free motion, {SIM_S:g} s simulated, {ROUNDS} rounds: x real time, ratio to MuJoCo alone (medians of the "
          "ratios within a round), by wall time and by CPU time:")  # fmt: skip
    base = times["MuJoCo alone"]
    for k in fns:
        for i, clock in enumerate(("wall", "cpu")):
            out[f"{k} x real time ({clock})"] = SIM_S / statistics.median(x[i] for x in times[k])
            out[f"{k} / MuJoCo alone ({clock})"] = statistics.median(
                b[i] / a[i] for a, b in zip(times[k], base, strict=True)
            )
        # the best CPU time of each over the rounds, as timeit takes it: on a loaded machine the other processes
        # only ever add to a run's CPU time (cache and memory bandwidth), so the least is the closest to the run's own
        out[f"{k} / MuJoCo alone (best cpu)"] = min(b[1] for b in base) / min(x[1] for x in times[k])
        print(
            f"  {k:<14} {out[f'{k} x real time (wall)']:6.1f}x real time, {out[f'{k} / MuJoCo alone (wall)']:.2f}x "
            f"MuJoCo alone (CPU: {out[f'{k} x real time (cpu)']:6.1f}x, {out[f'{k} / MuJoCo alone (cpu)']:.2f}x; "
            f"best CPU times: {out[f'{k} / MuJoCo alone (best cpu)']:.2f}x)"
        )
    for i, clock in enumerate(("wall", "cpu")):
        out[f"python stream x real time ({clock})"] = PY_S / py[i]
        out[f"python stream / MuJoCo alone ({clock})"] = (
            out[f"python stream x real time ({clock})"] / out[f"MuJoCo alone x real time ({clock})"]
        )
    print(f"  {'python stream':<14} {out['python stream x real time (wall)']:6.1f}x real time, "
          f"{out['python stream / MuJoCo alone (wall)']:.2f}x MuJoCo alone (CPU: "
          f"{out['python stream x real time (cpu)']:6.1f}x, {out['python stream / MuJoCo alone (cpu)']:.2f}x; one "
          f"{PY_S:g} s run against the medians)")  # fmt: skip
    return out


_SOAK_CHILD = r"""
import json, sys, threading, time, tempfile
from pathlib import Path
sys.path.insert(0, sys.argv[2])
import bench_long_runs as B
def rss():
    for line in open("/proc/self/status"):
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) * 1024
duration = float(sys.argv[1])
plant, ctrl, traj = B._setup(duration)
base = rss()
samples, stop = [], threading.Event()
def watch():
    t0 = time.perf_counter()
    while not stop.is_set():
        samples.append((time.perf_counter() - t0, float(plant.data.time), rss()))
        time.sleep(0.2)
th = threading.Thread(target=watch, daemon=True); th.start()
path = Path(tempfile.mkdtemp()) / "soak.parquet"
t0, c0 = time.perf_counter(), time.process_time()
stats = B.stream_fast(plant, ctrl, traj, duration, path=path, trace_every=B.C.default_trace_every(3600.0))
wall, cpu = time.perf_counter() - t0, time.process_time() - c0
stop.set(); th.join()
print(json.dumps({"base": base, "samples": samples, "wall": wall, "cpu": cpu, "loop": stats.loop,
                  "file_bytes": path.stat().st_size, "ticks": stats.ticks}))
"""


def _soak() -> dict[str, Any]:
    res = subprocess.run([sys.executable, "-c", _SOAK_CHILD, str(SOAK_S), str(HERE)], capture_output=True,
                         text=True, check=True, env=os.environ | {"MPLBACKEND": "Agg"})  # fmt: skip
    r = json.loads(res.stdout.strip().splitlines()[-1])
    s = np.array(r["samples"])  # (wall, simulated s, rss)
    peak = float(s[:, 2].max())
    late = s[s[:, 1] >= 0.2 * SOAK_S]  # after the first blocks and the writer's first row groups
    slope = float(np.polyfit(late[:, 1], late[:, 2], 1)[0]) if len(late) > 3 else float("nan")  # bytes per s
    hour = float(late[-1, 2] + slope * max(0.0, 3600.0 - late[-1, 1]))
    out = {
        "simulated_s": SOAK_S, "loop": r["loop"], "x real time": SOAK_S / r["wall"],
        "x real time (cpu)": SOAK_S / r["cpu"],
        "rss_after_imports_MB": r["base"] / 1e6, "rss_peak_MB": peak / 1e6,
        "rss_growth_MB_per_simulated_min": slope * 60 / 1e6, "rss_at_one_hour_MB": hour / 1e6,
        "trace_MB_per_simulated_hour": r["file_bytes"] / SOAK_S * 3600 / 1e6,
    }  # fmt: skip
    print(f"soak: free motion {SOAK_S:g} s simulated in a child process ({r['loop']} loop, "
          f"{out['x real time']:.1f}x real time, {out['x real time (cpu)']:.1f}x by CPU time), default trace of an "
          "hour (every 100th tick):")  # fmt: skip
    print(f"  RSS after imports {out['rss_after_imports_MB']:.0f} MB, peak {out['rss_peak_MB']:.0f} MB, growth "
          f"{out['rss_growth_MB_per_simulated_min']:+.2f} MB per simulated minute -> "
          f"{out['rss_at_one_hour_MB']:.0f} MB at one simulated hour "
          f"({'measured' if SOAK_S >= 3600 else 'extrapolated'}); trace "
          f"{out['trace_MB_per_simulated_hour']:.1f} MB per simulated hour")  # fmt: skip
    return out


_CLI_CHILD = r"""
import json, sys
def status():
    out = {}
    for line in open("/proc/self/status"):
        if line.startswith(("VmRSS:", "VmHWM:")):
            key, value = line.split(":")
            out[key] = int(value.split()[0]) * 1024
    return out
phases = []
def mark(name):  # RSS now and the peak since the last mark (the kernel's high-water mark, reset after reading)
    s = status()
    phases.append((name, s["VmRSS"], s["VmHWM"]))
    with open("/proc/self/clear_refs", "w") as f:
        f.write("5")
mark("interpreter")
from reflexarm.cli import main
import reflexarm._cli.run_outputs as ro, reflexarm.experiments.collision as col, reflexarm.experiments.plots as pl
mark("imports")
def wrap(owner, name, label, before=None):
    f = getattr(owner, name)
    def g(*a, **k):
        if before:
            mark(before)
        r = f(*a, **k)
        mark(label)
        return r
    setattr(owner, name, g)
wrap(col, "free_motion_false_alarms", "run (stream, trace written)", before="set-up (robot, options, scene capture)")
wrap(pl, "plot_free_motion", "figure (matplotlib)", before="summary")
wrap(ro.SceneCapture, "finish", "still (MuJoCo offscreen, EGL)")
main(["simulate", "free-motion", "--quiet", "--duration", sys.argv[1], "--out", sys.argv[2]])
mark("exit")
print(json.dumps(phases))
"""


def _cli_memory(duration: float = 10.0) -> dict[str, Any]:
    """Peak memory of ``reflexarm simulate free-motion`` (default trace, still and figure) by phase, in a child."""
    out_dir = tempfile.mkdtemp()
    res = subprocess.run([sys.executable, "-c", _CLI_CHILD, str(duration), out_dir], capture_output=True, text=True,
                         check=True, env=os.environ | {"MPLBACKEND": "Agg"})  # fmt: skip
    phases = json.loads(res.stdout.strip().splitlines()[-1])
    peak = max(p[2] for p in phases)
    print(f"reflexarm simulate free-motion --duration {duration:g} (default trace, still, figure): peak RSS "
          f"{peak / 1e6:.0f} MB (target < 400 MB); by phase, RSS after it and the peak during it:")  # fmt: skip
    prev = 0
    for name, rss, hwm in phases[1:]:
        print(f"  {name:<40} {rss / 1e6:5.0f} MB (+{(rss - prev) / 1e6:4.0f}), peak {hwm / 1e6:5.0f} MB")
        prev = rss
    by_phase = {name: {"rss_MB": rss / 1e6, "peak_MB": hwm / 1e6} for name, rss, hwm in phases}
    return {"duration_s": duration, "peak_MB": peak / 1e6, "phases": by_phase}


def _replay() -> dict[str, Any]:
    from reflexarm.control import Controller, replay
    from reflexarm.signals import Measurement, Reference

    robot = load_robot(C.ROBOT)
    rng = np.random.default_rng(0)
    N, n = 200_000, robot.n
    t = np.arange(N) * 1e-3
    q = robot.home + 0.2 * np.sin(np.outer(t, 0.5 + 0.3 * np.arange(n)))
    dq = np.gradient(q, t, axis=0) + 1e-3 * rng.standard_normal((N, n))
    tau = np.tile(robot.compute_gravity(robot.home), (N, 1)) + 0.3 * rng.standard_normal((N, n))

    def ctrl() -> Any:
        return Controller(robot, threshold=None, reaction="none", torque_limit=None)

    g, z, w, M = np.asarray(robot.gravity, float), np.zeros(n), np.zeros(6), N // 10

    def steps(c: Any) -> None:
        for k in range(M):
            c.step(Measurement(float(t[k]), q[k], dq[k], tau[k], w, g), Reference(q[k], z, z))

    rates = []
    for _ in range(ROUNDS):
        a, b = ctrl(), ctrl()
        one_call = _timed(lambda: replay(a, t, q, dq, tau))  # noqa: B023 (called at once)
        per = _timed(lambda: steps(b))  # noqa: B023
        rates.append((N / one_call[0], M / per[0], N / one_call[1], M / per[1]))
    one, per_s, one_cpu, per_cpu = (statistics.median(r[i] for r in rates) for i in range(4))
    ratio = statistics.median(r[0] / r[1] for r in rates)
    print(f"replay, Atlas (7 joints), {N:,} samples: one call {one / 1e6:.3f} M samples/s, Controller.step per "
          f"sample {per_s / 1e6:.3f} M samples/s: {ratio:.2f}x (per CPU second: {one_cpu / 1e6:.3f} and "
          f"{per_cpu / 1e6:.3f} M)")  # fmt: skip
    return {"one call M samples/s": one / 1e6, "step per sample M samples/s": per_s / 1e6, "ratio": ratio,
            "one call M samples per CPU s": one_cpu / 1e6, "step M samples per CPU s": per_cpu / 1e6}  # fmt: skip


def _hour_of_logs() -> list[Path]:
    """Four 15-minute free-motion logs (1 kHz, measured signals), written once into bench/out/long_logs/."""
    from reflexarm.logs.files import save_log
    from reflexarm.tuning import record_free_motion_log

    folder = HERE / "out" / "long_logs"
    paths = [folder / f"free_motion_{LOG_MINUTES}min_seed{s}.parquet" for s in range(LOG_PARTS)]
    for s, p in enumerate(paths):
        if not p.exists():
            t0 = time.perf_counter()
            run = record_free_motion_log(LOG_MINUTES * 60.0, motion="hydraulic", seed=s)
            save_log(run.log, p)
            print(f"  wrote {p.name} ({time.perf_counter() - t0:.0f} s)")
    return paths


def _tune() -> dict[str, Any]:
    paths = _hour_of_logs()
    out = Path(tempfile.mkdtemp())
    exe = Path(sys.executable).with_name("reflexarm")
    # the hydraulic motion moves four of the seven joints: --allow-unmoved writes the other three marked
    cmd = [str(exe), "tune-thresholds", *map(str, paths), "--out", str(out), "--no-figure", "--allow-unmoved"]
    t0, c0 = time.perf_counter(), _child_cpu()
    res = subprocess.run(cmd, capture_output=True, text=True, env=os.environ | {"MPLBACKEND": "Agg"})
    wall, cpu = time.perf_counter() - t0, _child_cpu() - c0
    ok = res.returncode == 0
    print(f"tune-thresholds on one hour of 1 kHz logs ({LOG_PARTS} x {LOG_MINUTES} min, Atlas): {wall:.1f} s end to "
          f"end, {cpu:.1f} s of CPU (exit {res.returncode})")  # fmt: skip
    if not ok:
        print("  " + (res.stderr.strip().splitlines() or ["(no output)"])[-1])
    return {"seconds": wall, "cpu_seconds": cpu, "exit": res.returncode, "logs": [p.name for p in paths]}


def main() -> dict[str, Any]:
    return {"speed": _speed(), "soak": _soak(), "cli_memory": _cli_memory(), "replay": _replay(),
            "tune_thresholds_hour": _tune()}  # fmt: skip


if __name__ == "__main__":
    main()
