"""Closed-loop simulation speed on the demo contact run (Figs. 7-8, Coll.Det, cinderblock), as a multiple of
real time: the compiled loop (reflexarm.sim.compiled_loop) next to MuJoCo stepping alone with the same
physics step, and the Python loop (run_closed_loop), in one process, medians of REPEATS runs.

"MuJoCo alone" replays the compiled run's recorded torques into the same plant from the same state
(``_closed_loop.replay_torques``: the torque written to ``qfrc_applied``, then the physics steps, in C++), so
it integrates exactly the same motion and contacts (checked: same final state) without sensors, controller,
reference or recording. Issue targets: compiled loop >= 50x real time and >= 0.7x MuJoCo alone.
Physics steps: two 0.5 ms substeps per 1 ms tick (the plant's default) and one 1 ms step.
"""

from __future__ import annotations

import os
import statistics
import time
from typing import Any

import numpy as np

from reflexarm import load_robot
from reflexarm.experiments import collision as C
from reflexarm.sim import PAPER_NOISE, Cinderblock, Plant, run_closed_loop
from reflexarm.sim.compiled_loop import run_compiled

REPEATS = 3


def _demo(timestep: float) -> tuple[Plant, Any, Any, Any]:
    robot = load_robot(C.ROBOT)
    model, _ = C.controller_model(robot, None, 0, None)
    traj = C.ee_collision_trajectory()
    plant = Plant(robot, scene=Cinderblock(**C._block("paper")), noise=PAPER_NOISE, seed=0, timestep=timestep)
    return plant, C.EE_SETTINGS[2].controller(model), traj, traj.sample(0.0).q_d


def _median_time(fn: Any, cpu: list[float] | None = None) -> float:
    """Median wall time of REPEATS calls; the median CPU time of this process is appended to ``cpu``."""
    times, cpus = [], []
    for _ in range(REPEATS):
        c0, t0 = time.process_time(), time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    if cpu is not None:
        cpu.append(statistics.median(cpus))
    return statistics.median(times)


def _measure(timestep: float, python_loop: bool) -> dict[str, float]:
    import reflexarm._closed_loop as cl

    plant, ctrl, traj, q0 = _demo(timestep)
    sim_s = traj.duration
    traces = []

    def compiled() -> None:
        plant.reset(q0)
        traces.append(run_compiled(plant, ctrl, traj, sim_s))

    cpu: list[float] = []
    t_comp = _median_time(compiled, cpu)
    tr = traces[-1]
    q_end = plant.q
    tau = np.ascontiguousarray(tr.tau)

    def alone() -> None:
        plant.reset(q0)
        cl.replay_torques(plant.model._address, plant.data._address, tau, plant._arm_dofs, plant.substeps)

    t_mj = _median_time(alone, cpu)
    if not np.array_equal(plant.q, q_end):
        raise AssertionError("the replay did not reproduce the compiled run's motion: the baseline is not comparable")
    res = {
        "compiled_x_realtime": sim_s / t_comp,
        "mujoco_alone_x_realtime": sim_s / t_mj,
        "compiled_vs_mujoco_alone": t_mj / t_comp,
        # the same ratio in CPU time of this process: less sensitive to other processes on the machine
        "compiled_vs_mujoco_alone_cpu": cpu[1] / cpu[0],
        "compiled_tick_us": t_comp / len(tr.t) * 1e6,
        "mujoco_alone_tick_us": t_mj / len(tr.t) * 1e6,
        "detection_t": float(tr.t[np.argmax(tr.collision)]) if tr.collision.any() else float("nan"),
    }
    if python_loop:

        def python() -> None:
            plant.reset(q0)
            run_closed_loop(plant, ctrl, traj, sim_s)

        t_py = _median_time(python, cpu)
        res["python_x_realtime"] = sim_s / t_py
        res["compiled_vs_python"] = t_py / t_comp
        res["compiled_vs_python_cpu"] = cpu[2] / cpu[0]
    return res


def main() -> dict[str, float]:
    load0 = os.getloadavg()[0]
    two = _measure(5e-4, python_loop=True)
    one = _measure(1e-3, python_loop=False)
    res = {f"{k}_2x0.5ms": v for k, v in two.items()} | {f"{k}_1ms": v for k, v in one.items()}
    res["load_average_at_start"] = load0
    print(f"demo contact run (8.5 s simulated, 1 kHz control), medians of {REPEATS}; load average {load0:.2f}")
    print(f"{'':28s}{'2 x 0.5 ms':>14s}{'1 x 1 ms':>14s}")
    for label, key in (
        ("compiled loop [x real time]", "compiled_x_realtime"),
        ("MuJoCo alone [x real time]", "mujoco_alone_x_realtime"),
        ("compiled / MuJoCo alone", "compiled_vs_mujoco_alone"),
        ("  same in CPU time", "compiled_vs_mujoco_alone_cpu"),
        ("compiled tick [us]", "compiled_tick_us"),
        ("MuJoCo alone tick [us]", "mujoco_alone_tick_us"),
        ("first detection [s]", "detection_t"),
    ):
        print(f"{label:28s}{two[key]:14.3f}{one[key]:14.3f}")
    print(
        f"Python loop (2 x 0.5 ms): {two['python_x_realtime']:.1f}x real time; compiled loop "
        f"{two['compiled_vs_python']:.2f}x faster ({two['compiled_vs_python_cpu']:.2f}x in CPU time)"
    )
    print("targets: compiled >= 50x real time, >= 0.7x MuJoCo alone")
    return res


if __name__ == "__main__":
    main()
