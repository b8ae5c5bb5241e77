"""Weighted least squares for the base and friction parameters, eqs. (14)-(19): combined and sequential.

The model (14) with tau_ext = 0 (or removed with the wrist wrench) and the friction regressor (15):

    tau_m = Phi_b(q, dq, ddq) beta_b + diag(dq) d_v + diag(sgn dq) mu_C [+ tau_off]

* **combined** (the paper's beta_I, their earlier work [24]): beta_b, d_v, mu_C (and the offsets)
  estimated together in one weighted least-squares problem.
* **sequential** (the paper's beta_II): d_v, mu_C come from the single-joint constant-velocity
  experiments (:mod:`reflexarm.ident.joint_friction`); the friction-corrected torque (16)-(17)
  ``tau_m,f = tau_m - Phi_f (d_v, mu_C)`` is then explained by Phi_b beta_b alone (45 instead of 59
  unknowns on the Atlas arm).

Both solve (18), ``beta = (F^T Sigma^-1 F)^-1 F^T Sigma^-1 b``, with F and b stacked over the samples as in
(19) and ``Sigma = diag(sigma_1^2, ..., sigma_n^2)`` repeated per sample: each joint's rows are weighted
by its torque noise variance. The variances are given (e.g. the sensor's) or estimated from the
residuals of an ordinary least-squares pass (``noise_variance="estimate"``, the usual two-step
weighting of Gautier and Swevers). The rows are reduced chunk by chunk to per-joint information matrices
(see ``_GramAccumulator``), so memory stays bounded for long logs.

Offsets (``offset=True``): a constant torque per joint, a friction-model extra for a torque sensor's
bias or an asymmetric friction (the Panda's identified friction law has one, see Gaz et al. 2019). In
the sequential method the offsets are estimated together with beta_b unless the given friction has
them.
"""

from __future__ import annotations

import json
import os
import time
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal

import numpy as np
import numpy.typing as npt

from reflexarm.errors import IdentificationError, NonFiniteEstimateError
from reflexarm.ident.base_parameters import (
    BaseParameters,
    compute_base_parameters,
    warn_if_ill_conditioned,
)
from reflexarm.ident.logs import RobotLog
from reflexarm.ident.plausibility import check_log_against_robot, likely_bad_rows
from reflexarm.ident.regressor import BatchRegressor
from reflexarm.robots.friction import DEFAULT_VELOCITY_BAND, CoulombViscousFriction
from reflexarm.robots.robot_model import RobotModel

__all__ = [
    "METHODS",
    "DynamicsIdentification",
    "FrictionParameters",
    "PhysicalConsistencyWarning",
    "TorqueValidation",
    "identify_dynamics",
    "mass_matrix_margin",
    "validate_model",
]

#: The two estimation methods of Sec. II-D.
METHODS = ("sequential", "combined")

#: Condition number of the column-normalised weighted regressor above which identification warns.
#: Column normalisation makes the number independent of parameter units; above ~1e3 a 1 % torque error
#: can move some parameter combination by more than 10 times its share of the torque.
DEFAULT_CONDITION_LIMIT = 1e3

_CHUNK = 10_000


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
            columns), the metric of :func:`~reflexarm.ident.consistency.project_physically_consistent`.
        physical_parameters: a physically consistent standard parameter vector realising beta_b, if
            known (set by the projection); :meth:`to_robot_model` then uses it.
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

    @property
    def n(self) -> int:
        return self.base.n_joints

    def compute_torque(
        self,
        robot: RobotModel | BatchRegressor,
        q: npt.ArrayLike,
        dq: npt.ArrayLike,
        ddq: npt.ArrayLike,
    ) -> np.ndarray:
        """Model torque Phi_b beta_b + tau_f(dq) for (N, n) samples [Nm] (the robot gives the kinematics)."""
        reg = robot if isinstance(robot, BatchRegressor) else BatchRegressor(robot)
        Q = np.atleast_2d(np.asarray(q, dtype=float))
        DQ = np.atleast_2d(np.asarray(dq, dtype=float))
        DDQ = np.atleast_2d(np.asarray(ddq, dtype=float))
        out = np.empty(Q.shape)
        for sl, Y in reg.iter_chunks(Q, DQ, DDQ, _CHUNK):
            out[sl] = self.base.select(Y) @ self.beta_b
        return out + self.friction.compute_torque(DQ)

    def standard_parameters(self, nominal: npt.ArrayLike | None = None) -> np.ndarray:
        """A standard (10 n) inertial vector consistent with beta_b, nearest to ``nominal``."""
        return self.base.standard_from_base(self.beta_b, nominal)

    def to_robot_model(self, robot: RobotModel, *, velocity_band: float | None = None) -> RobotModel:
        """``robot`` with inertias consistent with beta_b (nearest to its own) and the identified friction.

        The rigid-body torques of the returned model equal Phi_b beta_b for every motion. Friction
        coefficients below 0 are clipped to 0; offsets are not part of :class:`CoulombViscousFriction`
        and are dropped (a constant sensor bias is not friction the controller should compensate).
        Warns (:class:`PhysicalConsistencyWarning`) if M(q) of beta_b is not positive definite
        everywhere in the joint range (see :func:`mass_matrix_margin`).
        """
        if robot.n != self.n:
            raise IdentificationError(f"identified model has {self.n} joints; robot {robot.name!r} has {robot.n}")
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
        }

    @classmethod
    def from_dict(cls, d: dict[str, object]) -> DynamicsIdentification:
        try:
            base = BaseParameters.from_dict(d["base"])  # type: ignore[arg-type]
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
    from reflexarm.ident.base_parameters import random_samples

    q, _, _ = random_samples(robot, n_samples, np.random.default_rng(seed))
    worst = np.inf
    for k in range(n_samples):
        ev = np.linalg.eigvalsh(robot.compute_mass_matrix(q[k]))
        worst = min(worst, float(ev[0] / max(abs(ev[-1]), 1e-300)))
    return worst


# ---------------------------------------------------------------------------------------------- solve
@dataclass(frozen=True)
class _Solution:
    x: np.ndarray
    information: np.ndarray  # A^T W A
    covariance: np.ndarray  # (A^T W A)^+
    residual_norm: float
    condition_number: float  # of the column-equilibrated weighted regressor
    rank_deficiency: int


class _GramAccumulator:
    """Row-chunked weighted least squares per joint: keeps G_j = [A_j b_j]^T [A_j b_j], (p+1) x (p+1).

    Since Sigma is diagonal per joint, the weighted problem of any weights is ``sum_j G_j / sigma_j^2``,
    so one pass over the data serves the unweighted pass, the weighted solve and the residual
    statistics (``|A_j x - b_j|^2 = (x, -1)^T G_j (x, -1)``). The solve equilibrates the columns
    (unit diagonal, which removes the parameters' units from the conditioning) and uses the eigen-
    decomposition of the equilibrated information matrix: its relative accuracy is about eps * cond^2
    of the equilibrated regressor (1e-10 at the warning limit cond = 1e3), and a rank-deficient problem
    gets the minimum-norm solution instead of a failure. (A chunked QR would be accurate to eps * cond
    but costs 10-100x more on a shared machine, where multi-threaded LAPACK QR of tall matrices degrades
    badly.)
    """

    def __init__(self, n: int, p: int) -> None:
        self.n = n
        self.p = p
        self.G = np.zeros((n, p + 1, p + 1))
        self.rows = np.zeros(n, dtype=np.int64)

    def add(self, M: np.ndarray, keep: np.ndarray | None = None) -> None:
        """M: (n, m, p + 1) rows [A_j b_j] per joint; keep: (m, n) bool, rows to use (default all)."""
        for j in range(self.n):
            Mj = M[j] if keep is None else M[j][keep[:, j]]
            self.G[j] += Mj.T @ Mj
            self.rows[j] += Mj.shape[0]

    def solve(self, weights: np.ndarray) -> _Solution:
        """min sum_j w_j^2 |A_j x - b_j|^2 (minimum-norm in equilibrated coordinates if rank deficient)."""
        p = self.p
        G = np.einsum("j,jab->ab", weights**2, self.G)
        AtA, Atb, btb = G[:p, :p], G[:p, p], G[p, p]
        d = np.sqrt(np.maximum(np.diag(AtA), 0.0))
        zero = d <= max(d.max(), 1e-300) * 1e-13
        ds = np.where(zero, 1.0, d)
        S = AtA / np.outer(ds, ds)
        S[zero, :] = 0.0
        S[:, zero] = 0.0
        ev, V = np.linalg.eigh(0.5 * (S + S.T))
        keep = ev > max(ev[-1], 1e-300) * 1e-12
        cond = float(np.sqrt(ev[-1] / ev[0])) if ev[0] > 0 else float("inf")
        # y = S^+ (A^T b / d): eigen-decomposition solve, exact pseudo-inverse when rank deficient
        rhs = np.where(zero, 0.0, Atb / ds)
        y = V[:, keep] @ ((V[:, keep].T @ rhs) / ev[keep])
        x = y / ds
        res2 = max(float(btb - 2 * x @ Atb + x @ AtA @ x), 0.0)
        # covariance factor of the estimate: (A^T W A)^+ in the original coordinates
        cov = (V[:, keep] / ev[keep]) @ V[:, keep].T / np.outer(ds, ds)
        return _Solution(x, AtA, cov, float(np.sqrt(res2)), cond, int(p - keep.sum()))

    def residual_ss(self, x: np.ndarray) -> np.ndarray:
        """sum over samples of (A_j x - b_j)^2 per joint."""
        y = np.r_[x, -1.0]
        return np.maximum(np.einsum("a,jab,b->j", y, self.G, y), 0.0)


def _rhs(robot: RobotModel, log: RobotLog) -> np.ndarray:
    """b of (19): measured torque plus the external torque of the wrist wrench, eq. (14)."""
    tau = log.tau.copy()
    if log.wrench is not None:
        for k in range(len(log)):
            tau[k] += robot.compute_frame_jacobian(log.q[k]).T @ log.wrench[k]
    return tau


def identify_dynamics(
    robot: RobotModel,
    log: RobotLog | Sequence[RobotLog],
    *,
    method: Literal["sequential", "combined"] = "sequential",
    friction: FrictionParameters | CoulombViscousFriction | None = None,
    offset: bool = False,
    noise_variance: npt.ArrayLike | Literal["estimate"] | None = "estimate",
    base: BaseParameters | None = None,
    condition_limit: float = DEFAULT_CONDITION_LIMIT,
    min_speed: float = 0.0,
    progress: bool = False,
    check_limits: bool = True,
) -> DynamicsIdentification:
    """Identify beta_b (and friction) from a log by weighted least squares, eq. (18).

    Args:
        robot: the arm (kinematics; the nominal inertias are not used).
        log: one or more preprocessed logs (with ``ddq``, see :func:`~reflexarm.ident.preprocess_log`).
        method: ``"sequential"`` (friction fixed to ``friction``, eqs. (16)-(17)) or ``"combined"``.
        friction: the pre-identified friction for ``sequential`` (required there, ignored otherwise).
        offset: also estimate a constant torque per joint (see the module docstring).
        noise_variance: sigma_j^2 per joint [Nm^2] for Sigma; ``"estimate"``: from the residuals of an
            unweighted pass; None: unweighted (Sigma = I).
        base: base-parameter map (default: computed from ``robot``).
        condition_limit: warn (:class:`IllConditionedWarning`) above this condition number.
        min_speed: leave out the rows (joint j at sample k) with |dq_j| < min_speed [rad/s]: there the
            sign of the velocity, hence the Coulomb torque, is undetermined (sticking, or speeds within
            the velocity noise). Each joint's rows are separate equations of (19), so this drops no
            other joint's information. Default 0: every row is used.
        progress: show a progress bar over the regressor chunks.
        check_limits: refuse logs that leave the robot's limits by far
            (:func:`~reflexarm.ident.plausibility.check_log_against_robot`: torque beyond 10 x the effort
            limit, velocity beyond 10 x the velocity limit, position a quarter turn outside the range).

    Warns:
        IllConditionedWarning: the regressor is rank deficient or its condition number (column-
            normalised, weighted) exceeds ``condition_limit``; the message gives the condition number.

    Raises:
        IdentificationError: unknown method, missing friction for ``sequential``, log without ddq,
            joint count mismatch.
        NonFiniteEstimateError: (an IdentificationError) the solution is NaN/inf; the message and its
            ``samples`` name the rows that stand out most from their columns (the likely bad rows).
        ImplausibleDataError: (a DataError) ``check_limits`` and a log far outside the robot's limits;
            the message names the rows, columns, values and bounds.
    """
    if method not in METHODS:
        raise IdentificationError(f"unknown identification method {method!r}; choose one of: {', '.join(METHODS)}")
    logs = [log] if isinstance(log, RobotLog) else list(log)
    if not logs:
        raise IdentificationError("no log given")
    n = robot.n
    for lg in logs:
        if lg.n != n:
            raise IdentificationError(f"{lg.source}: log has {lg.n} joints; robot {robot.name!r} has {n}")
        if lg.ddq is None:
            raise IdentificationError(
                f"{lg.source}: log has no ddq; run reflexarm.ident.preprocess_log first (filtering and differentiation)"
            )
        if check_limits:
            check_log_against_robot(lg, robot)
    fixed: FrictionParameters | None = None
    if method == "sequential":
        if friction is None:
            raise IdentificationError(
                "method 'sequential' needs the pre-identified friction (friction=...; see identify_joint_friction)"
            )
        fixed = FrictionParameters.from_model(friction) if isinstance(friction, CoulombViscousFriction) else friction
        if fixed.n != n:
            raise IdentificationError(f"friction has {fixed.n} joints; robot {robot.name!r} has {n}")
    base = base if base is not None else compute_base_parameters(robot)
    reg = BatchRegressor(robot)
    nb = base.n_base
    est_offset = offset and (fixed is None or fixed.offset is None)
    n_fric = 0 if method == "sequential" else 2 * n
    p = nb + n_fric + (n if est_offset else 0)

    def rows(lg: RobotLog, b_all: np.ndarray, sl: slice, Y: np.ndarray) -> np.ndarray:
        """Rows [Phi_b (Phi_f) (offsets) | b] of (19), per joint: (n, m, p + 1)."""
        m = Y.shape[0]
        M = np.zeros((n, m, p + 1))
        M[:, :, :nb] = np.take(Y, base.independent, axis=2).transpose(1, 0, 2)
        b = b_all[sl]
        dq = lg.dq[sl]
        k = nb
        idx = np.arange(n)
        if method == "combined":  # eq. (15): each joint's friction columns act on its own rows only
            M[idx, :, k + idx] = dq.T
            M[idx, :, k + n + idx] = np.sign(dq).T
            k += 2 * n
        elif fixed is not None:
            b = b - fixed.compute_torque(dq)  # eq. (16)
        if est_offset:
            M[idx, :, k + idx] = 1.0
        M[:, :, p] = b.T
        return M

    # weights: given, estimated from an unweighted pass, or none
    given = None
    if isinstance(noise_variance, str):
        if noise_variance != "estimate":
            raise IdentificationError(
                f"noise_variance must be per-joint variances, 'estimate' or None; got {noise_variance!r}"
            )
    elif noise_variance is not None:
        given = np.broadcast_to(np.asarray(noise_variance, dtype=float), (n,)).copy()
        if not np.all(np.isfinite(given)) or np.any(given <= 0):
            raise IdentificationError(f"noise_variance must be positive per joint; got {given.tolist()}")
    total = sum(len(lg) for lg in logs)
    acc = _GramAccumulator(n, p)
    t_reg = t_solve = 0.0
    for lg in logs:
        assert lg.ddq is not None  # checked above
        clock = time.perf_counter()
        b_all = _rhs(robot, lg)
        t_reg += time.perf_counter() - clock
        chunks = _progress(reg.iter_chunks(lg.q, lg.dq, lg.ddq, _CHUNK), progress, lg)
        while True:
            clock = time.perf_counter()
            try:
                sl, Y = next(chunks)
            except StopIteration:
                break
            M = rows(lg, b_all, sl, Y)
            keep = np.abs(lg.dq[sl]) >= min_speed if min_speed > 0 else None
            t_reg += time.perf_counter() - clock
            clock = time.perf_counter()
            acc.add(M, keep)
            t_solve += time.perf_counter() - clock
    _refuse_non_finite({"entries of the information matrix": acc.G}, logs)
    clock = time.perf_counter()
    notes: list[str] = []
    if given is not None:
        sigma2 = given
        notes.append(
            "Sigma from the given per-joint noise variances: " + ", ".join(f"{s:.3g}" for s in sigma2) + " Nm^2"
        )
    elif noise_variance is None:
        sigma2 = np.ones(n)
        notes.append("unweighted least squares (Sigma = I)")
    else:
        # per-joint residual variance of an unweighted fit -> Sigma of (18)
        x0 = acc.solve(np.ones(n)).x
        sigma2 = np.maximum(acc.residual_ss(x0) / np.maximum(acc.rows - p / n, 1.0), 1e-12)
        _refuse_non_finite({"unweighted parameters": x0, "noise variances": sigma2}, logs)
        notes.append(
            "Sigma from the per-joint residual variances of an unweighted pass: "
            + ", ".join(f"{s:.3g}" for s in sigma2)
            + " Nm^2"
        )
    sol = acc.solve(1.0 / np.sqrt(sigma2))
    x, cond = sol.x, sol.condition_number
    t_solve += time.perf_counter() - clock
    what = f"the identification regressor ({p} parameters, {int(acc.rows.max()):,} samples)"
    warn_if_ill_conditioned(cond, what, condition_limit, sol.rank_deficiency)
    if sol.rank_deficiency:
        notes.append(
            f"rank deficient by {sol.rank_deficiency}: the unexcited parameter combinations got the minimum-norm "
            "estimate (in column-normalised coordinates)"
        )
    # parameter standard deviations: s^2 (F^T W F)^+ with s^2 the weighted residual variance
    dof = max(int(acc.rows.sum()) - p, 1)
    s2 = sol.residual_norm**2 / dof
    std = np.sqrt(np.maximum(s2 * np.diag(sol.covariance), 0.0))
    residual_rms = np.sqrt(acc.residual_ss(x) / np.maximum(acc.rows, 1))
    _refuse_non_finite({"parameters": x, "standard deviations": std, "residual RMS": residual_rms}, logs)
    if min_speed > 0:
        notes.append(
            f"rows with |dq_j| < {min_speed:g} rad/s left out: "
            + ", ".join(f"{100 * (1 - r / total):.0f} %" for r in acc.rows)
            + " of each joint's samples"
        )
    beta_b = x[:nb]
    k = nb
    if method == "combined":
        fr = FrictionParameters(x[k : k + n], x[k + n : k + 2 * n])
        k += 2 * n
    else:
        assert fixed is not None
        fr = fixed
    if est_offset:
        fr = replace(fr, offset=x[k : k + n])
    return DynamicsIdentification(
        method=method,
        robot_name=robot.name,
        joint_names=tuple(robot.joint_names),
        base=base,
        beta_b=beta_b,
        friction=fr,
        beta_std=std,
        noise_variance=sigma2,
        condition_number=cond,
        n_samples=total,
        residual_rms=residual_rms,
        notes=tuple(notes),
        timings={"regressor_s": t_reg, "solve_s": t_solve},
        information=sol.information,
    )


def _refuse_non_finite(values: dict[str, np.ndarray], logs: Sequence[RobotLog]) -> None:
    """Raise :class:`NonFiniteEstimateError` naming the likely bad rows if any of ``values`` is NaN/inf."""
    bad = {name: int(np.sum(~np.isfinite(v))) for name, v in values.items() if not np.all(np.isfinite(v))}
    if not bad:
        return
    suspects = likely_bad_rows(logs)
    what = ", ".join(f"{k} of {values[name].size} {name}" for name, k in bad.items())
    if suspects:
        listed = "; ".join(f"{s.source} {s} (its column's 99th percentile {s.reference:.3g})" for s in suspects)
        cause = f"the rows that stand out most from their columns (likely bad rows): {listed}. Remove or repair them"
    else:
        cause = "no row stands out from its column; check the given noise variances (tiny ones overflow the weights)"
    raise NonFiniteEstimateError(
        f"identification gave non-finite results ({what}): the weighted least-squares problem overflowed; {cause}",
        tuple(suspects),
    )


def _progress(it, progress: bool, lg: RobotLog):  # type: ignore[no-untyped-def]
    if not progress:
        yield from it
        return
    from tqdm import tqdm

    with tqdm(total=len(lg), desc=f"regressor {lg.source}", unit="sample", leave=False) as bar:
        for sl, Y in it:
            yield sl, Y
            bar.update(sl.stop - sl.start)


# ---------------------------------------------------------------------------------------------- validation
@dataclass(frozen=True)
class TorqueValidation:
    """Measured against predicted torques on a log (ideally not the one identified on).

    Attributes:
        t: time (N,) [s]; measured, predicted: (N, n) [Nm]; dq: the velocities used (N, n) [rad/s].
        mse: per joint [Nm^2]; rmse: per joint [Nm]; nrmse: rmse / std(measured) per joint [-].
        pooled_rmse: over all joints and samples [Nm].
        label: which model (e.g. ``"sequential"``).
    """

    t: np.ndarray
    measured: np.ndarray
    predicted: np.ndarray
    label: str = ""
    dq: np.ndarray | None = None

    @property
    def error(self) -> np.ndarray:
        return self.predicted - self.measured

    def mse_moving(self, min_speed: float) -> np.ndarray:
        """MSE per joint over the samples where that joint moves, |dq_j| >= ``min_speed`` [Nm^2]."""
        if self.dq is None:
            raise IdentificationError("this validation has no velocities; build it with validate_model")
        keep = np.abs(self.dq) >= min_speed
        e2 = np.where(keep, self.error**2, 0.0)
        return e2.sum(axis=0) / np.maximum(keep.sum(axis=0), 1)

    @property
    def mse(self) -> np.ndarray:
        return np.mean(self.error**2, axis=0)

    @property
    def rmse(self) -> np.ndarray:
        return np.sqrt(self.mse)

    @property
    def nrmse(self) -> np.ndarray:
        return self.rmse / np.maximum(self.measured.std(axis=0), 1e-300)

    @property
    def pooled_rmse(self) -> float:
        return float(np.sqrt(np.mean(self.error**2)))

    def table(self, joint_names: Sequence[str] | None = None) -> list[dict[str, object]]:
        """Rows ``{joint, mse, rmse, nrmse, std}`` per joint."""
        names = list(joint_names) if joint_names is not None else [str(j + 1) for j in range(self.measured.shape[1])]
        std = self.measured.std(axis=0)
        return [
            {
                "joint": names[j],
                "mse": float(self.mse[j]),
                "rmse": float(self.rmse[j]),
                "nrmse": float(self.nrmse[j]),
                "torque_std": float(std[j]),
            }
            for j in range(len(names))
        ]


def validate_model(
    result: DynamicsIdentification,
    robot: RobotModel,
    log: RobotLog,
    *,
    states: RobotLog | None = None,
    label: str | None = None,
) -> TorqueValidation:
    """Predict the torques of ``log`` with ``result`` and compare with its measured (unfiltered) torques.

    Args:
        result: an identification.
        robot: the arm (kinematics).
        log: the validation log; its measured torque is the reference (``log.measured_torque``).
        states: where to take q, dq, ddq from if not from ``log`` itself (e.g. a filtered copy on a
            uniform grid); they are interpolated to ``log.t``.
        label: name of the model in plots and tables (default: the method).
    """
    if states is None:
        if log.ddq is None:
            raise IdentificationError(f"{log.source}: validation log has no ddq; preprocess it or pass states=")
        q, dq, ddq = log.q, log.dq, log.ddq
    else:
        if states.ddq is None:
            raise IdentificationError(f"{states.source}: states have no ddq; preprocess them first")
        if log.t[0] < states.t[0] - 1e-9 or log.t[-1] > states.t[-1] + 1e-9:
            raise IdentificationError(
                f"{log.source}: validation times {log.t[0]:.4g}..{log.t[-1]:.4g} s are outside the states' "
                f"{states.t[0]:.4g}..{states.t[-1]:.4g} s"
            )
        _refuse_times_in_gaps(log, states)
        q = _interp_cols(states.t, states.q, log.t)
        dq = _interp_cols(states.t, states.dq, log.t)
        ddq = _interp_cols(states.t, states.ddq, log.t)
    pred = result.compute_torque(robot, q, dq, ddq)
    meas = log.measured_torque
    if log.wrench is not None:
        meas = _rhs(robot, replace(log, tau=meas, tau_raw=None))
    return TorqueValidation(log.t.copy(), meas.copy(), pred, label if label is not None else result.method, dq.copy())


def _refuse_times_in_gaps(log: RobotLog, states: RobotLog) -> None:
    """States split at long gaps (:func:`~reflexarm.ident.preprocess_log`) have no values inside a gap;
    interpolating there would invent q, dq, ddq, so validation times inside one are refused."""
    steps = np.diff(states.t)
    gaps = np.flatnonzero(steps > 1.5 * np.median(steps))
    if not gaps.size:
        return
    idx = np.searchsorted(states.t, log.t, side="right") - 1
    idx = np.clip(idx, 0, steps.size - 1)
    inside = np.isin(idx, gaps) & (log.t > states.t[idx] + 1e-9) & (log.t < states.t[idx + 1] - 1e-9)
    if inside.any():
        k = int(np.argmax(inside))
        raise IdentificationError(
            f"{log.source}: {int(inside.sum()):,} validation sample(s) fall in a gap of the states {states.source!r} "
            f"(first at t = {log.t[k]:.6g} s, between {states.t[idx[k]]:.6g} and {states.t[idx[k] + 1]:.6g} s); "
            "interpolating across it would invent q, dq, ddq: validate on the segments only (RobotLog.select)"
        )


def _interp_cols(t: np.ndarray, y: np.ndarray, tn: np.ndarray) -> np.ndarray:
    return np.column_stack([np.interp(tn, t, y[:, j]) for j in range(y.shape[1])])


def save_identification(result: DynamicsIdentification, path: str | os.PathLike[str]) -> Path:
    """Write ``result.to_dict()`` as JSON."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(json.dumps(result.to_dict(), indent=1))
    return p
