"""Generalized-momentum disturbance observer, eqs. (4)-(6), in discrete time."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from reflexarm._validation import as_positive_scalar, as_vector
from reflexarm.control.observer import DisturbanceObserver
from reflexarm.errors import ConfigError

__all__ = ["MomentumObserver"]


class MomentumObserver(DisturbanceObserver):
    """tau_eps_hat = K_o (p - p(0) - integral(tau_m - gamma + tau_eps_hat - alpha)), eq. (4).

    Discretised with the explicit (forward) Euler rule at the control period ``dt``: each sample the
    integral grows by ``dt * (tau_m - gamma - alpha + tau_eps_hat_previous)``. The estimate then follows
    the true disturbance with the discrete first-order law ``r_k = r_(k-1) + k_o dt (tau_eps - r_(k-1))``,
    i.e. eq. (8) with time constant ``-dt / ln(1 - k_o dt)`` (= 1/k_o to within 0.3 % for k_o dt <= 0.005).

    Args:
        n: number of joints.
        observer_gain: K_o, diagonal, [1/s]; scalar or (n,). ``observer_gain * dt`` must be < 1.
        dt: sample period [s].
    """

    def __init__(
        self,
        n: int,
        observer_gain: npt.ArrayLike,
        dt: float,
        *,
        _state: Sequence[np.ndarray] | None = None,
        _euler: bool = True,
    ) -> None:
        self.n = int(n)
        self.dt = as_positive_scalar(dt, "dt")
        self.observer_gain = as_vector(observer_gain, self.n, "observer_gain", positive=True)
        if _euler and np.any(self.observer_gain * self.dt >= 1.0):  # a Controller's exact form is stable at any gain
            raise ConfigError(
                f"observer_gain * dt must be < 1 for the discrete observer to be stable; got "
                f"observer_gain={self.observer_gain.tolist()} 1/s with dt={self.dt} s"
            )
        # state rows: integral, p(0), residual; a composing Controller may own the storage (``_state``: three
        # (n,) arrays, e.g. views of the C++ core's observer state)
        state = np.zeros((3, self.n)) if _state is None else _state
        self._integral, self._p0, self._r = state[0], state[1], state[2]
        self._buf = np.zeros(self.n)

    @property
    def residual(self) -> np.ndarray:
        return self._r

    @property
    def time_constant(self) -> np.ndarray:
        """Exact time constant of the discrete first-order response per joint [s]."""
        return -self.dt / np.log1p(-self.observer_gain * self.dt)

    def reset(self, momentum: np.ndarray | None = None) -> None:
        self._integral[:] = 0.0
        self._r[:] = 0.0
        if momentum is None:
            self._p0[:] = 0.0
        else:
            self._p0[:] = momentum

    def compute_residual(
        self,
        momentum: np.ndarray,
        tau_m: np.ndarray,
        gamma: np.ndarray,
        alpha: np.ndarray | None,
    ) -> np.ndarray:
        b = self._buf
        np.subtract(tau_m, gamma, out=b)
        if alpha is not None:
            b -= alpha
        b += self._r
        b *= self.dt
        self._integral += b
        np.subtract(momentum, self._p0, out=b)
        b -= self._integral
        np.multiply(self.observer_gain, b, out=self._r)
        return self._r
