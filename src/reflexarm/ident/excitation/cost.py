"""The excitation's free variables (:class:`Parametrisation`: Fourier coefficients at rest at t = 0) and its
cost, the log condition number of the base regressor over one period, with its exact gradient (Pinocchio's
RNEA derivatives)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from reflexarm.ident.estimation.base_parameters import BaseParameters
from reflexarm.ident.estimation.regressor import BatchRegressor
from reflexarm.ident.excitation.fourier_trajectory import FourierTrajectory
from reflexarm.robots.robot_model import RobotModel

__all__ = ["Parametrisation", "log_condition", "log_condition_gradient"]


class Parametrisation:
    """Free variables (a_i2..a_iL, b_i2..b_iL, q0_i per joint) <-> (a, b, q0) at rest at t = 0."""

    def __init__(self, n: int, L: int, base_frequency: float) -> None:
        self.n, self.L = n, L
        self.size = n * (2 * (L - 1) + 1)
        self.l = np.arange(1, L + 1)
        self.base_frequency = base_frequency

    def unpack(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        n, L = self.n, self.L
        X = x.reshape(n, 2 * (L - 1) + 1)
        a = np.empty((n, L))
        b = np.empty((n, L))
        a[:, 1:] = X[:, : L - 1]
        b[:, 1:] = X[:, L - 1 : 2 * (L - 1)]
        a[:, 0] = -a[:, 1:].sum(axis=1)  # dq(0) = sum_l a_l = 0
        b[:, 0] = -(b[:, 1:] * self.l[1:]).sum(axis=1)  # ddq(0) ~ sum_l l b_l = 0
        return a, b, X[:, -1]

    def pack(self, a: np.ndarray, b: np.ndarray, q0: np.ndarray) -> np.ndarray:
        return np.column_stack([a[:, 1:], b[:, 1:], q0]).reshape(-1)

    def trajectory(self, x: np.ndarray) -> FourierTrajectory:
        a, b, q0 = self.unpack(x)
        return FourierTrajectory(self.base_frequency, a, b, q0)

    def linear_maps(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(Gq, Gv, Ga), each (N, n, size): q(t_k) = Gq[k] x (and dq, ddq likewise); q, dq, ddq are linear in x."""
        cols = [self.trajectory(e).evaluate(t) for e in np.eye(self.size)]
        return tuple(np.stack([c[i] for c in cols], axis=-1) for i in range(3))  # type: ignore[return-value]

    def scaled(self, x: np.ndarray, s: float) -> np.ndarray:
        """The amplitudes times s about the same offsets q0."""
        a, b, q0 = self.unpack(x)
        return self.pack(a * s, b * s, q0)


def log_condition(
    robot: RobotModel, base: BaseParameters, par: Parametrisation, t_cost: np.ndarray
) -> Callable[[np.ndarray], float]:
    """The cost: log of the condition number of the base regressor stacked over ``t_cost``."""
    reg = BatchRegressor(robot)

    def log_cond(x: np.ndarray) -> float:
        q, dq, ddq = par.trajectory(x).evaluate(t_cost)
        W = base.select(reg.compute_regressor(q, dq, ddq)).reshape(-1, base.n_base)
        # cond(W) = sqrt(cond(W^T W)); eigvalsh of the small Gram matrix is ~10x cheaper than an SVD of W
        ev = np.linalg.eigvalsh(W.T @ W)
        return float(0.5 * np.log(ev[-1] / max(ev[0], 1e-300)))

    return log_cond


def log_condition_gradient(
    robot: RobotModel, base: BaseParameters, par: Parametrisation, t_cost: np.ndarray
) -> Callable[[np.ndarray], np.ndarray]:
    """d log cond / dx, exact: with G = W^T W and its extreme eigenpairs (lambda, v), d lambda = 2 (W v)^T
    (dW v), and W v stacks the joint torques Y_b(q, dq, ddq) v, i.e. inverse dynamics with the inertial
    parameters pi_v (v on the base columns): its derivatives come from Pinocchio's RNEA derivatives, taken
    as the difference of a model with pi_0 + pi_v and one with pi_0 (pi_0 the file's parameters, so every
    link keeps a positive mass; torques are linear in the parameters)."""
    import pinocchio as pin

    reg = BatchRegressor(robot)
    Gq, Gv, Ga = par.linear_maps(t_cost)
    model0 = robot.pin_model
    pi0 = robot.inertial_parameters()
    models = [pin.Model(model0), pin.Model(model0)]
    datas = [m.createData() for m in models]
    data0 = model0.createData()
    n = robot.n

    def torque_derivatives(model: pin.Model, data: pin.Data, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray):  # type: ignore[no-untyped-def]
        pin.computeRNEADerivatives(model, data, q, dq, ddq)
        M = np.triu(data.M) + np.triu(data.M, 1).T  # Pinocchio fills the upper triangle
        return np.array(data.dtau_dq), np.array(data.dtau_dv), M

    def gradient(x: np.ndarray) -> np.ndarray:
        q, dq, ddq = par.trajectory(x).evaluate(t_cost)
        W = base.select(reg.compute_regressor(q, dq, ddq)).reshape(-1, base.n_base)
        ev, V = np.linalg.eigh(W.T @ W)
        grad = np.zeros(par.size)
        for sign, k, model, data in ((1.0, -1, models[0], datas[0]), (-1.0, 0, models[1], datas[1])):
            v = V[:, k] / np.max(np.abs(V[:, k]))  # scaled to O(1) parameters (the derivative is linear in v)
            pi_v = np.zeros(10 * n)
            pi_v[base.independent] = v
            scale = 1e-2 * max(float(np.max(np.abs(pi0))), 1.0) / max(float(np.max(np.abs(pi_v))), 1e-300)
            pi = pi0 + scale * pi_v
            for j in range(n):
                model.inertias[j + 1] = pin.Inertia.FromDynamicParameters(pi[10 * j : 10 * j + 10])
            Wv = (W @ v).reshape(-1, n)
            g = np.zeros(par.size)
            for s in range(t_cost.size):
                a = torque_derivatives(model, data, q[s], dq[s], ddq[s])
                b = torque_derivatives(model0, data0, q[s], dq[s], ddq[s])
                dtau = ((a[0] - b[0]) @ Gq[s] + (a[1] - b[1]) @ Gv[s] + (a[2] - b[2]) @ Ga[s]) / scale
                g += Wv[s] @ dtau
            lam = max(float(ev[k]), 1e-300) * float(np.max(np.abs(V[:, k]))) ** -2  # lambda for the scaled v
            grad += sign * 0.5 * 2.0 * g / lam
        return grad

    return gradient
