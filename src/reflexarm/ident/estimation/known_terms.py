"""Known joint terms of the robot file (rotor armature, joint springs): given, never identified.

The inertial regressor Y(q, dq, ddq) of eq. (14) (:class:`~reflexarm.ident.estimation.regressor.BatchRegressor`,
:meth:`RobotModel.compute_regressor`) covers the rigid links only. A robot file can add two joint terms
that the motors supply as well:

* rotor inertia (armature) I_a: ``diag(I_a) ddq`` [Nm] (MJCF ``armature``; Pinocchio's rnea includes
  it through ``model.armature``);
* joint springs: ``K_s (q - q_s)`` [Nm] (MJCF ``stiffness``/``springref``,
  :meth:`RobotModel.compute_spring_torque`).

Identification takes both from the file as known: they are subtracted from the measured torque before
the regression, like the friction correction of eq. (16), and added back when the identified model
predicts torques. Without the subtraction they would be misattributed: the armature term is not in the
span of the link parameters (it would bias the link inertias), and the spring term is not in it either
(it would bias everything that correlates with q).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from reflexarm.errors import IdentificationError
from reflexarm.robots.robot_model import RobotModel

__all__ = ["KnownJointTerms"]


@dataclass(frozen=True)
class KnownJointTerms:
    """The file-given joint terms ``diag(I_a) ddq + K_s (q - q_s)`` that identification does not estimate.

    Attributes:
        armature: rotor inertia I_a per joint (n,) [kg m^2, or kg for a prismatic joint].
        spring_stiffness: K_s per joint (n,) [Nm/rad or N/m].
        spring_reference: q_s per joint (n,) [rad or m].
    """

    armature: np.ndarray
    spring_stiffness: np.ndarray
    spring_reference: np.ndarray

    def __post_init__(self) -> None:
        arrays = {
            name: np.asarray(getattr(self, name), dtype=float).reshape(-1)
            for name in ("armature", "spring_stiffness", "spring_reference")
        }
        shapes = {name: a.shape for name, a in arrays.items()}
        if len(set(shapes.values())) != 1:
            raise IdentificationError(f"known joint terms need one value per joint each; got shapes {shapes}")
        for name, a in arrays.items():
            if not np.all(np.isfinite(a)):
                raise IdentificationError(f"known joint term {name} must be finite; got {a.tolist()}")
            object.__setattr__(self, name, a)

    @classmethod
    def from_robot(cls, robot: RobotModel) -> KnownJointTerms:
        """The armature (Pinocchio ``model.armature``) and joint springs of ``robot``'s file."""
        return cls(
            np.array(robot.pin_model.armature, dtype=float).reshape(-1),
            robot.spring_stiffness,
            robot.spring_reference,
        )

    @property
    def n(self) -> int:
        return int(self.armature.size)

    @property
    def is_zero(self) -> bool:
        """True if the file has neither armature nor springs (nothing to subtract)."""
        return not (np.any(self.armature != 0.0) or np.any(self.spring_stiffness != 0.0))

    def compute_torque(self, q: npt.ArrayLike, ddq: npt.ArrayLike) -> np.ndarray:
        """``I_a ddq + K_s (q - q_s)`` for (n,) or (N, n) samples [Nm]."""
        Q = np.asarray(q, dtype=float)
        DDQ = np.asarray(ddq, dtype=float)
        if Q.shape != DDQ.shape or Q.shape[-1] != self.n:
            raise IdentificationError(f"q {Q.shape} and ddq {DDQ.shape} must both be (N, {self.n}) or ({self.n},)")
        return self.armature * DDQ + self.spring_stiffness * (Q - self.spring_reference)

    def matches(self, other: KnownJointTerms, *, rtol: float = 1e-9) -> bool:
        """Same torque function: equal I_a, K_s and K_s q_s within ``rtol`` of each one's largest value."""
        if other.n != self.n:
            return False
        mine = (self.armature, self.spring_stiffness, self.spring_stiffness * self.spring_reference)
        theirs = (other.armature, other.spring_stiffness, other.spring_stiffness * other.spring_reference)
        return all(
            np.allclose(a, b, rtol=0.0, atol=rtol * max(float(np.abs(a).max()), float(np.abs(b).max()), 1.0))
            for a, b in zip(mine, theirs, strict=True)
        )

    def describe(self) -> str:
        """One line for the identification notes."""
        parts = []
        if np.any(self.armature != 0.0):
            parts.append("armature I_a ddq (I_a = " + ", ".join(f"{a:.4g}" for a in self.armature) + ")")
        if np.any(self.spring_stiffness != 0.0):
            stiffness = ", ".join(f"{k:.4g}" for k in self.spring_stiffness)
            parts.append(f"joint springs K_s (q - q_s) (K_s = {stiffness})")
        what = " and ".join(parts) if parts else "none"
        return (
            f"known joint terms from the robot file subtracted from the measured torque before the regression "
            f"and added back in predictions (not identified): {what}"
        )

    def to_dict(self) -> dict[str, object]:
        return {
            "armature": self.armature.tolist(),
            "spring_stiffness": self.spring_stiffness.tolist(),
            "spring_reference": self.spring_reference.tolist(),
        }

    @classmethod
    def from_dict(cls, d: dict[str, object]) -> KnownJointTerms:
        try:
            return cls(
                np.asarray(d["armature"], dtype=float),
                np.asarray(d["spring_stiffness"], dtype=float),
                np.asarray(d["spring_reference"], dtype=float),
            )
        except (KeyError, TypeError, ValueError) as e:
            raise IdentificationError(f"malformed known joint terms: {e}") from e
