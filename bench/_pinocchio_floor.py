"""The Pinocchio objects of a tick's "floor" (its four dynamics calls plus the EFC Jacobian, made from Python),
shared by bench_controller.py and bench_cpp_core.py. Each bench writes its own call closure over them, so no
extra Python call level is added to the floor it times."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class FloorData:
    model: Any  # the robot's model (gravity, Coriolis, Jacobian)
    model0: Any  # the same model without gravity (the two RNEAs)
    d_g: Any
    d_c: Any
    d_j: Any
    d_p: Any
    d_ff: Any
    zeros: np.ndarray
    fid: int


def floor_data(robot: Any) -> FloorData:
    """Copies of ``robot``'s Pinocchio model (with and without gravity) and one Data per call."""
    model = robot.pin_model.copy()
    model0 = model.copy()
    model0.gravity.linear = np.zeros(3)
    return FloorData(
        model, model0, model.createData(), model.createData(), model.createData(),
        model0.createData(), model0.createData(), np.zeros(robot.n), robot.sensor_frame_id,
    )  # fmt: skip
