"""Joint impedance control, eq. (2), with modal damping by double diagonalization."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from reflexarm._validation import as_switch, as_vector
from reflexarm.control._setup import load_core
from reflexarm.errors import ConfigError
from reflexarm.robots.robot_model import RobotModel
from reflexarm.signals import Reference

__all__ = ["ImpedanceGains", "JointImpedanceController", "modal_damping"]


class ImpedanceGains(NamedTuple):
    """Joint stiffness K = diag(k_i) [Nm/rad] and modal damping ratios D_xi = diag(d_xi_i) [-]."""

    stiffness: np.ndarray
    damping_ratio: np.ndarray

    @classmethod
    def create(cls, n: int, stiffness: npt.ArrayLike, damping_ratio: npt.ArrayLike = 0.7) -> ImpedanceGains:
        """Validated gains: stiffness positive, damping ratio non-negative; scalars broadcast to (n,)."""
        return cls(
            as_vector(stiffness, n, "stiffness", positive=True),
            as_vector(damping_ratio, n, "damping_ratio", nonnegative=True),
        )


def modal_damping(mass_matrix: np.ndarray, stiffness: np.ndarray, damping_ratio: np.ndarray) -> np.ndarray:
    """Damping matrix D of (2) from the double diagonalization of M and K.

    With M = L L^T (Cholesky) and L^-1 K L^-T = U diag(lambda) U^T, the modal coordinates
    z = U^T L^T q decouple M and K into I and diag(lambda); damping each mode with ratio d_xi_i gives
    D = L U diag(2 d_xi_i sqrt(lambda_i)) U^T L^T. ``damping_ratio[i]`` applies to the i-th mode in
    ascending order of lambda (give a scalar/uniform ratio when the order should not matter).

    Args:
        mass_matrix: M(q), symmetric positive definite (n, n).
        stiffness: diagonal of K (n,) [Nm/rad].
        damping_ratio: modal damping ratios (n,).
    """
    M = np.ascontiguousarray(mass_matrix, dtype=float)
    if M.ndim != 2 or not np.all(np.isfinite(M)) or np.any(np.linalg.eigvalsh(M) <= 0.0):
        raise ConfigError(f"mass matrix is not symmetric positive definite; got {M.tolist()}")
    D = _modal_damping_or_none(M, stiffness, damping_ratio)
    if D is None:
        raise ConfigError(f"mass matrix is not symmetric positive definite; got {M.tolist()}")
    return D


def _modal_damping_or_none(M: np.ndarray, stiffness: npt.ArrayLike, damping_ratio: npt.ArrayLike) -> np.ndarray | None:
    """D from the upper triangle of M by the C++ core (the tick's own routine); None if M is unusable."""
    D = load_core().modal_damping(
        np.asarray(M, dtype=float), np.asarray(stiffness, dtype=float), np.asarray(damping_ratio, dtype=float)
    )
    return None if D is None else np.asarray(D)


class JointImpedanceController:
    """tau_d = K(q_d - q) + D(dq_d - dq) + g(q) + C(q,dq)dq + M(q_d)ddq_d + kappa_f tau_f(dq) - kappa_eps tau_eps.

    Eq. (2) of the paper, on its own (without the observer: pass ``disturbance`` to
    :meth:`compute_torque` for the last term). :class:`reflexarm.control.Controller` composes it with the
    momentum observer and collision handling and shares the dynamics terms between them.

    Args:
        robot: the controller's model (M_hat, C_hat, g_hat, tau_f_hat); a private copy is kept.
        stiffness: K, diagonal [Nm/rad]; scalar or (n,), positive.
        damping_ratio: D_xi, modal damping ratios [-]; scalar or (n,), non-negative.
        kappa_f: friction compensation switch (0/1).
        damping_update_period: recompute D from M(q) every this many calls (1 = every call). M(q)
            changes slowly against the control rate; the default, every 10th call (100 Hz at 1 kHz),
            keeps the double diagonalization off most control ticks.
    """

    def __init__(
        self,
        robot: RobotModel,
        *,
        stiffness: npt.ArrayLike,
        damping_ratio: npt.ArrayLike = 0.7,
        kappa_f: int = 0,
        damping_update_period: int = 10,
    ) -> None:
        self.robot = robot.copy()
        n = self.robot.n
        self.n = n
        self.gains = ImpedanceGains.create(n, stiffness, damping_ratio)
        self.kappa_f = as_switch(kappa_f, "kappa_f")
        if not isinstance(damping_update_period, (int, np.integer)) or damping_update_period < 1:
            raise ConfigError(f"damping_update_period must be a positive integer; got {damping_update_period!r}")
        self.damping_update_period = int(damping_update_period)
        self._model = self.robot.pin_model
        self._data = self._model.createData()
        self.model_no_gravity = self._model.copy()  # for M(q) x products as RNEA(q, 0, x)
        self.model_no_gravity.gravity.linear = np.zeros(3)
        self._data_ff = self.model_no_gravity.createData()
        self._zeros = np.zeros(n)
        self.damping = np.zeros((n, n))
        self._M = np.zeros((n, n))
        self.damping_ok = True  # False after an update_damping refused an unusable M(q)
        self._calls = 0

    @property
    def stiffness(self) -> np.ndarray:
        return self.gains.stiffness

    @property
    def damping_ratio(self) -> np.ndarray:
        return self.gains.damping_ratio

    def reset(self) -> None:
        self._calls = 0

    def update_damping(self, q: np.ndarray) -> np.ndarray:
        """Recompute D from M(q) now (in place) and return it.

        Never raises on bad values: if q or M(q) is unusable (non-finite, not positive definite) D stays
        as it was and :attr:`damping_ok` is False.
        """
        M = pin.crba(self._model, self._data, q)  # upper triangle filled; the core reads only that
        self._M[:] = M
        D = _modal_damping_or_none(self._M, self.gains.stiffness, self.gains.damping_ratio)
        self.damping_ok = D is not None
        if D is not None:
            self.damping[:] = D
        return self.damping

    def maybe_update_damping(self, q: np.ndarray) -> bool:
        """Update D if this call falls on the damping update period; False if that update was refused."""
        ok = True
        if self._calls % self.damping_update_period == 0:
            self.update_damping(q)
            ok = self.damping_ok
        self._calls += 1
        return ok

    def compute_feedforward(self, q_d: np.ndarray, ddq_d: np.ndarray) -> np.ndarray:
        """M_hat(q_d) ddq_d [Nm] (one RNEA with gravity off and zero velocity)."""
        return pin.rnea(self.model_no_gravity, self._data_ff, q_d, self._zeros, ddq_d)

    def compute_torque(
        self,
        q: npt.ArrayLike,
        dq: npt.ArrayLike,
        reference: Reference,
        disturbance: npt.ArrayLike | None = None,
    ) -> np.ndarray:
        """Eq. (2) computed from scratch (convenience API; the composed Controller is the fast path).

        Args:
            q, dq: measured joint position [rad] and velocity [rad/s].
            reference: desired q_d, dq_d, ddq_d.
            disturbance: kappa_eps * tau_eps_hat to subtract [Nm] (None: no compensation).
        """
        q = np.asarray(q, dtype=float)
        dq = np.asarray(dq, dtype=float)
        self.maybe_update_damping(q)
        nle = pin.nonLinearEffects(self._model, self._data, q, dq)
        if self.robot.has_springs:
            nle = nle + self.robot.compute_spring_torque(q)
        tau = self.gains.stiffness * (reference.q_d - q) + self.damping @ (reference.dq_d - dq) + nle
        tau = tau + self.compute_feedforward(np.asarray(reference.q_d, float), np.asarray(reference.ddq_d, float))
        if self.kappa_f:
            tau = tau + self.robot.friction.compute_torque(dq)
        if disturbance is not None:
            tau = tau - np.asarray(disturbance, dtype=float)
        return np.asarray(tau)
