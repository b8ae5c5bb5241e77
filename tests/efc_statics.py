"""Static predictions for the Fig. 12 (efc-step) tests: where controller (2) holds the arm under the load.

At rest (dq = 0, so the smooth friction of plant and model vanishes) controller (2) on the model
(g_hat) and the true arm (g) balance as

* no DC (kappa_eps = 0):      K (q - q_d) = J(q)^T F - e(q),   e := g - g_hat;
* DC + EFC (kappa_eps = kappa_ext = 1): the converged observer output is r = delta + tau_ext - J^T F_s
  = -e(q) (exact wrist sensor, unperturbed kinematics), so K (q - q_d) = J(q)^T F (eq. (11)).

F is the world force of :class:`reflexarm.sim.EndEffectorForce` (default direction: from the end
effector towards the wrist sensor, resolved at the posture where it switches on, then fixed in the world).
The no-DC posture before the load is therefore offset by K^-1 e, and that offset moves the direction of F.
"""

from __future__ import annotations

import numpy as np

from reflexarm.robots import RobotModel

#: Fixed-point iterations of the equilibrium: the map's contraction factor is |d(J^T F - e)/dq| / k
#: (< 0.05 here: 50 N on a < 1 m lever, +-10 % gravity errors, against 150 Nm/rad), so 60 iterations
#: reach machine precision.
ITERATIONS = 60


def ee_position(robot: RobotModel, q: np.ndarray) -> np.ndarray:
    """End-effector position [m] in the base frame."""
    return robot.compute_frame_pose(q, None)[1]


def world_force(robot: RobotModel, q_on: np.ndarray, magnitude: float) -> np.ndarray:
    """The default end-effector force [N] (world frame) switched on at posture ``q_on``."""
    axis = ee_position(robot, q_on) - robot.compute_frame_pose(q_on, robot.sensor_frame)[1]
    return -magnitude * axis / np.linalg.norm(axis)


def load_torque(robot: RobotModel, q: np.ndarray, force: np.ndarray) -> np.ndarray:
    """J(q)^T F [Nm] of a world force at the end effector."""
    return robot.compute_frame_jacobian(q, robot.ee_frame, world_aligned=True)[:3].T @ force


def equilibrium(
    robot: RobotModel, model: RobotModel | None, stiffness: float, q_d: np.ndarray, force: np.ndarray
) -> np.ndarray:
    """q with K (q - q_d) = J(q)^T F - (g - g_hat)(q); ``model`` None drops the gravity error (DC + EFC)."""
    q = q_d.copy()
    for _ in range(ITERATIONS):
        err = 0.0 if model is None else robot.compute_gravity(q) - model.compute_gravity(q)
        q = q_d + (load_torque(robot, q, force) - err) / stiffness
    return q


def static_displacement(
    robot: RobotModel, model: RobotModel | None, stiffness: float, q_d: np.ndarray, magnitude: float
) -> tuple[float, np.ndarray, np.ndarray]:
    """(|EE displacement| [m], posture before, posture under the load) at rest, force switched on at rest."""
    q0 = equilibrium(robot, model, stiffness, q_d, np.zeros(3))
    force = world_force(robot, q0, magnitude)
    q1 = equilibrium(robot, model, stiffness, q_d, force)
    return float(np.linalg.norm(ee_position(robot, q1) - ee_position(robot, q0))), q0, q1


def in_band_damping(robot: RobotModel, model: RobotModel, damping_diagonal: np.ndarray) -> np.ndarray:
    """Net damping [Nms/rad] of each joint inside the friction band |dq| < band, with kappa_f = 1.

    The true arm's smooth friction mu_C dq / band + d_v dq, minus the controller's compensation
    mu_C_hat dq / band + d_v_hat dq, plus the impedance damping D_ii of (2). Negative: the
    over-compensated friction feeds energy into that joint faster than D removes it, so the joint
    does not come to rest (it oscillates inside the band).
    """
    true, hat = robot.friction, model.friction
    band = true.velocity_band
    return np.asarray(damping_diagonal + (true.coulomb - hat.coulomb) / band + (true.viscous - hat.viscous))
