"""The disturbance-observer family: interface shared by observers of external/disturbance torques."""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np

__all__ = ["DisturbanceObserver"]


class DisturbanceObserver(ABC):
    """Estimates the disturbance torque tau_eps_hat acting on the joints.

    Implementations keep their own state; :meth:`reset` restarts them from a measured state.
    """

    @property
    @abstractmethod
    def residual(self) -> np.ndarray:
        """The current estimate tau_eps_hat (n,) [Nm] (a view; copy it to keep it)."""

    @abstractmethod
    def reset(self, momentum: np.ndarray | None = None) -> None:
        """Restart: zero the estimate; ``momentum`` is the generalized momentum p = M(q) dq at restart."""

    @abstractmethod
    def compute_residual(
        self,
        momentum: np.ndarray,
        tau_m: np.ndarray,
        gamma: np.ndarray,
        alpha: np.ndarray | None,
    ) -> np.ndarray:
        """Advance one sample and return tau_eps_hat.

        Args:
            momentum: p = M_hat(q) dq (n,) [Nms].
            tau_m: measured motor torque (n,) [Nm].
            gamma: g_hat(q) - C_hat^T(q, dq) dq, eq. (5) (n,) [Nm].
            alpha: kappa_f tau_f_hat(dq) - kappa_ext J^T F_ext, eq. (6) (n,) [Nm]; ``None`` for zero.
        """
