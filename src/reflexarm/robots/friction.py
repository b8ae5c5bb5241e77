"""Joint friction models: Coulomb + viscous, eq. (1) and (15) of the paper."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from reflexarm._validation import as_positive_scalar, as_vector
from reflexarm.errors import ConfigError

__all__ = ["CoulombViscousFriction"]

#: Default half-width of the velocity band in which the smooth sign is linear [rad/s]. Inside the band
#: the Coulomb term ramps linearly from -mu_C to +mu_C, so the compensation does not chatter at rest
#: where the measured velocity is mostly noise (the paper's velocity noise is +-5.5e-2 rad/s).
DEFAULT_VELOCITY_BAND = 0.02


@dataclass(frozen=True, eq=False)
class CoulombViscousFriction:
    """tau_f(dq) = mu_C * sgn_band(dq) + d_v * dq, per joint.

    Attributes:
        coulomb: mu_C, Coulomb friction per joint [Nm], non-negative.
        viscous: d_v, viscous friction per joint [Nms/rad], non-negative.
        velocity_band: half-width of the linear zone of the smooth sign [rad/s]; ``sgn_band(x) =
            clip(x / velocity_band, -1, 1)``. The identification regressor (15) uses the exact sign.

    The coefficient arrays are read-only (one friction model is shared by copies of a robot); use
    :meth:`scaled` or build a new model to change them.
    """

    coulomb: np.ndarray
    viscous: np.ndarray
    velocity_band: float = DEFAULT_VELOCITY_BAND
    _inv_band: float = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        n = np.asarray(self.coulomb).size
        coulomb = as_vector(self.coulomb, n, "coulomb", nonnegative=True)
        viscous = as_vector(self.viscous, n, "viscous", nonnegative=True)
        coulomb.flags.writeable = False
        viscous.flags.writeable = False
        object.__setattr__(self, "coulomb", coulomb)
        object.__setattr__(self, "viscous", viscous)
        band = as_positive_scalar(self.velocity_band, "velocity_band")
        object.__setattr__(self, "velocity_band", band)
        object.__setattr__(self, "_inv_band", 1.0 / band)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, CoulombViscousFriction):
            return NotImplemented
        return (
            self.velocity_band == other.velocity_band
            and np.array_equal(self.coulomb, other.coulomb)
            and np.array_equal(self.viscous, other.viscous)
        )

    def __hash__(self) -> int:
        return hash((self.coulomb.tobytes(), self.viscous.tobytes(), self.velocity_band))

    @property
    def n(self) -> int:
        """Number of joints."""
        return int(self.coulomb.size)

    @classmethod
    def zeros(cls, n: int) -> CoulombViscousFriction:
        """A frictionless model for ``n`` joints."""
        return cls(np.zeros(n), np.zeros(n))

    def compute_torque(self, dq: npt.ArrayLike) -> np.ndarray:
        """tau_f(dq) [Nm] with the smooth sign."""
        dq = np.asarray(dq, dtype=float)
        s = np.clip(dq * self._inv_band, -1.0, 1.0)
        return self.coulomb * s + self.viscous * dq

    def compute_torque_into(self, dq: np.ndarray, out: np.ndarray) -> np.ndarray:
        """tau_f(dq) written into ``out`` (float64 (n,), like ``dq``) for the control hot path; returns ``out``.

        ``out`` must be a different array from ``dq`` (the smooth sign is formed in ``out`` first).
        """
        if out is dq:
            raise ConfigError("compute_torque_into: out must not be dq (it is overwritten before dq is read)")
        np.multiply(dq, self._inv_band, out=out)
        np.minimum(out, 1.0, out=out)
        np.maximum(out, -1.0, out=out)
        out *= self.coulomb
        out += self.viscous * dq
        return out

    def compute_regressor(self, dq: npt.ArrayLike) -> np.ndarray:
        """Phi_f(dq) = (diag(dq)  diag(sgn(dq))), eq. (15), for one sample: shape (n, 2n).

        Parameter order: (d_v, mu_C), matching :meth:`parameters`.
        """
        dq = np.asarray(dq, dtype=float)
        return np.hstack([np.diag(dq), np.diag(np.sign(dq))])

    def parameters(self) -> np.ndarray:
        """(d_v, mu_C) stacked, shape (2n,)."""
        return np.concatenate([self.viscous, self.coulomb])

    def scaled(self, coulomb_scale: npt.ArrayLike, viscous_scale: npt.ArrayLike) -> CoulombViscousFriction:
        """A copy with each coefficient multiplied by the given factors."""
        return CoulombViscousFriction(
            self.coulomb * np.asarray(coulomb_scale, dtype=float),
            self.viscous * np.asarray(viscous_scale, dtype=float),
            self.velocity_band,
        )
