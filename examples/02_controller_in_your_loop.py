"""Run the Controller in your own 1 kHz loop: here against the MuJoCo plant, on a real robot the same
``step(measurement, reference)`` call sits in your control callback.

A 60 N push on the forearm during a hold is detected by the momentum observer (eq. (12)) and the arm
switches to gravity compensation (eq. (13)).

Run: .venv/bin/python examples/02_controller_in_your_loop.py
"""

from __future__ import annotations

import numpy as np

from reflexarm import Reference, load_robot
from reflexarm.control import Controller
from reflexarm.sim import PAPER_NOISE, Plant


def main() -> None:
    robot = load_robot("atlas_v5_left_arm")
    plant = Plant(robot, noise=PAPER_NOISE, seed=1)  # the "true" arm: Table I friction, noisy sensors
    q_hold = np.array([0.0, -1.3, 1.57, 1.57, 0.0, 0.0, 0.0])
    plant.reset(q_hold)
    ctrl = Controller(robot, stiffness=300.0, damping_ratio=0.7, observer_gain=5.0, threshold=11.0, reaction="gravity")
    reference = Reference.hold(q_hold)
    push = None
    for k in range(3000):  # 3 s at 1 kHz
        if k == 1000:  # at t = 1 s somebody pushes the forearm (at the wrist) with 60 N sideways
            _, wrist = robot.compute_frame_pose(plant.q, "wrist_ft")
            push = plant.apply_external_force(np.array([0.0, 60.0, 0.0]), point_world=wrist, body="l_larm")
        if k == 1500 and push is not None:
            plant.clear_external_force(push)
        m = plant.measure()
        cmd = ctrl.step(m, reference)
        plant.step(cmd.tau)
        if cmd.collided_joints and ctrl.detector is not None and ctrl.detector.first_time == m.t:
            print(
                f"t = {m.t:.3f} s: collision detected at joints {cmd.collided_joints}, "
                f"residual = {np.round(cmd.residual, 1)} Nm -> {cmd.mode}"
            )
    print(f"final mode: {cmd.mode}; |q - q_hold| = {np.abs(plant.q - q_hold).max():.3f} rad")


if __name__ == "__main__":
    main()
