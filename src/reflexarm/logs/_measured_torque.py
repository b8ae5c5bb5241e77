"""b of (19): the measured torque the regression explains (external torque of the wrist wrench added)."""

from __future__ import annotations

import numpy as np

from reflexarm.logs.robot_log import RobotLog
from reflexarm.robots.robot_model import RobotModel


def _rhs(robot: RobotModel, log: RobotLog) -> np.ndarray:
    """b of (19): measured torque plus the external torque of the wrist wrench, eq. (14)."""
    tau = log.tau.copy()
    if log.wrench is not None:
        for k in range(len(log)):
            tau[k] += robot.compute_frame_jacobian(log.q[k]).T @ log.wrench[k]
    return tau
