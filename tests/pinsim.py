"""A minimal independent plant for control tests: Pinocchio forward dynamics (ABA) integrated with RK4.

It has no friction, no contacts and no noise, so the exact-model promises of the observer and the
impedance law can be checked without MuJoCo in the loop.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pinocchio as pin

from reflexarm.robots import RobotModel
from reflexarm.signals import Measurement


class RigidBodyPlant:
    """M ddq + C dq + g = tau_m + tau_ext(t) + posture_torque(t, q), integrated with RK4 at ``substeps`` per control
    period (``posture_torque``: an external torque that depends on the posture, e.g. J_c(q)^T f of a contact force)."""

    def __init__(
        self,
        robot: RobotModel,
        dt: float = 1e-3,
        substeps: int = 10,
        tau_ext: Callable[[float], np.ndarray] | None = None,
        posture_torque: Callable[[float, np.ndarray], np.ndarray] | None = None,
    ) -> None:
        self.model = robot.pin_model.copy()
        self.data = self.model.createData()
        self.dt = dt
        self.h = dt / substeps
        self.substeps = substeps
        self.tau_ext = tau_ext
        self.posture_torque = posture_torque
        self.n = self.model.nv
        self.t = 0.0
        self.q = np.zeros(self.n)
        self.dq = np.zeros(self.n)
        self.last_tau = np.zeros(self.n)

    def reset(self, q0: np.ndarray, dq0: np.ndarray | None = None) -> None:
        self.t = 0.0
        self.q = np.array(q0, dtype=float)
        self.dq = np.zeros(self.n) if dq0 is None else np.array(dq0, dtype=float)

    def measure(self) -> Measurement:
        return Measurement(
            self.t, self.q.copy(), self.dq.copy(), self.last_tau.copy(), np.zeros(6), np.array([0.0, 0.0, -9.81])
        )

    def _f(self, t: float, q: np.ndarray, dq: np.ndarray, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        total = tau if self.tau_ext is None else tau + self.tau_ext(t)
        if self.posture_torque is not None:
            total = total + self.posture_torque(t, q)
        return dq, pin.aba(self.model, self.data, q, dq, total)

    def step(self, tau: np.ndarray) -> None:
        self.last_tau = np.array(tau, dtype=float)
        h = self.h
        q, dq, t = self.q, self.dq, self.t
        for _ in range(self.substeps):
            k1q, k1v = self._f(t, q, dq, tau)
            k2q, k2v = self._f(t + h / 2, q + h / 2 * k1q, dq + h / 2 * k1v, tau)
            k3q, k3v = self._f(t + h / 2, q + h / 2 * k2q, dq + h / 2 * k2v, tau)
            k4q, k4v = self._f(t + h, q + h * k3q, dq + h * k3v, tau)
            q = q + h / 6 * (k1q + 2 * k2q + 2 * k3q + k4q)
            dq = dq + h / 6 * (k1v + 2 * k2v + 2 * k3v + k4v)
            t += h
        self.q, self.dq, self.t = q, dq, self.t + self.dt
