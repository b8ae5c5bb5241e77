"""Coulomb + viscous (+ offset) friction parameters per joint, eq. (15), as identified.

The identification's own bundle (exact sign, optional constant offsets); :meth:`FrictionParameters.to_model`
turns it into the controller's :class:`~reflexarm.robots.friction.CoulombViscousFriction`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from reflexarm.errors import IdentificationError
from reflexarm.robots.friction import DEFAULT_VELOCITY_BAND, CoulombViscousFriction

__all__ = ["FrictionParameters"]


@dataclass(frozen=True)
class FrictionParameters:
    """Coulomb + viscous (+ offset) friction per joint, eq. (15), exact sign.

    Attributes:
        viscous: d_v [Nms/rad] (n,).
        coulomb: mu_C [Nm] (n,).
        offset: constant torque [Nm] (n,) or None.
    """

    viscous: np.ndarray
    coulomb: np.ndarray
    offset: np.ndarray | None = None

    def __post_init__(self) -> None:
        v = np.asarray(self.viscous, dtype=float).reshape(-1)
        c = np.asarray(self.coulomb, dtype=float).reshape(-1)
        if v.shape != c.shape:
            raise IdentificationError(f"viscous {v.shape} and coulomb {c.shape} must have one value per joint")
        object.__setattr__(self, "viscous", v)
        object.__setattr__(self, "coulomb", c)
        if self.offset is not None:
            o = np.asarray(self.offset, dtype=float).reshape(-1)
            if o.shape != v.shape:
                raise IdentificationError(f"offset {o.shape} must have one value per joint like viscous {v.shape}")
            object.__setattr__(self, "offset", o)

    @property
    def n(self) -> int:
        return int(self.viscous.size)

    @classmethod
    def from_model(cls, friction: CoulombViscousFriction) -> FrictionParameters:
        """From a :class:`CoulombViscousFriction` (no offsets)."""
        return cls(friction.viscous.copy(), friction.coulomb.copy())

    def parameters(self) -> np.ndarray:
        """(d_v, mu_C[, offset]) stacked, the column order of :func:`compute_friction_regressor`."""
        parts = [self.viscous, self.coulomb] + ([self.offset] if self.offset is not None else [])
        return np.concatenate(parts)

    def compute_torque(self, dq: npt.ArrayLike) -> np.ndarray:
        """tau_f = d_v dq + mu_C sgn(dq) [+ offset], exact sign, for (n,) or (N, n) velocities [Nm]."""
        dq = np.asarray(dq, dtype=float)
        out = self.viscous * dq + self.coulomb * np.sign(dq)
        return out + self.offset if self.offset is not None else out

    def to_model(self, velocity_band: float = DEFAULT_VELOCITY_BAND) -> CoulombViscousFriction:
        """The controller's friction model (negative coefficients clipped to 0; offsets are not part of it)."""
        return CoulombViscousFriction(
            np.maximum(self.coulomb, 0.0), np.maximum(self.viscous, 0.0), velocity_band=velocity_band
        )

    def to_dict(self) -> dict[str, object]:
        return {
            "viscous": self.viscous.tolist(),
            "coulomb": self.coulomb.tolist(),
            "offset": None if self.offset is None else self.offset.tolist(),
        }

    @classmethod
    def from_dict(cls, d: dict[str, object]) -> FrictionParameters:
        try:
            return cls(
                np.asarray(d["viscous"], dtype=float),
                np.asarray(d["coulomb"], dtype=float),
                None if d.get("offset") is None else np.asarray(d["offset"], dtype=float),
            )
        except (KeyError, TypeError, ValueError) as e:
            raise IdentificationError(f"malformed friction description: {e}") from e
