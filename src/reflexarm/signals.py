"""The data that crosses the control boundary each tick: Measurement in, Reference in, Command out.

These are the contract between a robot (real, or the simulated plant in :mod:`reflexarm.sim`) and the
:class:`reflexarm.control.Controller`. Arrays are float64, SI units, the model's joint order.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["Command", "Measurement", "Reference"]


class Measurement(NamedTuple):
    """What a torque-controlled arm reports each tick.

    Attributes:
        t: time [s].
        q: joint positions (n,) [rad].
        dq: joint velocities (n,) [rad/s].
        tau_m: measured actuator (motor) torques (n,) [Nm].
        wrench: load-compensated wrist wrench (f_x, f_y, f_z, m_x, m_y, m_z) acting on the arm beyond the
            sensor, in the sensor frame, about its origin (6,) [N, Nm]; zeros if there is no sensor.
        gravity: gravity vector in the base frame (3,) [m/s^2].
    """

    t: float
    q: np.ndarray
    dq: np.ndarray
    tau_m: np.ndarray
    wrench: np.ndarray
    gravity: np.ndarray


class Reference(NamedTuple):
    """Desired joint trajectory sample: q_d [rad], dq_d [rad/s], ddq_d [rad/s^2], each (n,)."""

    q_d: np.ndarray
    dq_d: np.ndarray
    ddq_d: np.ndarray

    @classmethod
    def hold(cls, q_d: np.ndarray) -> Reference:
        """Hold a position (zero velocity and acceleration)."""
        q = np.asarray(q_d, dtype=float)
        return cls(q, np.zeros_like(q), np.zeros_like(q))


class Command(NamedTuple):
    """What :meth:`Controller.step` returns.

    Attributes:
        tau: commanded motor torque tau_d (n,) [Nm]; always finite.
        residual: observer output tau_eps_hat (n,) [Nm] that the collision detector looks at (the
            detection observer's when two observers run in parallel), before the compensation cut-off.
        collision: True once a collision has been detected (latched until ``reset``); also True in every
            command while the observer state is invalid (detection off, ``fault`` says so), never False
            from an invalid residual.
        collided_joints: 0-based indices (the model's joint order) of joints whose |residual| exceeded the
            threshold this tick; command-line outputs and flags number joints from 1.
        mode: active control mode name (see :mod:`reflexarm.control.modes`).
        fault: non-empty when the tick's inputs broke the controller's contract (or its observer is
            invalid) and the safe command was sent: names the signal, the component, the value and the bound.
        saturated: joints whose torque was limited this tick (``torque_limit`` or ``torque_rate_limit``).
        fault_code: 0, or the fault's code (``reflexarm.control.contract.FAULT_CODES``).
    """

    tau: np.ndarray
    residual: np.ndarray
    collision: bool
    collided_joints: tuple[int, ...]
    mode: str
    fault: str
    saturated: tuple[int, ...] = ()
    fault_code: int = 0
