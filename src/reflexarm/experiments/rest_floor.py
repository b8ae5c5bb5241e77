"""The kinetic energy an arm keeps at rest under its own controller and sensor noise: the floor of a reaction's
"at rest".

A reaction that has stopped the arm hands it to a hold: law (2) around a posture. The hold feeds the measured
joint positions and velocities back through K and D, so sensor noise keeps the arm trembling, and an arm without
joint friction keeps that motion longest. The issue-15 bar "kinetic energy below 1 % of its value at detection
within 0.5 s" can therefore lie below anything a hold can reach when the contact had already nearly stopped the
arm (a link running into a held obstacle: 3e-5 to 3e-4 J at detection, so the bar is 3e-7 to 3e-6 J).

:func:`rest_floor` measures that floor directly. The run's own controller (same setting, same perturbed model,
reaction "none") holds the arm still at a given posture, without contact, on the same plant (same true friction,
same sensor noise), for :data:`REST_FLOOR_S` seconds; the plant's true kinetic energy 0.5 dq^T M(q) dq over the
last :data:`REST_FLOOR_WINDOW_S` seconds (after the start's settling onto the model's gravity error) gives the
floor's median and its :data:`REST_FLOOR_QUANTILE` quantile. A reaction whose energy 0.5 s after detection is at
or below that quantile left the arm as still as the controller can hold it there.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from reflexarm.experiments.collision import CollisionSetting, _true_friction, controller_model
from reflexarm.experiments.collision_events import _kinetic_energy
from reflexarm.robots import RobotModel
from reflexarm.sim import PAPER_NOISE, JointTrajectory, Plant, SensorNoise
from reflexarm.sim.compiled_loop import run_fast

__all__ = ["REST_FLOOR_QUANTILE", "REST_FLOOR_S", "REST_FLOOR_WINDOW_S", "RestFloor", "floor_verdict", "rest_floor"]

#: How long the arm is held [s].
REST_FLOOR_S = 1.5
#: The window at the end of the hold the floor is taken from [s] (the hold settles onto the controller model's
#: gravity error in its first ~0.3 s; a mode at sqrt(K / M) with the modal damping's ratio decays within it).
REST_FLOOR_WINDOW_S = 1.0
#: The quantile of the window's energies that a single sample "at the floor" stays below: a sample of the
#: trembling is at or below it 95 % of the time.
REST_FLOOR_QUANTILE = 0.95


@dataclass(frozen=True)
class RestFloor:
    """The kinetic energy of the arm held at rest [J]: the median and the :data:`REST_FLOOR_QUANTILE` quantile
    over the window, and the largest."""

    median_J: float
    quantile_J: float
    max_J: float

    def as_dict(self) -> dict[str, float]:
        return {"rest_floor_median_J": self.median_J, "rest_floor_q95_J": self.quantile_J,
                "rest_floor_max_J": self.max_J}  # fmt: skip


def rest_floor(
    robot: RobotModel,
    setting: CollisionSetting,
    q: np.ndarray,
    *,
    model_error: float | None = None,
    model_seed: int = 0,
    noise: SensorNoise = PAPER_NOISE,
    seed: int = 0,
    plant_friction: str = "file",
) -> RestFloor:
    """The kinetic energy floor of ``robot`` held at posture ``q`` by ``setting``'s controller (module docstring).

    The arguments after ``q`` are those of :func:`~reflexarm.experiments.collision.run_ee_collision`: the
    controller's model error and its seed, the sensor noise and its seed, and the plant's true friction.
    """
    q = np.asarray(q, dtype=float).reshape(-1)
    ctrl_model, _ = controller_model(robot, model_error, model_seed, None)
    plant = Plant(robot, noise=noise, seed=seed, true_friction=_true_friction(robot, plant_friction))
    plant.reset(q)
    hold = JointTrajectory(np.stack([q, q]), [REST_FLOOR_S])
    ctrl = replace(setting, reaction="none").controller(ctrl_model)
    trace = run_fast(plant, ctrl, hold, REST_FLOOR_S)
    window = trace.t >= trace.t[-1] - REST_FLOOR_WINDOW_S + 1e-9
    ke = _kinetic_energy(robot, trace.q[window], trace.dq[window])
    return RestFloor(float(np.median(ke)), float(np.quantile(ke, REST_FLOOR_QUANTILE)), float(ke.max()))


def floor_verdict(row: dict[str, Any]) -> str | None:
    """How a row's kinetic energy 0.5 s after detection compares with its rest floor: "at floor" (at or below
    the floor's quantile), "above floor", or None without the numbers."""
    after, q95 = row.get("kinetic_energy_after_J"), row.get("rest_floor_q95_J")
    if after is None or q95 is None:
        return None
    return "at floor" if after <= q95 else "above floor"
