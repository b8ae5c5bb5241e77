"""The result of an identification (:class:`DynamicsIdentification`): parameters, how they were
obtained, the model torque they predict, and the model they give the controller.
"""

from __future__ import annotations

import json
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import numpy.typing as npt

from reflexarm.errors import IdentificationError
from reflexarm.ident.estimation.base_parameters import BaseParameters
from reflexarm.ident.estimation.inertia_determinacy import InertiaDeterminacy
from reflexarm.ident.estimation.known_terms import KnownJointTerms
from reflexarm.ident.estimation.regressor import BatchRegressor
from reflexarm.ident.friction.parameters import FrictionParameters
from reflexarm.robots.robot_model import RobotModel

__all__ = ["DynamicsIdentification", "PhysicalConsistencyWarning", "mass_matrix_margin", "save_identification"]

#: Samples per regressor chunk (bounded memory for long logs).
_CHUNK = 10_000


@dataclass(frozen=True)
class DynamicsIdentification:
    """Result of :func:`identify_dynamics`: base parameters + friction, and how they were obtained.

    Attributes:
        method: ``"sequential"`` (beta_II) or ``"combined"`` (beta_I).
        robot_name: the robot's name; joint_names: its joints.
        base: the base-parameter map used.
        beta_b: identified base parameters (n_b,).
        friction: friction parameters (given ones for ``sequential``, identified ones for ``combined``).
        beta_std: standard deviations of the estimated parameters (beta_b, then the estimated friction
            columns), from (F^T Sigma^-1 F)^-1 with the residual variance.
        noise_variance: sigma_j^2 per joint used in Sigma [Nm^2].
        condition_number: of the column-normalised weighted regressor of the estimated parameters.
        n_samples: number of samples used.
        residual_rms: RMS of the training residual per joint [Nm].
        notes: what was done (weights, warnings).
        timings: wall time of the regressor assembly and of the solve [s].
        information: F^T Sigma^-1 F of the estimated parameters (beta_b, then the estimated friction
            columns), the metric of :func:`~reflexarm.ident.estimation.consistency.project_physically_consistent`.
        physical_parameters: a physically consistent standard parameter vector realising beta_b, if
            known (set by the projection); :meth:`to_robot_model` then uses it.
        known_terms: the robot file's armature and joint springs, subtracted from the measured torque
            before the regression and added back by :meth:`compute_torque` (not identified; see
            :mod:`reflexarm.ident.estimation.known_terms`); None in results saved before they were accounted for.
        friction_estimated: 0-based joints whose d_v, mu_C are estimated parameters (after beta_b in
            ``beta_std`` and ``information``: d_v of these joints, then their mu_C); every joint for the
            combined method, those the given friction did not know for the sequential one. None in
            results saved before it was recorded: see :attr:`estimated_friction_joints`.
        inertia_determinacy: how well the data determine M(q) of the least-squares beta_b (1-sigma relative
            uncertainty over postures, :mod:`reflexarm.ident.estimation.inertia_determinacy`); None in older results.
            A projection onto consistent links keeps it (it describes the data, not the projection).
    """

    method: str
    robot_name: str
    joint_names: tuple[str, ...]
    base: BaseParameters
    beta_b: np.ndarray
    friction: FrictionParameters
    beta_std: np.ndarray
    noise_variance: np.ndarray
    condition_number: float
    n_samples: int
    residual_rms: np.ndarray
    notes: tuple[str, ...] = field(default=())
    timings: dict[str, float] = field(default_factory=dict, compare=False)
    information: np.ndarray | None = field(default=None, compare=False)
    physical_parameters: np.ndarray | None = field(default=None, compare=False)
    known_terms: KnownJointTerms | None = field(default=None, compare=False)
    friction_estimated: tuple[int, ...] | None = field(default=None, compare=False)
    inertia_determinacy: InertiaDeterminacy | None = field(default=None, compare=False)

    @property
    def n(self) -> int:
        return self.base.n_joints

    @property
    def estimated_friction_joints(self) -> tuple[int, ...]:
        """:attr:`friction_estimated`, or for old results every joint (combined) or none (sequential)."""
        if self.friction_estimated is not None:
            return self.friction_estimated
        return tuple(range(self.n)) if self.method == "combined" else ()

    def compute_torque(
        self,
        robot: RobotModel | BatchRegressor,
        q: npt.ArrayLike,
        dq: npt.ArrayLike,
        ddq: npt.ArrayLike,
    ) -> np.ndarray:
        """Model torque Phi_b beta_b + tau_f(dq) [+ I_a ddq + K_s (q - q_s)] for (N, n) samples [Nm].

        The robot (or its regressor) gives the kinematics; the known joint terms are the result's own
        (:attr:`known_terms`, taken from the file identified on).
        """
        reg = robot if isinstance(robot, BatchRegressor) else BatchRegressor(robot)
        Q = np.atleast_2d(np.asarray(q, dtype=float))
        DQ = np.atleast_2d(np.asarray(dq, dtype=float))
        DDQ = np.atleast_2d(np.asarray(ddq, dtype=float))
        out = np.empty(Q.shape)
        for sl, Y in reg.iter_chunks(Q, DQ, DDQ, _CHUNK):
            out[sl] = self.base.select(Y) @ self.beta_b
        out += self.friction.compute_torque(DQ)
        if self.known_terms is not None:
            out += self.known_terms.compute_torque(Q, DDQ)
        return out

    def standard_parameters(self, nominal: npt.ArrayLike | None = None) -> np.ndarray:
        """A standard (10 n) inertial vector consistent with beta_b, nearest to ``nominal``."""
        return self.base.standard_from_base(self.beta_b, nominal)

    def to_robot_model(self, robot: RobotModel, *, velocity_band: float | None = None) -> RobotModel:
        """``robot`` with inertias consistent with beta_b (nearest to its own) and the identified friction.

        The rigid-body torques of the returned model equal Phi_b beta_b for every motion (plus the
        robot's armature and springs, which must be the ones identified with: else IdentificationError). Friction
        coefficients below 0 are clipped to 0; offsets are not part of :class:`CoulombViscousFriction`
        and are dropped (a constant sensor bias is not friction the controller should compensate).
        Warns (:class:`PhysicalConsistencyWarning`) if M(q) of beta_b is not positive definite
        everywhere in the joint range (see :func:`mass_matrix_margin`).
        """
        if robot.n != self.n:
            raise IdentificationError(f"identified model has {self.n} joints; robot {robot.name!r} has {robot.n}")
        if self.known_terms is not None:
            theirs = KnownJointTerms.from_robot(robot)
            if not self.known_terms.matches(theirs):
                raise IdentificationError(
                    f"robot {robot.name!r} has other armature/joint springs ({theirs.to_dict()}) than the file the "
                    f"model was identified with ({self.known_terms.to_dict()}); beta_b excludes the identified "
                    "file's terms, so the returned model would have wrong torques: use that file's robot"
                )
        pi = (
            self.physical_parameters
            if self.physical_parameters is not None
            else self.standard_parameters(robot.inertial_parameters())
        )
        band = robot.friction.velocity_band if velocity_band is None else velocity_band
        model = robot.with_inertial_parameters(pi).with_friction(self.friction.to_model(band))
        margin = mass_matrix_margin(model)
        if margin <= 0:
            warnings.warn(
                f"the {self.method} base parameters are not physically consistent: M(q) is not positive definite "
                f"in the joint range (smallest eigenvalue ratio {margin:.3g}); a controller cannot use this model. "
                "Leave out sticking rows (min_speed), use a richer excitation or the sequential method",
                PhysicalConsistencyWarning,
                stacklevel=2,
            )
        return model

    # ------------------------------------------------------------------ serialisation
    def to_dict(self) -> dict[str, object]:
        return {
            "method": self.method,
            "robot_name": self.robot_name,
            "joint_names": list(self.joint_names),
            "base": self.base.to_dict(),
            "beta_b": self.beta_b.tolist(),
            "base_names": self.base.base_names(),
            "friction": self.friction.to_dict(),
            "beta_std": self.beta_std.tolist(),
            "noise_variance": self.noise_variance.tolist(),
            "condition_number": self.condition_number,
            "n_samples": self.n_samples,
            "residual_rms": self.residual_rms.tolist(),
            "notes": list(self.notes),
            "information": None if self.information is None else self.information.tolist(),
            "physical_parameters": None if self.physical_parameters is None else self.physical_parameters.tolist(),
            "known_terms": None if self.known_terms is None else self.known_terms.to_dict(),
            "friction_estimated": None if self.friction_estimated is None else list(self.friction_estimated),
            "inertia_determinacy": None if self.inertia_determinacy is None else self.inertia_determinacy.to_dict(),
        }

    @classmethod
    def from_dict(cls, d: dict[str, object]) -> DynamicsIdentification:
        try:
            base = BaseParameters.from_dict(d["base"])  # type: ignore[arg-type]
            known = d.get("known_terms")
            return cls(
                method=str(d["method"]),
                robot_name=str(d["robot_name"]),
                joint_names=tuple(str(x) for x in d["joint_names"]),  # type: ignore[attr-defined]
                base=base,
                beta_b=np.asarray(d["beta_b"], dtype=float),
                friction=FrictionParameters.from_dict(d["friction"]),  # type: ignore[arg-type]
                beta_std=np.asarray(d.get("beta_std", []), dtype=float),
                noise_variance=np.asarray(d["noise_variance"], dtype=float),
                condition_number=float(d.get("condition_number", np.nan)),  # type: ignore[arg-type]
                n_samples=int(d.get("n_samples", 0)),  # type: ignore[call-overload]
                residual_rms=np.asarray(d.get("residual_rms", []), dtype=float),
                notes=tuple(str(x) for x in d.get("notes", [])),  # type: ignore[attr-defined]
                information=None if d.get("information") is None else np.asarray(d["information"], dtype=float),
                physical_parameters=None
                if d.get("physical_parameters") is None
                else np.asarray(d["physical_parameters"], dtype=float),
                known_terms=None if known is None else KnownJointTerms.from_dict(known),  # type: ignore[arg-type]
                friction_estimated=None
                if d.get("friction_estimated") is None
                else tuple(int(j) for j in d["friction_estimated"]),  # type: ignore[attr-defined]
                inertia_determinacy=None
                if d.get("inertia_determinacy") is None
                else InertiaDeterminacy.from_dict(d["inertia_determinacy"]),  # type: ignore[arg-type]
            )
        except (KeyError, TypeError, ValueError) as e:
            raise IdentificationError(f"malformed identification result: {e}") from e


class PhysicalConsistencyWarning(UserWarning):
    """Identified parameters give a mass matrix that is not positive definite somewhere."""


def mass_matrix_margin(robot: RobotModel, *, n_samples: int = 200, seed: int = 0) -> float:
    """min over random configurations in the joint range of lambda_min(M(q)) / lambda_max(M(q)).

    Positive: M(q) is positive definite at every sampled configuration (a necessary condition for a
    model a controller can use); <= 0: it is not.
    """
    from reflexarm.ident.estimation.base_parameters import random_samples

    q, _, _ = random_samples(robot, n_samples, np.random.default_rng(seed))
    worst = np.inf
    for k in range(n_samples):
        ev = np.linalg.eigvalsh(robot.compute_mass_matrix(q[k]))
        worst = min(worst, float(ev[0] / max(abs(ev[-1]), 1e-300)))
    return worst


def save_identification(result: DynamicsIdentification, path: str | os.PathLike[str]) -> Path:
    """Write ``result.to_dict()`` as JSON."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(json.dumps(result.to_dict(), indent=1))
    return p
