"""Closed-loop simulation speed: plant (MuJoCo, 2 substeps) + Controller at 1 kHz, as a multiple of real time.

Baselines in the same run: the plant alone driven by a constant torque (what the simulation costs
without any controller), and the controller alone on the recorded measurements.
"""

from __future__ import annotations

import time

from reflexarm import load_robot
from reflexarm.control import Controller
from reflexarm.experiments.collision import EE_SETTINGS, ee_collision_trajectory, run_ee_collision
from reflexarm.sim import PAPER_NOISE, Plant, run_closed_loop

SIM_SECONDS = 8.5


def main() -> dict[str, float]:
    robot = load_robot("atlas_v5_left_arm")
    traj = ee_collision_trajectory()
    # plant only
    plant = Plant(robot, noise=PAPER_NOISE, seed=0)
    plant.reset(traj.sample(0.0).q_d)
    g = robot.compute_gravity(traj.sample(0.0).q_d)
    n = int(SIM_SECONDS / 1e-3)
    t0 = time.perf_counter()
    for _ in range(n):
        plant.measure()
        plant.step(g)
    t_plant = time.perf_counter() - t0
    # controller only, on measurements of a closed-loop run
    plant.reset(traj.sample(0.0).q_d)
    ctrl = Controller(robot, stiffness=300, observer_gain=5, threshold=11)
    ms, refs = [], []
    for k in range(n):
        m = plant.measure()
        r = traj.sample(k * 1e-3)
        plant.step(ctrl.step(m, r).tau)
        ms.append(m)
        refs.append(r)
    ctrl.reset()
    t0 = time.perf_counter()
    for m, r in zip(ms, refs, strict=True):
        ctrl.step(m, r)
    t_ctrl = time.perf_counter() - t0
    # the full loop in free motion: the demo trajectory without the block, runner and trace recording
    plant.reset(traj.sample(0.0).q_d)
    ctrl = Controller(robot, stiffness=300, observer_gain=5, threshold=11)
    t0 = time.perf_counter()
    run_closed_loop(plant, ctrl, traj, traj.duration)
    t_free = time.perf_counter() - t0
    # the full demo run (Coll.Det): scene with the cinderblock, runner, trace recording
    t0 = time.perf_counter()
    tr = run_ee_collision(EE_SETTINGS[2], seed=0)
    t_loop = time.perf_counter() - t0
    sim_t = float(tr.t[-1] - tr.t[0] + 1e-3)
    res = {
        "plant_only_x_realtime": SIM_SECONDS / t_plant,
        "controller_only_x_realtime": SIM_SECONDS / t_ctrl,
        "closed_loop_free_motion_x_realtime": traj.duration / t_free,
        "closed_loop_x_realtime": sim_t / t_loop,
        "plant_tick_us": t_plant / n * 1e6,
        "controller_tick_us": t_ctrl / n * 1e6,
        "closed_loop_tick_us": t_loop / (sim_t / 1e-3) * 1e6,
    }
    overhead = res["closed_loop_tick_us"] / (res["plant_tick_us"] + res["controller_tick_us"])
    print(
        f"plant alone (measure + step, 2 substeps): {res['plant_tick_us']:.1f} us/tick = "
        f"{res['plant_only_x_realtime']:.1f}x real time"
    )
    print(
        f"controller alone:                          {res['controller_tick_us']:.1f} us/tick = "
        f"{res['controller_only_x_realtime']:.1f}x real time"
    )
    print(
        f"closed loop, free motion ({traj.duration:.1f} s):     {t_free / traj.duration * 1e3:.1f} us/tick = "
        f"{res['closed_loop_free_motion_x_realtime']:.1f}x real time"
    )
    print(
        f"closed loop, demo Coll.Det run ({sim_t:.1f} s):  {res['closed_loop_tick_us']:.1f} us/tick = "
        f"{res['closed_loop_x_realtime']:.1f}x real time "
        f"(loop/(plant+controller) = {overhead:.2f})"
    )
    return res


if __name__ == "__main__":
    main()
