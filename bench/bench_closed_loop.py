"""Closed-loop simulation speed on the demo contact run (Figs. 7-8, Coll.Det, cinderblock), as a multiple of
real time: the compiled loop (reflexarm.sim.compiled_loop) next to MuJoCo stepping alone with the same
physics step, and the Python loop (run_closed_loop), in one process; the runs alternate (compiled, alone,
...) for REPEATS rounds: speeds are medians over the rounds, ratios medians of the ratios within a round.

"MuJoCo alone" replays the compiled run's recorded torques into the same plant from the same state
(``_closed_loop.replay_torques``: the torque written to ``qfrc_applied``, then the physics steps, in C++), so
it integrates exactly the same motion and contacts (checked: same final state) without sensors, controller,
reference or recording. Both step with MuJoCo's profiling timers on a clock of 0 (reflexarm::QuietTimers, as
the compiled loop does when no time callback is installed). Issue targets: compiled loop >= 50x real time and
>= 0.7x MuJoCo alone. Physics steps: two 0.5 ms substeps per 1 ms tick (the plant's default) and one 1 ms step.

This machine's own MuJoCo facts are printed beside the ratio (they bound the compiled loop's speed):
- "arm alone, no scene": the same torques replayed into the arm without the table and the block (nv 7
  instead of 13, no contacts). Issue 10's "MuJoCo alone: 50x (2 substeps) / 90x (1 ms)" match this plant on
  this machine; its demo plant (commit 13d773a) is byte-identical to today's (same mjb).
- MuJoCo's own timers (mjData.timer, with the mujoco package's clock) in one more replay, alternated with the
  others: a physics step and its collision and constraint parts (from the last such replay). Reading that
  clock costs ~1-2 us per tick of 2 x 0.5 ms (why the loop and "alone" run with quiet timers); the difference
  of two medians of 3 runs is too noisy on a shared machine to print.
"""

from __future__ import annotations

import os
import statistics
import time
from collections.abc import Callable
from typing import Any

import mujoco
import numpy as np

from reflexarm import load_robot
from reflexarm.experiments import collision as C
from reflexarm.sim import PAPER_NOISE, Cinderblock, Plant, run_closed_loop
from reflexarm.sim.compiled_loop import run_compiled

REPEATS = 5
_TIMERS = {
    "step": mujoco.mjtTimer.mjTIMER_STEP,
    "collision": mujoco.mjtTimer.mjTIMER_POS_COLLISION,
    "constraint": mujoco.mjtTimer.mjTIMER_CONSTRAINT,
}


def _demo(timestep: float) -> tuple[Plant, Any, Any, Any]:
    robot = load_robot(C.ROBOT)
    model, _ = C.controller_model(robot, None, 0, None)
    traj = C.ee_collision_trajectory()
    block = Cinderblock(**C._block("paper"))  # type: ignore[arg-type]
    plant = Plant(robot, scene=block, noise=PAPER_NOISE, seed=0, timestep=timestep)
    return plant, C.EE_SETTINGS[2].controller(model), traj, traj.sample(0.0).q_d


def _alternate(fns: dict[str, Callable[[], None]]) -> tuple[dict[str, list[float]], dict[str, list[float]]]:
    """Wall and CPU (this process) times of REPEATS rounds, each calling every function once, in turn."""
    wall: dict[str, list[float]] = {k: [] for k in fns}
    cpu: dict[str, list[float]] = {k: [] for k in fns}
    for _ in range(REPEATS):
        for k, fn in fns.items():
            c0, t0 = time.process_time(), time.perf_counter()
            fn()
            wall[k].append(time.perf_counter() - t0)
            cpu[k].append(time.process_time() - c0)
    return wall, cpu


def _ratio(times: dict[str, list[float]], num: str, den: str) -> float:
    """Median over rounds of num/den within each round: runs next to each other meet the same machine (its
    speed drifts by tens of percent within a minute here, so a ratio of two medians is much noisier)."""
    return statistics.median(a / b for a, b in zip(times[num], times[den], strict=True))


def _replay(plant: Plant, q0: np.ndarray, tau: np.ndarray, *, quiet: bool = True) -> None:
    import reflexarm._closed_loop as cl

    plant.reset(q0)
    cl.replay_torques(plant.model._address, plant.data._address, tau, plant._arm_dofs, plant.substeps, quiet)


def _timed_replay(plant: Plant, q0: np.ndarray, tau: np.ndarray, timers: dict[str, float]) -> None:
    """A replay with MuJoCo's timers on the mujoco package's clock; their means per physics step [us] go to
    ``timers``."""
    for t in plant.data.timer:
        t.number, t.duration = 0, 0.0
    _replay(plant, q0, tau, quiet=False)  # plant.reset keeps the timers
    for name, idx in _TIMERS.items():
        timer = plant.data.timer[int(idx)]
        timers[name] = timer.duration / max(timer.number, 1) * 1e6


def _measure(timestep: float, python_loop: bool) -> dict[str, float]:
    plant, ctrl, traj, q0 = _demo(timestep)
    arm = Plant(plant.robot, noise=PAPER_NOISE, seed=0, timestep=timestep)  # no table, no block
    sim_s = traj.duration
    traces = []

    def compiled() -> None:
        plant.reset(q0)
        traces.append(run_compiled(plant, ctrl, traj, sim_s))

    compiled()  # the torques to replay (and a warm-up)
    tr = traces[-1]
    q_end = plant.q
    tau = np.ascontiguousarray(tr.tau)
    timers: dict[str, float] = {}
    fns: dict[str, Callable[[], None]] = {
        "compiled": compiled,
        "alone": lambda: _replay(plant, q0, tau),
        "arm": lambda: _replay(arm, q0, tau),
        "alone_timed": lambda: _timed_replay(plant, q0, tau, timers),
    }
    if python_loop:

        def python() -> None:
            plant.reset(q0)
            run_closed_loop(plant, ctrl, traj, sim_s)

        fns["python"] = python
    walls, cpus = _alternate(fns)
    wall = {k: statistics.median(v) for k, v in walls.items()}
    _replay(plant, q0, tau)
    if not np.array_equal(plant.q, q_end):
        raise AssertionError("the replay did not reproduce the compiled run's motion: the baseline is not comparable")
    n, steps = len(tr.t), len(tr.t) * plant.substeps
    res = {
        "compiled_x_realtime": sim_s / wall["compiled"],
        "mujoco_alone_x_realtime": sim_s / wall["alone"],
        "compiled_vs_mujoco_alone": _ratio(walls, "alone", "compiled"),
        # the same ratio in CPU time of this process: less sensitive to other processes on the machine
        "compiled_vs_mujoco_alone_cpu": _ratio(cpus, "alone", "compiled"),
        "compiled_tick_us": wall["compiled"] / n * 1e6,
        "mujoco_alone_tick_us": wall["alone"] / n * 1e6,
        "arm_alone_x_realtime": sim_s / wall["arm"],
        "mujoco_step_us": timers["step"],
        "mujoco_collision_us": timers["collision"],
        "mujoco_constraint_us": timers["constraint"],
        "physics_steps_per_run": float(steps),
        "detection_t": float(tr.t[np.argmax(tr.collision)]) if tr.collision.any() else float("nan"),
    }
    if python_loop:
        res["python_x_realtime"] = sim_s / wall["python"]
        res["compiled_vs_python"] = _ratio(walls, "python", "compiled")
        res["compiled_vs_python_cpu"] = _ratio(cpus, "python", "compiled")
    return res


def main() -> dict[str, float]:
    load0 = os.getloadavg()[0]
    two = _measure(5e-4, python_loop=True)
    one = _measure(1e-3, python_loop=False)
    res = {f"{k}_2x0.5ms": v for k, v in two.items()} | {f"{k}_1ms": v for k, v in one.items()}
    res["load_average_at_start"] = load0
    print(f"demo contact run (8.5 s simulated, 1 kHz control), medians of {REPEATS} rounds; load average {load0:.2f}")
    print(f"{'':34s}{'2 x 0.5 ms':>12s}{'1 x 1 ms':>12s}")
    for label, key in (
        ("compiled loop [x real time]", "compiled_x_realtime"),
        ("MuJoCo alone [x real time]", "mujoco_alone_x_realtime"),
        ("compiled / MuJoCo alone", "compiled_vs_mujoco_alone"),
        ("  same in CPU time", "compiled_vs_mujoco_alone_cpu"),
        ("compiled tick [us]", "compiled_tick_us"),
        ("MuJoCo alone tick [us]", "mujoco_alone_tick_us"),
        ("first detection [s]", "detection_t"),
        ("this machine's MuJoCo:", None),
        ("  arm alone, no scene [x real time]", "arm_alone_x_realtime"),
        ("  physics step [us]", "mujoco_step_us"),
        ("    of it collision [us]", "mujoco_collision_us"),
        ("    of it constraint [us]", "mujoco_constraint_us"),
    ):
        if key is None:
            print(label)
        else:
            print(f"{label:34s}{two[key]:12.3f}{one[key]:12.3f}")
    print(
        f"Python loop (2 x 0.5 ms): {two['python_x_realtime']:.1f}x real time; compiled loop "
        f"{two['compiled_vs_python']:.2f}x faster ({two['compiled_vs_python_cpu']:.2f}x in CPU time)"
    )
    print("targets: compiled >= 50x real time, >= 0.7x MuJoCo alone")
    return res


if __name__ == "__main__":
    main()
