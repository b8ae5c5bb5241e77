"""Shared checks of the controller-contract tests: plant copies and "is a push still detected in time?"."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from pinsim import RigidBodyPlant
from reflexarm.control import Controller
from reflexarm.robots import RobotModel
from reflexarm.signals import Reference

PUSH = 50.0  # [Nm] on joint PUSH_JOINT: the size of push the issue says was never detected once poisoned
PUSH_JOINT = 1


def copy_plant(plant: RigidBodyPlant, tau_ext: Callable[[float], np.ndarray] | None = None) -> RigidBodyPlant:
    """A plant in the same state (time, q, dq, last torque) with its own external torque."""
    other = type(plant).__new__(type(plant))
    other.__dict__.update(plant.__dict__)
    other.data = plant.model.createData()
    other.q, other.dq, other.last_tau = plant.q.copy(), plant.dq.copy(), plant.last_tau.copy()
    other.tau_ext = tau_ext
    return other


def push_from(t0: float, n: int) -> Callable[[float], np.ndarray]:
    push = np.zeros(n)
    push[PUSH_JOINT] = PUSH

    def tau_ext(t: float) -> np.ndarray:
        return push if t >= t0 else np.zeros(n)

    return tau_ext


def detection_tick(plant: RigidBodyPlant, ctrl: Controller, q_hold: np.ndarray, n_ticks: int) -> int | None:
    """Run the closed loop holding ``q_hold``; the index of the first tick whose command reports a collision."""
    ref = Reference.hold(q_hold)
    for k in range(n_ticks):
        cmd = ctrl.step(plant.measure(), ref)
        assert not cmd.fault, cmd.fault
        if cmd.collision:
            return k
        plant.step(cmd.tau)
    return None


def detected_as_by_a_fresh_controller(
    plant: RigidBodyPlant, ctrl: Controller, make: Callable[[], Controller], settle: float = 1.0, window: float = 0.5
) -> tuple[int | None, int | None]:
    """Detection tick of ``ctrl`` and of a fresh ``make()`` controller, each on its own copy of ``plant``
    holding the plant's current position, with a PUSH starting ``settle`` seconds from now."""
    n_ticks = round((settle + window) / plant.dt)
    t_push = plant.t + settle
    q_hold = plant.q.copy()
    a = detection_tick(copy_plant(plant, push_from(t_push, plant.n)), ctrl, q_hold, n_ticks)
    b = detection_tick(copy_plant(plant, push_from(t_push, plant.n)), make(), q_hold, n_ticks)
    return a, b


def settled_plant(robot: RobotModel, q0: np.ndarray, substeps: int = 10) -> RigidBodyPlant:
    plant = RigidBodyPlant(robot, substeps=substeps)
    plant.reset(q0)
    return plant
