"""Load the built-in Atlas v5 left arm and evaluate the terms of the arm model (1).

Run: .venv/bin/python examples/01_robot_model.py
"""

from __future__ import annotations

import numpy as np

from reflexarm import load_robot


def main() -> None:
    robot = load_robot("atlas_v5_left_arm")
    q = robot.home
    dq = np.full(robot.n, 0.2)
    np.set_printoptions(precision=3, suppress=True)
    print(robot)
    print("M(q) diagonal     [kg m^2]:", np.diag(robot.compute_mass_matrix(q)))
    print("g(q)              [Nm]    :", robot.compute_gravity(q))
    print("C(q,dq) dq        [Nm]    :", robot.compute_coriolis_matrix(q, dq) @ dq)
    print("tau_f(dq)         [Nm]    :", robot.friction.compute_torque(dq))
    print("end effector      [m]     :", robot.compute_frame_pose(q)[1])
    print("regressor shape           :", robot.compute_regressor(q, dq, dq).shape)


if __name__ == "__main__":
    main()
