"""Vectorised joint-torque regressor: Y(q, dq, ddq) for many samples at once, eq. (14).

:meth:`RobotModel.compute_regressor` calls Pinocchio's ``computeJointTorqueRegressor`` once per sample
(about 5 us each plus Python overhead).
Identification stacks it over 10^4..10^5 samples, so this module evaluates the same recursive
Newton-Euler regressor for a whole batch in one compiled loop (numba): per sample, a forward pass gives
each link's spatial velocity and acceleration in its own frame (gravity enters as a base acceleration),
the body regressor (f = I a + v x* I v, linear in the 10 parameters) is moved to world coordinates about
the world origin, and row i of the joint regressor is the Plucker product of joint i's motion subspace
with the body regressors of the links j >= i. The result is exactly Pinocchio's regressor (same parameter
order, about each joint frame origin; see ``INERTIAL_PARAMETER_NAMES``); the tests check it against
Pinocchio sample by sample.

Only fixed-base serial chains of 1-DoF revolute or prismatic joints are supported, which is what
:class:`RobotModel` accepts.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from reflexarm.errors import DataError, ModelError
from reflexarm.ident.estimation._regressor_kernel import regressor_kernel
from reflexarm.robots.robot_model import RobotModel

__all__ = ["BatchRegressor", "compute_friction_regressor"]


class BatchRegressor:
    """Y(q, dq, ddq) of a :class:`RobotModel` for a batch of samples, vectorised over the samples.

    Args:
        robot: the arm; its kinematics and gravity are copied at construction (later changes to the
            robot's inertial parameters do not matter: the regressor does not depend on them).

    Rigid links only: a file's rotor armature and joint springs are not in Y (they have no link
    parameters); with them, ``robot.compute_inverse_dynamics == Y @ pi + I_a ddq + K_s (q - q_s)``, and
    identification subtracts them as known terms (:mod:`reflexarm.ident.estimation.known_terms`).

    Example:
        >>> reg = BatchRegressor(load_robot("panda"))
        >>> Y = reg.compute_regressor(q, dq, ddq)      # (N, n, 10 n)
        >>> np.allclose(np.einsum("kij,j->ki", Y, robot.inertial_parameters()), tau_rnea)
    """

    def __init__(self, robot: RobotModel) -> None:
        model = robot.pin_model
        self.n = robot.n
        self.robot_name = robot.name
        self._placement_R = np.empty((self.n, 3, 3))
        self._placement_p = np.empty((self.n, 3))
        self._axis = np.empty((self.n, 3))
        self._revolute = np.empty(self.n, dtype=bool)
        data = model.createData()
        for k in range(self.n):
            j = k + 1
            jp = model.jointPlacements[j]
            self._placement_R[k] = jp.rotation
            self._placement_p[k] = jp.translation
            # the joint's motion subspace S (in the joint frame) from its own transform at q = 1
            qj = np.zeros(model.nq)
            qj[model.idx_qs[j]] = 1.0
            pin.forwardKinematics(model, data, qj)
            rel = jp.inverse() * data.liMi[j]
            s = np.asarray(pin.log6(rel).vector)  # (linear, angular)
            qj[model.idx_qs[j]] = 0.5
            pin.forwardKinematics(model, data, qj)
            half = np.asarray(pin.log6(jp.inverse() * data.liMi[j]).vector)
            lin, ang = s[:3], s[3:]
            if np.linalg.norm(ang) > 1e-12 and np.linalg.norm(lin) < 1e-12 and np.allclose(half, 0.5 * s):
                self._revolute[k] = True
                self._axis[k] = ang / np.linalg.norm(ang)
            elif np.linalg.norm(ang) < 1e-12 and np.linalg.norm(lin) > 1e-12 and np.allclose(half, 0.5 * s):
                self._revolute[k] = False
                self._axis[k] = lin / np.linalg.norm(lin)
            else:
                raise ModelError(
                    f"joint {model.names[j]!r} of {robot.name!r} is neither revolute nor prismatic about a fixed "
                    "axis; the batch regressor supports only those"
                )
        self._gravity = np.asarray(model.gravity.linear, dtype=float).copy()

    # ------------------------------------------------------------------ helpers
    def _check(self, q: npt.ArrayLike, name: str) -> np.ndarray:
        arr = np.asarray(q, dtype=float)
        if arr.ndim == 1 and arr.shape == (self.n,):
            arr = arr[None, :]
        if arr.ndim != 2 or arr.shape[1] != self.n:
            raise DataError(f"{name} must have shape (N, {self.n}); got {arr.shape}")
        return arr

    # ------------------------------------------------------------------ the regressor
    def compute_regressor(self, q: npt.ArrayLike, dq: npt.ArrayLike, ddq: npt.ArrayLike) -> np.ndarray:
        """Y for each sample: (N, n, 10 n) with ``Y[k] @ pi == rnea(q[k], dq[k], ddq[k])``.

        Args:
            q: joint positions (N, n) [rad or m].
            dq: joint velocities (N, n).
            ddq: joint accelerations (N, n).
        """
        Q, DQ, DDQ = self._check(q, "q"), self._check(dq, "dq"), self._check(ddq, "ddq")
        if not (Q.shape == DQ.shape == DDQ.shape):
            raise DataError(f"q, dq, ddq must have the same shape; got {Q.shape}, {DQ.shape}, {DDQ.shape}")
        N, n = Q.shape
        Y = np.zeros((N, n, 10 * n))
        regressor_kernel(
            np.ascontiguousarray(Q),
            np.ascontiguousarray(DQ),
            np.ascontiguousarray(DDQ),
            self._placement_R,
            self._placement_p,
            self._axis,
            self._revolute,
            self._gravity,
            Y,
        )
        return Y

    def iter_chunks(
        self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray, chunk: int = 5000
    ) -> Iterator[tuple[slice, np.ndarray]]:
        """Yield ``(samples, Y)`` for consecutive chunks of ``chunk`` samples (bounded memory)."""
        N = np.asarray(q).shape[0]
        for s in range(0, N, chunk):
            sl = slice(s, min(N, s + chunk))
            yield sl, self.compute_regressor(q[sl], dq[sl], ddq[sl])


def compute_friction_regressor(dq: npt.ArrayLike, *, offset: bool = False) -> np.ndarray:
    """Phi_f of eq. (15) for a batch: (N, n, 2 n) = (diag(dq)  diag(sgn(dq))), optionally (N, n, 3 n).

    Parameter order (d_v, mu_C[, tau_off]), as :meth:`CoulombViscousFriction.parameters`. The sign is the
    exact one (sgn(0) = 0). With ``offset=True`` a constant torque per joint is appended (a sensor bias or
    a friction asymmetry; see :mod:`reflexarm.ident.estimation.identify`).
    """
    DQ = np.asarray(dq, dtype=float)
    if DQ.ndim == 1:
        DQ = DQ[None]
    N, n = DQ.shape
    k = 3 if offset else 2
    out = np.zeros((N, n, k * n))
    idx = np.arange(n)
    out[:, idx, idx] = DQ
    out[:, idx, n + idx] = np.sign(DQ)
    if offset:
        out[:, idx, 2 * n + idx] = 1.0
    return out
